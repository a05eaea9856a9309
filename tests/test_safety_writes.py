"""Writes that cannot lie (issue 27): a write that fails -- a full disk, a
file size limit, a signal -- raises (the CLI exits 2) naming the output and
the cause, leaves the previous file as it was and no temporary behind.

The full disk is a real one: a small tmpfs (mounting needs root; the tests
skip cleanly otherwise), filled with a filler file.  The file size limit is
``ulimit -f`` (RLIMIT_FSIZE) in a subprocess, SIGXFSZ ignored so a write
past it fails with EFBIG instead of killing the process (Python ignores it anyway).
"""

import errno
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import sample_ortho, scaled

import photax.cli
from photax.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
ORTHO = sample_ortho(resolution="0.5")
OLD = b"the previous result\n"
PHOTAX = [sys.executable, "-c", "import sys, photax.cli; sys.exit(photax.cli.main(sys.argv[1:]))"]


@pytest.fixture
def tmpfs(tmp_path):
    """A folder on its own 1 MB tmpfs, unmounted after the test."""
    folder = tmp_path / "disk"
    folder.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    p = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(folder)], capture_output=True, check=False
    )
    if p.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {p.stderr.decode().strip()}")
    yield folder
    subprocess.run(["umount", "-l", str(folder)], check=False)


def _fill(folder: pathlib.Path, leave: int = 0) -> None:
    """Fill ``folder``'s file system with a file ``filler``, leaving about ``leave`` bytes free."""
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        room = shutil.disk_usage(folder).free - leave
        while room > 0:
            room -= os.write(fd, b"\0" * min(room, 1 << 16))
        while not leave:  # the last pages: until the disk says no
            try:
                os.write(fd, b"\0" * 4096)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
                break
    finally:
        os.close(fd)


def _limited(fsize: int, cmd: list[str]) -> list[str]:
    """``cmd`` under a file size limit of ``fsize`` bytes (RLIMIT_FSIZE, ``ulimit -f``),
    SIGXFSZ ignored so a write past it fails (EFBIG) rather than killing the process.
    Set by a small launcher, not a preexec_fn: forking this process (JAX's threads
    running) is unsafe."""
    launcher = (
        "import os, resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
        "resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]),) * 2); "
        "os.execv(sys.argv[2], sys.argv[2:])"
    )
    return [sys.executable, "-c", launcher, str(fsize), *cmd]


def _env():
    """The subprocesses run the photax this process imported."""
    src = str(pathlib.Path(photax.cli.__file__).parents[2])
    return dict(
        os.environ, PYTHONPATH=os.pathsep.join([src, os.environ.get("PYTHONPATH", "")]), PYTHONWARNINGS="ignore"
    )


# -- every writer, on a full disk ---------------------------------------------------------------


def _grid():
    from photax.rectification import Grid

    return Grid((1.0, 0, 500_000.0, 0, -1.0, 6_000_000.0), (512, 512), crs="EPSG:32633")


def _pixels():
    return np.random.default_rng(0).integers(0, 255, (512, 512), dtype=np.uint8)  # incompressible


def _geotiff(out):
    from photax.io import write_geotiff

    write_geotiff(out, _pixels(), tuple(_grid().transform)[:6], crs="EPSG:32633")


def _dask(out, cog=False):
    import dask.array as da

    from photax.io.lazy import dataarray, to_raster

    data = dataarray(da.from_array(_pixels(), chunks=256), _grid(), np.asarray(0, dtype=np.uint8), "ortho")
    to_raster(data, out, cog=cog)


def _json(out):
    from photax.io import write_json

    write_json({"result": list(range(1000))}, out)


def _csv(out):
    from photax.io import read_gcps, write_gcps

    write_gcps(out, read_gcps(DATA / "sample_gcps.csv"))


def _yaml(out):
    from photax.io import read_camera, write_camera

    write_camera(read_camera(DATA / "sample_camera.yaml"), out, unit="mm")


def _bal(out):
    from photax.io.bal import BALData, write_bal_arrays

    rng = np.random.default_rng(1)
    write_bal_arrays(
        BALData(
            rng.normal(size=(2, 9)),
            rng.normal(size=(50, 3)),
            np.arange(100) % 2,
            np.arange(100) % 50,
            rng.normal(size=(100, 2)),
        ),
        out,
    )


def _block(out):
    from photax.io import read_block, write_block

    write_block(read_block(DATA / "block"), out)


