"""The RPC ortho of a satellite image beside ``oty rpc`` and GDAL's RPC transformer (issue 23, item 3).

    python benchmarks/bench_rpc.py [--repeat N] [--data DIR] [--speed-only]

orthority's QuickBird scene (``DIR/rpc/qb2_basic1b.tif``, 850 x 1450, its RPC in the GeoTIFF tags,
5 GCPs in ``gcps.geojson``) on the NGI DEM (``DIR/ngi/dem.tif``; geoid heights used as ellipsoidal,
as orthority's tests do), UTM 35S at 5 m, bilinear grey values and DEM, deflate GeoTIFF, no
overviews.

Accuracy (the issue's targets), photax's library on orthority's own output grid:

* the ortho against ``oty rpc`` and ``oty rpc --gcp-refine`` (shift): the geometric offset (least
  squares on the image gradients, on the common pixels: :func:`offset_and_mad`) <= 0.2 px and the mean absolute grey difference
  <= 1 grey level;
* against GDAL's warper (``rasterio.warp.reproject`` with ``rpcs=``, ``RPC_DEM``, no vertical datum
  shift) and, exactly, the image positions of the grid's points against GDAL's RPC transformer
  with ``RPC_DEM``: <= 0.1 px;
* the refined GCP residual RMSE <= orthority's and its leave-one-out <= 0.15 px.

Speed: whole processes ``photax ortho --camera rpc`` and ``oty rpc`` (raw and refined), medians
of ``--repeat`` runs in turn after one warm-up each (photax's compile cache warm, as after a first
use); and in one process photax's ``orthorectify_file`` against orthority's ``Ortho.process``
(interleaved medians). Target: photax <= 1 x orthority's wall time. Load average and CPU steal
are printed beside every figure: the machine is shared, the ratios are the figures to read.
Writes ``benchmarks/results/bench_rpc.json``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shlex
import sys
import tempfile
import warnings

sys.path.insert(0, os.path.dirname(__file__))
from _common import add_threads_option, apply_threads, median_times, record, start
from bench_startup import BIN, REPO, interleaved, load, show

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
_ENVIRON = dict(os.environ)
from test_rpc_ortho import offset_and_mad  # noqa: E402 -- the tests' own offset measure (tested on a known shift)

# The tests' conftest (imported with it) sets the suite's XLA_FLAGS: LLVM -O0 and no expensive passes, which
# made photax's processes here (they inherit the environment) and this one's XLA 1.5 x slower. Not ours.
os.environ.clear()
os.environ.update(_ENVIRON)

CRS = "EPSG:32735"


def steal() -> float:
    """Seconds of CPU time stolen from this VM so far (``/proc/stat``), 0 where unknown."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def photax_cmd(data, out, refine=False):
    cmd = [BIN / "photax", "ortho", data / "rpc" / "qb2_basic1b.tif", "--camera", "rpc", "--dem",
           data / "ngi" / "dem.tif", "--crs", CRS, "--resolution", "5", "--resampling", "bilinear",
           "--no-progress", "-o", out]  # fmt: skip
    return cmd + (["--gcps", data / "rpc" / "gcps.geojson", "--refine", "shift"] if refine else [])


def oty_cmd(data, out_dir, refine=False):
    cmd = [BIN / "oty", "rpc", "-d", data / "ngi" / "dem.tif", "-c", CRS, "-r", "5", "-i", "bilinear",
           "-di", "bilinear", "-cm", "deflate", "-nbo", "-nwm", "-o", "--out-dir", out_dir]  # fmt: skip
    cmd += ["-gr", data / "rpc" / "gcps.geojson"] if refine else []
    return cmd + [data / "rpc" / "qb2_basic1b.tif"]


