"""Tie matching on the real NGI block: photax.match_ties against OpenCV SIFT (issue 21 item 2, issue 25).

    python benchmarks/bench_ties_real.py [--repeat N] [--points N] [--data DIR]

The four NGI frames of orthority's corpus (``DIR/orthority``, default ../shared/data; 640 x 1152 px, two
strips flown in opposite directions), as grey images in memory (reading not timed), all 6 pairs:

* ``photax``: ``photax.match_ties`` from the survey's orientations moved by 15 m and 0.15 deg (seeded),
  with the DEM (``--points`` interest points per image, ``min_rho`` 0.6, as tests/test_ties_real.py);
* ``OpenCV SIFT``: ``cv2.SIFT_create(4000)`` on each image, brute-force 2-NN matching with Lowe's ratio
  test (0.8) on each pair, a RANSAC fundamental matrix (2 px, 0.999) per pair (as benchmarks/gnss_ngi.py).

The first photax call (compilation) is timed on its own; then the two are run interleaved
(``_common.median_times``) and the medians of ``--repeat`` runs reported, with the load average and the
CPU steal over the run (``/proc/stat``).  The ties per pair of each are printed beside.  Issue 25's target:
photax warm <= 1x SIFT.  Figures go to ``benchmarks/results/bench_ties_real.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from _common import add_threads_option, apply_threads, median_times, ratio_line, record, start


def _cpu_ticks() -> tuple[int, int]:
    """(steal, total) jiffies of all CPUs so far."""
    with open("/proc/stat") as fh:
        v = [int(x) for x in fh.readline().split()[1:]]
    return v[7], sum(v)


def main() -> None:
    import cv2
    import jax
    import numpy as np
    import rasterio

    jax.config.update("jax_enable_x64", True)
    import photax
    from photax.io import read_dem, read_orthority_exterior, read_orthority_interior

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each (median)")
    ap.add_argument("--points", type=int, default=300, help="photax interest points per image")
    ap.add_argument(
        "--data", type=pathlib.Path, default=pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
    )
    add_threads_option(ap)
    args = ap.parse_args()
    apply_threads(args)
    ngi = args.data / "orthority"
    start("bench_ties_real")
    steal0 = _cpu_ticks()
    camera = next(iter(read_orthority_interior(ngi / "io" / "ngi_int_param.yaml").values()))
    survey = read_orthority_exterior(ngi / "io" / "ngi_xyz_opk.csv")
    names = sorted(p.stem for p in (ngi / "ngi").glob("*_RGB.tif"))
    images = []
    for n in names:
        with rasterio.open(ngi / "ngi" / f"{n}.tif") as src:
            images.append(src.read().astype(float).mean(axis=0))
    grey8 = [np.round(im).astype(np.uint8) for im in images]
    dem = read_dem(ngi / "ngi" / "dem.tif")
    rng = np.random.default_rng(21)
    exterior = []
    for n in names:
        e, d, a = survey[n], rng.normal(size=3), rng.normal(size=3)
        exterior.append(
            photax.ExteriorOrientation(
                np.asarray(e.position) + 15.0 * d / np.linalg.norm(d),
                np.asarray(e.angles) + np.radians(0.15) * a / np.linalg.norm(a),
                e.convention,
            )
        )
    out = {}

    def ours():
        out["photax"] = photax.match_ties(images, camera, exterior, dem, max_points=args.points, min_rho=0.6)

    def sift():
        det = cv2.SIFT_create(nfeatures=4000)
        feats = [det.detectAndCompute(im, None) for im in grey8]
        bf, inliers = cv2.BFMatcher(), {}
        for a in range(len(feats)):
            for b in range(a + 1, len(feats)):
                (ka, da), (kb, db) = feats[a], feats[b]
                m = [p for p, q in bf.knnMatch(da, db, k=2) if p.distance < 0.8 * q.distance]
                pa = np.float32([ka[x.queryIdx].pt for x in m])
                pb = np.float32([kb[x.trainIdx].pt for x in m])
                _, inl = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 2.0, 0.999)
                inliers[a, b] = 0 if inl is None else int(inl.sum())
        out["sift"] = inliers

    t0 = time.perf_counter()
    ours()
    first = time.perf_counter() - t0
    print(f"photax first call (compilation included): {first:.1f} s")
    record("photax first call", seconds=first)
    med = median_times({"photax": ours, "sift": sift}, repeat=args.repeat, warmup=0)
    print(ratio_line("NGI ties, 4 frames, 6 pairs (warm)", med["photax"], med["sift"]))
    steal1 = _cpu_ticks()
    steal = (steal1[0] - steal0[0]) / max(steal1[1] - steal0[1], 1)
    print(f"CPU steal over the run {100 * steal:.1f} %, load average {[round(v, 2) for v in os.getloadavg()]}")
    record("machine", steal_fraction=steal)
    short = [n[-7:] for n in names]
    ties = out["photax"]
    for (a, b), n in out["sift"].items():
        print(
            f"{short[a]}-{short[b]}: overlap {ties.pair_overlap[a, b]:.2f}, photax {ties.pair_ties[a, b]} ties "
            f"({ties.pair_status[a, b]}), SIFT {n} RANSAC inliers"
        )
        record(f"{short[a]}-{short[b]}", photax_ties=ties.pair_ties[a, b], sift_inliers=n)


if __name__ == "__main__":
    main()
