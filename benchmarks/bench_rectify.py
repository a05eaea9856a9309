"""Rectification speed and memory: photax against OpenCV, GDAL, scikit-image,
SciPy and orthority, on the same input in one process.

    python benchmarks/bench_rectify.py [--quick] [--big N] [--no-big] [--no-cli]

Every ratio is photax / peer from medians of runs *interleaved* with the
peer's (``_common.median_times``), so a change in the machine's load hits
both; the figures go to ``benchmarks/results/bench_rectify.json``.

1. A synthetic N x N uint8 image (N = 4096; 1024 with --quick) through a
   3rd-order polynomial map (map -> pixel, fitted with photax.fit_polynomial)
   onto an N x N grid.  photax's time includes the mapping: by default the
   approximate transformer (exact model on a 16-px lattice, checked at cell
   centres and edge midpoints, approx=0.125 px, exact fallback per chunk);
   the achieved check error is printed, and the exact per-pixel mapping
   (approx=0) is timed too.  cv2.remap, scipy.ndimage.map_coordinates and
   skimage.transform.warp get the SAME per-pixel maps, computed once outside
   the timing (their map computation is NOT included: their best case).
   Kernels: bilinear and cubic are compared with cv2's INTER_LINEAR /
   INTER_CUBIC (cv2's cubic has a = -0.75, photax's a = -0.5: same 4 x 4
   taps); photax's Lanczos-3 (6 x 6 taps) has no OpenCV twin: cv2's
   INTER_LANCZOS4 is Lanczos-4 on 8 x 8 taps, so that ratio is printed with
   the kernel sizes and per tap, and the like-with-like comparisons are
   photax's "lanczos4" (the same Lanczos-4 kernel) against cv2's, and
   photax's Lanczos-3 against GDAL's, which is Lanczos-3 on 6 x 6.  GDAL (through
   rasterio.warp.reproject with 100 GCPs, MAX_GCP_ORDER=3) fits its own
   order-3 polynomials to the GCPs and, by default, evaluates them exactly
   only every few pixels (approximate transformer, 0.125 px); its timing
   includes that map computation.
2. The same image through an orthorectification (synthetic frame camera,
   1000 m above a hilly DEM): photax.orthorectify (DEM lookup + collinearity
   + resampling, all timed) against cv2.remap on the maps photax computed
   once (not timed).
3. The real NGI frame (640 x 1152 x 3, ../shared/data) at 5 m, bilinear,
   from the same files to the same kind of output (deflate GeoTIFF, no
   overviews, nodata rather than a mask) for both: DEM read, grid set-up,
   resampling and writing are all timed.
   a. API: photax.orthorectify_file(image, out, exterior, camera, DEM path,
      resolution=5) vs orthority Ortho(image, DEM path, camera).process(...),
      the camera objects made once outside the timing.
   b. CLI, whole process as a subprocess: ``photax ortho`` vs ``oty frame``
      (wall time and peak resident memory of the process), warm (a run
      before the timed ones filled JAX's persistent compile cache) and, for
      photax, cold (an empty compile cache).
4. A --big x --big uint8 GeoTIFF (default 16384: 256 MPix) rectified
   file -> file with photax.rectify_file: wall time of the first call
   (cold: includes tracing and compilation) and of a second call (warm),
   and peak resident memory.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import tempfile
import time

import cv2
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _common import (
    add_threads_option,
    apply_threads,
    median_cpu_time,
    median_time,
    median_times,
    mib,
    peak_memory,
    ratio_line,
    record,
    run_process,
    start,
)  # noqa: E402

import photax  # noqa: E402
from photax.rectification import Grid, OrthoModel, ortho_grid  # noqa: E402
from photax.rectification._approx import _map_tile  # noqa: E402

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
    print(
        f"{name} approx: max position error at the check positions {info['approx_error']:.4f} px "
        f"(threshold {info['approx']}), {100 * info['exact_fraction']:.1f}% of chunks mapped exactly"
    )
    record(f"{name} approx", approx_error_px=info["approx_error"], exact_fraction=info["exact_fraction"])
    t = median_times(
        {"approx": lambda: run(resampling="bilinear"), "exact": lambda: run(resampling="bilinear", approx=0)},
        repeat=max(1, repeat // 2),
    )
    print(ratio_line(f"{name} bilinear approx=0.125 vs photax exact (approx=0)", t["approx"], t["exact"]))
    _, peak = peak_memory(lambda: run(resampling="bilinear"))
    record(f"{name} bilinear photax peak memory", bytes=peak)
    print(f"{name} bilinear photax peak memory {mib(peak)}")


# photax method -> (OpenCV flag, OpenCV taps per axis, photax taps per axis)
CV2 = {
    "bilinear": (cv2.INTER_LINEAR, 2, 2),
    "cubic": (cv2.INTER_CUBIC, 4, 4),
    "lanczos": (cv2.INTER_LANCZOS4, 8, 6),
    "lanczos4": (cv2.INTER_LANCZOS4, 8, 8),
}


def cv2_maps(cols, rows):
    c32, r32 = cols.astype(np.float32), rows.astype(np.float32)
    c32[~np.isfinite(c32)] = -1e6
    r32[~np.isfinite(r32)] = -1e6
    return c32, r32


def vs_cv2(name, run, image, cols, rows, methods, repeat):
    """photax ``run(resampling=m)`` vs cv2.remap on precomputed maps,
    interleaved; returns photax's times."""
    c32, r32 = cv2_maps(cols, rows)
    ours = {}
    for label in methods:
        flag, k_cv, k_ours = CV2[label]
        t = median_times(
            {
                "photax": lambda: run(resampling=label),
                "cv2": lambda: cv2.remap(image, c32, r32, flag, borderMode=cv2.BORDER_CONSTANT),
            },
            repeat,
        )
        ours[label] = t["photax"]
        if k_cv == k_ours:
            print(ratio_line(f"{name} {label} vs cv2.remap", t["photax"], t["cv2"]))
        else:
            print(
                ratio_line(
                    f"{name} {label} ({k_ours}x{k_ours} taps) vs cv2.remap INTER_LANCZOS4 ({k_cv}x{k_cv} taps: "
                    f"a different kernel)",
                    t["photax"],
                    t["cv2"],
                )
            )
            per_tap = (t["photax"] / k_ours**2) / (t["cv2"] / k_cv**2)
            record(f"{name} {label} vs cv2 per tap", ratio=per_tap)
            print(f"{name} {label} vs cv2.remap INTER_LANCZOS4 per tap (time / taps): ratio photax/peer {per_tap:.2f}")
    return ours


