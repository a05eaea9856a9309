"""GCP files of 10^4-10^6 lines: reading them, and ``photax resect`` on them (issue 27).

    python benchmarks/bench_gcp_io.py [--sizes 10000 100000 1000000] [--resect 10000 100000] [--line-by-line]

Synthetic measurements of the sample image (``data/sample_camera.yaml``,
the orientation of ``data/sample_truth.json``): ground points over its
footprint, projected, 0.3 px of noise, written as a GCP CSV with every
column (``name,image,E,N,h,col,row,sigma,role``).  For each size:
:func:`photax.read_gcps` (the whole-file parser), and with
``--line-by-line`` the line-by-line parser it falls back to for files it
cannot take whole (what every file went through before 2026-11-27; 10^6
lines took 16 s and 1 GB then).  ``--resect``: the whole ``photax resect``
process (warm compile cache, output to a file) for those sizes: parsing,
validation, the adjustment with blunder testing, the report.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _common import record, run_process, start  # noqa: E402

import photax as ptx  # noqa: E402
from photax.io import gcp  # noqa: E402

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"


def write_gcps(path: pathlib.Path, n: int, seed: int = 1) -> pathlib.Path:
    """``n`` synthetic measurements of the sample image (module docstring)."""
    truth = json.loads((DATA / "sample_truth.json").read_text())
    cam = ptx.read_camera(DATA / "sample_camera.yaml")
    eo = ptx.ExteriorOrientation(truth["position"], truth["angles_rad"])
    rng = np.random.default_rng(seed)
    centre = np.asarray(truth["position"])
    g = np.column_stack([centre[:2] + rng.uniform(-250.0, 250.0, (3 * n, 2)), rng.uniform(30.0, 70.0, 3 * n)])
    px = np.asarray(cam.image_to_pixel(ptx.project(g, eo, cam)))
    inside = np.all((px > 0) & (px < np.asarray(cam.image_size) - 1), axis=1)
    g, px = g[inside][:n], px[inside][:n] + rng.normal(0.0, 0.3, (n, 2))
    with open(path, "w") as fh:
        fh.write(f"# crs: {truth['crs']}\nname,image,E,N,h,col,row,sigma,role\n")
        fh.writelines(
            f"P{i},IMG_0001,{a:.3f},{b:.3f},{c:.3f},{d:.3f},{e:.3f},0.3,control\n"
            for i, (a, b, c, d, e) in enumerate(np.column_stack([g, px]).tolist())
        )
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--resect", type=int, nargs="*", default=[10_000, 100_000])
    ap.add_argument("--line-by-line", action="store_true", help="also time the line-by-line parser")
    args = ap.parse_args()
    start("bench_gcp_io")
    with tempfile.TemporaryDirectory() as tmp:
        files = {n: write_gcps(pathlib.Path(tmp) / f"g{n}.csv", n) for n in sorted(set(args.sizes + args.resect))}
        for n in args.sizes:
            t0 = time.perf_counter()
            gcp.read_gcps(files[n])
            fig = {"read_s": time.perf_counter() - t0}
            if args.line_by_line:
                fast, gcp._fast_rows = gcp._fast_rows, lambda *a, **k: None
                t0 = time.perf_counter()
                gcp.read_gcps(files[n])
                fig["line_by_line_s"] = time.perf_counter() - t0
                gcp._fast_rows = fast
            print(f"read_gcps, {n:>9,} lines: " + ", ".join(f"{k} {v:.2f}" for k, v in fig.items()))
            record(f"read_gcps {n} lines", **fig)
        camera = str(DATA / "sample_camera.yaml")
        for n in args.resect:
            cmd = [
                sys.executable,
                "-c",
                "import sys; from photax.cli import main; sys.exit(main(sys.argv[1:]))",
                "resect",
                str(files[n]),
                "--camera",
                camera,
                "--json",
                str(pathlib.Path(tmp) / "r.json"),
            ]
            run_process(cmd)  # warms the compile cache for this point count
            wall, peak = run_process(cmd)
            print(f"photax resect, {n:>9,} GCPs: {wall:.2f} s, peak {peak / 2**20:.0f} MiB")
            record(f"photax resect {n} GCPs (whole process, warm cache)", photax_s=wall, peak_bytes=peak)


if __name__ == "__main__":
    main()
