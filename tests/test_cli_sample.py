"""The quick start of the README on the sample image and DEM.

References: OpenCV's ``cornerSubPix`` finds the painted survey targets in
the sample image independently of photax (they must sit where the sample's
truth projects the GCPs); the orthophoto from the true orientation
(``data/sample_truth.json``) is the reference for the one made from the
resected orientation; the README is parsed for the commands it shows.
"""

import json
import os
import pathlib
import re
import shutil
import subprocess
import sys
import warnings

import cv2
import numpy as np
import pytest
import rasterio
from conftest import ROOT, scaled

import photax as ptx
from photax.cli import main
from photax.demo import SAMPLE_BLUNDER

DATA = ROOT / "data"
README = ROOT / "README.md"
GETTING_STARTED = ROOT / "docs" / "getting-started.md"  # the quick start in full (the README shows three)
CLI_PAGE = ROOT / "docs" / "cli.md"  # the camera files

QUICK_START = [
    "photax resect data/sample_gcps.csv --camera data/sample_camera.yaml -o out/resect.json",
    "photax ortho data/sample_image.tif --dem data/sample_dem.tif --camera data/sample_camera.yaml "
    "--exterior out/resect.json -o out/ortho.tif",
    "photax rectify data/sample_image.tif --gcps data/sample_gcps.csv --order 3 -o out/rect.tif",
    "photax compare data/sample_gcps.csv --camera data/sample_camera.yaml --dem data/sample_dem.tif "
    "--image data/sample_image.tif --orders 1-5 -o out/compare",
]


def _photax_cmd():
    exe = pathlib.Path(sys.executable).with_name("photax")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "photax.cli"]


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            return src.read(1), src.transform, src.nodata, src.crs


def _common_abs_diff(path_a, path_b):
    """|a - b| over the pixels both orthophotos cover (same pixel size, aligned grids)."""
    a, ta, na, _ = _read(path_a)
    b, tb, nb, _ = _read(path_b)
    assert (ta.a, ta.e) == (tb.a, tb.e)
    dc, dr = round((tb.c - ta.c) / ta.a), round((tb.f - ta.f) / ta.e)
    assert abs((tb.c - ta.c) / ta.a - dc) < 1e-6 and abs((tb.f - ta.f) / ta.e - dr) < 1e-6  # grids aligned
    r0, c0 = max(0, dr), max(0, dc)
    r1, c1 = min(a.shape[0], b.shape[0] + dr), min(a.shape[1], b.shape[1] + dc)
    wa = a[r0:r1, c0:c1].astype(float)
    wb = b[r0 - dr : r1 - dr, c0 - dc : c1 - dc].astype(float)
    ok = (wa != na) & (wb != nb)
    return np.abs(wa - wb)[ok]


def test_readme_shows_the_quick_start_commands_and_they_name_existing_files():
    lines = [" ".join(ln.split()) for ln in GETTING_STARTED.read_text().splitlines()]
    for cmd in QUICK_START:
        assert cmd in lines, f"docs/getting-started.md does not show: {cmd}"
    shown = [" ".join(ln.split()) for ln in README.read_text().splitlines() if ln.startswith("    photax ")]
    assert shown == QUICK_START[:3], "the README's shell example: the quick start's first three commands"
    for cmd in QUICK_START:
        for arg in cmd.split():
            if arg.startswith("data/"):
                assert (ROOT / arg).is_file(), arg


def test_sample_image_shows_targets_at_the_gcps():
    # OpenCV refines each measured GCP position to the saddle of its quartered
    # target: it must land on the noise-free projection of the GCP (truth),
    # except for the planted 15 px blunder.
    image, *_ = _read(DATA / "sample_image.tif")
    camera = ptx.read_camera(DATA / "sample_camera.yaml")
    assert image.shape == tuple(camera.image_size)[::-1] and image.dtype == np.uint8
    table = ptx.read_gcps(DATA / "sample_gcps.csv")
    truth = json.loads((DATA / "sample_truth.json").read_text())["pixel_true"]
    true = np.array([truth[n] for n in table.names])
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    found = cv2.cornerSubPix(
        image.astype(np.float32), table.pixel.astype(np.float32).reshape(-1, 1, 2).copy(), (4, 4), (-1, -1), crit
    )[:, 0]
    err = np.linalg.norm(found - true, axis=1)
    blunder = table.names == SAMPLE_BLUNDER[0]
    assert err[~blunder].max() < 0.2, err
    # the blunder's target is where the truth says, 15 px from its measurement
    at_target = cv2.cornerSubPix(
        image.astype(np.float32), np.float32(np.round(true[blunder])).reshape(-1, 1, 2).copy(), (4, 4), (-1, -1), crit
    )[:, 0]
    assert np.linalg.norm(at_target - true[blunder]) < 0.2
    assert np.linalg.norm(table.pixel[blunder] - at_target) > 10
    # the targets are visible: black and white quadrants around each centre
    for c, r in np.round(true[~blunder]).astype(int):
        patch = image[r - 4 : r + 5, c - 4 : c + 5].astype(int)
        assert patch.max() - patch.min() > 150


