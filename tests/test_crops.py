"""Satellite images as users receive them (issue 35, items 2 and 3) on the shared QuickBird scene: a crop
cut with its RPC offsets shifted as vendors and gdal_translate do (RPCCamera.crop), orthorectified onto a
DEM that covers half of it (footprint, default grid, nodata, PartialDEMWarning), refined from the GCPs
inside it (refine_rpc, adjust_rpc_block), and two orthos over a DEM with 15 % holes co-registered."""

import shutil
import subprocess
import warnings

import numpy as np
import pytest
from conftest import shared_file

from photax.dem import DEM
from photax.errors import PartialDEMWarning
from photax.grid import Grid, dem_coverage
from photax.rectification import OrthoModel, ortho_grid, orthorectify
from photax.rpc import RPCCamera, check_gcps, read_rpc, refine_rpc

rasterio = pytest.importorskip("rasterio")
pyproj = pytest.importorskip("pyproj")

UTM = "EPSG:32735"
WINDOW = (200, 300, 512, 768)  # col_off, row_off, width, height of the crop in the 850 x 1450 scene


@pytest.fixture(scope="module")
def qb():
    from photax.io.raster import read_dem

    tif = shared_file("orthority/rpc/qb2_basic1b.tif")
    dem_path = shared_file("orthority/ngi/dem.tif")
    with rasterio.open(tif) as src:
        image = src.read(1).astype(float)
    return read_rpc(tif), image, read_dem(str(dem_path)), tif, dem_path


def _half_dem(dem: DEM, camera: RPCCamera) -> DEM:
    """The DEM blanked (NaN) south of the ground under the image's centre: it covers half the image."""
    w, h = camera.image_size
    lon, lat, _ = camera.to_ground_dem(np.array([w / 2 - 0.5, h / 2 - 0.5]), dem)
    _, y = pyproj.Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True).transform(lon, lat)
    heights, t = np.array(dem.heights), np.asarray(dem.transform)
    ys = t[5] + t[4] * (np.arange(heights.shape[0]) + 0.5)
    heights[ys < y] = np.nan
    return DEM(heights, t, dem.crs)


def _write_dem(path, dem: DEM, like):
    with rasterio.open(like) as src:
        crs = src.crs
    h = np.asarray(dem.heights)
    profile = dict(driver="GTiff", width=h.shape[1], height=h.shape[0], count=1, dtype="float64", crs=crs,
                   transform=rasterio.Affine(*np.asarray(dem.transform)), nodata=np.nan)  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(h, 1)
    return path


# --- RPCCamera.crop -------------------------------------------------------------------------------


def test_crop_offsets_equal_gdal_translate(qb, tmp_path):
    """``crop`` shifts SAMP_OFF/LINE_OFF by the window's origin exactly as ``gdal_translate -srcwin`` writes
    a crop's RPC (GDAL the reference where its command is installed), keeps the rest, and images every
    ground point where the scene does, less the origin, a refinement's correction included."""
    rpc = qb[0]
    c0, r0, w, h = WINDOW
    crop = rpc.crop(c0, r0, w, h)
    assert crop.image_size == (w, h)
    if shutil.which("gdal_translate"):
        out = tmp_path / "crop.tif"
        subprocess.run(["gdal_translate", "-q", "-srcwin", *map(str, WINDOW), str(qb[3]), str(out)], check=True)
        gdal = read_rpc(out)
        assert gdal.image_size == (w, h)
        np.testing.assert_allclose(np.asarray(crop.offsets), np.asarray(gdal.offsets), rtol=0, atol=1e-9)
        np.testing.assert_array_equal(np.asarray(crop.scales), np.asarray(gdal.scales))
        np.testing.assert_array_equal(np.asarray(crop.coefficients), np.asarray(gdal.coefficients))
    rng = np.random.default_rng(0)
    o, s = np.asarray(rpc.offsets), np.asarray(rpc.scales)
    ground = o[:3] + rng.uniform(-1, 1, (50, 3)) * s[:3]
    np.testing.assert_allclose(np.asarray(crop(ground)), np.asarray(rpc(ground)) - [c0, r0], rtol=0, atol=1e-9)
    refined = RPCCamera(
        rpc.coefficients, rpc.offsets, rpc.scales, [[1.5, 2e-4, -3e-4], [-0.7, 1e-4, 5e-4]], (850, 1450)
    )
    np.testing.assert_allclose(
        np.asarray(refined.crop(c0, r0, w, h)(ground)), np.asarray(refined(ground)) - [c0, r0], rtol=0, atol=1e-9
    )
    with pytest.raises(ValueError, match="not inside the 850 x 1450 pixel image"):
        rpc.crop(700, 0, 512, 512)
    with pytest.raises(ValueError, match="positive integers"):
        rpc.crop(0, 0, 0, 10)


