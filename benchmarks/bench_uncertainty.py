"""Cost of the per-pixel geolocation uncertainty against the ortho itself
(issue 12: ``ortho_uncertainty`` at most 2x ``orthorectify`` on the same grid).

    python benchmarks/bench_uncertainty.py [--size 1000] [--oversample 2] [--repeat 5]

A rendered relief scene (``photax.relief_scene``, ``--size`` x 0.8 ``--size``
pixels), its ortho grid at the image's ground sampling distance divided by
``--oversample`` (more output pixels per image pixel, as a fine ortho is made).
Timed on that grid, in one process:

* ``photax.orthorectify`` (default: approximate mapping, bilinear), the
  image in memory, the result in memory;
* ``photax.ortho_uncertainty`` with an exterior covariance, intrinsics
  covariance and a DEM sigma (default ``step=16``: exact propagation on a
  16-pixel lattice, bilinear in between, the DEM's slope at every pixel),
  full-resolution rasters in memory; and with ``coarsen=4``.

First calls (tracing and compilation included) are timed once each, in
that order; warm times are medians of ``--repeat`` runs interleaved
(``_common.median_times``), wall and CPU (process time of all threads),
so the ratios are robust to the machine's load.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _common import median_times, record, start  # noqa: E402

import photax  # noqa: E402
from photax.rectification import ortho_grid  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=1000, help="image width in pixels (height 0.8 x)")
    ap.add_argument("--oversample", type=float, default=2.0, help="ortho pixels per image pixel along each axis")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    start("bench_uncertainty")
    w = args.size
    s = photax.relief_scene(300.0, image_size=(w, w * 4 // 5), focal_px=float(w), n_gcp=3, n_check=0, tilt_deg=4.0)
    gsd = ortho_grid(s.exterior, s.camera, s.dem).transform.a
    grid = ortho_grid(s.exterior, s.camera, s.dem, resolution=gsd / args.oversample)
    mpix = grid.shape[0] * grid.shape[1] / 1e6
    print(
        f"image {w} x {w * 4 // 5}, ortho grid {grid.shape[1]} x {grid.shape[0]} ({mpix:.2f} MPix), "
        f"DEM {s.dem.heights.shape[1]} x {s.dem.heights.shape[0]}"
    )
    std = np.array([1.0, 1.0, 0.5, 4e-4, 4e-4, 2.5e-4])
    cov, cov_c = np.diag(std**2), np.diag([0.8, 0.5, 0.5]) ** 2
    image = np.asarray(s.image)

    def ortho():
        return photax.orthorectify(image, s.exterior, s.camera, s.dem, grid=grid)

    def sigma(coarsen=1):
        return photax.ortho_uncertainty(
            s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c, dem_sigma=1.0, coarsen=coarsen
        ).ground_var

    fns = {"ortho": ortho, "uncertainty": sigma, "uncertainty coarsen=4": lambda: sigma(4)}
    first = {}
    for k, fn in fns.items():
        t0 = time.perf_counter()
        fn()
        first[k] = time.perf_counter() - t0
    warm = median_times(fns, repeat=args.repeat, warmup=0)
    cpu = {k: [] for k in fns}  # process time of all threads: less sensitive to other jobs than wall time
    for _ in range(args.repeat):
        for k, fn in fns.items():
            t0 = time.process_time()
            fn()
            cpu[k].append(time.process_time() - t0)
    cpu = {k: float(np.median(v)) for k, v in cpu.items()}
    load = os.getloadavg()[0]
    for k in fns:
        print(
            f"{k:24s} first call {first[k]:6.2f} s, warm {warm[k]:6.3f} s wall ({mpix / warm[k]:5.1f} MPix/s) "
            f"{cpu[k]:6.3f} s CPU; / ortho: wall {warm[k] / warm['ortho']:.2f}, CPU {cpu[k] / cpu['ortho']:.2f}"
        )
        record(
            k,
            first_s=first[k],
            warm_s=warm[k],
            cpu_s=cpu[k],
            mpix=mpix,
            ratio_to_ortho=warm[k] / warm["ortho"],
            cpu_ratio_to_ortho=cpu[k] / cpu["ortho"],
        )
    print(f"load average (1 min) at the end: {load:.2f}")


if __name__ == "__main__":
    main()
