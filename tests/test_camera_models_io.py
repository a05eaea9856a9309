"""Readers of the opencv and fisheye cameras of other tools (issue 22): orthority's
interior files (``opencv``, ``fisheye``, every parameter), OpenSfM's
``reconstruction.json`` cameras (``fisheye``, ``fisheye_opencv``, ``radial``,
``simple_radial``; ``spherical`` refused by name), photax's own camera file, and
:func:`photax.io.orthority.camera_to_orthority` back.

References: orthority 0.7's cameras (``create_camera(...).world_to_pixel``) and OpenCV's
``cv2.fisheye.projectPoints`` for OpenSfM's ``fisheye_opencv`` (which orthority does
not read).
"""

from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import pytest
import yaml

import photax
from photax.io.camera_file import read_camera, write_camera
from photax.io.opensfm import read_opensfm_cameras
from photax.io.orthority import camera_to_orthority, read_orthority_interior

OPENCV = dict(
    im_size=(1368, 912),
    focal_len=(6.31, 6.35),
    sensor_size=(13.2, 8.8),
    cx=-0.0015,
    cy=0.0047,
    k1=-0.264,
    k2=0.1019,
    p1=0.00073,
    p2=0.00026,
    k3=-0.0258,
    k4=0.12,
    k5=-0.031,
    k6=0.008,
    s1=0.0011,
    s2=-0.0004,
    s3=-0.0009,
    s4=0.0003,
)
FISHEYE = dict(im_size=(1368, 912), focal_len=0.45, cx=0.003, cy=-0.002, k1=0.043, k2=-0.012, k3=0.0041, k4=-0.0009)
XYZ, OPK = (10.0, 20.0, 150.0), tuple(np.radians([5.0, -8.0, 30.0]))


def _yaml(path, kind, params):
    path.write_text(yaml.safe_dump({"cam": {"type": kind, **{k: list(v) if isinstance(v, tuple) else v
                                                            for k, v in params.items()}}}))  # fmt: skip
    return path


def _orthority_pixels(kind, params, ground):
    from orthority.camera import create_camera
    from orthority.enums import CameraType

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # orthority: no sensor_size
        ref = create_camera(CameraType(kind), **params, xyz=XYZ, opk=OPK)
    return ref.world_to_pixel(ground.T).T


def _pixels(camera, ground):
    ext = photax.ExteriorOrientation(XYZ, OPK, "omega-phi-kappa")
    return np.asarray(camera.image_to_pixel(photax.project(ground, ext, camera)))


def _ground(n=200):
    return np.c_[np.random.default_rng(1).uniform(-60, 80, (n, 2)), np.zeros(n)]


@pytest.mark.parametrize("kind,params", [("opencv", OPENCV), ("fisheye", FISHEYE)])
def test_orthority_opencv_and_fisheye_interiors_project_as_orthority(tmp_path, kind, params):
    pytest.importorskip("orthority")
    camera = read_orthority_interior(_yaml(tmp_path / "int.yaml", kind, params))["cam"]
    assert camera.model == kind
    ground = _ground()
    ours, ref = _pixels(camera, ground), _orthority_pixels(kind, params, ground)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-8)
    assert np.ptp(ours[:, 0]) > 300
    # every coefficient is read: dropping any one moves the pixels
    for key in [k for k in params if k[0] in "kps" and k[1:].isdigit()]:
        other = read_orthority_interior(_yaml(tmp_path / "o.yaml", kind, {**params, key: 0.0}))["cam"]
        assert np.abs(_pixels(other, ground) - ref).max() > 1e-3, key


def test_orthority_opencv_tilt_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"opencv parameters \['tx'\] are not zero.*tilted sensor"):
        read_orthority_interior(_yaml(tmp_path / "int.yaml", "opencv", {**OPENCV, "tx": 0.01}))
    assert read_orthority_interior(_yaml(tmp_path / "int.yaml", "opencv", {**OPENCV, "tx": 0.0}))


@pytest.mark.parametrize("kind,params", [("opencv", OPENCV), ("fisheye", FISHEYE), ("brown", None)])
def test_camera_to_orthority_round_trips(tmp_path, kind, params):
    """photax camera -> orthority dict: orthority's camera made from it projects as
    photax's, and photax reads the dict back to the same camera."""
    pytest.importorskip("orthority")
    if params is None:
        params = {k: v for k, v in OPENCV.items() if not (k[0] in "ks" and k[1:].isdigit()) or k in ("k1", "k2", "k3")}
    camera = read_orthority_interior(_yaml(tmp_path / "int.yaml", kind, params))["cam"]
    d = camera_to_orthority(camera)
    assert d["type"] == kind
    ground = _ground(50)
    ours = _pixels(camera, ground)
    np.testing.assert_allclose(_orthority_pixels(d.pop("type"), d, ground), ours, rtol=0, atol=1e-8)
    back = read_orthority_interior(_yaml(tmp_path / "back.yaml", kind, d))["cam"]
    np.testing.assert_allclose(_pixels(back, ground), ours, rtol=0, atol=1e-8)
    with pytest.raises(ValueError, match="pixel grid"):
        camera_to_orthority(photax.FrameCamera(1.0))


def _reconstruction(tmp_path, cameras):
    path = tmp_path / "reconstruction.json"
    rec = [{"cameras": cameras, "shots": {}, "reference_lla": {"latitude": 0, "longitude": 0, "altitude": 0}}]
    path.write_text(json.dumps(rec))
    return path


