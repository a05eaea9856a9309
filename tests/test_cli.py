"""The ``photax`` command end to end: resect and demo.

References: the synthetic sample's known truth (data/sample_truth.json),
OpenCV's solvePnP on the real ODM targets, OpenCV's projectPoints for the
sample data itself.
"""

import json
import os
import pathlib
import subprocess
import sys

import cv2
import numpy as np
from conftest import ROOT, scaled, shared_file

import photax as ptx
import photax.demo
from photax.camera import from_opencv_extrinsics, opencv_extrinsics
from photax.cli import main
from photax.demo import SAMPLE_BLUNDER, write_sample

DATA = ROOT / "data"
GCPS, CAMERA, TRUTH = DATA / "sample_gcps.csv", DATA / "sample_camera.yaml", DATA / "sample_truth.json"


def _opencv_pose(eo):
    r_cv, t_cv = opencv_extrinsics(eo.rotation, eo.position)  # OpenCV camera: y down, z forward
    return cv2.Rodrigues(r_cv)[0], t_cv


def test_sample_files_are_current_and_consistent_with_truth(tmp_path):
    # The committed files are what data/make_sample.py writes ...
    fresh = write_sample(tmp_path)
    for key, path in (("gcps", GCPS), ("camera", CAMERA), ("truth", TRUTH)):
        assert fresh[key].read_text() == path.read_text(), f"{path.name} is stale: run python data/make_sample.py"
    for key in ("image", "dem"):  # rasters: the same pixels and georeference (bytes may differ between GDALs)
        new, old = ptx.io.read_geotiff(fresh[key]), ptx.io.read_geotiff(DATA / f"sample_{key}.tif")
        assert np.abs(new[0].astype(float) - old[0].astype(float)).max() <= (1 if key == "image" else 0), (
            f"sample_{key}.tif is stale: run python data/make_sample.py"
        )
        assert new[1]["transform"] == old[1]["transform"] and new[1]["crs"] == old[1]["crs"]
        assert (DATA / f"sample_{key}.tif").stat().st_size <= 2 * 1024**2
    # ... and the measurements are the truth projected by OpenCV, plus 0.3 px noise and one blunder.
    truth = json.loads(TRUTH.read_text())
    table = ptx.read_gcps(GCPS)
    eo = ptx.ExteriorOrientation(truth["position"], truth["angles_rad"], truth["convention"])
    rvec, tvec = _opencv_pose(eo)
    ps = 0.0176  # mm per pixel; 1000 x 750 pixels
    f_px = 8.8 / ps
    K = np.array([[f_px, 0, 499.5 + 0.011 / ps], [0, f_px, 374.5 + 0.0066 / ps], [0, 0, 1]])
    ref, _ = cv2.projectPoints(table.ground, rvec, tvec, K, np.array([-0.02, 0.004, 0.0, 0.0, 0.0]))
    err = table.pixel - ref[:, 0, :]
    blunder = table.names == SAMPLE_BLUNDER[0]
    np.testing.assert_allclose(err[blunder][0], SAMPLE_BLUNDER[1], atol=1.5)
    assert 0.15 < np.std(err[~blunder]) < 0.45
    assert table.role.tolist().count("check") == 4


