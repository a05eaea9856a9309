"""True orthophotos: z-buffer visibility of a DSM (:func:`occluded`, public as
:func:`photax.occlusion_mask`); the block's true ortho is :mod:`._true_ortho`.

Z-buffer (Amhar, Jansa & Ries 1998; Rau, Chen & Chen 2002): the DSM surface is sampled on a
lattice aligned with the output grid, its step ``1/supersample`` of the finer of the DSM cell and
the buffer cell's ground size (heights bilinear, so a wall between a
roof cell and a ground cell is a steep slope sampled at the intermediate points) and widened by the
relief displacement of its height range; every sample is projected into the image and the buffer
keeps, per buffer cell (``s x s`` image pixels, ``s`` about one grid cell's image size so every cell
of the surface's image gets a sample), its smallest *depth*:

* frame camera: the distance ``|P - C|`` to the projection centre;
* ground camera (RPC, push-broom, :class:`photax.sensor.GroundSensor`): ``-Z``. Its rays are nearly
  parallel and points sharing a buffer cell lie on about one ray, along which the point nearer the
  satellite is the higher one (the height-along-ray test).

An output cell (its centre at the DSM's height) is *occluded* where its depth exceeds the buffer's
at its image position by more than ``tolerance`` (default twice the larger of the grid cell and the
buffer cell's ground size: surface samples sharing a buffer cell differ by about that much). Scatter-min
in JAX (``.at[].min``), strips of the sample lattice in a Python loop (bounded memory), no loop over
pixels.

Limits: a façade longer in the image than ``supersample`` samples per DSM cell can leave gaps in
the buffer where hidden ground shows through (raise ``supersample``); objects lower than the
tolerance are not detected; an occluder outside the DSM is not seen.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import filter_jit
from ..grid import Grid
from ..sensor import FrameSensor

_STRIP = 1 << 16  # surface samples per compiled scatter call


def _cell(grid: Grid) -> float:
    a, b, _, d, e, _ = tuple(grid.transform)[:6]
    return float(max(np.hypot(a, d), np.hypot(b, e)))


def _centres(grid: Grid, rows, cols) -> np.ndarray:
    """``(..., 2)`` ground ``(X, Y)`` at fractional grid ``(row, col)`` pixel-centre positions."""
    a, b, c, d, e, f = tuple(grid.transform)[:6]
    cc, rr = np.meshgrid(np.asarray(cols, dtype=float) + 0.5, np.asarray(rows, dtype=float) + 0.5)
    return np.stack([c + a * cc + b * rr, f + d * cc + e * rr], axis=-1)


@filter_jit
def _heights(model, xy):
    """``(n,)`` DSM heights at ``(n, 2)`` grid-CRS points."""
    at = xy if model.to_dem is None else model.to_dem(xy)
    return model.dem.height(at[:, 0], at[:, 1])


@filter_jit
def _project(model, p):
    """``(n, 3)`` ground -> ``(n, 2)`` pixel and ``(n,)`` depth (module docstring), NaN where not imaged."""
    pix = model.sensor(p)
    if isinstance(model.sensor, FrameSensor):
        depth = jnp.linalg.norm(p - model.sensor.exterior.position[None], axis=-1)
    else:
        depth = -p[:, 2]
    ok = jnp.all(jnp.isfinite(p), axis=-1) & jnp.all(jnp.isfinite(pix), axis=-1)
    return jnp.where(ok[:, None], pix, jnp.nan), jnp.where(ok, depth, jnp.nan)


def _chunked(fn, model, points: np.ndarray):
    """``fn(model, chunk)`` over ``points`` in chunks of :data:`_STRIP` (the last padded): one
    compiled shape for any grid."""
    n = len(points)
    parts = []
    for a in range(0, max(n, 1), _STRIP):
        chunk = points[a : a + _STRIP]
        pad = (
            np.concatenate([chunk, np.repeat(chunk[-1:], _STRIP - len(chunk), axis=0)])
            if len(chunk) < _STRIP
            else chunk
        )
        res = fn(model, jnp.asarray(pad, dtype=float))
        parts.append([np.asarray(r)[: len(chunk)] for r in (res if isinstance(res, tuple) else (res,))])
    out = [np.concatenate(c) for c in zip(*parts)]
    return out if len(out) > 1 else out[0]


def _surface(model, xy: np.ndarray):
    """``(n, 2)`` ground -> pixel, depth of the DSM point above it."""
    z = _chunked(_heights, model, xy)
    return _chunked(_project, model, np.column_stack([xy, z]))


def _buffer_index(pix: np.ndarray, s: int, shape) -> np.ndarray:
    """Flat buffer index of pixels (``-1`` outside the image's buffer)."""
    bh, bw = shape
    with np.errstate(invalid="ignore"):
        bc = np.floor((pix[:, 0] + 0.5) / s)
        br = np.floor((pix[:, 1] + 0.5) / s)
        inside = (bc >= 0) & (bc < bw) & (br >= 0) & (br < bh)
    return np.where(inside, np.nan_to_num(br) * bw + np.nan_to_num(bc), -1).astype(np.int64)


@jax.jit
def _scatter_min(buffer, idx, depth):
    keep = (idx >= 0) & jnp.isfinite(depth)
    # Samples off the buffer go to its extra last slot, never read.
    return buffer.at[jnp.where(keep, idx, buffer.size - 1)].min(jnp.where(keep, depth, jnp.inf))


def ground_lean(model, xy: np.ndarray) -> np.ndarray:
    """``(n,)`` ground shift of the imaged point per metre of height (``tan`` of the off-nadir angle)
    at ``(n, 2)`` ground points, from the sensor's Jacobian by finite differences: any sensor."""
    xy = np.asarray(xy, dtype=float)
    z = _chunked(_heights, model, xy)
    z = np.where(np.isfinite(z), z, np.nanmean(np.asarray(model.dem.heights)))
    p = np.column_stack([xy, z])
    step = 1.0
    probes = np.concatenate([p, p + [step, 0, 0], p + [0, step, 0], p + [0, 0, step]])
    q = _chunked(_project, model, probes)[0].reshape(4, len(p), 2)
    jac = np.stack([q[1] - q[0], q[2] - q[0]], axis=-1) / step  # (n, 2 pixel, 2 ground)
    dz = (q[3] - q[0]) / step
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = np.linalg.solve(jac, dz[..., None])[..., 0]
    return np.hypot(shift[:, 0], shift[:, 1])


def occluded(
    model,
    grid: Grid,
    *,
    supersample: int = 2,
    tolerance: float | None = None,
    buffer_cell: int | None = None,
) -> np.ndarray:
    """Which cells of ``grid`` the ortho ``model``'s DSM hides from its sensor (z-buffer, module
    docstring; :func:`photax.occlusion_mask` is the public form).

    Args:
        model: a :class:`photax.rectification.OrthoModel` whose DEM is the DSM, checked.
        grid: the output grid.
        supersample: surface samples per DSM cell (or per buffer cell, the finer) along each
            axis (walls are sampled by the bilinear DSM at these points).
        tolerance: depth margin (m) before a cell counts as hidden; default twice the larger of
            the grid cell and the buffer cell's ground size.
        buffer_cell: buffer cell edge in image pixels; default about one grid cell's image size
            (at least 1).

    Returns:
        ``(rows, cols)`` bool, True where the cell's ground point is hidden by a nearer surface.
        False where it is visible and where it is not imaged at all (off the image, no DSM height:
        the ortho is nodata there anyway).
    """
    if int(supersample) < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    dsm = model.dem
    if model.sensor.image_size is None:
        raise ValueError("the camera needs an image_size for the z-buffer")
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance must be a finite depth >= 0 (m), got {tolerance}")
    rows, cols = grid.shape
    cell = _cell(grid)
    w, h = model.sensor.image_size
    # The grid's image scale (pixels per metre) and lean (ground shift per metre of height) at its
    # corners and centre: the buffer's cell and the margin of surface that may hide the grid.
    probe = _centres(grid, [0, (rows - 1) / 2, rows - 1], [0, (cols - 1) / 2, cols - 1]).reshape(-1, 2)
    pix = _surface(model, probe)[0]
    pix_dx = _surface(model, probe + [[cell, 0.0]])[0]
    scale = np.nanmedian(np.hypot(*(pix_dx - pix).T)) / cell  # px per metre
    if not np.isfinite(scale) or scale <= 0:
        scale = 1.0 / cell
    s = int(buffer_cell) if buffer_cell is not None else max(1, int(np.ceil(cell * scale)))
    if s < 1:
        raise ValueError(f"buffer_cell must be >= 1 pixel, got {buffer_cell}")
    heights = np.asarray(dsm.heights)
    span = float(np.nanmax(heights) - np.nanmin(heights)) if np.isfinite(heights).any() else 0.0
    lean = np.nanmax(ground_lean(model, probe), initial=0.0)
    margin = int(np.ceil(min(span * (lean if np.isfinite(lean) else 0.0) / cell, 4 * max(rows, cols)))) + 1
    if tolerance is None:
        tolerance = 2.0 * max(cell, s / scale)
    shape = (int(np.ceil(h / s)) + 1, int(np.ceil(w / s)) + 1)
    buffer = jnp.full(shape[0] * shape[1] + 1, jnp.inf)
    # Sample step: 1/supersample of the finer of the DSM cell and the buffer cell's ground size (a
    # grid finer than the image and the DSM needs no more samples than they resolve).
    step = min(_dsm_cell(model, cell), s / scale)
    f = step / cell / int(supersample)
    n_c, n_r = int(np.ceil((cols + 2 * margin) / f)), int(np.ceil((rows + 2 * margin) / f))
    sub_c = -margin + (np.arange(n_c) + 0.5) * f - 0.5
    per = max(1, _STRIP // len(sub_c))
    sub_r = -margin + (np.arange(n_r) + 0.5) * f - 0.5
    for a in range(0, len(sub_r), per):
        pix, depth = _surface(model, _centres(grid, sub_r[a : a + per], sub_c).reshape(-1, 2))
        idx = _buffer_index(pix, s, shape)
        for b in range(0, len(idx), _STRIP):
            i, d = _pad(idx[b : b + _STRIP], _STRIP), _pad(depth[b : b + _STRIP], _STRIP)
            buffer = _scatter_min(buffer, jnp.asarray(i), jnp.asarray(d))
    buffer = np.asarray(buffer)
    pix, depth = _surface(model, _centres(grid, np.arange(rows), np.arange(cols)).reshape(-1, 2))
    idx = _buffer_index(pix, s, shape)
    nearest = np.where(idx >= 0, buffer[np.maximum(idx, 0)], np.inf)
    with np.errstate(invalid="ignore"):
        hidden = (idx >= 0) & np.isfinite(depth) & (depth > nearest + tolerance)
    return hidden.reshape(rows, cols)


def _dsm_cell(model, cell: float) -> float:
    """The DSM's cell size in the grid's units (the grid's own where the DSM is in another CRS)."""
    if model.to_dem is not None:
        return cell
    a, b, _, d, e, _ = np.asarray(model.dem.transform)
    return float(max(np.hypot(a, d), np.hypot(b, e)))


def _pad(v: np.ndarray, n: int) -> np.ndarray:
    """``v`` padded to ``n`` by repeating its last value: every strip one compiled shape."""
    return np.concatenate([v, np.repeat(v[-1:], n - len(v))]) if len(v) < n else v