def test_resect_then_ortho_subprocesses_match_the_true_orientation(tmp_path):
    # resect -> ortho as a user runs them (two processes), then the same
    # orthophoto from the true orientation: they must agree.
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    cmd = _photax_cmd()
    common = [
        "ortho",
        str(DATA / "sample_image.tif"),
        "--dem",
        str(DATA / "sample_dem.tif"),
        "--camera",
        str(DATA / "sample_camera.yaml"),
        "--resolution",
        "4",
        "--no-progress",
    ]
    # The reference first, in this process: its compilation lands in the
    # session's persistent cache, which the subprocess below then reads.
    # sample_truth.json holds position / angles_rad / convention: a valid --exterior.
    assert main(common + ["--exterior", str(DATA / "sample_truth.json"), "--out", str(tmp_path / "true.tif")]) == 0
    res = tmp_path / "resect.json"
    p = subprocess.run(
        cmd
        + ["resect", str(DATA / "sample_gcps.csv"), "--camera", str(DATA / "sample_camera.yaml"), "--json", str(res)],
        capture_output=True,
        text=True,
        env=env,
        timeout=scaled(600),
    )
    assert p.returncode == 0, p.stderr
    assert f"blunder: {SAMPLE_BLUNDER[0]} excluded" in p.stdout
    p = subprocess.run(
        cmd + common + ["--exterior", str(res), "--out", str(tmp_path / "resected.tif")],
        capture_output=True,
        text=True,
        env=env,
        timeout=scaled(600),
    )
    assert p.returncode == 0, p.stderr
    assert "pixels of 4 m" in p.stdout and "Traceback" not in p.stderr
    d = _common_abs_diff(tmp_path / "resected.tif", tmp_path / "true.tif")
    assert d.size > 10_000
    assert d.mean() <= 2.0, d.mean()
    # the comparison can fail: a camera 4 m off gives a visibly different orthophoto
    truth = json.loads((DATA / "sample_truth.json").read_text())
    truth["position"][0] += 4.0
    (tmp_path / "off.json").write_text(json.dumps(truth))
    assert main(common + ["--exterior", str(tmp_path / "off.json"), "--out", str(tmp_path / "off.tif")]) == 0
    assert _common_abs_diff(tmp_path / "off.tif", tmp_path / "true.tif").mean() > 2.0
    _, _, _, crs = _read(tmp_path / "resected.tif")
    assert crs.to_epsg() == 32633


def test_quick_start_runs_from_a_fresh_folder(tmp_path, monkeypatch, capsys):
    # The four README commands from a folder holding data/ and no out/
    # (coarser --resolution where the command has it, to keep it fast).
    (tmp_path / "data").mkdir()
    for f in DATA.glob("sample_*"):
        shutil.copy(f, tmp_path / "data" / f.name)
    monkeypatch.chdir(tmp_path)
    extra = {c: ["--resolution", "4", "--no-progress"] for c in ("ortho", "rectify", "compare")}
    for cmd in QUICK_START:
        argv = cmd.split()[1:]
        assert main(argv + extra.get(argv[0], [])) == 0, cmd
    printed = capsys.readouterr().out
    assert "1 of 1 image solved" in printed and "12 GCPs" in printed
    for f in ("resect.json", "ortho.tif", "rect.tif", "compare/comparison.md", "compare/rectified.png"):
        assert (tmp_path / "out" / f).is_file(), f
    assert re.search(r"wrote out/ortho.tif: \d+ x \d+ pixels of 4 m", printed)
    assert not list((tmp_path / "out").rglob("*.part"))


