"""Start-up: what a command costs as a whole process, photax beside orthority.

    python benchmarks/bench_startup.py [--repeat N] [--cold N] [--data DIR] [--only PART ...]

Every figure is a whole process started by a small wrapper (``run``): its
wall time, its CPU time (user + system, all threads: less sensitive to the
other jobs of a shared machine than wall time) and its peak resident memory,
the median of ``--repeat`` runs interleaved with the peer's where there is
one, with the load average beside it.  Parts:

* ``import``: ``python -c "import photax"`` (target <= 0.5 s), beside a bare
  ``python -c pass`` and ``import jax`` (what any JAX program pays), and
  ``import photax; photax.orthorectify_file`` (a first public name: what a
  script pays before its first call).
* ``help``: ``photax --help`` (target < 0.5 s).
* ``ortho``: ``photax ortho`` on the NGI frame at 5 m (../shared/data) vs
  ``oty frame`` from the same files to the same kind of output (deflate
  GeoTIFF, no mask, no overviews), warm compile cache (target <= 1.5 x oty,
  wall and peak memory); photax's first run with an empty cache (target
  < 5 s) is the median of ``--cold`` runs, each with a new empty cache.
* ``resect``, ``rectify``, ``bundle``: the README's sample commands, warm
  and cold; resect's warm time is compared with oty's ortho time (issue 8's
  target: within 1.5 x), and the number of persistent-cache entries each
  command leaves shows that the cache now works for all of them.
* ``breakdown``: where one warm ``photax ortho``'s time goes, in one process:
  imports, reading the inputs, the grid, the first orthorectify_file call
  (tracing + lowering + cache read + work, with JAX's own log of the
  tracing, lowering and compile/cache-read seconds) and a second identical
  call (the work alone), with the resident and peak memory after each
  phase (issue 8's memory target is 1.5 x oty's peak).

Python byte-code: the checkout's own modules are compiled to a byte-code
cache in a temporary PYTHONPYCACHEPREFIX by a first run (as an installed
package would have), so neither program is charged for compiling Python.
Writes ``benchmarks/results/bench_startup.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from _common import add_threads_option, apply_threads, mib, record, start  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
BIN = pathlib.Path(sys.executable).parent
NAME = "3324c_2015_1004_05_0182_RGB"

# Wall seconds, CPU seconds (user + system of the child, all threads) and
# peak resident KiB of one command, measured by a wrapper process (a child
# forked from this process would inherit its high-water mark).
_WRAPPER = """
import resource, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.run(sys.argv[1:], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
dt = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
sys.stdout.buffer.write(p.stdout)
print("\\n@@", p.returncode, dt, ru.ru_utime + ru.ru_stime, ru.ru_maxrss)
"""


def run(cmd: list[str], env: dict, cwd=None) -> tuple[float, float, int]:
    """``(wall s, cpu s, peak bytes)`` of ``cmd`` run to completion; raises,
    showing its output, if it fails."""
    out = subprocess.run([sys.executable, "-c", _WRAPPER, *map(str, cmd)], env=env, cwd=cwd, capture_output=True)
    body, _, tail = out.stdout.decode(errors="replace").rpartition("\n@@ ")
    code, wall, cpu, rss = tail.split()
    if int(code) != 0:
        sys.stdout.write(body)
        raise RuntimeError(f"{shlex.join(map(str, cmd))} failed with exit code {code}")
    return float(wall), float(cpu), int(rss) * 1024


def medians(runs: list[tuple[float, float, int]]) -> tuple[float, float, int]:
    """Median wall and CPU time, largest peak memory."""
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs), max(r[2] for r in runs)


def interleaved(cmds: dict[str, tuple[list, dict]], repeat: int, cwd=None) -> dict[str, tuple[float, float, int]]:
    """Medians of the commands run a, b, a, b, ... after one warm-up each."""
    for cmd, env in cmds.values():
        run(cmd, env, cwd)
    runs: dict[str, list] = {k: [] for k in cmds}
    for _ in range(repeat):
        for k, (cmd, env) in cmds.items():
            runs[k].append(run(cmd, env, cwd))
    return {k: medians(v) for k, v in runs.items()}


def load() -> float:
    return round(os.getloadavg()[0], 2)


def show(label: str, m: tuple[float, float, int], extra: str = "") -> None:
    print(f"{label}: wall {m[0]:.3f} s, cpu {m[1]:.3f} s, peak {mib(m[2])}{extra} (load {load()})")


def entries(cache: pathlib.Path) -> int:
    return sum(1 for p in cache.glob("*-cache")) if cache.is_dir() else 0


def bench_import(env, repeat):
    print("\n== import ==")
    py = sys.executable
    cmds = {
        "python -c pass": ([py, "-c", "pass"], env),
        "import jax": ([py, "-c", "import jax"], env),
        "import photax": ([py, "-c", "import photax"], env),
        "import photax; photax.orthorectify_file": ([py, "-c", "import photax; photax.orthorectify_file"], env),
    }
    t = interleaved(cmds, repeat)
    for k, m in t.items():
        show(k, m)
    record(
        "import photax (whole process)",
        photax_s=t["import photax"][0],
        cpu_s=t["import photax"][1],
        photax_bytes_peak=t["import photax"][2],
        bare_python_s=t["python -c pass"][0],
        target_s=0.5,
        load=load(),
    )
    record("import jax (whole process, reference)", photax_s=t["import jax"][0], cpu_s=t["import jax"][1])
    k = "import photax; photax.orthorectify_file"
    record(k + " (whole process)", photax_s=t[k][0], cpu_s=t[k][1])


def bench_help(env, repeat):
    print("\n== photax --help ==")
    t = interleaved({"help": ([BIN / "photax", "--help"], env)}, repeat)
    show("photax --help", t["help"])
    record("photax --help (whole process)", photax_s=t["help"][0], cpu_s=t["help"][1], target_s=0.5, load=load())


def ngi_files(data: pathlib.Path, tmp: pathlib.Path) -> bool:
    """The NGI inputs in ``tmp``, the DEM with the horizontal CRS of the
    orientation (as bench_rectify.py does), or False when absent."""
    if not (data / "dem.tif").is_file():
        return False
    import rasterio

    prj = (data / "ngi_xyz_opk.prj").read_text()
    with rasterio.open(data / "dem.tif") as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string(prj))
    with rasterio.open(tmp / "dem.tif", "w", **profile) as dst:
        dst.write(heights)
    for f in ("ngi_int_param.yaml", "ngi_xyz_opk.csv", "ngi_xyz_opk.prj", f"{NAME}.tif"):
        shutil.copy(data / f, tmp / f)
    (tmp / "oty").mkdir()
    return True


def oty_frame(names, out_dir="oty"):
    """``oty frame`` on the NGI images ``names`` at 5 m, as photax's ortho runs (bilinear, deflate, no mask, no
    overviews); also bench_ortho_block's peer."""
    return [
        BIN / "oty",
        "frame",
        *(f"{n}.tif" for n in names),
        "--dem",
        "dem.tif",
        "--int-param",
        "ngi_int_param.yaml",
        "--ext-param",
        "ngi_xyz_opk.csv",
        "--res",
        "5",
        "--interp",
        "bilinear",
        "--dem-interp",
        "bilinear",
        "--compress",
        "deflate",
        "--no-write-mask",
        "--no-build-ovw",
        "--out-dir",
        out_dir,
        "--overwrite",
    ]