def peers(name, image, cols, rows, ours_by_order, slow_repeat):
    from scipy import ndimage
    from skimage.transform import warp

    coords = np.stack([np.nan_to_num(rows, nan=-1e6), np.nan_to_num(cols, nan=-1e6)])
    for label, order in (("bilinear", 1), ("cubic", 3)):
        ours = ours_by_order[label]
        t = median_time(
            lambda: ndimage.map_coordinates(image, coords, order=order, cval=0), repeat=slow_repeat, warmup=0
        )
        print(ratio_line(f"{name} {label} vs scipy map_coordinates(order={order})", ours, t))
        t = median_time(lambda: warp(image, coords, order=order, preserve_range=True), repeat=slow_repeat, warmup=0)
        print(ratio_line(f"{name} {label} vs skimage warp(order={order})", ours, t))


def bench_polynomial(n, repeat, slow_repeat):
    from rasterio.control import GroundControlPoint
    from rasterio.warp import Resampling, reproject

    image = synthetic_image(n)
    model, grid, pix, ground = polynomial_case(n)
    print(f"\n== {n} x {n} uint8, 3rd-order polynomial map ==")
    cols, rows = maps(model, grid)
    run = lambda **kw: photax.rectify(image, model, grid, **kw)  # noqa: E731
    ours = vs_cv2("poly", run, image, cols, rows, ("bilinear", "cubic", "lanczos", "lanczos4"), repeat)
    report_ours("poly", run, ours, repeat)
    peers("poly", image, cols, rows, ours, slow_repeat)
    gcps = [GroundControlPoint(row=r, col=c, x=x, y=y) for (c, r), (x, y) in zip(pix + 0.5, ground)]
    for label, rs in (("bilinear", Resampling.bilinear), ("cubic", Resampling.cubic), ("lanczos", Resampling.lanczos)):
        dst = np.zeros(grid.shape, np.uint8)

        def gdal():
            reproject(
                image,
                dst,
                gcps=gcps,
                src_crs=CRS,
                dst_transform=grid.transform,
                dst_crs=CRS,
                resampling=rs,
                num_threads=2,
                MAX_GCP_ORDER=3,
            )

        t = median_times({"photax": lambda: run(resampling=label), "gdal": gdal}, repeat=max(1, repeat // 2))
        print(ratio_line(f"poly {label} vs GDAL reproject (GCP_POLYNOMIAL order 3, 2 threads)", t["photax"], t["gdal"]))


def bench_breakdown(n, repeat):
    """Where photax's resampling time goes, in CPU time per output pixel
    (process time of all threads, so the machine's other load matters less
    than for wall time), on the same 4096^2 polynomial case:

    * the lattice plan alone (exact model on the 16-px lattice and at the
      check positions, per tile: ``_tile_plan``);
    * the file path's two steps: positions stored per tile
      (``_tile_positions``) and resampling from them (``_resample_tile``);
    * the in-memory path: each tile's fused kernel (plan, positions and
      resampling in one jitted call, ``_rectify_tile``) run tile after tile,
      and the whole ``photax.rectify`` call (thread pool, source padding,
      copying tiles out): the difference is the cost outside the kernels;
    * OpenCV's CPU time for the same pixels, maps given.

    ``(cubic - bilinear) / 12`` is the cost of one more tap."""
    import equinox as eqx

    from photax.rectification._approx import _tile_plan, _tile_positions
    from photax.rectification._indirect import _rectify_tile, _resample_tile
    from photax.rectification._tiling import _approx_arg, _layout, tile_windows
    from photax.resampling import gather_source

    image = synthetic_image(n)
    model, grid, _, _ = polynomial_case(n)
    cols, rows = maps(model, grid)
    c32, r32 = cv2_maps(cols, rows)
    transform = jnp.asarray(tuple(grid.transform)[:6])
    tiles = list(tile_windows(grid.shape, 1024))
    layout = _layout(*tiles[0][2:])
    size = image.shape
    fill = jnp.zeros((1,), jnp.uint8)
    approx = _approx_arg(0.125)
    offsets = [np.array([r0, c0], dtype=float) for r0, c0, _, _ in tiles]
    plan = eqx.filter_jit(_tile_plan)

    def plans():
        for o in offsets:
            jax.block_until_ready(plan(model, transform, o, layout, approx, size))

    def positions():
        return [jax.block_until_ready(_tile_positions(model, transform, o, layout, approx, size)) for o in offsets]

    plans()
    pos = positions()
    px = float(n * n)
    ns = {
        "plan": median_cpu_time(plans, repeat=repeat) / px * 1e9,
        "positions": median_cpu_time(positions, repeat=repeat) / px * 1e9,
    }
    print(f"\n== where the time goes ({n} x {n}, CPU ns per output pixel, all threads) ==")
    print(f"lattice plan alone (exact model on the 16-px lattice and check positions): {ns['plan']:.2f} ns/px")
    print(f"file path: plan + positions stored per tile: {ns['positions']:.2f} ns/px")
    record("breakdown plan", photax_ns_per_px=ns["plan"])
    for label in ("bilinear", "cubic", "lanczos", "lanczos4"):
        flat = gather_source(image[None], label, jnp.float32)

        def resample_only():
            for p, o, _, _ in pos:
                jax.block_until_ready(
                    _resample_tile(flat, p, o, o, fill, size, size, label, jnp.float32, np.dtype("uint8"))
                )

        def kernels():
            for o in offsets:
                jax.block_until_ready(
                    _rectify_tile(
                        model, flat, transform, o, fill, layout, approx, size, label, jnp.float32, np.dtype("uint8")
                    )
                )

        def whole():
            photax.rectify(image, model, grid, resampling=label)

        for f in (resample_only, kernels, whole):
            f()
        ns[label] = median_cpu_time(resample_only, repeat=repeat) / px * 1e9
        k_ns = median_cpu_time(kernels, repeat=repeat) / px * 1e9
        w_ns = median_cpu_time(whole, repeat=repeat) / px * 1e9
        flag, k_cv, k_ours = CV2[label]
        ns_cv = (
            median_cpu_time(lambda: cv2.remap(image, c32, r32, flag, borderMode=cv2.BORDER_CONSTANT), repeat=repeat)
            / px
            * 1e9
        )
        print(
            f"{label} ({k_ours}x{k_ours} taps): file path resampling from stored positions {ns[label]:.2f} ns/px; "
            f"in memory: fused tile kernels one after another {k_ns:.2f} ns/px, whole rectify call {w_ns:.2f} "
            f"ns/px; cv2.remap ({k_cv}x{k_cv} taps, maps given): {ns_cv:.2f} ns/px"
        )
        record(
            f"breakdown {label}",
            photax_ns_per_px=ns[label],
            tile_kernels_ns_per_px=k_ns,
            rectify_ns_per_px=w_ns,
            cv2_ns_per_px=ns_cv,
            taps=k_ours**2,
            cv2_taps=k_cv**2,
        )
    per_tap = (ns["cubic"] - ns["bilinear"]) / 12
    fixed = ns["bilinear"] - 4 * per_tap
    record("breakdown positions", photax_ns_per_px=ns["positions"])
    record("breakdown per tap", photax_ns=per_tap, fixed_ns_per_px=fixed)
    print(f"one more tap: {per_tap:.2f} ns; per pixel besides the taps and positions: {fixed:.2f} ns")


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
    cols, rows = maps(OrthoModel(exterior, camera, dem), grid)
    run = lambda **kw: photax.orthorectify(image, exterior, camera, dem, grid, **kw)  # noqa: E731
    ours = vs_cv2("ortho", run, image, cols, rows, ("bilinear", "cubic"), repeat)
    report_ours("ortho", run, ours, repeat)


def bench_ngi(repeat, cli: bool, data, resolution: float = 5.0):
    import pathlib
    import shutil

    import rasterio
    from orthority.camera import PinholeCamera
    from orthority.ortho import Ortho

    data = pathlib.Path(data)
    if not (data / "dem.tif").is_file():
        print(f"\n(NGI data absent from {data}: orthority comparison skipped; give --data)")
        return
    from photax.io import read_orthority_exterior, read_orthority_interior

    name = "3324c_2015_1004_05_0182_RGB"
    prj = (data / "ngi_xyz_opk.prj").read_text()
    camera = read_orthority_interior(data / "ngi_int_param.yaml")["Integraph DMC"]
    exterior = read_orthority_exterior(data / "ngi_xyz_opk.csv")[name]
    with tempfile.TemporaryDirectory() as tmp:
        # The DEM with the horizontal CRS only (no geoid grid needed), and
        # the orientation files beside it: both programs read the same files.
        with rasterio.open(data / "dem.tif") as src:
            profile, heights = src.profile, src.read()
        profile.update(crs=rasterio.CRS.from_string(prj))
        with rasterio.open(f"{tmp}/dem.tif", "w", **profile) as dst:
            dst.write(heights)
        for f in ("ngi_int_param.yaml", "ngi_xyz_opk.csv", "ngi_xyz_opk.prj", f"{name}.tif"):
            shutil.copy(data / f, f"{tmp}/{f}")
        image = f"{tmp}/{name}.tif"
        ocam = PinholeCamera(
            (640, 1152),
            120.0,
            (92.16, 165.888),
            0.0,
            0.0,
            xyz=tuple(np.asarray(exterior.position)),
            opk=tuple(np.asarray(exterior.angles)),
        )

        def orth():
            Ortho(image, f"{tmp}/dem.tif", ocam, crs=prj).process(
                f"{tmp}/o.tif",
                resolution=(resolution, resolution),
                interp="bilinear",
                dem_interp="bilinear",
                compress="deflate",
                write_mask=False,
                build_ovw=False,
                overwrite=True,
            )

        def ours():
            photax.orthorectify_file(
                image,
                f"{tmp}/p.tif",
                exterior,
                camera,
                f"{tmp}/dem.tif",
                resolution=resolution,
                resampling="bilinear",
                compress="deflate",
            )

        t = median_times({"photax": ours, "orthority": orth}, repeat=repeat)
        shapes = []
        for f in ("p.tif", "o.tif"):
            with rasterio.open(f"{tmp}/{f}") as ds:
                shapes.append(f"{ds.width} x {ds.height}")
        print(f"\n== NGI frame 640 x 1152 x 3 at {resolution:g} m, bilinear, file to file (DEM read, grid, deflate) ==")
        print(f"outputs: photax {shapes[0]}, orthority {shapes[1]} pixels")
        print(ratio_line("NGI ortho API call vs orthority Ortho.process", t["photax"], t["orthority"]))
        if not cli:
            return
        bindir = pathlib.Path(sys.executable).parent
        photax_cmd = [
            str(bindir / "photax"),
            "ortho",
            image,
            "--dem",
            f"{tmp}/dem.tif",
            "--interior",
            f"{tmp}/ngi_int_param.yaml",
            "--exterior",
            f"{tmp}/ngi_xyz_opk.csv",
            "--out",
            f"{tmp}/pc.tif",
            "--resolution",
            str(resolution),
            "--resampling",
            "bilinear",
            "--no-progress",
        ]
        oty_cmd = [
            str(bindir / "oty"),
            "frame",
            image,
            "--dem",
            f"{tmp}/dem.tif",
            "--int-param",
            f"{tmp}/ngi_int_param.yaml",
            "--ext-param",
            f"{tmp}/ngi_xyz_opk.csv",
            "--res",
            str(resolution),
            "--interp",
            "bilinear",
            "--dem-interp",
            "bilinear",
            "--compress",
            "deflate",
            "--no-write-mask",
            "--no-build-ovw",
            "--out-dir",
            f"{tmp}/oty",
            "--overwrite",
        ]
        os.makedirs(f"{tmp}/oty", exist_ok=True)
        env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=f"{tmp}/jax-cache")  # starts empty: the first run is cold
        cold = run_process(photax_cmd, env)
        runs = {"photax": [], "oty": []}
        for _ in range(repeat):
            runs["photax"].append(run_process(photax_cmd, env))
            runs["oty"].append(run_process(oty_cmd))
        med = {k: (float(np.median([r[0] for r in v])), max(r[1] for r in v)) for k, v in runs.items()}
        print("photax: " + shlex.join(photax_cmd).replace(tmp, "$TMP"))
        print("oty:    " + shlex.join(oty_cmd).replace(tmp, "$TMP"))
        print(
            ratio_line("NGI ortho whole CLI process, warm compile cache, vs oty frame", med["photax"][0], med["oty"][0])
        )
        record(
            "NGI ortho whole CLI process peak memory",
            photax_bytes=med["photax"][1],
            peer_bytes=med["oty"][1],
            ratio=med["photax"][1] / med["oty"][1],
        )
        print(
            f"NGI ortho CLI peak resident memory: photax {mib(med['photax'][1])}, oty {mib(med['oty'][1])}, "
            f"ratio {med['photax'][1] / med['oty'][1]:.2f}"
        )
        record("NGI ortho whole CLI process, cold (empty compile cache)", photax_s=cold[0], photax_bytes=cold[1])
        print(f"NGI ortho CLI photax cold (empty compile cache): {cold[0]:.2f} s, peak {mib(cold[1])}")


def bench_big(n):
    import rasterio
    from rasterio.windows import Window

    model, grid, _, _ = polynomial_case(n)
    with tempfile.TemporaryDirectory() as tmp:
        src = f"{tmp}/big_in.tif"
        block = synthetic_image(1024, seed=3)
        with rasterio.open(
            src,
            "w",
            driver="GTiff",
            width=n,
            height=n,
            count=1,
            dtype="uint8",
            tiled=True,
            blockxsize=256,
            blockysize=256,
            BIGTIFF="IF_SAFER",
        ) as dst:
            for r in range(0, n, 1024):
                for c in range(0, n, 1024):
                    dst.write(
                        block[None, : min(1024, n - r), : min(1024, n - c)],
                        window=Window(c, r, min(1024, n - c), min(1024, n - r)),
                    )

        def once():
            t0 = time.perf_counter()
            _, peak = peak_memory(
                lambda: photax.rectify_file(
                    src, f"{tmp}/big_out.tif", model, grid, tile=1024, compress=None, progress=True
                )
            )
            return time.perf_counter() - t0, peak

        cold, warm = once(), once()  # the first call traces and compiles
        print(f"\n== {n} x {n} = {n * n / 1e6:.0f} MPix uint8 file -> file (rectify_file, bilinear, tile 1024) ==")
        print(
            f"big rectify_file: cold (first call, with compilation) {cold[0]:.1f} s, warm {warm[0]:.1f} s, "
            f"peak memory {mib(max(cold[1], warm[1]))} (target < 2048 MiB)"
        )
        record("big rectify_file", n=n, cold_s=cold[0], warm_s=warm[0], peak_bytes=max(cold[1], warm[1]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1024^2 instead of 4096^2, 4096^2 big case")
    ap.add_argument("--big", type=int, default=None, help="edge of the big file case (default 16384)")
    ap.add_argument("--no-big", action="store_true")
    ap.add_argument("--no-cli", action="store_true", help="skip the whole-process photax ortho / oty frame runs")
    ap.add_argument(
        "--data",
        default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data"),
        help="folder with the NGI files (default ../shared/data beside the repository)",
    )
    ap.add_argument(
        "--only", choices=("poly", "breakdown", "ortho", "ngi", "big"), action="append", help="run only these parts"
    )
    add_threads_option(ap)
    args = ap.parse_args()
    apply_threads(args)
    start("_".join(["bench_rectify"] + (["quick"] if args.quick else []) + sorted(args.only or [])))
    n = 1024 if args.quick else 4096
    repeat, slow = (5, 1) if not args.quick else (5, 2)
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}; opencv threads {cv2.getNumThreads()}")
    parts = set(args.only or ("poly", "breakdown", "ortho", "ngi", "big"))
    if "poly" in parts:
        bench_polynomial(n, repeat, slow)
    if "breakdown" in parts:
        bench_breakdown(n, repeat)
    if "ortho" in parts:
        bench_ortho(n, repeat, slow)
    if "ngi" in parts:
        bench_ngi(5, not args.no_cli, args.data)
    if "big" in parts and not args.no_big:
        bench_big(args.big or (4096 if args.quick else 16384))


if __name__ == "__main__":
    main()
