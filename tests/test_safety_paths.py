"""Path safety (issue 27): what a command reads is never what it writes, names
from inside files never leave the output folder, readers read only regular
files of a bounded size and quote nothing of a file that is not theirs.

References: the inputs themselves (their bytes before and after a refused
run), the file system (what exists after it), POSIX file types (``mkfifo``,
``/dev/zero``), bzip2's own compressor for the decompression limit.
"""

import bz2
import json
import os
import pathlib
import shutil
import signal

import pytest
from conftest import ROOT

import photax.io.files as files
from photax.cli import main
from photax.io.atomic import check_output_path, output_name
from photax.io.bal import read_bal_arrays
from photax.io.block import read_block
from photax.io.camera_file import read_camera
from photax.io.gcp import read_gcps
from photax.io.orientation import read_interior
from photax.io.orthority import read_orthority_exterior
from photax.io.raster import open_raster
from photax.io.results import read_json

DATA = ROOT / "data"
GCPS, CAMERA, IMAGE, DEM = (
    DATA / n for n in ("sample_gcps.csv", "sample_camera.yaml", "sample_image.tif", "sample_dem.tif")
)
CAM_PX = "focal_length_px: 3000.0\nimage_size: [4000, 3000]\n"  # the sample block's camera, as a file
SECRET = "S3CRET-VALUE-0123456789"


def _error(capsys, command):
    err = capsys.readouterr().err
    assert err.startswith(f"photax {command}: error:") and err.count("\n") == 1, err
    return err


def _block(tmp_path, cameras, camera_of=lambda i: "cam") -> pathlib.Path:
    """The sample block, its cameras replaced by ``cameras`` (block.json entries)."""
    block = tmp_path / "block"
    shutil.copytree(DATA / "block", block)
    meta = json.loads((block / "block.json").read_text())
    meta["cameras"] = cameras
    for i, im in enumerate(meta["images"]):
        im["camera"] = camera_of(i)
    (block / "block.json").write_text(json.dumps(meta))
    return block


# --- an input overwritten, exit 0 ---------------------------------------------------


@pytest.mark.parametrize("where", ["inside", "outside"])
def test_bundle_json_never_replaces_the_camera_file_block_json_reads(tmp_path, capsys, where):
    cam = (tmp_path / "block" / "cam.yaml") if where == "inside" else (tmp_path / "elsewhere" / "cam.yaml")
    block = _block(tmp_path, {"cam": {"file": str(cam) if where == "outside" else "cam.yaml"}})
    cam.parent.mkdir(exist_ok=True)
    cam.write_text(CAM_PX)
    for spelling in (cam, cam.parent / ".." / cam.parent.name / "cam.yaml"):
        assert main(["bundle", str(block), "--json", str(spelling), "--quiet", "--no-progress"]) == 2
        assert "it is an input of this run" in _error(capsys, "bundle")
        assert cam.read_text() == CAM_PX


def test_every_file_a_reader_opens_is_an_input(tmp_path):
    cam = tmp_path / "cam.yaml"
    cam.write_text(CAM_PX)
    block = _block(tmp_path, {"cam": {"file": str(cam)}})
    check_output_path(cam)  # outside a command: only the inputs given
    with files.recording_inputs() as seen:
        read_block(block)
        assert cam.absolute() in seen and (block / "points.csv").absolute() in seen
        with pytest.raises(ValueError, match="it is an input of this run"):
            check_output_path(cam)
        with pytest.raises(ValueError, match="cam.prj, read with the input"):  # its sidecars too
            check_output_path(tmp_path / "cam.prj")
    check_output_path(cam)  # the record ends with the command


