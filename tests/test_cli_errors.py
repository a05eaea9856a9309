"""Every command: exit status, one-line errors, no overwritten input, units.

References: the exit-status contract of the README (0 / 1 / 2 / 130), GDAL's
sidecar naming (``x.prj``, ``x.tif.aux.xml``, ``x.tif.ovr``, ``x.tfw``,
``x.tif.msk``), rasterio's CRS units.
"""

import json
import os
import shutil

import numpy as np
import pytest
from conftest import ROOT, scaled

import photax.cli._common as common
import photax.rectification._files
import photax.resection
from photax.cli import main
from photax.io.atomic import check_output_path
from photax.io.raster import crs_unit

DATA = ROOT / "data"
GCPS, CAMERA = DATA / "sample_gcps.csv", DATA / "sample_camera.yaml"
IMAGE, DEM, TRUTH = DATA / "sample_image.tif", DATA / "sample_dem.tif", DATA / "sample_truth.json"


def _one_line_error(capsys, command):
    err = capsys.readouterr().err
    assert err.startswith(f"photax {command}: error:"), err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def _argv(command, tmp_path, **swap):
    """A valid command line of each command, with some inputs swapped."""
    f = {"gcps": GCPS, "camera": CAMERA, "image": IMAGE, "dem": DEM, "exterior": TRUTH, **swap}
    f = {k: str(v) for k, v in f.items()}
    out = str(tmp_path / "out.tif")
    return {
        "resect": ["resect", f["gcps"], "--camera", f["camera"], "--json", str(tmp_path / "r.json")],
        "ortho": [
            "ortho",
            f["image"],
            "--dem",
            f["dem"],
            "--camera",
            f["camera"],
            "--exterior",
            f["exterior"],
            "--out",
            out,
        ],
        "rectify": ["rectify", f["image"], "--gcps", f["gcps"], "--out", out],
        "compare": [
            "compare",
            f["gcps"],
            "--camera",
            f["camera"],
            "--dem",
            f["dem"],
            "--image",
            f["image"],
            "--out",
            str(tmp_path / "cmp"),
        ],
    }[command]


CASES = [
    ("resect", "gcps"),
    ("resect", "camera"),
    ("ortho", "image"),
    ("ortho", "dem"),
    ("ortho", "camera"),
    ("ortho", "exterior"),
    ("rectify", "image"),
    ("rectify", "gcps"),
    ("compare", "gcps"),
    ("compare", "camera"),
    ("compare", "dem"),
    ("compare", "image"),
]


@pytest.mark.parametrize("command,which", CASES)
def test_a_folder_where_a_file_is_expected(tmp_path, capsys, command, which):
    folder = tmp_path / "folder.csv"
    folder.mkdir()
    assert main(_argv(command, tmp_path, **{which: folder})) == 2
    assert "is a folder, expected a file" in _one_line_error(capsys, command)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.csv"]  # nothing written


@pytest.mark.parametrize("command,which", CASES[:4])
def test_an_unreadable_file(tmp_path, capsys, monkeypatch, command, which):
    # The tests run as root, who reads anything: a chmod 000 file proves
    # nothing here, so open() is made to fail as it does for a user (the
    # real case is test_unreadable_file_as_a_user, skipped under root).
    target = tmp_path / "locked"
    shutil.copy({"gcps": GCPS, "camera": CAMERA, "image": IMAGE, "dem": DEM}[which], target)
    real_open = open

    def deny(path, *a, **k):
        if os.fspath(path) == str(target):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *a, **k)

    monkeypatch.setattr(common, "open", deny, raising=False)
    assert main(_argv(command, tmp_path, **{which: target})) == 2
    assert "permission denied" in _one_line_error(capsys, command)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root can read a chmod 000 file")
def test_unreadable_file_as_a_user(tmp_path, capsys):
    target = tmp_path / "locked.csv"
    shutil.copy(GCPS, target)
    target.chmod(0)
    assert main(["resect", str(target), "--camera", str(CAMERA)]) == 2
    assert "permission denied" in _one_line_error(capsys, "resect")


def test_an_oserror_deep_inside_is_one_line(tmp_path, capsys, monkeypatch):
    def boom(*a, **k):
        raise IsADirectoryError(21, "Is a directory", "/x/y")

    monkeypatch.setattr(photax.resection, "resect", boom)
    assert main(["resect", str(GCPS), "--camera", str(CAMERA), "--no-progress"]) == 2  # the message, not a bar
    assert "/x/y: Is a directory" in _one_line_error(capsys, "resect")


