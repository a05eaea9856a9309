"""File I/O: GCP lists, camera files, JSON results.

References: the ODM file parsed independently with numpy; cameras checked
against OpenCV's projectPoints; JSON read back with the standard library.
"""

import json
import math

import cv2
import numpy as np
import pytest
from conftest import shared_file

import photax as ptx
from photax.io.camera_file import read_camera, write_camera
from photax.io.gcp import read_gcps
from photax.io.results import read_json, write_json


# --- GCP files ------------------------------------------------------------------


def test_odm_file_matches_an_independent_parse():
    path = shared_file("gcp_list_floatxy_raw.txt")
    table = read_gcps(path)
    lines = path.read_text().splitlines()
    ref = [ln.split() for ln in lines[1:] if ln.strip()]
    assert table.crs == lines[0].strip()
    assert len(table) == len(ref)
    np.testing.assert_array_equal(table.ground, np.array([r[:3] for r in ref], dtype=float))
    np.testing.assert_array_equal(table.pixel, np.array([r[3:5] for r in ref], dtype=float))
    assert table.image_xy is None and np.all(np.isnan(table.sigma)) and set(table.role) == {"control"}
    assert sorted(set(table.names)) == [f"HV{i:02d}" for i in range(1, 20)]
    one = table.select("IMG_5357.JPG")
    assert len(one) == 14 and set(one.images) == {"IMG_5357.JPG"}
    assert table.image_names[0] == "IMG_5349.JPG" and len(table.image_names) == 10
    # The file measures HV11 twice in IMG_5352 at different places: kept, and reported.
    assert table.duplicates() == ["point 'HV11' measured twice in image 'IMG_5352.JPG' (lines 51 and 52)"]


def test_odm_without_names_groups_by_ground_point(tmp_path):
    p = tmp_path / "gcp_list.txt"
    p.write_text("EPSG:32633\n1 2 3 10 20 a.jpg\n1 2 3 11 21 b.jpg\n4 5 6 12 22 a.jpg extra1 extra2\n")
    t = read_gcps(p)
    assert t.crs == "EPSG:32633"
    assert t.names.tolist() == ["gcp1", "gcp1", "extra1"]
    assert t.lines.tolist() == [2, 3, 4]


@pytest.mark.parametrize(
    "body, line, words",
    [
        ("1 2 3 10 20 a.jpg p\n1 2 3 10 a.jpg\n", 3, "got 5 columns"),
        ("1 2 3 10 a.jpg q\n", 2, "row is not a number: 'a.jpg' \\(columns are"),
        ("1 2 3 10 20 a.jpg p\n1 2 x 10 20 a.jpg q\n", 3, "not a number"),
        ("1 2 3 10 nan a.jpg p\n", 2, "not finite"),
    ],
)
def test_odm_malformed_lines_name_file_and_line(tmp_path, body, line, words):
    p = tmp_path / "bad.txt"
    p.write_text("EPSG:4326\n" + body)
    with pytest.raises(ValueError, match=rf"bad.txt, line {line}: .*{words}"):
        read_gcps(p)


def test_odm_missing_crs_line(tmp_path):
    p = tmp_path / "nocrs.txt"
    p.write_text("1 2 3 10 20 a.jpg p\n4 5 6 11 21 a.jpg q\n")
    with pytest.raises(ValueError, match="nocrs.txt, line 1: an ODM GCP list starts with its CRS"):
        read_gcps(p)


