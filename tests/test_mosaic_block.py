"""photax mosaic --block: every image of a rendered block orthorectified straight into one mosaic.

A 1 x 3 strip (60 % overlap) rendered over a sloping plane (photax.scene's texture), the middle image brightened by
1.1; orientations in a photax bundle --json result.  Truth: the scene's texture at each mosaic pixel
centre (photax.scene.texture) and the gain of 1.1.
"""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
import rasterio
from conftest import needs

import photax
from photax.io import write_geotiff
from photax.io.camera_file import write_camera
from photax.scene import texture

pytestmark = needs("dask", "rioxarray")

X0, Y0 = 500_000.0, 4_000_000.0
W, H = 160, 120
CAM = photax.FrameCamera.from_pixels(150.0, (W, H))
GSD = 280.0 / 150.0  # m/px: 300 m flying height over ~20 m terrain


def _render(e, s=2):
    """The image ``e`` takes of the textured plane ``Z = 20 + 0.03 (X - X0) - 0.02 (Y - Y0)`` (the DEM below,
    on which bilinear interpolation is exact): ``s x s`` rays per pixel cut with the plane in closed form,
    the texture averaged (area sampling, as photax.scene.render_image, without its compiled monoplotting)."""
    sub = (np.arange(s) + 0.5) / s - 0.5
    cc, rr = np.meshgrid((np.arange(W)[:, None] + sub).ravel(), (np.arange(H)[:, None] + sub).ravel())
    px = np.column_stack([cc.ravel(), rr.ravel()])
    rays = np.asarray(CAM.ray(CAM.pixel_to_image(px))) @ np.asarray(e.rotation).T
    c = np.asarray(e.position)
    t = (20 + 0.03 * (c[0] - X0) - 0.02 * (c[1] - Y0) - c[2]) / (rays[:, 2] - 0.03 * rays[:, 0] + 0.02 * rays[:, 1])
    g = c + t[:, None] * rays
    return np.asarray(texture(g[:, 0] - X0, g[:, 1] - Y0)).reshape(H, s, W, s).mean(axis=(1, 3))


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    d = tmp_path_factory.mktemp("block")
    cell = 4.0
    c = -400 + cell * (np.arange(200) + 0.5)
    heights = 20 + 0.03 * c[None, :] + 0.02 * c[:, None]  # rows run south: Y - Y0 = -c
    dem_t = (cell, 0.0, X0 - 400, 0.0, -cell, Y0 + 400)
    write_geotiff(d / "dem.tif", heights, dem_t, crs="EPSG:32633")
    base = 0.4 * W * GSD
    ext = [
        photax.ExteriorOrientation([X0 + (k - 1) * base, Y0, 300.0], np.radians([0.5, -0.4, 0.3 * k])) for k in range(3)
    ]
    (d / "images").mkdir()
    for k, e in enumerate(ext):
        img = _render(e)
        write_geotiff(d / "images" / f"img{k}.tif", (img * (1.1 if k == 1 else 1.0)).astype(np.float32), None)
    write_camera(CAM, d / "camera.yaml")
    # What photax bundle --json writes (BundleResult.to_dict): images [{name, position, angles_rad}], convention.
    result = {
        "converged": True,
        "convention": ext[0].convention,
        "images": [
            {
                "name": f"img{k}",
                "position": np.asarray(e.position).tolist(),
                "angles_rad": np.asarray(e.angles).tolist(),
            }
            for k, e in enumerate(ext)
        ],
    }
    (d / "bundle.json").write_text(json.dumps(result))
    return d


def _rms_vs_truth(v, transform):
    """RMS of ``g v + o - truth`` (global least-squares gain/offset) over the valid pixels."""
    rows, cols = np.mgrid[0 : v.shape[0], 0 : v.shape[1]] + 0.5
    X, Y = transform * (cols, rows)
    truth = np.asarray(texture(X - X0, Y - Y0))
    ok = np.isfinite(v)
    g, o = np.linalg.lstsq(np.stack([v[ok], np.ones(ok.sum())], 1), truth[ok], rcond=None)[0]
    return float(np.sqrt(np.mean((g * v[ok] + o - truth[ok]) ** 2))), ok


