"""A big ortho on Dask: photax.orthorectify_dask + to_raster against GDAL
(rasterio.warp.reproject, 2 threads) and odc-geo's xr_reproject, with the
peak memory of photax's run against one chunk's working set.

    python benchmarks/bench_scale.py [--size 20000] [--chunks 1024 [512 2048 ...]] [--image 2000] [--no-peers]

A rendered relief scene (``photax.relief_scene``, ``--image`` x 0.8
``--image`` pixels, uint8) and a ``--size`` x ``--size`` output grid inside
its footprint (finer than the image's ground sampling distance, as a big
ortho from a big frame would be: the cost is per output pixel).  Dask's
threaded scheduler with 2 workers (this machine has 2 cores); a progress bar
shows each run.  Measured, in this order, each once (a big run is minutes):

1. photax: ``orthorectify_dask(...)`` (bilinear, default approximate
   mapping) written by ``photax.to_raster`` to a tiled deflate GeoTIFF (the
   whole path a user runs), for each ``--chunks``: wall and CPU time,
   MPix/s, and the peak resident memory above the start
   (``_common.peak_memory``: the kernel's high-water mark).  Compilation is
   done first on one chunk, and a first write of a small ortho (2 x 2
   chunks) loads the writing code (not timed or measured: a big run pays
   them once, ~2 s and ~10 MiB of modules and thread pools; before
   2026-11-24 09:30 they were inside the first chunk size's peak).
   "One chunk's working set" is what computing one chunk must hold -- its
   source window, its mapping (the ``(2, h, w)`` float32 positions), its
   output and the kernels' temporaries -- measured as the peak resident
   memory above the start of computing one chunk (one Dask task, the middle
   one) alone, compiled, the largest of three runs.  The issue's acceptance
   is a whole-write peak <= 2x that.
   Both are measured twice.  First as a user's process runs (glibc's
   default malloc: a freed buffer above its dynamic mmap threshold stays in
   the freeing thread's arena, so a chunk measured alone reuses what the
   compilation left, and the whole write's peak includes the pools of the
   2 worker threads and the main thread).  Then, last, in a fresh process
   with glibc's mmap threshold fixed at 128 KiB from the start
   (``MALLOC_MMAP_THRESHOLD_``): every buffer is mapped when allocated and
   unmapped when freed, so resident memory is the bytes in use -- the
   like-for-like ratio (the kernels fault in fresh pages for every buffer:
   more CPU time).  (Before 2026-11-24 07:30 the "chunk"
   was a 1024^2 slice straddling 4 chunks of 1000^2, measured against the
   pools only: 4-11 MiB.)
2. photax into memory: the same array computed into a NumPy array
   (``dask.array.store``) -- the like-for-like figure against 3 and 4.
3. GDAL: ``rasterio.warp.reproject`` of the image to the same grid,
   bilinear, ``num_threads=2``, from 100 GCPs (photax's projection of a
   10 x 10 ground lattice) with ``MAX_GCP_ORDER=3``: gdalwarp's warping with
   its own (approximate, 0.125 px) transformer, the GCP polynomial standing
   in for the collinearity model (GDAL has no frame-camera model; an RPC
   model would be slower).  Into a NumPy array.
4. odc-geo (``pip install -e ".[bench]"``): ``xr_reproject`` of the image
   given an affine georeference (the order-1 fit to the same GCPs: odc
   reprojects between CRSs and affine grids, it has no GCP or camera model,
   so this is only the resampling's cost on Dask) onto the same GeoBox,
   bilinear, chunked like photax, computed into a NumPy array.

Peers 3-4 do not orthorectify; their figures bound what a warp of the same
size costs, not the same result.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _common import mib, peak_memory, record, start  # noqa: E402

import photax  # noqa: E402
from photax.rectification import Grid, ortho_grid  # noqa: E402

CRS = "EPSG:32633"


def scene(width: int):
    s = photax.relief_scene(300.0, image_size=(width, width * 4 // 5), focal_px=float(width), n_gcp=3, n_check=0)
    grey = np.asarray(s.image, dtype=float)  # rendered as float: an 8-bit frame, as aerial images are
    lo, hi = np.nanmin(grey), np.nanmax(grey)
    return s, np.round(255 * (grey - lo) / (hi - lo)).astype(np.uint8)


def square_grid(s, size: int) -> Grid:
    """A size x size grid centred in the image's footprint, inside it."""
    from rasterio import Affine

    g = ortho_grid(s.exterior, s.camera, s.dem)
    a, e = g.transform.a, -g.transform.e
    side = 0.6 * min(g.shape[1] * a, g.shape[0] * e)  # metres: well inside the footprint
    cx, cy = g.transform * (g.shape[1] / 2, g.shape[0] / 2)
    res = side / size
    return Grid(Affine(res, 0, cx - side / 2, 0, -res, cy + side / 2), (size, size), CRS)


