"""Mosaicking the real NGI block: photax.mosaic against rasterio.merge on the same four orthos (issue 21).

    python benchmarks/bench_mosaic_real.py [--repeat N] [--data DIR]

The four NGI frames of orthority's corpus (``DIR/orthority``, default ../shared/data) are orthorectified
once by photax at 5 m onto one pixel lattice (not timed).  Then, interleaved (``_common.median_times``),
the median of ``--repeat`` runs of, from the same files to a GeoTIFF:

* ``rasterio.merge``: ``rasterio.merge.merge(paths)`` (first wins, no balancing, no seams) written as a
  deflate GeoTIFF (uint8, nodata 0, like the orthos);
* ``photax.mosaic``: the default options (gain/offset balancing, seamlines of least difference,
  8 px feathering) in the orthos' type as ``photax mosaic`` writes it (uint8, nodata 0), written by
  ``photax.to_raster`` as a deflate GeoTIFF (``cog=False``; the CLI's COG, with overviews, is timed
  on its own, as ``photax.mosaic (COG)``);
* the seam cut alone (``mosaic`` up to the lazy result: reading, overlap moments, balance, seams).

Then the CPU times (all threads) of merge and of photax to GeoTIFF, medians of ``--repeat`` runs each.

Issue 21's target: the whole photax mosaic within 4x rasterio.merge's wall time (it was ~400x: the seam
cut alone took 223 s).  The figures go to ``benchmarks/results/bench_mosaic_real.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(__file__))
from _common import median_time, median_times, ratio_line, record, start


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
    ap.add_argument(
        "--data",
        default=str(pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"),
    )
    args = ap.parse_args()
    data = pathlib.Path(args.data)
    if not (data / "orthority" / "ngi" / "dem.tif").is_file():
        sys.exit(f"{data}/orthority is not present")
    start("bench_mosaic_real")
    import rasterio
    import rasterio.merge

    from photax import mosaic, to_raster
    from photax.cli.mosaic import _in_dtype

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

        def ours(cog=False):
            to_raster(
                _in_dtype(mosaic(paths, info=info), paths[0]),
                tmp / "mosaic.tif",
                cog=cog,
            )

        t = median_times(
            {
                "merge": merge,
                "photax": ours,
                "photax_cog": lambda: ours(True),
                "seams": lambda: mosaic(paths),
            },
            repeat=args.repeat,
        )
        print(f"load average {[round(v, 2) for v in os.getloadavg()]} (1, 5, 15 min) at the end")
        with rasterio.open(tmp / "mosaic.tif") as ds:
            shape, dtype = ds.shape, ds.dtypes[0]
        print(
            f"NGI mosaic {shape[1]} x {shape[0]} px, 3 bands, {dtype}, seam grid {info['seam_scale']} px; gains "
            + ", ".join("/".join(f"{x:.3f}" for x in g) for g in info["gains"])
        )
        print(ratio_line("photax.mosaic vs rasterio.merge (to GeoTIFF)", t["photax"], t["merge"]) + "  (target <= 4)")
        print(
            ratio_line(
                "photax.mosaic (COG, as the CLI writes) vs rasterio.merge",
                t["photax_cog"],
                t["merge"],
            )
        )
        print(
            ratio_line(
                "photax.mosaic up to the lazy result (seams) vs rasterio.merge",
                t["seams"],
                t["merge"],
            )
        )
        # CPU time (all threads, user + system): less sensitive than wall time to the other jobs of a busy machine.
        cpu = {
            k: median_time(fn, repeat=args.repeat, clock=time.process_time)
            for k, fn in (("merge", merge), ("photax", ours))
        }
        print(
            ratio_line(
                "CPU time: photax.mosaic vs rasterio.merge (to GeoTIFF)",
                cpu["photax"],
                cpu["merge"],
            )
        )
        record(
            "ngi",
            mosaic_px=list(shape),
            seam_scale=info["seam_scale"],
            repeat=args.repeat,
        )


if __name__ == "__main__":
    main()