def test_block_to_mosaic_end_to_end(block, tmp_path, capsys):
    from photax.cli import main

    out = tmp_path / "mosaic.tif"
    args = [
        "mosaic",
        "--block",
        str(block / "bundle.json"),
        "--images",
        str(block / "images"),
        "--camera",
        str(block / "camera.yaml"),
        "--dem",
        str(block / "dem.tif"),
        "-o",
        str(out),
        "--chunks",
        "64",
    ]
    assert main(args) == 0
    cap = capsys.readouterr()
    assert "3 orthos" in cap.out
    assert re.findall(r"(\w+): +\d+%\|", cap.err)[-1] == "mosaic" and "ortho:" not in cap.err  # one bar
    gains = [float(g) for g in re.search(r"gains ([-\d., ]+)\)", cap.out).group(1).split(",")]
    np.testing.assert_allclose(gains[1] / gains[0], 1 / 1.1, rtol=0.02)
    np.testing.assert_allclose(gains[2] / gains[0], 1.0, rtol=0.02)
    assert not list(tmp_path.glob(".photax-mosaic-*"))  # the temporary orthos are gone
    with rasterio.open(out) as ds:
        assert ds.crs == rasterio.CRS.from_epsg(32633) and ds.driver == "GTiff"
        assert ds.profile["tiled"] and ds.profile.get("compress", "").lower() == "deflate"
        v, transform = ds.read(1, masked=True).filled(np.nan).astype(float), ds.transform
    assert v.shape[1] >= 1.7 * W  # three footprints 0.4 W apart: (2 x 0.4 + 1) W wide
    rms, ok = _rms_vs_truth(v, transform)
    assert ok.mean() > 0.9
    # Balanced and seamless: within 1 % of the grey range of the truth (an uncorrected gain of 1.1 on
    # the middle third alone would give ~0.03).  Measured: 0.0027; the middle ortho alone, at the same
    # resolution through the same command (a block of one), 0.0022.
    assert rms < 0.01, rms


def test_block_bad_input(block, tmp_path, capsys):
    from photax.cli import main

    base = [
        "mosaic",
        "--images",
        str(block / "images"),
        "--camera",
        str(block / "camera.yaml"),
        "--dem",
        str(block / "dem.tif"),
        "-o",
        str(tmp_path / "m.tif"),
    ]
    assert main(["mosaic", "--block", str(block / "bundle.json"), "-o", str(tmp_path / "m.tif")]) == 2
    assert "--block needs --images" in capsys.readouterr().err
    bad = json.loads((block / "bundle.json").read_text())
    bad["images"][2]["name"] = "img9"
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert main([*base, "--block", str(tmp_path / "bad.json")]) == 2
    assert "no image in" in capsys.readouterr().err and not (tmp_path / "m.tif").exists()
    assert main(["mosaic", "-o", str(tmp_path / "m.tif")]) == 2
    assert "give the ORTHO files" in capsys.readouterr().err