# --- a crop on a DEM covering half of it ----------------------------------------------------------


def test_crop_ortho_on_half_dem_equals_scene_ortho(qb):
    """The crop on a DEM covering its northern half: the default grid (the footprint crashed: 'assignment
    destination is read-only'), a PartialDEMWarning of ~50 %, nodata where the DEM has none, the covered
    half equal to the whole scene's ortho on the whole DEM at the same cells."""
    rpc, image, dem, _, dem_path = qb
    c0, r0, w, h = WINDOW
    crop = rpc.crop(c0, r0, w, h)
    half = _half_dem(dem, crop)
    share = dem_coverage(None, crop, half)
    print(f"covered share of the crop: {share:.3f} (whole DEM: {dem_coverage(None, crop, dem):.3f})")
    assert abs(share - 0.5) < 0.03 and dem_coverage(None, crop, dem) > 0.99
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        grid = ortho_grid(None, crop, half, 25.0, crs=UTM)
        ours, _ = orthorectify(image[r0 : r0 + h, c0 : c0 + w], None, crop, half, grid, approx=None)
        scene, _ = orthorectify(image, None, rpc, dem, grid, approx=None)
    partial = [x.message for x in caught if isinstance(x.message, PartialDEMWarning)]
    assert len(partial) == 1 and abs(partial[0].coverage - share) < 1e-12 and f"{share:.1%}" in str(partial[0])
    xy = grid.xy().reshape(-1, 2)
    pos = np.asarray(OrthoModel(None, crop, half, grid.crs)(xy))
    on = np.all(np.isfinite(pos), axis=1)
    assert 0.3 < on.mean() < 0.7
    assert np.isnan(ours.reshape(-1)[~on]).all()  # off the DEM: nodata
    inner = on & np.all((pos > 1) & (pos < [w - 2, h - 2]), axis=1)  # the crop's edge pixels are replicated
    diff = np.abs(ours.reshape(-1)[inner] - scene.reshape(-1)[inner])
    print(f"crop on the half DEM - scene on the whole DEM: max {diff.max():.2e} grey levels on {inner.sum()} cells")
    assert inner.sum() > 1000 and diff.max() < 1e-6


def test_crop_positions_on_half_dem_equal_gdal_rpc_dem(qb, tmp_path):
    """The crop's image positions of the grid's cells (OrthoModel: the crop's RPC, the half DEM) against
    GDAL's RPC transformer with RPC_DEM on the same half DEM and the crop's RPC: the same cells off the
    DEM, the others within 1e-6 px."""
    from rasterio.rpc import RPC
    from rasterio.transform import RPCTransformer

    rpc, image, dem, _, dem_path = qb
    c0, r0, w, h = WINDOW
    crop = rpc.crop(c0, r0, w, h)
    half = _half_dem(dem, crop)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        grid = ortho_grid(None, crop, half, 25.0, crs=UTM)
    xy = grid.xy().reshape(-1, 2)
    pos = np.asarray(OrthoModel(None, crop, half, grid.crs)(xy))
    on = np.all(np.isfinite(pos), axis=1)
    dem_file = _write_dem(tmp_path / "half.tif", half, dem_path)
    lon, lat = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True).transform(xy[:, 0], xy[:, 1])
    opts = {"RPC_DEM": str(dem_file), "RPC_DEMINTERPOLATION": "bilinear", "RPC_DEM_APPLY_VDATUM_SHIFT": False}
    with RPCTransformer(RPC(**crop.to_dict()), **opts) as t:
        rows, cols = t.rowcol(lon, lat, op=lambda v: v)
    gdal = np.column_stack([cols, rows]) - 0.5  # GDAL counts from the pixel's corner
    assert np.array_equal(np.all(np.isfinite(gdal), axis=1), on)  # the same cells off the DEM
    inside = on & np.all((pos > 0) & (pos < [w - 1, h - 1]), axis=1)
    err = np.abs(pos[inside] - gdal[inside]).max()
    print(f"photax - GDAL RPC_DEM positions in the crop, half DEM: max {err:.2e} px over {inside.sum()} points")
    assert inside.sum() > 1000 and err < 1e-6