def test_opensfm_fisheye_opencv_projects_as_cv2_fisheye(tmp_path):
    w, h = 4000, 3000
    p = dict(projection_type="fisheye_opencv", width=w, height=h, focal_x=0.25, focal_y=0.2515, c_x=0.004,
             c_y=-0.003, k1=0.043, k2=-0.012, k3=0.0041, k4=-0.0009)  # fmt: skip
    camera = read_opensfm_cameras(_reconstruction(tmp_path, {"v2 fish": p}))["fish"]
    assert camera.model == "fisheye"
    m = max(w, h)
    k = np.array([[p["focal_x"] * m, 0, (w - 1) / 2 + p["c_x"] * m], [0, p["focal_y"] * m, (h - 1) / 2 + p["c_y"] * m],
                  [0, 0, 1]])  # fmt: skip
    rng = np.random.default_rng(3)
    tan = np.tan(np.radians(rng.uniform(0, 80, 100)))
    az = rng.uniform(0, 2 * np.pi, 100)
    pts_cv = np.c_[tan * np.cos(az), tan * np.sin(az), np.ones(100)] * 7.0  # OpenCV's camera frame
    ref = cv2.fisheye.projectPoints(pts_cv[:, None], np.zeros(3), np.zeros(3), k, np.array([p[f"k{i}"] for i in
                                    range(1, 5)]))[0][:, 0]  # fmt: skip
    ours = np.asarray(camera.image_to_pixel(camera.project(pts_cv * [1, -1, -1])))  # photax's frame: y up, z back
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)


def test_opensfm_fisheye_and_radial_as_orthority_reads_them(tmp_path):
    pytest.importorskip("orthority")
    from orthority.camera import create_camera
    from orthority.param_io import read_osfm_int_param

    cams = {
        "v2 fish": dict(projection_type="fisheye", width=1368, height=912, focal=0.45, k1=0.043, k2=-0.012),
        "v2 radial": dict(projection_type="radial", width=1368, height=912, focal_x=0.66, focal_y=0.67,
                          c_x=0.002, c_y=-0.004, k1=-0.2, k2=0.05),
        "v2 simple": dict(projection_type="simple_radial", width=1368, height=912, focal_x=0.66, focal_y=0.66,
                          c_x=0.002, c_y=-0.004, k1=-0.2),
    }  # fmt: skip
    path = _reconstruction(tmp_path, cams)
    ours = read_opensfm_cameras(path)
    ref = read_osfm_int_param(path)
    ground = _ground()
    for name, params in ref.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cam = create_camera(**params, xyz=XYZ, opk=OPK)
        np.testing.assert_allclose(_pixels(ours[name], ground), cam.world_to_pixel(ground.T).T, rtol=0, atol=1e-8)
    assert ours["fish"].model == "fisheye" and ours["radial"].model == "brown"


def test_opensfm_spherical_is_refused_by_name(tmp_path):
    path = _reconstruction(tmp_path, {"v2 pano": {"projection_type": "spherical", "width": 10, "height": 5}})
    with pytest.raises(ValueError, match="projection_type 'spherical'.*spherical.*no photax camera"):
        read_opensfm_cameras(path)


@pytest.mark.parametrize("model", ["opencv", "fisheye"])
def test_photax_camera_file_keeps_the_model(tmp_path, model):
    """write_camera / read_camera keep every coefficient; ``convention: opencv`` negates
    p1, s3, s4 as OpenCV's y points down."""
    names = photax.camera.DISTORTION_MODELS[model]
    d = np.linspace(-0.05, 0.06, len(names))
    camera = photax.FrameCamera.from_pixels(900.0, (1200, 800), (601.0, 398.5), d, model=model)
    write_camera(camera, tmp_path / "cam.yaml")
    back = read_camera(tmp_path / "cam.yaml")
    assert back.model == model
    np.testing.assert_array_equal(np.asarray(back.distortion), d)
    text = {"focal_length_px": 900.0, "image_size": [1200, 800],
            "distortion": {"model": model, "convention": "opencv", **dict(zip(names, d.tolist()))}}  # fmt: skip
    (tmp_path / "cv.yaml").write_text(yaml.safe_dump(text))
    flip = np.array([-1.0 if n in ("p1", "s3", "s4") else 1.0 for n in names])
    np.testing.assert_array_equal(np.asarray(read_camera(tmp_path / "cv.yaml").distortion), d * flip)
    text["distortion"]["s9"] = 0.1
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(text))
    with pytest.raises(ValueError, match=f"unknown key distortion.s9 for the {model} model"):
        read_camera(tmp_path / "bad.yaml")


def test_block_folder_keeps_a_fisheye_camera_and_its_free_coefficients(tmp_path):
    """write_block / read_block: the camera file names the model, ``free`` its coefficients."""
    from photax.io import read_block, write_block
    from photax.scene import synthetic_block

    problem, _ = synthetic_block(0, n_tie=15)
    fish = photax.FrameCamera.from_pixels(3000.0, (4000, 3000), distortion=(0.03, -0.01, 0.0, 0.002), model="fisheye")
    problem = problem.replace(cameras=[fish], free_intrinsics=("f", "k1", "k4"))
    write_block(problem, tmp_path / "block")
    back = read_block(tmp_path / "block")
    assert back.cameras[0].model == "fisheye" and back.intrinsic_names == ("f", "x0", "y0", "k1", "k2", "k3", "k4")
    np.testing.assert_array_equal(np.asarray(back.cameras[0].distortion), np.asarray(fish.distortion))
    np.testing.assert_array_equal(back.free_intrinsics, problem.free_intrinsics)