def test_csv_pixels_roles_sigma_and_case(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text(
        "Name,Image,Easting,Northing,Height,Col,Row,Sigma,Role\n"
        "# a comment\n# CRS: EPSG:32633\n"
        "A,i1,500000.5,4000000.25,100,10.5,20.25,0.5,control\n"
        "B,i1,500010,4000010,101,30,40,,CHECK\n"
    )
    t = read_gcps(p)
    np.testing.assert_array_equal(t.ground, [[500000.5, 4000000.25, 100], [500010, 4000010, 101]])
    np.testing.assert_array_equal(t.pixel, [[10.5, 20.25], [30, 40]])
    assert t.sigma[0] == 0.5 and math.isnan(t.sigma[1])
    assert t.role.tolist() == ["control", "check"] and t.check.tolist() == [False, True]
    assert t.lines.tolist() == [4, 5] and t.crs == "EPSG:32633"
    cam = ptx.FrameCamera.from_pixels(1000.0, (101, 51))
    # centre pixel (50, 25): x = c - 50, y = -(r - 25)
    np.testing.assert_allclose(t.image_plane(cam), [[-39.5, 4.75], [-20, -15]])


def test_csv_image_plane_columns(tmp_path):
    # x, y are image-plane here because the ground columns are named E, N.
    p = tmp_path / "g.csv"
    p.write_text("name,E,N,h,x,y\nA,1,2,3,-4.5,6.25\n")
    t = read_gcps(p)
    assert t.pixel is None and t.images.tolist() == [""]
    np.testing.assert_array_equal(t.ground, [[1, 2, 3]])
    np.testing.assert_array_equal(t.image_plane(None), [[-4.5, 6.25]])
    # Upper-case X, Y, Z are the ground next to lower-case x, y.
    p.write_text("name,X,Y,Z,x,y\nA,1,2,3,-4.5,6.25\n")
    t = read_gcps(p)
    np.testing.assert_array_equal(t.ground, [[1, 2, 3]])
    np.testing.assert_array_equal(t.image_xy, [[-4.5, 6.25]])


@pytest.mark.parametrize(
    "text, words",
    [
        ("name,E,N,h,col,row\nA,1,2,3,4\n", "line 2: expected 6 columns"),
        ("name,E,N,h,col,row\nA,1,2,3,4,5\nB,1,2,3,4,abc\n", "line 3: row is not a number"),
        ("name,E,N,h,col,row,role\nA,1,2,3,4,5,tie\n", "line 2: role must be"),
        ("name,E,N,h,col,row,sigma\nA,1,2,3,4,5,-1\n", "line 2: sigma must be positive"),
        ("name,E,N,h,col,row,sigm\nA,1,2,3,4,5,1\n", "line 1: unknown column 'sigm'"),
        ("name,E,N,col,row\nA,1,2,4,5\n", "line 1: no height"),
        ("name,E,N,h\nA,1,2,3\n", "line 1: give pixel columns"),
    ],
)
def test_csv_errors(tmp_path, text, words):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(ValueError, match=rf"bad.csv, {words}"):
        read_gcps(p)


def test_select_unknown_image(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("name,image,E,N,h,col,row\nA,i1,1,2,3,4,5\n")
    with pytest.raises(ValueError, match="'nope' is not in"):
        read_gcps(p).select("nope")


# --- camera files ---------------------------------------------------------------


def _opencv_pixels(ground, eo, K, dist_cv):
    flip = np.diag([1.0, -1.0, -1.0])
    r_cv = flip @ np.asarray(eo.rotation).T
    ref, _ = cv2.projectPoints(ground, cv2.Rodrigues(r_cv)[0], -r_cv @ np.asarray(eo.position), K, dist_cv)
    return ref[:, 0, :]


def test_camera_mm_file_projects_like_opencv(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(
        "focal_length: 8.8\nunit: mm\npixel_size: 0.0044\nimage_size: [4000, 3000]\n"
        "principal_point_px: [2010.0, 1490.0]\n"
        "distortion: {k1: -0.1, k2: 0.02, p1: 0.001, p2: -0.0005, convention: opencv}\n"
    )
    cam = read_camera(p)
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-50, 50, 20), rng.uniform(-40, 40, 20), rng.uniform(0, 5, 20)])
    eo = ptx.look_at([3.0, -2.0, 120.0], [0.0, 0.0, 0.0])
    ours = np.asarray(cam.image_to_pixel(ptx.project(ground, eo, cam)))
    f_px = 8.8 / 0.0044
    K = np.array([[f_px, 0, 2010.0], [0, f_px, 1490.0], [0, 0, 1]])
    # The file's p1 is OpenCV's: passed to OpenCV unchanged.
    np.testing.assert_allclose(ours, _opencv_pixels(ground, eo, K, np.array([-0.1, 0.02, 0.001, -0.0005, 0.0])), atol=1e-6)