def test_block_library_calls(block, tmp_path, monkeypatch):
    """What the CLI's --block is built from: read_exteriors parses the file once and finds what
    read_exterior finds image by image; orthorectify_block puts every image on one pixel lattice,
    each ortho the very pixels of orthorectify_file on its own grid; heights_on_grid gives the DEM's
    plane (truth: Z = 20 + 0.03 (X - X0) - 0.02 (Y - Y0)) on the mosaic's grid."""
    import photax.io.orientation as orientation
    from photax.grid import ortho_grid
    from photax.io import block_images, read_camera, read_dem, read_exterior, read_exteriors
    from photax.mosaicking import heights_on_grid, mosaic_grid
    from photax.rectification import orthorectify_block, orthorectify_file

    parsed, real = [], orientation.read_json
    monkeypatch.setattr(orientation, "read_json", lambda p: parsed.append(p) or real(p))
    table, crs = read_exteriors(block / "bundle.json", ["img2", "elsewhere/img0.tif"])
    assert len(parsed) == 1 and list(table) == ["img2", "elsewhere/img0.tif"] and crs is None
    for name, e in table.items():
        ref = read_exterior(block / "bundle.json", name)[0]
        np.testing.assert_array_equal(e.position, ref.position)
        np.testing.assert_array_equal(e.angles, ref.angles)
    with pytest.raises(ValueError, match="img7"):
        read_exteriors(block / "bundle.json", ["img7"])

    images, exteriors, crs = block_images(block / "bundle.json", block / "images")
    assert [p.name for p in images] == ["img0.tif", "img1.tif", "img2.tif"] and crs is None
    camera, dem_file = read_camera(block / "camera.yaml"), read_dem(block / "dem.tif")
    dem = dataclasses.replace(dem_file, crs=None)  # a DEM without a CRS: the orientation file's names the grids'
    seen = []
    paths = orthorectify_block(images, exteriors, camera, dem, tmp_path, crs="EPSG:32634", callback=seen.append)
    assert seen == [0, 1, 2] and [p.parent for p in paths] == [tmp_path] * 3
    transforms = []
    for image, e, path in zip(images, exteriors, paths):
        with rasterio.open(path) as ds:
            v, t = ds.read(1), ds.transform
            assert ds.crs == rasterio.CRS.from_epsg(32634)  # the orientation file's CRS
        transforms.append(t)
        ref = tmp_path / "ref.tif"
        orthorectify_file(image, ref, e, camera, dem, ortho_grid(e, camera, dem, abs(t.a)))
        with rasterio.open(ref) as ds:
            np.testing.assert_array_equal(v, ds.read(1))
            assert ds.transform == t
    t0 = transforms[0]
    for t in transforms[1:]:  # one lattice: the same pixel size, whole pixels apart
        assert (t.a, t.e) == (t0.a, t0.e)
        offset = np.array([(t.c - t0.c) / t0.a, (t.f - t0.f) / t0.e])
        np.testing.assert_allclose(offset, np.round(offset), atol=1e-6)

    grid = mosaic_grid(paths)
    assert grid.transform.a == t0.a and grid.crs == rasterio.CRS.from_epsg(32634)
    h = heights_on_grid(
        block / "dem.tif", photax.Grid(grid.transform, grid.shape, dem_file.crs)
    )  # the coordinates' CRS
    # what rioxarray's reproject_match gives (heights_on_grid used it; now rasterio's reproject alone)
    import rioxarray

    from photax.io.lazy import dataarray

    template = dataarray(
        np.zeros(grid.shape), photax.Grid(grid.transform, grid.shape, dem_file.crs), np.asarray(np.nan), "t"
    )
    ref = (
        rioxarray.open_rasterio(block / "dem.tif", masked=True).squeeze("band", drop=True).rio.reproject_match(template)
    )
    np.testing.assert_array_equal(h, ref.values)
    xy = grid.xy()
    plane = 20 + 0.03 * (xy[..., 0] - X0) - 0.02 * (xy[..., 1] - Y0)
    ok = np.isfinite(h)
    assert ok.mean() > 0.9
    # nearest-neighbour resampling of the 4 m DEM: off by at most half a cell's slope, 0.05 * 4 / 2 m
    assert np.max(np.abs(h[ok] - plane[ok])) <= 0.1 + 1e-9


def test_ortho_grid_takes_the_crs(block):
    from photax.grid import ortho_grid
    from photax.io import read_camera, read_dem

    camera, dem = read_camera(block / "camera.yaml"), read_dem(block / "dem.tif")
    e = photax.ExteriorOrientation([X0, Y0, 300.0], np.radians([0.5, -0.4, 0.0]))
    default = ortho_grid(e, camera, dem)
    named = ortho_grid(e, camera, dataclasses.replace(dem, crs=None), crs="EPSG:32634")  # a DEM without one
    assert default.crs == dem.crs and named.crs == "EPSG:32634"
    with pytest.raises(ValueError, match="does not reproject"):  # a DEM labelled otherwise: never relabelled
        ortho_grid(e, camera, dem, crs="EPSG:32634")
    assert (named.transform, named.shape) == (default.transform, default.shape)  # only the label differs
