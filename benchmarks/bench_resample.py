"""photax.resample vs OpenCV cv2.remap on a 4096 x 4096 image, same maps.

    python benchmarks/bench_resample.py [size] [dtype]

Maps: a mild affine + shear (every sample inside or near the image), float64
for photax (as the rectifier produces them), float32 for OpenCV (its only
float map type).  Border: replicate in both.  Prints median wall times as
ratios photax / OpenCV and photax's peak memory.
"""

import sys

import cv2
import jax
import numpy as np
from _common import mib, median_time, peak_memory, ratio_line

from photax.resample import resample

FLAGS = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC,
         "lanczos": cv2.INTER_LANCZOS4}


def main(n: int = 4096, dtype: str = "uint8") -> None:
    rng = np.random.default_rng(0)
    img = (rng.random((n, n)) * 255).astype(dtype)
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    cols, rows = c * 0.98 + 20.3 + 1e-3 * r, r * 1.01 - 10.7 + 1e-3 * c
    c32, r32 = cols.astype(np.float32), rows.astype(np.float32)
    jimg, jc, jr = (jax.device_put(v) for v in (img, cols, rows))
    print(f"{n} x {n} {dtype}, median of 5 runs")
    for method in ["nearest", "bilinear", "cubic", "lanczos", "bspline"]:
        ours = lambda: jax.block_until_ready(resample(jimg, jc, jr, method))  # noqa: E731
        flag = FLAGS.get(method, cv2.INTER_CUBIC)  # OpenCV has no B-spline: cubic as the yardstick
        peer = lambda: cv2.remap(img, c32, r32, flag, borderMode=cv2.BORDER_REPLICATE)  # noqa: E731
        t_ours, t_peer = median_time(ours, repeat=5), median_time(peer, repeat=5)
        _, mem = peak_memory(ours)
        print(ratio_line(f"{method:8s}", t_ours, t_peer), f"peak {mib(mem)}")


if __name__ == "__main__":
    main(*(int(sys.argv[1]),) if len(sys.argv) > 1 else (), *sys.argv[2:3])