def test_resect_sample_recovers_truth_and_flags_the_blunder(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["resect", str(GCPS), "--camera", str(CAMERA), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"blunder: {SAMPLE_BLUNDER[0]} excluded" in text and "check points: rmse" in text
    r = json.loads(out.read_text())["images"]["IMG_0001"]
    truth = json.loads(TRUTH.read_text())
    est = np.array(r["position"] + r["angles_rad"])
    ref = np.array(truth["position"] + truth["angles_rad"])
    assert np.all(np.abs(est - ref) < 4 * np.array(r["std"]))
    assert [p["name"] for p in r["points"] if p["outlier"]] == [SAMPLE_BLUNDER[0]]
    assert sum(p["role"] == "check" for p in r["points"]) == 4


def test_resect_all_images_skips_those_with_too_few_points(tmp_path, capsys):
    # An image that cannot be solved makes the exit status 1; the JSON is
    # still written, with a status per image.
    gcps = tmp_path / "two.csv"
    lines = GCPS.read_text().splitlines()
    gcps.write_text(
        "\n".join(lines + [ln.replace("IMG_0001", "IMG_0002") for ln in lines if ln.startswith(("P01,", "P02,"))])
        + "\n"
    )
    out = tmp_path / "r.json"
    assert main(["resect", str(gcps), "--camera", str(CAMERA), "--json", str(out)]) == 1
    text = capsys.readouterr().out
    assert "== IMG_0001: 16 points (12 control, 4 check) ==" in text
    assert "== IMG_0002: NOT SOLVED, skipped (2 points (2 control, 0 check)): need at least 3 control points" in text
    assert "1 of 2 images solved, 1 not" in text
    images = json.loads(out.read_text())["images"]
    assert images["IMG_0001"]["status"] == "solved" and images["IMG_0002"]["status"] == "skipped"


def test_resect_odm_image_matches_opencv_solvepnp(tmp_path, capsys):
    gcp_file = shared_file("gcp_list_floatxy_raw.txt")
    cam_file = tmp_path / "canon.yaml"
    cam_file.write_text("focal_length_px: 2904.0\nimage_size: [4000, 3000]\n")
    out = tmp_path / "r.json"
    rc = main(
        [
            "resect",
            str(gcp_file),
            "--camera",
            str(cam_file),
            "--image",
            "IMG_5357.JPG",
            "--convention",
            "omega-phi-kappa",
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    assert "== IMG_5357.JPG: 14 points (14 control, 0 check) ==" in capsys.readouterr().out
    r = json.loads(out.read_text())["images"]["IMG_5357.JPG"]
    assert r["convention"] == "omega-phi-kappa" and not any(p["outlier"] for p in r["points"])
    # OpenCV's iterative PnP minimises the same reprojection error; ODM pixels
    # and OpenCV pixels both put integers at pixel centres.
    t = ptx.read_gcps(gcp_file).select("IMG_5357.JPG")
    origin = t.ground.mean(0)
    K = np.array([[2904.0, 0, 1999.5], [0, 2904.0, 1499.5], [0, 0, 1]])
    _, rvec, tvec = cv2.solvePnP(t.ground - origin, t.pixel, K, None, flags=cv2.SOLVEPNP_ITERATIVE)
    R = cv2.Rodrigues(rvec)[0]
    world_from_camera, position = from_opencv_extrinsics(R, tvec)
    np.testing.assert_allclose(r["position"], position + origin, atol=2e-3)
    np.testing.assert_allclose(
        np.asarray(ptx.rotation_matrix(np.array(r["angles_rad"]), "omega-phi-kappa")), world_from_camera, atol=1e-6
    )


def test_malformed_gcp_line_exit_2_with_line_number(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    lines = GCPS.read_text().splitlines()
    lines[4] = lines[4].replace(",0.3,", ",0.3,extra,")
    bad.write_text("\n".join(lines) + "\n")
    assert main(["resect", str(bad), "--camera", str(CAMERA)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("photax resect: error:") and "bad.csv, line 5: expected 9 columns" in err
    assert "\n" not in err


def test_json_refuses_to_overwrite_the_gcp_input(tmp_path, capsys):
    gcps = tmp_path / "g.csv"
    gcps.write_text(GCPS.read_text())
    assert main(["resect", str(gcps), "--camera", str(CAMERA), "--json", str(gcps)]) == 2
    assert "refusing to write" in capsys.readouterr().err
    assert gcps.read_text() == GCPS.read_text()


def test_unknown_image_and_bad_camera_exit_2(tmp_path, capsys):
    assert main(["resect", str(GCPS), "--camera", str(CAMERA), "--image", "nope"]) == 2
    assert "'nope' is not in" in capsys.readouterr().err
    cam = tmp_path / "c.yaml"
    cam.write_text("focal_length: 8.8\nunit: mm\nfocus: 1\n")
    assert main(["resect", str(GCPS), "--camera", str(cam)]) == 2
    assert "unknown key 'focus'" in capsys.readouterr().err


def test_demo_writes_report_and_refuses_the_data_folder(tmp_path, capsys, monkeypatch):
    # The framework and the resection section; other sections have their own tests.
    monkeypatch.setattr(photax.demo, "SECTIONS", [photax.demo.resection_section])
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert f"report: {out / 'report.md'}" in printed and "demo: 100%" in captured.err  # its progress bar
    report = (out / "report.md").read_text()
    assert f"the planted blunder on {SAMPLE_BLUNDER[0]} was found" in report
    png = out / "resection_residuals.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["demo", "--out", str(DATA / "out")]) == 2
    assert "choose a folder of your own" in capsys.readouterr().err
    assert not (DATA / "out").exists()


def test_console_script_subprocess(tmp_path):
    exe = pathlib.Path(sys.executable).with_name("photax")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "photax.cli"]
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    proc = subprocess.run(
        cmd + ["resect", str(GCPS), "--camera", str(CAMERA), "--no-robust"],
        capture_output=True,
        text=True,
        env=env,
        timeout=scaled(600),
    )
    assert proc.returncode == 0, proc.stderr
    assert "Space resection: converged" in proc.stdout and "OUTLIER" not in proc.stdout
    bad = tmp_path / "bad.txt"
    bad.write_text("EPSG:32633\n1 2 3 4 5 a.jpg p\n1 2 3 4 a.jpg\n")
    proc = subprocess.run(cmd + ["resect", str(bad), "--camera", str(CAMERA)], capture_output=True, text=True, env=env)
    assert proc.returncode == 2 and "bad.txt, line 3" in proc.stderr


def test_transfer_and_ties_read_their_inputs_and_refuse_bad_ones(tmp_path, capsys):
    """The shared input prologue of ``photax transfer`` / ``photax ties``
    (cli/_common.read_oriented_images): a missing orientation file and an
    output that would overwrite an input are one-line errors, exit 2."""
    data = ROOT / "data"
    common = [
        str(data / "sample_image.tif"),
        "--camera",
        str(data / "sample_camera.yaml"),
        "--dem",
        str(data / "sample_dem.tif"),
        "--gcps",
        str(data / "sample_gcps.csv"),
    ]
    for command in ("transfer", "ties"):
        assert main([command, *common, "--exterior", str(tmp_path / "missing.json"), "-o", str(tmp_path / "o")]) == 2
        assert "missing.json" in capsys.readouterr().err
        assert (
            main([command, *common, "--exterior", str(data / "sample_gcps.csv"), "-o", str(data / "sample_dem.tif")])
            == 2
        )
        assert "refusing to write" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
