"""Pan-sharpening on Dask: a lazy, chunked :class:`xarray.DataArray` for scenes larger than memory.

:func:`pansharpen_dask` runs :func:`photax.fusion.pansharpen`'s own code (:mod:`._sharpen`: the plan,
the passes, the per-block fusion) as a graph of tasks, in three passes over the PAN, each reading the
blocks it needs (a slice of an in-memory array, a Dask array's chunks, or a rasterio windowed read of a
file done by the worker itself):

1. **statistics** (streamed, every PAN pixel): per block of ``chunks`` pixels the sum and count of its
   valid pixels and, over the MS pixels it falls in, the count, valid count and sum of its pixels
   (:func:`._sharpen.pan_sums`); added up, the PAN averaged over each MS pixel, exactly as over the whole
   image at once;
2. **low-pass** (GSA, MTF-GLP and MTF-GLP-HPM only): per block, plus the Gaussian's radius (4 sigma) and
   one pixel for the bilinear taps, the MTF-matched Gaussian of the PAN sampled at the centres of the MS
   pixels that fall in the block (:func:`._sharpen.lowpass_at_ms`);
3. one task adds the passes up into the statistics (:func:`._sharpen.statistics`: means, covariances,
   the weights by regression, the gains), from which each output chunk is fused
   (:func:`._sharpen.fuse`) from its PAN window grown by the filter's footprint (HPF, SFIM: the box's
   radius; the other methods read no neighbour).

The weights and gains are therefore those of the in-memory function (the same sums, in another order:
equal to float64 rounding), and the output equals its output to float32 rounding.  What is held in
memory: the MS-resolution arrays (the MS, the PAN averaged per MS pixel, the decimated low-passes), i.e.
``1 / ratio**2`` of the PAN per band, plus a few PAN windows per thread; never the PAN or the output.
Each pass reads the PAN afresh (its own keys), so no pass keeps blocks alive for the next.

Dask, xarray and rioxarray are imported inside the functions only (the optional ``dask`` extra).
"""

from __future__ import annotations

import functools
import threading

import numpy as np

from . import _sharpen


class _BandReader:
    """One band of a raster file as an array-like for :func:`dask.array.from_array`: each block a rasterio
    windowed read, on the worker that needs it (the file opened per read: rasterio datasets are not
    shared across threads)."""

    def __init__(self, path, band, shape, dtype):
        self.path, self.band, self.shape, self.dtype, self.ndim = path, band, shape, np.dtype(dtype), 2

    def __getitem__(self, key):
        from rasterio.windows import Window

        from ..io.raster import open_raster

        rows, cols = (k.indices(n) for k, n in zip(key, self.shape))
        with open_raster(self.path) as src:
            win = Window(cols[0], rows[0], cols[1] - cols[0], rows[1] - rows[0])
            return src.read(self.band, window=win)


def _georef(src):
    """``(transform, crs)`` of an open raster; ``(None, None)`` without georeference."""
    t, crs = src.transform, src.crs
    return (None, None) if crs is None and t.is_identity else (t, crs)


def _read_ms(path):
    from ..io.raster import read_geotiff

    return read_geotiff(path)[0]


