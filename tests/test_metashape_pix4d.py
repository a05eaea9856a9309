"""Metashape calibration XML and Omega-Phi-Kappa export, Pix4D external parameters (photax.io.metashape).

The sample files are written here from the documented layouts: Metashape's calibration XML
(Metashape Professional manual, Appendix C, and the tags Metashape writes: <calibration>,
<projection>, <width>, <height>, <f>, <cx>, <cy>, <b1>, <k1>..<p2>), Metashape's "Omega Phi
Kappa" export ("# Cameras (n)", "# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11 ... r33",
tab-separated) and Pix4D's calibrated_external_camera_parameters.txt ("imageName X Y Z Omega
Phi Kappa", space-separated; Pix4D support article 202559089)."""

from __future__ import annotations

import numpy as np
import pytest

import photax as ptx
from photax.io.metashape import read_metashape_calibration, read_opk_export

CAL = """<?xml version="1.0" encoding="UTF-8"?>
<calibration>
  <projection>frame</projection>
  <width>5472</width>
  <height>3648</height>
  <f>3664.2</f>
  <cx>-12.7</cx>
  <cy>21.3</cy>
  <b1>-1.9</b1>
  <k1>-0.0123</k1>
  <k2>0.0081</k2>
  <k3>-0.0021</k3>
  <p1>0.00031</p1>
  <p2>-0.00054</p2>
  <date>2021-05-04T09:31:12Z</date>
</calibration>
"""


def _metashape_project(xyz, p):
    """Appendix C's frame model, written out here (the reference): pixel (u, v), corner origin."""
    x, y = xyz[:, 0] / xyz[:, 2], xyz[:, 1] / xyz[:, 2]
    r2 = x * x + y * y
    radial = 1 + p["k1"] * r2 + p["k2"] * r2**2 + p["k3"] * r2**3
    xd = x * radial + p["p1"] * (r2 + 2 * x * x) + 2 * p["p2"] * x * y
    yd = y * radial + p["p2"] * (r2 + 2 * y * y) + 2 * p["p1"] * x * y
    u = p["width"] / 2 + p["cx"] + xd * (p["f"] + p["b1"])
    v = p["height"] / 2 + p["cy"] + yd * p["f"]
    return np.column_stack([u, v])


def test_calibration_projects_as_metashape(tmp_path):
    path = tmp_path / "calib.xml"
    path.write_text(CAL)
    (cam,) = read_metashape_calibration(path).values()
    p = {"width": 5472, "height": 3648, "f": 3664.2, "cx": -12.7, "cy": 21.3, "b1": -1.9, "k1": -0.0123,
         "k2": 0.0081, "k3": -0.0021, "p1": 0.00031, "p2": -0.00054}  # fmt: skip
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(-0.7, 0.7, (60, 2)), np.ones(60)]) * rng.uniform(2, 50, (60, 1))
    ours = np.asarray(cam.image_to_pixel(cam.project(xyz * [1, -1, -1]))) + 0.5  # Metashape's corner origin
    np.testing.assert_allclose(ours, _metashape_project(xyz, p), rtol=0, atol=1e-9)
    # and it reads through read_interior (what --camera uses)
    same = ptx.io.read_interior(path)
    np.testing.assert_array_equal(np.asarray(same.distortion), np.asarray(cam.distortion))


def test_cameras_xml_sensors_and_adjusted_calibration(tmp_path):
    path = tmp_path / "cameras.xml"
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<document version="1.5.0"><chunk><sensors>'
        '<sensor id="0" label="FC6310 (8.8mm)" type="frame"><resolution width="5472" height="3648"/>'
        '<calibration type="frame" class="initial"><resolution width="5472" height="3648"/><f>3600</f></calibration>'
        '<calibration type="frame" class="adjusted"><resolution width="5472" height="3648"/><f>3664.2</f>'
        "<cx>-12.7</cx><cy>21.3</cy><k1>-0.0123</k1></calibration></sensor></sensors></chunk></document>\n"
    )
    cams = read_metashape_calibration(path)
    assert list(cams) == ["FC6310 (8.8mm)"]
    assert float(cams["FC6310 (8.8mm)"].focal_length) == 3664.2
    assert ptx.io.read_interior(path, "FC6310 (8.8mm)").image_size == (5472, 3648)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ("<k4>0.001</k4>", "k4 = 0.001: photax's camera has no k4"),
        ("<b2>0.4</b2>", "b2 = 0.4"),
        ("<p3>0.1</p3>", "p3 = 0.1"),
    ],
)
def test_terms_photax_cannot_hold_are_refused_by_name(tmp_path, change, words):
    path = tmp_path / "c.xml"
    path.write_text(CAL.replace("<date>", change + "<date>"))
    with pytest.raises(ValueError, match=words) as err:
        read_metashape_calibration(path)
    assert str(path) in str(err.value)