def ortho_cmds(tmp: pathlib.Path):
    photax = [
        BIN / "photax",
        "ortho",
        f"{NAME}.tif",
        "--dem",
        "dem.tif",
        "--interior",
        "ngi_int_param.yaml",
        "--exterior",
        "ngi_xyz_opk.csv",
        "--out",
        "photax.tif",
        "--resolution",
        "5",
        "--resampling",
        "bilinear",
        "--no-progress",
    ]
    oty = oty_frame([NAME])
    return photax, oty


def cold_runs(cmd, env, tmp, n, cwd) -> tuple[tuple[float, float, int], int]:
    """Medians of ``n`` runs, each with a new empty compile cache, and the
    number of entries the last one left."""
    runs = []
    for i in range(n):
        cache = tmp / f"cold-cache-{i}"
        runs.append(run(cmd, dict(env, JAX_COMPILATION_CACHE_DIR=str(cache)), cwd))
    return medians(runs), entries(cache)


def bench_ortho(env, repeat, n_cold, data, tmp, oty_time):
    print("\n== NGI frame 640 x 1152 x 3 at 5 m, bilinear, whole CLI process ==")
    work = tmp / "ngi"
    work.mkdir()
    if not ngi_files(data, work):
        print(f"(NGI data absent from {data}: skipped; give --data)")
        return
    photax, oty = ortho_cmds(work)
    warm_env = dict(env, JAX_COMPILATION_CACHE_DIR=str(tmp / "warm-cache"))
    print("photax: " + shlex.join(map(str, photax)).replace(str(BIN) + "/", ""))
    print("oty:    " + shlex.join(map(str, oty)).replace(str(BIN) + "/", ""))
    print(f"(in a folder holding the NGI files; photax's warm cache is {tmp}/warm-cache, filled by a first run)")
    t = interleaved({"photax": (photax, warm_env), "oty": (oty, env)}, repeat, cwd=work)
    show("photax ortho, warm compile cache", t["photax"])
    show("oty frame", t["oty"])
    oty_time.update(wall=t["oty"][0], cpu=t["oty"][1], peak=t["oty"][2])
    record(
        "NGI ortho whole CLI process, warm compile cache, vs oty frame",
        photax_s=t["photax"][0],
        peer_s=t["oty"][0],
        ratio=t["photax"][0] / t["oty"][0],
        photax_cpu_s=t["photax"][1],
        peer_cpu_s=t["oty"][1],
        cpu_ratio=t["photax"][1] / t["oty"][1],
        load=load(),
    )
    record(
        "NGI ortho whole CLI process peak memory",
        photax_bytes=t["photax"][2],
        peer_bytes=t["oty"][2],
        ratio=t["photax"][2] / t["oty"][2],
    )
    print(
        f"ratios photax / oty: wall {t['photax'][0] / t['oty'][0]:.2f}, cpu {t['photax'][1] / t['oty'][1]:.2f}, "
        f"peak memory {t['photax'][2] / t['oty'][2]:.2f} (targets <= 1.5)"
    )
    cold, n = cold_runs(photax, env, tmp, n_cold, work)
    show(f"photax ortho, empty compile cache (median of {n_cold})", cold, f", {n} cache entries written")
    record(
        "NGI ortho whole CLI process, cold (empty compile cache)",
        photax_s=cold[0],
        cpu_s=cold[1],
        photax_bytes=cold[2],
        cache_entries=n,
        target_s=5.0,
        load=load(),
    )


