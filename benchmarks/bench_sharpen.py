"""Pan-sharpening, whole process: ``photax sharpen --method gs`` beside ``oty sharpen`` (orthority's
Gram-Schmidt) on the real pair ``../shared/data/orthority/pan_sharp`` (pan.tif 1368 x 912, ms.tif 3 bands
342 x 228).

    python benchmarks/bench_sharpen.py [--repeat N]

Each figure is the median wall time (and CPU time, user + system: less sensitive to the machine's other
jobs; and peak memory) of ``--repeat`` fresh processes, photax and oty
interleaved so that the machine's load hits both alike; the load average is printed before and after.
Both write a deflate GeoTIFF without overviews or mask (oty: ``-cm deflate -nbo -nwm``); photax runs with
its compile cache warm (a first run fills it, as any second use of the command would find it).  Python
byte-code of both is compiled by that first run too.  Issue 24's target: photax within 1x oty's time.
Then the Dask row: the pair tiled ``--tiles`` x ``--tiles`` times (real content; 4: a 5472 x 3648 PAN,
20 Mpx) sharpened by ``photax sharpen`` in memory and with ``--chunks 1024`` (pansharpen_dask, written chunk
by chunk): the median wall time and peak memory of each, fresh processes, interleaved.
Writes ``benchmarks/results/bench_sharpen.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import resource
import statistics
import sys
import tempfile

from _common import add_threads_option, apply_threads, record, run_process, start

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAIR = ROOT.parent / "shared" / "data" / "orthority" / "pan_sharp"
BIN = pathlib.Path(sys.executable).parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="fresh processes per program (median; >= 3)")
    parser.add_argument("--tiles", type=int, default=4, help="the pair tiled N x N times for the Dask row (0: none)")
    add_threads_option(parser)
    args = parser.parse_args()
    apply_threads(args)
    if not (PAIR / "pan.tif").is_file():
        sys.exit(f"{PAIR}: not present")
    start("bench_sharpen")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        env = dict(
            os.environ,
            PYTHONPATH=str(ROOT / "src"),
            PYTHONPYCACHEPREFIX=str(tmp / "pycache"),
            PYTHONWARNINGS="ignore",
            JAX_COMPILATION_CACHE_DIR=str(tmp / "jax"),
        )
        pan, ms = str(PAIR / "pan.tif"), str(PAIR / "ms.tif")
        cmds = {
            "photax": [
                sys.executable,
                "-m",
                "photax.cli",
                "sharpen",
                pan,
                ms,
                "-o",
                str(tmp / "photax.tif"),
                "--method",
                "gs",
            ],
            "oty": [
                str(BIN / "oty"),
                "sharpen",
                "-p",
                pan,
                "-ms",
                ms,
                "-of",
                str(tmp / "oty.tif"),
                "-cm",
                "deflate",
                "-nbo",
                "-nwm",
                "-o",
            ],
        }
        for cmd in cmds.values():  # warm: byte-code, photax's compile cache
            run_process(cmd, env=env)
        cold_env = dict(env, JAX_COMPILATION_CACHE_DIR=str(tmp / "jax-cold"))
        times = {k: [] for k in cmds}
        cpus = {k: [] for k in cmds}
        peaks = {k: [] for k in cmds}
        print(f"load average before: {[round(v, 2) for v in os.getloadavg()]}")
        for _ in range(max(3, args.repeat)):
            for k, cmd in cmds.items():
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                dt, peak = run_process(cmd, env=env)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)  # the wrapper and the command
                cpus[k].append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
                times[k].append(dt)
                peaks[k].append(peak)
        cold = run_process(cmds["photax"], env=cold_env)[0]
        if args.tiles:
            dask_row(tmp, env, args.tiles, max(3, args.repeat))
        print(f"load average after:  {[round(v, 2) for v in os.getloadavg()]}")
    med = {k: statistics.median(v) for k, v in times.items()}
    mem = {k: statistics.median(v) for k, v in peaks.items()}
    cpu = {k: statistics.median(v) for k, v in cpus.items()}
    for k in cmds:
        print(
            f"{k:7s} median {med[k]:.2f} s of {[round(t, 2) for t in times[k]]}, CPU (user + system) "
            f"{cpu[k]:.2f} s, peak {mem[k] / 2**20:.0f} MiB"
        )
    print(f"photax first run with an empty compile cache: {cold:.2f} s")
    print(
        f"ratio photax / oty: wall {med['photax'] / med['oty']:.2f} (target <= 1), CPU "
        f"{cpu['photax'] / cpu['oty']:.2f}, peak memory {mem['photax'] / mem['oty']:.2f}"
    )
    record(
        "GS pan-sharpening whole process, warm compile cache, vs oty sharpen",
        photax_s=med["photax"],
        peer_s=med["oty"],
        ratio=med["photax"] / med["oty"],
        photax_cpu_s=cpu["photax"],
        peer_cpu_s=cpu["oty"],
        cpu_ratio=cpu["photax"] / cpu["oty"],
        photax_cold_s=cold,
        photax_bytes=mem["photax"],
        peer_bytes=mem["oty"],
        load=[round(v, 2) for v in os.getloadavg()],
    )


def dask_row(tmp, env, tiles, repeat) -> None:
    """In memory vs ``--chunks 1024`` on the pair tiled ``tiles`` x ``tiles`` times: wall time, peak memory."""
    import numpy as np

    sys.path.insert(0, str(ROOT / "src"))
    from photax.io.raster import read_geotiff, write_geotiff

    paths = {}
    for name in ("pan", "ms"):
        image = read_geotiff(PAIR / f"{name}.tif")[0]
        paths[name] = str(tmp / f"{name}_x{tiles}.tif")
        write_geotiff(paths[name], np.tile(image, (1, tiles, tiles)), None)
    base = [sys.executable, "-m", "photax.cli", "sharpen", paths["pan"], paths["ms"], "--method", "gs"]
    cmds = {
        "in memory": [*base, "-o", str(tmp / "memory.tif")],
        "dask, chunks 1024": [*base, "-o", str(tmp / "dask.tif"), "--chunks", "1024"],
    }
    times = {k: [] for k in cmds}
    peaks = {k: [] for k in cmds}
    print(f"Dask row: the pair tiled {tiles} x {tiles}; load average {[round(v, 2) for v in os.getloadavg()]}")
    for _ in range(repeat):
        for k, cmd in cmds.items():
            dt, peak = run_process(cmd, env=env)
            times[k].append(dt)
            peaks[k].append(peak)
    med = {k: statistics.median(v) for k, v in times.items()}
    mem = {k: statistics.median(v) for k, v in peaks.items()}
    for k in cmds:
        print(f"  {k:18s} median {med[k]:.2f} s of {[round(t, 2) for t in times[k]]}, peak {mem[k] / 2**20:.0f} MiB")
    a, b = cmds
    print(f"  ratio dask / in memory: wall {med[b] / med[a]:.2f}, peak memory {mem[b] / mem[a]:.2f}")
    record(
        f"GS pan-sharpening of the pair tiled {tiles} x {tiles}: Dask (chunks 1024) vs in memory, whole process",
        dask_s=med[b],
        memory_s=med[a],
        dask_bytes=mem[b],
        memory_bytes=mem[a],
        peak_ratio=mem[b] / mem[a],
        load=[round(v, 2) for v in os.getloadavg()],
    )


if __name__ == "__main__":
    main()