def _as_pan(pan, band, chunks):
    """The PAN as ``(make, shape, dtype, nodata, transform, crs)``: ``make()`` a fresh 2-D Dask array of
    it (new keys each call)."""
    import dask.array as da
    import xarray as xr
    from dask.graph_manipulation import clone

    transform = crs = nodata = None
    if isinstance(pan, (str, bytes)) or hasattr(pan, "__fspath__"):
        from ..io.raster import open_raster

        path = str(pan)
        with open_raster(path) as src:
            if not 1 <= band <= src.count:
                raise ValueError(f"pan_band {band}: {path} has {src.count} band(s)")
            shape, dtype, nodata = (src.height, src.width), np.dtype(src.dtypes[band - 1]), src.nodata
            transform, crs = _georef(src)
        reader = _BandReader(path, band, shape, dtype)
        meta = np.empty((0, 0), dtype)  # else from_array reads an empty window to find it
        return (
            (lambda: da.from_array(reader, chunks=chunks, name=False, meta=meta)),
            shape,
            dtype,
            nodata,
            transform,
            crs,
        )
    if isinstance(pan, xr.DataArray):
        import rioxarray  # noqa: F401  (the .rio accessor)

        if pan.rio.crs is not None:
            transform, crs = pan.rio.transform(), pan.rio.crs
        nodata = pan.rio.nodata
        pan = pan.data
    if pan.ndim == 3:
        if not 1 <= band <= pan.shape[0]:
            raise ValueError(f"pan_band {band}: the PAN has {pan.shape[0]} band(s)")
        pan = pan[band - 1]
    if isinstance(pan, da.Array):
        return (lambda: clone(pan, assume_layers=False)), pan.shape, pan.dtype, nodata, transform, crs
    pan = np.asarray(pan)
    return (lambda: da.from_array(pan, chunks=chunks, name=False)), pan.shape, pan.dtype, nodata, transform, crs


def _as_ms(ms):
    """The MS as ``(data, shape, dtype, nodata, transform, crs)``: ``data`` an array, a Dask array, or a
    delayed read of the file (read whole by the statistics task: MS resolution)."""
    import dask
    import xarray as xr

    if isinstance(ms, (str, bytes)) or hasattr(ms, "__fspath__"):
        from ..io.raster import open_raster

        path = str(ms)
        with open_raster(path) as src:
            shape, dtype, nodata = (src.count, src.height, src.width), np.dtype(src.dtypes[0]), src.nodata
            transform, crs = _georef(src)
        return dask.delayed(_read_ms, pure=False)(path), shape, dtype, nodata, transform, crs
    transform = crs = nodata = None
    if isinstance(ms, xr.DataArray):
        import rioxarray  # noqa: F401  (the .rio accessor)

        if ms.rio.crs is not None:
            transform, crs = ms.rio.transform(), ms.rio.crs
        nodata = ms.rio.nodata
        ms = ms.data
    if not hasattr(ms, "dask"):
        ms = np.asarray(ms)
    return ms, tuple(ms.shape), np.dtype(ms.dtype), nodata, transform, crs


def _tiles(r0, r1, c0, c1, chunks):
    """``(r, c, h, w)`` blocks of ``chunks`` pixels tiling rows ``r0:r1`` and columns ``c0:c1``, row by row."""
    return [
        [(r, c, min(chunks, r1 - r), min(chunks, c1 - c)) for c in range(c0, c1, chunks)] for r in range(r0, r1, chunks)
    ]


def _grown(tile, halo, shape):
    """``tile`` grown by ``halo`` pixels, clipped to an image of ``shape``."""
    r, c, h, w = tile
    a0, b0 = max(r - halo, 0), max(c - halo, 0)
    return a0, b0, min(r + h + halo, shape[0]) - a0, min(c + w + halo, shape[1]) - b0


def _read(src, window):
    r, c, h, w = window
    return src[r : r + h, c : c + w]


_LOCK = threading.Lock()


def _statistics(plan, ms, fill, sums, lows, info):
    st = _sharpen.statistics(plan, ms, fill, sums, lows)
    if info is not None:
        info.update(weights=st.weights, gains=np.asarray(st.gains), ratio=plan.ratio)
    return st


def _fuse_chunk(plan, st, block, window, tile, fill, info):
    fused, valid = _sharpen.fuse(plan, st, block, window, tile)
    image, _, clipped = _sharpen._to_dtype(fused, valid, plan.ms_dtype, fill)
    if info is not None and clipped:
        with _LOCK:
            info["clipped"] = info.get("clipped", 0) + clipped
    return image


