"""Shared timing and memory helpers for the benchmarks.

Machines here are noisy (2 cores): every figure is the median of several
runs, and results are reported as ratios photax / peer.
"""

from __future__ import annotations

import os
import statistics
import time
from typing import Callable


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
    """``name: photax 1.23 ms, peer 4.56 ms, ratio photax/peer 0.27``."""
    return f"{name}: photax {ours * 1e3:.3f} ms, peer {peer * 1e3:.3f} ms, ratio photax/peer {ours / peer:.2f}"


def mib(nbytes: int) -> str:
    return f"{nbytes / 2**20:.0f} MiB"


if __name__ == "__main__":  # a quick self-check of the memory probe
    import numpy as np

    _, peak = peak_memory(lambda: np.ones((4096, 4096)).sum())
    print("128 MiB array ->", mib(peak), "pid", os.getpid())