def test_cli_partial_dem_warns_and_writes_none_covered_fails(qb, tmp_path, capsys):
    """``photax ortho`` of the crop (its RPC in the GeoTIFF tags) on the half DEM: the warning printed,
    exit 0, the ortho written; on a DEM with no height under the image: a clear error, exit 2, nothing written."""
    from rasterio.rpc import RPC

    from photax.cli import main

    rpc, image, dem, tif, dem_path = qb
    c0, r0, w, h = WINDOW
    crop = rpc.crop(c0, r0, w, h)
    crop_tif = tmp_path / "crop.tif"
    with rasterio.open(crop_tif, "w", driver="GTiff", width=w, height=h, count=1, dtype="uint8",
                       rpcs=RPC(**crop.to_dict())) as dst:  # fmt: skip
        dst.write(image[r0 : r0 + h, c0 : c0 + w].astype(np.uint8), 1)
    half = _write_dem(tmp_path / "half.tif", _half_dem(dem, crop), dem_path)
    none = np.full(np.asarray(dem.heights).shape, np.nan)
    none[:3, :3] = np.asarray(dem.heights)[:3, :3]  # a corner far from the image
    none = _write_dem(tmp_path / "none.tif", DEM(none, np.asarray(dem.transform), dem.crs), dem_path)
    base = [str(crop_tif), "--camera", "rpc", "--crs", UTM, "--resolution", "25", "--no-progress"]
    assert main(["ortho", *base, "--dem", str(half), "-o", str(tmp_path / "o.tif")]) == 0
    err = capsys.readouterr().err
    assert "warning: the DEM covers 5" in err or "warning: the DEM covers 4" in err, err
    with rasterio.open(tmp_path / "o.tif") as src:
        got = src.read(1)
    assert 0.2 < (got > 0).mean() < 0.8
    assert main(["ortho", *base, "--dem", str(none), "-o", str(tmp_path / "n.tif")]) == 2
    err = capsys.readouterr().err
    assert "error" in err and "no height" in err, err
    assert not (tmp_path / "n.tif").exists()


# --- refine_rpc of a crop ---------------------------------------------------------------------------


def _far_offsets(rpc: RPCCamera, k: float = 38.0, shrink: float = 0.05) -> RPCCamera:
    """The same projection written with its sample offset ``k`` (new, ``shrink`` times smaller) scales away
    from the image, as a vendor's crop RPC keeps the full scene's offsets with the crop's scales:
    ``col = off' + s' (num' / den)`` with ``s' = shrink s``, ``off' = off + k s'`` and
    ``num' = (num - k shrink den) / shrink`` -- exactly the RPC's columns."""
    coef = np.array(rpc.coefficients)
    off, scale = np.array(rpc.offsets), np.array(rpc.scales)
    s2 = shrink * scale[3]
    coef[2] = (coef[2] - k * shrink * coef[3]) / shrink
    off[3], scale[3] = off[3] + k * s2, s2
    return RPCCamera(coef, off, scale, rpc.correction, rpc.image_size)


