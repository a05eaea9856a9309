"""Mosaicking the real NGI block: photax.mosaic against rasterio.merge on the same four orthos (issue 21).

    python benchmarks/bench_mosaic_real.py [--repeat N] [--data DIR] [--no-processes]

The four NGI frames of orthority's corpus (``DIR/orthority``, default ../shared/data) are orthorectified
once by photax at 5 m onto one pixel lattice (not timed).  Then, interleaved (one round runs each once,
in turn), ``--repeat`` rounds of, from the same files to a file:

* ``rasterio.merge``: ``rasterio.merge.merge(paths)`` (first wins, no balancing, no seams) written as a
  deflate GeoTIFF (uint8, nodata 0, like the orthos);
* ``photax.mosaic_to_raster`` (what ``photax mosaic`` runs): the default options (gain/offset balancing,
  seamlines of least difference, 8 px feathering) in the orthos' type (uint8, nodata 0), the orthos read
  whole into NumPy arrays, each tile on a thread, no Dask, written as a deflate GeoTIFF (``cog=False``;
  the CLI's COG, with overviews, is timed on its own, as ``photax.mosaic_to_raster (COG)``);
* the lazy way: ``photax.mosaic`` (a Dask graph of the same per-tile functions) in the same type,
  written by ``photax.to_raster`` as a deflate GeoTIFF;
* the seam cut alone (``mosaic`` up to the lazy result: reading, overlap moments, balance, seams).

Each ratio is the median over the rounds of photax / merge in the same round, with its range.  Then
the CPU times (all threads) of merge and of ``mosaic_to_raster`` to GeoTIFF, medians of ``--repeat`` runs.

Whole processes (unless ``--no-processes``), interleaved likewise: ``python -m photax.cli mosaic ...``
(a COG, start-up included: Python, NumPy, rasterio, SciPy's sparse graphs; since ``mosaic_to_raster``
no Dask, xarray, pandas or rioxarray) against a Python script calling ``rasterio.merge`` and writing a
deflate GeoTIFF, and the same script writing a COG (``driver="COG"``, the CLI's output format).

Issue 21's target: the whole photax mosaic within 4x rasterio.merge's wall time (it was ~400x: the seam
cut alone took 223 s).  The figures go to ``benchmarks/results/bench_mosaic_real.json``.

Measured 2026-11-27 14:50-14:52, ``--repeat 5``, load 6.7-7.5 on 2 cores: the whole process 2.81x per
round (1.92-2.90) the script writing a GeoTIFF (an earlier run, load 6.4-7.1: 2.56x, 2.15-4.45), 1.91x
(1.31-2.18) the one writing a COG (with Dask, xarray and rioxarray imported, before ``mosaic_to_raster``:
4.29x, 3.69-4.46, at load 1.6); in one process ``mosaic_to_raster`` 2.37x (2.06-2.87) to a GeoTIFF,
3.73x to the COG, the lazy way 2.42x.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import statistics
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(__file__))
from _common import add_threads_option, apply_threads, load_now, median_time, ratio_line, record, run_process, start

MERGE_SCRIPT = """
import sys, rasterio, rasterio.merge
driver, out, paths = sys.argv[1], sys.argv[2], sys.argv[3:]
arr, transform = rasterio.merge.merge(paths)
with rasterio.open(paths[0]) as ds:
    profile = ds.profile
profile.update(driver=driver, height=arr.shape[1], width=arr.shape[2], transform=transform, compress="deflate")
if driver == "GTiff":
    profile.update(tiled=True, blockxsize=256, blockysize=256)
else:
    profile = {k: v for k, v in profile.items() if k not in ("tiled", "blockxsize", "blockysize", "interleave")}
with rasterio.open(out, "w", **profile) as dst:
    dst.write(arr)
