"""Whole-image rectification and orthorectification.

**Indirect mapping** (output -> input; the default, DESIGN.md): for every
output pixel centre take its map/ground coordinate from the output
:class:`Grid`, find its position in the input image with a *model*
``(..., 2) map (X, Y) -> (..., 2) input pixel (column, row)``, and
interpolate the grey value there (:func:`photax.resampling.resample`).  Every
output pixel gets a value, so there are no holes.

**Direct mapping** (input -> output), kept for comparison: every input pixel
centre is sent forward with the *inverse* model and its value dropped into
the nearest output pixel.  When the output is finer than the input (or the
map stretches the image) some output pixels are never hit: holes.

**Orthorectification** is indirect mapping with the collinearity model: a
ground point ``(X, Y)`` of the output grid gets its height ``Z`` from the DEM
(bilinear), and ``(X, Y, Z)`` is projected into the image with the
collinearity equations (:func:`photax.collinearity.project`) and converted
to pixels (:meth:`photax.FrameCamera.image_to_pixel`).  This removes relief
displacement, which no plane-to-plane polynomial can.  Occlusion is **not**
handled: a ground point hidden behind a hill still receives the grey value
of whatever the camera saw along that ray (a "ghost"), as in orthority and
most DEM (non-true) orthophoto software.

The output is processed in tiles of about ``tile x tile`` pixels, so memory
stays bounded; each tile's mapping (grid -> ground -> pixel) and resampling
are one jitted function (no full-size coordinate maps), and tiles run on a
thread pool.  By default the mapping is *approximate*, as GDAL's warper
does it: the exact model on a 16-pixel lattice, bilinear interpolation in
between where checks show the position error is at most ``approx``
(0.125 px), exact evaluation elsewhere (see :func:`rectify`).  The ``*_file`` variants stream through rasterio windows: per
output tile they read only the input window it needs (plus a margin for the
interpolation kernel), so images far larger than memory can be processed.

Frames and conventions: ``docs/conventions.md`` (pixel centres at integer
pixel coordinates; raster georeference at pixel corners).
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import Any, Callable, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from rasterio import Affine

from .camera import FrameCamera
from .collinearity import ExteriorOrientation, depth, image_to_ground, project
from .dem import DEM
from .resampling import Resampling

_FAR = -1e6  # a pixel position far outside any image: resample gives nodata


def _check_resampling(resampling) -> str:
    return Resampling.check(resampling).value


@dataclasses.dataclass(frozen=True)
class Grid:
    """An output raster grid: georeference, size and CRS.

    Attributes:
        transform: GDAL/rasterio affine ``(a, b, xoff, d, e, yoff)``
            (``rasterio.Affine``) from raster coordinates to map coordinates,
            georeferenced at pixel *corners*: the centre of pixel
            ``[row, col]`` is at ``transform * (col + 0.5, row + 0.5)``.
        shape: ``(rows, cols)``.
        crs: the map CRS (anything rasterio accepts), or ``None``.
    """

    transform: Affine
    shape: tuple[int, int]
    crs: Any = None

    def __post_init__(self):
        t = tuple(float(v) for v in tuple(self.transform)[:6])
        if len(t) != 6 or not all(math.isfinite(v) for v in t):
            raise ValueError(f"transform must hold 6 finite affine coefficients, got {self.transform!r}")
        if t[0] * t[4] - t[1] * t[3] == 0:
            raise ValueError(f"transform is singular: {t}")
        shape = tuple(int(n) for n in self.shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be (rows, cols) with both >= 1, got {self.shape!r}")
        object.__setattr__(self, "transform", Affine(*t))
        object.__setattr__(self, "shape", shape)

    @classmethod
    def from_bounds(cls, bounds, resolution, crs=None) -> "Grid":
        """A north-up grid covering ``bounds``, snapped to the resolution.

        Args:
            bounds: ``(xmin, ymin, xmax, ymax)`` in map units.
            resolution: pixel size, a scalar or ``(x_size, y_size)``, > 0.
            crs: the map CRS.

        The edges are moved outwards to whole multiples of the resolution,
        so grids of the same resolution line up pixel for pixel.
        """
        xmin, ymin, xmax, ymax = (float(v) for v in bounds)
        rx, ry = (float(v) for v in np.broadcast_to(np.asarray(resolution, dtype=float), (2,)))
        if not (rx > 0 and ry > 0):
            raise ValueError(f"resolution must be positive, got {resolution!r}")
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"bounds must be (xmin, ymin, xmax, ymax) with max > min, got {bounds!r}")
        x0, x1 = math.floor(xmin / rx) * rx, math.ceil(xmax / rx) * rx
        y0, y1 = math.floor(ymin / ry) * ry, math.ceil(ymax / ry) * ry
        shape = (max(round((y1 - y0) / ry), 1), max(round((x1 - x0) / rx), 1))
        return cls(Affine(rx, 0.0, x0, 0.0, -ry, y1), shape, crs)

    @property
    def height(self) -> int:
        return self.shape[0]

    @property
    def width(self) -> int:
        return self.shape[1]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the outer pixel edges."""
        rows, cols = self.shape
        xs, ys = zip(*(self.transform * (c, r) for c in (0, cols) for r in (0, rows)))
        return min(xs), min(ys), max(xs), max(ys)

    def xy(self, rows: slice = slice(None), cols: slice = slice(None)) -> np.ndarray:
        """Map coordinates of the pixel centres of a window.

        Args:
            rows, cols: slices of the grid (default: all of it).

        Returns:
            ``(h, w, 2)`` float64 ``(X, Y)``.
        """
        r = np.arange(self.shape[0], dtype=float)[rows] + 0.5
        c = np.arange(self.shape[1], dtype=float)[cols] + 0.5
        a, b, xoff, d, e, yoff = tuple(self.transform)[:6]
        x = xoff + a * c[None, :] + b * r[:, None]
        y = yoff + d * c[None, :] + e * r[:, None]
        return np.stack([x, y], axis=-1)


