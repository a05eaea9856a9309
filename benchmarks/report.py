"""The README's benchmark table, regenerated from ``benchmarks/results/*.json``.

    python benchmarks/report.py [results/bench_rectify.json ...]

Each JSON is one benchmark run (``_common.start``): its command, date,
machine and load average, and its figures.  Prints a Markdown table per run
with the ratio photax / peer and, where issue 8 set one, the target.
"""

from __future__ import annotations

import json
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
# figure name (or its start) -> largest acceptable ratio photax / peer, and the
# issue that set it; a figure whose name starts with a key gets that target
TARGETS = {
    "poly bilinear vs cv2.remap": 2.0,  # issue 8
    "poly cubic vs cv2.remap": 2.0,
    # OpenCV has no Lanczos-3 (its INTER_LANCZOS4 is 8 x 8): GDAL's is the same 6 x 6 kernel
    "poly lanczos vs GDAL reproject (GCP_POLYNOMIAL order 3, 2 threads)": 3.0,
    "NGI ortho whole CLI process, warm compile cache, vs oty frame": 1.5,
    "NGI ortho whole CLI process peak memory": 1.5,
    # bench_startup: the README's resect command against oty frame's NGI ortho (issue 8)
    "photax resect whole process, warm compile cache": 1.5,
    # bench_resection (issue 8): the batch against OpenCV's SQPnP loop, one image against solvePnP
    "10000 images resect_batch(robust=True) vs SQPNP loop": 0.5,
    "10000 images resect_batch(robust=False) vs SQPNP loop": 0.5,
    "latency resect (robust) vs ITERATIVE, each back to back": 4.0,
    # bench_bundle (issue 13): BAL problem-49-7776 against Ceres DENSE_SCHUR, the 900-image block
    "vs Ceres DENSE_SCHUR": 0.75,
    "block 30x30": 1.0,
}
# figures whose ratio has another key: (key, target) (issue 12)
OTHER_RATIOS = {
    "photax to_raster": ("peak_over_chunk", 2.0),
    "uncertainty": ("cpu_ratio_to_ortho", 2.0),
}


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def table(run: dict) -> str:
    m = run["machine"]
    lines = [
        f"`{run['command']}` on {run['date'][:16].replace('T', ' ')} UTC, {m['cpus']} x {m['cpu_model']}, "
        f"load average {m['load_average'][0]} at the start, {run.get('load_average_end', ['?'])[0]} at the end",
        "",
        "| figure | photax | peer | ratio photax/peer | target |",
        "|---|---|---|---|---|",
    ]
    for name, f in run["figures"].items():
        ours = f.get("photax_s", f.get("photax_bytes", f.get("bytes", f.get("cold_s"))))
        peer = f.get("peer_s", f.get("peer_bytes"))
        unit = (
            (lambda v: f"{v / 2**20:.0f} MiB")
            if ("photax_bytes" in f or "bytes" in f) and "photax_s" not in f
            else (lambda v: f"{v * 1e3:.1f} ms" if v < 1 else f"{v:.2f} s")
        )
        if "cold_s" in f:
            ours_s = f"cold {f['cold_s']:.1f} s, warm {f['warm_s']:.1f} s, peak {f['peak_bytes'] / 2**20:.0f} MiB"
        elif "photax_ns_per_px" in f or "photax_ns" in f:
            v = f.get("photax_ns_per_px", f.get("photax_ns"))
            ours_s = f"{v:.2f} ns" + (
                "/px" if "photax_ns_per_px" in f else f" per tap, {f['fixed_ns_per_px']:.2f} ns/px fixed"
            )
            if "cv2_ns_per_px" in f:
                peer, unit, ratio_cpu = f["cv2_ns_per_px"], (lambda v: f"{v:.2f} ns/px (cv2)"), v / f["cv2_ns_per_px"]
                f = dict(f, ratio=ratio_cpu)
        elif "approx_error_px" in f:
            ours_s = f"check error {f['approx_error_px']:.3f} px, {100 * f['exact_fraction']:.1f} % exact"
        else:
            ours_s = unit(ours) if isinstance(ours, (int, float)) else ""
        ratio = f.get("ratio")
        target = next((t for k, t in TARGETS.items() if name.split(" (Lanczos")[0].startswith(k)), None)
        if name in OTHER_RATIOS:
            key, target = OTHER_RATIOS[name]
            ratio = f.get(key)
            ours_s = ours_s or ", ".join(f"{k} {_fmt(v)}" for k, v in f.items() if k != key)
        verdict = (
            "" if target is None or ratio is None else f"<= {target:g} " + ("met" if ratio <= target else "**missed**")
        )
        if "target_s" in f and isinstance(ours, (int, float)):  # an absolute target (bench_startup: import, --help)
            verdict = f"<= {f['target_s']:g} s " + ("met" if ours <= f["target_s"] else "**missed**")
        lines.append(
            f"| {name.strip()} | {ours_s} | {unit(peer) if isinstance(peer, (int, float)) else ''} | "
            f"{'' if ratio is None else f'{ratio:.2f}'} | {verdict} |"
        )
    return "\n".join(lines)


def main(paths) -> None:
    paths = [pathlib.Path(p) for p in paths] or sorted((HERE / "results").glob("*.json"))
    for p in paths:
        run = json.loads(p.read_text())
        if "figures" not in run:  # a per-block detail file of bench_bundle --grid, in its run's table
            continue
        print(f"### {p.stem}\n\n{table(run)}\n")


if __name__ == "__main__":
    main(sys.argv[1:])
