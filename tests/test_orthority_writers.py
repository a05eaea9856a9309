"""orthority's file formats written by photax (issue 22): interior YAML, exterior
CSV (+ .prj) and GeoJSON, and ``photax ortho --export-params``.

References: photax's own readers (read -> write -> read is the identity to 1e-9)
and orthority 0.7 itself (its readers and cameras project ground points onto the
same pixels as photax's camera and orientation that were written).
"""

from __future__ import annotations

import json
import pathlib
import warnings

import numpy as np
import pyproj
import pytest

import photax
from photax.io.orthority import (
    read_orthority_exterior_crs,
    read_orthority_geojson,
    read_orthority_interior,
    write_orthority_exterior,
    write_orthority_geojson,
    write_orthority_interior,
)

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"
CRS = "EPSG:32633"

CAMERAS = {
    "pinhole_mm": photax.FrameCamera(8.8, (0.011, -0.0066), None, pixel_size=0.0176, image_size=(1000, 750)),
    "brown_px": photax.FrameCamera.from_pixels(
        3666.7, (5472, 3648), (2740.3, 1818.9), (-0.267, 0.112, -0.0332, 0.00092, -0.000088)
    ),
    # non-square pixels (fx != fy), portrait
    "brown_tall": photax.FrameCamera(
        120.0, (0.3, -0.2), (0.01, -0.002, 0.0003, 1e-4, -2e-4), pixel_size=(0.144, 0.1446), image_size=(640, 1152)
    ),
    # photax's full OpenCV and fisheye models (orthority's opencv and fisheye types)
    "opencv_px": photax.FrameCamera.from_pixels(
        3666.7,
        (5472, 3648),
        (2740.3, 1818.9),
        (-0.267, 0.112, -0.0332, 0.00092, -0.000088, 0.01, -0.002, 0.0005, 1e-4, -2e-5, 3e-5, -1e-5),
        model="opencv",
    ),
    "fisheye_px": photax.FrameCamera.from_pixels(
        2400.0, (4000, 3000), (2010.0, 1490.0), (0.05, -0.01, 0.003, -0.0004), model="fisheye"
    ),
}


def _assert_same_camera(a, b):
    for key in ("focal_length", "principal_point", "distortion", "pixel_size"):
        np.testing.assert_allclose(np.asarray(getattr(a, key)), np.asarray(getattr(b, key)), rtol=1e-12, atol=1e-12)
    assert a.image_size == b.image_size


def _table(n=5, seed=0):
    rng = np.random.default_rng(seed)
    out = {}
    for k in range(n):
        position = (512000 + rng.uniform(-500, 500), 4103000 + rng.uniform(-500, 500), rng.uniform(300, 900))
        angles = np.radians(rng.uniform([-10, -10, -180], [10, 10, 180]))
        out[f"IMG_{k:04d}.tif"] = photax.ExteriorOrientation(
            position, angles, ["phi-omega-kappa", "omega-phi-kappa"][k % 2]
        )
    return out


def _rotation(eo):
    return np.asarray(photax.rotation_matrix(eo.angles, eo.convention))


def test_interior_round_trip(tmp_path):
    path = write_orthority_interior(tmp_path / "int.yaml", CAMERAS)
    back = read_orthority_interior(path)
    assert list(back) == list(CAMERAS)
    for name, cam in CAMERAS.items():
        _assert_same_camera(back[name], cam)
    # written again from what was read: the same cameras again
    again = read_orthority_interior(write_orthority_interior(tmp_path / "again.yaml", back))
    for name, cam in CAMERAS.items():
        _assert_same_camera(again[name], cam)


def test_interior_refuses_what_orthority_cannot_hold(tmp_path):
    with pytest.raises(ValueError, match="pixel grid"):
        write_orthority_interior(tmp_path / "x.yaml", {"c": photax.FrameCamera(8.8)})
    with pytest.raises(ValueError, match="legacy"):
        write_orthority_interior(tmp_path / "x.yaml", {"camera": CAMERAS["brown_px"]})
    assert not (tmp_path / "x.yaml").exists()


def test_exterior_csv_and_geojson_round_trip(tmp_path):
    table = _table()
    csv = write_orthority_exterior(tmp_path / "ext.csv", table, CRS)
    back, crs = read_orthority_exterior_crs(csv)
    assert pyproj.CRS(crs) == pyproj.CRS(CRS)
    gj, gcrs = read_orthority_geojson(write_orthority_geojson(tmp_path / "ext.geojson", table, CRS))
    assert gcrs == CRS
    for name, eo in table.items():
        stem = pathlib.Path(name).stem
        for got in (back[stem], gj[stem]):
            np.testing.assert_allclose(np.asarray(got.position), np.asarray(eo.position), rtol=0, atol=1e-9)
            np.testing.assert_allclose(_rotation(got), _rotation(eo), rtol=0, atol=1e-12)
    # no CRS: no .prj, and the reader says none
    write_orthority_exterior(tmp_path / "bare.csv", table)
    assert not (tmp_path / "bare.prj").exists()
    assert read_orthority_exterior_crs(tmp_path / "bare.csv")[1] is None


