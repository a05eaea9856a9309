"""Indirect mapping (output -> input), the default: :func:`rectify`.

Per tile one jitted function maps the output pixels to input positions
(:mod:`._approx`) and resamples there (:func:`photax.resampling.interpolate`),
tiles on a thread pool (:func:`._tiling._run_tiles`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._pytree import filter_jit
from ..grid import Grid
from ..io.sizes import check_output_size
from ..resampling import Resampling
from ._approx import _bounds, _chunk_positions, _lattice_cells, _tile_plan
from ._direct import _rectify_direct
from ._tiling import (
    _STEP,
    _approx_arg,
    _check_approx,
    _check_model,
    _check_resampling,
    _fill_value,
    _layout,
    _run_tiles,
    tile_windows,
)


@filter_jit
def _rectify_tile(model, flat, transform, offset, fill, layout, approx, size, method, compute, out_dtype):
    """One output tile, mapping and resampling fused: ``(block, err, n_exact)``.

    ``flat`` is the whole image prepared by :func:`photax.resampling.gather_source`;
    ``block`` is ``(B, *layout[0])``, ``n_exact`` the number of chunks mapped
    exactly (all of them when ``approx`` is 0).
    """
    from ..resampling import interpolate

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
            v = interpolate(
                flat,
                pos[0],
                pos[1],
                fill,
                lo,
                hi,
                origin,
                shape=size,
                method=method,
                a=-0.5,
                compute=compute,
                out_dtype=out_dtype,
            )
            return jax.lax.dynamic_update_slice(out, v.reshape(-1, s, cw), (0, i * s, j * cw))

        return jax.lax.fori_loop(0, (tr // s) * nc, body, jnp.empty((flat.shape[0], tr, tc), dtype=out_dtype))

    def interpolated(p):
        # No chunk needs the exact mapping: the whole tile in one pass over
        # the lattice's positions.  Measured faster than any loop over
        # strips: XLA:CPU's in-place dynamic-update-slice of each strip's
        # result is not vectorised.
        v = interpolate(
            flat,
            p[0],
            p[1],
            fill,
            lo,
            hi,
            origin,
            shape=size,
            method=method,
            a=-0.5,
            compute=compute,
            out_dtype=out_dtype,
        )
        return v.reshape(-1, tr, tc)

    if approx is None:
        out = loop(True)
    else:
        # The lattice's positions are made in one lax.cond and resampled in
        # another: a cond's operands and results are stored, anything else XLA
        # fuses, and LLVM vectorises neither the loop that makes the positions
        # from the f64 plan nor one that also gathers (nearest ran 2x slower
        # per pixel than bilinear, whose positions XLA happened to store).
        some_bad = jnp.any(bad)
        cells = jax.lax.cond(
            some_bad, lambda r: jnp.zeros((2, tr // s, s, tc), jnp.float32), lambda r: _lattice_cells(r, s), plan[0]
        )
        out = jax.lax.cond(some_bad, lambda _: loop(False), interpolated, cells)
    return out, plan[3], jnp.sum(bad)


@filter_jit
def _resample_tile(flat, pos, origin, offset, fill, size, window, method, compute, out_dtype):
    """Resample the window ``flat`` (prepared, ``window`` = (h, w)) at
    ``pos`` relative to ``origin`` (image pixels); ``offset`` = origin minus
    the window's (col, row); footprint: the whole image ``size`` (H, W)."""
    from ..resampling import interpolate

    lo, hi = _bounds(origin, size, pos.dtype)
    tr, tc = pos.shape[1:]

    # 16-row strips, the arithmetic of _rectify_tile's exact loop, so file
    # and memory give the same bits (one fused pass over the tile, as in
    # _rectify_tile's interpolated branch, is faster but differs from the
    # exact loop by float32 round-off: 1 grey value in 40,000 for cubic).
    def body(i, out):
        p = jax.lax.dynamic_slice(pos, (0, i * _STEP, 0), (2, _STEP, tc)).reshape(2, -1)
        v = interpolate(
            flat,
            p[0],
            p[1],
            fill,
            lo,
            hi,
            offset,
            shape=window,
            method=method,
            a=-0.5,
            compute=compute,
            out_dtype=out_dtype,
        )
        return jax.lax.dynamic_update_slice(out, v.reshape(-1, _STEP, tc), (0, i * _STEP, 0))

    return jax.lax.fori_loop(0, tr // _STEP, body, jnp.empty((flat.shape[0], tr, tc), dtype=out_dtype))


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
            a = -0.5), ``"lanczos"`` (Lanczos-3), ``"lanczos4"``
            (Lanczos-4, as OpenCV's) or ``"bspline"``.
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

    Examples:
        A frame over flat land rectified by the projective model of its control points onto the grid
        of the scene's true orthophoto (the ground texture itself), which it reproduces:

        >>> import numpy as np
        >>> import photax as ptx
        >>> flat = ptx.relief_scene(0.0, seed=1, image_size=(400, 300), focal_px=400.0)
        >>> model = ptx.fit_projective(flat.gcp_ground[:, :2], flat.gcp_pixel)
        >>> grid = ptx.Grid(flat.ortho_transform, flat.ortho.shape)
        >>> out = ptx.rectify(flat.image, model, grid, resampling="cubic")
        >>> seen = np.isfinite(out)  # NaN outside the image
        >>> out.shape == grid.shape, bool(np.corrcoef(out[seen], flat.ortho[seen])[0, 1] > 0.95)
        (True, True)
    """
    # Over 80 lines only by its docstring, the reference for every argument
    # the other entry points share; the work is in _tiling and _approx.
    resampling = _check_resampling(resampling)
    _check_model(model)
    if not isinstance(grid, Grid):
        raise ValueError(f"grid must be a photax Grid, got {type(grid).__name__}")
    # numpy stays numpy (no jnp.asarray copy): gather_source pads it in numpy.
    image = image if isinstance(image, (jax.Array, np.ndarray)) else np.asarray(image)
    if image.ndim < 2 or min(image.shape[-2:]) < 1:
        raise ValueError(f"image must have shape (..., H, W), got {image.shape}")
    fill = _fill_value(image.dtype, nodata)
    check_output_size(grid.shape, int(np.prod(image.shape[:-2], dtype=np.int64)), image.dtype)
    if mapping == "direct":
        return _rectify_direct(image, model, grid, fill, tile, progress, inverse)
    if mapping != "indirect":
        raise ValueError(f"mapping must be 'indirect' or 'direct', got {mapping!r}")
    from ..resampling import compute_dtype, gather_source

    approx = _check_approx(approx)
    tiles = list(tile_windows(grid.shape, int(tile)))
    layout = _layout(*tiles[0][2:])  # every call gets this shape (edge tiles are cropped): one compilation
    out = np.empty(image.shape[:-2] + grid.shape, dtype=image.dtype)
    size = tuple(image.shape[-2:])
    flat = gather_source(image.reshape((-1,) + size), resampling, compute_dtype(image.dtype))
    transform = jnp.asarray(tuple(grid.transform)[:6])
    fill_j = jnp.full((flat.shape[0],), fill, dtype=image.dtype)

    compute, out_dtype = compute_dtype(image.dtype), np.dtype(image.dtype)

    approx_j = _approx_arg(approx)

    def one(t):
        offset = np.array(t[:2], dtype=float)  # numpy: see _approx_arg
        return _rectify_tile(
            model, flat, transform, offset, fill_j, layout, approx_j, size, resampling, compute, out_dtype
        )

    def sink(t, block):
        r0, c0, h, w = t
        out[..., r0 : r0 + h, c0 : c0 + w] = np.asarray(block)[:, :h, :w].reshape(out.shape[:-2] + (h, w))

    chunks = (layout[0][0] // layout[1]) * (layout[0][1] // layout[2])
    _run_tiles(one, tiles, progress, "rectify", info, approx, chunks, sink)
    return out
