"""photax.measure Canny and Sobel vs scikit-image and OpenCV on a 4096 x 4096 image.

    python benchmarks/bench_measure.py [--size 4096] [--repeat 5] [--json out.json]

Image: uint8, smoothed noise plus bright discs and rectangles (edges of all
directions).  Same parameters for every library where they have them:

* Sobel magnitude: photax ``sobel`` (float64, ``skimage.filters.sobel``'s
  definition) vs ``skimage.filters.sobel`` vs ``cv2.Sobel`` dx, dy (CV_64F,
  ksize 3, reflect border) + ``cv2.magnitude``.
* Canny, sigma 1.4, thresholds 0.1 / 0.2 of the range: photax ``canny`` vs
  ``skimage.feature.canny`` (same algorithm) vs ``cv2.GaussianBlur`` +
  ``cv2.Canny(L2gradient=True)`` (OpenCV has no smoothing inside Canny;
  its non-maximum suppression is the unsnapped 4-sector one, not the
  interpolated one, so its map differs slightly).

Prints first-call (compile + run) and warm times (median of --repeat runs;
wall and process CPU time),
ratios photax / peer, photax's peak memory, the load average, and writes
the figures to --json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import cv2
import jax
import numpy as np
import scipy.ndimage as ndi
from _common import mib, peak_memory, ratio_line
from skimage import feature, filters

import photax as ptx


def test_image(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    img = ndi.gaussian_filter(rng.random((n, n)), 3.0) * 400.0
    r, c = np.ogrid[0:n, 0:n]
    for _ in range(60):
        cy, cx, rad = rng.uniform(0, n), rng.uniform(0, n), rng.uniform(n / 80, n / 12)
        img[(r - cy) ** 2 + (c - cx) ** 2 < rad**2] += 60.0
        y0, x0 = rng.integers(0, n - n // 10, 2)
        img[y0:y0 + n // 12, x0:x0 + n // 15] -= 50.0
    img -= img.min()
    return np.clip(img / img.max() * 255.0, 0, 255).astype(np.uint8)


def wall_and_cpu(fn, repeat):
    """Medians of wall and process CPU time over ``repeat`` runs after one
    warm-up: on a shared machine the CPU time is the steadier figure."""
    fn()
    walls, cpus = [], []
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return float(np.median(walls)), float(np.median(cpus))


def timed_first(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=4096)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", default="bench_measure.json")
    args = ap.parse_args(argv)
    n, rep = args.size, args.repeat
    print("command:", " ".join([os.path.basename(sys.executable)] + sys.argv))
    load = os.getloadavg()
    print(f"{n} x {n} uint8, median of {rep} warm runs; load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} "
          f"on {os.cpu_count()} cores; jax {jax.__version__}, OpenCV {cv2.__version__}")
    img = test_image(n)
    jimg = jax.device_put(img)
    lo, hi = 0.1 * float(np.ptp(img)), 0.2 * float(np.ptp(img))
    sigma = 1.4
    f_img = img.astype(np.float64)
    results: dict = {"size": n, "repeat": rep, "load_average": load, "cores": os.cpu_count()}

    # ---- Sobel magnitude
    def ours_sobel():
        return jax.block_until_ready(ptx.measure.sobel(jimg))

    def cv_sobel():
        gx = cv2.Sobel(img, cv2.CV_64F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT)
        gy = cv2.Sobel(img, cv2.CV_64F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT)
        return cv2.magnitude(gx, gy)

    first = timed_first(ours_sobel)
    t_ours, c_ours = wall_and_cpu(ours_sobel, rep)
    t_sk, c_sk = wall_and_cpu(lambda: filters.sobel(img), rep)
    t_cv, c_cv = wall_and_cpu(cv_sobel, rep)
    _, mem = peak_memory(ours_sobel)
    # same answer (OpenCV's magnitude is 4 sqrt(2) x skimage's definition)
    dev = float(np.max(np.abs(np.asarray(ours_sobel()) * 4.0 * np.sqrt(2.0) - cv_sobel())[1:-1, 1:-1]))
    print(f"Sobel  first call {first:.2f} s; |photax*4sqrt2 - OpenCV| max {dev:.1e} (grey/px)")
    print("  " + ratio_line("vs scikit-image", t_ours, t_sk))
    print("  " + ratio_line("vs OpenCV      ", t_ours, t_cv), f"| photax peak {mib(mem)}")
    print(f"  CPU time: photax {c_ours * 1e3:.1f} ms, scikit-image {c_sk * 1e3:.1f} ms, OpenCV {c_cv * 1e3:.1f} ms;"
          f" ratios {c_ours / c_sk:.2f}, {c_ours / c_cv:.2f}")
    results["sobel"] = {"photax_first_s": first, "photax_s": t_ours, "skimage_s": t_sk, "opencv_s": t_cv,
                        "ratio_skimage": t_ours / t_sk, "ratio_opencv": t_ours / t_cv, "photax_peak_bytes": mem,
                        "cpu_s": {"photax": c_ours, "skimage": c_sk, "opencv": c_cv}}

    # ---- Canny
    def ours_canny():
        return jax.block_until_ready(ptx.measure.canny(jimg, sigma, lo, hi))

    def sk_canny():
        return feature.canny(f_img, sigma, lo, hi)

    ksize = 2 * int(4.0 * sigma + 0.5) + 1

    def cv_canny():
        blur = cv2.GaussianBlur(img, (ksize, ksize), sigma, borderType=cv2.BORDER_CONSTANT)
        return cv2.Canny(blur, lo, hi, L2gradient=True)  # unnormalised 3x3 Sobel magnitude, as ours

    first = timed_first(ours_canny)
    t_ours, c_ours = wall_and_cpu(ours_canny, rep)
    t_sk, c_sk = wall_and_cpu(sk_canny, max(1, rep // 2))
    t_cv, c_cv = wall_and_cpu(cv_canny, rep)
    _, mem = peak_memory(ours_canny)
    a, b, c = np.asarray(ours_canny()), sk_canny(), cv_canny() > 0
    f1_sk = 2 * (a & b).sum() / (a.sum() + b.sum())
    f1_cv = 2 * (a & c).sum() / (a.sum() + c.sum())
    print(f"Canny  first call {first:.2f} s; F1 vs scikit-image {f1_sk:.4f}, vs OpenCV {f1_cv:.3f}; "
          f"{a.sum()} edge pixels")
    print("  " + ratio_line("vs scikit-image", t_ours, t_sk))
    print("  " + ratio_line("vs OpenCV      ", t_ours, t_cv), f"| photax peak {mib(mem)}")
    print(f"  CPU time: photax {c_ours * 1e3:.1f} ms, scikit-image {c_sk * 1e3:.1f} ms, OpenCV {c_cv * 1e3:.1f} ms;"
          f" ratios {c_ours / c_sk:.2f}, {c_ours / c_cv:.2f}")
    results["canny"] = {"photax_first_s": first, "photax_s": t_ours, "skimage_s": t_sk, "opencv_s": t_cv,
                        "ratio_skimage": t_ours / t_sk, "ratio_opencv": t_ours / t_cv, "photax_peak_bytes": mem,
                        "cpu_s": {"photax": c_ours, "skimage": c_sk, "opencv": c_cv}, "f1_skimage": f1_sk, "f1_opencv": f1_cv}
    results["load_average_end"] = os.getloadavg()
    with open(args.json, "w") as fh:
        json.dump(results, fh, indent=1)
    print("wrote", args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