def test_an_input_or_sidecar_reached_by_another_name_is_an_input(tmp_path):
    # What the file system says is one file (a hard link, a symbolic link, a path through a linked
    # folder) is refused whatever its name; the same names elsewhere are not.
    image = tmp_path / "image.tif"
    image.write_bytes(b"x")
    (tmp_path / "image.prj").write_text("PROJCS[...]")
    (tmp_path / "linked").symlink_to(tmp_path, target_is_directory=True)
    os.link(image, tmp_path / "hard.tif")
    (tmp_path / "soft.tif").symlink_to(tmp_path / "image.prj")
    for out, why in [
        (tmp_path / "hard.tif", "it is an input of this run"),
        (tmp_path / "linked" / "image.tif", "it is an input of this run"),
        (tmp_path / "soft.tif", "it is image.prj, read with the input"),
        (tmp_path / "linked" / "IMAGE.PRJ", "it is image.prj, read with the input"),
        (tmp_path / "linked" / "image.tfw", "it is image.tfw, read with the input"),  # not there yet
    ]:
        with pytest.raises(ValueError, match=why):
            check_output_path(out, [image])
    (tmp_path / "sub").mkdir()
    for out in (tmp_path / "sub" / "image.tif", tmp_path / "sub" / "image.prj", tmp_path / "other.tif"):
        check_output_path(out, [image])
    with pytest.raises(ValueError, match="it is an input of this run"):  # an input not there: by path
        check_output_path(tmp_path / "linked" / "gone.tif", [tmp_path / "gone.tif"])


# --- writes outside the folder asked for ---------------------------------------------


@pytest.mark.parametrize("bad", ["../../x", "/ABS/x", "..", ".", "", " cam", "a\\b", "nul\x00x", "CON", "lpt1.txt"])
def test_bundle_camera_out_never_writes_outside_its_folder(tmp_path, capsys, bad):
    bad = bad.replace("/ABS", str(tmp_path / "abs"))
    (tmp_path / "abs").mkdir()
    cam = {"focal_length_px": 3000.0, "image_size": [4000, 3000], "free": ["f"]}
    cams = {bad: cam, "good": cam}
    block = _block(tmp_path, cams, camera_of=lambda i: bad if i % 2 else "good")
    out = tmp_path / "w" / "v" / "cams"
    before = sorted(tmp_path.rglob("*"))
    assert main(["bundle", str(block), "--camera-out", str(out), "--quiet", "--no-progress"]) == 2
    assert "cannot be a file name" in _error(capsys, "bundle")
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, anywhere under tmp_path


def test_output_name():
    for good in ("cam", "cam.1", "Kamera ä", "a..b", "CONSOLE", "com10"):
        assert output_name(good) == good
    for bad in (
        "a/b",
        "/etc/passwd",
        "..",
        ".",
        "",
        "   ",
        "a\\b",
        "x\x00",
        "tab\tx",
        "aux",
        "Nul.yaml",
        "COM3",
        "con .txt",
        "end.",
        "x" * 201,
    ):
        with pytest.raises(ValueError, match="cannot be a file name"):
            output_name(bad, "camera")


# --- reading only what a file should be ------------------------------------------------

READERS = {
    "camera file": read_camera,
    "GCP file": read_gcps,
    "JSON file": read_json,
    "orthority exterior file": read_orthority_exterior,
    "BAL file": read_bal_arrays,
    "raster file": open_raster,
}


@pytest.fixture
def alarm():
    """A reader blocked on a FIFO fails the test instead of hanging it."""

    def timeout(*_):
        raise TimeoutError("blocked reading")

    old = signal.signal(signal.SIGALRM, timeout)
    signal.alarm(10)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("what", sorted(READERS))
