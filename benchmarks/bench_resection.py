"""Space resection: photax vs OpenCV solvePnP (ITERATIVE, SQPNP) on the same GCPs.

    /work/venv/bin/python benchmarks/bench_resection.py [--images 10000]

1. single-call latency after compilation (median of many calls), 12 GCPs;
2. throughput for N synthetic images (12 GCPs each): one resect_batch call
   vs a Python loop of cv2.solvePnP over the same images.
Ratios are photax / peer (below 1: photax faster).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import median_time, mib, peak_memory, ratio_line  # noqa: E402

import photax as ptx  # noqa: E402

F, W, H = 3000.0, 4000, 3000
CAM = ptx.FrameCamera.from_pixels(F, (W, H))
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])


def scenes(rng, b, n=12):
    """b images of n GCPs each (UTM coordinates, 0.5 px noise), any kappa."""
    px = np.stack([rng.uniform(100, W - 100, (b, n)), rng.uniform(100, H - 100, (b, n))], axis=-1)
    xy = np.asarray(CAM.pixel_to_image(px))
    ground = np.empty((b, n, 3))
    for i in range(b):
        eo = ptx.ExteriorOrientation(np.array([500_000.0, 4_000_000.0, 0.0]) + np.array([rng.uniform(-1000, 1000), rng.uniform(-1000, 1000), rng.uniform(700, 1200)]),
                                     [rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-np.pi, np.pi)])
        ground[i] = np.asarray(ptx.image_to_ground(xy[i], eo, CAM, height=rng.uniform(80, 140, n)))
    xy = xy + rng.normal(0, 0.5, xy.shape)
    return xy, ground, np.asarray(CAM.image_to_pixel(xy))


def opencv(ground, pixel, flag):
    origin = ground.mean(0)  # OpenCV needs the same reduction to a local origin
    ok, rvec, tvec = cv2.solvePnP(ground - origin, pixel, K, None, flags=flag)
    return rvec, tvec


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--images", type=int, default=10_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    xy, ground, pixel = scenes(rng, args.images)
    sys.stdout.reconfigure(line_buffering=True)
    print(f"jax {jax.__version__}, OpenCV {cv2.__version__}, {args.images} images x 12 GCPs")

    # --- single-call latency
    t_robust = median_time(lambda: ptx.resect(xy[0], ground[0], CAM), repeat=51, warmup=2)
    t_plain = median_time(lambda: ptx.resect(xy[0], ground[0], CAM, robust=False), repeat=51, warmup=2)
    t_it = median_time(lambda: opencv(ground[0], pixel[0], cv2.SOLVEPNP_ITERATIVE), repeat=201)
    t_sq = median_time(lambda: opencv(ground[0], pixel[0], cv2.SOLVEPNP_SQPNP), repeat=201)
    print(ratio_line("latency resect (robust) vs ITERATIVE", t_robust, t_it))
    print(ratio_line("latency resect (robust=False) vs ITERATIVE", t_plain, t_it))
    print(ratio_line("latency resect (robust=False) vs SQPNP", t_plain, t_sq))

    # --- throughput
    def batch(robust):
        return lambda: jax.block_until_ready(ptx.resect_batch(xy, ground, CAM, robust=robust).exterior.position)

    def loop(flag):
        return lambda: [opencv(ground[i], pixel[i], flag) for i in range(args.images)]

    batch(False)()
    batch(True)()  # compile
    tb = median_time(batch(False), repeat=3, warmup=0)
    tbr = median_time(batch(True), repeat=3, warmup=0)
    tl_sq = median_time(loop(cv2.SOLVEPNP_SQPNP), repeat=3, warmup=0)
    tl_it = median_time(loop(cv2.SOLVEPNP_ITERATIVE), repeat=3, warmup=0)
    print(ratio_line(f"{args.images} images resect_batch(robust=False) vs SQPNP loop", tb, tl_sq))
    print(ratio_line(f"{args.images} images resect_batch(robust=True) vs SQPNP loop", tbr, tl_sq))
    print(ratio_line(f"{args.images} images resect_batch(robust=False) vs ITERATIVE loop", tb, tl_it))
    res, mem = peak_memory(lambda: ptx.resect_batch(xy, ground, CAM))
    _, mem_cv = peak_memory(loop(cv2.SOLVEPNP_SQPNP))
    print(f"peak memory: resect_batch {mib(mem)}, OpenCV SQPNP loop {mib(mem_cv)}; "
          f"converged {int(np.sum(res.converged))}/{args.images}")
    # same answer: photax's centres vs SQPnP's (both least squares on the same points)
    r, t = opencv(ground[0], pixel[0], cv2.SOLVEPNP_ITERATIVE)
    c_cv = ground[0].mean(0) - cv2.Rodrigues(r)[0].T @ t.ravel()
    print(f"image 0: |C_photax - C_opencv| = {np.linalg.norm(np.asarray(res[0].exterior.position) - c_cv):.2e} m")


if __name__ == "__main__":
    main()
