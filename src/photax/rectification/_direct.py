"""Direct mapping (input -> output), kept for comparison: holes appear
where the output is finer than the input."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax import Array

from .._pytree import filter_jit
from ..grid import Grid
from ._approx import _map_tile
from ._tiling import _check_model, _progress, tile_windows


@filter_jit
def _forward_rows(inverse, offset: Array, shape: tuple[int, int]) -> Array:
    r = offset + jnp.arange(shape[0], dtype=float)
    c = jnp.arange(shape[1], dtype=float)
    colrow = jnp.stack(jnp.broadcast_arrays(c[None, :], r[:, None]), axis=-1)
    return jnp.asarray(inverse(colrow))


def _fit_inverse(model, grid: Grid, order: int = 3):
    """A pixel -> map polynomial fitted to ``model`` on a 33 x 33 lattice of the grid."""
    from ..polynomial import fit_polynomial

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
    for r0, c0, h, w in tile_windows(grid.shape, int(tile)):
        cols, rows = (np.asarray(v) for v in _map_tile(model, transform, jnp.array([r0, c0], dtype=float), (h, w)))
        inside = (cols >= -0.5) & (cols <= W - 0.5) & (rows >= -0.5) & (rows <= H - 0.5)
        holes += int(np.count_nonzero(inside & ~hit[r0 : r0 + h, c0 : c0 + w]))
    return out, holes
