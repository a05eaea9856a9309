"""Lazy georeferenced rasters: the ``xarray.DataArray`` photax returns for
rasters larger than memory (:func:`photax.orthorectify_dask`,
:func:`photax.mosaic`, :func:`photax.ortho_uncertainty`) and its atomic
GeoTIFF writer.

:func:`to_raster` writes chunk by chunk.  Without a ``dask.distributed``
client one thread writes: it keeps the output open for the
whole write and takes the chunks as Dask computes them through a queue of
one, while the other threads compute -- a pipeline stage, where
rioxarray's ``.rio.to_raster`` makes every worker queue on a lock, reopen
the file and hold its own GDAL state to write its chunk.  The GeoTIFF's
tiles divide the chunks (336 px for chunks of 1008), so each chunk writes
whole tiles, each compressed once: a tile straddling two chunks is written
part-empty, then read back, merged and appended again, which costs CPU and
leaves dead bytes in the file.  With a ``dask.distributed`` client the
workers write (rioxarray's way, under a distributed lock; the file must be
where they can reach it).

Dask, xarray, rioxarray and rasterio are imported inside the functions
(the optional ``dask`` extra).  :func:`write_tiles` writes NumPy tiles given
by the caller into the same file (tiles, COG copy, atomic rename) with
rasterio alone: the in-memory paths that need no Dask (``photax mosaic`` of
ortho files, :func:`photax.mosaic_to_raster`).
"""

from __future__ import annotations

import functools
import math
import os
import queue
import threading
import uuid

import numpy as np

from .atomic import atomic_path, temporary
from .sizes import check_output_size


def dataarray(data, grid, fill, name: str):
    """A DataArray with rioxarray's georeference: dims y, x (band), pixel
    centre coordinates when the :class:`photax.Grid` is north-up, CRS,
    transform, nodata ``fill`` (a NumPy scalar)."""
    import rioxarray  # noqa: F401  (registers the .rio accessor)
    import xarray as xr

    a, b, xoff, d, e, yoff = tuple(grid.transform)[:6]
    dims = ("band", "y", "x") if data.ndim == 3 else ("y", "x")
    coords = {}
    if b == 0 and d == 0:
        coords["x"] = xoff + a * (np.arange(grid.shape[1]) + 0.5)
        coords["y"] = yoff + e * (np.arange(grid.shape[0]) + 0.5)
    if data.ndim == 3:
        coords["band"] = np.arange(1, data.shape[0] + 1)
    arr = xr.DataArray(data, dims=dims, coords=coords, name=name)
    arr = arr.rio.write_transform(grid.transform)
    if grid.crs is not None:
        arr = arr.rio.write_crs(grid.crs)
    return arr.rio.write_nodata(fill.item(), encoded=False)


def _tile_edge(chunks: tuple[int, ...]) -> int:
    """GeoTIFF tile edge along an axis chunked as ``chunks``: the multiple
    of 16 (the format's rule) dividing every chunk but the last that is
    nearest 256 (GDAL's default) in ratio, up to 1024; 256 if there is none."""
    inner = math.gcd(*chunks[:-1]) if len(chunks) > 1 else chunks[0]
    edges = [t for t in range(16, min(inner, 1024) + 1, 16) if inner % t == 0]
    return min(edges, key=lambda t: abs(math.log(t / 256))) if edges else 256


class _Writer:
    """One thread writing chunks into one open rasterio dataset, fed through
    a queue of one; ``put`` raises the writer's error once it has failed."""

    def __init__(self, dataset):
        self._ds = dataset
        self._queue = queue.Queue(maxsize=1)
        self._error = None
        self._thread = threading.Thread(target=self._run, name="photax-writer", daemon=True)
        self._thread.start()

    def _run(self):
        from .raster import gdal_errors

        try:
            with gdal_errors():  # a failing write raises, in this thread (close's in the caller's)
                while (item := self._queue.get()) is not None:
                    self._write(*item)
        except BaseException as err:  # noqa: BLE001  (kept, raised by put() and close() in the caller's thread)
            self._error = err

    def _write(self, key, block, mask=False):
        """Write one chunk: ``key`` is its (band,) row and column slices; ``mask``: ``block`` is the
        (rows, cols) validity, written to the dataset's mask band."""
        from rasterio.windows import Window

        ys, xs = key[-2:]
        window = Window(xs.start, ys.start, xs.stop - xs.start, ys.stop - ys.start)
        if mask:
            self._ds.write_mask(np.where(block, np.uint8(255), np.uint8(0)), window=window)
        elif block.ndim == 2:
            self._ds.write(block, 1, window=window)
        else:
            start, stop, step = key[0].indices(self._ds.count)
            self._ds.write(block, list(range(start + 1, stop + 1, step)), window=window)

    def _put(self, item):
        while self._error is None and self._thread.is_alive():
            try:
                self._queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue
        if self._error is not None:
            raise self._error
        raise RuntimeError("photax: the GeoTIFF writer thread has stopped")

    def __setitem__(self, key, block):  # dask.array.store's target, called by the workers
        self._put((key, np.asarray(block)))

    @property
    def mask(self):
        """A ``dask.array.store`` target writing the validity chunks to the mask band, through this thread."""
        writer = self

        class _Mask:
            def __setitem__(self, key, block):
                writer._put((key, np.asarray(block), True))

        return _Mask()

    def close(self):
        """Wait for the chunks queued; raise the writer's error if any."""
        if self._thread.is_alive():
            self._put(None)
            self._thread.join()
        if self._error is not None:
            raise self._error