def sample_cmds(out: pathlib.Path) -> dict[str, list]:
    """The README's sample commands (run in the repository's folder)."""
    p = BIN / "photax"
    return {
        "resect": [p, "resect", "data/sample_gcps.csv", "--camera", "data/sample_camera.yaml"],
        "rectify": [
            p,
            "rectify",
            "data/sample_image.tif",
            "--gcps",
            "data/sample_gcps.csv",
            "--order",
            "3",
            "--out",
            out / "rect.tif",
            "--no-progress",
        ],
        "bundle": [p, "bundle", "data/block", "--quiet", "--no-progress"],
    }


def bench_samples(env, repeat, n_cold, tmp, parts, oty_time):
    print("\n== sample commands (README), whole process ==")
    out = tmp / "out"
    out.mkdir(exist_ok=True)
    for name, cmd in sample_cmds(out).items():
        if name not in parts:
            continue
        print(shlex.join(map(str, cmd)).replace(str(BIN) + "/", "") + "   (in the repository's folder)")
        cold, n = cold_runs(cmd, env, tmp / name, n_cold, REPO)
        cache = tmp / name / "warm-cache"
        t = interleaved({name: (cmd, dict(env, JAX_COMPILATION_CACHE_DIR=str(cache)))}, repeat, cwd=REPO)[name]
        show(f"photax {name}, warm compile cache", t)
        show(f"photax {name}, empty compile cache (median of {n_cold})", cold, f", {n} cache entries written")
        fig = dict(
            photax_s=t[0],
            cpu_s=t[1],
            photax_bytes=t[2],
            empty_cache_s=cold[0],
            empty_cache_cpu_s=cold[1],
            cache_entries=n,
            load=load(),
        )
        if oty_time:  # issue 8: resect within 1.5 x of orthority's CLI on the NGI ortho
            fig.update(peer_s=oty_time["wall"], ratio=t[0] / oty_time["wall"], peer_bytes=oty_time["peak"])
            print(
                f"  vs oty frame's NGI ortho: wall ratio {t[0] / oty_time['wall']:.2f}, "
                f"peak memory ratio {t[2] / oty_time['peak']:.2f}"
            )
        record(f"photax {name} whole process, warm compile cache", **fig)


# One warm photax ortho in one process, phase by phase (run as a child).
_PHASES = r"""
import dataclasses, logging, os, sys, time
t0, c0 = time.perf_counter(), time.process_time()
marks = []
def rss():
    with open("/proc/self/status") as f:
        d = dict(line.split(":", 1) for line in f if ":" in line)
    return int(d["VmRSS"].split()[0]) / 1024, int(d["VmHWM"].split()[0]) / 1024
def mark(name):
    marks.append((name, time.perf_counter() - t0, time.process_time() - c0, *rss()))
import jax
jax.config.update("jax_log_compiles", True)
mark("import jax")
import jax.numpy as jnp
jnp.zeros(1).block_until_ready()
mark("JAX's CPU backend (first array)")
import photax.cli
from photax.io.orientation import read_exterior, read_interior
from photax.io.raster import read_dem
from photax.rectification import ortho_grid, orthorectify_file
photax.cli._enable_compilation_cache()
mark("import photax's ortho modules")
camera = read_interior("ngi_int_param.yaml", None)
exterior, crs = read_exterior("ngi_xyz_opk.csv", "NAME.tif")
dem = read_dem("dem.tif")
mark("read orientation and DEM")
grid = dataclasses.replace(ortho_grid(exterior, camera, dem, 5.0), crs=crs)
mark("ortho_grid (the footprint: one jitted call)")
for label in ("orthorectify_file, first call", "orthorectify_file, second call (the work)"):
    orthorectify_file("NAME.tif", "phases.tif", exterior, camera, dem, grid, resampling="bilinear",
                      compress="deflate")
    mark(label)
prev = (0.0, 0.0)
for name, w, c, r, hwm in marks:
    print(f"@@ {name}|{w - prev[0]:.4f}|{c - prev[1]:.4f}|{r:.0f}|{hwm:.0f}")
    prev = (w, c)
"""

