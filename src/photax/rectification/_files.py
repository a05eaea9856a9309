"""Rectification from a raster file to a GeoTIFF, window by window: per
output tile only the input window it needs is read (rasterio windows)."""

from __future__ import annotations

import contextvars
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from jax import Array

from .._aot import disk_cached
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..dem import DEM
from ..grid import Grid, GridSpec, gsd_hint, ortho_grid
from ..io.sizes import check_output_size
from ..resampling import Resampling
from ._approx import _tile_positions
from ._indirect import _resample_tile
from ._occlusion import occluded
from ._ortho import _check_image_size, check_ortho_inputs
from ._tiling import (
    _approx_arg,
    _check_approx,
    _check_model,
    _check_resampling,
    _fill_value,
    _layout,
    _run_tiles,
    tile_windows,
)

# Compiled executables kept on disk by photax._aot when a compilation cache
# folder is set (the CLI): a new process loads them without tracing again.
_tile_positions = disk_cached(_tile_positions, "rectify_tile_positions")
_resample_tile = disk_cached(_resample_tile, "rectify_resample_tile")


def _source_window(pos: np.ndarray, origin, width: int, height: int, margin: int, bucket: int = 256):
    """The input window ``(row_off, col_off, h, w)`` an output tile needs, or None.

    ``pos`` ``(2, h, w)`` are the tile's positions (col, row) relative to the integer ``origin``
    (col, row).  Sizes are rounded up to multiples of ``bucket`` (shifting the window
    back inside the image rather than padding it) so the jitted resampler
    sees few distinct shapes.
    """
    o = [int(v) for v in origin]
    # The bounds moved to the positions' side and compared in their dtype, where they are exact
    # (integers): no float64 copy of the positions.  NaN and infinities fail one of the two tests.
    bounds = [(-margin - o[k], n - 1 + margin - o[k]) for k, n in ((0, width), (1, height))]
    exact = max(abs(b) for pair in bounds for b in pair) < 2**24 or pos.dtype == np.float64
    ok = np.ones(pos.shape[1:], dtype=bool)
    for k, (lo, hi) in enumerate(bounds):
        v = pos[k] if exact else pos[k].astype(np.float64)  # Python ints: compared in v's dtype
        ok &= (v > lo) & (v < hi)
    if not ok.any():
        return None
    out = []
    keep = ok.ravel()
    for k, n in ((1, height), (0, width)):
        v = np.compress(keep, pos[k].ravel())  # min + o: exact in float64, as the float64 sums were
        lo = max(int(np.floor(float(v.min()) + o[k])) - margin, 0)
        hi = min(int(np.ceil(float(v.max()) + o[k])) + margin + 1, n)
        size = min(-(-(hi - lo) // bucket) * bucket, n)
        out.append((min(lo, n - size), size))
    (r0, h), (c0, w) = out
    return r0, c0, h, w


def _geotiff_profile(grid: Grid, count: int, dtype, fill: np.ndarray | None, compress: str | None) -> dict:
    """The rasterio profile of the output: tiled 256 x 256, BigTIFF if needed; ``fill`` None: no nodata
    value (the output carries a mask band instead)."""
    profile = dict(
        driver="GTiff",
        width=grid.width,
        height=grid.height,
        count=count,
        dtype=dtype,
        transform=grid.transform,
        crs=grid.crs,
        nodata=None if fill is None else fill.item(),
        tiled=True,
        blockxsize=256,
        blockysize=256,
        BIGTIFF="IF_SAFER",
    )
    if compress:
        profile["compress"] = compress
    return profile


#: GDAL's block cache while an ortho is written, MB (see :func:`rectify_file`).
WRITE_CACHE_MB = 64


def rectify_file(
    src_path,
    dst_path,
    model: Callable[[Array], Array],
    grid: Grid,
    *,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    progress: bool | str = False,
    compress: str | None = "deflate",
    inputs=(),
    approx: float | None = 0.125,
    info: dict | None = None,
    hint: Callable[[], str] | None = None,
    hidden: np.ndarray | None = None,
) -> Grid:
    """:func:`rectify` from one raster file to a GeoTIFF, window by window.

    For each output tile only the input window its pixels map into (plus a
    kernel margin) is read, and the tile is written with
    ``dst.write(window=...)`` into a temporary file renamed onto
    ``dst_path`` at the end (:func:`photax.io.atomic.atomic_path`): no
    partial output on failure, and ``dst_path`` may not be ``src_path`` (or
    one of ``inputs``).  Memory is bounded by the tile size, whatever the
    image size.  The result equals :func:`rectify` on the whole image (to
    rounding for ``"bspline"``, whose prefilter sees only the window).

    Args:
        src_path: input raster (any GDAL format); all bands are rectified.
        dst_path: output GeoTIFF (tiled, BigTIFF if needed).
        nodata: the value of output pixels without data, recorded as the file's nodata. Default the
            input's nodata; else, for a floating-point image, NaN; for an integer image (where any value
            may be a real grey value: a true-black 0 must stay data) no nodata value but GDAL's internal
            per-dataset mask band (``rasterio``'s ``read_masks`` / ``read(masked=True)``; the pixels under
            the mask are 0). Pixels the input's own mask or alpha band marks as no data (nearest input
            pixel) are no data in the output too.
        resampling: the kernel; None: ``"bilinear"``, or ``"nearest"`` for a palette image (values
            indexing a colour map), which takes no other kernel and keeps its colour map.
        compress: GeoTIFF compression (``"deflate"``, ``"lzw"``, None...).
        inputs: further paths the output must not overwrite (e.g. a DEM).
        approx, info: as in :func:`rectify`.
        hint: called only when the output cannot fit on the disk (checked before any work: uncompressed
            size against ``shutil.disk_usage``); its sentence ends the error message.
        hidden: ``grid.shape`` bool, cells written as no data whatever the image holds there (the
            cells a DSM hides from the camera: :func:`photax.occlusion_mask`).

    Returns:
        ``grid``.

    Examples:
        :func:`photax.rectify`'s example from a file to a GeoTIFF: the same pixels, georeferenced:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> flat = ptx.relief_scene(0.0, seed=1, image_size=(400, 300), focal_px=400.0)
        >>> model = ptx.fit_projective(flat.gcp_ground[:, :2], flat.gcp_pixel)
        >>> grid = ptx.Grid(flat.ortho_transform, flat.ortho.shape)
        >>> src = ptx.write_geotiff(folder / "image.tif", flat.image, None)
        >>> _ = ptx.rectify_file(src, folder / "rectified.tif", model, grid, resampling="cubic")
        >>> bands, profile = ptx.read_geotiff(folder / "rectified.tif")
        >>> same = np.array_equal(bands[0], ptx.rectify(flat.image, model, grid, resampling="cubic"), equal_nan=True)
        >>> bool(same), profile["transform"][:6] == tuple(grid.transform)[:6]
        (True, True)
    """
    # Over 80 lines only by its docstring; the per-tile work is the closure
    # ``one`` (window, read, resample), the rest is setup.
    import rasterio
    from rasterio.enums import MaskFlags
    from rasterio.windows import Window

    from ..io.atomic import atomic_path
    from ..io.raster import check_palette, colormap, gdal_errors, open_raster
    from ..resampling import compute_dtype, gather_source

    auto = resampling is None
    resampling = _check_resampling("bilinear" if auto else resampling)
    _check_model(model)
    approx = _check_approx(approx)
    tile = int(tile)
    if tile < 1:
        raise ValueError(f"tile must be a positive number of pixels, got {tile!r}")
    if hidden is not None and np.shape(hidden) != tuple(grid.shape):
        raise ValueError(f"hidden must have the grid's shape {tuple(grid.shape)}, got {np.shape(hidden)}")
    with open_raster(src_path) as src, atomic_path(dst_path, inputs=(src_path, *inputs)) as tmp:
        if auto and colormap(src) is not None:
            resampling = _check_resampling("nearest")
        cmap = check_palette(src_path, src, resampling)
        if nodata is None:
            nodata = src.nodata
        # No nodata value for an integer image: a mask band, so that no grey value is lost to it.
        masked = nodata is None and not np.issubdtype(np.dtype(src.dtypes[0]), np.floating)
        fill = _fill_value(src.dtypes[0], nodata)
        check_output_size(
            grid.shape, src.count + masked, src.dtypes[0], path=dst_path, hint=hint, compressed=bool(compress)
        )
        profile = _geotiff_profile(grid, src.count, src.dtypes[0], None if masked else fill, compress)
        src_masked = any(MaskFlags.per_dataset in f or MaskFlags.alpha in f for f in src.mask_flag_enums)
        # numpy, not jnp, for the kernels' arguments: each eager jnp conversion is a
        # small compiled program of its own (lowered again in every process).
        transform = np.asarray(tuple(grid.transform)[:6], dtype=float)
        tiles = list(tile_windows(grid.shape, tile))
        layout = _layout(*tiles[0][2:])
        fill_j = np.full((src.count,), fill, dtype=fill.dtype)
        size = (src.height, src.width)
        compute, out_dtype = compute_dtype(fill.dtype), np.dtype(fill.dtype)
        lock = threading.Lock()  # a rasterio dataset is not thread-safe

        def one(t):
            r0, c0, h, w = t
            pos, origin, err, n_exact = _tile_positions(
                model, transform, np.array([r0, c0], dtype=float), layout, _approx_arg(approx), size
            )
            p, o = np.asarray(pos)[:, :h, :w], np.asarray(origin)
            # The window from the very positions resampled: none falls outside it.
            win = _source_window(p, o, src.width, src.height, Resampling(resampling).margin)
            if win is None:
                empty = np.full((src.count, h, w), fill, dtype=fill.dtype)
                return (empty, np.zeros((h, w), bool)), err, n_exact
            window = Window(win[1], win[0], win[3], win[2])
            with lock:
                data = src.read(window=window)
                src_mask = src.read_masks(1, window=window) if src_masked else None
            offset = np.asarray(o - np.array([win[1], win[0]]), dtype=np.int32)
            # Full-size tiles (edge tiles cropped after): fewer compilations.
            block = _resample_tile(
                gather_source(data, resampling, compute),
                pos,
                origin,
                offset,
                fill_j,
                size,
                data.shape[-2:],
                resampling,
                compute,
                out_dtype,
            )
            block = np.asarray(block)[:, :h, :w]
            valid = _valid(p, o, size, win, src_mask)
            if hidden is not None:
                valid &= ~hidden[r0 : r0 + h, c0 : c0 + w]
            if src_mask is not None or hidden is not None:
                block = np.where(valid, block, fill)
            return (block, valid), err, n_exact

        def sink(t, result):
            block, valid = result
            window = Window(t[1], t[0], t[3], t[2])
            dst.write(block, window=window)
            if masked:
                dst.write_mask(np.where(valid, np.uint8(255), np.uint8(0)), window=window)

        chunks = (layout[0][0] // layout[1]) * (layout[0][1] // layout[2])
        # GDAL_NUM_THREADS: the blocks are compressed on all cores (as oty does), written in their order.
        # GDAL_CACHEMAX: with GDAL's default block cache (5 % of the memory) every block of the
        # output stayed in it until the dataset closed, which then compressed and wrote them all
        # in one C call: 4-5 s for a 99 MPix ortho on a busy machine, during which a Ctrl-C or
        # SIGTERM waited (issue 38).  A small cache writes the blocks as their tiles come (each
        # tile covers whole blocks), so the close is short (0.2-0.5 s measured) and the run no slower.
        env = rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True, GDAL_NUM_THREADS="ALL_CPUS", GDAL_CACHEMAX=WRITE_CACHE_MB)
        with gdal_errors(), env, rasterio.open(tmp, "w", **profile) as dst:
            if cmap is not None:
                dst.write_colormap(1, cmap)
            _run_tiles(one, tiles, progress, "rectify", info, approx, chunks, sink)
    return grid


def _valid(pos, origin, size, win, src_mask) -> np.ndarray:
    """Where a tile's positions ``pos`` (relative to ``origin``) have data: inside the image footprint, the
    resampling kernels' own test (:func:`photax.rectification._approx._bounds`, in ``pos``' dtype), and,
    with the input's mask ``src_mask`` over the window ``win``, on a valid input pixel (the nearest one)."""
    lo = (np.array([-0.5, -0.5]) - origin).astype(pos.dtype)
    hi = (np.array([size[1] - 0.5, size[0] - 0.5]) - origin).astype(pos.dtype)
    with np.errstate(invalid="ignore"):
        valid = (pos[0] >= lo[0]) & (pos[0] <= hi[0]) & (pos[1] >= lo[1]) & (pos[1] <= hi[1])
    if src_mask is not None:
        col = np.clip(np.rint(np.where(valid, pos[0] + origin[0], 0.0)) - win[1], 0, src_mask.shape[1] - 1)
        row = np.clip(np.rint(np.where(valid, pos[1] + origin[1], 0.0)) - win[0], 0, src_mask.shape[0] - 1)
        valid &= src_mask[row.astype(np.intp), col.astype(np.intp)] > 0
    return valid


def orthorectify_file(
    src_path,
    dst_path,
    exterior: ExteriorOrientation | None,
    camera,
    dem,
    grid: Grid | None = None,
    *,
    resolution=None,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    progress: bool | str = False,
    compress: str | None = "deflate",
    approx: float | None = 0.125,
    info: dict | None = None,
    occlusion: str | None = None,
) -> Grid:
    """:func:`orthorectify` from an image file to a GeoTIFF, window by window.

    ``dem`` is a :class:`photax.DEM` or the path of a DEM raster (read with
    :func:`photax.io.read_dem`, which may not be overwritten either).  The
    output CRS is ``grid.crs`` (default the DEM's).  See
    :func:`rectify_file` for the streaming and atomic writing.  ``exterior=None`` and an
    :class:`photax.rpc.RPCCamera`: as in :func:`orthorectify` (default grid CRS the scene's UTM zone).
    ``occlusion="mark"``: the cells the DEM (a DSM) hides from the camera are no data
    (:func:`photax.occlusion_mask`, in memory over the grid), as in :func:`orthorectify`.

    Returns:
        the output grid.

    Examples:
        :func:`photax.orthorectify`'s example from a file to a GeoTIFF, bit for bit:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> grid = ptx.Grid(scene.ortho_transform, scene.ortho.shape)
        >>> src = ptx.write_geotiff(folder / "frame.tif", scene.image, None)
        >>> _ = ptx.orthorectify_file(src, folder / "ortho.tif", scene.exterior, scene.camera, scene.dem, grid)
        >>> bands, _ = ptx.read_geotiff(folder / "ortho.tif")
        >>> ortho, _ = ptx.orthorectify(scene.image, scene.exterior, scene.camera, scene.dem, grid)
        >>> bool(np.array_equal(bands[0], ortho, equal_nan=True))
        True
    """
    from ..io.raster import open_raster

    inputs = ()
    if not isinstance(dem, DEM):
        from ..io.raster import read_dem

        inputs = (dem,)
        dem = read_dem(dem)
    with open_raster(src_path) as src:
        _check_image_size((src.height, src.width), camera)
    if grid is None:
        grid = ortho_grid(exterior, camera, dem, resolution)
    model = check_ortho_inputs(exterior, camera, dem, grid)
    if occlusion not in (None, "mark"):
        raise ValueError(f"occlusion must be None or 'mark', got {occlusion!r}")
    hidden = occluded(model, grid) if occlusion == "mark" else None
    return rectify_file(
        src_path,
        dst_path,
        model,
        grid,
        resampling=resampling,
        nodata=nodata,
        tile=tile,
        progress=progress,
        compress=compress,
        inputs=inputs,
        approx=approx,
        info=info,
        hint=lambda: gsd_hint(exterior, camera, dem, grid),
        hidden=hidden,
    )


def orthorectify_block(
    images,
    exteriors,
    camera: FrameCamera,
    dem: DEM,
    folder,
    *,
    resolution=None,
    crs=None,
    resampling: Resampling | str = "bilinear",
    tile: int = 1024,
    callback: Callable[[int], None] | None = None,
    grid: Grid | None = None,
) -> list:
    """Every image of a block orthorectified into ``folder``, all on one pixel lattice (ready for
    :func:`photax.mosaic`): :func:`orthorectify_file` per image.

    Args:
        images: the image files, one per orientation.
        exteriors: their :class:`photax.ExteriorOrientation`\\ s.
        camera, dem: shared by all.
        folder: where the orthos go, named ``{k:05d}-{image stem}.tif``.
        resolution: ground pixel size of all of them; default the median of the images' ground
            sampling distances (one resolution: :meth:`Grid.from_bounds` snaps every grid to it).
        crs: the grids' CRS (the orientation file's); default the DEM's.
        callback: called with ``k`` after image ``k`` is written (progress).
        grid: the mosaic's grid (e.g. :meth:`photax.GridSpec.grid` of gdalwarp's ``-te``/``-tr``):
            each ortho is its part over the image's footprint (:meth:`Grid.crop`: on its lattice,
            at its resolution, in its CRS); images wholly outside it are left out.  Not with
            ``resolution``.

    Returns:
        the ortho paths, in the order of ``images`` (with ``grid``: of those it overlaps).
    """
    import pathlib

    images, exteriors = list(images), list(exteriors)
    if len(images) != len(exteriors):
        raise ValueError(f"exteriors: {len(exteriors)} orientations for {len(images)} images")
    if not images:
        raise ValueError("images: a block needs at least one image")
    if grid is not None:
        if resolution is not None:
            raise ValueError("give resolution or grid (whose resolution it is), not both")
        resolution = (abs(grid.transform.a), abs(grid.transform.e))
    elif resolution is None:
        resolution = float(np.median([abs(ortho_grid(e, camera, dem).transform.a) for e in exteriors]))
    paths = []
    for k, (image, e) in enumerate(zip(images, exteriors)):
        out = pathlib.Path(folder) / f"{k:05d}-{pathlib.Path(image).stem}.tif"
        own = ortho_grid(e, camera, dem, resolution, crs=crs)
        b, g = own.bounds, (grid or own).bounds
        if b[0] < g[2] and g[0] < b[2] and b[1] < g[3] and g[1] < b[3]:  # else no part in the mosaic's grid
            own = own if grid is None else grid.crop(b)
            orthorectify_file(image, out, e, camera, dem, own, resampling=resampling, tile=tile)
            paths.append(out)
        if callback is not None:
            callback(k)
    return paths


def orthorectify_files(
    images,
    outputs,
    exteriors,
    camera,
    dem,
    *,
    resolution=None,
    crs=None,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    compress: str | None = "deflate",
    progress: bool | str = False,
    spec: GridSpec | None = None,
) -> list:
    """Many images orthorectified in one call, each exactly as :func:`orthorectify_file` does it
    alone (its own footprint grid from :func:`photax.ortho_grid`), under one progress bar over all
    their tiles.  An image that fails does not stop the others: its exception is its result.

    Unlike :func:`orthorectify_block` (one shared lattice for a mosaic), each ortho is what
    ``photax ortho IMAGE -o OUT`` writes for that image, bit for bit.  Two images are in flight at
    a time (threads): one is compressed and written while the next one's tiles are computed.

    Args:
        images: the image files.
        outputs: one output GeoTIFF per image (each written atomically).
        exteriors: one :class:`photax.ExteriorOrientation` per image; None (or None entries) for
            images with a ground camera (an :class:`photax.rpc.RPCCamera`, a
            :class:`photax.PushbroomCamera`), which carries its own orientation.
        camera, dem: shared by all, or one per image (a list): satellite images each have their own
            RPC.
        resolution: ground pixel size; default each image's mean ground sampling distance.
        crs: the grids' CRS (the orientation file's); default the DEM's (a ground camera: the UTM
            zone of its scene).
        nodata: as in :func:`rectify_file`.
        spec: the output grid asked for (:class:`photax.GridSpec`: gdalwarp's ``-te``, ``-tr``,
            ``-tap``, ``-ts``, a raster's grid), as :func:`photax.ortho_grid` takes it; with it,
            ``resolution`` must be None (it is ``spec.resolution``).

    Returns:
        per image, its output :class:`photax.Grid`, or the exception that stopped it.

    Examples:
        Two images, one that is no raster: the first is orthorectified on its own 15 m footprint grid
        (as ``orthorectify(..., resolution=15.0)`` makes it), the second's error is its result:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> good = ptx.write_geotiff(folder / "frame.tif", scene.image, None)
        >>> _ = (folder / "bad.tif").write_text("not a raster")
        >>> results = ptx.orthorectify_files([good, folder / "bad.tif"], [folder / "o1.tif", folder / "o2.tif"],
        ...                                  [scene.exterior] * 2, scene.camera, scene.dem, resolution=15.0)
        >>> _, own = ptx.orthorectify(scene.image, scene.exterior, scene.camera, scene.dem, resolution=15.0)
        >>> results[0].shape == own.shape, tuple(results[0].transform) == tuple(own.transform)
        (True, True)
        >>> isinstance(results[1], ptx.PhotaxError), (folder / "o2.tif").exists()
        (True, False)
    """

    from ..progress import progress_bar

    if spec is not None and resolution is not None:
        raise ValueError("give the resolution in spec (GridSpec.resolution), not also as resolution=")
    images, outputs = list(images), list(outputs)
    exteriors = [None] * len(images) if exteriors is None else list(exteriors)
    cameras, dems = (_per_image(v, len(images), what) for v, what in ((camera, "cameras"), (dem, "DEMs")))
    if not len(images) == len(outputs) == len(exteriors):
        raise ValueError(
            f"{len(images)} images, {len(outputs)} outputs and {len(exteriors)} orientations: one of each per image"
        )
    from ..io.raster import open_raster

    results: list = []
    for image, e, cam, d in zip(images, exteriors, cameras, dems):  # the grids first: the bar counts all tiles
        try:
            with open_raster(image) as src:
                _check_image_size((src.height, src.width), cam)
            if spec is None:
                results.append(ortho_grid(e, cam, d, resolution, crs=crs))
            else:
                results.append(ortho_grid(e, cam, d, crs=crs, spec=spec))
        except (ValueError, OSError) as exc:
            results.append(exc)
    total = sum(len(list(tile_windows(g.shape, tile))) for g in results if isinstance(g, Grid))

    def one(k, bar):
        try:
            return orthorectify_file(
                images[k],
                outputs[k],
                exteriors[k],
                cameras[k],
                dems[k],
                results[k],
                resampling=resampling,
                nodata=nodata,
                tile=tile,
                progress=bar,
                compress=compress,
            )
        except (ValueError, OSError) as exc:  # this image's; KeyboardInterrupt and bugs stop the run
            return exc

    # Two images in flight: while one is compressed, synced and renamed (one thread, the GIL
    # released) or its window read, the other's tiles are computed.  Each image is still written
    # by one thread, as alone (the same bytes); results are kept in the images' order.
    todo = [k for k, g in enumerate(results) if isinstance(g, Grid)]
    with progress_bar(progress, total, desc="ortho", unit="tile") as bar, ThreadPoolExecutor(2) as pool:
        bar, running = _SharedBar(bar), deque()
        for k in [*todo, None]:
            if k is not None:  # in this thread's context: the command's record of its inputs (io.files)
                running.append((k, pool.submit(contextvars.copy_context().run, one, k, bar)))
            while running and (len(running) == 2 or k is None):
                j, future = running.popleft()
                results[j] = future.result()
    return results


class _SharedBar:
    """A progress bar advanced by several threads (:func:`orthorectify_files`' images)."""

    def __init__(self, bar):
        self._bar, self._lock = bar, threading.Lock()

    def update(self, n=1):
        with self._lock:
            self._bar.update(n)

    def set_postfix(self, *args, **kwargs):
        with self._lock:
            self._bar.set_postfix(*args, **kwargs)


def _per_image(value, n: int, what: str) -> list:
    """``value`` shared by ``n`` images, or its list of one per image."""
    if not isinstance(value, (list, tuple)):
        return [value] * n
    if len(value) != n:
        raise ValueError(f"{len(value)} {what} for {n} images: give one shared, or one per image")
    return list(value)