def test_ortho_picks_the_image_named_like_the_file(tmp_path, capsys):
    from photax.io import read_exterior

    one = json.loads((DATA / "sample_truth.json").read_text())
    other = dict(one, position=[0.0, 0.0, 100.0])
    multi = tmp_path / "multi.json"
    multi.write_text(json.dumps({"crs": "EPSG:32633", "images": {"IMG_0002": other, "IMG_0001": one}}))
    eo, crs = read_exterior(multi, "/some/where/IMG_0001.tif")
    np.testing.assert_allclose(np.asarray(eo.position), one["position"])
    assert crs == "EPSG:32633"
    with pytest.raises(ValueError, match=r"holds 2 images \['IMG_0001', 'IMG_0002'\], none named like 'x.tif'"):
        read_exterior(multi, "x.tif")
    # a single image is used whatever its name; an unsolved one is refused
    single = tmp_path / "single.json"
    single.write_text(json.dumps({"images": {"IMG_0001": one}}))
    assert read_exterior(single, "x.tif")[0].convention == one["convention"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"images": {"IMG_0001": {"status": "skipped", "message": "need at least 3"}}}))
    assert (
        main(
            [
                "ortho",
                str(DATA / "sample_image.tif"),
                "--dem",
                str(DATA / "sample_dem.tif"),
                "--interior",
                str(DATA / "sample_camera.yaml"),
                "--exterior",
                str(bad),
                "--out",
                str(tmp_path / "o.tif"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "image 'IMG_0001' was not solved (need at least 3)" in err and err.count("\n") == 1
    assert not (tmp_path / "o.tif").exists()


def _yaml_blocks_from_help(text):
    """Indented blocks after a line announcing a camera file in ``--help``."""
    blocks, current = [], None
    for line in text.splitlines():
        if line.startswith("    ") and current is not None:
            current.append(line[4:])
        elif current:
            blocks.append("\n".join(current))
            current = None
        if not line.startswith(" ") and "camera file" in line or line.startswith("or in pixels"):
            current = []
    return blocks


def _check_camera_text(tmp_path, text, name):
    path = tmp_path / name
    path.write_text(text)
    cam = ptx.read_camera(path)
    assert cam.pixel_size is not None and cam.image_size is not None and float(cam.focal_length) > 0
    return cam


def test_camera_yaml_in_help_and_readme_parse(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["resect", "--help"])
    assert exc.value.code == 0
    help_text = capsys.readouterr().out
    assert "photax.io.camera_file)" in help_text and "see photax.io.camera_file" not in help_text
    blocks = _yaml_blocks_from_help(help_text)
    readme = re.findall(r"```yaml\n(.*?)```", CLI_PAGE.read_text(), flags=re.S)
    assert len(blocks) == 2 and len(readme) == 2
    sample = ptx.read_camera(DATA / "sample_camera.yaml")
    for k, text in enumerate(blocks + readme):
        assert ("unit: mm" in text) != ("focal_length_px" in text)  # one mm file, one pixel file, in each place
        cam = _check_camera_text(tmp_path, text, f"c{k}.yaml")
        if "unit: mm" in text:  # the mm example is the sample camera
            for a in ("focal_length", "principal_point", "pixel_size", "distortion"):
                np.testing.assert_allclose(np.asarray(getattr(cam, a)), np.asarray(getattr(sample, a)))
        else:
            assert tuple(cam.image_size) == (4000, 3000)


def test_ortho_reads_a_bundle_result(tmp_path):
    """`photax ortho --exterior bundle.json`: BundleResult.to_dict's list of named images with the
    convention beside it; an adjustment that did not converge gives no orientation."""
    from photax.io import read_exterior

    one = json.loads((DATA / "sample_truth.json").read_text())
    other = dict(position=[0.0, 0.0, 100.0], angles_rad=[0.0, 0.0, 0.0])
    entry = dict(name="IMG_0001", position=one["position"], angles_rad=one["angles_rad"])
    bundle = {"converged": True, "convention": one["convention"], "images": [dict(other, name="IMG_0002"), entry]}
    path = tmp_path / "bundle.json"
    path.write_text(json.dumps(bundle))
    eo, _ = read_exterior(path, "/data/IMG_0001.tif")
    np.testing.assert_allclose(np.asarray(eo.position), one["position"])
    np.testing.assert_allclose(np.asarray(eo.angles), one["angles_rad"])
    assert eo.convention == one["convention"]
    path.write_text(json.dumps(dict(bundle, converged=False, message="50 iterations")))
    with pytest.raises(ValueError, match=r"did not converge \(50 iterations\)"):
        read_exterior(path, "IMG_0001.tif")
    path.write_text(json.dumps({"images": [entry]}))  # no convention anywhere
    with pytest.raises(ValueError, match="'convention'"):
        read_exterior(path, "IMG_0001.tif")


def test_bundle_writes_the_self_calibrated_camera(tmp_path, capsys):
    """`photax bundle BLOCK --camera-out cam.yaml`: the adjusted camera as a camera file, the same
    numbers as the JSON result, within 4 sigma of the generating camera (f = 3000 px, make_block.py);
    a block without free intrinsics, a BAL file or an input as output: exit 2, nothing written."""
    import shutil

    from photax.io import read_camera, write_camera

    folder = tmp_path / "block"
    shutil.copytree(ROOT / "data" / "block", folder, ignore=shutil.ignore_patterns("*.py"))
    meta = json.loads((folder / "block.json").read_text())
    out = tmp_path / "cam.yaml"
    assert main(["bundle", str(folder), "--camera-out", str(out), "--quiet", "--no-progress"]) == 2
    assert "no camera of the block is self-calibrated" in capsys.readouterr().err and not out.exists()
    size = meta["cameras"]["cam"]["image_size"]
    write_camera(ptx.FrameCamera.from_pixels(3030.0, size), folder / "start.yaml")  # 1 % off: to be found
    meta["cameras"] = {"cam": {"file": "start.yaml", "free": ["f"]}}
    (folder / "block.json").write_text(json.dumps(meta))
    assert main(["bundle", str(folder), "--camera-out", str(folder / "start.yaml"), "--quiet"]) == 2
    assert "refusing to write" in capsys.readouterr().err  # the camera file read is an input
    assert (
        main(
            [
                "bundle",
                str(folder),
                "--camera-out",
                str(out),
                "--json",
                str(tmp_path / "r.json"),
                "--quiet",
                "--no-progress",
            ]
        )
        == 0
    )
    cam = read_camera(out)
    result = json.loads((tmp_path / "r.json").read_text())
    f, sf = result["cameras"][0]["focal_length"], result["cameras"][0]["std"][0]
    assert cam.focal_length == pytest.approx(f, rel=1e-12)
    # this small block (8 frames, flat control) holds f only loosely: the check is against its own sigma
    assert 0 < sf < 200 and abs(f - 3000.0) < 4 * sf, (f, sf)
    assert cam.image_size == tuple(size) and float(cam.pixel_size[0]) == 1.0  # in the start file's unit, px


def test_readme_python_resection_reports_what_the_cli_reports(tmp_path, monkeypatch, capsys):
    """Issue 26: the README's Python snippet (no sigma: Pope's tau, sigma0 in px) and ``photax resect``
    (the file's sigma column: Baarda's w) reported different sigma0 and tests on data/sample_gcps.csv.
    The snippet, run as the README shows it, prints the CLI's report for the image: the same sigma0,
    test and residuals."""
    block = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)[0]
    lines = block.splitlines()
    end = next(i for i, line in enumerate(lines) if line.startswith("print(res.summary("))
    monkeypatch.chdir(ROOT)
    space = {}
    exec("\n".join(lines[: end + 1]), space)  # the README's lines up to its print of the summary
    printed = capsys.readouterr().out
    assert (
        main(
            [
                "resect",
                "data/sample_gcps.csv",
                "--camera",
                "data/sample_camera.yaml",
                "--json",
                str(tmp_path / "r.json"),
            ]
        )
        == 0
    )
    cli = capsys.readouterr().out
    data = json.loads((tmp_path / "r.json").read_text())["images"]["IMG_0001"]
    res = space["res"]
    assert res.statistic == data["statistic"] == "w"
    assert res.sigma0 == pytest.approx(data["sigma0"], rel=1e-9)
    assert printed.strip() and printed.strip() in cli