WRITERS = {
    "geotiff": ("o.tif", _geotiff),
    "cog": ("o.tif", lambda out: _dask(out, cog=True)),
    "dask to_raster": ("o.tif", _dask),
    "json": ("o.json", _json),
    "csv": ("o.csv", _csv),
    "yaml": ("o.yaml", _yaml),
    "bal": ("o.txt", _bal),
    "block folder": ("block", _block),
}


@pytest.mark.parametrize("writer", WRITERS)
def test_every_writer_fails_loudly_on_a_full_disk_and_keeps_the_old_file(tmpfs, writer):
    if writer in ("cog", "dask to_raster"):
        pytest.importorskip("rioxarray")
    name, write = WRITERS[writer]
    out = tmpfs / name
    if writer == "block folder":
        out.mkdir()  # a block is written into a new or empty folder
    else:
        out.write_bytes(OLD)
    _fill(tmpfs)
    with pytest.raises(OSError) as info:
        write(out)
    assert info.value.errno == errno.ENOSPC, info.value
    text = str(info.value)
    assert name in text and "no space left on device" in text and "free" in text, text
    # the old file as it was, and nothing else: no temporary left
    assert sorted(p.name for p in tmpfs.iterdir()) == sorted(["filler", name])
    if writer == "block folder":
        assert list(out.iterdir()) == []
    else:
        assert out.read_bytes() == OLD
    # with room again, the same writer succeeds (the failure was the disk's)
    (tmpfs / "filler").unlink()
    write(out)
    assert out.exists() and (out.is_dir() or out.read_bytes() != OLD)
    assert not [p for p in tmpfs.iterdir() if p.name.endswith((".part", ".gtiff"))]


def test_a_known_size_is_refused_before_writing_with_the_figures(tmpfs):
    # Uncompressed, a GeoTIFF's size is known: refused before the write, saying
    # what it needs and what the disk has (checked against shutil.disk_usage).
    from photax.io import write_geotiff

    out = tmpfs / "o.tif"
    out.write_bytes(OLD)
    _fill(tmpfs, leave=200_000)
    free = shutil.disk_usage(tmpfs).free
    a = _pixels()
    with pytest.raises(OSError) as info:
        write_geotiff(out, np.stack([a, a, a, a]), tuple(_grid().transform)[:6], compress=None)  # 1.05 MB
    assert info.value.errno == errno.ENOSPC
    assert f"{4 * a.nbytes / 1e6:.3g} MB needed, {free / 1e3:.3g} kB free" in str(info.value), str(info.value)
    assert out.read_bytes() == OLD and sorted(p.name for p in tmpfs.iterdir()) == ["filler", "o.tif"]


def test_json_over_the_file_size_limit_is_refused_before_writing(tmp_path):
    # issue 27: `resect --json` under `ulimit -f` failed with "File too large" and no file name.
    out = tmp_path / "r.json"
    out.write_bytes(OLD)
    data = {"result": list(range(1000))}
    size = len((json.dumps(data, indent=2) + "\n").encode())
    code = f"import sys\nfrom photax.io import write_json\nwrite_json({data!r}, sys.argv[1])"
    p = subprocess.run(
        _limited(1000, [sys.executable, "-c", code, str(out)]),
        capture_output=True,
        text=True,
        env=_env(),
        timeout=scaled(120),
        check=False,
    )
    assert p.returncode == 1
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith(
        "OSError: [Errno 27] not written (the existing file is kept): file too large: "
        f"{size / 1e3:.3g} kB needed, the file size limit (ulimit -f) is 1 kB"
    ), last
    assert str(out) in last and out.read_bytes() == OLD and sorted(tmp_path.iterdir()) == [out]


# -- the command line ----------------------------------------------------------------------------