def test_refine_crop_from_gcps_inside_recovers_the_shift(qb):
    """GCPs measured in the crop only (DEM points imaged by the crop's RPC shifted by a known correction):
    refine_rpc recovers the shift, the refined RPC is still the crop's (its offsets, its size) and equals
    the crop of the scene refined on the same GCPs; the same RPC written with its offsets 38 scales from
    the crop (as the issue's Pleiades crop) is accepted and refined alike (its GCPs were refused: 'outside
    the RPC's image'); adjust_rpc_block takes the crop's GCPs too."""
    from photax.rpc_block import adjust_rpc_block

    rpc, _, dem, _, _ = qb
    c0, r0, w, h = WINDOW
    crop = rpc.crop(c0, r0, w, h)
    shift = np.array([2.3, -1.7])
    truth = RPCCamera(
        crop.coefficients, crop.offsets, crop.scales, [[shift[0], 0, 0], [shift[1], 0, 0]], crop.image_size
    )
    u, v = np.meshgrid(np.linspace(20, w - 20, 5), np.linspace(20, h - 20, 7))
    pixel = np.column_stack([u.ravel(), v.ravel()])
    ground = truth.to_ground_dem(pixel, dem)
    assert np.isfinite(ground).all()
    np.testing.assert_allclose(np.asarray(truth(ground)), pixel, atol=1e-6)  # the GCPs are the truth's
    res = refine_rpc(crop, ground, pixel, "shift")
    print(f"crop refinement: correction {res.correction[:, 0]} (truth {shift}), raw RMSE {res.raw_rmse:.3f} px")
    np.testing.assert_allclose(res.correction[:, 0], shift, atol=1e-6)
    assert res.rmse < 1e-5 and res.camera.image_size == (w, h)
    np.testing.assert_array_equal(np.asarray(res.camera.offsets), np.asarray(crop.offsets))
    scene = refine_rpc(rpc, ground, pixel + [c0, r0], "shift").camera.crop(c0, r0, w, h)
    np.testing.assert_allclose(np.asarray(scene(ground)), np.asarray(res.camera(ground)), atol=1e-9)
    far = _far_offsets(crop)
    np.testing.assert_allclose(np.asarray(far(ground)), np.asarray(crop(ground)), rtol=0, atol=1e-8)
    assert np.abs(pixel[:, 0] - float(far.offsets[3])).min() > 30 * float(far.scales[3])  # 1.5 were refused
    res_far = refine_rpc(far, ground, pixel, "shift")
    np.testing.assert_allclose(res_far.correction, res.correction, atol=1e-6)
    # the block: the crop (offsets far away) and the scene, each with the GCPs at its own pixels, no ties
    k = len(pixel)
    gobs = np.concatenate([np.column_stack([np.arange(k), np.zeros(k), pixel]),
                           np.column_stack([np.arange(k), np.ones(k), pixel + [c0, r0]])])  # fmt: skip
    block = adjust_rpc_block([far, rpc], np.zeros((0, 4)), (ground, gobs), model="shift")
    np.testing.assert_allclose(np.asarray(block.cameras[0](ground)), pixel, atol=1e-6)
    np.testing.assert_allclose(np.asarray(block.cameras[1](ground)), pixel + [c0, r0], atol=1e-6)
    # bad GCPs: outside the RPC's validity volume, or far outside the image given
    wrong = ground.copy()
    wrong[3, 0] += 2 * float(rpc.scales[0])
    with pytest.raises(ValueError, match="1 GCP.s. outside the RPC's validity volume.*GCP 3 at"):
        refine_rpc(far, wrong, pixel, "shift")
    blunder = pixel.copy()
    blunder[5] += [3 * w, 0]
    with pytest.raises(ValueError, match="outside the 512 x 768 pixel image by more than its size.*GCP 5"):
        refine_rpc(far, ground, blunder, "shift")
    with pytest.raises(ValueError, match="gcps in image 0"):
        bad = np.column_stack([np.arange(k), np.zeros(k), blunder])
        adjust_rpc_block([far], np.zeros((0, 4)), (ground, bad), model="shift")
    near = pixel.copy()
    near[0] = [-30.0, 10.0]
    with pytest.warns(UserWarning, match="1 GCP.s. outside the 512 x 768 pixel image, inside"):
        check_gcps(far, ground, near)


# --- co-registration over a DEM with holes ------------------------------------------------------------