def test_other_projections_and_bad_xml_are_refused(tmp_path):
    path = tmp_path / "c.xml"
    path.write_text(CAL.replace(">frame<", ">fisheye<"))
    with pytest.raises(ValueError, match="projection 'fisheye': photax reads Metashape 'frame' cameras only"):
        read_metashape_calibration(path)
    path.write_text(CAL.replace("</f>", "</g>"))
    with pytest.raises(ValueError, match=r"c.xml, line \d+: not well-formed XML"):
        read_metashape_calibration(path)
    path.write_text(CAL.replace("3664.2", "nan"))
    with pytest.raises(ValueError, match="<f> is not finite"):
        read_metashape_calibration(path)


def _collinearity_matrix(omega, phi, kappa):
    """The classical photogrammetric rotation matrix M of omega, phi, kappa (world -> camera,
    camera x right, y up, z back; as in Wolf & Dewitt, Elements of Photogrammetry), typed
    element by element: the layout of Metashape's r11..r33 (photax.io.metashape's docstring)."""
    so, co, sp, cp, sk, ck = np.sin(omega), np.cos(omega), np.sin(phi), np.cos(phi), np.sin(kappa), np.cos(kappa)
    return np.array([
        [cp * ck, so * sp * ck + co * sk, -co * sp * ck + so * sk],
        [-cp * sk, -so * sp * sk + co * ck, co * sp * sk + so * ck],
        [sp, -so * cp, co * cp],
    ])  # fmt: skip


def _metashape_opk_line(name, xyz, opk_deg):
    r = _collinearity_matrix(*np.radians(opk_deg))
    return "\t".join(
        [name, *(f"{v:.6f}" for v in xyz), *(f"{v:.6f}" for v in opk_deg), *(f"{v:.6f}" for v in r.ravel())]
    )


def test_metashape_opk_export(tmp_path):
    rows = [("DJI_0001.JPG", [500120.25, 4100300.5, 231.75], [1.2, -0.8, 91.5]),
            ("DJI_0002.JPG", [500160.0, 4100301.0, 232.0], [-0.4, 2.1, -178.25])]  # fmt: skip
    path = tmp_path / "cameras_opk.txt"
    body = "\n".join(_metashape_opk_line(*r) for r in rows)
    path.write_text(f"# Cameras ({len(rows)})\n# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11, r12, r13, r21, r22, r23, "
                    f"r31, r32, r33\n{body}\n")  # fmt: skip
    table = read_opk_export(path)
    assert list(table) == ["DJI_0001", "DJI_0002"]
    np.testing.assert_allclose(table["DJI_0002"].position, rows[1][1])
    np.testing.assert_allclose(np.degrees(table["DJI_0002"].angles), rows[1][2], atol=1e-12)
    # read_exterior (what --exterior uses) finds it by content
    eo, crs = ptx.io.read_exterior(path, "images/DJI_0001.JPG")
    assert crs is None and np.allclose(eo.position, rows[0][1])
    # the camera the file means: its axes in world coordinates are the rows of M (y up, z back)
    m = _collinearity_matrix(*np.radians(rows[0][2]))
    np.testing.assert_allclose(np.asarray(table["DJI_0001"].rotation), m.T, rtol=0, atol=1e-12)
    # a matrix of another convention (the transpose; the same in a y-down camera frame: the
    # camera looking up) is refused, naming the line
    for change in (lambda r: r.T, lambda r: np.diag([1.0, -1.0, -1.0]) @ r):
        bad = path.read_text().splitlines()
        fields = bad[3].split("\t")
        r = change(np.array(fields[7:], dtype=float).reshape(3, 3))
        bad[3] = "\t".join(fields[:7] + [f"{v:.6f}" for v in r.ravel()])
        (tmp_path / "bad.txt").write_text("\n".join(bad) + "\n")
        with pytest.raises(ValueError, match=r"bad.txt, line 4: the rotation matrix r11..r33 does not match"):
            read_opk_export(tmp_path / "bad.txt")