def test_cli_ortho_onto_a_full_disk_exits_2_and_keeps_the_old_ortho(tmpfs, capsys):
    # issue 27: exit 0, "wrote ...", a truncated GeoTIFF in place of the good one.
    out = tmpfs / "o.tif"
    out.write_bytes(OLD)
    _fill(tmpfs, leave=100_000)  # the ortho is about 400 kB
    assert main(ORTHO + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(
        f"photax ortho: error: {out}: not written (the existing file is kept): no space left on device:"
    ), err
    assert out.read_bytes() == OLD
    assert sorted(p.name for p in tmpfs.iterdir()) == ["filler", "o.tif"]


def test_cli_rectify_past_the_file_size_limit_exits_2_and_keeps_the_old_file(tmp_path):
    out = tmp_path / "r.tif"
    out.write_bytes(OLD)
    cmd = [
        *PHOTAX,
        "rectify",
        str(DATA / "sample_image.tif"),
        "--gcps",
        str(DATA / "sample_gcps.csv"),
        "--resolution",
        "1",
        "--no-progress",
        "--out",
        str(out),
    ]
    p = subprocess.run(
        _limited(50_000, cmd), capture_output=True, text=True, env=_env(), timeout=scaled(600), check=False
    )
    # (the output is about 140 kB)
    assert p.returncode == 2, p.stdout + p.stderr
    assert "wrote" not in p.stdout
    err = p.stderr.strip().splitlines()[-1]
    assert (
        err.startswith(f"photax rectify: error: {out}: not written (the existing file is kept): file too large:")
        and "(ulimit -f) is 50 kB" in err
    ), err
    assert out.read_bytes() == OLD
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.tif"]


def test_cli_compare_that_fails_writes_nothing(tmpfs, capsys):
    # issue 27: exit 2 left comparison.md and comparison.json behind.  Room
    # for the table (3 kB) but not the error maps (about 300 kB).
    _fill(tmpfs, leave=60_000)
    out = tmpfs / "cmp"
    argv = [
        "compare",
        str(DATA / "sample_gcps.csv"),
        "--camera",
        str(DATA / "sample_camera.yaml"),
        "--dem",
        str(DATA / "sample_dem.tif"),
        "--out",
        str(out),
        "--no-progress",
    ]
    assert main(argv) == 2
    assert "no space left on device" in capsys.readouterr().err
    assert sorted(p.name for p in tmpfs.iterdir()) == ["filler"]  # not even the folder


# -- signals and leftovers -----------------------------------------------------------------------

_WRITER = """
import sys, time
from photax.cli import _all_or_nothing
from photax.io.atomic import atomic_write
with _all_or_nothing(["photax test"]):
    with atomic_write(sys.argv[1]) as fh:  # a first output, complete
        fh.write("new")
    with atomic_write(sys.argv[2]) as fh:  # the second being written
        fh.write("x" * 10_000_000)
        fh.flush()
        print("writing", flush=True)
        time.sleep(60)
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_signal_during_a_write_removes_the_temporary_and_takes_back_the_run(tmp_path, sig, spawn):
    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    first.write_bytes(OLD)
    p = spawn(
        [sys.executable, "-c", _WRITER, str(first), str(second)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_env(),
    )
    assert p.stdout.readline() == b"writing\n"
    assert first.read_text() == "new"
    assert len([q for q in tmp_path.iterdir() if q.name.endswith(".part")]) == 1  # a 10 MB temporary
    p.send_signal(sig)
    _, err = p.communicate(timeout=scaled(60))
    # SIGINT: KeyboardInterrupt, uncaught here, so Python ends by SIGINT (-2)
    assert p.returncode == (-sig if sig == signal.SIGINT else 128 + sig), err
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.txt"] and first.read_bytes() == OLD


def test_a_run_that_fails_writes_nothing(tmp_path):
    from photax.io import write_geotiff, write_json
    from photax.io.atomic import all_or_nothing

    kept, new, folder = tmp_path / "kept.json", tmp_path / "new.tif", tmp_path / "empty"
    kept.write_bytes(OLD)
    folder.mkdir()
    with pytest.raises(RuntimeError, match="later"), all_or_nothing():
        write_json({"a": 1}, kept)
        write_geotiff(new, _pixels(), tuple(_grid().transform)[:6])
        _block(folder)
        assert json.loads(kept.read_text()) == {"a": 1} and new.exists() and (folder / "block.json").exists()
        raise RuntimeError("a later step fails")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "kept.json"]
    assert kept.read_bytes() == OLD and list(folder.iterdir()) == []
    with all_or_nothing():  # and one that succeeds keeps its outputs, no copy of the old ones
        write_json({"a": 2}, kept)
    assert json.loads(kept.read_text()) == {"a": 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "kept.json"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_during_a_large_ortho_is_acted_on_at_once_and_leaves_no_temporary(tmp_path, sig, spawn):
    # issue 27: `timeout` during a large ortho left hidden .o.tif.*.part files (up to 68 MB).
    # issue 38: Ctrl-C during the write was acted on only when the write ended (the tiles in
    # flight all computed first): now within a second (on an idle machine; scaled to the load).
    # The console script's own entry (argv None: the process ends with os._exit).
    out = tmp_path / "o.tif"
    out.write_bytes(OLD)
    argv = [*ORTHO[:-3], "--resolution", "0.1", "--no-progress", "--out", str(out)]  # 99 MPix: many seconds
    p = spawn([sys.executable, "-m", "photax.cli", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env())
    deadline = time.monotonic() + scaled(300)
    while not [q for q in tmp_path.iterdir() if q.name.endswith(".part") and q.stat().st_size > 0]:
        if p.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"the ortho ended before its temporary was seen: {p.returncode}")
        time.sleep(0.01)
    time.sleep(0.5)  # well into the tiles' write
    assert p.poll() is None, "the ortho ended before the signal: make it larger"
    sent = time.monotonic()
    p.send_signal(sig)
    _, err = p.communicate(timeout=scaled(120))
    latency = time.monotonic() - sent
    assert sorted(q.name for q in tmp_path.iterdir()) == ["o.tif"] and out.read_bytes() == OLD
    if sig == signal.SIGINT:
        assert p.returncode == 130 and b"interrupted; nothing written" in err, err
    else:
        assert p.returncode == 128 + signal.SIGTERM and b"stopped by SIGTERM; nothing written" in err, err
    assert latency < scaled(1.0), f"{signal.Signals(sig).name} acted on after {latency:.2f} s"


def test_stale_temporaries_are_removed_on_the_next_write(tmp_path):
    from photax.io import write_json

    day = 24 * 3600
    stale = [
        tmp_path / ".o.json.a1b2c3d4.part",
        tmp_path / ".x.tif.zz_9yy8x.part",
        tmp_path / ".x.tif.k2j3h4g5.part.gtiff",
    ]
    (tmp_path / ".blk.q1w2e3r4.part").mkdir()  # a block folder's
    stale.append(tmp_path / ".blk.q1w2e3r4.part")
    fresh = tmp_path / ".o.json.f5g6h7j8.part"  # another process may be writing it
    kept = tmp_path / ".o.json.f5g6h7j9.part.old"  # a previous file another run keeps: linked now
    others = [tmp_path / "notes.part", tmp_path / ".o.json.part", tmp_path / "o.json.a1b2c3d4.part"]
    for f in [*stale[:-1], fresh, kept, *others]:
        f.write_text("x")
    old = time.time() - 2 * day
    for f in [*stale, kept, *others]:
        os.utime(f, (old, old))
    write_json({"a": 1}, tmp_path / "o.json")
    left = ["o.json", fresh.name, kept.name, *(o.name for o in others)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(left)
    assert json.loads((tmp_path / "o.json").read_text()) == {"a": 1}


def test_main_restores_the_signal_handlers():
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)}
    with photax.cli._all_or_nothing(["photax"]):
        assert signal.getsignal(signal.SIGTERM) is not before[signal.SIGTERM]
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_raster_write_stops_between_strips_after_a_ctrl_c(tmp_path, monkeypatch):
    """issue 38: ``write_geotiff`` writes strip by strip (Python's signal handlers run between
    them) and stops at the first strip after a Ctrl-C (``photax.io.atomic.interrupted``), even
    one a dependency swallowed: KeyboardInterrupt, the previous file kept, no temporary."""
    import rasterio

    from photax.io import atomic
    from photax.io.raster import STRIP_ROWS, write_geotiff

    out = tmp_path / "o.tif"
    out.write_bytes(OLD)
    pixels = np.arange(3 * 4 * STRIP_ROWS * 300, dtype=np.uint16).reshape(3, 4 * STRIP_ROWS, 300)
    calls = []
    real_write = rasterio.io.DatasetWriter.write

    def write(self, arr, *args, **kwargs):  # the Ctrl-C arrives during the second strip
        calls.append(arr.shape)
        if len(calls) == 2:
            atomic.interrupted.set()
        return real_write(self, arr, *args, **kwargs)

    monkeypatch.setattr(rasterio.io.DatasetWriter, "write", write)
    try:
        with pytest.raises(KeyboardInterrupt):
            write_geotiff(out, pixels, (0.5, 0, 500000, 0, -0.5, 4000000), crs="EPSG:32633")
    finally:
        atomic.interrupted.clear()
    assert calls == [(3, STRIP_ROWS, 300)] * 2  # stopped before the third strip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.tif"] and out.read_bytes() == OLD
    monkeypatch.undo()
    write_geotiff(out, pixels, (0.5, 0, 500000, 0, -0.5, 4000000), crs="EPSG:32633")  # and whole, strip by strip
    with rasterio.open(out) as src:
        np.testing.assert_array_equal(src.read(), pixels)
