"""File I/O: GCP lists, camera files, JSON results, and every reader's errors.

References: the ODM file parsed independently with numpy; cameras checked
against OpenCV's projectPoints; JSON read back with the standard library.
Error cases: the contract of docs/architecture.md (ValueError naming file and
line), each case one the fuzz tests (tests/test_fuzz_readers.py) found.
"""

import json
import math
import os

import cv2
import numpy as np
import pytest
from conftest import shared_file

import photax as ptx
from photax.camera import opencv_extrinsics
from photax.io.bal import read_bal
from photax.io.block import read_block
from photax.io.camera_file import read_camera, write_camera
from photax.io.gcp import read_gcps
from photax.io.orthority import read_orthority_crs, read_orthority_exterior, read_orthority_interior
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
    r_cv, t_cv = opencv_extrinsics(eo.rotation, eo.position)
    ref, _ = cv2.projectPoints(ground, cv2.Rodrigues(r_cv)[0], t_cv, K, dist_cv)
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
    np.testing.assert_allclose(
        ours, _opencv_pixels(ground, eo, K, np.array([-0.1, 0.02, 0.001, -0.0005, 0.0])), atol=1e-6
    )


def test_camera_pixel_shorthand_and_round_trip(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(
        json.dumps(
            {
                "focal_length_px": 2904.0,
                "image_size": [4000, 3000],
                "principal_point_px": [2001.0, 1502.5],
                "distortion": [0.01, 0, 0, 1e-4, 0],
            }
        )
    )
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
    assert data == {
        "a": [0, 1, 2],
        "b": [1.5, None],
        "s": 2.5,
        "eo": {"position": [1.0, 2.0, 3.0], "angles": [0.1, 0.2, 0.3], "convention": "phi-omega-kappa"},
    }
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


# --- every reader: folders, unreadable and binary files, insane values ------------
# (what tests/test_fuzz_readers.py found; each case failed before the fix)

READERS = {
    "gcps.csv": read_gcps, "camera.yaml": read_camera, "camera.json": read_camera, "result.json": read_json,
    "int_param.yaml": read_orthority_interior, "xyz_opk.csv": read_orthority_exterior, "problem.txt": read_bal,
    "problem.txt.bz2": read_bal,
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_given_a_folder_names_it(tmp_path, name):
    folder = tmp_path / name
    folder.mkdir()
    with pytest.raises(ValueError, match=rf"^{folder}: is a folder, expected a"):
        READERS[name](folder)


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_given_an_unreadable_file_names_it(tmp_path, name, monkeypatch):
    path = tmp_path / name
    path.write_text("x")
    # Simulated: chmod 000 does not stop root, who runs these tests in CI.
    real_open = os.open

    def denied(file, *args, **kwargs):
        if os.fspath(file) == str(path):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(os, "open", denied)
    with pytest.raises(ValueError, match=rf"^{path}: cannot read the .* \(Permission denied\)$"):
        READERS[name](path)


@pytest.mark.parametrize("name", sorted(READERS))
def test_reader_given_a_missing_file_names_it(tmp_path, name):
    with pytest.raises(FileNotFoundError, match=rf"{tmp_path / name}: no such"):
        READERS[name](tmp_path / name)


@pytest.mark.parametrize("name", ["gcps.csv", "camera.yaml", "camera.json", "result.json", "xyz_opk.csv",
                                  "int_param.yaml"])  # fmt: skip
def test_binary_file_is_an_error_with_its_line(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"a,b\n\n\x89PNG\x00\xff")
    with pytest.raises(ValueError, match=rf"^{path}, line 3: not UTF-8 text"):
        READERS[name](path)
    path.write_bytes(b"a\nb\x00c\n")
    with pytest.raises(ValueError, match=rf"^{path}, line 2: a NUL byte"):
        READERS[name](path)


def test_block_given_a_file_or_missing_folder(tmp_path):
    f = tmp_path / "block.json"
    f.write_text("{}")
    with pytest.raises(ValueError, match="a block is a folder"):
        read_block(f)
    with pytest.raises(FileNotFoundError, match="no such block folder"):
        read_block(tmp_path / "nope")


@pytest.mark.parametrize(
    "text, words",
    [
        # Was silently accepted: a negative or zero pixel size.
        (
            "focal_length: 8.8\nunit: mm\npixel_size: -0.0044\nimage_size: [40, 30]\n",
            "line 3: pixel_size must be positive",
        ),
        (
            "focal_length: 8.8\nunit: mm\npixel_size: [0.0044, 0]\nimage_size: [40, 30]\n",
            "line 3: pixel_size must be positive",
        ),
        # Was: the second value silently won.
        (
            "focal_length: 8.8\nunit: mm\nfocal_length: 88\n",
            "line 3: not valid YAML: a key given twice \\(first on line 1\\)",
        ),
        # Was a TypeError (sorting int and str keys).
        ("focal_length: 8.8\nunit: mm\n1: 2\n", "line 3: unknown key 1"),
        # Was: True read as 1.0.
        ("focal_length: true\nunit: px\n", "line 1: focal_length must be numbers"),
        # Was an OverflowError.
        ("focal_length: " + "9" * 400 + "\nunit: px\n", "line 1: focal_length must be numbers"),
        ("focal_length_px: 0\nimage_size: [4, 3]\n", "line 1: focal_length_px must be positive"),
        ("focal_length: 8.8\nunit: mm\nimage_size: [0, 30]\n", "line 3: image_size must be"),
        # Was a bare ValueError from datetime, not naming the file.
        ("focal_length: 8.8\nunit: mm\nname: 2024-13-45\nfocal: 1\n", "line 4: unknown key 'focal'"),
        ("- 1\n- 2\n", "not a photax camera file \\(YAML mapping expected"),
        ("focal_length: 8.8\nunit: mm\n\x00", "line 3: a NUL byte"),
    ],
)
def test_camera_file_insane_values(tmp_path, text, words):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ValueError, match=rf"^{p}, {words}" if "line" in words else rf"^{p}: {words}"):
        read_camera(p)


@pytest.mark.parametrize(
    "text, words",
    [
        ('{"focal_length": NaN, "unit": "px"}', "line 1: not valid JSON: NaN is not a JSON number"),
        ('{"focal_length": 1e999,\n "unit": "px"}', "line 1: not valid JSON: 1e999 is out of range"),
        ('{"focal_length": 8,\n "unit": "px",\n "unit": "mm"}', "line 2: not valid JSON: a key given twice"),
    ],
)
def test_camera_json_strict(tmp_path, text, words):
    p = tmp_path / "bad.json"
    p.write_text(text)
    with pytest.raises(ValueError, match=rf"^{p}, {words}"):
        read_camera(p)
    with pytest.raises(ValueError, match=rf"^{p}, {words}"):
        read_json(p)


def test_gcp_name_reused_for_another_point(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("# crs: EPSG:32633\nname,image,E,N,h,col,row\nA,i1,1,2,3,4,5\nA,i2,1,2,3,6,7\nA,i3,1,2,4,6,7\n")
    with pytest.raises(ValueError, match=rf"^{p}, line 5: point 'A' has ground coordinates .* on line 3"):
        read_gcps(p)
    p.write_text("name,image,E,N,h,col,row,role\nA,i1,1,2,3,4,5,control\nA,i2,1,2,3,6,7,check\n")
    with pytest.raises(
        ValueError, match=rf"^{p}, line 3: point 'A' is a check point here but a control point on line 2"
    ):
        read_gcps(p)


def test_gcp_header_errors_name_the_header_line(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("# comment\n# crs: EPSG:32633\nname,E,N,h,col,rw\nA,1,2,3,4,5\n")
    with pytest.raises(ValueError, match=rf"^{p}, line 3: unknown column 'rw'"):
        read_gcps(p)


@pytest.mark.parametrize(
    "text, words",
    [
        ("type: pinhole\nim_size: [400, 300]\nfocal_len: -0.8\n", "line 3: camera None: focal_len must be positive"),
        (
            "type: pinhole\nim_size: [400, 300]\nfocal_len: 0.8\nsensor_size: [-1, 1]\n",
            "line 4: .*sensor_size must be positive",
        ),
        # Was read as [6, 4]: a string iterated character by character.
        ("type: pinhole\nim_size: '64'\nfocal_len: 0.8\n", "line 2: .*im_size must be 2 finite numbers"),
        ("type: pinhole\nim_size: [1e999, 3]\nfocal_len: 0.8\n", "line 2: .*im_size must be 2 finite numbers"),
        ("type: pinhole\nim_size: [400.5, 300]\nfocal_len: 0.8\n", "line 2: .*im_size must be"),
        ("cam:\n  type: pinhole\n  im_size: [400, 300]\n", "line 1: camera 'cam': missing parameter 'focal_len'"),
    ],
)
def test_orthority_interior_insane_values(tmp_path, text, words):
    p = tmp_path / "int.yaml"
    p.write_text(text)
    with pytest.raises(ValueError, match=rf"^{p}, {words}"):
        read_orthority_interior(p)


def test_orthority_single_unnamed_camera(tmp_path):
    """The single-camera form was rejected before the single-camera branch was reached."""
    p = tmp_path / "int.yaml"
    p.write_text("type: pinhole\nim_size: [400, 300]\nfocal_len: 0.8\n")
    cams = read_orthority_interior(p)
    # orthority: focal_len normalised by the width, so f = 0.8 * 400 px.
    assert list(cams) == [None] and float(cams[None].focal_length) == pytest.approx(320.0)


def test_read_interior_detects_the_format(tmp_path):
    """photax.io.read_interior gives what the format's own reader gives."""
    ortho1 = tmp_path / "one.yaml"
    ortho1.write_text("type: pinhole\nim_size: [400, 300]\nfocal_len: 0.8\n")
    assert float(ptx.io.read_interior(ortho1).focal_length) == pytest.approx(320.0)
    ortho2 = tmp_path / "two.yaml"
    ortho2.write_text(
        "a:\n  type: pinhole\n  im_size: [400, 300]\n  focal_len: 0.8\n"
        "b:\n  type: pinhole\n  im_size: [400, 300]\n  focal_len: 0.5\n"
    )
    assert ptx.io.read_interior(ortho2, "b") == read_orthority_interior(ortho2)["b"]
    with pytest.raises(ValueError, match=rf"^{ortho2}: holds 2 cameras: name one .*\['a', 'b'\]"):
        ptx.io.read_interior(ortho2)
    cam = tmp_path / "cam.yaml"
    cam.write_text("focal_length_px: 2904.0\nimage_size: [4000, 3000]\n")
    assert ptx.io.read_interior(cam) == read_camera(cam)
    assert ptx.io.read_camera_unit(cam) == "px"
    cam.write_text("focal_length: 8.8\nunit: mm\npixel_size: 0.0044\nimage_size: [4000, 3000]\n")
    assert ptx.io.read_camera_unit(cam) == "mm"
    cam.write_text("focal_length: 8.8\nunit: mm\nfocal_length: 9\n")
    with pytest.raises(ValueError, match=rf"^{cam}, line 3: "):  # the readers' contract: file and line
        ptx.io.read_interior(cam)


def test_orthority_exterior_and_crs_errors(tmp_path):
    p = tmp_path / "ext.csv"
    p.write_text("filename,x,y,z,omega,phi,kappa\n,1,2,3,0,0,0\n")
    with pytest.raises(ValueError, match=rf"^{p}, line 2: empty file name"):
        read_orthority_exterior(p)
    prj = tmp_path / "ext.prj"
    prj.mkdir()
    assert read_orthority_crs(p) is None  # a folder is not a .prj beside the file


def test_bal_bad_bz2_and_problem_errors_name_the_file(tmp_path):
    p = tmp_path / "x.txt.bz2"
    p.write_bytes(b"BZh91AY&SY not really")
    with pytest.raises(ValueError, match=rf"^{p}: not a readable bzip2 file"):
        read_bal(p)
    # A point seen by one camera only: BundleProblem's error, now naming the file.
    q = tmp_path / "one.txt"
    q.write_text("1 1 1\n0 0 1 2\n" + "0\n0\n0\n0\n0\n0\n500\n0\n0\n" + "0\n0\n-10\n")
    with pytest.raises(ValueError, match=rf"^{q}: point 0 \(tie\) is observed on 1 image"):
        read_bal(q)


def test_raster_readers_folder_and_damaged_file(tmp_path):
    from photax.io.raster import read_dem, read_geotiff, write_geotiff

    for read in (read_geotiff, read_dem):
        with pytest.raises(ValueError, match=rf"^{tmp_path}: is a folder, expected a raster file"):
            read(tmp_path)
    good = write_geotiff(tmp_path / "dem.tif", np.zeros((40, 40), np.float32), (1, 0, 500, 0, -1, 1000), compress=None)
    raw = good.read_bytes()
    bad = tmp_path / "cut.tif"
    bad.write_bytes(raw[: len(raw) // 2])  # header intact, pixels cut: GDAL opens it, then fails to read
    for read in (read_geotiff, read_dem):
        with pytest.raises(ValueError, match=rf"^{bad}: "):
            read(bad)


def test_line_numbers_count_newlines_only(tmp_path):
    """str.splitlines also breaks at \\x0b, \\x0c, \\x1c, U+2028: line numbers drifted."""
    p = tmp_path / "g.txt"
    p.write_text("EPSG:32633\n1 2 3 4 5 a.jpg\x0cp\n1 2 3 4 a.jpg q\n")
    with pytest.raises(ValueError, match=rf"^{p}, line 3: row is not a number: 'a.jpg'"):
        read_gcps(p)


def test_orthority_exterior_header_only(tmp_path):
    p = tmp_path / "ext.csv"
    p.write_text("filename,x,y,z,omega,phi,kappa\n")
    with pytest.raises(ValueError, match=rf"^{p}: no exterior orientations"):
        read_orthority_exterior(p)


def test_camera_numbers_yaml_reads_as_text(tmp_path):
    """PyYAML (YAML 1.1) reads 1e-5 without a dot as a string: still a number here."""
    p = tmp_path / "c.yaml"
    p.write_text("focal_length: 35e-3\nunit: m\npixel_size: [1e-5, 1.1e-5]\nimage_size: [40, 30]\n")
    cam = read_camera(p)
    assert float(cam.focal_length) == 0.035
    np.testing.assert_array_equal(np.asarray(cam.pixel_size), [1e-5, 1.1e-5])


def _same_problem(a, b):
    np.testing.assert_allclose(b.obs_xy, a.obs_xy, rtol=0, atol=1e-9 * np.abs(a.obs_xy).max())
    np.testing.assert_allclose(b.obs_sigma, a.obs_sigma, rtol=1e-12)
    np.testing.assert_array_equal(b.obs_image, a.obs_image)
    np.testing.assert_array_equal(b.obs_point, a.obs_point)
    np.testing.assert_array_equal(b.points, a.points)  # NaN where unknown, 17 digits elsewhere
    np.testing.assert_array_equal(b.roles, a.roles)
    np.testing.assert_array_equal(b.point_sigma, a.point_sigma)
    np.testing.assert_array_equal(b.free_intrinsics, a.free_intrinsics)
    np.testing.assert_array_equal(b.fixed_exterior, a.fixed_exterior)
    np.testing.assert_array_equal(np.asarray(b.exterior.position), np.asarray(a.exterior.position))
    np.testing.assert_array_equal(np.asarray(b.exterior.angles), np.asarray(a.exterior.angles))
    assert b.exterior.convention == a.exterior.convention and b.image_names == a.image_names
    assert b.point_names == a.point_names
    for ca, cb in zip(a.cameras, b.cameras, strict=True):
        for k in ("focal_length", "principal_point", "distortion", "pixel_size"):
            np.testing.assert_array_equal(np.asarray(getattr(cb, k)), np.asarray(getattr(ca, k)))
        assert cb.image_size == ca.image_size


def test_block_round_trip(tmp_path):
    """write_block then read_block gives the problem back: the sample block (pixel camera), then one
    in mm with control sigmas, a check point, an unknown tie point, a fixed image and free intrinsics."""
    from conftest import ROOT

    from photax.io import write_block

    a = read_block(ROOT / "data" / "block")
    _same_problem(a, read_block(write_block(a, tmp_path / "b1")))
    cam = ptx.FrameCamera(24.0, (0.01, -0.02), pixel_size=0.006, image_size=(4000, 3000), distortion=(1e-4, 0, 0, 0, 0))
    roles = np.array(a.roles)
    seen = np.bincount(a.obs_point, minlength=a.n_points)
    roles[np.flatnonzero((roles == "control") & (seen >= 2))[-1]] = "check"
    pts = a.points.copy()
    pts[np.flatnonzero(roles == "tie")[0]] = np.nan
    xy = np.asarray(a.cameras[0].image_to_pixel(a.obs_xy))  # the same pixels, in a mm camera
    b = a.replace(
        cameras=[cam],
        obs_xy=np.asarray(cam.pixel_to_image(xy)),
        obs_sigma=0.003,
        roles=roles,
        points=pts,
        point_sigma=np.where(roles == "control", 0.05, 0.0),
        free_intrinsics=("f", "k1"),
        fixed_exterior=np.arange(a.n_images) == 2,
    )
    out = write_block(b, tmp_path / "b2", units="mm")
    _same_problem(b, read_block(out))
    assert read_camera(out / "cameras" / "cam.yaml").focal_length == 24.0
    with pytest.raises(ValueError, match="not an empty folder"):
        write_block(b, out, units="mm")
    with pytest.raises(ValueError, match="unit is required"):
        write_block(b, tmp_path / "b3")
    assert not (tmp_path / "b3").exists() and not list(tmp_path.glob(".b3.*"))  # nothing left behind
    with pytest.raises(ValueError, match="x and y sigmas differ"):
        write_block(b.replace(obs_sigma=np.tile([0.003, 0.004], (b.n_observations, 1))), tmp_path / "b4", units="mm")
