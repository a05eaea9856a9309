"""``photax dsm`` on a synthetic RPC pair rendered from a known DSM (issue 36's "done when": the DSM
to <= 0.5 m median absolute error with >= 90 % completeness), and its failures.

Two push-broom images (:func:`photax.scene.pushbroom_scene`, 1 m GSD, 15 deg forwards and
backwards) are rendered from a textured surface (a tilted plane with a 40 m hill) by their rigorous
models: each pixel centre is localized on the surface (fixed point on the height) and
painted with a random band-limited texture there.  Their RPCs (:func:`photax.fit_rpc`) are written
into the GeoTIFFs, as satellite images come; ``photax dsm --camera rpc`` sees only those files.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
import rasterio
from rasterio.rpc import RPC
from rpc_pair import render, surface, texture

from photax.cli import main
from photax.pushbroom import fit_rpc
from photax.scene import pushbroom_scene
from photax.sensor import WGS84, _pyproj, utm_crs
from photax.stereo import read_ply

SIZE = (200, 200)
HEIGHTS = (0.0, 400.0)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rpc_pair")
    scenes = [
        pushbroom_scene(pitch=-15.0, gsd=1.0, image_size=SIZE, height_range=HEIGHTS, seed=0),
        pushbroom_scene(pitch=15.0, roll=2.0, gsd=1.0, image_size=SIZE, height_range=HEIGHTS, seed=1),
    ]
    rpcs = [fit_rpc(s.camera, HEIGHTS, grid=9, layers=4).camera for s in scenes]
    centre = np.asarray(rpcs[0].ground_box()[0], dtype=float)
    crs = utm_crs(*centre)
    x0, y0 = _pyproj(centre[None], WGS84, crs)[0]
    tex = texture(7)  # 1 m cells, x0 - 600 .. x0 + 600
    paths = []
    for k, (s, rpc) in enumerate(zip(scenes, rpcs)):
        img = render(s.camera, crs, x0, y0, tex, SIZE).astype(np.float32)
        path = folder / f"img_{k}.tif"
        profile = dict(driver="GTiff", width=SIZE[0], height=SIZE[1], count=1, dtype="float32")
        with rasterio.open(path, "w", rpcs=RPC(**rpc.to_dict()), **profile) as dst:
            dst.write(img, 1)
        paths.append(path)
    return paths, [s.camera for s in scenes], crs, (x0, y0)


def test_dsm_of_a_rendered_rpc_pair(rendered, tmp_path, capsys):
    (a, b), cams, crs, (x0, y0) = rendered
    out, ply, laz = tmp_path / "dsm.tif", tmp_path / "pts.ply", tmp_path / "pts.laz"
    # the points also as LAZ where laspy and its LAZ backend are there (the las extra; CI has it)
    with_laz = importlib.util.find_spec("laspy") is not None and importlib.util.find_spec("lazrs") is not None
    rc = main(["dsm", str(a), str(b), "--camera", "rpc", "--heights", "100", "260", "--crs", crs,
               "--resolution", "2", "--tile", "100", "-o", str(out), "--ply", str(ply), "--no-progress",
               *(["--points", str(laz)] if with_laz else [])])  # fmt: skip
    cap = capsys.readouterr()
    text = cap.out
    assert rc == 0, cap.err
    assert "completeness" in text and "vertical residual" in text
    with rasterio.open(out) as src:
        dsm, transform = src.read(1), src.transform
        assert src.crs == rasterio.crs.CRS.from_user_input(crs) and np.isnan(src.nodata)
    rows, cols = np.mgrid[0 : dsm.shape[0], 0 : dsm.shape[1]]
    x, y = transform * (cols + 0.5, rows + 0.5)
    truth = surface(x, y, x0, y0)
    # the common footprint: cells whose surface point both rigorous cameras see 3 px inside their images
    llh = np.column_stack([*_pyproj(np.column_stack([x.ravel(), y.ravel()]), crs, WGS84).T, truth.ravel()])
    seen = np.ones(len(llh), bool)
    for cam in cams:
        px = np.asarray(cam(llh))
        seen &= np.all((px >= 3) & (px <= np.array(SIZE) - 4), axis=1)
    seen = seen.reshape(dsm.shape)
    err = np.abs(dsm - truth)[seen]
    completeness = np.isfinite(err).mean()
    median = np.nanmedian(err)
    print(f"synthetic RPC pair: median |dz| {median:.3f} m, completeness {completeness:.1%} of {seen.sum()} cells")
    assert completeness >= 0.90
    assert median <= 0.5
    pts = read_ply(ply)
    assert len(pts["x"]) > 1000 and np.all(pts["sigma_z"] > 0)
    if with_laz:  # the LAZ: what laspy reads is the PLY's points (1 mm integers), on the true surface
        import laspy
        import pyproj

        las = laspy.read(laz)
        assert las.header.parse_crs().equals(pyproj.CRS.from_user_input(crs))
        for axis in "xyz":
            np.testing.assert_allclose(np.asarray(las[axis]), pts[axis], atol=0.5e-3 + 1e-9, rtol=0)
        np.testing.assert_array_equal(las.sigma_z, pts["sigma_z"])
        dz = np.abs(np.asarray(las.z) - surface(np.asarray(las.x), np.asarray(las.y), x0, y0))
        print(f"LAZ: {len(las.points)} points, median |dz| {np.median(dz):.3f} m against the surface")
        assert np.median(dz) <= 0.5


def test_dsm_blank_and_bad_input(rendered, tmp_path, capsys):
    (a, b), _, crs, (x0, y0) = rendered
    out = tmp_path / "blank.tif"
    far = [str(v) for v in (x0 + 50e3, y0, x0 + 50.5e3, y0 + 500)]  # a grid 50 km away: no height on it
    rc = main(["dsm", str(a), str(b), "--camera", "rpc", "--heights", "100", "260", "--crs", crs, "--bounds", *far,
               "--resolution", "5", "-o", str(out), "--no-progress"])  # fmt: skip
    assert rc == 1 and not out.exists()
    assert "no height" in capsys.readouterr().err
    assert main(["dsm", str(a), "--camera", "rpc", "-o", str(out)]) == 2  # one image
    assert main(["dsm", str(a), str(b), "--camera", "rpc", "--heights", "5", "1", "-o", str(out)]) == 2
    assert main(["dsm", str(a), str(b), "--camera", "rpc", "--exterior", str(a), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "at least two images" in err and "H_MAX" in err and "own orientation" in err


def test_epipolar_command_with_rpcs(rendered, tmp_path, capsys):
    (a, b), cams, _, _ = rendered
    prefix = tmp_path / "pair"
    rc = main(["epipolar", str(a), str(b), "--camera", "rpc", "--bounds", "0", "0", "99", "99",
               "--heights", "100", "260", "-o", str(prefix)])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    assert "residual vertical disparity" in capsys.readouterr().out
    info = json.loads((tmp_path / "pair.json").read_text())
    assert info["vertical_residual_px"] <= 0.5
    # the affine maps put a rigorous correspondence on one row (the cameras' own geometry, not the RPCs')
    h_l, h_r = np.asarray(info["affine_left"]), np.asarray(info["affine_right"])
    px = np.array([[50.0, 50.0]])
    ll = np.asarray(cams[0].to_ground(px, np.array([180.0])))
    pr = np.asarray(cams[1](np.column_stack([ll, [180.0]])))
    row_l = (h_l @ np.r_[px[0], 1.0])[1]
    row_r = (h_r @ np.r_[pr[0], 1.0])[1]
    assert abs(row_l - row_r) <= 0.5
    with rasterio.open(tmp_path / "pair_left.tif") as src:
        assert src.count == 1 and src.height > 50
    assert main(["epipolar", str(a), str(b), "--camera", "rpc", "--exterior", str(a), "-o", str(prefix)]) == 2
