"""Dense stereo: ``photax.disparity`` (semi-global matching) beside OpenCV's ``StereoSGBM`` on Middlebury's
Motorcycle pair with its ground truth (``skimage.data.stereo_motorcycle()``, 741 x 500, disparities 7-60 px).

    python benchmarks/bench_stereo.py [--repeat N]

Both on the same grey images (``rgb2gray * 255``; SGBM on their uint8), the same range 0..63:
OpenCV ``StereoSGBM_create(minDisparity=0, numDisparities=64, blockSize=3, P1=8*9, P2=32*9,
mode=STEREO_SGBM_MODE_SGBM_3WAY)`` (output / 16, negative = invalid), photax with its defaults
(census 5 x 5, 8 paths, uniqueness 0.02, left-right check 1 px, speckles < 50 px).  Accuracy: density,
bad-2.0 (|d - GT| > 2 px) of each method's own estimates and of all ground-truth pixels (a missing value
counts as bad).  Time: warm, median of ``--repeat`` runs interleaved in one process, and the ratio
photax / SGBM; the CPU model, thread settings and the load before and after are printed beside them.
Memory (``--big N``, default 2048; 0 skips it): an N x N synthetic pair (tests/test_disparity.py's
smooth field) over the same 64 disparities, cut into tiles automatically: its peak resident memory
above the start and its time (one run), beside the size one untiled int16 cost volume would have.
Writes ``benchmarks/results/bench_stereo.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

import numpy as np
from _common import load_now, median_times, mib, peak_memory, record, start

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from test_disparity import _smooth_pair  # noqa: E402 -- the tests' exact synthetic pair

import photax as ptx  # noqa: E402


def _scores(d, gt):
    valid = np.isfinite(gt)
    ok = np.isfinite(d) & valid
    e = np.abs(d - gt)
    return dict(
        density=float(np.isfinite(d).mean()),
        bad2_own=float((e[ok] > 2.0).mean()),
        bad2_all=float(1 - ((e <= 2.0) & ok).sum() / valid.sum()),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per method (median)")
    parser.add_argument("--big", type=int, default=2048, help="side of the memory check's pair (0: skip)")
    args = parser.parse_args()
    import cv2
    import jax
    from skimage.color import rgb2gray
    from skimage.data import stereo_motorcycle

    run = start("bench_stereo")
    left, right, gt = stereo_motorcycle()  # gt: disparity of the left image, inf where unknown
    left, right = rgb2gray(left) * 255, rgb2gray(right) * 255
    l8, r8 = left.astype(np.uint8), right.astype(np.uint8)
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=64, blockSize=3, P1=8 * 9, P2=32 * 9, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY
    )

    def ours():
        return ptx.disparity(left, right, disparity_range=(0, 63))

    def peer():
        d = sgbm.compute(l8, r8).astype(np.float32) / 16
        d[d < 0] = np.nan
        return d

    threads = dict(
        opencv_threads=cv2.getNumThreads(),
        jax_devices=str(jax.devices()),
        **{k: os.environ.get(k, "unset") for k in ("XLA_FLAGS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")},
    )
    print("threads:", ", ".join(f"{k}={v}" for k, v in threads.items()))
    s_ours, s_peer = _scores(ours(), gt), _scores(peer(), gt)
    t = median_times({"photax": ours, "sgbm": peer}, repeat=args.repeat, warmup=1)
    end = load_now()
    for name, s, dt in (("photax.disparity", s_ours, t["photax"]), ("OpenCV SGBM 3-way", s_peer, t["sgbm"])):
        print(f"{name:18s}: density {s['density']:.3f}, bad-2.0 {100 * s['bad2_own']:.1f} % of its estimates, "
              f"{100 * s['bad2_all']:.1f} % of all GT pixels (missing = bad), {dt * 1e3:.0f} ms")  # fmt: skip
    ratio = t["photax"] / t["sgbm"]
    print(f"time ratio photax / SGBM {ratio:.1f} (warm, median of {args.repeat}, interleaved, one process)")
    print(f"load average {end['load_average']} (1, 5, 15 min) at the end, CPUs busy {100 * end['busy']:.0f} %")
    record(
        "motorcycle_0_63",
        photax_s=t["photax"],
        peer_s=t["sgbm"],
        ratio=ratio,
        **{f"photax_{k}": v for k, v in s_ours.items()},
        **{f"sgbm_{k}": v for k, v in s_peer.items()},
        cpu_model=run["machine"]["cpu_model"],
        **{k: str(v) for k, v in threads.items()},
    )
    if args.big:
        left, right, _ = _smooth_pair(h=args.big, w=args.big)
        t0 = time.perf_counter()
        _, peak = peak_memory(lambda: ptx.disparity(left, right, disparity_range=(0, 63)))
        dt = time.perf_counter() - t0
        volume = args.big * args.big * 64 * 2
        print(f"{args.big} x {args.big} pair, 64 disparities, automatic tiles: peak memory {mib(peak)} above the "
              f"start (one untiled int16 cost volume alone: {mib(volume)}), {dt:.1f} s incl. compiling")  # fmt: skip
        record(f"memory_{args.big}", peak_bytes=peak, untiled_volume_bytes=volume, seconds=dt)


if __name__ == "__main__":
    main()