# --- the per-tile work (jitted) ------------------------------------------------
#
# An output tile is processed in chunks of _STEP rows x `cols` columns inside
# one jitted loop: positions are made, resampled and written per chunk, so no
# full-size coordinate map ever exists.  With ``approx`` the exact mapping is
# evaluated only on a lattice every _STEP output pixels and at the lattice
# cells' centres and edge midpoints (the check positions); a chunk whose cells
# all interpolate their check positions within ``approx`` pixels gets
# bilinearly interpolated positions, any other chunk the exact ones (GDAL's
# approximate transformer checks segment midpoints along rows, threshold
# 0.125 px).  Positions are float32 relative to an integer origin near the
# tile's positions (ample: 2^-24 relative).

_STEP = 16  # lattice spacing in output pixels (cost of the lattice: ~2/256 of exact)
_CHUNK_COLS = 1024  # columns per chunk at most: 16 x 1024 samples (measured 25 % faster than 16 x 256)


def _layout(rows: int, cols: int) -> tuple[tuple[int, int], int, int]:
    """Kernel tile shape (multiples of _STEP), step and chunk width for a
    ``rows x cols`` tile (edge tiles are computed at this shape and cropped)."""
    s = _STEP
    tr, tc = -(-rows // s) * s, -(-cols // s) * s
    q = max(d for d in range(1, _CHUNK_COLS // s + 1) if (tc // s) % d == 0)
    return (tr, tc), s, q * s


def _map_xy(transform: Array, r: Array, c: Array) -> Array:
    """``(len(r), len(c), 2)`` map coordinates of raster coordinates ``r`` x ``c``."""
    a, b, xoff, d, e, yoff = (transform[i] for i in range(6))
    return jnp.stack([xoff + a * c[None, :] + b * r[:, None], yoff + d * c[None, :] + e * r[:, None]], axis=-1)


@eqx.filter_jit
def _map_tile(model, transform: Array, offset: Array, shape: tuple[int, int]) -> tuple[Array, Array]:
    """Exact input pixel (cols, rows), each ``shape``, of an output tile at ``offset`` (row, col)."""
    r = offset[0] + jnp.arange(shape[0], dtype=float) + 0.5
    c = offset[1] + jnp.arange(shape[1], dtype=float) + 0.5
    colrow = jnp.asarray(model(_map_xy(transform, r, c)), dtype=float)
    return colrow[..., 0], colrow[..., 1]


def _plan(model, transform, offset, layout, approx, size):
    """The lattice of one tile: ``(nodes, origin, bad, err)``.

    nodes: ``(2, mr+1, mc+1)`` exact positions (col, row) minus ``origin``
    (float32);
    origin: ``(2,)`` int32 (col, row), the rounded mean position clipped to
    the image ``size`` (H, W); bad: ``(chunk rows, chunk cols)`` chunks that
    need the exact mapping; err: the largest check error of the others (px).
    A cell whose check positions and corners are all NaN (e.g. off the DEM)
    is taken as NaN throughout; a partly NaN cell is bad.
    """
    (tr, tc), s, cw = layout
    mr, mc = tr // s, tc // s
    r = offset[0] + s * jnp.arange(mr + 1, dtype=float) + 0.5
    c = offset[1] + s * jnp.arange(mc + 1, dtype=float) + 0.5
    nodes = jnp.asarray(model(_map_xy(transform, r, c)), dtype=float)
    rm, cm = r[:-1] + s / 2, c[:-1] + s / 2  # cell mid-rows and mid-columns
    # Check positions: the cell centres and the edge midpoints, with the
    # bilinear (on edges: linear) interpolation of the nodes there.
    checks = [
        (model(_map_xy(transform, rm, cm)), 0.25 * (nodes[:-1, :-1] + nodes[1:, :-1] + nodes[:-1, 1:] + nodes[1:, 1:])),
        (model(_map_xy(transform, r, cm)), 0.5 * (nodes[:, :-1] + nodes[:, 1:])),  # (mr+1, mc): horizontal edges
        (model(_map_xy(transform, rm, c)), 0.5 * (nodes[:-1, :] + nodes[1:, :])),  # (mr, mc+1): vertical edges
    ]
    errs = []
    for exact, interp in checks:
        exact = jnp.asarray(exact, dtype=float)
        e = jnp.max(jnp.abs(exact - interp), axis=-1)
        f = jnp.all(jnp.isfinite(exact), axis=-1) & jnp.all(jnp.isfinite(interp), axis=-1)
        n = ~(jnp.any(jnp.isfinite(exact), axis=-1) | jnp.any(jnp.isfinite(interp), axis=-1))
        errs.append(jnp.where(f, e, jnp.where(n, 0.0, jnp.inf)))  # NaN everywhere is no error
    # Per cell: its centre and its four edges.
    cell = [errs[0], errs[1][:-1], errs[1][1:], errs[2][:, :-1], errs[2][:, 1:]]
    err = jnp.maximum(jnp.maximum(jnp.maximum(cell[0], cell[1]), jnp.maximum(cell[2], cell[3])), cell[4])
    q = cw // s
    chunk_err = jnp.max(err.reshape(mr, mc // q, q), axis=-1)
    bad = ~(chunk_err <= approx)
    ok = jnp.isfinite(nodes)
    mean = jnp.sum(jnp.where(ok, nodes, 0.0), axis=(0, 1)) / jnp.maximum(jnp.sum(ok, axis=(0, 1)), 1).astype(float)
    origin = jnp.round(jnp.clip(mean, 0.0, jnp.array([size[1] - 1.0, size[0] - 1.0])))
    # Column and row planes apart (2, mr+1, mc+1): contiguous for interpolation.
    rel = jnp.moveaxis(nodes - origin[None, None, :], -1, 0).astype(jnp.float32)
    return rel, origin.astype(jnp.int32), bad, jnp.max(jnp.where(bad, 0.0, chunk_err))


def _chunk_positions(model, transform, offset, plan, i, j, layout, exact):
    """``(2, step, cols)`` positions (col, row) of chunk ``(i, j)`` relative
    to the plan's origin: float64 exact, or float32 (interpolated or exact)."""
    (_, _), s, cw = layout
    rel, origin, bad = plan[:3]

    def exact_positions(_):
        r = offset[0] + (i * s).astype(float) + jnp.arange(s, dtype=float) + 0.5
        c = offset[1] + (j * cw).astype(float) + jnp.arange(cw, dtype=float) + 0.5
        p = jnp.moveaxis(jnp.asarray(model(_map_xy(transform, r, c)), dtype=float), -1, 0)
        return p if exact else (p - origin.astype(float)[:, None, None]).astype(jnp.float32)

    if exact:
        return exact_positions(None)

    def interpolated(_):
        q = cw // s
        n = jax.lax.dynamic_slice(rel, (0, i, j * q), (2, 2, q + 1))  # (col/row, top/bottom, nodes)
        f = jnp.arange(s, dtype=jnp.float32) / s
        along = n[:, :, :-1, None] + (n[:, :, 1:, None] - n[:, :, :-1, None]) * f[None, None, None, :]
        top, bottom = along[:, 0].reshape(2, 1, cw), along[:, 1].reshape(2, 1, cw)
        return top + (bottom - top) * f[None, :, None]

    if exact is None:  # the tile has no bad chunk: no per-chunk branch (which slows the loop ~2x)
        return interpolated(None)
    return jax.lax.cond(bad[i, j], exact_positions, interpolated, None)


def _lattice_positions(rel: Array, s: int) -> Array:
    """``(2, mr+1, mc+1)`` lattice positions -> ``(2, mr*s, mc*s)`` positions
    of the whole tile, bilinear in each cell: the arithmetic of
    :func:`_chunk_positions` (along rows first, then between rows), so the
    same float32 values, but one vectorised pass instead of one small
    computation per chunk (measured ~30 % of the bilinear tile time)."""
    f = jnp.arange(s, dtype=jnp.float32) / s
    along = rel[..., :-1, None] + (rel[..., 1:, None] - rel[..., :-1, None]) * f[None, None, None, :]
    along = along.reshape(rel.shape[0], rel.shape[1], -1)  # (2, mr+1, tc)
    top, bottom = along[:, :-1, None, :], along[:, 1:, None, :]
    return (top + (bottom - top) * f[None, None, :, None]).reshape(rel.shape[0], -1, along.shape[-1])


def _tile_plan(model, transform, offset, layout, approx, size):
    if approx is not None:
        return _plan(model, transform, offset, layout, approx, size)
    (tr, tc), s, cw = layout
    return None, jnp.zeros(2, dtype=jnp.int32), jnp.ones((tr // s, tc // cw), dtype=bool), jnp.zeros(())


def _bounds(origin, size, dtype):
    """The image footprint ``[-0.5, W-0.5] x [-0.5, H-0.5]`` relative to ``origin``."""
    o = origin.astype(float)
    lo = (jnp.array([-0.5, -0.5]) - o).astype(dtype)
    hi = (jnp.array([size[1] - 0.5, size[0] - 0.5]) - o).astype(dtype)
    return lo, hi


@eqx.filter_jit
def _rectify_tile(model, flat, transform, offset, fill, layout, approx, size, method, compute, out_dtype):
    """One output tile, mapping and resampling fused: ``(block, err, n_exact)``.

    ``flat`` is the whole image prepared by :func:`photax.resampling._source`;
    ``block`` is ``(B, *layout[0])``, ``n_exact`` the number of chunks mapped
    exactly (all of them when ``approx`` is 0).
    """
    from .resampling import _interp

    (tr, tc), s, cw = layout
    plan = _tile_plan(model, transform, offset, layout, approx, size)
    origin, bad = plan[1], plan[2]
    dtype = jnp.float64 if approx is None else jnp.float32
    lo, hi = _bounds(origin, size, dtype)
    nc = tc // cw

    def loop(exact):
        def body(k, out):
            i, j = k // nc, k % nc
            pos = _chunk_positions(model, transform, offset, plan, i, j, layout, exact).reshape(2, -1)
            v = _interp(flat, pos[0], pos[1], fill, lo, hi, origin, shape=size, method=method, a=-0.5,
                        compute=compute, out_dtype=out_dtype)
            return jax.lax.dynamic_update_slice(out, v.reshape(-1, s, cw), (0, i * s, j * cw))

        return jax.lax.fori_loop(0, (tr // s) * nc, body, jnp.empty((flat.shape[0], tr, tc), dtype=out_dtype))

    def interpolated():  # no chunk needs the exact mapping: whole-tile positions, row strips
        pos = _lattice_positions(plan[0], s)

        def body(i, out):
            p = jax.lax.dynamic_slice(pos, (0, i * s, 0), (2, s, tc)).reshape(2, -1)
            v = _interp(flat, p[0], p[1], fill, lo, hi, origin, shape=size, method=method, a=-0.5,
                        compute=compute, out_dtype=out_dtype)
            return jax.lax.dynamic_update_slice(out, v.reshape(-1, s, tc), (0, i * s, 0))

        return jax.lax.fori_loop(0, tr // s, body, jnp.empty((flat.shape[0], tr, tc), dtype=out_dtype))

    if approx is None:
        out = loop(True)
    else:
        out = jax.lax.cond(jnp.any(bad), lambda: loop(False), interpolated)
    return out, plan[3], jnp.sum(bad)


@eqx.filter_jit
def _tile_positions(model, transform, offset, layout, approx, size):
    """The positions of :func:`_rectify_tile` without resampling (for the
    file path, which must know the input window first): ``(pos, origin, err,
    n_exact)`` with ``pos`` ``(2, *layout[0])`` relative to ``origin``."""
    (tr, tc), s, cw = layout
    plan = _tile_plan(model, transform, offset, layout, approx, size)
    nc = tc // cw

    def body(k, out):
        i, j = k // nc, k % nc
        pos = _chunk_positions(model, transform, offset, plan, i, j, layout, approx is None)
        return jax.lax.dynamic_update_slice(out, pos, (0, i * s, j * cw))

    dtype = jnp.float64 if approx is None else jnp.float32

    def loop():
        return jax.lax.fori_loop(0, (tr // s) * nc, body, jnp.empty((2, tr, tc), dtype=dtype))

    if approx is None:
        pos = loop()
    else:  # no bad chunk: the whole tile in one pass
        pos = jax.lax.cond(jnp.any(plan[2]), loop, lambda: _lattice_positions(plan[0], s))
    return pos, plan[1], plan[3], jnp.sum(plan[2])


@eqx.filter_jit
def _resample_tile(flat, pos, origin, offset, fill, size, window, method, compute, out_dtype):
    """Resample the window ``flat`` (prepared, ``window`` = (h, w)) at
    ``pos`` relative to ``origin`` (image pixels); ``offset`` = origin minus
    the window's (col, row); footprint: the whole image ``size`` (H, W)."""
    from .resampling import _interp

    lo, hi = _bounds(origin, size, pos.dtype)
    tr, tc = pos.shape[1:]

    def body(i, out):
        p = jax.lax.dynamic_slice(pos, (0, i * _STEP, 0), (2, _STEP, tc)).reshape(2, -1)
        v = _interp(flat, p[0], p[1], fill, lo, hi, offset, shape=window, method=method, a=-0.5,
                    compute=compute, out_dtype=out_dtype)
        return jax.lax.dynamic_update_slice(out, v.reshape(-1, _STEP, tc), (0, i * _STEP, 0))

    return jax.lax.fori_loop(0, tr // _STEP, body, jnp.empty((flat.shape[0], tr, tc), dtype=out_dtype))


def _check_approx(approx) -> float:
    a = 0.0 if approx is None else float(approx)
    if not (math.isfinite(a) and a >= 0):
        raise ValueError(f"approx must be None or a maximum position error >= 0 in pixels, got {approx!r}")
    return a


def _approx_arg(approx: float):
    """The kernels' ``approx``: None for exact, else a traced threshold (no
    recompilation per value)."""
    return jnp.asarray(approx, dtype=float) if approx > 0 else None


def _run_tiles(fn, tiles, progress, desc: str, info: dict | None, approx: float, chunks: int, sink):
    """``sink(tile, block)`` for ``block, err, n_exact = fn(tile)`` over the
    tiles, in order; ``fn`` runs on a thread pool (XLA:CPU runs each tile's
    loop on one thread and releases the GIL), at most two tiles per thread
    in flight.  Shows a progress bar and fills ``info`` (see :func:`rectify`)."""
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    from .resampling import _THREADS

    worst, exact = 0.0, 0
    threads = max(1, min(_THREADS, len(tiles)))
    with _progress(len(tiles), progress, desc) as bar, ThreadPoolExecutor(threads) as pool:
        running = deque()
        for i in range(len(tiles) + 1):
            if i < len(tiles):
                running.append((tiles[i], pool.submit(fn, tiles[i])))
            while running and (len(running) >= 2 * threads or i == len(tiles)):
                t, future = running.popleft()
                block, err, n_exact = future.result()
                sink(t, block)
                worst, exact = max(worst, float(err)), exact + int(n_exact)
                if approx:
                    bar.set_postfix(max_err=f"{worst:.3f}px", refresh=False)
                bar.update()
    if info is not None:
        info.update(approx=approx, approx_error=worst, exact_fraction=exact / max(chunks * len(tiles), 1))


def _fill_value(dtype: np.dtype, nodata) -> np.ndarray:
    """The nodata value as a 0-d array of ``dtype`` (default NaN, or 0 for integers)."""
    dtype = np.dtype(dtype)
    if nodata is None:
        nodata = np.nan if np.issubdtype(dtype, np.floating) else 0
    if np.isnan(nodata) and not np.issubdtype(dtype, np.floating):
        raise ValueError(f"nodata=NaN needs a floating-point image, got {dtype}")
    value = np.asarray(nodata, dtype=dtype)
    if not np.isnan(nodata) and float(value) != float(nodata):
        raise ValueError(f"nodata={nodata!r} is not representable in the image dtype {dtype}")
    return value


def _tiles(shape: tuple[int, int], tile: int):
    """``(r0, c0, h, w)`` of the tiles covering ``shape``, row by row: about
    ``tile`` pixels square, balanced (a 4097-row grid gets five 832-row
    tiles, not four of 1024 and one of 1) and multiples of the lattice step
    except the last, so the approximate mapping's lattice does not depend
    on the tiling."""
    if int(tile) < 1:
        raise ValueError(f"tile must be a positive number of pixels, got {tile!r}")
    def up(a, b):  # ceil(a / b)
        return -(-a // b)

    sizes = [up(up(n, up(n, int(tile))), _STEP) * _STEP for n in shape]
    for r0 in range(0, shape[0], sizes[0]):
        for c0 in range(0, shape[1], sizes[1]):
            yield r0, c0, min(sizes[0], shape[0] - r0), min(sizes[1], shape[1] - c0)


def _progress(total: int, progress, desc: str):
    from .progress import progress_bar

    return progress_bar(progress, total, desc=desc, unit="tile")


def _check_model(model):
    if not callable(model):
        raise ValueError(f"model must be a callable (..., 2) map -> (..., 2) pixel, got {type(model).__name__}")


def rectify(
    image,
    model: Callable[[Array], Array],
    grid: Grid,
    *,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    progress: bool | str = False,
    mapping: Literal["indirect", "direct"] = "indirect",
    inverse: Callable[[Array], Array] | None = None,
    approx: float | None = 0.125,
    info: dict | None = None,
):
    """Resample an image onto a map grid through a geometric model.

    Indirect mapping (default): output pixel centre -> map ``(X, Y)`` from
    ``grid`` -> input pixel ``(col, row) = model(X, Y)`` -> grey value by
    ``resampling``.  Output pixels whose position is outside the image, or
    where the model returns NaN (e.g. no DEM height), get ``nodata``.

    Approximate mapping (``approx > 0``, the default; as GDAL's approximate
    transformer): the model is evaluated exactly only every 16 output pixels
    and at the centres and edge midpoints of those 16 x 16 cells (the check
    positions), and positions in between are interpolated bilinearly
    wherever the check error is at most ``approx`` pixels in column and row;
    elsewhere (rough DEM, NaN edges) the exact mapping is used for that
    16 x 1024 chunk.  A cell whose corners and check positions all map to NaN
    is taken as nodata.  Between check positions the error is not measured;
    on smooth maps and DEM relief it peaks at them (tests).

    Direct mapping (``mapping="direct"``, for comparison): every input pixel
    centre is sent to the map by ``inverse`` (pixel -> map) and its value put
    into the nearest output pixel (later input pixels win).  Without
    ``inverse`` a polynomial of order 3 fitted to ``model`` on the output grid
    is used (or ``model.inverse()`` when the model has one).  Returns the image and the number of *holes*: output pixels
    inside the image footprint (where the indirect mapping has a value) that
    no input pixel hit.

    Args:
        image: ``(..., H, W)`` array, leading axes are bands (rasterio layout).
        model: callable ``(..., 2)`` map ``(X, Y)`` -> ``(..., 2)`` input
            pixel ``(col, row)`` (integer = pixel centre), jax-traceable,
            e.g. a :class:`photax.PolynomialModel` fitted map -> pixel.
        grid: the output :class:`Grid`.
        resampling: ``"nearest"``, ``"bilinear"``, ``"cubic"`` (Keys,
            a = -0.5), ``"lanczos"`` or ``"bspline"``.
        nodata: value for output pixels without data; default NaN for
            floating-point images, 0 for integer ones.
        tile: output tile edge in pixels; memory grows with ``tile**2``.
        progress: a progress bar over the tiles: ``True`` (labelled
            "rectify"), a label, or an open bar to advance
            (:mod:`photax.progress`).
        mapping: ``"indirect"`` or ``"direct"``.
        inverse: pixel -> map callable, for ``mapping="direct"`` only.
        approx: maximum position error (pixels) of the approximate mapping
            at the check positions; ``0`` or ``None``: the exact model at
            every output pixel (slower).
        info: a dict to receive ``approx`` (the threshold),
            ``approx_error`` (the largest position error at the check
            positions of the interpolated chunks, px) and ``exact_fraction``
            (share of chunks mapped exactly).

    Returns:
        ``(..., rows, cols)`` numpy array in the input dtype; with
        ``mapping="direct"`` the tuple ``(array, holes)``.
    """
    resampling = _check_resampling(resampling)
    _check_model(model)
    if not isinstance(grid, Grid):
        raise ValueError(f"grid must be a photax Grid, got {type(grid).__name__}")
    image = jnp.asarray(image)
    if image.ndim < 2 or min(image.shape[-2:]) < 1:
        raise ValueError(f"image must have shape (..., H, W), got {image.shape}")
    fill = _fill_value(image.dtype, nodata)
    if mapping == "direct":
        return _rectify_direct(image, model, grid, fill, tile, progress, inverse)
    if mapping != "indirect":
        raise ValueError(f"mapping must be 'indirect' or 'direct', got {mapping!r}")
    from .resampling import _compute_dtype, _source

    approx = _check_approx(approx)
    tiles = list(_tiles(grid.shape, int(tile)))
    layout = _layout(*tiles[0][2:])  # every call gets this shape (edge tiles are cropped): one compilation
    out = np.empty(image.shape[:-2] + grid.shape, dtype=image.dtype)
    size = tuple(image.shape[-2:])
    flat = _source(image.reshape((-1,) + size), resampling, _compute_dtype(image.dtype))
    transform = jnp.asarray(tuple(grid.transform)[:6])
    fill_j = jnp.full((flat.shape[0],), fill, dtype=image.dtype)

    compute, out_dtype = _compute_dtype(image.dtype), np.dtype(image.dtype)

    def one(t):
        offset = jnp.array(t[:2], dtype=float)
        return _rectify_tile(model, flat, transform, offset, fill_j, layout, _approx_arg(approx), size, resampling,
                             compute, out_dtype)

    def sink(t, block):
        r0, c0, h, w = t
        out[..., r0 : r0 + h, c0 : c0 + w] = np.asarray(block)[:, :h, :w].reshape(out.shape[:-2] + (h, w))

    chunks = (layout[0][0] // layout[1]) * (layout[0][1] // layout[2])
    _run_tiles(one, tiles, progress, "rectify", info, approx, chunks, sink)
    return out


@eqx.filter_jit
def _forward_rows(inverse, offset: Array, shape: tuple[int, int]) -> Array:
    r = offset + jnp.arange(shape[0], dtype=float)
    c = jnp.arange(shape[1], dtype=float)
    colrow = jnp.stack(jnp.broadcast_arrays(c[None, :], r[:, None]), axis=-1)
    return jnp.asarray(inverse(colrow))


def _fit_inverse(model, grid: Grid, order: int = 3):
    """A pixel -> map polynomial fitted to ``model`` on a 33 x 33 lattice of the grid."""
    from .polynomial import fit_polynomial

    rows = np.linspace(0, grid.height - 1, 33).round().astype(int)
    cols = np.linspace(0, grid.width - 1, 33).round().astype(int)
    xy = grid.xy()[rows][:, cols].reshape(-1, 2)
    pix = np.asarray(model(jnp.asarray(xy)))
    ok = np.all(np.isfinite(pix), axis=-1)
    return fit_polynomial(jnp.asarray(pix[ok]), jnp.asarray(xy[ok]), order)


def _rectify_direct(image, model, grid, fill, tile, progress, inverse):
    if inverse is None:
        inverse = model.inverse() if callable(getattr(model, "inverse", None)) else _fit_inverse(model, grid)
    _check_model(inverse)
    H, W = image.shape[-2:]
    img = np.asarray(image)
    out = np.full(image.shape[:-2] + grid.shape, fill, dtype=image.dtype)
    hit = np.zeros(grid.shape, dtype=bool)
    back = ~grid.transform  # map -> raster coordinates (pixel k spans [k, k+1))
    step = max(1, int(tile) ** 2 // W)
    with _progress(math.ceil(H / step), progress, "direct mapping") as bar:
        for r0 in range(0, H, step):
            h = min(step, H - r0)
            xy = np.asarray(_forward_rows(inverse, jnp.asarray(float(r0)), (h, W)))
            gc, gr = back * (xy[..., 0], xy[..., 1])
            gc, gr = np.floor(gc), np.floor(gr)
            ok = (gc >= 0) & (gc < grid.width) & (gr >= 0) & (gr < grid.height)
            ri, ci = gr[ok].astype(np.intp), gc[ok].astype(np.intp)
            out[..., ri, ci] = img[..., r0 : r0 + h, :][..., ok]
            hit[ri, ci] = True
            bar.update()
    # Holes: pixels the indirect mapping would fill (inside the image) but no
    # input pixel reached.
    holes = 0
    transform = jnp.asarray(tuple(grid.transform)[:6])
    for r0, c0, h, w in _tiles(grid.shape, int(tile)):
        cols, rows = (np.asarray(v) for v in _map_tile(model, transform, jnp.array([r0, c0], dtype=float), (h, w)))
        inside = (cols >= -0.5) & (cols <= W - 0.5) & (rows >= -0.5) & (rows <= H - 0.5)
        holes += int(np.count_nonzero(inside & ~hit[r0 : r0 + h, c0 : c0 + w]))
    return out, holes


# --- orthorectification --------------------------------------------------------


class OrthoModel(eqx.Module):
    """Ground ``(X, Y)`` -> image pixel ``(col, row)`` through a DEM.

    ``Z = dem.height(X, Y)`` (bilinear), then the collinearity equations and
    ``camera.image_to_pixel``.  NaN where the DEM has no height or the
    ground point is behind the camera.  No occlusion test.
    """

    exterior: ExteriorOrientation
    camera: FrameCamera
    dem: DEM

    def __call__(self, xy: Array) -> Array:
        xy = jnp.asarray(xy, dtype=float)
        flat = xy.reshape(-1, 2)
        z = self.dem.height(flat[:, 0], flat[:, 1])
        ground = jnp.concatenate([flat, z[:, None]], axis=-1)
        pix = self.camera.image_to_pixel(project(ground, self.exterior, self.camera))
        ok = jnp.isfinite(z) & (depth(ground, self.exterior) > 0)
        return jnp.where(ok[:, None], pix, jnp.nan).reshape(xy.shape)


_to_ground = eqx.filter_jit(image_to_ground)


def _shoelace(p: np.ndarray) -> float:
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(np.roll(p[:, 0], -1), p[:, 1])))


def ortho_grid(
    exterior: ExteriorOrientation, camera: FrameCamera, dem: DEM, resolution=None, *, per_side: int = 16
) -> Grid:
    """The grid covering an image's footprint on a DEM.

    The image outline (``per_side`` points per edge, on the outer pixel
    edges) is cut with the DEM by :func:`photax.image_to_ground`; rays that
    miss the DEM are cut with the plane at the DEM's mean height.  The
    bounds are clipped to the DEM and snapped to the resolution.

    Args:
        resolution: ground pixel size; default the mean ground sampling
            distance ``sqrt(footprint area / image area in pixels)``.
    """
    if camera.image_size is None:
        raise ValueError("camera must have an image_size to find the image footprint")
    w, h = camera.image_size
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    x0, x1, y0, y1 = -0.5, w - 0.5, -0.5, h - 0.5
    px = np.concatenate(
        [
            np.stack([x0 + t * (x1 - x0), np.full_like(t, y0)], -1),
            np.stack([np.full_like(t, x1), y0 + t * (y1 - y0)], -1),
            np.stack([x1 - t * (x1 - x0), np.full_like(t, y1)], -1),
            np.stack([np.full_like(t, x0), y1 - t * (y1 - y0)], -1),
        ]
    )
    img = camera.pixel_to_image(jnp.asarray(px))
    ground = np.asarray(_to_ground(img, exterior, camera, dem=dem))
    flat = np.asarray(_to_ground(img, exterior, camera, height=jnp.nanmean(dem.heights)))
    ground = np.where(np.isfinite(ground), ground, flat)[:, :2]
    if not np.all(np.isfinite(ground)):
        raise ValueError("the image outline does not reach the ground (camera looks above the horizon)")
    if resolution is None:
        resolution = math.sqrt(_shoelace(ground) / _shoelace(px))
    dxmin, dymin, dxmax, dymax = dem.bounds
    bounds = (
        max(ground[:, 0].min(), dxmin),
        max(ground[:, 1].min(), dymin),
        min(ground[:, 0].max(), dxmax),
        min(ground[:, 1].max(), dymax),
    )
    if not (bounds[2] > bounds[0] and bounds[3] > bounds[1]):
        raise ValueError("the image footprint does not overlap the DEM")
    return Grid.from_bounds(bounds, resolution, crs=dem.crs)


def orthorectify(
    image,
    exterior: ExteriorOrientation,
    camera: FrameCamera,
    dem: DEM,
    grid: Grid | None = None,
    *,
    resolution=None,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    progress: bool | str = False,
    approx: float | None = 0.125,
    info: dict | None = None,
) -> tuple[np.ndarray, Grid]:
    """Orthorectify a frame image with its orientation and a DEM.

    For every ground pixel centre ``(X, Y)`` of the output grid:
    ``Z = DEM(X, Y)`` (bilinear), ``(x, y) = project((X, Y, Z))`` by the
    collinearity equations, ``(col, row) = camera.image_to_pixel(x, y)``, and
    the grey value is resampled there.  Output pixels are ``nodata`` where
    the point falls outside the image, where the DEM is nodata or absent, and
    behind the camera.

    Occlusion is NOT handled: ground hidden from the camera by relief gets
    the grey value of the surface that hides it (double mapping).

    Args:
        image: ``(..., H, W)`` with ``(W, H) == camera.image_size``.
        exterior, camera: the image's orientation (``docs/conventions.md``).
        dem: heights in the same ground CRS and vertical datum as ``exterior``.
        grid: output grid; default the image footprint on the DEM
            (:func:`ortho_grid`) at ``resolution``.
        resolution: ground pixel size when ``grid`` is not given; default
            the mean ground sampling distance.
        resampling, nodata, tile, progress, approx, info: as in :func:`rectify`
            (the approximate mapping's check catches rough DEMs: chunks
            whose check error exceeds ``approx`` are mapped exactly).

    Returns:
        ``(ortho, grid)``: the ``(..., rows, cols)`` orthophoto in the input
        dtype and its grid.
    """
    image = jnp.asarray(image)
    _check_image_size(image.shape, camera)
    if grid is None:
        grid = ortho_grid(exterior, camera, dem, resolution)
    model = OrthoModel(exterior, camera, dem)
    out = rectify(image, model, grid, resampling=resampling, nodata=nodata, tile=tile, progress=progress,
                  approx=approx, info=info)
    return out, grid


def _check_image_size(shape, camera: FrameCamera):
    if camera.image_size is not None and tuple(shape[-2:][::-1]) != tuple(camera.image_size):
        raise ValueError(
            f"image is {shape[-1]} x {shape[-2]} pixels but the camera's image_size is "
            f"{camera.image_size[0]} x {camera.image_size[1]}"
        )


# --- streaming through files ---------------------------------------------------


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
    import rasterio
    from rasterio.windows import Window

    from .io.atomic import atomic_path
    from .io.raster import open_raster
    from .resampling import _compute_dtype, _source

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
        profile = dict(
            driver="GTiff", width=grid.width, height=grid.height, count=src.count, dtype=src.dtypes[0],
            transform=grid.transform, crs=grid.crs, nodata=fill.item(), tiled=True, blockxsize=256,
            blockysize=256, BIGTIFF="IF_SAFER",
        )
        if compress:
            profile["compress"] = compress
        transform = jnp.asarray(tuple(grid.transform)[:6])
        tiles = list(_tiles(grid.shape, tile))
        layout = _layout(*tiles[0][2:])
        fill_j = jnp.full((src.count,), fill, dtype=fill.dtype)
        size = (src.height, src.width)
        compute, out_dtype = _compute_dtype(fill.dtype), np.dtype(fill.dtype)
        lock = threading.Lock()  # a rasterio dataset is not thread-safe

        def one(t):
            r0, c0, h, w = t
            pos, origin, err, n_exact = _tile_positions(
                model, transform, jnp.array([r0, c0], dtype=float), layout, _approx_arg(approx), size)
            p, o = np.asarray(pos)[:, :h, :w], np.asarray(origin)
            # The window from the very positions resampled: none falls outside it.
            win = _source_window(p[0] + o[0], p[1] + o[1], src.width, src.height, Resampling(resampling).margin)
            if win is None:
                return np.full((src.count, h, w), fill, dtype=fill.dtype), err, n_exact
            with lock:
                data = src.read(window=Window(win[1], win[0], win[3], win[2]))
            offset = jnp.asarray(o - np.array([win[1], win[0]]), dtype=jnp.int32)
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
    from .io.raster import open_raster

    inputs = ()
    if not isinstance(dem, DEM):
        from .io.raster import read_dem

        inputs = (dem,)
        dem = read_dem(dem)
    with open_raster(src_path) as src:
        _check_image_size((src.height, src.width), camera)
    if grid is None:
        grid = ortho_grid(exterior, camera, dem, resolution)
    return rectify_file(
        src_path, dst_path, OrthoModel(exterior, camera, dem), grid, resampling=resampling, nodata=nodata,
        tile=tile, progress=progress, compress=compress, inputs=inputs, approx=approx, info=info,
    )