_LOG = {
    "tracing": re.compile(r"Finished tracing.* in ([0-9.e-]+) sec"),
    "lowering": re.compile(r"Finished jaxpr to MLIR module conversion.* in ([0-9.e-]+) sec"),
    "compile or cache read": re.compile(r"Finished XLA compilation.* in ([0-9.e-]+) sec"),
}


def bench_breakdown(env, repeat, data, tmp):
    print("\n== where a warm photax ortho's time goes (one process, medians) ==")
    work = tmp / "ngi-phases"
    work.mkdir()
    if not ngi_files(data, work):
        return
    env = dict(env, JAX_COMPILATION_CACHE_DIR=str(tmp / "phases-cache"))
    code = _PHASES.replace("NAME", NAME)
    phases: dict[str, list] = {}
    logs: dict[str, list] = {k: [] for k in _LOG}
    hits = []
    for i in range(repeat + 1):  # the first fills the cache
        p = subprocess.run([sys.executable, "-c", code], env=env, cwd=work, capture_output=True, text=True, check=True)
        if i == 0:
            continue
        for line in p.stdout.splitlines():
            if line.startswith("@@ "):
                name, w, c, r, hwm = line[3:].split("|")
                phases.setdefault(name, []).append((float(w), float(c), float(r), float(hwm)))
        for k, rx in _LOG.items():
            logs[k].append(sum(float(x) for x in rx.findall(p.stderr)))
        hits.append(
            (p.stderr.count("Persistent compilation cache hit"), len(_LOG["compile or cache read"].findall(p.stderr)))
        )
    for name, v in phases.items():
        w, c, r, hwm = (statistics.median(x[i] for x in v) for i in range(4))
        print(f"{name:45s} wall {w:.3f} s, cpu {c:.3f} s; after it: resident {r:.0f} MiB, peak {hwm:.0f} MiB")
        record(f"breakdown warm ortho: {name}", photax_s=w, cpu_s=c, rss_mib=r, peak_mib=hwm)
    for k, v in logs.items():
        print(f"  JAX log, summed over every jitted call: {k} {statistics.median(v):.3f} s wall")
        record(f"breakdown warm ortho: JAX {k} (sum)", photax_s=statistics.median(v))
    print(f"  {hits[-1][1]} XLA executables needed, {hits[-1][0]} read from the persistent cache (load {load()})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per command (medians)")
    ap.add_argument("--cold", type=int, default=3, help="runs with an empty compile cache (medians)")
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"), help="folder with the NGI files")
    parts_all = ("import", "help", "ortho", "resect", "rectify", "bundle", "breakdown")
    ap.add_argument("--only", choices=parts_all, action="append", help="run only these parts")
    add_threads_option(ap)
    args = ap.parse_args()
    apply_threads(args)
    start("bench_startup" + "".join("_" + p for p in sorted(args.only or [])))
    parts = set(args.only or parts_all)
    with tempfile.TemporaryDirectory(prefix="photax-startup-") as tmp:
        tmp = pathlib.Path(tmp)
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "JAX_COMPILATION_CACHE_DIR")}
        env.update(PYTHONPYCACHEPREFIX=str(tmp / "pycache"), PYTHONWARNINGS="ignore")
        # byte-compile once (both programs then run from byte-code, as installed)
        subprocess.run(
            [
                sys.executable,
                "-c",
                "import photax.cli, photax.rectification, photax.resection, "
                "photax.bundle, photax.io.orientation, photax.io.raster, orthority.cli",
            ],
            env=env,
            check=True,
        )
        if "import" in parts:
            bench_import(env, args.repeat)
        if "help" in parts:
            bench_help(env, args.repeat)
        oty_time: dict = {}
        if "ortho" in parts:
            bench_ortho(env, args.repeat, args.cold, pathlib.Path(args.data), tmp, oty_time)
        bench_samples(env, args.repeat, args.cold, tmp, parts, oty_time)
        if "breakdown" in parts:
            bench_breakdown(env, args.repeat, pathlib.Path(args.data), tmp)


if __name__ == "__main__":
    main()
