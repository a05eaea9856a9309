"""Shared timing, memory and reporting helpers for the benchmarks.

Machines here are noisy (2 cores): every figure is the median of several
runs, and results are reported as ratios photax / peer measured in the same
run.  A benchmark calls :func:`start` first: it prints the command that
reproduces the run, the machine and its load, and at exit writes every
figure given to :func:`ratio_line` or :func:`record` to
``benchmarks/results/<name>.json`` (``python benchmarks/report.py`` turns
those files into the README's table).

Every run also records how honest its figures can be (issue 37): the CPU model and core count, the
thread settings of both sides (:func:`threads`: the OpenMP / MKL / OpenBLAS / GDAL / OpenCV
variables, ``cv2.getNumThreads()``, ``XLA_FLAGS``, the BLAS pools threadpoolctl sees) and the
1-minute load before and after.  ``report.py`` writes no README row from a run whose 1-minute
load was above :data:`QUIET_LOAD` at its start.  Where peers use all cores, :func:`add_threads_option`
gives a script ``--threads all|one|both``: all cores each (the default), one thread each (every
pool of both sides set to one thread, in a fresh process), or both, one after the other.
"""

from __future__ import annotations

import atexit
import datetime
import json
import os
import pathlib
import platform
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

RESULTS = pathlib.Path(__file__).resolve().parent / "results"
_RUN: dict = {}
#: the highest 1-minute load average at a run's start whose figures may go into the README
QUIET_LOAD = 0.5
#: the environment variables that set the thread pools of photax (XLA) and of its peers
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "GDAL_NUM_THREADS",
    "OPENCV_FOR_THREADS_NUM",
    "XLA_FLAGS",
    "JAX_PLATFORMS",
)
#: one thread each: every pool of both sides (XLA's Eigen pool and its intra-op parallelism included)
ONE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "GDAL_NUM_THREADS": "1",
    "OPENCV_FOR_THREADS_NUM": "1",
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
}
_MODE = ["all"]  # --threads of this process (add_threads_option)


def threads() -> dict:
    """The thread settings both sides run with: the :data:`THREAD_VARIABLES` (None: unset), the
    CPUs this process may use, ``cv2.getNumThreads()`` (when OpenCV is installed) and the
    native pools threadpoolctl finds loaded (BLAS, OpenMP: library, version, threads)."""
    out: dict = {"mode": _MODE[0], "env": {k: os.environ.get(k) for k in THREAD_VARIABLES}}
    try:
        out["usable_cpus"] = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        out["usable_cpus"] = os.cpu_count()
    try:
        import cv2

        out["cv2_threads"] = cv2.getNumThreads()
    except ImportError:
        out["cv2_threads"] = None
    try:
        from threadpoolctl import threadpool_info

        out["pools"] = [
            dict(
                api=p.get("internal_api"),
                library=os.path.basename(p.get("filepath", "")),
                version=p.get("version"),
                threads=p.get("num_threads"),
            )  # fmt: skip
            for p in threadpool_info()
        ]
    except ImportError:
        out["pools"] = None
    return out


def threads_text(t: dict) -> str:
    """One line: the mode, OpenCV's threads, the pools and the variables that are set."""
    env = ", ".join(f"{k}={v}" for k, v in t["env"].items() if v is not None) or "no thread variables set"
    pools = ", ".join(f"{p['library']} {p['threads']}" for p in t.get("pools") or []) or "none seen"
    return (
        f"threads: {t['mode']} ({t['usable_cpus']} usable CPUs), cv2.getNumThreads() {t['cv2_threads']}, "
        f"native pools: {pools}; {env}"
    )


def add_threads_option(ap) -> None:
    """``--threads all|one|both`` on a benchmark whose peers use all cores (see :func:`apply_threads`)."""
    ap.add_argument(
        "--threads",
        choices=("all", "one", "both"),
        default="all",
        help="all cores each (default), one thread each (OpenMP/MKL/OpenBLAS/GDAL/OpenCV and XLA's pools "
        "set to 1, in a fresh process), or both runs one after the other",
    )


