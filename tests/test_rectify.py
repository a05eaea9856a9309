"""Rectification: indirect/direct mapping, tiling, nodata, files, CLI.

References: rasterio's own affine arithmetic, scipy.ndimage.map_coordinates
and cv2.remap on coordinates computed here in numpy, and closed forms
(bilinear interpolation reproduces a linear grey-value ramp exactly).
"""

import importlib

import cv2
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import rasterio
import rasterio.transform
from scipy import ndimage

import photax
from photax.io.raster import read_dem, read_geotiff, write_geotiff
from photax.rectification import Grid, rectify, rectify_file

H, W = 90, 120
# Map -> pixel: col = (X - 1000) / 2 + 0.05 (Y - 5000), row = (5200 - Y) / 2.5 ...
A = np.array([[0.5, 0.05, -500.0 - 250.0], [0.02, -0.4, 2080.0 - 20.0]])


def affine_model(xy):
    x, y = xy[..., 0], xy[..., 1]
    return jnp.stack([A[0, 0] * x + A[0, 1] * y + A[0, 2], A[1, 0] * x + A[1, 1] * y + A[1, 2]], axis=-1)


def affine_np(x, y):
    return A[0, 0] * x + A[0, 1] * y + A[0, 2], A[1, 0] * x + A[1, 1] * y + A[1, 2]


def poly_model(xy):  # a 2nd-order map, with curvature
    x, y = (xy[..., 0] - 1100.0) / 100.0, (xy[..., 1] - 5100.0) / 100.0
    c = 60.0 + 48.0 * x + 4.0 * y + 3.0 * x * x - 2.0 * x * y
    r = 45.0 - 36.0 * y + 2.0 * x + 1.5 * y * y
    return jnp.stack([c, r], axis=-1)


GRID = Grid.from_bounds((1000.0, 4980.0, 1260.0, 5200.0), 2.0, crs="EPSG:32633")


def test_grid_matches_rasterio():
    g = Grid.from_bounds((1000.3, 4980.2, 1259.1, 5199.5), (2.0, 2.5), crs="EPSG:32633", target_aligned=True)
    assert g.bounds == (1000.0, 4980.0, 1260.0, 5200.0)
    assert g.shape == (88, 130)
    rows, cols = np.mgrid[3:7, 10:14]
    xs, ys = rasterio.transform.xy(g.transform, rows, cols, offset="center")
    xy = g.xy(slice(3, 7), slice(10, 14))
    np.testing.assert_allclose(xy[..., 0], np.reshape(xs, rows.shape), rtol=0, atol=1e-9)
    np.testing.assert_allclose(xy[..., 1], np.reshape(ys, rows.shape), rtol=0, atol=1e-9)


def _footprint(cols, rows):
    return (cols >= -0.5) & (cols <= W - 0.5) & (rows >= -0.5) & (rows <= H - 0.5)


@pytest.mark.parametrize("approx, atol", [(0, 1e-9), (0.125, 5e-4)])
def test_indirect_linear_ramp_is_exact(approx, atol):
    # Bilinear interpolation reproduces a linear grey-value ramp exactly.  The
    # approximate mapping interpolates an affine map exactly too, but in
    # float32 relative to a local origin (< 200 px: ulp 1.5e-5 px; a few ulps
    # times the ramp's gradient |3| + |2| stays far below 5e-4).
    r, c = np.mgrid[0:H, 0:W].astype(float)
    image = 3.0 * c - 2.0 * r + 7.0
    out = rectify(image, affine_model, GRID, resampling="bilinear", approx=approx)
    xy = GRID.xy()
    cols, rows = affine_np(xy[..., 0], xy[..., 1])
    inside = _footprint(cols, rows) & (cols <= W - 1) & (rows <= H - 1) & (cols >= 0) & (rows >= 0)
    assert inside.sum() > 5000
    np.testing.assert_allclose(out[inside], (3.0 * cols - 2.0 * rows + 7.0)[inside], rtol=0, atol=atol)


@pytest.mark.parametrize("order", [1, 3])
def test_indirect_matches_scipy_map_coordinates(order):
    rng = np.random.default_rng(1)
    image = ndimage.gaussian_filter(rng.uniform(0, 255, (2, H, W)), 1.5)
    method = {1: "bilinear", 3: "bspline"}[order]
    out = rectify(image, poly_model, GRID, resampling=method, approx=0)
    xy = GRID.xy()
    cr = np.asarray(poly_model(jnp.asarray(xy)))
    cols, rows = cr[..., 0], cr[..., 1]
    inside = _footprint(cols, rows)
    for b in range(2):
        ref = ndimage.map_coordinates(image[b], [rows, cols], order=order, mode="nearest")
        np.testing.assert_allclose(out[b][inside], ref[inside], atol=1e-7)
    assert np.all(np.isnan(out[:, ~inside]))
    assert inside.sum() > 3000 and (~inside).sum() > 1000


