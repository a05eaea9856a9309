"""Sub-pixel locators: photax vs OpenCV on the same points.

    PYTHONPATH=src python benchmarks/bench_measure_locators.py [--points 10000]

1. Förstner corner locator (``locate_corners``) on N corners vs
   ``cv2.cornerSubPix`` (the same method, one call for all corners);
2. least-squares matching (``match_lsm``, 21 x 21 templates) and
   ``match_ncc`` on N points vs a Python loop of ``cv2.matchTemplate``
   (TM_CCOEFF_NORMED) + parabola peak fit on the same points.
The images tile 100 rendered patterns (corners / shifted textures with gain
0.9, offset 0.05) so that N points need no N renders.  Reported: first call
(with compilation) and warm median, ratio photax / OpenCV (below 1: photax
faster), peak memory above the start, and the RMSE against the known truth.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import median_time, mib, peak_memory, ratio_line  # noqa: E402

import photax  # noqa: E402,F401
from photax.measure import locate_corners, match_lsm, match_ncc  # noqa: E402
from photax.measure import _render as R  # noqa: E402

TILE, C, KINDS = 45, 22, 100


def tiled(patches, n):
    """Tile ``n`` patches (cycling through ``patches``) into one square-ish image; returns it and the tile origins."""
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    img = np.zeros((rows * TILE, cols * TILE))
    origin = np.zeros((n, 2))
    for i in range(n):
        r, c = divmod(i, cols)
        img[r * TILE:(r + 1) * TILE, c * TILE:(c + 1) * TILE] = patches[i % len(patches)]
        origin[i] = (c * TILE, r * TILE)
    return img, origin


def rmse(e):
    return float(np.sqrt(np.nanmean(np.sum(e**2, axis=1))))


def timed(name, fn, repeat):
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    warm = median_time(fn, repeat=repeat, warmup=0)
    _, peak = peak_memory(fn)
    print(f"{name}: first call {first:.2f} s, warm median {warm * 1e3:.1f} ms, peak memory {mib(peak)}")
    return out, warm


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    n = args.points
    sys.stdout.reconfigure(line_buffering=True)
    print(f"jax {jax.__version__}, OpenCV {cv2.__version__}, {n} points, load average {os.getloadavg()}")
    rng = np.random.default_rng(0)

    # --- corners: blur 0.7, noise 1 %
    kinds, truths = [], []
    for _ in range(KINDS):
        t = C + rng.uniform(-0.5, 0.5, 2)
        kinds.append(R.render(R.corner(t, rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(60, 120))),
                              (TILE, TILE), blur=0.7, noise=0.01, rng=rng))
        truths.append(t)
    img, origin = tiled(kinds, n)
    truth = origin + np.array(truths)[np.arange(n) % KINDS]
    approx = truth + rng.uniform(-1, 1, truth.shape)
    img32 = img.astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)

    def ours():
        return np.asarray(jax.block_until_ready(locate_corners(img, approx).xy))

    def theirs():
        return cv2.cornerSubPix(img32, approx[:, None].astype(np.float32).copy(), (14, 14), (-1, -1), crit)[:, 0]

    xy, t_ours = timed("locate_corners", ours, args.repeat)
    cxy, t_cv = timed("cv2.cornerSubPix", theirs, args.repeat)
    print(ratio_line(f"corners x{n} (warm)", t_ours, t_cv))
    print(f"corners rmse: photax {rmse(xy - truth):.4f} px, cornerSubPix {rmse(cxy - truth):.4f} px")

    # --- matching: 21 x 21 templates, gain 0.9, offset 0.05, noise 1 %
    shifts = rng.uniform(-2, 2, (KINDS, 2))
    tk = [R.texture((TILE, TILE), seed=i, noise=0.01, rng=rng) for i in range(KINDS)]
    sk = [0.9 * R.texture((TILE, TILE), seed=i, shift=s, noise=0.01 / 0.9, rng=rng) + 0.05
          for i, s in enumerate(shifts)]
    timg, origin = tiled(tk, n)
    simg, _ = tiled(sk, n)
    txy = origin + C
    truth = txy + shifts[np.arange(n) % KINDS]
    approx = np.round(truth) + rng.integers(-1, 2, truth.shape)
    w, s = 10, 4
    t32, s32 = timg.astype(np.float32), simg.astype(np.float32)

    def lsm():
        return np.asarray(jax.block_until_ready(match_lsm(timg, txy, simg, approx, window=w).xy))

    def ncc():
        return np.asarray(jax.block_until_ready(match_ncc(timg, txy, simg, approx, window=w, search=s).xy))

    def cv_ncc():
        out = np.empty((n, 2))
        ti = txy.astype(int)
        ai = approx.astype(int)
        for i in range(n):
            tpl = t32[ti[i, 1] - w:ti[i, 1] + w + 1, ti[i, 0] - w:ti[i, 0] + w + 1]
            big = s32[ai[i, 1] - w - s:ai[i, 1] + w + s + 1, ai[i, 0] - w - s:ai[i, 0] + w + s + 1]
            cc = cv2.matchTemplate(big, tpl, cv2.TM_CCOEFF_NORMED)
            _, _, _, (x, y) = cv2.minMaxLoc(cc)
            dx = dy = 0.0
            if 0 < x < cc.shape[1] - 1:
                a, b, c = cc[y, x - 1], cc[y, x], cc[y, x + 1]
                dx = 0.5 * (a - c) / (a - 2 * b + c)
            if 0 < y < cc.shape[0] - 1:
                a, b, c = cc[y - 1, x], cc[y, x], cc[y + 1, x]
                dy = 0.5 * (a - c) / (a - 2 * b + c)
            out[i] = ai[i] + (x - s + dx, y - s + dy)
        return out

    lxy, t_lsm = timed("match_lsm", lsm, args.repeat)
    nxy, t_ncc = timed("match_ncc", ncc, args.repeat)
    cxy, t_cv = timed("cv2.matchTemplate + parabola (Python loop)", cv_ncc, args.repeat)
    print(ratio_line(f"LSM x{n} vs matchTemplate+parabola (warm)", t_lsm, t_cv))
    print(ratio_line(f"NCC x{n} vs matchTemplate+parabola (warm)", t_ncc, t_cv))
    print(f"matching rmse: LSM {rmse(lxy - truth):.4f} px, photax NCC {rmse(nxy - truth):.4f} px, "
          f"matchTemplate+parabola {rmse(cxy - truth):.4f} px")
    print(f"load average at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()