def apply_threads(args) -> None:
    """Act on ``args.threads`` before :func:`start`: ``both`` runs this script twice (``--threads
    all``, then ``one``) and exits with the worse exit status; ``one`` re-executes it with
    :data:`ONE_THREAD_ENV` (XLA reads its flags when it starts, OpenMP when it loads), then sets
    ``cv2.setNumThreads(1)``.  The run's results file gets ``_1thread`` after its name."""
    mode = getattr(args, "threads", "all")
    if mode == "both":
        base, argv = [], iter(sys.argv[1:])
        for a in argv:  # this script's arguments less --threads both / --threads=both
            if a == "--threads":
                next(argv, None)
            elif not a.startswith("--threads="):
                base.append(a)
        codes = [
            subprocess.run([sys.executable, sys.argv[0], *base, "--threads", m]).returncode for m in ("all", "one")
        ]
        sys.exit(max(codes))
    if mode == "one":
        if any(os.environ.get(k) != v for k, v in ONE_THREAD_ENV.items()):
            os.environ.update(ONE_THREAD_ENV)
            sys.stdout.flush()
            os.execv(sys.executable, [sys.executable, *sys.argv])
        try:
            import cv2

            cv2.setNumThreads(1)
        except ImportError:
            pass
    _MODE[0] = mode


def machine() -> dict:
    """CPU count and model, load averages (1, 5, 15 min), OS and Python."""
    model = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as fh:
            model = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), model)
    except OSError:
        pass
    return dict(
        cpus=os.cpu_count(),
        cpu_model=model,
        load_average=[round(v, 2) for v in os.getloadavg()],
        system=platform.platform(),
        python=platform.python_version(),
    )


def cpu_times() -> list[int]:
    """The machine's ``/proc/stat`` CPU counters (user nice system idle iowait irq softirq steal), all CPUs."""
    try:
        with open("/proc/stat") as fh:
            return [int(v) for v in fh.readline().split()[1:9]]
    except (OSError, ValueError):
        return [0] * 8


def steal_between(a: list[int], b: list[int]) -> float:
    """Fraction of CPU time stolen by the hypervisor between two :func:`cpu_times` samples."""
    d = [y - x for x, y in zip(a, b)]
    return d[7] / sum(d) if sum(d) > 0 else 0.0


def load_now(sample_s: float = 0.5) -> dict:
    """Load averages, and the steal and busy fractions of the CPUs over ``sample_s`` seconds."""
    a = cpu_times()
    time.sleep(sample_s)
    b = cpu_times()
    d = [y - x for x, y in zip(a, b)]
    busy = 1 - (d[3] + d[4]) / sum(d) if sum(d) > 0 else 0.0
    return dict(load_average=[round(v, 2) for v in os.getloadavg()], steal=round(steal_between(a, b), 3),
                busy=round(busy, 3))  # fmt: skip


class busy_threads:
    """``with busy_threads(n):`` ``n`` processes spinning on a CPU each, a controlled extra load
    (a benchmark's ``--busy``), ended on exit."""

    def __init__(self, n: int):
        self.n, self.procs = int(n), []

    def __enter__(self):
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(self.n)]
        if self.n:
            time.sleep(0.2)
        return self

    def __exit__(self, *exc):
        for p in self.procs:
            p.kill()
            p.wait()


def start(name: str) -> dict:
    """Begin a benchmark run: print how to reproduce it and the machine's
    load; at exit write the recorded figures to ``results/<name>.json``."""
    command = "python " + " ".join(shlex.quote(a) for a in [os.path.relpath(sys.argv[0])] + sys.argv[1:])
    name = name + ("_1thread" if _MODE[0] == "one" else "")
    _RUN.clear()
    _RUN.update(
        benchmark=name,
        command=command,
        date=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        machine=machine(),
        threads=threads(),
        figures={},
    )
    m = _RUN["machine"]
    now = load_now()
    m["steal"], m["busy"] = now["steal"], now["busy"]
    _RUN["load_1min_start"] = m["load_average"][0]
    _RUN["quiet"] = m["load_average"][0] <= QUIET_LOAD
    _RUN["cpu_times_start"] = cpu_times()
    print(f"reproduce with: {command}")
    print(
        f"{m['cpus']} x {m['cpu_model']}, load average {m['load_average']} (1, 5, 15 min), "
        f"CPU steal {100 * now['steal']:.0f} %, CPUs busy {100 * now['busy']:.0f} % at the start"
    )
    print(threads_text(_RUN["threads"]))
    if not _RUN["quiet"]:
        print(f"LOADED: 1-minute load {m['load_average'][0]} > {QUIET_LOAD} at the start: not a README figure")
    atexit.register(_write)
    return _RUN


def record(key: str, **values) -> None:
    """Keep ``values`` (numbers in seconds / bytes / ratios, strings) under ``key``."""
    if _RUN:
        _RUN["figures"].setdefault(key, {}).update(values)


