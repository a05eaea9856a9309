"""Rectification from a raster file to a GeoTIFF, window by window: per
output tile only the input window it needs is read (rasterio windows)."""

from __future__ import annotations

import threading
from typing import Callable

import numpy as np
from jax import Array

from .._aot import disk_cached
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..dem import DEM
from ..io.crs import check_dem
from ..resampling import Resampling
from ._approx import _tile_positions
from ._grid import Grid, ortho_grid
from ._indirect import _resample_tile
from ._ortho import OrthoModel, _check_image_size
from ._tiling import (
    _approx_arg,
    _check_approx,
    _check_model,
    _check_resampling,
    _fill_value,
    _layout,
    _run_tiles,
    _tiles,
)

# Compiled executables kept on disk by photax._aot when a compilation cache
# folder is set (the CLI): a new process loads them without tracing again.
_tile_positions = disk_cached(_tile_positions, "rectify_tile_positions")
_resample_tile = disk_cached(_resample_tile, "rectify_resample_tile")


def _source_window(cols: np.ndarray, rows: np.ndarray, width: int, height: int, margin: int, bucket: int = 256):
    """The input window ``(row_off, col_off, h, w)`` an output tile needs, or None.

    Sizes are rounded up to multiples of ``bucket`` (shifting the window
    back inside the image rather than padding it) so the jitted resampler
    sees few distinct shapes.
    """
    ok = np.isfinite(cols) & np.isfinite(rows)
    ok &= (cols > -margin) & (cols < width - 1 + margin) & (rows > -margin) & (rows < height - 1 + margin)
    if not ok.any():
        return None
    out = []
    for v, n in ((rows[ok], height), (cols[ok], width)):
        lo = max(int(np.floor(v.min())) - margin, 0)
        hi = min(int(np.ceil(v.max())) + margin + 1, n)
        size = min(-(-(hi - lo) // bucket) * bucket, n)
        out.append((min(lo, n - size), size))
    (r0, h), (c0, w) = out
    return r0, c0, h, w


def _geotiff_profile(grid: Grid, count: int, dtype, fill: np.ndarray, compress: str | None) -> dict:
    """The rasterio profile of the output: tiled 256 x 256, BigTIFF if needed."""
    profile = dict(
        driver="GTiff", width=grid.width, height=grid.height, count=count, dtype=dtype,
        transform=grid.transform, crs=grid.crs, nodata=fill.item(), tiled=True, blockxsize=256,
        blockysize=256, BIGTIFF="IF_SAFER",
    )
    if compress:
        profile["compress"] = compress
    return profile


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
        nodata: default the input's nodata, else NaN/0 as in :func:`rectify`.
        compress: GeoTIFF compression (``"deflate"``, ``"lzw"``, None...).
        inputs: further paths the output must not overwrite (e.g. a DEM).
        approx, info: as in :func:`rectify`.

    Returns:
        ``grid``.
    """
    # Over 80 lines only by its docstring; the per-tile work is the closure
    # ``one`` (window, read, resample), the rest is setup.
    import rasterio
    from rasterio.windows import Window

    from ..io.atomic import atomic_path
    from ..io.raster import open_raster
    from ..resampling import _compute_dtype, _source

    resampling = _check_resampling(resampling)
    _check_model(model)
    approx = _check_approx(approx)
    tile = int(tile)
    if tile < 1:
        raise ValueError(f"tile must be a positive number of pixels, got {tile!r}")
    with open_raster(src_path) as src, atomic_path(dst_path, inputs=(src_path, *inputs)) as tmp:
        if nodata is None:
            nodata = src.nodata
        fill = _fill_value(src.dtypes[0], nodata)
        profile = _geotiff_profile(grid, src.count, src.dtypes[0], fill, compress)
        # numpy, not jnp, for the kernels' arguments: each eager jnp conversion is a
        # small compiled program of its own (lowered again in every process).
        transform = np.asarray(tuple(grid.transform)[:6], dtype=float)
        tiles = list(_tiles(grid.shape, tile))
        layout = _layout(*tiles[0][2:])
        fill_j = np.full((src.count,), fill, dtype=fill.dtype)
        size = (src.height, src.width)
        compute, out_dtype = _compute_dtype(fill.dtype), np.dtype(fill.dtype)
        lock = threading.Lock()  # a rasterio dataset is not thread-safe

        def one(t):
            r0, c0, h, w = t
            pos, origin, err, n_exact = _tile_positions(
                model, transform, np.array([r0, c0], dtype=float), layout, _approx_arg(approx), size)
            p, o = np.asarray(pos)[:, :h, :w], np.asarray(origin)
            # The window from the very positions resampled: none falls outside it.
            win = _source_window(p[0] + o[0], p[1] + o[1], src.width, src.height, Resampling(resampling).margin)
            if win is None:
                return np.full((src.count, h, w), fill, dtype=fill.dtype), err, n_exact
            with lock:
                data = src.read(window=Window(win[1], win[0], win[3], win[2]))
            offset = np.asarray(o - np.array([win[1], win[0]]), dtype=np.int32)
            # Full-size tiles (edge tiles cropped after): fewer compilations.
            block = _resample_tile(_source(data, resampling, compute), pos, origin, offset, fill_j, size,
                                   data.shape[-2:], resampling, compute, out_dtype)
            return np.asarray(block)[:, :h, :w], err, n_exact

        chunks = (layout[0][0] // layout[1]) * (layout[0][1] // layout[2])
        with rasterio.open(tmp, "w", **profile) as dst:
            _run_tiles(one, tiles, progress, "rectify", info, approx, chunks,
                       lambda t, block: dst.write(block, window=Window(t[1], t[0], t[3], t[2])))
    return grid


def orthorectify_file(
    src_path,
    dst_path,
    exterior: ExteriorOrientation,
    camera: FrameCamera,
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
) -> Grid:
    """:func:`orthorectify` from an image file to a GeoTIFF, window by window.

    ``dem`` is a :class:`photax.DEM` or the path of a DEM raster (read with
    :func:`photax.io.read_dem`, which may not be overwritten either).  The
    output CRS is ``grid.crs`` (default the DEM's).  See
    :func:`rectify_file` for the streaming and atomic writing.

    Returns:
        the output grid.
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
    check_dem(dem, grid)
    return rectify_file(
        src_path, dst_path, OrthoModel(exterior, camera, dem), grid, resampling=resampling, nodata=nodata,
        tile=tile, progress=progress, compress=compress, inputs=inputs, approx=approx, info=info,
    )