def test_indirect_uint8_matches_cv2_remap_nearest_and_bilinear():
    rng = np.random.default_rng(2)
    image = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (5, 5), 1.0)
    xy = GRID.xy()
    cr = np.asarray(poly_model(jnp.asarray(xy)))
    cols, rows = cr[..., 0].astype(np.float32), cr[..., 1].astype(np.float32)
    inside = _footprint(cols, rows) & (cols >= 0) & (cols <= W - 1) & (rows >= 0) & (rows <= H - 1)
    out = rectify(image, poly_model, GRID, resampling="nearest", nodata=7, approx=0)
    ref = cv2.remap(image, cols, rows, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    # Exact ties (x.5) may round differently; there are none at random positions.
    assert np.mean(out[inside] == ref[inside]) > 0.999
    assert np.all(out[~_footprint(cols, rows)] == 7)
    out = rectify(image, poly_model, GRID, resampling="bilinear", approx=0)
    ref = cv2.remap(image, cols, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # OpenCV quantises the fractions to 1/32 pixel: differences of one grey level.
    assert np.abs(out[inside].astype(int) - ref[inside]).max() <= 1


def test_tiling_gives_identical_output():
    rng = np.random.default_rng(3)
    image = rng.uniform(0, 1, (H, W)).astype(np.float32)
    one = rectify(image, poly_model, GRID, resampling="cubic", tile=4096, approx=0)
    tiled = rectify(image, poly_model, GRID, resampling="cubic", tile=37, approx=0)
    np.testing.assert_array_equal(one, tiled)
    assert one.dtype == np.float32 and one.shape == GRID.shape


def test_direct_mapping_leaves_holes_when_upsampling():
    # The output pixel (1 m) is half the input pixel on the ground: each
    # input pixel lands in one output pixel of the four it covers.
    model = lambda xy: jnp.stack([xy[..., 0] / 2.0, (100.0 - xy[..., 1]) / 2.0], axis=-1)  # noqa: E731
    inverse = lambda cr: jnp.stack([cr[..., 0] * 2.0, 100.0 - cr[..., 1] * 2.0], axis=-1)  # noqa: E731
    grid = Grid.from_bounds((-1.0, 100.0 - 2 * H + 1.0, 2 * W - 1.0, 101.0), 1.0)
    image = np.arange(H * W, dtype=np.float64).reshape(H, W) + 1.0
    direct, holes = rectify(image, model, grid, mapping="direct", inverse=inverse)
    indirect = rectify(image, model, grid, resampling="nearest")
    xy = grid.xy()
    inside = _footprint(xy[..., 0] / 2.0, (100.0 - xy[..., 1]) / 2.0)
    assert not np.isnan(indirect[inside]).any()  # indirect: no holes
    filled = ~np.isnan(direct)
    assert filled.sum() == H * W  # every input pixel lands once
    assert holes == inside.sum() - H * W
    assert holes > 0.7 * inside.sum()
    # Where direct mapping did put a value, it is the nearest input pixel's.
    np.testing.assert_array_equal(direct[filled], indirect[filled])


def test_bad_arguments_raise():
    image = np.zeros((H, W))
    with pytest.raises(ValueError, match="resampling"):
        rectify(image, affine_model, GRID, resampling="cubicspline")
    with pytest.raises(ValueError, match="tile"):
        rectify(image, affine_model, GRID, tile=0)
    with pytest.raises(ValueError, match="grid"):
        rectify(image, affine_model, (1, 2))
    with pytest.raises(ValueError, match="model"):
        rectify(image, "affine", GRID)
    with pytest.raises(ValueError, match="nodata"):
        rectify(image.astype(np.uint8), affine_model, GRID, nodata=np.nan)
    with pytest.raises(ValueError, match="shape"):
        Grid((1, 0, 0, 0, -1, 0), (0, 5))


@pytest.fixture
def src_tif(tmp_path):
    rng = np.random.default_rng(4)
    image = rng.integers(1, 256, (3, H, W), dtype=np.uint8)
    path = tmp_path / "in.tif"
    write_geotiff(path, image, None, None, nodata=0)  # a raw photo: no georeference
    return path, image


@pytest.mark.parametrize("resampling", ["nearest", "cubic"])
def test_rectify_file_equals_memory_and_georeference(tmp_path, src_tif, resampling):
    path, image = src_tif
    out = tmp_path / "out.tif"
    rectify_file(path, out, poly_model, GRID, resampling=resampling, tile=48, approx=0)
    ref = rectify(image, poly_model, GRID, resampling=resampling, nodata=0, approx=0)
    with rasterio.open(out) as ds:
        assert ds.transform == rasterio.Affine(2.0, 0.0, 1000.0, 0.0, -2.0, 5200.0)
        assert ds.crs == rasterio.CRS.from_epsg(32633)
        assert (ds.height, ds.width, ds.count) == (*GRID.shape, 3)
        assert ds.nodata == 0
        np.testing.assert_array_equal(ds.read(), ref)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.tif", "out.tif"]


def test_rectify_file_failure_leaves_no_partial_file(tmp_path, src_tif, monkeypatch):
    files = importlib.import_module("photax.rectification._files")  # where rectify_file looks it up

    path, _ = src_tif
    out = tmp_path / "out.tif"
    out.write_bytes(b"previous result")
    calls = []
    real = files._resample_tile

    def failing(*args):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("disk full (injected)")
        return real(*args)

    monkeypatch.setattr(files, "_resample_tile", failing)
    with pytest.raises(RuntimeError, match="injected"):
        rectify_file(path, out, poly_model, GRID, tile=40)
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.tif", "out.tif"]


def test_rectify_file_refuses_to_overwrite_input(tmp_path, src_tif):
    path, _ = src_tif
    before = path.read_bytes()
    with pytest.raises(ValueError, match="input"):
        rectify_file(path, path, poly_model, GRID)
    assert path.read_bytes() == before


def test_write_read_geotiff_and_dem(tmp_path):
    heights = np.arange(12.0).reshape(3, 4)
    heights[1, 2] = -9999.0
    path = write_geotiff(tmp_path / "dem.tif", heights, (10, 0, 500, 0, -10, 900), "EPSG:32633", nodata=-9999.0)
    arr, profile = read_geotiff(path)
    assert arr.shape == (1, 3, 4) and profile["nodata"] == -9999.0
    assert profile["transform"] == rasterio.Affine(10, 0, 500, 0, -10, 900)
    dem = read_dem(path)
    assert np.isnan(dem.heights[1, 2]) and float(dem.heights[2, 3]) == 11.0
    # Centre of cell [2, 0] is at (505, 875).
    assert float(dem.height(505.0, 875.0)) == 8.0
    with pytest.raises(ValueError, match="input"):
        write_geotiff(path, heights, (10, 0, 500, 0, -10, 900), inputs=[path])
    with pytest.raises(FileNotFoundError):
        read_dem(tmp_path / "missing.tif")


def test_orthorectify_masks_nodata_dem_and_behind_camera():
    camera = photax.FrameCamera.from_pixels(100.0, (64, 48))
    exterior = photax.look_at([0.0, 0.0, 200.0], [0.0, 0.0, 0.0])
    heights = np.full((20, 20), 10.0)
    heights[:, :5] = np.nan
    dem = photax.DEM(heights, (10.0, 0, -100.0, 0, -10.0, 100.0))
    image = np.full((48, 64), 9.0)
    with pytest.warns(photax.PartialDEMWarning, match="the DEM covers"):  # its west quarter has no height
        ortho, grid = photax.orthorectify(image, exterior, camera, dem, resolution=5.0)
    xy = grid.xy()
    assert np.all(np.isnan(ortho[xy[..., 0] < -55.0]))  # DEM nodata (incl. its bilinear rim)
    assert np.all(ortho[(xy[..., 0] > -40.0) & (np.abs(xy[..., 0]) < 50) & (np.abs(xy[..., 1]) < 40)] == 9.0)
    # A camera below the ground looking down: everything is behind it, an all-nodata ortho: refused.
    under = photax.look_at([0.0, 0.0, -50.0], [0.0, 0.0, -100.0])
    with pytest.raises(photax.OutsideValidityError, match="the DEM covers none of the image"):
        photax.orthorectify(image, under, camera, dem, grid)
    with pytest.raises(ValueError, match="image_size"):
        photax.orthorectify(image.T, exterior, camera, dem, grid)


def test_cli_rectify_with_gcps(tmp_path, src_tif):
    from photax.cli import main

    path, image = src_tif
    rng = np.random.default_rng(5)
    x, y = rng.uniform(1000, 1260, 12), rng.uniform(4980, 5200, 12)
    cols, rows = affine_np(x, y)
    gcps = tmp_path / "gcps.csv"
    gcps.write_text(
        "name,E,N,h,col,row\n"
        + "".join(f"p{i},{x[i]:.12f},{y[i]:.12f},0,{cols[i]:.12f},{rows[i]:.12f}\n" for i in range(12))
    )
    out = tmp_path / "rect.tif"
    args = [
        "rectify",
        str(path),
        "--gcps",
        str(gcps),
        "--order",
        "1",
        "--out",
        str(out),
        "--resolution",
        "2",
        "--no-progress",
    ]
    assert main(args) == 0
    with rasterio.open(out) as ds:
        grid = Grid(ds.transform, ds.shape)
        data = ds.read()
    assert grid.bounds[0] <= x.min() and grid.bounds[2] >= x.max() and ds.res == (2.0, 2.0)
    # The order-1 fit of exact affine GCPs is the affine map itself.
    ref = rectify(image, affine_model, grid, nodata=0)
    assert np.abs(data.astype(int) - ref).max() <= 1
    args[args.index("--out") + 1] = str(path)
    assert main(args) == 2  # --out IMAGE: refused


# --- the approximate mapping (approx > 0, the default) --------------------------


def _approx_positions(model, grid, approx, tile, size):
    """Per-pixel positions the approximate mapping resamples at, and its
    reported check error (the file path's internal helper)."""
    from photax.rectification._approx import _tile_positions
    from photax.rectification._tiling import _approx_arg, _layout, tile_windows

    out = np.full((2,) + grid.shape, np.nan)
    tiles = list(tile_windows(grid.shape, tile))
    layout = _layout(*tiles[0][2:])
    transform = jnp.asarray(tuple(grid.transform)[:6])
    worst = 0.0
    for r0, c0, h, w in tiles:
        pos, origin, err, _ = _tile_positions(
            model, transform, jnp.array([r0, c0], dtype=float), layout, _approx_arg(approx), size
        )
        out[:, r0 : r0 + h, c0 : c0 + w] = np.asarray(pos)[:, :h, :w] + np.asarray(origin)[:, None, None]
        worst = max(worst, float(err))
    return out, worst


def _exact_positions(model, grid):
    cr = np.asarray(eqx.filter_jit(lambda m, xy: m(xy))(model, jnp.asarray(grid.xy())))
    return np.moveaxis(cr, -1, 0)


def _cubic_map(xy):  # a strongly curved 3rd-order map: interpolation errors of several pixels at 64 px
    x, y = (xy[..., 0] - 1100.0) / 100.0, (xy[..., 1] - 5100.0) / 100.0
    c = 60.0 + 48.0 * x + 4.0 * y + 3.0 * x * x - 2.0 * x * y + 2.5 * x**3
    r = 45.0 - 36.0 * y + 2.0 * x + 1.5 * y * y - 1.5 * x * y * y
    return jnp.stack([c, r], axis=-1)


@pytest.mark.parametrize("approx", [0.125, 0.01])
def test_approx_positions_within_threshold_on_polynomial(approx):
    # Independent reference: the model evaluated at every output pixel.
    grid = Grid.from_bounds((1000.0, 4980.0, 1260.0, 5200.0), 0.5)
    exact = _exact_positions(_cubic_map, grid)
    approx_pos, err = _approx_positions(_cubic_map, grid, approx, 128, (H, W))
    dev = np.abs(approx_pos - exact).max()
    assert dev <= approx and err <= approx
    assert err > 0.5 * dev  # the reported check error is the actual worst case, not a loose bound
    # The threshold is honoured by interpolating where possible: at 0.125 px
    # most of this map is interpolated, so the positions are not all exact.
    if approx == 0.125:
        assert np.mean(np.abs(approx_pos - exact) > 1e-3) > 0.5


def test_approx_positions_within_threshold_on_relief_ortho():
    # A wide-angle camera over 600 m hills: the DEM's bilinear cells put kinks
    # into the mapping between lattice nodes; the check positions (cell
    # centres and edge midpoints) catch them (centres alone gave 0.22 px).
    s = photax.relief_scene(600.0, image_size=(400, 300), focal_px=400.0)
    model = photax.rectification.OrthoModel(s.exterior, s.camera, s.dem)
    grid = photax.rectification.ortho_grid(s.exterior, s.camera, s.dem)
    exact = _exact_positions(model, grid)
    for approx in (0.125, 0.02):
        approx_pos, err = _approx_positions(model, grid, approx, 128, (300, 400))
        assert np.array_equal(np.isfinite(approx_pos), np.isfinite(exact))
        assert np.nanmax(np.abs(approx_pos - exact)) <= approx
        assert err <= approx


def test_approx_image_agrees_with_exact():
    rng = np.random.default_rng(6)
    image = ndimage.gaussian_filter(rng.uniform(0, 255, (H, W)), 2.0)
    grid = Grid.from_bounds((1000.0, 4980.0, 1260.0, 5200.0), 0.5)
    info = {}
    ours = rectify(image, _cubic_map, grid, resampling="bilinear", info=info)
    exact = rectify(image, _cubic_map, grid, resampling="bilinear", approx=0)
    assert info["approx"] == 0.125 and 0 < info["approx_error"] <= 0.125 and info["exact_fraction"] < 0.5
    # Bilinear grey values move by at most |gradient| x position error.
    gy, gx = np.gradient(image)
    bound = (np.abs(gx).max() + np.abs(gy).max()) * info["approx_error"]
    both = np.isfinite(ours) & np.isfinite(exact)
    assert both.sum() > 0.3 * both.size
    assert np.abs(ours - exact)[both].max() <= bound + 1e-9
    # Footprints agree except where the footprint edge passes within the error.
    assert np.mean(np.isfinite(ours) != np.isfinite(exact)) < 1e-3


def test_approx_falls_back_to_exact_where_the_check_fails():
    # A threshold no interpolation can meet: every chunk is mapped exactly,
    # and the image equals the exact one (up to float32 positions).
    rng = np.random.default_rng(7)
    image = ndimage.gaussian_filter(rng.uniform(0, 255, (H, W)), 2.0)
    info = {}
    ours = rectify(image, _cubic_map, GRID, resampling="cubic", approx=1e-9, info=info)
    exact = rectify(image, _cubic_map, GRID, resampling="cubic", approx=0)
    assert info["exact_fraction"] == 1.0 and info["approx_error"] == 0.0
    np.testing.assert_allclose(ours, exact, rtol=0, atol=1e-2)
    with pytest.raises(ValueError, match="approx"):
        rectify(image, _cubic_map, GRID, approx=-1.0)


def test_approx_file_equals_memory(tmp_path, src_tif):
    path, image = src_tif
    out = tmp_path / "out.tif"
    info = {}
    rectify_file(path, out, _cubic_map, GRID, resampling="bilinear", tile=64, info=info)
    ref = rectify(image, _cubic_map, GRID, resampling="bilinear", nodata=0, tile=64)
    with rasterio.open(out) as ds:
        data = ds.read()
    # Same lattice and positions; uint8 rounding of float32 sums may differ by one.
    assert np.abs(data.astype(int) - ref).max() <= 1 and np.mean(data != ref) < 1e-3
    assert 0 < info["approx_error"] <= 0.125


def test_function_and_module_have_different_names():
    """``photax.rectify`` is the function, ``photax.rectification`` its
    package: importing the package does not replace the function, and every
    public name is the same object through both."""
    import types

    module = importlib.import_module("photax.rectification")
    assert isinstance(module, types.ModuleType) and photax.rectification is module
    for name in ("Grid", "rectify", "orthorectify", "rectify_file", "orthorectify_file"):
        assert getattr(photax, name) is getattr(module, name)
    assert callable(photax.rectify) and not isinstance(photax.rectify, types.ModuleType)


def test_kernel_tiles_waste_little_and_a_block_shares_one_shape():
    # Edge tiles run at the bucketed kernel shape and are cropped: the pixels computed per pixel
    # kept must stay small for awkward sizes (a 4097-px grid ran its 832-px tiles at 896: 20 %
    # more work), while the NGI block's frames (tiles 704 x 784, 704 x 800, 688 x 784) must still
    # share one compiled kernel shape.
    from photax.rectification._tiling import _layout, tile_windows

    for n in (1000, 4097, 5000, 10001):
        tiles = list(tile_windows((n, n), 1024))
        side = _layout(*tiles[0][2:])[0][0]
        computed = side * len({t[0] for t in tiles})  # kernel rows per column of tiles
        assert n <= computed <= 1.07 * n, (n, side, computed)
    assert len({_layout(*shape) for shape in [(704, 784), (704, 800), (688, 784)]}) == 1