def test_bundle_inputs(tmp_path, capsys):
    folder = tmp_path / "bal"
    folder.mkdir()
    assert main(["bundle", str(folder), "--format", "bal"]) == 2
    assert "is a folder, expected a file" in _one_line_error(capsys, "bundle")
    assert main(["bundle", str(GCPS), "--format", "block"]) == 2
    assert "is a file, expected a folder" in _one_line_error(capsys, "bundle")
    assert main(["bundle", str(folder), "--format", "block"]) == 2  # no block.json in it
    assert "block.json: no such file" in _one_line_error(capsys, "bundle")
    # a result may not replace a file of the block
    block = tmp_path / "block"
    shutil.copytree(DATA / "block", block)
    before = (block / "points.csv").read_bytes()
    assert main(["bundle", str(block), "--json", str(block / "points.csv")]) == 2
    assert "refusing to write" in _one_line_error(capsys, "bundle")
    assert (block / "points.csv").read_bytes() == before


def test_ctrl_c_exits_130_without_output(tmp_path, capsys, monkeypatch):
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(photax.resection, "resect", interrupted)
    out = tmp_path / "r.json"
    assert main(["resect", str(GCPS), "--camera", str(CAMERA), "-o", str(out), "--no-progress"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err and err.strip().count("\n") == 0
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_during_ortho_leaves_no_partial_file(tmp_path, capsys, monkeypatch):
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(photax.rectification._files, "_resample_tile", interrupted)
    argv = _argv("ortho", tmp_path) + [
        "--resolution",
        "4",
        "--no-progress",
    ]  # as in test_cli_sample: shared compilation
    assert main(argv) == 130
    assert "interrupted" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # neither out.tif nor a .part file


SIDECARS = [
    "{stem}.prj",
    "{name}.aux.xml",
    "{name}.ovr",
    "{stem}.tfw",
    "{stem}.tifw",
    "{stem}.wld",
    "{name}.msk",
    "{stem}.TFW",
]


@pytest.mark.parametrize("pattern", SIDECARS)
def test_check_output_path_refuses_sidecars(tmp_path, pattern):
    src = tmp_path / "image.tif"
    src.write_bytes(b"x")
    out = tmp_path / pattern.format(stem="image", name="image.tif")
    with pytest.raises(ValueError, match="refusing to write"):
        check_output_path(out, [src])
    check_output_path(tmp_path / "other.tif", [src])  # an unrelated name is fine
    check_output_path(tmp_path / "sub" / out.name, [src])  # so is the same name elsewhere


@pytest.mark.parametrize(
    "which,pattern",
    [
        ("exterior", "{stem}.prj"),
        ("image", "{name}.aux.xml"),
        ("dem", "{stem}.tfw"),
        ("dem", "{name}.ovr"),
        ("image", "{name}.msk"),
        ("camera", "{stem}.prj"),
    ],
)
def test_ortho_never_overwrites_an_input_sidecar(tmp_path, capsys, which, pattern):
    # `photax ortho --out DIR/ngi_xyz_opk.prj` replaced the exterior's .prj with a GeoTIFF
    src = {"image": IMAGE, "dem": DEM, "camera": CAMERA, "exterior": TRUTH}[which]
    copy = tmp_path / src.name
    shutil.copy(src, copy)
    side = tmp_path / pattern.format(stem=copy.stem, name=copy.name)
    side.write_text("PROJCS[...]")
    argv = _argv("ortho", tmp_path, **{which: copy})
    argv[argv.index("--out") + 1] = str(side)
    assert main(argv) == 2
    assert "refusing to write" in _one_line_error(capsys, "ortho")
    assert side.read_text() == "PROJCS[...]"


def test_rectify_and_resect_refuse_sidecars(tmp_path, capsys):
    gcps = tmp_path / "g.csv"
    shutil.copy(GCPS, gcps)
    assert main(["resect", str(gcps), "--camera", str(CAMERA), "--json", str(tmp_path / "g.prj")]) == 2
    _one_line_error(capsys, "resect")
    image = tmp_path / "img.tif"
    shutil.copy(IMAGE, image)
    assert main(["rectify", str(image), "--gcps", str(GCPS), "--out", str(tmp_path / "img.tfw")]) == 2
    _one_line_error(capsys, "rectify")
    assert main(["rectify", str(image), "--gcps", str(GCPS), "--out", str(tmp_path)]) == 2  # a folder
    assert "it is a folder" in _one_line_error(capsys, "rectify")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.csv", "img.tif"]


def test_too_few_points_is_not_success(tmp_path, capsys):
    # Two GCPs used to print "wrote out.json" and exit 0.
    two = tmp_path / "two.csv"
    two.write_text(
        "".join(
            ln for ln in GCPS.read_text().splitlines(True) if not ln.startswith("P") or ln.startswith(("P01,", "P02,"))
        )
    )
    out = tmp_path / "out.json"
    assert main(["resect", str(two), "--camera", str(CAMERA), "--json", str(out)]) == 1
    assert "0 of 1 image solved, 1 not" in capsys.readouterr().out
    assert json.loads(out.read_text())["images"]["IMG_0001"]["status"] == "skipped"
    # the same with --image, and a usage error stays 2
    assert main(["resect", str(two), "--camera", str(CAMERA), "--image", "IMG_0001"]) == 1
    assert main(["resect", str(two), "--camera", str(CAMERA), "--image", "nope"]) == 2
    with pytest.raises(SystemExit) as exc:
        main(["resect", str(two)])  # --camera missing: argparse's usage error
    assert exc.value.code == 2


def test_not_converged_is_exit_1_with_status(tmp_path, capsys, monkeypatch):
    import dataclasses

    real = photax.resection.resect
    monkeypatch.setattr(
        photax.resection,
        "resect",
        lambda *a, **k: dataclasses.replace(real(*a, **k), converged=False, message="diverged"),
    )
    out = tmp_path / "out.json"
    assert main(["resect", str(GCPS), "--camera", str(CAMERA), "--json", str(out)]) == 1
    assert "IMG_0001: NOT SOLVED - diverged" in capsys.readouterr().out
    assert json.loads(out.read_text())["images"]["IMG_0001"]["status"] == "not converged"


def test_duplicate_note_only_under_its_image(tmp_path, capsys):
    lines = GCPS.read_text().splitlines()
    b = [ln.replace("IMG_0001", "IMG_0002") for ln in lines if ln.startswith("P")]
    gcps = tmp_path / "dup.csv"
    gcps.write_text("\n".join(lines + b + [b[0]]) + "\n")  # P01 twice in IMG_0002
    assert main(["resect", str(gcps), "--camera", str(CAMERA), "--image", "IMG_0001", "--no-robust"]) == 0
    assert "measured twice" not in capsys.readouterr().out
    main(["resect", str(gcps), "--camera", str(CAMERA), "--no-robust"])
    text = capsys.readouterr().out
    assert text.count("measured twice") == 1
    note = text.index("measured twice")
    assert text.rindex("== IMG_0002", 0, note) > text.index("== IMG_0001")  # printed under IMG_0002


def test_units_from_the_crs():
    assert crs_unit("EPSG:32633") == "m"
    assert crs_unit("EPSG:2263") == "US survey ft"
    assert crs_unit("EPSG:4326") == "°"
    assert crs_unit(None) is None and crs_unit("not a crs") is None
    assert common.plural(1, "camera") == "1 camera" and common.plural(2, "camera") == "2 cameras"


def test_no_file_cites_the_shared_folder():
    # A package user has no ../shared beside the checkout.
    offenders = [
        str(p.relative_to(ROOT))
        for d in ("src", "docs")
        for p in (ROOT / d).rglob("*")
        if p.is_file()
        and p.suffix in (".py", ".md", ".txt", ".yaml", ".json")
        and ("../shared" in p.read_text(errors="ignore") or "DESIGN.md" in p.read_text(errors="ignore"))
    ]
    assert offenders == []


def test_bundle_report_plurals_and_units():
    from photax.bundle import bundle_adjust
    from photax.scene import synthetic_block

    problem, _ = synthetic_block(0, noise_px=0.5)  # the demo's block: its compilation is shared
    text = bundle_adjust(problem).report(unit="m")
    assert "1 camera," in text and "1 cameras" not in text
    assert np.any([" m, angles" in ln for ln in text.splitlines()])


def test_ctrl_c_at_any_moment_of_a_real_run(tmp_path, spawn):
    """Ctrl-C sent to a real ``photax bundle --json`` process at 10 moments of its first seconds (JAX's
    import, XLA's start, compilation, the adjustment): exit 130 with one message each time, nothing
    written.  Before: a segfault (-11) now and then, exit 0 with the JSON written after the Ctrl-C, or
    "unexpected ImportError" (a KeyboardInterrupt inside jaxlib's start)."""
    import signal
    import subprocess
    import sys
    import time

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    out = tmp_path / "out.json"
    # "started" once photax's main() is about to run: before it, Python's own handler is the one at work.
    code = "import sys; from photax.cli import main; print('started', file=sys.stderr, flush=True); sys.exit(main())"
    inside = 0  # signals that arrived while the command ran
    for delay in (0.05, 0.2, 0.35, 0.5, 0.7, 0.9, 1.2, 1.6, 2.2, 3.0):
        proc = spawn(
            [sys.executable, "-c", code, "bundle", str(DATA / "block"), "-o", str(out), "--quiet", "--no-progress"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            cwd=tmp_path,
        )
        assert proc.stderr.readline() == "started\n"
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=scaled(60))
        if out.exists() and "interrupted" not in err:  # the run had ended before the signal (a quiet machine)
            assert proc.returncode in (0, -signal.SIGINT), (delay, proc.returncode, err)
            break
        inside += 1
        assert proc.returncode == 130, (delay, proc.returncode, err)
        assert err.strip().endswith("interrupted; nothing written"), (delay, err)
        assert "Traceback" not in err and "Exception ignored" not in err, (delay, err)
        assert list(tmp_path.iterdir()) == [], delay  # neither out.json nor a temporary
    assert inside >= 5, inside