def test_camera_pixel_shorthand_and_round_trip(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"focal_length_px": 2904.0, "image_size": [4000, 3000],
                             "principal_point_px": [2001.0, 1502.5], "distortion": [0.01, 0, 0, 1e-4, 0]}))
    cam = read_camera(p)
    ref = ptx.FrameCamera.from_pixels(2904.0, (4000, 3000), (2001.0, 1502.5), (0.01, 0, 0, 1e-4, 0))
    for a, b in ((cam.principal_point, ref.principal_point), (cam.distortion, ref.distortion)):
        np.testing.assert_array_equal(a, b)
    for suffix in (".yaml", ".json"):
        out = write_camera(cam, tmp_path / f"back{suffix}")
        back = read_camera(out)
        np.testing.assert_array_equal(back.principal_point, cam.principal_point)
        np.testing.assert_array_equal(back.distortion, cam.distortion)
        assert float(back.focal_length) == 2904.0 and back.image_size == (4000, 3000)


def test_write_camera_needs_unit_for_metric_camera(tmp_path):
    cam = ptx.FrameCamera(8.8, pixel_size=0.0044, image_size=(40, 30))
    with pytest.raises(ValueError, match="unit is required"):
        write_camera(cam, tmp_path / "c.yaml")
    back = read_camera(write_camera(cam, tmp_path / "c.yaml", unit="mm"))
    np.testing.assert_array_equal(back.pixel_size, [0.0044, 0.0044])


@pytest.mark.parametrize(
    "text, words",
    [
        ("focal_length: 8.8\nunit: mm\nfocal: 3\n", "unknown key 'focal'"),
        ("focal_length: 8.8\nunit: inch\n", "unit must be one of"),
        ("focal_length: 8.8\nunit: mm\ndistortion: {k4: 1}\n", "unknown key distortion.k4"),
        ("focal_length_px: 100\n", "needs image_size"),
        ("focal_length: -1\nunit: px\n", "focal_length must be positive"),
        ("focal_length: [1, 2]\nunit: px\n", "focal_length must be 1 finite number"),
        ("focal_length: 8.8\n  unit: : mm\n", "line 2: not valid YAML"),
    ],
)
def test_camera_errors(tmp_path, text, words):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ValueError, match=rf"bad.yaml.*{words}"):
        read_camera(p)


# --- JSON results ---------------------------------------------------------------


def test_write_json_arrays_nan_and_modules(tmp_path):
    eo = ptx.ExteriorOrientation([1.0, 2.0, 3.0], [0.1, 0.2, 0.3])
    obj = {"a": np.arange(3), "b": np.array([1.5, np.nan]), "eo": eo, "s": np.float64(2.5)}
    out = write_json(obj, tmp_path / "r.json")
    data = json.loads(out.read_text())  # the standard library is the reference reader
    assert data == {"a": [0, 1, 2], "b": [1.5, None], "s": 2.5,
                    "eo": {"position": [1.0, 2.0, 3.0], "angles": [0.1, 0.2, 0.3], "convention": "phi-omega-kappa"}}
    assert read_json(out) == data


def test_write_json_refuses_to_overwrite_an_input(tmp_path):
    src = tmp_path / "gcps.csv"
    src.write_text("keep me")
    with pytest.raises(ValueError, match="it is an input"):
        write_json({"a": 1}, src, inputs=[src])
    assert src.read_text() == "keep me"


def test_read_json_error_names_line(tmp_path):
    p = tmp_path / "x.json"
    p.write_text('{\n"a": 1,\n}\n')
    with pytest.raises(ValueError, match="x.json, line 3"):
        read_json(p)


def test_atomic_write_gives_ordinary_permissions(tmp_path):
    """Files photax writes are readable like any other (mkstemp makes them 0600)."""
    import os

    from photax.io.atomic import atomic_write

    out = tmp_path / "x.txt"
    with atomic_write(out) as fh:
        fh.write("hi")
    plain = tmp_path / "plain.txt"
    plain.write_text("hi")
    assert os.stat(out).st_mode & 0o777 == os.stat(plain).st_mode & 0o777