"""


def rounds(fns: dict, repeat: int, timed: bool = False) -> dict[str, list[float]]:
    """Each function once in turn, ``repeat`` rounds after a warm-up round (a change of the machine's
    load hits all alike): their wall times (or what they return, with ``timed``), a list each."""
    for fn in fns.values():
        fn()
    out = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            dt = fn()
            out[k].append(dt if timed else time.perf_counter() - t0)
    return out


def ratio_range(name: str, ours: list[float], peer: list[float]) -> str:
    """The median times and the median (min-max) over the rounds of ours / peer in the same round."""
    r = sorted(a / b for a, b in zip(ours, peer))
    line = ratio_line(name, statistics.median(ours), statistics.median(peer))
    record(name, ratio_per_round=statistics.median(r), ratio_min=r[0], ratio_max=r[-1])
    return f"{line}; per round {statistics.median(r):.2f} ({r[0]:.2f}-{r[-1]:.2f})"


def make_orthos(data: pathlib.Path, folder: pathlib.Path) -> list[str]:
    """The four NGI orthos at 5 m in ``folder`` (the DEM tagged with the orientation's CRS, as
    tests/test_ortho_real.py does)."""
    import rasterio

    from photax.io import read_dem
    from photax.io.orientation import block_images, read_interior
    from photax.rectification import orthorectify_block

    ngi = data / "orthority"
    with rasterio.open(ngi / "ngi" / "dem.tif") as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string((ngi / "io" / "ngi_xyz_opk.prj").read_text()))
    with rasterio.open(folder / "dem.tif", "w", **profile) as dst:
        dst.write(heights)
    images, exteriors, crs = block_images(ngi / "io" / "ngi_xyz_opk.csv", ngi / "ngi")
    camera = read_interior(ngi / "io" / "ngi_int_param.yaml", None)
    return [
        str(p)
        for p in orthorectify_block(
            images,
            exteriors,
            camera,
            read_dem(folder / "dem.tif"),
            folder,
            resolution=5.0,
            crs=crs,
        )
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-processes", dest="processes", action="store_false", help="no whole-process comparison")
    ap.add_argument(
        "--data",
        default=str(pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"),
    )
    add_threads_option(ap)
    args = ap.parse_args()
    apply_threads(args)
    data = pathlib.Path(args.data)
    if not (data / "orthority" / "ngi" / "dem.tif").is_file():
        sys.exit(f"{data}/orthority is not present")
    start("bench_mosaic_real")
    import numpy as np
    import rasterio
    import rasterio.merge

    from photax import mosaic, mosaic_to_raster, to_raster
    from photax.mosaicking import _out_type, _to_type

    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        paths = make_orthos(data, tmp)

        def merge():
            arr, transform = rasterio.merge.merge(paths)
            with rasterio.open(paths[0]) as ds:
                profile = ds.profile
            profile.update(
                height=arr.shape[1],
                width=arr.shape[2],
                transform=transform,
                compress="deflate",
                tiled=True,
                blockxsize=256,
                blockysize=256,
            )
            with rasterio.open(tmp / "merge.tif", "w", **profile) as dst:
                dst.write(arr)

        info = {}

        def ours(cog=False):  # what photax mosaic runs: NumPy on threads, no Dask
            mosaic_to_raster(paths, tmp / "mosaic.tif", cog=cog, info=info)

        def lazy():  # the lazy mosaic (Dask) in the orthos' type, written by to_raster
            out = mosaic(paths)
            dtype, nodata, lo, hi = _out_type(np.uint8, 0)
            data = out.data.map_blocks(_to_type, dtype, nodata, lo, hi, dtype=dtype)
            to_raster(out.copy(data=data).rio.write_nodata(nodata, encoded=False), tmp / "lazy.tif")

        t = rounds(
            {
                "merge": merge,
                "photax": ours,
                "photax_cog": lambda: ours(True),
                "lazy": lazy,
                "seams": lambda: mosaic(paths),
            },
            args.repeat,
        )
        print(f"load average {[round(v, 2) for v in os.getloadavg()]} (1, 5, 15 min) at the end")
        with rasterio.open(tmp / "mosaic.tif") as ds:
            shape, dtype = ds.shape, ds.dtypes[0]
        print(
            f"NGI mosaic {shape[1]} x {shape[0]} px, 3 bands, {dtype}, seam grid {info['seam_scale']} px; gains "
            + ", ".join("/".join(f"{x:.3f}" for x in g) for g in info["gains"])
        )
        for key, name in (
            ("photax", "photax.mosaic_to_raster vs rasterio.merge (to GeoTIFF)"),
            ("photax_cog", "photax.mosaic_to_raster (COG, as the CLI writes) vs rasterio.merge"),
            ("lazy", "photax.mosaic (lazy, Dask) + to_raster vs rasterio.merge (to GeoTIFF)"),
            ("seams", "photax.mosaic up to the lazy result (seams) vs rasterio.merge"),
        ):
            print(ratio_range(name, t[key], t["merge"]) + ("  (target <= 4)" if key == "photax" else ""))
        # CPU time (all threads, user + system): less sensitive than wall time to the other jobs of a busy machine.
        cpu = {
            k: median_time(fn, repeat=args.repeat, clock=time.process_time)
            for k, fn in (("merge", merge), ("photax", ours))
        }
        print(
            ratio_line(
                "CPU time: photax.mosaic_to_raster vs rasterio.merge (to GeoTIFF)",
                cpu["photax"],
                cpu["merge"],
            )
        )
        if args.processes:
            py = [sys.executable]
            w = rounds(
                {
                    "cli": lambda: run_process(
                        [*py, "-m", "photax.cli", "mosaic", *paths, "-o", str(tmp / "cli.tif"), "--no-progress"]
                    )[0],  # fmt: skip
                    "merge": lambda: run_process([*py, "-c", MERGE_SCRIPT, "GTiff", str(tmp / "m.tif"), *paths])[0],
                    "merge_cog": lambda: run_process([*py, "-c", MERGE_SCRIPT, "COG", str(tmp / "m.tif"), *paths])[0],
                },
                args.repeat,
                timed=True,
            )
            print(f"whole processes: load {load_now()} at the end")
            print(ratio_range("whole process: photax mosaic (COG) vs a rasterio.merge script (GeoTIFF)", w["cli"],
                              w["merge"]) + "  (target <= 4)")  # fmt: skip
            print(ratio_range("whole process: photax mosaic (COG) vs a rasterio.merge script (COG)", w["cli"],
                              w["merge_cog"]))  # fmt: skip
        record(
            "ngi",
            mosaic_px=list(shape),
            seam_scale=info["seam_scale"],
            repeat=args.repeat,
        )


if __name__ == "__main__":
    main()
