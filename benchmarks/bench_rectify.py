"""Rectification speed and memory: photax against OpenCV, GDAL, scikit-image,
SciPy and orthority, on the same input in one process.

    python benchmarks/bench_rectify.py [--quick] [--big N] [--no-big]

1. A synthetic N x N uint8 image (N = 4096; 1024 with --quick) through a
   3rd-order polynomial map (map -> pixel, fitted with photax.fit_polynomial)
   onto an N x N grid.  photax's time includes the mapping: by default the
   approximate transformer (exact model on a 16-px lattice, checked at cell
   centres and edge midpoints, approx=0.125 px, exact fallback per chunk);
   the achieved check error is printed, and the exact per-pixel mapping
   (approx=0) is timed too.  cv2.remap, scipy.ndimage.map_coordinates and
   skimage.transform.warp get the SAME per-pixel maps, computed once outside
   the timing (their map computation is NOT included).  GDAL (through
   rasterio.warp.reproject with 100 GCPs, MAX_GCP_ORDER=3) fits its own
   order-3 polynomials to the GCPs (GCP_POLYNOMIAL transformer) and, by
   default, evaluates them exactly only every few pixels, interpolating
   linearly in between (approximate transformer, error threshold 0.125 px);
   its timing includes that map computation.
2. The same image through an orthorectification (synthetic frame camera,
   1000 m above a hilly DEM): photax.orthorectify (DEM lookup + collinearity
   + resampling, all timed) against cv2.remap / scipy / scikit-image on the
   maps photax computed once (not timed).
3. The real NGI frame (640 x 1152 x 3, ../shared/data): photax
   orthorectify_file against orthority's Ortho.process, file to file, 6 m,
   bilinear both.
4. A --big x --big uint8 GeoTIFF (default 16384: 256 MPix) rectified
   file -> file with photax.rectify_file: wall time and peak resident memory.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import cv2
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _common import median_time, mib, peak_memory, ratio_line  # noqa: E402

import photax  # noqa: E402
from photax.rectify import Grid, OrthoModel, _map_tile, ortho_grid  # noqa: E402

CRS = "EPSG:32633"


def synthetic_image(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (max(n // 8, 2), max(n // 8, 2)), dtype=np.uint8)
    return cv2.resize(small, (n, n), interpolation=cv2.INTER_CUBIC)


def polynomial_case(n: int):
    """A map -> pixel cubic polynomial and an n x n output grid (0.5 m pixels)."""
    rng = np.random.default_rng(1)
    pix = rng.uniform(0, n - 1, (100, 2))
    x, y = (pix[:, 0] - n / 2) / n, (pix[:, 1] - n / 2) / n
    # Ground of each control pixel: scale, small rotation, and cubic distortion.
    gx = 500000.0 + 0.5 * pix[:, 0] + 0.02 * pix[:, 1] + n * (0.01 * x**3 - 0.008 * x * y * y + 0.005 * y * y)
    gy = 5000000.0 - 0.5 * pix[:, 1] + 0.02 * pix[:, 0] + n * (0.009 * y**3 + 0.006 * x * x * y - 0.004 * x * y)
    ground = np.column_stack([gx, gy])
    model = photax.fit_polynomial(ground, pix, 3)
    centre = ground.mean(axis=0)
    half = 0.25 * n
    grid = Grid.from_bounds((centre[0] - half, centre[1] - half, centre[0] + half, centre[1] + half), 0.5, crs=CRS)
    return model, grid, pix, ground


def maps(model, grid: Grid):
    cols, rows = _map_tile(model, jnp.asarray(tuple(grid.transform)[:6]), jnp.zeros(2), grid.shape)
    return np.asarray(cols), np.asarray(rows)


def report_ours(name, run, ours, repeat):
    """The approximate mapping's achieved error, photax approx vs exact, peak memory."""
    info = {}
    run(resampling="bilinear", info=info)
    print(f"{name} approx: max position error at the check positions {info['approx_error']:.4f} px "
          f"(threshold {info['approx']}), {100 * info['exact_fraction']:.1f}% of chunks mapped exactly")
    t = median_time(lambda: run(resampling="bilinear", approx=0), repeat=max(1, repeat // 2))
    print(ratio_line(f"{name} bilinear approx=0.125 vs photax exact (approx=0)", ours["bilinear"], t))
    _, peak = peak_memory(lambda: run(resampling="bilinear"))
    print(f"{name} bilinear photax peak memory {mib(peak)}")


def peers(name, image, cols, rows, ours_by_order, repeat, slow_repeat):
    from scipy import ndimage
    from skimage.transform import warp

    c32, r32 = cols.astype(np.float32), rows.astype(np.float32)
    c32[~np.isfinite(c32)] = -1e6
    r32[~np.isfinite(r32)] = -1e6
    for label, order, flag in (("bilinear", 1, cv2.INTER_LINEAR), ("cubic", 3, cv2.INTER_CUBIC)):
        ours = ours_by_order[label]
        t = median_time(lambda: cv2.remap(image, c32, r32, flag, borderMode=cv2.BORDER_CONSTANT), repeat=repeat)
        print(ratio_line(f"{name} {label} vs cv2.remap", ours, t))
        coords = np.stack([np.nan_to_num(rows, nan=-1e6), np.nan_to_num(cols, nan=-1e6)])
        t = median_time(lambda: ndimage.map_coordinates(image, coords, order=order, cval=0), repeat=slow_repeat, warmup=0)
        print(ratio_line(f"{name} {label} vs scipy map_coordinates(order={order})", ours, t))
        t = median_time(lambda: warp(image, coords, order=order, preserve_range=True), repeat=slow_repeat, warmup=0)
        print(ratio_line(f"{name} {label} vs skimage warp(order={order})", ours, t))


def bench_polynomial(n, repeat, slow_repeat):
    from rasterio.control import GroundControlPoint
    from rasterio.warp import Resampling, reproject

    image = synthetic_image(n)
    model, grid, pix, ground = polynomial_case(n)
    print(f"\n== {n} x {n} uint8, 3rd-order polynomial map ==")
    ours = {}
    for label in ("bilinear", "cubic"):
        ours[label] = median_time(lambda: photax.rectify(image, model, grid, resampling=label), repeat=repeat)
    report_ours("poly", lambda **kw: photax.rectify(image, model, grid, **kw), ours, repeat)
    cols, rows = maps(model, grid)
    peers("poly", image, cols, rows, ours, repeat, slow_repeat)
    gcps = [GroundControlPoint(row=r, col=c, x=x, y=y) for (c, r), (x, y) in zip(pix + 0.5, ground)]
    for label, rs in (("bilinear", Resampling.bilinear), ("cubic", Resampling.cubic)):
        dst = np.zeros(grid.shape, np.uint8)

        def gdal():
            reproject(image, dst, gcps=gcps, src_crs=CRS, dst_transform=grid.transform, dst_crs=CRS,
                      resampling=rs, num_threads=2, MAX_GCP_ORDER=3)

        t = median_time(gdal, repeat=max(1, repeat // 2))
        print(ratio_line(f"poly {label} vs GDAL reproject (GCP_POLYNOMIAL order 3, 2 threads)", ours[label], t))


def ortho_case(n: int):
    camera = photax.FrameCamera.from_pixels(1.2 * n, (n, n))
    exterior = photax.ExteriorOrientation([500.0, 700.0, 1100.0], np.radians([1.0, -2.0, 15.0]), "omega-phi-kappa")
    yy, xx = np.mgrid[0:200, 0:200] * 10.0
    heights = 100.0 + 60.0 * np.sin(xx / 300.0) * np.cos(yy / 250.0) + 0.05 * xx
    dem = photax.DEM(heights, (10.0, 0.0, -500.0, 0.0, -10.0, 1700.0))
    return camera, exterior, dem, ortho_grid(exterior, camera, dem)


def bench_ortho(n, repeat, slow_repeat):
    image = synthetic_image(n, seed=2)
    camera, exterior, dem, grid = ortho_case(n)
    print(f"\n== {n} x {n} uint8, orthorectification onto {grid.shape[1]} x {grid.shape[0]} ==")
    ours = {}
    for label in ("bilinear", "cubic"):
        ours[label] = median_time(
            lambda: photax.orthorectify(image, exterior, camera, dem, grid, resampling=label), repeat=repeat
        )
    report_ours("ortho", lambda **kw: photax.orthorectify(image, exterior, camera, dem, grid, **kw), ours, repeat)
    cols, rows = maps(OrthoModel(exterior, camera, dem), grid)
    peers("ortho", image, cols, rows, ours, repeat, slow_repeat)


def bench_ngi(repeat):
    import pathlib

    import rasterio
    from orthority.camera import PinholeCamera
    from orthority.ortho import Ortho

    data = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
    if not (data / "dem.tif").is_file():
        print("\n(NGI data absent: orthority comparison skipped)")
        return
    from photax.io import read_dem, read_orthority_exterior, read_orthority_interior

    name = "3324c_2015_1004_05_0182_RGB"
    prj = (data / "ngi_xyz_opk.prj").read_text()
    camera = read_orthority_interior(data / "ngi_int_param.yaml")["Integraph DMC"]
    exterior = read_orthority_exterior(data / "ngi_xyz_opk.csv")[name]
    with tempfile.TemporaryDirectory() as tmp:
        with rasterio.open(data / "dem.tif") as src:  # horizontal CRS only: no geoid grid needed
            profile, heights = src.profile, src.read()
        profile.update(crs=rasterio.CRS.from_string(prj))
        with rasterio.open(f"{tmp}/dem.tif", "w", **profile) as dst:
            dst.write(heights)
        ocam = PinholeCamera((640, 1152), 120.0, (92.16, 165.888), 0.0, 0.0,
                             xyz=tuple(np.asarray(exterior.position)), opk=tuple(np.asarray(exterior.angles)))

        def orth():
            Ortho(data / f"{name}.tif", f"{tmp}/dem.tif", ocam, crs=prj).process(
                f"{tmp}/o.tif", resolution=(6.0, 6.0), interp="bilinear", dem_interp="bilinear",
                compress="deflate", write_mask=False, overwrite=True)

        orth()
        with rasterio.open(f"{tmp}/o.tif") as ds:
            grid = Grid(ds.transform, ds.shape, prj)
        dem = read_dem(f"{tmp}/dem.tif")
        t_o = median_time(orth, repeat=repeat)
        t_p = median_time(lambda: photax.orthorectify_file(
            data / f"{name}.tif", f"{tmp}/p.tif", exterior, camera, dem, grid, resampling="bilinear"), repeat=repeat)
        print(f"\n== NGI frame 640 x 1152 x 3 -> {grid.shape[1]} x {grid.shape[0]} at 6 m, file to file ==")
        print(ratio_line("NGI ortho bilinear vs orthority", t_p, t_o))


def bench_big(n):
    import rasterio
    from rasterio.windows import Window

    model, grid, _, _ = polynomial_case(n)
    with tempfile.TemporaryDirectory() as tmp:
        src = f"{tmp}/big_in.tif"
        block = synthetic_image(1024, seed=3)
        with rasterio.open(src, "w", driver="GTiff", width=n, height=n, count=1, dtype="uint8", tiled=True,
                           blockxsize=256, blockysize=256, BIGTIFF="IF_SAFER") as dst:
            for r in range(0, n, 1024):
                for c in range(0, n, 1024):
                    dst.write(block[None, : min(1024, n - r), : min(1024, n - c)],
                              window=Window(c, r, min(1024, n - c), min(1024, n - r)))
        t0 = time.perf_counter()
        _, peak = peak_memory(lambda: photax.rectify_file(src, f"{tmp}/big_out.tif", model, grid, tile=1024,
                                                          compress=None, progress=True))
        dt = time.perf_counter() - t0
        print(f"\n== {n} x {n} = {n * n / 1e6:.0f} MPix uint8 file -> file (rectify_file, bilinear, tile 1024) ==")
        print(f"big rectify_file: {dt:.1f} s, peak memory {mib(peak)} (target < 2048 MiB)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1024^2 instead of 4096^2, 4096^2 big case")
    ap.add_argument("--big", type=int, default=None, help="edge of the big file case (default 16384)")
    ap.add_argument("--no-big", action="store_true")
    args = ap.parse_args()
    n = 1024 if args.quick else 4096
    repeat, slow = (5, 1) if not args.quick else (5, 2)
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}, {os.cpu_count()} cpus; opencv threads {cv2.getNumThreads()}")
    bench_polynomial(n, repeat, slow)
    bench_ortho(n, repeat, slow)
    bench_ngi(3)
    if not args.no_big:
        bench_big(args.big or (4096 if args.quick else 16384))


if __name__ == "__main__":
    main()
