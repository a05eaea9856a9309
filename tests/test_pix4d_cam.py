"""Pix4D's ``*_pix4d_calibrated_internal_camera_parameters.cam`` (photax.io.pix4d).

References, independent of the reader:

* Pix4D's perspective-lens model (support article 202559089 "How are the Internal and
  External Camera Parameters defined?", section 2.1.2), typed below in
  ``_pix4d_project`` in the frame of the ``calibrated_camera_parameters.txt`` it is
  exported with (x right, y down, z forward; pixels from the top-left corner), with
  f, cx, cy = F, Px, Py times W / sensor width;
* a real PIX4Dmapper run's pair of files, the ``maize`` project whose
  ``pix4d_calibrated_internal_camera_parameters.cam`` and
  ``calibrated_camera_parameters.txt`` (image DJI_0954.JPG, 4608 x 3456) EasyIDP
  quotes in its ``easyidp/pix4d.py`` docstrings: the ``.cam`` below is that file, and
  ``MAIZE_K`` that run's camera matrix K (pixels).
"""

from __future__ import annotations

import numpy as np
import pytest

import photax as ptx
from photax.io.pix4d import read_pix4d_cam, write_pix4d_cam

MAIZE_CAM = """Pix4D camera calibration file 0
#Focal Length mm assuming a sensor width of 17.49998592000000030566x13.12498944000000200560mm
F 15.01175404934517487732
#Principal Point mm
Px 8.48210511970419922534
Py 6.33434629978042273990
#Symmetrical Lens Distortion Coeffs
K1 0.03833474118270804865
K2 -0.01750917966495743258
K3 0.02049798716391852335
#Tangential Lens Distortion Coeffs
T1 0.00240851666319534747
T2 0.00292562392135245920
"""
MAIZE_SIZE = (4608, 3456)
MAIZE_K = (3952.81247514184087776812, 2233.46124792750424603582, 1667.92521335858214115433)  # f, cx, cy


def _pix4d_project(xyz_cv, p, size):
    """Pix4D's section 2.1.2 written out: camera-frame points (x right, y down, z forward)
    -> pixel (u, v) from the top-left corner, f, cx, cy from mm by W / sensor width."""
    scale = size[0] / p["w_mm"]
    f, cx, cy = p["F"] * scale, p["Px"] * scale, p["Py"] * size[1] / p["h_mm"]
    xh, yh = xyz_cv[:, 0] / xyz_cv[:, 2], xyz_cv[:, 1] / xyz_cv[:, 2]
    r2 = xh**2 + yh**2
    radial = 1 + p["K1"] * r2 + p["K2"] * r2**2 + p["K3"] * r2**3
    xhd = radial * xh + 2 * p["T1"] * xh * yh + p["T2"] * (r2 + 2 * xh**2)
    yhd = radial * yh + 2 * p["T2"] * xh * yh + p["T1"] * (r2 + 2 * yh**2)
    return np.column_stack([f * xhd + cx, f * yhd + cy])


def _params(text):
    p = {ln.split()[0]: float(ln.split()[1]) for ln in text.splitlines()[2:] if ln and not ln.startswith("#")}
    w, h = text.splitlines()[1].split("of ")[1].removesuffix("mm").split("x")
    return {**p, "w_mm": float(w), "h_mm": float(h)}


def _pixels(camera, xyz_cv):
    """photax's projection of the same points (its camera frame: x right, y up, z back),
    in pixels from the top-left *corner* (photax's pixel origin is the first pixel's centre)."""
    return np.asarray(camera.image_to_pixel(camera.project(xyz_cv * [1, -1, -1]))) + 0.5


def _points(seed, n=80):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.6, 0.6, (n, 2)), np.ones(n)]) * rng.uniform(2, 60, (n, 1))


def test_maize_cam_projects_as_pix4d_and_matches_its_camera_matrix(tmp_path):
    path = tmp_path / "maize_pix4d_calibrated_internal_camera_parameters.cam"
    path.write_text(MAIZE_CAM)
    cam = read_pix4d_cam(path, MAIZE_SIZE)
    xyz = _points(0)
    np.testing.assert_allclose(_pixels(cam, xyz), _pix4d_project(xyz, _params(MAIZE_CAM), MAIZE_SIZE), atol=1e-9)
    # the same run's camera matrix K (pixels from the top-left corner) from the photax camera
    ps = float(np.asarray(cam.pixel_size)[0])
    x0, y0 = np.asarray(cam.principal_point)
    f_px, cx, cy = float(cam.focal_length) / ps, x0 / ps + MAIZE_SIZE[0] / 2, -y0 / ps + MAIZE_SIZE[1] / 2
    np.testing.assert_allclose([f_px, cx, cy], MAIZE_K, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(cam.pixel_size), [17.49998592 / 4608, 13.12498944 / 3456], rtol=1e-12)


