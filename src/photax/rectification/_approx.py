"""Input pixel positions of an output tile: exact, or GDAL-style approximate.

An output tile is processed in chunks of ``_STEP`` rows x ``cols`` columns
inside one jitted loop: positions are made, resampled and written per chunk,
so no full-size coordinate map ever exists.  With ``approx`` the exact
mapping is evaluated only on a lattice every ``_STEP`` output pixels and at
the lattice cells' centres and edge midpoints (the check positions); a chunk
whose cells all interpolate their check positions within ``approx`` pixels
gets bilinearly interpolated positions, any other chunk the exact ones
(GDAL's approximate transformer checks segment midpoints along rows,
threshold 0.125 px).  Positions are float32 relative to an integer origin
near the tile's positions (ample: 2^-24 relative).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._pytree import filter_jit


def _map_xy(transform: Array, r: Array, c: Array) -> Array:
    """``(len(r), len(c), 2)`` map coordinates of raster coordinates ``r`` x ``c``."""
    a, b, xoff, d, e, yoff = (transform[i] for i in range(6))
    return jnp.stack([xoff + a * c[None, :] + b * r[:, None], yoff + d * c[None, :] + e * r[:, None]], axis=-1)


@filter_jit
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
    rm, cm = r[:-1] + s / 2, c[:-1] + s / 2  # cell mid-rows and mid-columns
    # The nodes, then the check positions: the cell centres and the edge midpoints (horizontal edges
    # (mr+1, mc), vertical edges (mr, mc+1)).  One call of the model on all of them: each call is a
    # copy of the model in the compiled program, whose size is what a new process pays to load it.
    sets = [_map_xy(transform, a, b) for a, b in ((r, c), (rm, cm), (r, cm), (rm, c))]
    ends = np.cumsum([x.shape[0] * x.shape[1] for x in sets])[:-1].tolist()
    mapped = jnp.asarray(model(jnp.concatenate([x.reshape(-1, 2) for x in sets])), dtype=float)
    nodes, *exacts = (m.reshape(x.shape) for m, x in zip(jnp.split(mapped, ends), sets))
    # ... with the bilinear (on edges: linear) interpolation of the nodes there.
    interps = [
        0.25 * (nodes[:-1, :-1] + nodes[1:, :-1] + nodes[:-1, 1:] + nodes[1:, 1:]),
        0.5 * (nodes[:, :-1] + nodes[:, 1:]),
        0.5 * (nodes[:-1, :] + nodes[1:, :]),
    ]
    errs = []
    for exact, interp in zip(exacts, interps):
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


def _lattice_cells(rel: Array, s: int) -> Array:
    """``(2, mr+1, mc+1)`` lattice positions -> ``(2, mr, s, mc*s)``
    positions of the whole tile (cell row, row in cell, column), bilinear in
    each cell: the arithmetic of :func:`_chunk_positions` (along rows first,
    then between rows), so the same float32 values.

    Along rows the cells' columns are merged into one axis before the
    interpolation between rows, so that XLA's loop over the tile reads the
    row interpolants at consecutive addresses (LLVM vectorises it; over
    ``(2, mr, s, mc, s)`` it did not).
    """
    f = jnp.arange(s, dtype=jnp.float32) / s
    n0, n1 = rel[:, :, :-1, None], rel[:, :, 1:, None]  # (2, mr+1, mc, 1): cell corners along rows
    along = (n0 + (n1 - n0) * f[None, None, None, :]).reshape(rel.shape[0], rel.shape[1], -1)  # (2, mr+1, mc*s)
    top, bottom = along[:, :-1, None], along[:, 1:, None]  # (2, mr, 1, mc*s)
    return top + (bottom - top) * f[None, None, :, None]


def _lattice_positions(rel: Array, s: int) -> Array:
    """:func:`_lattice_cells` as ``(2, mr*s, mc*s)`` (row-major: a reshape)."""
    _, mr1, mc1 = rel.shape
    return _lattice_cells(rel, s).reshape(2, (mr1 - 1) * s, (mc1 - 1) * s)


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


@filter_jit
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
