"""The README's benchmark table, regenerated from ``benchmarks/results/*.json``.

    python benchmarks/report.py [results/bench_rectify.json ...]
    python benchmarks/report.py --run [--times 2] [--only remap measure ...]

``--run`` first runs the command of every README row (:data:`ROWS`; ``--only``
picks some by key) ``--times`` times each, printing the machine's load and CPU
steal before each run, then prints each figure of the runs: its value where
the runs agree within 30 %, else the range ``min-max``.

Each JSON is one benchmark run (``_common.start``): its command, date,
machine and load average, thread settings, and its figures.  Prints a Markdown table per run
with the ratio photax / peer and, where issue 8 set one, the target.

Only quiet runs make README rows (issue 37): a run whose 1-minute load average was above
``_common.QUIET_LOAD`` (0.5) at its start is refused (named on stderr, exit status 1).
``--loaded`` appends such runs to the history in ``docs/performance.md`` instead, marked
**loaded** with their load; ``--history`` appends the quiet ones there too.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
PERFORMANCE = HERE.parent / "docs" / "performance.md"
HISTORY = "## History written by benchmarks/report.py"
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


def start_load(run: dict) -> float:
    """The 1-minute load average at the run's start."""
    return float(run.get("load_1min_start", run["machine"]["load_average"][0]))


def is_quiet(run: dict) -> bool:
    sys.path.insert(0, str(HERE))
    from _common import QUIET_LOAD

    return start_load(run) <= QUIET_LOAD


def threads_line(run: dict) -> str:
    """The thread settings both sides ran with (runs before issue 37 did not record them)."""
    t = run.get("threads")
    if t is None:
        return "thread settings not recorded"
    sys.path.insert(0, str(HERE))
    from _common import threads_text

    return threads_text(t)