def gcps_for(s, grid: Grid):
    """100 GCPs: a 10 x 10 ground lattice over the grid, on the DEM, and the
    pixels photax projects them to."""
    import jax.numpy as jnp

    t = np.linspace(0.02, 0.98, 10)
    cols, rows = np.meshgrid(t * grid.shape[1], t * grid.shape[0])
    x, y = grid.transform * (cols.ravel(), rows.ravel())
    x, y = np.asarray(x), np.asarray(y)
    z = np.asarray(s.dem.height(jnp.asarray(x), jnp.asarray(y)))
    pix = np.asarray(
        s.camera.image_to_pixel(photax.project(jnp.asarray(np.stack([x, y, z], -1)), s.exterior, s.camera))
    )
    return pix, np.stack([x, y], -1)


def _trim() -> None:
    """Hand freed heap memory back to the system (glibc), so that a peak
    measured next starts from what is in use, not from a pool."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


def _block(arr):
    """The chunk in the middle of a lazy ortho: one Dask block, one task."""
    nb = arr.data.numblocks
    return arr.data.blocks[nb[0] // 2, nb[1] // 2]


def _chunk_peak(arr) -> int:
    """One chunk's working set: the peak resident memory above the start of
    computing that one chunk (one task) alone, compiled, the largest of
    three runs (freed heap handed back to the system before each)."""
    one = _block(arr)
    peak = 0
    for _ in range(3):
        _trim()
        peak = max(peak, peak_memory(one.compute)[1])
    return peak


def _write(arr, label: str) -> dict:
    """``photax.to_raster`` of the whole lazy ortho to a tiled deflate
    GeoTIFF: wall and CPU time, peak resident memory above the start."""
    import resource

    from dask.diagnostics import ProgressBar

    size = arr.shape[-1]
    chunk = arr.data.chunksize[-1]
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "ortho.tif")
        print(f"photax orthorectify_dask -> to_raster ({arr.data.npartitions} chunks of {chunk}^2, {label})")
        # dt 0.5 s: Dask's finish callback waits for the bar's next tick inside the
        # timed call (dt=5 added up to 5 s to the times before 2026-11-24 07:40).
        with ProgressBar(dt=0.5):
            _trim()
            t0, c0 = time.perf_counter(), time.process_time()
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            _, peak = peak_memory(lambda: photax.to_raster(arr, out))
            dt, cpu = time.perf_counter() - t0, time.process_time() - c0
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
        load = os.getloadavg()[0]
        mpix = size**2 / 1e6
        print(
            f"  {dt:.1f} s ({cpu:.1f} CPU s, {faults} page faults), {mpix / dt:.1f} MPix/s, peak {mib(peak)} above "
            f"the start; file {mib(os.path.getsize(out))} (load {load:.1f})"
        )
        return {
            "seconds": dt,
            "cpu_seconds": cpu,
            "page_faults": faults,
            "mpix_per_s": mpix / dt,
            "peak_bytes": peak,
            "load": load,
        }


def _live(args, chunk_default, write_default) -> None:
    """The same measurements in a fresh process with glibc's mmap threshold
    fixed at its initial 128 KiB (``MALLOC_MMAP_THRESHOLD_``, read when
    malloc starts: set later, ``mallopt`` would still serve buffers from
    the pools already there): every buffer above it is mapped when allocated
    and unmapped when freed, no pools of freed buffers in the threads'
    arenas, so resident memory is the bytes in use, for the chunk alone and
    for the whole write alike -- the like-for-like ratio (the kernels fault
    in fresh pages for every buffer: more CPU time)."""
    import json
    import subprocess

    env = dict(os.environ, MALLOC_MMAP_THRESHOLD_=str(128 * 1024))
    cmd = [
        sys.executable,
        __file__,
        "--size",
        str(args.size),
        "--image",
        str(args.image),
        "--live-child",
        "--chunks",
        *map(str, args.chunks),
    ]
    print("live memory (a fresh process, glibc's mmap threshold fixed at 128 KiB):", flush=True)
    out = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, text=True, check=True).stdout
    text, _, tail = out.rpartition("@@live ")
    print(text, end="")
    live = json.loads(tail)
    for c in args.chunks:
        chunk, w = live[str(c)]["chunk"], live[str(c)]["write"]
        d = write_default[c]
        print(
            f"chunks {c}: one chunk {mib(chunk)} live ({mib(chunk_default[c])} with the default allocator); "
            f"whole write {mib(w['peak_bytes'])} live = {w['peak_bytes'] / chunk:.2f}x; "
            f"{mib(d['peak_bytes'])} with the default allocator = {d['peak_bytes'] / chunk:.2f}x the live chunk "
            f"(load {w['load']:.1f} / {d['load']:.1f})"
        )
        record(
            f"photax to_raster chunks={c}",
            size=args.size,
            chunks=c,
            chunk_shape=live[str(c)]["shape"],
            chunk_live_bytes=chunk,
            chunk_default_bytes=chunk_default[c],
            write_live=w,
            write_default=d,
            live_over_chunk=w["peak_bytes"] / chunk,
            default_over_chunk=d["peak_bytes"] / chunk,
        )
        if c == args.chunks[0]:
            record(
                "photax to_raster",
                seconds=d["seconds"],
                cpu_seconds=d["cpu_seconds"],
                mpix_per_s=d["mpix_per_s"],
                peak_bytes=d["peak_bytes"],
                peak_live_bytes=w["peak_bytes"],
                chunk_bytes=chunk,
                peak_over_chunk=w["peak_bytes"] / chunk,
                default_peak_over_chunk=d["peak_bytes"] / chunk,
                size=args.size,
                chunks=c,
                load=d["load"],
            )


def _live_child(ortho) -> None:
    """In the child of :func:`_live`: each chunk size's chunk and whole write."""
    import json

    res = {}
    for c, arr in ortho.items():
        res[c] = {
            "chunk": _chunk_peak(arr),
            "write": _write(arr, "mmap threshold fixed"),
            "shape": list(arr.data.chunksize),
        }
    print("@@live " + json.dumps(res))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=20000, help="output grid edge in pixels")
    ap.add_argument(
        "--chunks",
        type=int,
        nargs="+",
        default=[1024],
        help="chunk edges (several: a sweep; the first is used against the peers)",
    )
    ap.add_argument("--image", type=int, default=2000, help="rendered image width in pixels")
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--live-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if not args.live_child:
        start("bench_scale")
    import dask
    import dask.array as da
    from dask.diagnostics import ProgressBar

    dask.config.set(scheduler="threads", num_workers=2)
    t0 = time.perf_counter()
    s, image = scene(args.image)
    grid = square_grid(s, args.size)
    mpix = args.size**2 / 1e6
    print(
        f"scene {image.shape[1]} x {image.shape[0]} rendered in {time.perf_counter() - t0:.1f} s; output "
        f"{args.size} x {args.size} ({mpix:.0f} MPix) at {grid.transform.a:.3f} m, chunks {args.chunks}"
    )
    ortho = {c: photax.orthorectify_dask(image, s.exterior, s.camera, s.dem, grid, chunks=c) for c in args.chunks}
    for arr in ortho.values():
        _block(arr).compute()  # compiles the kernels (not timed)
    with tempfile.TemporaryDirectory() as tmp:  # loads the writing code (not measured)
        small = square_grid(s, 2 * args.chunks[0])
        photax.to_raster(
            photax.orthorectify_dask(image, s.exterior, s.camera, s.dem, small, chunks=args.chunks[0]),
            os.path.join(tmp, "warm.tif"),
        )
    if args.live_child:
        _live_child(ortho)
        return
    # 1. The user's process (glibc malloc as configured by default).
    chunk_default = {c: _chunk_peak(arr) for c, arr in ortho.items()}
    write_default = {c: _write(arr, "default allocator") for c, arr in ortho.items()}
    arr = ortho[args.chunks[0]]
    dst = np.empty((args.size, args.size), np.uint8)

    def store(data) -> float:
        """Seconds to compute a lazy array into ``dst``, with a progress bar
        (its last tick, <= 0.5 s, is inside the time)."""
        with ProgressBar(dt=0.5):
            t0 = time.perf_counter()
            da.store(data, dst, lock=False)
            return time.perf_counter() - t0

    print("photax orthorectify_dask -> memory")
    dt = store(arr.data)
    load = os.getloadavg()[0]
    ours_out = dst[:: args.size // 500, :: args.size // 500].copy()  # a sample to compare the peers' with
    print(f"  {dt:.1f} s, {mpix / dt:.1f} MPix/s (load {load:.1f})")
    record("photax memory", seconds=dt, mpix_per_s=mpix / dt, load=load)
    ours = dt
    if not args.no_peers:
        _peers(args, s, image, grid, ours_out, ours, dst, store)
    _live(args, chunk_default, write_default)


def _peers(args, s, image, grid, ours_out, ours, dst, store) -> None:
    import dask.array as da

    mpix = args.size**2 / 1e6
    from rasterio.control import GroundControlPoint
    from rasterio.warp import Resampling, reproject

    def agree(out):  # the peer warped the same image to the same place (not the same model: see above)
        d = np.abs(out[:: args.size // 500, :: args.size // 500].astype(float) - ours_out)
        return f"median |peer - photax| {np.median(d):.1f} grey levels on a sample"

    pix, ground = gcps_for(s, grid)
    gcps = [GroundControlPoint(row=r, col=c, x=x, y=y) for (c, r), (x, y) in zip(pix + 0.5, ground)]
    print("GDAL rasterio.warp.reproject (GCP polynomial order 3, bilinear, 2 threads) -> memory")
    t0 = time.perf_counter()
    reproject(
        image,
        dst,
        gcps=gcps,
        src_crs=CRS,
        dst_transform=grid.transform,
        dst_crs=CRS,
        resampling=Resampling.bilinear,
        num_threads=2,
        MAX_GCP_ORDER=3,
        warp_mem_limit=512,
    )
    dt = time.perf_counter() - t0
    load = os.getloadavg()[0]
    print(f"  {dt:.1f} s, {mpix / dt:.1f} MPix/s; photax / GDAL {ours / dt:.2f} (load {load:.1f}); {agree(dst)}")
    record("gdal reproject", seconds=dt, mpix_per_s=mpix / dt, photax_over_peer=ours / dt, load=load)
    try:
        from odc.geo.geobox import GeoBox
        from odc.geo.xr import wrap_xr, xr_reproject
    except ImportError:
        print("odc-geo not installed (pip install -e '.[bench]'): skipped")
        return
    from rasterio import Affine

    # Order-1 fit pixel -> ground: the affine georeference odc needs.
    a = np.c_[pix + 0.5, np.ones(len(pix))]
    coef, *_ = np.linalg.lstsq(a, ground, rcond=None)
    src_affine = Affine(coef[0, 0], coef[1, 0], coef[2, 0], coef[0, 1], coef[1, 1], coef[2, 1])
    src = wrap_xr(da.from_array(image, chunks=args.chunks[0]), GeoBox(image.shape, src_affine, CRS))
    dst_box = GeoBox((args.size, args.size), grid.transform, CRS)
    out = xr_reproject(src, dst_box, resampling="bilinear", chunks=(args.chunks[0], args.chunks[0]))
    print("odc-geo xr_reproject (affine, bilinear, Dask threads) -> memory")
    dt = store(out.data)
    load = os.getloadavg()[0]
    print(f"  {dt:.1f} s, {mpix / dt:.1f} MPix/s; photax / odc-geo {ours / dt:.2f} (load {load:.1f}); {agree(dst)}")
    record("odc-geo xr_reproject", seconds=dt, mpix_per_s=mpix / dt, photax_over_peer=ours / dt, load=load)


if __name__ == "__main__":
    main()
