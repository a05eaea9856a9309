"""The benchmarks' honesty rules (issue 37, item 1): every run records its CPU, thread settings and
load before and after (``benchmarks/_common.py``); ``benchmarks/report.py`` writes no README row
from a run loaded above 0.5 at its start, and ``--loaded`` keeps it in the performance history,
marked loaded."""

import json
import os
import subprocess
import sys

import pytest
from conftest import ROOT

BENCH = ROOT / "benchmarks"
sys.path.insert(0, str(BENCH))

import _common  # noqa: E402
import report  # noqa: E402


def _run(load: float) -> dict:
    return dict(
        benchmark="bench_x",
        command="python benchmarks/bench_x.py",
        date="2026-12-03T09:00:00+00:00",
        machine=dict(cpus=2, cpu_model="Test CPU", load_average=[load, 0.1, 0.1]),
        load_1min_start=load,
        load_average_end=[0.2, 0.1, 0.1],
        threads=dict(mode="all", env={"OMP_NUM_THREADS": None}, usable_cpus=2, cv2_threads=2, pools=[]),
        figures={"poly bilinear vs cv2.remap": dict(photax_s=0.05, peer_s=0.03, ratio=5 / 3)},
    )


def test_loaded_run_is_refused_and_quiet_run_is_tabulated(tmp_path, capsys, monkeypatch):
    quiet, loaded = tmp_path / "quiet.json", tmp_path / "loaded.json"
    quiet.write_text(json.dumps(_run(0.3)))
    loaded.write_text(json.dumps(_run(0.51)))
    history = tmp_path / "performance.md"
    monkeypatch.setattr(report, "PERFORMANCE", history)
    assert report.main([str(quiet), str(loaded)]) == 1
    out = capsys.readouterr()
    assert "### quiet" in out.out and "Test CPU" in out.out and "quiet: load average 0.3" in out.out
    assert "### loaded" not in out.out
    assert "loaded (load 0.51)" in out.err
    assert not history.exists()
    # --loaded: into the history, marked loaded, still not a README table
    assert report.main([str(loaded), "--loaded"]) == 0
    out = capsys.readouterr().out
    assert "### loaded\n" not in out
    text = history.read_text()
    assert "LOADED (1-minute load 0.51 at the start)" in text and "| poly bilinear vs cv2.remap |" in text


def test_start_records_cpu_threads_and_loads(tmp_path):
    """A run's JSON holds the CPU model, core count, both sides' thread settings and the load at
    its start and end; --threads one runs with every pool at one thread (cv2's included)."""
    script = tmp_path / "bench_tiny.py"
    script.write_text(
        "import argparse, sys\n"
        f"sys.path.insert(0, {str(BENCH)!r})\n"
        "import _common\n"
        f"_common.RESULTS = __import__('pathlib').Path({str(tmp_path)!r})\n"
        "ap = argparse.ArgumentParser(); _common.add_threads_option(ap); args = ap.parse_args()\n"
        "_common.apply_threads(args); _common.start('bench_tiny'); _common.record('x', photax_s=1.0)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in _common.THREAD_VARIABLES}
    subprocess.run([sys.executable, str(script), "--threads", "both"], check=True, env=env, capture_output=True)
    all_cores = json.loads((tmp_path / "bench_tiny.json").read_text())
    one = json.loads((tmp_path / "bench_tiny_1thread.json").read_text())
    for run in (all_cores, one):
        assert run["machine"]["cpus"] == os.cpu_count() and run["machine"]["cpu_model"]
        assert isinstance(run["load_1min_start"], float) and isinstance(run["load_1min_end"], float)
        assert run["quiet"] == (run["load_1min_start"] <= _common.QUIET_LOAD)
    assert all_cores["threads"]["mode"] == "all" and all_cores["threads"]["env"]["OMP_NUM_THREADS"] is None
    assert one["threads"]["mode"] == "one"
    assert one["threads"]["env"] == {**dict.fromkeys(_common.THREAD_VARIABLES), **_common.ONE_THREAD_ENV}
    cv2 = pytest.importorskip("cv2")
    assert one["threads"]["cv2_threads"] == 1 and all_cores["threads"]["cv2_threads"] == cv2.getNumThreads()