def test_pix4d_external_parameters(tmp_path):
    path = tmp_path / "p_calibrated_external_camera_parameters.txt"
    path.write_text("imageName X Y Z Omega Phi Kappa\nIMG_0001.JPG 12.5 -3.25 101.0 0.5 -1.25 92.0\n"
                    "IMG_0002.JPG 22.5 -3.0 100.5 0.25 -1.0 -88.5\n")  # fmt: skip
    table = read_opk_export(path)
    np.testing.assert_allclose(np.degrees(table["IMG_0002"].angles), [0.25, -1.0, -88.5], atol=1e-12)
    assert table["IMG_0001"].convention == "omega-phi-kappa"
    table2, _ = ptx.io.read_exteriors(path)
    assert set(table2) == {"IMG_0001", "IMG_0002"}
    path.write_text("imageName X Y Z Omega Phi Kappa\nIMG_0001.JPG 12.5 -3.25 101.0 0.5 -1.25\n")
    with pytest.raises(ValueError, match=r"line 2: expected 7 values"):
        read_opk_export(path)


def test_resect_with_a_metashape_camera_equals_the_photax_camera(tmp_path, capsys):
    """The sample camera written as a Metashape calibration (pixels, cx/cy from the centre, y down,
    P1/P2 swapped) resects the sample image to the same orientation as the photax camera file."""
    import json
    import pathlib

    from photax.cli import main

    data = pathlib.Path(__file__).resolve().parents[1] / "data"
    cam = ptx.io.read_camera(data / "sample_camera.yaml")
    ps = float(np.asarray(cam.pixel_size)[0])
    (x0, y0), (k1, k2, k3, p1, p2) = np.asarray(cam.principal_point).tolist(), np.asarray(cam.distortion).tolist()
    xml = tmp_path / "sample_camera.xml"
    xml.write_text(
        f"<calibration><projection>frame</projection><width>{cam.image_size[0]}</width>"
        f"<height>{cam.image_size[1]}</height><f>{float(cam.focal_length) / ps!r}</f><cx>{x0 / ps!r}</cx>"
        f"<cy>{-y0 / ps!r}</cy><k1>{k1!r}</k1><k2>{k2!r}</k2><k3>{k3!r}</k3><p1>{p2!r}</p1><p2>{-p1!r}</p2>"
        "</calibration>\n"
    )
    results = []
    for camera in (data / "sample_camera.yaml", xml):
        out = tmp_path / f"{camera.stem}{camera.suffix}.json"
        assert main(["resect", str(data / "sample_gcps.csv"), "--camera", str(camera), "-o", str(out)]) == 0
        results.append(json.loads(out.read_text())["images"]["IMG_0001"])
    capsys.readouterr()
    np.testing.assert_allclose(results[1]["position"], results[0]["position"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(results[1]["angles_rad"], results[0]["angles_rad"], rtol=0, atol=1e-9)


def test_writers_round_trip(tmp_path):
    """A camera in mm with non-square pixels and every term, written as Metashape XML and read
    back, projects to the same pixels; orientations round-trip through both OPK layouts."""
    from photax.io.metashape import write_metashape_calibration, write_opk_export

    cam = ptx.FrameCamera(8.8, (0.011, -0.0066), (-0.02, 0.004, -0.001, 0.0003, -0.0002),
                          pixel_size=(0.0044, 0.00441), image_size=(4000, 3000))  # fmt: skip
    path = write_metashape_calibration(cam, tmp_path / "cam.xml")
    (back,) = read_metashape_calibration(path).values()
    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, (40, 2)), -np.ones(40)]) * rng.uniform(2, 9, (40, 1))
    px = lambda c: np.asarray(c.image_to_pixel(c.project(pts)))  # noqa: E731
    np.testing.assert_allclose(px(back), px(cam), rtol=0, atol=1e-9)
    eos = {f"IMG_{k}": ptx.ExteriorOrientation([5e5 + k, 4e6 - k, 200.0], rng.uniform(-0.3, 0.3, 3), "omega-phi-kappa")
           for k in range(3)}  # fmt: skip
    eos["IMG_9"] = eos["IMG_2"].to_convention("phi-omega-kappa")
    for fmt in ("metashape", "pix4d"):
        table = read_opk_export(write_opk_export(eos, tmp_path / f"{fmt}.txt", format=fmt))
        for k, eo in eos.items():
            np.testing.assert_allclose(table[k].position, eo.position, rtol=0, atol=0)
            np.testing.assert_allclose(table[k].rotation, eo.rotation, rtol=0, atol=1e-14)