def accuracy(data: pathlib.Path, tmp: pathlib.Path) -> None:
    """The accuracy targets, on orthority's grids (module docstring)."""
    import numpy as np
    import pyproj
    import rasterio
    from orthority import Ortho
    from orthority.camera import RpcCamera
    from orthority.enums import RpcRefine
    from orthority.fit import refine_rpc as oty_refine
    from rasterio.enums import Resampling
    from rasterio.transform import RPCTransformer
    from rasterio.warp import reproject

    from photax.grid import Grid
    from photax.io.gcp import read_gcps
    from photax.io.raster import read_dem
    from photax.rectification import OrthoModel, orthorectify
    from photax.rpc import read_rpc, refine_rpc

    tif, dem_path = data / "rpc" / "qb2_basic1b.tif", data / "ngi" / "dem.tif"
    rpc, dem = read_rpc(tif), read_dem(str(dem_path))
    with rasterio.open(tif) as src:
        image, rpcs = src.read(1), src.rpcs
    table = read_gcps(data / "rpc" / "gcps.geojson")
    lon, lat = pyproj.Transformer.from_crs(table.crs, "EPSG:4326", always_xy=True).transform(*table.ground[:, :2].T)
    ground, pixel = np.column_stack([lon, lat, table.ground[:, 2]]), table.pixel
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # 2 GCPs beyond the file, inside the RPC's image
        res = refine_rpc(rpc, ground, pixel, "shift")
    gcps = [{"ji": p, "xyz": g} for p, g in zip(pixel, ground, strict=True)]
    refined = oty_refine(rpc.to_dict(), gcps, RpcRefine.shift)
    oty_rmse = float(
        np.sqrt(np.mean(np.sum((pixel - RpcCamera(rpc.image_size, refined).world_to_pixel(ground.T).T) ** 2, 1)))
    )
    print(f"\nrefined GCP RMSE: photax {res.rmse:.4f} px, orthority {oty_rmse:.4f} px (target photax <= orthority); "
          f"leave-one-out {res.loo_rmse:.3f} px (target <= 0.15)")  # fmt: skip
    record("QuickBird shift refinement GCP RMSE", photax_px=res.rmse, peer_px=oty_rmse, loo_px=res.loo_rmse)
    for label, camera, rpc_dict in (("raw", rpc, rpc.to_dict()), ("shift-refined", res.camera, refined)):
        out = tmp / f"oty-{label}.tif"
        cam = RpcCamera(rpc.image_size, rpc_dict, crs=CRS)
        Ortho(str(tif), str(dem_path), cam, crs=CRS).process(
            out, (5.0, 5.0), interp="bilinear", dem_interp="bilinear", compress="deflate", build_ovw=False
        )
        with rasterio.open(out) as src:
            ref, grid = src.read(1), Grid(src.transform, src.shape, CRS)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ours, _ = orthorectify(image, None, camera, dem, grid, nodata=0)
        shift, mad, n = offset_and_mad(ours, ref)
        print(f"{label} ortho vs oty rpc: offset {shift:.3f} px, MAD {mad:.3f} grey levels on {n} common pixels "
              "(targets 0.2 px, 1 grey level)")  # fmt: skip
        record(f"QuickBird {label} ortho vs orthority", offset_px=shift, mad_grey=mad, pixels=n)
        if label != "raw":
            continue
        gdal = np.zeros(grid.shape, np.uint8)
        opts = dict(RPC_DEM=str(dem_path), RPC_DEM_APPLY_VDATUM_SHIFT=False, RPC_DEMINTERPOLATION="bilinear")
        reproject(image, gdal, rpcs=rpcs, src_crs="EPSG:4326", dst_crs=CRS, dst_transform=grid.transform,
                  resampling=Resampling.bilinear, src_nodata=0, dst_nodata=0, **opts)  # fmt: skip
        shift, mad, n = offset_and_mad(ours, gdal)
        xy = grid.xy()[::7, ::7].reshape(-1, 2)
        ll = pyproj.Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(xy[:, 0], xy[:, 1])
        with RPCTransformer(rpcs, **opts) as t:
            rows, cols = t.rowcol(*ll, op=lambda v: v)
        pos = np.asarray(OrthoModel(None, rpc, dem, CRS)(xy))
        inside = np.isfinite(pos).all(1) & (pos >= 0).all(1) & (pos < np.array(rpc.image_size) - 1).all(1)
        err = float(np.abs(pos[inside] - (np.column_stack([cols, rows])[inside] - 0.5)).max())
        print(f"raw ortho vs GDAL's warper: offset {shift:.3f} px, MAD {mad:.4f} grey levels; image positions vs "
              f"GDAL's RPC transformer with RPC_DEM: max {err:.1e} px over {inside.sum()} points (target 0.1 px)")  # fmt: skip
        record("QuickBird raw ortho vs GDAL", offset_px=shift, mad_grey=mad, positions_max_px=err)


