"""Many images in one command: ``photax ortho IMAGE... --out-dir`` beside ``oty frame`` (issue 21, item 4).

    python benchmarks/bench_ortho_block.py [--repeat N] [--data DIR] [--copies K] [--baseline SRC]

The four NGI frames of orthority's test corpus (``DIR/ngi``, ``DIR/io``; 640 x 1152 x 3
each) orthorectified on the survey's DEM at 5 m, bilinear (grey values and DEM), deflate
GeoTIFF, no mask, no overviews, by one whole process of each program: ``photax ortho`` with
all four images and ``--out-dir``, and ``oty frame`` with all four.  Figures are the medians of
``--repeat`` fresh processes run in turn (after one warm-up each: photax's compile cache is
warm, as after a first use), wall and CPU seconds, with the load average printed beside them
(a shared 2-core machine: the ratios, measured in the same run, are the figures to read).
Also: the same with one image, so the per-image marginal time ``(t4 - t1) / 3`` of each, and
four single-image ``photax ortho`` processes (what the block command saves).  ``--copies K``
(K > 1) also times both programs on a block of 4 K images (each frame copied K times under new
names, with its orientation): where photax's smaller per-image time has paid for its start-up.
``--baseline SRC`` also times photax's 1- and 4-image commands with the photax package of another
source tree (e.g. ``/path/to/main/src``: the code before a change) in the same interleaved runs,
with a compile cache of its own: before and after under the same load.
Writes ``benchmarks/results/bench_ortho_block.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shlex
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from _common import add_threads_option, apply_threads, record, start
from bench_startup import BIN, REPO, interleaved, load, oty_frame, show

NAMES = [
    "3324c_2015_1004_05_0182_RGB",
    "3324c_2015_1004_05_0184_RGB",
    "3324c_2015_1004_06_0251_RGB",
    "3324c_2015_1004_06_0253_RGB",
]


def inputs(data: pathlib.Path, work: pathlib.Path, copies: int = 1) -> list[str]:
    """The NGI files in ``work``, the DEM with the orientation's CRS (as bench_startup does); with
    ``copies`` > 1 also ``copies - 1`` copies of each frame (``NAME_cK``) and their rows in the
    exterior CSV.  Returns every image name (the four first)."""
    import rasterio

    prj = (data / "io" / "ngi_xyz_opk.prj").read_text()
    with rasterio.open(data / "ngi" / "dem.tif") as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string(prj))
    with rasterio.open(work / "dem.tif", "w", **profile) as dst:
        dst.write(heights)
    for f in ("ngi_int_param.yaml", "ngi_xyz_opk.csv", "ngi_xyz_opk.prj"):
        shutil.copy(data / "io" / f, work / f)
    for n in NAMES:
        shutil.copy(data / "ngi" / f"{n}.tif", work / f"{n}.tif")
    names = list(NAMES)
    if copies > 1:
        rows = {ln.split(",")[0]: ln for ln in (work / "ngi_xyz_opk.csv").read_text().splitlines()}
        extra = []
        for k in range(1, copies):
            for n in NAMES:
                shutil.copy(work / f"{n}.tif", work / f"{n}_c{k}.tif")
                extra.append(rows[n].replace(n, f"{n}_c{k}", 1))
                names.append(f"{n}_c{k}")
        with open(work / "ngi_xyz_opk.csv", "a") as fh:
            fh.write("\n".join(["", *extra]) + "\n")
    return names


def photax_cmd(names, out_dir="photax"):
    return [
        BIN / "photax",
        "ortho",
        *(f"{n}.tif" for n in names),
        "--dem",
        "dem.tif",
        "--interior",
        "ngi_int_param.yaml",
        "--exterior",
        "ngi_xyz_opk.csv",
        "--out-dir",
        out_dir,
        "--resolution",
        "5",
        "--resampling",
        "bilinear",
        "--no-progress",
    ]


def singles_cmd(names):
    """Four ``photax ortho IMAGE -o OUT`` processes, one after the other (a shell loop)."""
    one = [
        [
            BIN / "photax",
            "ortho",
            f"{n}.tif",
            "--dem",
            "dem.tif",
            "--interior",
            "ngi_int_param.yaml",
            "--exterior",
            "ngi_xyz_opk.csv",
            "-o",
            f"single/{n}.tif",
            "--resolution",
            "5",
            "--resampling",
            "bilinear",
            "--no-progress",
        ]
        for n in names
    ]
    return ["sh", "-c", "mkdir -p single && " + " && ".join(shlex.join(map(str, c)) for c in one)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed processes per command (medians)")
    ap.add_argument(
        "--data",
        default=str(REPO.parent / "shared" / "data" / "orthority"),
        help="orthority's test data (ngi/ and io/)",
    )
    ap.add_argument("--baseline", metavar="SRC", help="also time the photax package of this src folder")
    ap.add_argument("--copies", type=int, default=1, help="also a block of 4 x COPIES images (copies of the frames)")
    add_threads_option(ap)
    args = ap.parse_args()
    apply_threads(args)
    start("bench_ortho_block")
    data = pathlib.Path(args.data)
    if not (data / "ngi" / "dem.tif").is_file():
        print(f"NGI data absent from {data}: give --data")
        return
    with tempfile.TemporaryDirectory(prefix="photax-block-") as tmp:
        tmp = pathlib.Path(tmp)
        work = tmp / "ngi"
        work.mkdir()
        names = inputs(data, work, args.copies)
        (work / "oty").mkdir()
        drop = ("PYTHONDONTWRITEBYTECODE", "JAX_COMPILATION_CACHE_DIR")
        env = {k: v for k, v in os.environ.items() if k not in drop}
        env.update(
            PYTHONPYCACHEPREFIX=str(tmp / "pycache"),
            PYTHONWARNINGS="ignore",
            JAX_COMPILATION_CACHE_DIR=str(tmp / "warm-cache"),
        )
        modules = "photax.cli, photax.rectification, photax.io.orientation, photax.io.raster, orthority.cli"
        subprocess.run([sys.executable, "-c", f"import {modules}"], env=env, check=True)  # byte-code for both
        cmds = {
            "photax 4": photax_cmd(NAMES),
            "oty 4": oty_frame(NAMES),
            "photax 1": photax_cmd(NAMES[:1]),
            "oty 1": oty_frame(NAMES[:1]),
            "photax 4 single processes": singles_cmd(NAMES),
        }
        n = len(names)
        if n > 4:
            cmds.update({f"photax {n}": photax_cmd(names), f"oty {n}": oty_frame(names)})
        for k, c in cmds.items():
            print(f"{k}: " + shlex.join(map(str, c)).replace(str(BIN) + "/", ""))
        print(f"(in {work}, a copy of the NGI files; load average {load()} before)")
        envs = {k: env for k in cmds}
        if args.baseline:
            base = dict(env, PYTHONPATH=args.baseline, JAX_COMPILATION_CACHE_DIR=str(tmp / "baseline-cache"))
            subprocess.run([sys.executable, "-c", f"import {modules}"], env=base, check=True)
            for n in (4, 1):
                cmds[f"photax {n} baseline"], envs[f"photax {n} baseline"] = photax_cmd(NAMES[:n], "base"), base
        t = interleaved({k: (c, envs[k]) for k, c in cmds.items()}, args.repeat, cwd=work)
        for k, m in t.items():
            show(k, m)
        wall = {k: m[0] for k, m in t.items()}
        ratio = wall["photax 4"] / wall["oty 4"]
        marginal = {p: (wall[f"{p} 4"] - wall[f"{p} 1"]) / 3 for p in ("photax", "oty")}
        w4, o4, single = wall["photax 4"], wall["oty 4"], wall["photax 4 single processes"]
        print(
            f"\nfour NGI frames, one process each: photax {w4:.2f} s, oty {o4:.2f} s, ratio {ratio:.2f} "
            f"(target <= 1.0); cpu ratio {t['photax 4'][1] / t['oty 4'][1]:.2f}"
        )
        print(
            f"per-image marginal time (t4 - t1) / 3: photax {marginal['photax']:.2f} s, "
            f"oty {marginal['oty']:.2f} s (target photax <= oty)"
        )
        print(
            f"four single-image photax processes: {single:.2f} s ({single / w4:.2f} x the block command); load {load()}"
        )
        record(
            "NGI 4 frames, one ortho process vs oty frame (wall)",
            photax_s=w4,
            peer_s=o4,
            ratio=ratio,
            photax_cpu_s=t["photax 4"][1],
            peer_cpu_s=t["oty 4"][1],
            load=load(),
        )
        record(
            "NGI per-image marginal ortho time vs oty frame",
            photax_s=marginal["photax"],
            peer_s=marginal["oty"],
            ratio=marginal["photax"] / marginal["oty"],
        )
        record("NGI 4 frames as 4 single-image photax processes", photax_s=single, block_s=w4)
        if args.baseline:
            b4, b1 = t["photax 4 baseline"], t["photax 1 baseline"]
            print(
                f"baseline ({args.baseline}): 4 images {b4[0]:.2f} s wall, {b4[1]:.2f} s cpu (ratio to oty "
                f"{b4[0] / o4:.2f}, cpu {b4[1] / t['oty 4'][1]:.2f}); 1 image {b1[0]:.2f} s, {b1[1]:.2f} s cpu"
            )
            record("NGI 4 frames, baseline photax vs oty frame (wall)", photax_s=b4[0], peer_s=o4, ratio=b4[0] / o4,
                   photax_cpu_s=b4[1], peer_cpu_s=t["oty 4"][1], baseline=args.baseline)  # fmt: skip
        if n > 4:
            pn, on = t[f"photax {n}"], t[f"oty {n}"]
            print(
                f"{n} images (copies of the 4), one process each: photax {pn[0]:.2f} s, oty {on[0]:.2f} s, "
                f"ratio {pn[0] / on[0]:.2f}; cpu ratio {pn[1] / on[1]:.2f}"
            )
            record(
                f"NGI {n} images (4 frames x {args.copies}), one ortho process vs oty frame (wall)",
                photax_s=pn[0],
                peer_s=on[0],
                ratio=pn[0] / on[0],
                photax_cpu_s=pn[1],
                peer_cpu_s=on[1],
                load=load(),
            )


if __name__ == "__main__":
    main()
