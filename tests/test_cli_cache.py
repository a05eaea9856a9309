"""The command line's on-disk caches (JAX's persistent compilation cache and photax._aot's exported
programs in one folder) shared by processes that run at the same time (issue 21 item 4: many
``photax ortho`` runs, e.g. one per core or per job of a cluster, start on one empty cache).

Reference: the same command run alone with no cache at all (``JAX_COMPILATION_CACHE_DIR`` pointing
to an empty folder that is never read back): every output must be identical byte for byte, and a
third process must then find every program in the cache (JAX logs a cache hit for each and none
is compiled again).
"""

import filecmp
import os
import subprocess
import sys

from conftest import ROOT, scaled

DATA = ROOT / "data"


def _ortho(spawn, out, cache, log=False):
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT / "src"))
    env.pop("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", None)  # the CLI's own setting: cache everything
    if log:  # JAX's log of each compilation, and Python's of each import
        env["JAX_LOG_COMPILES"] = "1"
    cmd = [sys.executable, *(["-X", "importtime"] if log else []), "-m", "photax.cli", "ortho"]
    cmd += [str(DATA / "sample_image.tif"), "--dem"]
    cmd += [str(DATA / "sample_dem.tif"), "--camera", str(DATA / "sample_camera.yaml"), "--exterior"]
    cmd += [str(DATA / "sample_truth.json"), "--resolution", "2", "--no-progress", "-o", str(out)]
    env.pop("PYTHONWARNINGS", None)  # Python's default: a warning is printed on stderr, where the test looks
    return spawn(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_processes_sharing_one_empty_cache_agree_and_fill_it(tmp_path, spawn):
    shared = tmp_path / "cache"
    runs = [_ortho(spawn, tmp_path / f"ortho{k}.tif", shared) for k in range(2)]  # at the same time
    runs.append(_ortho(spawn, tmp_path / "alone.tif", tmp_path / "own-cache"))
    for p in runs:
        out, err = p.communicate(timeout=scaled(600))
        assert p.returncode == 0, err
        # issue 38: no "Error reading persistent compilation cache entry" (a half-written entry
        # read by the other process), no traceback from the caches: nothing at all on stderr
        assert err == "", err[-3000:]
    assert filecmp.cmp(tmp_path / "ortho0.tif", tmp_path / "alone.tif", shallow=False)
    assert filecmp.cmp(tmp_path / "ortho1.tif", tmp_path / "alone.tif", shallow=False)
    assert list((shared / "photax-aot").glob("*.bin"))  # exported programs kept
    # no half-written entry left (photax._aot.write_atomically's temporaries: .NAME.*.tmp)
    assert not [p for p in shared.rglob("*") if p.name.startswith("tmp") or p.name.endswith(".tmp")]

    third = _ortho(spawn, tmp_path / "third.tif", shared, log=True)
    _, err = third.communicate(timeout=scaled(600))
    assert third.returncode == 0, err
    assert filecmp.cmp(tmp_path / "third.tif", tmp_path / "alone.tif", shallow=False)
    compiled = err.count("Finished XLA compilation")
    hits = err.count("Persistent compilation cache hit")
    assert compiled > 0 and hits == compiled, err[-3000:]
    # A warm run loads its programs from disk: it needs neither equinox (photax._pytree) nor LAPACK
    # (whose initialisation imports scipy.linalg; photax._aot): 0.2 and 0.1 s of CPU a process.
    imported = {line.rpartition("|")[2].strip() for line in err.splitlines() if line.startswith("import time:")}
    assert "jax" in imported and not {"equinox", "scipy.linalg"} & imported
