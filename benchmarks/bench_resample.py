"""photax.resample vs OpenCV cv2.remap on a 4096 x 4096 image, same maps.

    python benchmarks/bench_resample.py [size] [dtype]

Maps: a mild affine + shear (every sample inside or near the image), float64
for photax (as the rectifier produces them), float32 for OpenCV (its only
float map type), both precomputed.  Border: replicate in both.  Prints median
wall times of interleaved runs as ratios photax / OpenCV and photax's peak
memory; the figures go to ``benchmarks/results/bench_resample.json``.

Kernels: nearest, bilinear and cubic have the same taps in both (cv2's cubic
is a = -0.75, photax's default a = -0.5).  photax's "lanczos" is Lanczos-3
(6 x 6 taps); OpenCV's INTER_LANCZOS4 is Lanczos-4 (8 x 8): a different
kernel, so that line also gives the ratio per tap; photax's "lanczos4" is
OpenCV's kernel, compared like with like.  OpenCV has no B-spline:
its cubic is the yardstick.
"""

import sys

import cv2
import jax
import numpy as np
from _common import median_times, mib, peak_memory, ratio_line, record, start

from photax.resampling import resample

# method -> (OpenCV flag, OpenCV taps per axis, photax taps per axis)
FLAGS = {
    "nearest": (cv2.INTER_NEAREST, 1, 1),
    "bilinear": (cv2.INTER_LINEAR, 2, 2),
    "cubic": (cv2.INTER_CUBIC, 4, 4),
    "lanczos": (cv2.INTER_LANCZOS4, 8, 6),
    "lanczos4": (cv2.INTER_LANCZOS4, 8, 8),
    "bspline": (cv2.INTER_CUBIC, 4, 4),
}


def main(n: int = 4096, dtype: str = "uint8") -> None:
    start(f"bench_resample_{n}_{dtype}")
    rng = np.random.default_rng(0)
    img = (rng.random((n, n)) * 255).astype(dtype)
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    cols, rows = c * 0.98 + 20.3 + 1e-3 * r, r * 1.01 - 10.7 + 1e-3 * c
    c32, r32 = cols.astype(np.float32), rows.astype(np.float32)
    jimg, jc, jr = (jax.device_put(v) for v in (img, cols, rows))
    print(f"{n} x {n} {dtype}, median of 5 interleaved runs")
    for method, (flag, k_cv, k_ours) in FLAGS.items():
        ours = lambda: jax.block_until_ready(resample(jimg, jc, jr, method))  # noqa: E731
        peer = lambda: cv2.remap(img, c32, r32, flag, borderMode=cv2.BORDER_REPLICATE)  # noqa: E731
        t = median_times({"photax": ours, "cv2": peer}, repeat=5)
        _, mem = peak_memory(ours)
        record(f"{method} photax peak memory", bytes=mem)
        note = {
            "lanczos": " (Lanczos-3, 6x6 taps, vs INTER_LANCZOS4, 8x8: kernels differ)",
            "lanczos4": " (Lanczos-4, 8x8 taps: the same kernel as INTER_LANCZOS4)",
        }.get(method, "")
        if method == "bspline":
            note = " (vs cv2 INTER_CUBIC: OpenCV has no B-spline)"
        print(ratio_line(f"{method:8s}{note}", t["photax"], t["cv2"]), f"peak {mib(mem)}")
        if k_cv != k_ours:
            per_tap = (t["photax"] / k_ours**2) / (t["cv2"] / k_cv**2)
            record(f"{method} per tap vs cv2", ratio=per_tap)
            print(f"{method:8s} per tap (time / taps): ratio photax/peer {per_tap:.2f}")


if __name__ == "__main__":
    main(*(int(sys.argv[1]),) if len(sys.argv) > 1 else (), *sys.argv[2:3])