def pansharpen_dask(
    pan,
    ms,
    method: str = "gs",
    *,
    chunks: int = 1024,
    pan_transform=None,
    ms_transform=None,
    pan_crs=None,
    ms_crs=None,
    weights=None,
    resampling: str = "cubic",
    nyquist_gain=0.3,
    pan_nodata=None,
    ms_nodata=None,
    pan_band: int = 1,
    name: str = "sharpened",
    info: dict | None = None,
):
    """:func:`photax.fusion.pansharpen` as a lazy, chunked ``xarray.DataArray``, for scenes larger than memory.

    Nothing is read or computed until ``.compute()`` or :func:`photax.to_raster` (atomic, chunk by chunk)
    is called, on whatever Dask scheduler is active; the graph runs the statistics pass, then the fusion
    chunk by chunk (the module docstring).  The result equals :func:`photax.fusion.pansharpen`'s image to
    float32 rounding (integer outputs: at most one grey level, at rare pixels), whatever ``chunks``.

    Args:
        pan: ``(rows, cols)`` (or ``(bands, rows, cols)``, band ``pan_band`` used) NumPy or Dask array, an
            ``xarray.DataArray`` (its rioxarray georeference used when it has a CRS), or a raster's path
            (its georeference and nodata used unless given; read window by window by the workers).
        ms: ``(bands, rows, cols)``: the same kinds; read whole by the statistics task (it is MS
            resolution: ``1 / ratio**2`` of the PAN per band).
        method, weights, resampling, nyquist_gain: as in :func:`photax.fusion.pansharpen`.
        chunks: output chunk edge in PAN pixels (memory ~ bands x chunks^2 per thread).
        pan_transform, ms_transform, pan_crs, ms_crs, pan_nodata, ms_nodata: as in
            :func:`photax.fusion.pansharpen`; None: the file's or the DataArray's when it has one.
        pan_band: 1-based band of a multi-band PAN.
        name: the DataArray's name.
        info: a dict filled when the graph runs on a local scheduler: ``weights``, ``gains``, ``ratio``
            (by the statistics task) and ``clipped`` (values clipped to the MS dtype's range, added up by
            the chunks).

    Returns:
        A Dask-backed ``xarray.DataArray`` ``(band, y, x)`` on the PAN grid cropped to the pixels the MS
        covers (``pansharpen``'s ``window``), in the MS dtype, with the PAN's CRS and the cropped
        transform the rioxarray way; its nodata (always set, unlike ``pansharpen``'s, which is None when
        every pixel is valid: a chunk cannot know) is ``ms_nodata``, else 0 (integers) or NaN (floats).

    Raises:
        ValueError: a bad argument, or no overlap, when the graph is built (from the geometry alone);
            the data's errors (too few valid pixels, a constant PAN) when it is computed.

    Examples:
        A lazy result in 32 x 32 px chunks, equal to the in-memory fusion once computed:

        >>> import numpy as np
        >>> import photax as ptx
        >>> pan = np.random.default_rng(0).uniform(50, 150, (64, 64))
        >>> ms = np.stack([k * pan.reshape(16, 4, 16, 4).mean(axis=(1, 3)) for k in (0.8, 1.0, 1.2)])
        >>> lazy = ptx.pansharpen_dask(pan, ms, "gs", chunks=32)
        >>> lazy.dims, lazy.chunks
        (('band', 'y', 'x'), ((3,), (32, 32), (32, 32)))
        >>> gap = np.abs(lazy.compute().values - ptx.pansharpen(pan, ms, "gs").image).max()
        >>> bool(gap < 1e-4)
        True
    """

    import dask
    import dask.array as da
    from rasterio import Affine

    from ..grid import Grid
    from ..io.lazy import dataarray

    if isinstance(chunks, bool) or not isinstance(chunks, (int, np.integer)) or chunks < 16:
        raise ValueError(f"chunks must be at least 16 pixels, got {chunks!r}")
    chunks = int(chunks)
    make_pan, pan_shape, pan_dtype, p_nodata, p_t, p_crs = _as_pan(pan, pan_band, chunks)
    ms, ms_shape, ms_dtype, m_nodata, m_t, m_crs = _as_ms(ms)
    if pan_transform is None and ms_transform is None and (p_t is None) == (m_t is None):
        pan_transform, ms_transform = p_t, m_t
        pan_crs = p_crs if pan_crs is None else pan_crs
        ms_crs = m_crs if ms_crs is None else ms_crs
    plan = _sharpen.make_plan(
        pan_shape,
        pan_dtype,
        ms_shape,
        ms_dtype,
        method,
        pan_transform=pan_transform,
        ms_transform=ms_transform,
        pan_crs=pan_crs,
        ms_crs=ms_crs,
        weights=weights,
        resampling=resampling,
        nyquist_gain=nyquist_gain,
        pan_nodata=p_nodata if pan_nodata is None else pan_nodata,
        ms_nodata=m_nodata if ms_nodata is None else ms_nodata,
    )
    task = functools.partial(dask.delayed, pure=False)
    blocks = [t for row in _tiles(0, pan_shape[0], 0, pan_shape[1], chunks) for t in row]

    # 1. statistics: every PAN block once
    src = make_pan()
    sums = [task(_sharpen.pan_sums)(plan, _read(src, t), t) for t in blocks]
    fill = task(_sharpen.pan_fill)(sums)

    # 2. the Gaussian low-passes at the MS pixel centres, each MS pixel answered by the block it falls in
    lows = []
    if plan.sigmas:
        src = make_pan()
        cols, rows = (v.ravel() for v in _sharpen.ms_points(plan))
        ok = np.isfinite(cols) & np.isfinite(rows)
        ti = np.floor(np.where(ok, rows, 0) + 0.5).clip(0, pan_shape[0] - 1).astype(np.int64) // chunks
        tj = np.floor(np.where(ok, cols, 0) + 0.5).clip(0, pan_shape[1] - 1).astype(np.int64) // chunks
        which = ti * -(-pan_shape[1] // chunks) + tj  # the block's index in `blocks`
        order = np.argsort(which, kind="stable")
        bounds = np.searchsorted(which[order], np.arange(len(blocks) + 1))
        for k, t in enumerate(blocks):
            index = order[bounds[k] : bounds[k + 1]]
            window = _grown(t, plan.lowpass_halo, pan_shape)
            args = (plan, fill, _read(src, window), window, t, cols[index], rows[index], index)
            lows.append(task(_sharpen.lowpass_at_ms)(*args))
    stats = task(functools.partial(_statistics, info=info))(plan, ms, fill, sums, lows)  # info: not copied

    # 3. the fusion, chunk by chunk of the output
    is_int = np.issubdtype(ms_dtype, np.integer)
    out_fill = plan.ms_nodata if plan.ms_nodata is not None else (0 if is_int else np.nan)
    src = make_pan()
    r0, r1, c0, c1 = plan.window
    bands = ms_shape[0]
    rows_of_blocks = []
    for row in _tiles(r0, r1, c0, c1, chunks):
        out_row = []
        for t in row:
            window = _grown(t, plan.halo, pan_shape)
            block = task(functools.partial(_fuse_chunk, info=info))(
                plan, stats, _read(src, window), window, t, out_fill
            )
            out_row.append(da.from_delayed(block, (bands, t[2], t[3]), dtype=ms_dtype))
        rows_of_blocks.append(out_row)
    data = da.block([rows_of_blocks])
    transform = plan.out_transform or Affine.translation(c0, r0)
    grid = Grid(transform, (r1 - r0, c1 - c0), pan_crs if plan.pan_transform is not None else None)
    return dataarray(data, grid, np.asarray(out_fill, dtype=ms_dtype), name)