@functools.cache
def _has_zstd() -> bool:
    """Whether GDAL's GeoTIFF driver writes ZSTD (it does in rasterio's wheels; a build may lack it:
    GDAL then only warns and writes the file uncompressed)."""
    import warnings

    from rasterio.io import MemoryFile

    with warnings.catch_warnings(), MemoryFile() as mem:
        warnings.simplefilter("ignore")
        with mem.open(driver="GTiff", width=1, height=1, count=1, dtype="uint8", compress="zstd") as ds:
            ds.write(np.zeros((1, 1, 1), np.uint8))
        with mem.open() as ds:
            return ds.compression is not None and ds.compression.value == "ZSTD"


def _on_cluster() -> bool:
    """Whether Dask's scheduler in effect is a ``dask.distributed`` client's."""
    import sys

    from dask.base import get_scheduler

    if "distributed" not in sys.modules:  # no client without it (and get_scheduler would import it: ~0.3 s)
        return False

    owner = getattr(get_scheduler(), "__self__", None)
    return type(owner).__module__.split(".")[0] == "distributed"


def _profile(data, options) -> dict:
    """rasterio's creation profile for the DataArray ``data``."""
    shape = data.shape
    profile = dict(
        driver="GTiff",
        width=shape[-1],
        height=shape[-2],
        count=shape[0] if data.ndim == 3 else 1,
        dtype=data.dtype,
        crs=data.rio.crs,
        transform=data.rio.transform(),
        nodata=data.rio.encoded_nodata if data.rio.encoded_nodata is not None else data.rio.nodata,
    )
    profile.update(options)
    return profile


def _write_local(data, path, options: dict, mask=None) -> None:
    """Write ``data`` to ``path`` on Dask's local scheduler: of Dask's
    ``num_workers`` threads (default the CPU count) one writes, the others
    compute (at least one).  The synchronous scheduler computes in this
    thread; the processes one is replaced by threads (the writer is here)."""
    import dask
    import dask.array as da
    import dask.local
    import dask.threaded
    import rasterio
    from dask.base import get_scheduler

    from .raster import gdal_errors

    with gdal_errors(), rasterio.open(path, "w", **_profile(data, options)) as ds:
        if isinstance(data.name, str):
            ds.descriptions = (data.name,) * ds.count
        tags = {k: v for k, v in data.attrs.items() if not k.startswith("_") and k != "grid_mapping"}
        if tags:
            ds.update_tags(**tags)
        if not hasattr(data.data, "dask") and not hasattr(mask, "dask"):
            from .raster import write_in_strips  # a signal is acted on between strips

            a = np.asarray(data.data)
            write_in_strips(ds, a if a.ndim == 3 else a[None], None if mask is None else np.asarray(mask))
            return
        sync = get_scheduler() is dask.local.get_sync
        threads = int(dask.config.get("num_workers", None) or os.cpu_count() or 1)
        writer = _Writer(ds)
        sources, targets = [da.asarray(data.data)], [writer]
        if mask is not None:
            sources.append(da.asarray(mask).rechunk(sources[0].chunks[-2:]))
            targets.append(writer.mask)
        try:
            # The schedulers' functions, not their names: a name makes Dask look for a distributed client
            # (importing distributed: 0.3 s).
            scheduler = dask.local.get_sync if sync else dask.threaded.get
            da.store(sources, targets, lock=False, scheduler=scheduler, num_workers=max(threads - 1, 1))
        finally:
            writer.close()