def test_readers_refuse_fifos_and_devices(tmp_path, alarm, what):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=rf"^{fifo}: a FIFO \(named pipe\), not a regular file"):
        READERS[what](fifo)
    if os.path.exists("/dev/zero"):
        with pytest.raises(ValueError, match=r"^/dev/zero: a character device, not a regular file"):
            READERS[what]("/dev/zero")
    with pytest.raises(ValueError, match=rf"^{tmp_path}: is a folder"):
        READERS[what](tmp_path)


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not os.path.exists("/dev/zero"), reason="no FIFOs, devices")
@pytest.mark.parametrize(
    "argv, what",
    [
        (["resect", str(GCPS), "--camera", "{}"], "camera file"),
        (["resect", "{}", "--camera", str(CAMERA)], "GCP file"),
        (
            ["ortho", str(IMAGE), "--dem", str(DEM), "--camera", str(CAMERA), "--exterior", "{}", "--out", "o.tif"],
            "exterior file",
        ),
        (["ortho", "{}", "--dem", str(DEM), "--camera", str(CAMERA), "--exterior", "x", "--out", "o.tif"], "image"),
    ],
)
def test_cli_refuses_a_fifo_or_device_at_once(tmp_path, capsys, alarm, argv, what):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for special in (fifo, "/dev/zero"):
        assert main([str(special) if a == "{}" else a for a in argv]) == 2
        err = _error(capsys, argv[0])
        assert f"{what} {special}: " in err and "not a regular file" in err


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_block_files_dev_zero(tmp_path, capsys, alarm):
    block = _block(tmp_path, {"cam": {"file": "/dev/zero"}})
    assert main(["bundle", str(block), "--quiet"]) == 2
    err = _error(capsys, "bundle")
    assert "/dev/zero: a character device, not a regular file; expected a camera file" in err
    for name in ("block.json", "points.csv"):  # a block folder's own files, linked to a device
        saved = (block / name).read_bytes()
        (block / name).unlink()
        (block / name).symlink_to("/dev/zero")
        assert main(["bundle", str(block), "--quiet"]) == 2
        assert f"{name}: a character device, not a regular file" in _error(capsys, "bundle")
        (block / name).unlink()
        (block / name).write_bytes(saved)


def test_size_limits(tmp_path, monkeypatch):
    cam = tmp_path / "cam.yaml"
    cam.write_text(CAM_PX + "name: " + "x" * 100 + "\n")
    gcps = tmp_path / "g.csv"
    shutil.copy(GCPS, gcps)
    assert read_camera(cam).focal_length == 3000.0 and len(read_gcps(gcps)) > 0
    assert files.MAX_BYTES["camera file"] == 1 << 20 and files.MAX_BYTES_DEFAULT == 1 << 30  # as documented
    monkeypatch.setitem(files.MAX_BYTES, "camera file", 100)
    with pytest.raises(ValueError, match=rf"^{cam}: .* too large for a camera file \(at most .*\); is this"):
        read_camera(cam)
    monkeypatch.setattr(files, "MAX_BYTES_DEFAULT", gcps.stat().st_size - 1)
    with pytest.raises(ValueError, match="too large for a GCP file"):
        read_gcps(gcps)


BAL = "1 1 1\n0 0 1.5 -2.5\n0.1 0.2 0.3 1 2 3 500 0 0\n1 2 -10\n"  # 1 camera, 1 point, 1 observation


def test_bal_bz2_is_decompressed_only_up_to_the_limit(tmp_path, monkeypatch):
    plain = read_bal_arrays(_write(tmp_path / "p.txt", BAL.encode()))
    half = len(BAL) // 2  # two bzip2 streams, as pbzip2 writes them: still read whole
    multi = read_bal_arrays(
        _write(tmp_path / "m.txt.bz2", bz2.compress(BAL[:half].encode()) + bz2.compress(BAL[half:].encode()))
    )
    assert (multi.observations == plain.observations).all() and (multi.cameras == plain.cameras).all()
    bomb = _write(tmp_path / "bomb.txt.bz2", bz2.compress(BAL.encode() + b" " * 100_000))  # 100 kB from 100 B
    monkeypatch.setitem(files.MAX_BYTES, "BAL file", 10_000)
    with pytest.raises(ValueError, match=r"decompresses to over .* too large for a BAL file"):
        read_bal_arrays(bomb)
    with pytest.raises(ValueError, match="not a readable bzip2 file"):
        read_bal_arrays(_write(tmp_path / "t.txt.bz2", bz2.compress(BAL.encode())[:-10]))


def _write(path, raw: bytes) -> pathlib.Path:
    path.write_bytes(raw)
    return path


# --- file contents echoed ----------------------------------------------------------------