def _write() -> None:
    if not _RUN or not _RUN["figures"]:
        return
    _RUN["load_average_end"] = [round(v, 2) for v in os.getloadavg()]
    _RUN["load_1min_end"] = _RUN["load_average_end"][0]
    _RUN["threads_end"] = threads()  # a pool a peer started during the run (cv2, BLAS) shows here
    _RUN["steal_during"] = round(steal_between(_RUN.pop("cpu_times_start", cpu_times()), cpu_times()), 3)
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{_RUN['benchmark']}.json"
    path.write_text(json.dumps(_RUN, indent=1) + "\n")
    print(
        f"figures written to {os.path.relpath(path)} (load average at the end {_RUN['load_average_end']}, "
        f"CPU steal during the run {100 * _RUN['steal_during']:.0f} %)"
    )


def median_times(fns: dict[str, Callable[[], object]], repeat: int = 5, warmup: int = 1) -> dict[str, float]:
    """Median wall times of several functions run *interleaved* (a, b, a,
    b, ...), so that a change in the machine's load hits all of them alike:
    the fair way to measure a ratio on a shared machine."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


_WRAPPER = """
import resource, subprocess, sys, time
t0 = time.perf_counter()
code = subprocess.run(sys.argv[1:], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
dt = time.perf_counter() - t0
sys.stdout.buffer.write(code.stdout)
print("\\n@@", code.returncode, dt, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


def run_process(cmd: list[str], env: dict | None = None, cwd=None) -> tuple[float, int]:
    """Run a command to completion: ``(wall seconds, peak resident bytes)``
    of that one process.  It is started by a small Python wrapper, whose
    child's ``ru_maxrss`` (KiB on Linux) is the command's own peak: Linux
    keeps the peak across ``exec``, so a child forked straight from this
    (large) process would report at least this process's size.  Raises if
    the command fails, printing its output."""
    out = subprocess.run([sys.executable, "-c", _WRAPPER, *cmd], env=env, cwd=cwd, capture_output=True, check=True)
    text = out.stdout.decode(errors="replace")
    body, _, tail = text.rpartition("\n@@ ")
    code, dt, maxrss = tail.split()
    if int(code) != 0:
        sys.stdout.write(body)
        raise RuntimeError(f"{shlex.join(cmd)} failed with exit code {code}")
    return float(dt), int(maxrss) * 1024


def median_time(
    fn: Callable[[], object], repeat: int = 7, warmup: int = 1, clock: Callable[[], float] = time.perf_counter
) -> float:
    """Median time of ``fn()`` in seconds over ``repeat`` runs, by ``clock``
    (wall time by default).

    ``fn`` must block until its result is ready (call
    ``jax.block_until_ready`` inside it for JAX results).
    """
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return statistics.median(times)


def median_cpu_time(fn: Callable[[], object], repeat: int = 7, warmup: int = 1) -> float:
    """Median process CPU time (all threads) of ``fn()``: less sensitive
    than wall time to other jobs on a shared machine."""
    return median_time(fn, repeat, warmup, clock=time.process_time)


def peak_rss() -> int:
    """Absolute peak resident set size of this process so far, in bytes."""
    return _vm_hwm_bytes()


def _vm_hwm_bytes() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmHWM in /proc/self/status")


def _vm_rss_bytes() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def peak_memory(fn: Callable[[], object]) -> tuple[object, int]:
    """Run ``fn`` and return ``(result, peak resident bytes above the start)``.

    Resets the kernel's high-water mark (``echo 5 > /proc/self/clear_refs``)
    so native allocations (XLA, OpenCV, GDAL) count as well as Python's,
    which tracemalloc alone would miss.
    """
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:  # not Linux, or not allowed: report the absolute peak
        pass
    base = _vm_rss_bytes()
    result = fn()
    return result, max(_vm_hwm_bytes() - base, 0)


def ratio_line(name: str, ours: float, peer: float) -> str:
    """``name: photax 1.23 ms, peer 4.56 ms, ratio photax/peer 0.27``; the
    figures are also recorded for the run's JSON (:func:`start`)."""
    record(name, photax_s=ours, peer_s=peer, ratio=ours / peer)
    return f"{name}: photax {ours * 1e3:.3f} ms, peer {peer * 1e3:.3f} ms, ratio photax/peer {ours / peer:.2f}"


def mib(nbytes: int) -> str:
    return f"{nbytes / 2**20:.0f} MiB"


if __name__ == "__main__":  # a quick self-check of the memory probe
    import numpy as np

    _, peak = peak_memory(lambda: np.ones((4096, 4096)).sum())
    print("128 MiB array ->", mib(peak), "pid", os.getpid())