def test_coregister_orthos_over_a_dem_with_holes(qb):
    """Two orthos of the scene over a DEM with 15 % of holes (blobs of a few cells, as a stereo DSM's),
    the second on the grid moved by (0.5, -0.3) px: masked correlation measures the shift to < 0.1 px
    (filled with each window's mean and cut at 5 % no data it found 'only 0 reliable windows')."""
    from rasterio import Affine
    from scipy.ndimage import gaussian_filter

    import photax as ptx

    rpc, image, dem, _, _ = qb
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = ortho_grid(None, rpc, dem, 8.0, crs=UTM)
    n, m = 256, 16
    grid = Grid(
        full.transform * Affine.translation(full.shape[1] // 2 - n // 2, full.shape[0] // 2 - n // 2), (n, n), UTM
    )
    # the DEM on an 8 m grid around the ortho's (bilinear from the shared one), 15 % of it holes
    around = Grid(grid.transform * Affine.translation(-m, -m), (n + 2 * m, n + 2 * m), UTM)
    xy = around.xy().reshape(-1, 2)
    x, y = pyproj.Transformer.from_crs(UTM, dem.crs, always_xy=True).transform(xy[:, 0], xy[:, 1])
    heights = np.array(dem.height(x, y)).reshape(around.shape)
    field = gaussian_filter(np.random.default_rng(5).normal(size=heights.shape), 1.0)
    heights[field < np.quantile(field, 0.15)] = np.nan
    holey = DEM(heights, tuple(around.transform)[:6], UTM)
    d = np.array([0.5, -0.3])
    moved = Grid(grid.transform * Affine.translation(*d), grid.shape, UTM)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a, _ = orthorectify(image, None, rpc, holey, grid)
        b, _ = orthorectify(image, None, rpc, holey, moved)
    print(f"no data: DEM {np.isnan(heights).mean():.1%}, orthos {np.isnan(a).mean():.1%} and {np.isnan(b).mean():.1%}")
    assert 0.1 < np.isnan(a).mean() and 0.2 < np.isnan(b).mean()
    reg = ptx.coregister(a, b, window=64)  # b(p + s) = a(p): s = -d
    err = np.abs(reg.shift_at(reg.centres) + d).max()
    print(f"coregister: {reg.counts}, model shift error {err:.3f} px, rmse {reg.rmse:.3f} px")
    assert reg.counts["ok"] >= 0.8 * len(reg.centres) and err < 0.1
    with pytest.raises(ValueError, match="only 0 reliable windows"):
        ptx.coregister(a, b, window=64, max_nodata=0.05)  # the old rule: every window has holes


def test_frame_dem_coverage_and_warning():
    """A frame over relief (photax.relief_scene), its DEM blanked west of the image centre's ground: the
    covered share against an independent count (the lattice's rays cut with the whole DEM by
    image_to_ground, kept where the blanked DEM has a height there), the PartialDEMWarning of
    orthorectify, nodata in the blanked part; a DEM with no height under the image is refused."""
    import photax as ptx
    from photax.collinearity import image_to_ground

    scene = ptx.relief_scene(200.0, seed=1, image_size=(400, 300), focal_px=400.0)
    dem = scene.dem
    w, h = scene.camera.image_size
    full = dem_coverage(scene.exterior, scene.camera, dem)
    t = np.asarray(dem.transform)
    mid = image_to_ground(scene.camera.pixel_to_image(np.array([[w / 2 - 0.5, h / 2 - 0.5]])),
                          scene.exterior, scene.camera, dem=dem)[0]  # fmt: skip
    heights = np.array(dem.heights)
    heights[:, t[2] + t[0] * (np.arange(heights.shape[1]) + 0.5) < float(mid[0])] = np.nan
    half = DEM(heights, t, dem.crs)
    share = dem_coverage(scene.exterior, scene.camera, half, samples=24)
    u = (np.arange(24) + 0.5) / 24
    px = np.stack(np.meshgrid(u * w - 0.5, u * h - 0.5), -1).reshape(-1, 2)
    g = np.asarray(image_to_ground(scene.camera.pixel_to_image(px), scene.exterior, scene.camera, dem=dem))
    expected = np.mean(np.isfinite(np.asarray(half.height(g[:, 0], g[:, 1]))))
    print(f"frame: covered share {share:.4f}, independent count {expected:.4f}, whole DEM {full:.3f}")
    assert full == 1.0 and abs(share - expected) <= 2 / 24**2 and 0.3 < share < 0.7
    grid = Grid(scene.ortho_transform, scene.ortho.shape)
    with pytest.warns(PartialDEMWarning, match="the DEM covers"):
        ortho, _ = orthorectify(scene.image, scene.exterior, scene.camera, half, grid)
    xy = grid.xy().reshape(-1, 2)
    off = ~np.isfinite(np.asarray(half.height(xy[:, 0], xy[:, 1])))
    assert off.mean() > 0.2 and np.isnan(ortho.reshape(-1)[off]).all()
    none = DEM(np.full(heights.shape, np.nan), t, dem.crs)
    with pytest.raises(ValueError, match="the DEM covers none of the image"):
        orthorectify(scene.image, scene.exterior, scene.camera, none, grid)