# Foreign files: a shadow-like file whose lines end in ':' (YAML reads each as a key), a
# secrets YAML, a secrets CSV, a private key.
FOREIGN = {
    "shadow": f"root:*:19000:0:99999:7:::\n_apt:*:{SECRET}:0:99999:7:::\n",
    "secrets.yaml": f"AWS_SECRET_ACCESS_KEY: {SECRET}\n",
    "secrets.csv": f"user,password\nadmin,{SECRET}\n",
    "id_rsa": f"-----BEGIN OPENSSH PRIVATE KEY-----\n{SECRET}\n-----END OPENSSH PRIVATE KEY-----\n",
    "dup.yaml": f"{SECRET}: 1\n{SECRET}: 2\n",
    "alias.yaml": f"a: *{SECRET}\n",
}


@pytest.mark.parametrize("name", sorted(FOREIGN))
@pytest.mark.parametrize("what", sorted(set(READERS) - {"raster file"}))
def test_no_reader_quotes_a_foreign_file(tmp_path, name, what):
    path = tmp_path / name
    path.write_text(FOREIGN[name])
    try:
        READERS[what](path)
    except ValueError as exc:
        assert SECRET[:5] not in str(exc), str(exc)
    else:
        pytest.fail(f"read {name} as a {what}")


@pytest.mark.parametrize("name", ["shadow", "secrets.yaml"])
def test_cli_says_not_a_camera_file_and_quotes_nothing(tmp_path, capsys, name):
    secret = tmp_path / name
    secret.write_text(FOREIGN[name])
    assert main(["resect", str(GCPS), "--camera", str(secret)]) == 2
    err = _error(capsys, "resect")
    assert "not a photax camera file (YAML mapping with focal_length" in err and SECRET[:5] not in err
    block = _block(tmp_path, {"cam": {"file": str(secret)}})
    assert main(["bundle", str(block), "--quiet"]) == 2
    err = _error(capsys, "bundle")
    assert "not a photax camera file" in err and SECRET[:5] not in err


def test_block_files_that_are_foreign_are_not_quoted(tmp_path, capsys):
    block = _block(tmp_path, {"cam": {"focal_length_px": 3000.0, "image_size": [4000, 3000]}})
    for name in ("points.csv", "observations.csv"):
        saved = (block / name).read_bytes()
        (block / name).write_text(FOREIGN["secrets.csv"])  # e.g. a symbolic link to someone's file
        assert main(["bundle", str(block), "--quiet"]) == 2
        err = _error(capsys, "bundle")
        assert "got none of them" in err and SECRET[:5] not in err
        (block / name).write_bytes(saved)


def test_a_camera_file_with_a_typo_quotes_a_short_excerpt(tmp_path):
    # of the expected format (a camera key is there): the unknown key is named, short and printable
    cam = tmp_path / "cam.yaml"
    cam.write_text(CAM_PX + "focus\u200b" + "y" * 500 + ": 3\n")  # a zero-width space: printed escaped
    with pytest.raises(ValueError, match=r"line 3: unknown key 'focus\\u200byyy") as exc:
        read_camera(cam)
    assert len(str(exc.value)) < len(str(cam)) + 300 and "y" * 60 not in str(exc.value)
    cam.write_text(CAM_PX + "pixel_size: '" + "9" * 5000 + "x'\n")
    with pytest.raises(ValueError, match="pixel_size") as exc:
        read_camera(cam)
    assert len(str(exc.value)) < len(str(cam)) + 300


def test_a_yaml_alias_bomb_is_refused_at_once(tmp_path):
    # 1 kB of nested aliases ("billion laughs"): 9**9 values; read whole, it ran out of time and memory
    levels = ", ".join(f"&a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 9))
    cam = tmp_path / "bomb.yaml"
    cam.write_text(f"focal_length: 1\nunit: mm\ndescription: [&a0 [1,1,1,1,1,1,1,1,1], {levels}]\npixel_size: *a8\n")
    assert cam.stat().st_size < 1000
    with pytest.raises(ValueError, match=r"line 3: not valid YAML: its aliases expand to over 100000 values"):
        read_interior(cam)
    cam.write_text(
        "focal_length: &f 8.8\nunit: mm\nprincipal_point: &pp [0.1, 0.2]\nname: *f\ndescription: *pp\n"
    )  # a few aliases are fine
    assert read_camera(cam).focal_length == 8.8