def test_read_interior_takes_the_size_from_the_runs_camera_parameters(tmp_path):
    cam_path = tmp_path / "maize_pix4d_calibrated_internal_camera_parameters.cam"
    cam_path.write_text(MAIZE_CAM)
    with pytest.raises(ValueError, match="does not give the image's size in pixels"):
        ptx.io.read_interior(cam_path)
    (tmp_path / "maize_calibrated_camera_parameters.txt").write_text(
        "fileName imageWidth imageHeight\ncamera matrix K [3x3]\nradial distortion [3x1]\n"
        "tangential distortion [2x1]\ncamera position t [3x1]\ncamera rotation R [3x3]\n"
        "camera model m = K [R|-Rt] X\n\nDJI_0954.JPG 4608 3456\n3952.8 0 2233.4\n0 3952.8 1667.9\n0 0 1\n"
    )
    cam = ptx.io.read_interior(cam_path)
    assert cam.image_size == MAIZE_SIZE
    xyz = _points(1)
    np.testing.assert_allclose(_pixels(cam, xyz), _pix4d_project(xyz, _params(MAIZE_CAM), MAIZE_SIZE), atol=1e-9)


def test_writer_round_trip_and_pix4d_projection(tmp_path):
    """A photax camera in mm with every Brown term, written as .cam: read back it is the same
    camera, and Pix4D's equations on the written numbers give photax's pixels."""
    cam = ptx.FrameCamera(8.8, (0.031, -0.052), (-0.11, 0.04, -0.006, 0.0007, -0.0004),
                          pixel_size=0.0044, image_size=(4000, 3000))  # fmt: skip
    path = write_pix4d_cam(cam, tmp_path / "p_pix4d_calibrated_internal_camera_parameters.cam")
    back = read_pix4d_cam(path, (4000, 3000))
    for key in ("focal_length", "principal_point", "distortion", "pixel_size"):
        np.testing.assert_allclose(np.asarray(getattr(back, key)), np.asarray(getattr(cam, key)), rtol=0, atol=1e-15)
    xyz = _points(2)
    np.testing.assert_allclose(_pix4d_project(xyz, _params(path.read_text()), (4000, 3000)), _pixels(cam, xyz),
                               rtol=0, atol=1e-9)  # fmt: skip
    with pytest.raises(ValueError, match="square pixels"):
        write_pix4d_cam(ptx.FrameCamera(8.8, pixel_size=(0.0044, 0.0045), image_size=(40, 30)), tmp_path / "x.cam")
    with pytest.raises(ValueError, match="not finite"):
        write_pix4d_cam(ptx.FrameCamera(8.8, (np.nan, 0.0), pixel_size=0.0044, image_size=(40, 30)), tmp_path / "x.cam")
    assert not (tmp_path / "x.cam").exists()


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("Pix4D camera calibration file 0", "camera file", r"line 1: not a Pix4D camera file"),
        ("K2 -0.01750917966495743258", "K2 x", r"line 9: K2 is not a number: 'x'"),
        ("K2 -0.01750917966495743258", "K2 nan", r"line 9: K2 is not finite"),
        ("T1 0.00240851666319534747", "T1 1 2", r"line 12: expected 'T1 <number>', got 3 fields"),
        ("T1 0.00240851666319534747", "C 1.0", r"line 12: unknown term 'C'"),
        ("T2 0.00292562392135245920", "T1 0.1", r"line 13: T1 is given twice"),
        ("T2 0.00292562392135245920\n", "", r": no T2"),
        ("F 15.01175404934517487732", "F -1", r": F \(focal length, mm\) must be positive"),
        ("17.49998592000000030566x", "0x", r"line 2: the sensor size must be positive"),
        ("#Focal Length mm assuming", "#Focal", r": no '#Focal Length mm assuming a sensor width"),
        ("#Principal Point mm", "#Fisheye lens", r"line 4: a Pix4D fisheye camera"),
    ],
)
def test_malformed_cam_names_the_line(tmp_path, old, new, match):
    path = tmp_path / "c.cam"
    assert old in MAIZE_CAM
    path.write_text(MAIZE_CAM.replace(old, new))
    with pytest.raises(ValueError, match=match) as err:
        read_pix4d_cam(path, MAIZE_SIZE)
    assert str(err.value).startswith(str(path))


def test_resect_with_a_pix4d_cam_equals_the_photax_camera(tmp_path, capsys):
    """The sample camera written as a Pix4D .cam (with the run's calibrated_camera_parameters.txt
    beside it for the pixel count) resects the sample image as the photax camera file does."""
    import json
    import pathlib

    from photax.cli import main

    data = pathlib.Path(__file__).resolve().parents[1] / "data"
    cam = ptx.io.read_camera(data / "sample_camera.yaml")
    path = write_pix4d_cam(cam, tmp_path / "s_pix4d_calibrated_internal_camera_parameters.cam")
    w, h = cam.image_size
    (tmp_path / "s_calibrated_camera_parameters.txt").write_text(
        f"fileName imageWidth imageHeight\nIMG_0001.tif {w} {h}\n"
    )
    assert ptx.io.read_camera_unit(path) == "mm"
    results = []
    for camera in (data / "sample_camera.yaml", path):
        out = tmp_path / f"{camera.stem}.json"
        assert main(["resect", str(data / "sample_gcps.csv"), "--camera", str(camera), "-o", str(out)]) == 0
        results.append(json.loads(out.read_text())["images"]["IMG_0001"])
    capsys.readouterr()
    np.testing.assert_allclose(results[1]["position"], results[0]["position"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(results[1]["angles_rad"], results[0]["angles_rad"], rtol=0, atol=1e-9)