def _orthority_pixels(int_path, ext_params, name, ground):
    from orthority.camera import create_camera
    from orthority.param_io import read_oty_int_param

    (cam_id, params), *_ = read_oty_int_param(int_path).items()
    e = ext_params[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cam = create_camera(**params, xyz=e["xyz"], opk=e["opk"])
    return cam.world_to_pixel(ground.T).T


@pytest.mark.parametrize("name", list(CAMERAS))
def test_orthority_reads_what_photax_writes(tmp_path, name):
    """orthority's own readers and camera put ground points on photax's pixels."""
    from orthority.param_io import CsvReader, OtyReader

    camera = CAMERAS[name]
    int_path = write_orthority_interior(tmp_path / "int.yaml", {name: camera})
    table = _table(3, seed=1)
    write_orthority_exterior(tmp_path / "ext.csv", table, CRS)
    write_orthority_geojson(tmp_path / "ext.geojson", table, CRS, camera=name)
    csv_params = CsvReader(tmp_path / "ext.csv").read_ext_param()
    gj_params = OtyReader(tmp_path / "ext.geojson").read_ext_param()
    rng = np.random.default_rng(2)
    for image, eo in table.items():
        # ground points seen by the camera: rays through pixels, 200-400 m out
        w, h = camera.image_size
        pix = rng.uniform((0, 0), (w - 1, h - 1), (50, 2))
        rays = np.asarray(camera.ray(camera.pixel_to_image(pix)))
        ground = np.asarray(eo.position) + rng.uniform(200, 400, (50, 1)) * (rays @ _rotation(eo).T)
        ours = np.asarray(camera.image_to_pixel(photax.project(ground, eo, camera)))
        np.testing.assert_allclose(ours, pix, atol=0.05)  # in view (ray() undistorts in 20 fixed-point steps)
        for params, key in ((csv_params, pathlib.Path(image).stem), (gj_params, image)):
            ref = _orthority_pixels(int_path, params, key, ground)
            np.testing.assert_allclose(ref, ours, rtol=0, atol=1e-6)


def test_cli_ortho_export_params(tmp_path):
    """``photax ortho --export-params DIR`` writes the camera and orientation it used;
    orthority reads them and projects as photax does."""
    from orthority.param_io import OtyReader

    from photax.cli import main
    from photax.io import read_interior

    truth = json.loads((DATA / "sample_truth.json").read_text())
    ext = {k: truth[k] for k in ("crs", "convention", "position", "angles_rad")}
    (tmp_path / "ext.json").write_text(json.dumps(ext))
    out = tmp_path / "params"
    argv = ["ortho", str(DATA / "sample_image.tif"), "--height", "0", "--camera", str(DATA / "sample_camera.yaml")]
    argv += ["--exterior", str(tmp_path / "ext.json"), "--resolution", "20", "--no-progress"]
    assert main([*argv, "-o", str(tmp_path / "o.tif"), "--export-params", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "ext_param.csv",
        "ext_param.geojson",
        "ext_param.prj",
        "int_param.yaml",
    ]
    camera = read_interior(DATA / "sample_camera.yaml")
    _assert_same_camera(read_orthority_interior(out / "int_param.yaml")["photax_camera"], camera)
    eo = photax.ExteriorOrientation(ext["position"], ext["angles_rad"], ext["convention"])
    ground = np.c_[np.random.default_rng(3).uniform(-300, 300, (40, 2)) + np.asarray(ext["position"][:2]), np.zeros(40)]
    ours = np.asarray(camera.image_to_pixel(photax.project(ground, eo, camera)))
    ref = _orthority_pixels(
        out / "int_param.yaml", OtyReader(out / "ext_param.geojson").read_ext_param(), "sample_image.tif", ground
    )
    np.testing.assert_allclose(ref, ours, rtol=0, atol=1e-6)
    # the ortho itself was written too; and a file where the folder should be is refused
    assert (tmp_path / "o.tif").is_file()
    (tmp_path / "file").write_text("x")
    assert main([*argv, "-o", str(tmp_path / "o2.tif"), "--export-params", str(tmp_path / "file")]) == 2


def test_real_orthority_files_round_trip(tmp_path):
    """orthority's own test files (NGI) read, written, read again: the same cameras and
    orientations, the same CRS."""
    from conftest import shared_file

    interior = read_orthority_interior(shared_file("orthority/io/ngi_int_param.yaml"))
    back = read_orthority_interior(write_orthority_interior(tmp_path / "int.yaml", interior))
    for name, cam in interior.items():
        _assert_same_camera(back[name], cam)
    for src in ("orthority/io/ngi_xyz_opk.csv", "orthority/io/ngi_ext_param.geojson"):
        path = shared_file(src)
        table, crs = read_orthority_geojson(path) if path.suffix == ".geojson" else read_orthority_exterior_crs(path)
        csv, csv_crs = read_orthority_exterior_crs(write_orthority_exterior(tmp_path / "e.csv", table, crs))
        gj, gj_crs = read_orthority_geojson(write_orthority_geojson(tmp_path / "e.geojson", table, crs))
        assert pyproj.CRS(csv_crs) == pyproj.CRS(crs) == pyproj.CRS(gj_crs)
        for name, eo in table.items():
            for got in (csv[name], gj[name]):
                np.testing.assert_allclose(np.asarray(got.position), np.asarray(eo.position), rtol=0, atol=1e-9)
                np.testing.assert_allclose(_rotation(got), _rotation(eo), rtol=0, atol=1e-12)