def to_raster(data, path, *, compress: str | None = "deflate", cog: bool = False, inputs=(), mask=None, **kwargs):
    """Write a (Dask-backed) georeferenced DataArray to a GeoTIFF, atomically.

    Chunk by chunk into a temporary file beside ``path``, renamed onto
    ``path`` only when every chunk is written
    (:func:`photax.io.atomic.atomic_path`): a failing chunk, a dead worker
    or an interrupt leaves ``path`` as it was and no partial file.  On
    Dask's local schedulers one thread writes while ``num_workers - 1``
    compute (see the module docstring), with GeoTIFF tiles that divide the
    chunks; with a ``dask.distributed`` client the workers write, through
    rioxarray's ``.rio.to_raster`` under a distributed lock.  GDAL's block
    cache (``GDAL_CACHEMAX``) is bounded to two chunks' bytes (at least
    16 MiB) for the write, in this process (the writer, the COG copy).
    Plain ``.rio.to_raster(path)`` writes in place, rioxarray's way.

    The output's uncompressed size is checked against the free disk space before any work.

    Args:
        data: an ``xarray.DataArray`` with a rioxarray georeference (e.g.
            from :func:`photax.orthorectify_dask` or :func:`photax.mosaic`).
        path: the output file.
        compress: GeoTIFF compression.
        cog: write a Cloud-Optimized GeoTIFF (tiled, compressed, with
            overviews; GDAL's COG driver copies the written GeoTIFF).
        inputs: paths ``path`` must not overwrite.
        mask: ``(y, x)`` bool (NumPy, Dask or DataArray), True where the pixels hold data (e.g. from
            ``orthorectify_dask(..., mask=True)``): written as GDAL's internal per-dataset mask band
            instead of a nodata value, so that no grey value (true black in a uint8 ortho) is taken
            for no data. Local Dask schedulers only.
        kwargs: more creation options for rasterio (``blockxsize`` and
            ``blockysize`` replace the tiles chosen to divide the chunks).

    Returns:
        ``path``.

    Examples:
        A chunked DataArray with a rioxarray georeference, written chunk by chunk and read back:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import rioxarray  # noqa: F401  (the .rio accessor)
        >>> import xarray as xr
        >>> import photax as ptx
        >>> data = xr.DataArray(np.arange(64 * 48, dtype=np.float32).reshape(48, 64), dims=("y", "x")).chunk(16)
        >>> grid = ptx.Grid.from_bounds((0.0, 0.0, 64.0, 48.0), 1.0)  # 1 m pixels, top-left corner (0, 48)
        >>> data = data.rio.write_crs("EPSG:32633").rio.write_transform(grid.transform)
        >>> path = ptx.to_raster(data, pathlib.Path(tempfile.mkdtemp()) / "out.tif")
        >>> bands, profile = ptx.read_geotiff(path)
        >>> bool(np.array_equal(bands[0], data.values)), str(profile["crs"]), profile["transform"][:6]
        (True, 'EPSG:32633', (1.0, 0.0, 0.0, 0.0, -1.0, 48.0))

    """

    import rioxarray  # noqa: F401

    if data.ndim not in (2, 3) or tuple(data.dims[-2:]) != (data.rio.y_dim, data.rio.x_dim):
        raise ValueError(
            f"to_raster writes (band, y, x) or (y, x) arrays, got dims {data.dims}: "
            f"transpose it first (data.transpose(..., {data.rio.y_dim!r}, {data.rio.x_dim!r}))"
        )
    on_cluster = _on_cluster()
    if mask is not None:
        mask = getattr(mask, "data", mask)
        if tuple(mask.shape) != tuple(data.shape[-2:]):
            raise ValueError(f"mask must be (y, x) = {tuple(data.shape[-2:])}, got shape {tuple(mask.shape)}")
        if on_cluster:
            raise ValueError("to_raster: mask= is written by the local schedulers only, not by a distributed client")
    ys, xs = data.data.chunks[-2:] if hasattr(data.data, "chunks") else ((data.shape[-2],), (data.shape[-1],))
    options = _options(ys, xs, compress, hasattr(data.data, "chunks"), kwargs)
    bands = data.shape[0] if data.ndim == 3 else 1
    check_output_size(
        data.shape[-2:], bands + (mask is not None), data.dtype, path=path, compressed=bool(compress or cog)
    )
    if mask is not None:
        options["nodata"] = None  # the mask band, not a value, says where there is no data
    chunk = data.data.chunksize if hasattr(data.data, "chunksize") else data.shape

    def write(target, options):
        if not on_cluster:
            _write_local(data, target, options, mask)
            return
        from distributed import Lock

        data.rio.to_raster(target, lock=Lock(f"photax-write-{uuid.uuid4().hex}"), **options)

    # Uncompressed, the size is known: refused before the work when the disk cannot hold it.
    size = None if compress or cog else data.size * data.dtype.itemsize
    _atomic_geotiff(path, write, options, compress, cog, inputs, size, math.prod(chunk) * data.dtype.itemsize)
    return path