def in_process(data: pathlib.Path, tmp: pathlib.Path, repeat: int) -> None:
    """photax's orthorectify_file and orthority's Ortho.process, one process, interleaved medians."""
    from orthority import Ortho
    from orthority.camera import RpcCamera

    from photax.io.raster import read_dem
    from photax.rectification import orthorectify_file
    from photax.rpc import read_rpc

    tif, dem_path = data / "rpc" / "qb2_basic1b.tif", data / "ngi" / "dem.tif"
    rpc = read_rpc(tif)

    def ours():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dem = read_dem(str(dem_path))  # as the command reads it, each time
            orthorectify_file(tif, tmp / "p.tif", None, rpc, dem, resolution=5.0)

    def peer():
        cam = RpcCamera(rpc.image_size, rpc.to_dict(), crs=CRS)
        Ortho(str(tif), str(dem_path), cam, crs=CRS).process(
            tmp / "o.tif", (5.0, 5.0), interp="bilinear", dem_interp="bilinear", compress="deflate",
            build_ovw=False, overwrite=True,
        )  # fmt: skip

    s0 = steal()
    t = median_times({"photax": ours, "orthority": peer}, repeat=repeat)
    print(f"\nin one process (warm): photax orthorectify_file {t['photax']:.3f} s, orthority Ortho.process "
          f"{t['orthority']:.3f} s, ratio {t['photax'] / t['orthority']:.2f} (target <= 1); load {load()}, "
          f"steal {steal() - s0:.1f} s")  # fmt: skip
    record("QuickBird RPC ortho in one process vs orthority (wall)", photax_s=t["photax"], peer_s=t["orthority"],
           ratio=t["photax"] / t["orthority"], load=load())  # fmt: skip


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per command (medians)")
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data" / "orthority"),
                    help="orthority's test data (rpc/ and ngi/)")  # fmt: skip
    ap.add_argument("--speed-only", action="store_true", help="only the whole-process timings (no accuracy)")
    add_threads_option(ap)
    args = ap.parse_args()
    apply_threads(args)
    start("bench_rpc")
    data = pathlib.Path(args.data).resolve()
    if not (data / "rpc" / "qb2_basic1b.tif").is_file() or not (data / "ngi" / "dem.tif").is_file():
        print(f"QuickBird / NGI data absent from {data}: give --data")
        return
    with tempfile.TemporaryDirectory(prefix="photax-rpc-") as tmp:
        tmp = pathlib.Path(tmp)
        if not args.speed_only:
            accuracy(data, tmp)
            in_process(data, tmp, args.repeat)
        drop = ("PYTHONDONTWRITEBYTECODE", "JAX_COMPILATION_CACHE_DIR")
        env = {k: v for k, v in os.environ.items() if k not in drop}
        env.update(PYTHONPYCACHEPREFIX=str(tmp / "pycache"), PYTHONWARNINGS="ignore",
                   JAX_COMPILATION_CACHE_DIR=str(tmp / "warm-cache"))  # fmt: skip
        for d in ("oty-raw", "oty-ref"):
            (tmp / d).mkdir()
        cmds = {
            "photax raw": photax_cmd(data, tmp / "p-raw.tif"),
            "oty raw": oty_cmd(data, tmp / "oty-raw"),
            "photax shift": photax_cmd(data, tmp / "p-ref.tif", refine=True),
            "oty shift": oty_cmd(data, tmp / "oty-ref", refine=True),
        }
        print()
        for k, c in cmds.items():
            print(f"{k}: " + shlex.join(map(str, c)).replace(str(BIN) + "/", ""))
        s0 = steal()
        t = interleaved({k: (c, env) for k, c in cmds.items()}, args.repeat, cwd=tmp)
        for k, m in t.items():
            show(k, m)
        for kind in ("raw", "shift"):
            p, o = t[f"photax {kind}"], t[f"oty {kind}"]
            print(f"whole process, {kind}: photax {p[0]:.2f} s, oty {o[0]:.2f} s, ratio {p[0] / o[0]:.2f} (target <= 1); "
                  f"cpu ratio {p[1] / o[1]:.2f}")  # fmt: skip
            record(f"QuickBird RPC ortho ({kind}), one process vs oty rpc (wall)", photax_s=p[0], peer_s=o[0],
                   ratio=p[0] / o[0], photax_cpu_s=p[1], peer_cpu_s=o[1], load=load())  # fmt: skip
        print(f"load {load()}, CPU steal during the commands {steal() - s0:.1f} s")


if __name__ == "__main__":
    main()