def table(run: dict) -> str:
    m = run["machine"]
    state = "quiet" if is_quiet(run) else "**loaded**"
    lines = [
        f"`{run['command']}` on {run['date'][:16].replace('T', ' ')} UTC, {m['cpus']} x {m['cpu_model']}, "
        f"{state}: load average {m['load_average'][0]} at the start, {run.get('load_average_end', ['?'])[0]} at the end",
        "",
        threads_line(run),
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


# key -> the command (in benchmarks/) of the README's rows; see benchmarks/README.md
ROWS = {
    "remap": "bench_remap.py --calls 7 --processes 3 --busy 0 1 2",
    "rectify": "bench_rectify.py --only poly",
    "startup": "bench_startup.py --repeat 5 --cold 3",
    "ortho-block": "bench_ortho_block.py --repeat 3",
    "resection": "bench_resection.py --images 10000",
    "resection-1000": "bench_resection.py --images 1000",
    "measure": "bench_measure.py --points 1000",
    "bundle": "bench_bundle.py --no-scipy",
    "bundle-blocks": "bench_bundle.py --grid 10 20 30 --ceres-up-to 30 --no-scipy",
    "scale": "bench_scale.py --size 20000 --chunks 1024 512 2048",
    "uncertainty": "bench_uncertainty.py --repeat 9",
    "ties": "bench_ties_real.py --repeat 3",
    "rpc": "bench_rpc.py --repeat 7",
    "mosaic": "bench_mosaic_real.py --repeat 7",
    "sharpen": "bench_sharpen.py --repeat 5",
    "coregister": "bench_coregister.py --repeat 5",
}


def _numbers(run: dict) -> dict:
    """``{(figure, key): value}`` of a run's numeric figures."""
    return {
        (name, k): v
        for name, f in run["figures"].items()
        for k, v in f.items()
        if isinstance(v, (int, float)) and not isinstance(v, bool)
    }


def spread(runs: list[dict]) -> str:
    """Markdown lines: each figure of repeated runs, a range where they differ by more than 30 %."""
    vals: dict = {}
    for run in runs:
        for key, v in _numbers(run).items():
            vals.setdefault(key, []).append(v)
    lines = ["| figure | value | runs |", "|---|---|---|"]
    for (name, k), v in vals.items():
        lo, hi = min(v), max(v)
        text = f"{lo:.3g}" if (lo == hi or (lo > 0 and hi / lo <= 1.3)) else f"{lo:.3g}-{hi:.3g} (range)"
        lines.append(f"| {name} {k} | {text} | {len(v)} |")
    loads = ", ".join(
        f"load {start_load(r)}{'' if is_quiet(r) else ' (LOADED)'}, steal {r['machine'].get('steal', '?')}"
        for r in runs
    )
    return f"{loads}\n\n" + "\n".join(lines)


def run_rows(keys, times: int) -> None:
    sys.path.insert(0, str(HERE))
    from _common import load_now

    env = dict(os.environ, PYTHONPATH=str(HERE.parent / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for key in keys:
        runs: dict = {}
        for i in range(times):
            now = load_now()
            print(f"## {key}, run {i + 1} of {times}: python benchmarks/{ROWS[key]}")
            print(
                f"load average {now['load_average']}, CPU steal {100 * now['steal']:.0f} %, busy {100 * now['busy']:.0f} %"
            )
            t0 = time.time()
            subprocess.run([sys.executable, str(HERE / ROWS[key].split()[0]), *ROWS[key].split()[1:]], env=env)
            for p in (HERE / "results").glob("*.json"):
                if p.stat().st_mtime >= t0:
                    runs.setdefault(p.stem, []).append(json.loads(p.read_text()))
        for stem, rs in runs.items():
            if all("figures" in r for r in rs):
                print(f"### {stem}, {len(rs)} run(s)\n\n{spread(rs)}\n")


def append_history(stem: str, run: dict, path: pathlib.Path | None = None) -> None:
    """Append the run's table to the history section of ``docs/performance.md``, marked quiet or
    **loaded** with its load."""
    path = PERFORMANCE if path is None else path
    text = path.read_text() if path.exists() else "# Performance: the measurement log\n"
    if HISTORY not in text:
        text = (
            text.rstrip("\n")
            + f"\n\n{HISTORY}\n\nEach run as `benchmarks/report.py` tabulated it; runs above load 0.5 at their start are marked **loaded** and never quoted in the README.\n"
        )
    state = "quiet" if is_quiet(run) else f"LOADED (1-minute load {start_load(run)} at the start)"
    added = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    text = (
        text.rstrip("\n")
        + f"\n\n### {stem}, {run['date'][:16].replace('T', ' ')} UTC, {state}\n\n{table(run)}\n\n(added {added} UTC)\n"
    )
    path.write_text(text)


def main(argv) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", help="result files to tabulate (default: all)")
    ap.add_argument("--run", action="store_true", help="run the README rows' commands first")
    ap.add_argument("--times", type=int, default=2, help="runs of each command with --run")
    ap.add_argument("--only", nargs="+", choices=sorted(ROWS), help="with --run: only these rows")
    ap.add_argument("--loaded", action="store_true",
                    help="runs loaded at their start (1-minute load > 0.5): append them to docs/performance.md's "
                    "history, marked loaded, instead of refusing them")  # fmt: skip
    ap.add_argument("--history", action="store_true", help="also append the quiet runs to docs/performance.md")
    args = ap.parse_args(argv)
    if args.run:
        run_rows(args.only or list(ROWS), args.times)
        return 0
    paths = [pathlib.Path(p) for p in args.paths] or sorted((HERE / "results").glob("*.json"))
    refused = []
    for p in paths:
        run = json.loads(p.read_text())
        if "figures" not in run:  # a per-block detail file of bench_bundle --grid, in its run's table
            continue
        if not is_quiet(run):
            if args.loaded:
                append_history(p.stem, run)
                print(
                    f"{p.stem}: loaded (load {start_load(run)} at the start): appended to {PERFORMANCE}, marked loaded"
                )
            else:
                refused.append(f"{p.stem} (load {start_load(run)})")
            continue
        print(f"### {p.stem}\n\n{table(run)}\n")
        if args.history:
            append_history(p.stem, run)
    if refused:
        print(
            f"report.py: no README row from {len(refused)} run(s) loaded above 0.5 at their start: "
            f"{', '.join(refused)}; rerun them on a quiet machine, or --loaded to keep them in docs/performance.md",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