def _options(ys, xs, compress, tiles_from_chunks: bool, kwargs) -> dict:
    """The GeoTIFF creation options of :func:`to_raster` for chunks ``ys``, ``xs`` (edges along y and x):
    tiled, its tiles dividing the chunks (``tiles_from_chunks``; else 256 px), ``compress``, ``kwargs``."""
    options = dict(driver="GTiff", tiled=True, BIGTIFF="IF_SAFER", blockxsize=256, blockysize=256)
    if tiles_from_chunks:
        options.update(blockysize=_tile_edge(ys), blockxsize=_tile_edge(xs))
    if compress:
        options["compress"] = compress
    options.update(kwargs)
    return options


def _atomic_geotiff(path, write, options, compress, cog, inputs, size, chunk_bytes) -> None:
    """``write(target, options)`` a GeoTIFF into a temporary file renamed onto ``path`` once written
    (and, with ``cog``, copied by GDAL's COG driver first), GDAL's block cache bounded to two chunks."""
    import rasterio

    # GDAL's block cache bounded for the write (default: 5 % of the RAM): two
    # chunks' bytes, at least 16 MiB.  GDAL's COG copy reads the whole raster
    # through the cache: 172 MiB for a 100 MPix uint8 ortho by default, 55 MiB so.
    env = rasterio.Env(GDAL_CACHEMAX=max(16 << 20, 2 * chunk_bytes), GDAL_TIFF_INTERNAL_MASK=True)
    with atomic_path(path, inputs=inputs, size=size) as tmp, env:
        if not cog:
            write(tmp, options)
            return
        import rasterio.shutil

        from .raster import gdal_errors

        # The intermediate GeoTIFF, read once by the copy, is compressed fast (ZSTD level 1: a quarter
        # of deflate's CPU time, at about its size); the COG copy compresses on every CPU.
        fast = dict(compress="zstd", zstd_level=1) if _has_zstd() else {}
        with temporary(tmp.with_name(tmp.name + ".gtiff")) as plain:
            write(plain, {**options, **fast})
            with gdal_errors():
                rasterio.shutil.copy(
                    plain,
                    tmp,
                    driver="COG",
                    compress=compress or "deflate",
                    overviews="AUTO",
                    num_threads="ALL_CPUS",
                )


def write_tiles(
    path, tiles, *, shape, dtype, transform, crs, nodata, name, chunks: int, compress="deflate", cog=False, inputs=()
):
    """Write a raster given tile by tile, NumPy blocks from this thread, as :func:`to_raster` writes the
    same array in Dask chunks of ``chunks`` (its GeoTIFF tiles, compression, COG copy, atomic rename):
    for the in-memory paths that need no Dask (e.g. ``photax mosaic`` of ortho files).

    Args:
        path: the output file.
        tiles: iterable of ``((row, col), block)``: ``block`` ``(bands, h, w)`` (or ``(h, w)`` for one band)
            at ``(row, col)`` of the raster, in any order, covering it.
        shape: ``(bands, rows, cols)``.
        dtype, transform, crs, nodata: the raster's.
        name: each band's description.
        chunks: the blocks' edge (GeoTIFF tiles divide it).
        compress, cog, inputs: as for :func:`to_raster`.

    Returns:
        ``path``.
    """
    import rasterio
    from rasterio.windows import Window

    from .raster import gdal_errors

    bands, rows, cols = shape
    ys, xs = _axis_chunks(rows, chunks), _axis_chunks(cols, chunks)
    options = _options(ys, xs, compress, True, {})
    check_output_size((rows, cols), bands, np.dtype(dtype), path=path, compressed=bool(compress or cog))
    profile = dict(width=cols, height=rows, count=bands, dtype=dtype, crs=crs, transform=transform, nodata=nodata)

    def write(target, options):
        with gdal_errors(), rasterio.open(target, "w", **profile, **options) as ds:
            ds.descriptions = (name,) * bands
            for (r, c), block in tiles:
                block = block.reshape(-1, *block.shape[-2:])
                ds.write(block, window=Window(c, r, block.shape[2], block.shape[1]))

    size = None if compress or cog else rows * cols * bands * np.dtype(dtype).itemsize
    _atomic_geotiff(
        path, write, options, compress, cog, inputs, size, chunks * chunks * bands * np.dtype(dtype).itemsize
    )
    return path


def _axis_chunks(size: int, chunks: int) -> tuple[int, ...]:
    """Dask's chunks of an axis of ``size`` in chunks of ``chunks``."""
    return (chunks,) * (size // chunks) + ((size % chunks,) if size % chunks else ())
