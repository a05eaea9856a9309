"""Point clouds -> surface models (issue 36 item 3): rasterisation against a brute-force per-cell
reference, hole filling on a plane, fusion, the COG and PLY files read back, and the frame-pair
triangulation of exact disparities against the DEM they were made from."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

import photax
from photax.stereo import PointCloud, fill_holes, fuse_dsms, rasterize_points, write_cog

CRS = "EPSG:32633"
X0, Y0 = 500_000.0, 4_000_000.0


def cloud(n=4000, seed=0, slope=(0.1, -0.05)):
    rng = np.random.default_rng(seed)
    x, y = X0 + rng.uniform(0, 40, n), Y0 + rng.uniform(0, 30, n)
    z = 100 + slope[0] * (x - X0) + slope[1] * (y - Y0) + rng.normal(0, 0.2, n)
    return PointCloud(np.column_stack([x, y, z]), np.zeros(n), rng.uniform(0.1, 0.5, n), crs=CRS)


@pytest.mark.parametrize("reducer", ["median", "max"])
def test_rasterize_equals_brute_force(reducer):
    pts = cloud()
    grid = photax.Grid.from_bounds((X0, Y0, X0 + 40, Y0 + 30), 2.0, CRS)
    dsm = rasterize_points(pts, grid, reducer=reducer, fill=0)
    want = np.full(grid.shape, np.nan)
    sig = np.full(grid.shape, np.nan)
    col = ((pts.x - X0) // 2).astype(int)
    row = ((Y0 + 30 - pts.y) // 2).astype(int)
    for r in range(grid.height):
        for c in range(grid.width):
            k = (row == r) & (col == c)
            if k.any():
                want[r, c] = np.median(pts.z[k]) if reducer == "median" else pts.z[k].max()
                sig[r, c] = np.median(pts.sigma_z[k])
                assert dsm.count[r, c] == k.sum()
    np.testing.assert_allclose(dsm.heights, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dsm.sigma, sig, rtol=0, atol=1e-12)
    assert dsm.completeness == 1.0


def test_holes_small_filled_large_kept():
    grid = photax.Grid.from_bounds((X0, Y0, X0 + 60, Y0 + 60), 1.0, CRS)
    xy = grid.xy()
    plane = 50 + 0.3 * (xy[..., 0] - X0) - 0.2 * (xy[..., 1] - Y0)
    h = plane.copy()
    h[10, 10] = np.nan  # one cell: all 8 neighbours valid, a plane is filled exactly
    h[20:23, 30:33] = np.nan  # 3 x 3: filled, to within a slope times a cell
    h[40:45, 10:15] = np.nan  # 5 x 5: left
    h[0:2, 50:52] = np.nan  # at the edge: left
    got, mask = fill_holes(h, 3)
    assert got[10, 10] == pytest.approx(plane[10, 10], abs=1e-9)
    assert np.all(np.abs(got[20:23, 30:33] - plane[20:23, 30:33]) < 0.4)
    assert np.isnan(got[40:45, 10:15]).all() and np.isnan(got[0:2, 50:52]).all()
    assert mask.sum() == 1 + 9
    # through rasterize: cell centres as points, the same holes
    keep = np.isfinite(h).ravel()
    pts = PointCloud(np.column_stack([xy.reshape(-1, 2), plane.ravel()])[keep], np.zeros(keep.sum()),
                     np.ones(keep.sum()), crs=CRS)  # fmt: skip
    dsm = rasterize_points(pts, grid)
    assert dsm.filled.sum() == 10 and np.isnan(dsm.heights).sum() == 25 + 4
    with pytest.raises(ValueError, match="reducer"):
        rasterize_points(pts, grid, reducer="mean")
    with pytest.raises(ValueError, match="CRS"):
        rasterize_points(PointCloud(pts.xyz, pts.residual, pts.sigma_z, crs="EPSG:4326"), grid)


def test_fuse_median_and_cog(tmp_path):
    grid = photax.Grid.from_bounds((X0, Y0, X0 + 400, Y0 + 300), 1.0, CRS)
    rng = np.random.default_rng(1)
    truth = 20 + rng.normal(0, 1, grid.shape)
    models = []
    for k in range(3):
        h = truth + (k - 1) * 0.5  # -0.5, 0, +0.5: the median is the truth
        h[rng.random(grid.shape) < 0.1] = np.nan
        if k == 2:
            h[50:60, 50:60] = 1000.0  # a blunder in one pair
        models.append(photax.stereo.SurfaceModel(h, grid, np.isfinite(h).astype(int), np.full(grid.shape, 0.1),
                                                 np.zeros(grid.shape, bool)))  # fmt: skip
    fused = fuse_dsms(models)
    all3 = np.all([np.isfinite(m.heights) for m in models], axis=0)
    np.testing.assert_allclose(fused.heights[all3], truth[all3], atol=1e-12)
    assert np.all(fused.heights[50:60, 50:60][all3[50:60, 50:60]] < 100)
    assert (fused.count == np.sum([np.isfinite(m.heights) for m in models], axis=0)).all()
    assert np.isnan(fuse_dsms(models, min_count=3).heights[~all3]).all()
    # the Cloud-Optimized GeoTIFF: heights, CRS, nodata, tiles and overviews
    out = fused.write(tmp_path / "dsm.tif")
    with rasterio.open(out) as src:
        assert src.crs == rasterio.crs.CRS.from_user_input(CRS)
        assert np.isnan(src.nodata) and src.dtypes[0] == "float32"
        assert src.block_shapes[0][0] < grid.height  # tiled
        assert src.overviews(1)  # with overviews
        if "COG" in rasterio.Env().drivers():
            assert src.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        np.testing.assert_array_equal(src.read(1), fused.heights.astype(np.float32))
        assert src.transform == grid.transform
    with pytest.raises(ValueError, match="blank"):
        write_cog(tmp_path / "blank.tif", np.full(grid.shape, np.nan), grid)
    assert not (tmp_path / "blank.tif").exists()
    with pytest.raises(ValueError, match="another grid"):
        fuse_dsms([models[0], rasterize_points(cloud(), photax.Grid.from_bounds((X0, Y0, X0 + 40, Y0 + 30), 2.0, CRS))])


def test_ply_layout(tmp_path):
    pts = cloud(50)
    pts = PointCloud(pts.xyz, np.arange(50) / 10, pts.sigma_z, np.tile(np.arange(50, dtype=np.uint8)[:, None], 3), CRS)
    raw = pts.write_ply(tmp_path / "p.ply").read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"] and "element vertex 50" in lines
    assert "comment crs EPSG:32633" in lines
    rec = np.frombuffer(body, dtype=[("xyz", "<f8", 3), ("rgb", "u1", 3), ("res", "<f4"), ("sz", "<f4")])
    np.testing.assert_array_equal(rec["xyz"], pts.xyz)
    np.testing.assert_array_equal(rec["rgb"][:, 0], np.arange(50))
    np.testing.assert_allclose(rec["res"], pts.residual, rtol=1e-6)


def test_frame_pair_disparities_to_dem():
    """Exact disparities of a frame epipolar pair (monoplotted on a DEM, projected right) -> the DEM."""
    from photax.sensor import FrameSensor
    from photax.stereo import disparity_to_points

    cam = photax.FrameCamera.from_pixels(300.0, (200, 160))
    e = photax.ExteriorOrientation
    left = e([X0 - 30, Y0, 320.0], np.radians([0.5, -0.3, 1.0]))
    right = e([X0 + 30, Y0 + 2, 321.0], np.radians([-0.4, 0.6, -0.5]))
    n, cell = 300, 2.0
    c = -300 + cell * (np.arange(n) + 0.5)
    h = 20 + 15 * np.exp(-((c[None, :] - 40) ** 2 + (c[:, None] + 30) ** 2) / (2 * 90.0**2)) + 0.02 * c[None, :]
    dem = photax.DEM(h, (cell, 0.0, X0 - 300, 0.0, -cell, Y0 + 300))
    img = np.zeros((160, 200))
    pair = photax.epipolar_pair(img, img, cam, left, right)
    rows, cols = pair.left.shape
    rr, cc = np.mgrid[0:rows:4, 0:cols:4]
    el = np.column_stack([cc.ravel(), rr.ravel()]).astype(float)
    pl = pair.from_epipolar("left", el)
    inside = np.all((pl >= 0) & (pl <= [199, 159]), axis=1)
    g = np.asarray(photax.image_to_ground(cam.pixel_to_image(pl[inside]), left, cam, dem=dem))
    pr = np.asarray(FrameSensor(right, cam)(g))
    er = pair.to_epipolar("right", pr)
    disparity = np.full((rows, cols), np.nan)
    disparity[rr.ravel()[inside], cc.ravel()[inside]] = el[inside, 0] - er[:, 0]
    pts = disparity_to_points(pair, disparity, crs=CRS, colour=False)
    ok = np.isfinite(g).all(axis=1).sum()
    assert len(pts) >= 0.95 * ok
    dz = pts.z - np.asarray(dem.height(pts.x, pts.y))
    assert np.nanmax(np.abs(dz)) < 1e-3  # the exact disparity gives the exact point
    assert np.max(pts.residual) < 1e-3
    # sigma_z: parallax precision sigma_Z ~ Z^2 / (f B) sigma_p at near-nadir
    expect = (320 - 25) ** 2 / (300.0 * abs(pair.baseline)) * 0.3
    assert np.median(pts.sigma_z) == pytest.approx(expect, rel=0.1)


def test_rendered_frame_pair_to_a_dsm_of_its_terrain():
    """Two frames rendered over a hilly DEM (photax.scene, 40 % of the width as base) -> pair_points ->
    rasterize_points, against the DEM they were rendered from: the median height error is a small part of
    one disparity pixel's height, and cells off by more than one disparity pixel (a gross mismatch) are
    at most 1 %.  At the overlap's edge the true match of a left pixel is outside the right image;
    matching every candidate there (``whole_range=False``) put wrong heights in the DSM."""
    import equinox as eqx

    from photax.scene import render_image
    from photax.sensor import FrameSensor
    from photax.stereo import pair_points

    s = photax.relief_scene(250.0, seed=3, image_size=(480, 360), focal_px=525.0, flying_height=2500.0,
                            tilt_deg=0.0, n_gcp=6, n_check=4)  # fmt: skip
    base = 0.4 * 480 * s.gsd
    ext = eqx.tree_at(lambda e: e.position, s.exterior, s.exterior.position + np.array([base, 0.0, 0.0]))
    right = render_image(s.camera, ext, s.dem, origin=(X0, Y0))
    per_px = 2500.0 / (base / s.gsd)  # height of one disparity pixel at the datum, m
    bad = {}
    for whole in (True, False):
        # the pair as two sensors once, as camera and exteriors once (photax.epipolar_pair takes both)
        views = (
            (FrameSensor(s.exterior, s.camera), FrameSensor(ext, s.camera)) if whole else (s.camera, s.exterior, ext)
        )
        pts, info = pair_points(s.image, right, *views, heights=(0.0, 250.0), crs=CRS, matcher={"whole_range": whole})
        grid = photax.Grid.from_bounds((X0 - 700, Y0 - 600, X0 + 700, Y0 + 600), 2 * s.gsd, CRS)
        dsm = rasterize_points(pts, grid)
        xy = grid.xy()
        err = np.abs(dsm.heights - np.asarray(s.dem.height(xy[..., 0], xy[..., 1])))
        bad[whole] = float(np.mean(err[np.isfinite(err)] > per_px))
        if whole:
            median = float(np.nanmedian(err))
            assert info["valid"] > 0.4 and np.isfinite(err).sum() > 0.3 * err.size
    print(f"median |dz| {median:.2f} m ({median / per_px:.3f} px); gross: {bad[True]:.2%} (whole range), "
          f"{bad[False]:.2%} (every pixel matched)")  # fmt: skip
    assert median < 0.25 * per_px
    assert bad[True] <= 0.01 and bad[True] < bad[False]
