"""Per-pixel geolocation uncertainty of an orthophoto, by first-order propagation.

An ortho pixel at ground ``g = (X, Y)`` shows the image at
``p = pi(theta, c, X, Y, Z(X, Y) + dz)``: ``theta`` the exterior orientation
``(X0, Y0, Z0, a1, a2, a3)`` (angles in the convention's order), ``c`` the
intrinsics (:data:`photax.bundle.INTRINSICS`: ``f, x0, y0, k1, k2, k3, p1,
p2``), ``Z`` the DEM's bilinear height and ``dz`` its error; ``pi`` is the
collinearity model with lens distortion (:func:`photax.project`) and the
camera's pixel grid.  With the Jacobians (closed form: the collinearity
Jacobian that bundle adjustment uses, :func:`photax.collinearity.collinearity_jacobian`,
and :func:`photax.camera.intrinsics_jacobian`; equal to ``jax.jacfwd`` of
:func:`photax.project` to 1e-12)

    J_t = dp/dtheta (2x6),  J_c = dp/dc (2x8; 2 x (3 + n) for a model of n coefficients),  J_z = dp/dZ (2x1),
    A   = dp/d(X, Y) (2x2, the total derivative through the DEM's slope),

the error of the image position read for the pixel is, to first order
(law of propagation of variances, e.g. Mikhail, Bethel & McGlone 2001,
ch. 2; Förstner & Wrobel 2016, sec. 2.7),

    S_p = J_t S_t J_t^T + J_c S_c J_c^T + s_z^2 J_z J_z^T        (pixels^2)

and the ground point whose grey value the pixel actually shows is off by
``dg = -A^-1 dp`` (the ray through ``p`` meets the DEM elsewhere), so

    S_g = A^-1 S_p A^-T                                          (metres^2).

Cost: ``J`` and ``S_p`` vary smoothly with the ground position, so they are
computed exactly (float64) on a lattice every ``step`` output pixels (on the
DEM) and interpolated bilinearly in between (float32: the 10 % a standard
deviation is asked to hold leaves ample room), in the form ``S_p``, ``J_z``,
``T = B S_p B^T`` and ``u = B J_z`` (``B = (dp/d(X, Y))^-1`` on flat
terrain); at every pixel only the DEM's slope ``g`` enters, by
Sherman-Morrison ``A^-1 = (I - u g^T / (1 + g.u)) B``, so that with ``h = g
/ (1 + g.u)`` and ``q = T h``

    S_g = T - (u q^T + q u^T) + (h.q) u u^T

(``T`` and ``S_p`` with the DEM sigma's terms ``sz^2 u u^T`` and ``sz^2 J_z
J_z^T``).  When the grid's axes are the DEM's the slope is read separably
(the DEM column of a pixel depends on its column only).  Interpolation
error: the entries vary on the scale of the flying height ``H`` above the
terrain, so the relative error of every standard deviation is about ``(s /
H)^2`` for a lattice spacing ``s`` on the ground (measured below ``2 (s /
H)^2``, and tested).  With ``step=16`` on a 10 cm ortho from 1000 m that is
3e-6.  Within a lattice cell of DEM nodata the nodes there take the DEM's
mean height and the error is larger (measured 2 % beside a hole where the
bound was 2 %, tested below 5 %; ``step=1`` has none).

Error ellipses (1 sigma) are the eigen-decompositions of these 2x2
covariances: semi-axes ``sqrt(l1) >= sqrt(l2)`` and the major axis' angle.
No occlusion and no misregistration of the image itself are modelled.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .camera import intrinsics_jacobian
from .collinearity import ExteriorOrientation, angle_axes, collinearity_jacobian
from .dem import DEM
from .geo import check_dem
from .grid import Grid
from .pushbroom import PushbroomResection
from .rpc import RPCRefinement
from .sensor import FrameSensor, GroundSensor, camera_kind, is_sensor, sensor_arguments

_BLOCK = 1 << 14  # points per jitted call (padded): one compilation, bounded memory
_STRIP = 1 << 19  # pixels per strip at most: its intermediates stay small


def _node_planes(sensor, g, cov):
    """The planes of :func:`_frame_planes`, :func:`_rpc_planes` or :func:`_pushbroom_planes`, by the
    sensor's kind."""
    if sensor.kind == "pushbroom":
        return _pushbroom_planes(sensor, g, cov)
    if sensor.kind == "rpc":
        return _rpc_planes(sensor, g, cov)
    return _frame_planes(sensor.exterior, sensor.camera, g, cov)


def _pushbroom_planes(sensor, g, cov):
    """As :func:`_frame_planes` for a push-broom model (:class:`photax.sensor.GroundSensor`): ``J = dp/d
    theta`` ``(2, P)`` of all its orbit and attitude coefficients (:meth:`photax.PushbroomCamera.parameters`)
    and ``dp/d(X, Y, Z)``, both by ``jax.jacfwd`` through the line search and the map CRS -> lon, lat
    transformation; ``cov`` ``(P, P)``."""
    cam = sensor.camera

    def project(theta, gi):
        return eqx.tree_at(lambda s: s.camera, sensor, cam.with_parameters(theta))(gi)

    j = jax.vmap(jax.jacfwd(project), in_axes=(None, 0))(cam.parameters(), g)  # (n, 2, P)
    jc = (j.reshape(-1, j.shape[-1]) @ cov).reshape(j.shape)
    sp = [jnp.sum(jc[:, a] * j[:, b], axis=-1) for a, b in ((0, 0), (0, 1), (1, 1))]
    pix = sensor(g)
    jg = jax.vmap(jax.jacfwd(sensor))(g)  # (n, 2, 3)
    return jnp.concatenate([pix.T, jnp.stack(sp), jg.reshape(-1, 6).T])


def _rpc_planes(sensor, g, cov):
    """As :func:`_frame_planes` for an RPC (:class:`photax.sensor.GroundSensor`): ``J = dp/dk`` ``(2, 6)``
    of its image-space correction ``k = (a0, a1, a2, b0, b1, b2)`` (``dc = a0 + a1 c + a2 r``, ``dr =
    b0 + b1 c + b2 r`` at the RPC's own pixel ``(c, r)``: :func:`photax.rpc.refine_rpc`), ``cov``
    ``(6, 6)``; ``dp/d(X, Y, Z)`` by ``jax.jacfwd`` through the map CRS -> lon, lat transformation."""
    rpc = sensor.camera
    llh = jnp.concatenate([sensor.to_lonlat(g[:, :2]), g[:, 2:3]], axis=-1)
    cr = rpc.uncorrected(llh)  # (n, 2)
    one, zero = jnp.ones(len(g)), jnp.zeros(len(g))
    j = jnp.stack(
        [
            jnp.stack([one, cr[:, 0], cr[:, 1], zero, zero, zero], -1),
            jnp.stack([zero, zero, zero, one, cr[:, 0], cr[:, 1]], -1),
        ],
        axis=1,
    )  # (n, 2, 6)
    jc = (j.reshape(-1, 6) @ cov).reshape(j.shape)
    sp = [jnp.sum(jc[:, a] * j[:, b], axis=-1) for a, b in ((0, 0), (0, 1), (1, 1))]
    pix = sensor(g)
    jg = jax.vmap(jax.jacfwd(sensor))(g)  # (n, 2, 3)
    return jnp.concatenate([pix.T, jnp.stack(sp), jg.reshape(-1, 6).T])


def _frame_planes(exterior, camera, g, cov):
    """At ground points ``g`` ``(n, 3)``: ``(11, n)`` planes, the pixel (2),
    ``S_p = J S J^T`` of the exterior and intrinsics (xx, xy, yy) and
    ``dp/d(X, Y, Z)`` (6, row-major 2 x 3), all in pixels; NaN behind the
    camera.  ``J = dp/d(theta, c)`` ``(2, 6 + n_c)`` (``(2, 14)`` for a
    ``"brown"`` camera) in closed form: the
    collinearity Jacobian (:func:`photax.collinearity.collinearity_jacobian`,
    the one bundle adjustment uses) and :func:`photax.camera.intrinsics_jacobian`,
    scaled to pixels (column right, row down); ``cov`` ``(6 + n_c, 6 + n_c)``."""
    axes = angle_axes(exterior.angles, exterior.convention)
    xy, jac, q = collinearity_jacobian(g, exterior.position, exterior.rotation, axes, camera)
    ji = intrinsics_jacobian(-q[:, :2] / q[:, 2:3], camera.focal_length, camera.distortion)
    s = jnp.stack([1.0 / camera.pixel_size[0], -1.0 / camera.pixel_size[1]])[None, :, None]
    j = jnp.concatenate([jac[:, :, :6], ji], axis=-1) * s  # (n, 2, 14)
    jg = jac[:, :, 6:] * s
    jc = (j.reshape(-1, j.shape[-1]) @ cov).reshape(j.shape)  # one (2n, 14) x (14, 14) product (brown)
    sp = [jnp.sum(jc[:, a] * j[:, b], axis=-1) for a, b in ((0, 0), (0, 1), (1, 1))]
    planes = jnp.concatenate([camera.image_to_pixel(xy).T, jnp.stack(sp), jg.reshape(-1, 6).T])
    return jnp.where((q[:, 2] < 0)[None], planes, jnp.nan)


def _finish(pix, sp, jg, sz, grad, z, image_size):
    """Planes ``(6, ...)``: ``S_p`` (xx, xy, yy) then ``S_g`` (xx, xy, yy), from the
    planes of the pixel ``(2, ...)``, the exterior/intrinsics ``S_p`` ``(3, ...)``,
    ``dp/d(X, Y, Z)`` ``(6, ...)`` (row-major 2 x 3), the DEM sigma, gradient
    ``(2, ...)`` and height.  Written out entry by entry: planes, not 2 x 2
    matrices in the last axes, vectorise on XLA:CPU."""
    j00, j01, j02, j10, j11, j12 = jg
    sxx = sp[0] + sz * sz * j02 * j02
    sxy = sp[1] + sz * sz * j02 * j12
    syy = sp[2] + sz * sz * j12 * j12
    # A = dp/d(X, Y) through the DEM: the image moves with the terrain's height.
    a00, a01 = j00 + j02 * grad[0], j01 + j02 * grad[1]
    a10, a11 = j10 + j12 * grad[0], j11 + j12 * grad[1]
    det = a00 * a11 - a01 * a10
    i00, i01, i10, i11 = a11 / det, -a01 / det, -a10 / det, a00 / det
    gxx = i00 * i00 * sxx + 2 * i00 * i01 * sxy + i01 * i01 * syy
    gxy = i00 * i10 * sxx + (i00 * i11 + i01 * i10) * sxy + i01 * i11 * syy
    gyy = i10 * i10 * sxx + 2 * i10 * i11 * sxy + i11 * i11 * syy
    w, h = image_size
    ok = jnp.isfinite(z) & (pix[0] >= -0.5) & (pix[0] <= w - 0.5) & (pix[1] >= -0.5) & (pix[1] <= h - 0.5)
    return jnp.where(ok[None], jnp.stack([sxx, sxy, syy, gxx, gxy, gyy]), jnp.nan)


def _dem_slope(dem, x, y):
    """Height (:meth:`photax.DEM.height`) and its gradient ``(2, ...)``: the
    derivative of the same bilinear interpolation, in closed form (8x cheaper
    than ``jax.linearize`` through ``DEM.height``, whose nodata handling
    dominates); 0 towards a nodata corner of weight 0, as ``DEM.height``'s."""
    z = dem.height(x, y)
    col, row = dem.ground_to_pixel(x, y)
    rows, cols = dem.heights.shape
    c0, r0 = jnp.clip(jnp.floor(col), 0, cols - 2), jnp.clip(jnp.floor(row), 0, rows - 2)
    tc, tr = col - c0, row - r0
    ci, ri = c0.astype(int), r0.astype(int)
    h = dem.heights
    h00, h01, h10, h11 = h[ri, ci], h[ri, ci + 1], h[ri + 1, ci], h[ri + 1, ci + 1]
    dc = (h01 - h00) * (1 - tr) + (h11 - h10) * tr  # dZ/dcol
    dr = (h10 - h00) * (1 - tc) + (h11 - h01) * tc  # dZ/drow
    a, b, _, d, e, _ = (dem.transform[i] for i in range(6))
    det = a * e - b * d
    grad = jnp.stack([(dc * e - dr * d) / det, (-dc * b + dr * a) / det])
    return z, jnp.where(jnp.isfinite(grad), grad, 0.0)


@eqx.filter_jit
def _propagate(sensor, dem, xy, cov, sigma_z):
    """Every point exactly: ``(n, 2)`` ground points -> ``(6, n)`` planes
    (see :func:`_finish`), NaN off the DEM, behind the camera or off the image."""
    z, grad = _dem_slope(dem, xy[:, 0], xy[:, 1])
    g = jnp.concatenate([xy, jnp.where(jnp.isfinite(z), z, 0.0)[:, None]], axis=-1)
    pl = _node_planes(sensor, g, cov)
    return _finish(pl[:2], pl[2:5], pl[5:], sigma_z, grad, z, sensor.image_size)


def _flat_terrain(planes):
    """Node planes (:func:`_node_planes`) -> ``(12, n)``: the pixel (2),
    ``S_p`` (3), ``J_z = dp/dZ`` (2), ``T = B S_p B^T`` (3) and ``u = B J_z``
    (2), with ``B = (dp/d(X, Y))^-1``: the ground covariance on flat terrain
    and the horizontal shift of the image point's ground position per metre
    of height.  Smooth in the ground position, so they are interpolated."""
    s0, s1, s2 = planes[2:5]
    j00, j01, j02, j10, j11, j12 = planes[5:]
    det = j00 * j11 - j01 * j10
    b00, b01, b10, b11 = j11 / det, -j01 / det, -j10 / det, j00 / det
    t0 = b00 * b00 * s0 + 2 * b00 * b01 * s1 + b01 * b01 * s2
    t1 = b00 * b10 * s0 + (b00 * b11 + b01 * b10) * s1 + b01 * b11 * s2
    t2 = b10 * b10 * s0 + 2 * b10 * b11 * s1 + b11 * b11 * s2
    u0, u1 = b00 * j02 + b01 * j12, b10 * j02 + b11 * j12
    return jnp.stack([planes[0], planes[1], s0, s1, s2, j02, j12, t0, t1, t2, u0, u1])


def _node_fields(planes, sz):
    """Node planes (:func:`_flat_terrain`) -> the float32 fields that are
    interpolated: the pixel (2), ``S_p`` (3), ``T`` (3), ``u`` (2) and, when
    the DEM sigma ``sz`` is per pixel (``sz`` None), ``J_z`` (2); with a
    scalar ``sz`` its terms ``sz^2 J_z J_z^T`` and ``sz^2 u u^T`` are smooth
    and added here, at the nodes."""
    px, py, s0, s1, s2, jz0, jz1, t0, t1, t2, u0, u1 = planes
    if sz is None:
        fields = (px, py, s0, s1, s2, t0, t1, t2, u0, u1, jz0, jz1)
    else:
        s2z = sz * sz
        fields = (
            px,
            py,
            s0 + s2z * jz0 * jz0,
            s1 + s2z * jz0 * jz1,
            s2 + s2z * jz1 * jz1,
            t0 + s2z * u0 * u0,
            t1 + s2z * u0 * u1,
            t2 + s2z * u1 * u1,
            u0,
            u1,
        )
    return jnp.stack(fields).astype(jnp.float32)


@eqx.filter_jit
def _lattice(sensor, dem, transform, cov, sz, zfill, step, shape):
    """The exact propagation (float64) on the nodes every ``step`` pixels of
    a grid padded to ``shape`` (multiples of ``step``), node ``(i, j)`` at
    pixel centre ``(step i, step j)``, then its fields (:func:`_node_fields`,
    float32) interpolated along the lattice rows to every column: ``(k,
    shape[0] / step + 1, shape[1])``, 1/step of the pixels (what
    :func:`_tile` interpolates between).  Off the DEM the nodes take the
    height ``zfill`` (the pixels there are NaN anyway)."""
    a, b, xoff, d, e, yoff = (transform[i] for i in range(6))
    r = step * jnp.arange(shape[0] // step + 1, dtype=float) + 0.5
    c = step * jnp.arange(shape[1] // step + 1, dtype=float) + 0.5
    xn, yn = xoff + a * c[None, :] + b * r[:, None], yoff + d * c[None, :] + e * r[:, None]
    zn = dem.height(xn, yn)
    g = jnp.stack([xn, yn, jnp.where(jnp.isfinite(zn), zn, zfill)], axis=-1).reshape(-1, 3)
    n = _node_fields(_flat_terrain(_node_planes(sensor, g, cov)), sz).reshape(-1, *xn.shape)
    f = jnp.arange(step, dtype=jnp.float32) / step
    return (n[:, :, :-1, None] + (n[:, :, 1:, None] - n[:, :, :-1, None]) * f[None, None, None, :]).reshape(
        *n.shape[:2], shape[1]
    )


def _between_rows(along, step):
    """``(mr + 1, cols)`` values on lattice rows -> ``(mr step, cols)``,
    linear between them, as broadcasts (no gathers; fused into the consumer)."""
    f = jnp.arange(step, dtype=jnp.float32) / step
    top = along[:-1, None, :]
    return (top + (along[1:, None, :] - top) * f[None, :, None]).reshape(-1, along.shape[1])


def _slope_rows(heights, dem_transform, transform, r0, shape, window):
    """What :func:`_strip` needs of the DEM for a strip of whole rows of a
    grid whose axes are the DEM's (both transforms without rotation terms),
    in numpy: the DEM column of a pixel depends on its column only and the
    DEM row on its row only, so the bilinear slopes are interpolated along
    the columns here, for the ``window`` DEM rows the strip sees (small
    arrays), and between those rows in the program, where each pixel row
    reads its two DEM rows (cheap gathers from a small, cached array).  Same
    values as :func:`_dem_slope` (``dZ/dX`` linear in the row fraction,
    ``dZ/dY`` in the column fraction; both 0 where a corner is nodata) and
    the same nodata rule as :meth:`photax.DEM.height`.  Returns float32
    ``(window, cols)`` ``dZ/dX`` on the DEM rows, ``(window - 1, cols)``
    ``dZ/dY`` between them, ``(rows,)`` each pixel row's DEM row in the
    window and fraction, the rows and columns inside the DEM's centres and,
    with nodata, ``(window, cols)`` "blocked along this DEM row" (a corner
    of non-zero weight is NaN), else None."""
    a, _, xoff, _, e, yoff = transform
    da, _, dxoff, _, de, dyoff = dem_transform
    nr, nc = heights.shape
    col = (xoff + a * (np.arange(shape[1]) + 0.5) - dxoff) / da - 0.5
    row = (yoff + e * (r0 + np.arange(shape[0]) + 0.5) - dyoff) / de - 0.5
    ci = np.clip(np.floor(col), 0, nc - 2)
    ri = np.clip(np.floor(row), 0, nr - 2)
    tc, tr = col - ci, row - ri
    ci, ri = ci.astype(int), ri.astype(int)
    start = int(np.clip(ri.min(), 0, nr - window))
    hw = heights[start : start + window]
    dx = (np.diff(hw, axis=1) / da)[:, ci].astype(np.float32)
    dy = np.diff(hw, axis=0) / de
    dy = (dy[:, ci] * (1 - tc) + dy[:, ci + 1] * tc).astype(np.float32)
    nan = np.isnan(hw)
    blocked = (nan[:, ci] & (tc != 1)) | (nan[:, ci + 1] & (tc != 0)) if nan.any() else None
    return (
        dx,
        dy,
        (ri - start).astype(np.int32),
        tr.astype(np.float32),
        (row >= 0) & (row <= nr - 1),
        (col >= 0) & (col <= nc - 1),
        blocked,
    )


def _separable_slope(rows):
    """The DEM's validity ``(rows, cols)`` and gradient (float32) at every
    pixel of a strip from :func:`_slope_rows`."""
    dx, dy, ri, tr, in_rows, in_cols, blocked = rows
    trc = tr[:, None]
    gx = dx[ri] + (dx[ri + 1] - dx[ri]) * trc
    gy = dy[ri]
    ok = in_rows[:, None] & in_cols[None, :]
    if blocked is None:
        return ok, gx, gy
    blocked = (blocked[ri] & (trc != 1)) | (blocked[ri + 1] & (trc != 0))
    finite = jnp.isfinite(gx) & jnp.isfinite(gy)
    return ok & ~blocked, jnp.where(finite, gx, 0.0), jnp.where(finite, gy, 0.0)


@functools.partial(jax.jit, static_argnames=("image_size", "step"))  # (eqx.filter_jit: 1.5 ms more a call)
def _effective_slope(along, image_size, dem, transform, r0, step, rows):
    """``h = g / (1 + g.u)`` (two float32 planes), NaN where the ortho has
    no data (off the DEM or the image), for a strip of whole rows from row
    ``r0`` with its rows of lattice fields ``along`` (:func:`_lattice`):
    ``g`` the DEM's gradient at every pixel, from ``rows``
    (:func:`_slope_rows`) when the grid's axes are the DEM's, else by
    :func:`_dem_slope`.  A program of its own, so that these planes are
    made once: fused into :func:`_strip`, XLA:CPU recomputes them in every
    output plane's loop."""
    px, py, u0, u1 = (_between_rows(along[k], step) for k in (0, 1, 8, 9))
    shape = px.shape
    if rows is not None:
        okz, g0, g1 = _separable_slope(rows)
    else:
        a, b, xoff, d, e, yoff = (transform[i] for i in range(6))
        r, c = r0 + jnp.arange(shape[0], dtype=float) + 0.5, jnp.arange(shape[1], dtype=float) + 0.5
        z, grad = _dem_slope(dem, xoff + a * c[None, :] + b * r[:, None], yoff + d * c[None, :] + e * r[:, None])
        okz, g0, g1 = jnp.isfinite(z), grad[0].astype(jnp.float32), grad[1].astype(jnp.float32)
    w, h = image_size
    ok = okz & (px >= -0.5) & (px <= w - 0.5) & (py >= -0.5) & (py <= h - 0.5)
    k = jnp.where(ok, 1.0 / (1.0 + g0 * u0 + g1 * u1), jnp.nan)
    return k * g0, k * g1


@functools.partial(jax.jit, static_argnames=("step", "want"))
def _strip(along, slope, sz, step, want):
    """One strip's covariances (float32 planes), from its rows of lattice
    fields ``along`` (:func:`_lattice`), bilinear between them, and its
    effective slope ``h = g / (1 + g.u)`` (:func:`_effective_slope`, NaN
    where the ortho has no data); the DEM sigma ``sz`` per pixel when it is
    an array.  With ``T' = T + sz^2 u u^T``, ``S_g = M T' M^T`` and ``M = I
    - u h^T`` (module docstring) is

        S_g = T' - (u q^T + q u^T) + (h.q) u u^T,   q = T' h

    (no division).  Returns a tuple: ``S_p`` (xx, xy, yy) if ``want`` has
    "image", then ``S_g`` if it has "ground"; NaN where the ortho has no
    data."""
    h0, h1 = slope
    px, py, s0, s1, s2, t0, t1, t2, u0, u1 = (_between_rows(along[k], step) for k in range(10))
    if sz.ndim:  # per pixel: the DEM sigma's terms here
        jz0, jz1 = _between_rows(along[10], step), _between_rows(along[11], step)
        s2z = sz * sz
        s0, s1, s2 = s0 + s2z * jz0 * jz0, s1 + s2z * jz0 * jz1, s2 + s2z * jz1 * jz1
        t0, t1, t2 = t0 + s2z * u0 * u0, t1 + s2z * u0 * u1, t2 + s2z * u1 * u1
    planes = []
    if "image" in want:
        nan = 0 * h0  # NaN where the ortho has no data
        planes += [s0 + nan, s1 + nan, s2 + nan]
    if "ground" in want:
        q0, q1 = t0 * h0 + t1 * h1, t1 * h0 + t2 * h1
        w = h0 * q0 + h1 * q1
        planes += [
            t0 - 2 * u0 * q0 + w * u0 * u0,
            t1 - (u0 * q1 + q0 * u1) + w * u0 * u1,
            t2 - 2 * u1 * q1 + w * u1 * u1,
        ]
    return tuple(planes)


def _matrix(var: np.ndarray) -> np.ndarray:
    return np.stack([np.stack([var[0], var[1]], -1), np.stack([var[1], var[2]], -1)], -2)


def _ellipse(var: np.ndarray) -> np.ndarray:
    """``(3, ...)`` (s_xx, s_xy, s_yy) -> ``(3, ...)`` semi-major, semi-minor
    (1 sigma) and the major axis' angle from the first axis towards the
    second (radians, in (-pi/2, pi/2])."""
    sxx, sxy, syy = var
    t, d = 0.5 * (sxx + syy), np.hypot(0.5 * (sxx - syy), sxy)
    return np.stack([np.sqrt(t + d), np.sqrt(np.maximum(t - d, 0.0)), 0.5 * np.arctan2(2 * sxy, sxx - syy)])


@dataclasses.dataclass(frozen=True)
class OrthoUncertainty:
    """Geolocation uncertainty of every pixel of an ortho grid.

    Attributes:
        grid: the grid the rasters belong to (the ortho's, or coarser).
        image_var: ``(3, rows, cols)`` variances and covariance ``(s_cc,
            s_cr, s_rr)`` of the image position ``(col, row)`` read for each
            ortho pixel, pixels^2.
        ground_var: ``(3, rows, cols)`` ``(s_XX, s_XY, s_YY)`` of the ground
            position each ortho pixel shows, ground units^2.
        NaN where the ortho has no data (off the DEM or the image);
        float32 (float64 from ``step=1``).

    Examples:
        :func:`photax.ortho_uncertainty`'s vertical frame with a DEM good to 2 m: a height error
        moves a ground point only along the ray, so each error ellipse is a line pointing away from
        the nadir, ``2 r / H`` long (1 sigma):

        >>> import numpy as np
        >>> import photax as ptx
        >>> flat = ptx.relief_scene(0.0, seed=1, image_size=(400, 300), focal_px=400.0, tilt_deg=0.0)
        >>> grid = ptx.Grid(flat.ortho_transform, flat.ortho.shape)
        >>> u = ptx.ortho_uncertainty(flat.exterior, np.zeros((6, 6)), flat.camera, flat.dem, grid,
        ...                           dem_sigma=2.0, coarsen=8, step=1)
        >>> major, minor, angle = u.ground_ellipse
        >>> rows, cols = np.indices(u.grid.shape)
        >>> x, y = u.grid.transform * (cols + 0.5, rows + 0.5)
        >>> x0, y0, height = np.asarray(flat.exterior.position)
        >>> seen = np.isfinite(major) & (np.hypot(x - x0, y - y0) > 50)  # the angle is the nadir's only off it
        >>> bool(np.allclose(major[seen], 2.0 * np.hypot(x - x0, y - y0)[seen] / height)), bool(np.nanmax(minor) < 1e-6)
        (True, True)
        >>> turn = np.angle(np.exp(2j * (angle - np.arctan2(y - y0, x - x0))))  # an axis: modulo 180 deg
        >>> bool(np.abs(turn[seen]).max() < 1e-9)
        True
        >>> list(u.to_xarray().data_vars)[:3]
        ['ground_sigma', 'sigma_x', 'sigma_y']
    """

    grid: Grid
    image_var: np.ndarray
    ground_var: np.ndarray

    @property
    def image_cov(self) -> np.ndarray:
        """``(rows, cols, 2, 2)`` covariance of ``(col, row)``, pixels^2."""
        return _matrix(self.image_var)

    @property
    def ground_cov(self) -> np.ndarray:
        """``(rows, cols, 2, 2)`` covariance of ``(X, Y)``, ground units^2."""
        return _matrix(self.ground_var)

    @property
    def image_std(self) -> np.ndarray:
        """``(2, rows, cols)`` std of the column and the row, pixels."""
        return np.sqrt(self.image_var[::2])

    @property
    def ground_std(self) -> np.ndarray:
        """``(2, rows, cols)`` std of X and Y, ground units."""
        return np.sqrt(self.ground_var[::2])

    @property
    def ground_sigma(self) -> np.ndarray:
        """``(rows, cols)`` horizontal position error ``sqrt(s_X^2 + s_Y^2)``
        (the radial RMS error), ground units: the map to show."""
        return np.sqrt(self.ground_var[0] + self.ground_var[2])

    @property
    def image_ellipse(self) -> np.ndarray:
        """``(3, rows, cols)`` semi-major, semi-minor axis (1 sigma, pixels)
        and angle of the major axis from the column axis towards the row
        axis (radians)."""
        return _ellipse(self.image_var)

    @property
    def ground_ellipse(self) -> np.ndarray:
        """``(3, rows, cols)`` semi-major, semi-minor axis (1 sigma, ground
        units) and angle of the major axis from east towards north
        (radians)."""
        return _ellipse(self.ground_var)

    def to_xarray(self):
        """An ``xarray.Dataset`` of the std rasters and ellipses on
        :attr:`grid`, georeferenced the rioxarray way."""
        import xarray as xr

        from .io.lazy import dataarray

        fill = np.asarray(np.nan)
        layers = {
            "ground_sigma": self.ground_sigma,
            "sigma_x": self.ground_std[0],
            "sigma_y": self.ground_std[1],
            "ground_major": self.ground_ellipse[0],
            "ground_minor": self.ground_ellipse[1],
            "ground_angle": self.ground_ellipse[2],
            "sigma_col": self.image_std[0],
            "sigma_row": self.image_std[1],
        }
        return xr.Dataset({k: dataarray(v, self.grid, fill, k) for k, v in layers.items()})


def _coarse(grid: Grid, factor: int) -> Grid:
    if factor == 1:
        return grid
    from rasterio import Affine

    shape = tuple(-(-n // factor) for n in grid.shape)
    return Grid(grid.transform * Affine.scale(factor), shape, grid.crs)


def ortho_uncertainty(
    exterior,
    covariance,
    camera=None,
    dem: DEM | None = None,
    grid: Grid | None = None,
    *,
    camera_covariance=None,
    dem_sigma=0.0,
    coarsen: int = 1,
    step: int = 16,
    image: int = 0,
) -> OrthoUncertainty:
    """Per-pixel standard deviations and error ellipses of an ortho's geolocation:
    ``ortho_uncertainty(sensor, covariance, dem, grid, ...)`` for any :class:`photax.sensor.Sensor`
    (``covariance`` that of its kind, below; the grid in the sensor's CRS), or the older
    ``(exterior, covariance, camera, dem, grid, ...)``.

    First-order propagation (module docstring) of the exterior orientation's
    covariance, the intrinsics' and the DEM's height error to the image
    position read for each ortho pixel and to the ground position it shows.

    Args:
        exterior: the image's :class:`photax.ExteriorOrientation`, or a
            :class:`photax.ResectionResult` (its orientation and covariance),
            or a :class:`photax.BundleResult` (image ``image``: its
            ``orientation_cov`` block, exterior and self-calibrated
            intrinsics with their correlations; give ``camera`` as that
            image's adjusted camera).
        covariance: ``(6, 6)`` covariance of ``(X0, Y0, Z0, a1, a2, a3)``
            (metres, radians; angles in the exterior's convention order), or
            ``(14, 14)`` of those and the intrinsics ``(f, x0, y0, k1, k2,
            k3, p1, p2)`` jointly (:attr:`photax.BundleResult.orientation_cov`;
            ``6 + n`` square with the ``n`` intrinsics of another distortion
            model, :attr:`photax.FrameCamera.intrinsic_names`),
            or None when ``exterior`` is a result.
        camera: the interior orientation (pixel grid required).
        dem: the DEM the ortho was made with.
        grid: the ortho's grid.
        camera_covariance: ``(8, 8)`` covariance of ``(f, x0, y0, k1, k2,
            k3, p1, p2)`` (or ``(3, 3)`` of ``f, x0, y0``), image-plane units;
            another distortion model's: ``n x n`` of the camera's
            ``intrinsic_names``; default none (fixed intrinsics).
        dem_sigma: std of the DEM heights, metres: a scalar or an array of
            the (coarsened) grid's shape.
        coarsen: compute on a grid ``coarsen`` times coarser (pixel size x
            ``coarsen``, same origin): the fields are smooth.
        step: the propagation is exact every ``step`` pixels and
            interpolated bilinearly in between (relative error of the stds
            below ``2 (s / H)^2``, ``s`` the lattice spacing on the ground and
            ``H`` the flying height: module docstring), while the DEM's
            slope and sigma enter at every pixel; ``step=1``: everything at
            every pixel (~20x slower).
        image: which image of a bundle result.

    An RPC (a satellite image): ``exterior`` None and ``camera`` an :class:`photax.rpc.RPCCamera`
    with ``covariance`` the ``(6, 6)`` covariance of its image-space correction ``(a0, a1, a2, b0, b1,
    b2)`` (pixels; zeros for an unrefined RPC, whose bias is unknown), or ``exterior`` a
    :class:`photax.rpc.RPCRefinement` (its camera and covariance; ``camera`` None). The grid may be
    in any projected CRS, the DEM in the grid's. A push-broom image: ``exterior`` None and ``camera`` a
    :class:`photax.PushbroomCamera` with ``covariance`` the ``(P, P)`` one of all its orbit and
    attitude coefficients (:attr:`~photax.PushbroomCamera.parameter_names`, m and rad), or ``exterior``
    a :class:`photax.PushbroomResection` (its adjusted camera; its covariance of the parameters it
    adjusted, the others held exact; ``camera`` None); the Jacobians by ``jax.jacfwd``.

    Returns:
        :class:`OrthoUncertainty`, float32 rasters (float64 with ``step=1``).

    Examples:
        A vertical frame over flat land with an exact orientation and a DEM good to 2 m: a height
        error ``dh`` moves the ground point a pixel shows by ``r dh / H`` (``r`` its distance from
        the nadir, ``H`` the flying height), which the propagation reproduces:

        >>> import numpy as np
        >>> import photax as ptx
        >>> flat = ptx.relief_scene(0.0, seed=1, image_size=(400, 300), focal_px=400.0, tilt_deg=0.0)
        >>> grid = ptx.Grid(flat.ortho_transform, flat.ortho.shape)
        >>> u = ptx.ortho_uncertainty(flat.exterior, np.zeros((6, 6)), flat.camera, flat.dem, grid,
        ...                           dem_sigma=2.0, coarsen=8, step=1)
        >>> rows, cols = np.indices(u.grid.shape)
        >>> x, y = u.grid.transform * (cols + 0.5, rows + 0.5)  # the (coarsened) pixel centres
        >>> x0, y0, height = np.asarray(flat.exterior.position)
        >>> expected = 2.0 * np.hypot(x - x0, y - y0) / height
        >>> seen = np.isfinite(u.ground_sigma)  # NaN off the image
        >>> bool(np.allclose(u.ground_sigma[seen], expected[seen], atol=1e-6))
        True
    """
    # Over 80 lines because the docstring documents every argument; the body is ~55 lines.
    if is_sensor(exterior):
        exterior, camera, dem, grid, _ = sensor_arguments(exterior, (camera, dem, grid))
        if exterior is None:  # a ground sensor: its camera, in the grid's CRS (checked the sensor's)
            camera = camera.camera
        if grid is None:
            raise TypeError("ortho_uncertainty(sensor, covariance, dem, grid): give the ortho's grid")
    ground_kinds = (RPCRefinement, PushbroomResection)
    kind = camera_kind(camera)
    if not isinstance(exterior, ground_kinds) and kind is None:
        raise ValueError(
            f"ortho_uncertainty: a frame camera, an RPC or a push-broom model, not a {type(camera).__name__}"
        )
    check_dem(dem, grid)
    if isinstance(exterior, PushbroomResection) or kind == "pushbroom":
        sensor, joint = _pushbroom(exterior, covariance, camera, grid)
        if camera_covariance is not None:
            raise ValueError("camera_covariance: give a push-broom model's in covariance (over its parameters)")
    elif isinstance(exterior, RPCRefinement) or kind == "rpc":
        sensor, joint = _rpc(exterior, covariance, camera, grid)
        if camera_covariance is not None:
            raise ValueError("camera_covariance: an RPC has no intrinsics (its covariance is the correction's)")
    else:
        sensor, joint = _frame(exterior, covariance, camera, camera_covariance, image)
    if not isinstance(grid, Grid):
        raise ValueError(f"grid must be a photax Grid, got {type(grid).__name__}")
    if int(coarsen) < 1:
        raise ValueError(f"coarsen must be a positive integer, got {coarsen!r}")
    if int(step) < 1:
        raise ValueError(f"step must be a positive integer, got {step!r}")
    step = int(step)
    grid = _coarse(grid, int(coarsen))
    sz = np.asarray(dem_sigma, dtype=float)
    if sz.shape not in ((), grid.shape) or not np.all(sz >= 0):
        raise ValueError(f"dem_sigma must be >= 0, a scalar or of shape {grid.shape}")
    scalar_sz = sz.shape == ()
    sz = np.broadcast_to(sz, grid.shape)
    rows, cols = grid.shape
    args = (sensor, dem)
    covs = (jnp.asarray(joint),)
    if step == 1:  # every pixel exactly, in blocks of one shape
        xy, sz = grid.xy().reshape(-1, 2), sz.reshape(-1)
        n = xy.shape[0]
        block = min(_BLOCK, 1 << (n - 1).bit_length())
        out = np.empty((6, n))
        for s in range(0, n, block):
            e = min(s + block, n)
            p = np.concatenate([xy[s:e], np.repeat(xy[:1], block - (e - s), axis=0)])
            z = np.concatenate([sz[s:e], np.zeros(block - (e - s))])
            out[:, s:e] = np.asarray(_propagate(*args, jnp.asarray(p), *covs, jnp.asarray(z)))[:, : e - s]
        out = out.reshape(6, rows, cols)
        return OrthoUncertainty(grid, out[:3], out[3:])

    # Strips of whole rows, of one padded shape (one compilation), about
    # _STRIP pixels each, copied out (measured cheaper than XLA filling a
    # fresh buffer for them to be written into in place).
    def up(a, b):  # ceil(a / b)
        return -(-a // b)

    cols_p = up(cols, step) * step
    th = up(up(rows, up(rows * cols_p, _STRIP)), step) * step
    rows_p = up(rows, th) * th
    heights = np.asarray(dem.heights)
    zfill = jnp.asarray(float(np.nanmean(heights)) if np.isfinite(heights).any() else 0.0)
    transform = jnp.asarray(tuple(grid.transform)[:6])
    along = np.asarray(
        _lattice(
            sensor,
            dem,
            transform,
            *covs,
            jnp.asarray(sz[0, 0]) if scalar_sz else None,
            zfill,
            step,
            (rows_p, cols_p),
        )
    )
    window = _dem_window(grid, dem, th)
    dem_t = tuple(float(v) for v in np.asarray(dem.transform))
    z0 = jnp.asarray(np.float32(sz[0, 0]))
    out = np.empty((6, rows_p, cols_p), dtype=np.float32)

    def one(r0):
        z = z0
        if not scalar_sz:
            z = np.zeros((th, cols_p), dtype=np.float32)
            z[: min(th, rows - r0), :cols] = sz[r0 : r0 + th]
        a = jnp.asarray(along[:, r0 // step : (r0 + th) // step + 1])
        srows = (
            None if window is None else _slope_rows(heights, dem_t, tuple(grid.transform)[:6], r0, (th, cols_p), window)
        )
        slope = _effective_slope(a, sensor.image_size, dem, transform, np.asarray(float(r0)), step, srows)
        for k, plane in enumerate(_strip(a, slope, jnp.asarray(z), step, ("image", "ground"))):
            out[k, r0 : r0 + th] = plane

    from concurrent.futures import ThreadPoolExecutor

    from .resampling import THREADS

    strips = range(0, rows, th)
    with ThreadPoolExecutor(max(1, min(THREADS, len(strips)))) as pool:  # XLA and copies release the GIL
        list(pool.map(one, strips))
    out = out[:, :rows, :cols]
    return OrthoUncertainty(grid, out[:3], out[3:])


def _dem_window(grid: Grid, dem: DEM, rows: int) -> int | None:
    """DEM rows a tile of ``rows`` grid rows reads when the grid's and the
    DEM's axes coincide (:func:`_separable_slope`), else None."""
    a, b, _, d, e, _ = tuple(grid.transform)[:6]
    da, db, _, dd, de, _ = (float(v) for v in np.asarray(dem.transform))
    if b != 0 or d != 0 or db != 0 or dd != 0:
        return None
    return int(min(dem.heights.shape[0], np.ceil(rows * abs(e / de)) + 3))


def _frame(exterior, covariance, camera, camera_covariance, image):
    """A frame's sensor and ``(6 + n, 6 + n)`` joint covariance of its exterior and ``n`` intrinsics."""
    exterior, covariance = _orientation(exterior, covariance, image)
    if camera_kind(camera) != "frame" or camera.image_size is None or camera.pixel_size is None:
        raise ValueError("camera must have a pixel grid (pixel_size and image_size)")
    cov = np.asarray(covariance, dtype=float)
    n_intr = len(camera.intrinsic_names)
    n_all = 6 + n_intr  # exterior then intrinsics: the joint covariance's size
    if cov.shape not in ((6, 6), (n_all, n_all)) or not np.all(np.isfinite(cov)):
        raise ValueError(f"covariance must be a finite (6, 6) or ({n_all}, {n_all}) matrix, got shape {cov.shape}")
    if np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < -1e-12 * max(np.abs(cov).max(), 1e-300):
        raise ValueError("covariance must be symmetric positive semi-definite")
    joint = np.zeros((n_all, n_all))
    joint[: cov.shape[0], : cov.shape[0]] = cov
    if camera_covariance is not None:
        c = np.asarray(camera_covariance, dtype=float)
        if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] not in (3, n_intr):
            raise ValueError(f"camera_covariance must be ({n_intr}, {n_intr}) or (3, 3), got shape {c.shape}")
        if cov.shape == (n_all, n_all):
            raise ValueError(
                f"camera_covariance must be None when covariance is ({n_all}, {n_all}) (it holds the intrinsics)"
            )
        joint[6 : 6 + c.shape[0], 6 : 6 + c.shape[0]] = c
    return FrameSensor(exterior, camera), joint


def _rpc(refinement, covariance, camera, grid):
    """An RPC's sensor (in the grid's CRS) and the ``(6, 6)`` covariance of its correction."""
    if isinstance(refinement, RPCRefinement):
        terms = {"shift": [0], "shift-drift": [0, 2], "affine": [0, 1, 2]}[refinement.model]
        adjusted = terms + [3 + t for t in terms]
    else:
        adjusted = None
    return _ground_sensor(
        refinement, RPCRefinement, "refinement", adjusted, covariance, camera, grid,
        names=("a0", "a1", "a2", "b0", "b1", "b2"), what="an RPC's", of="its correction",
    )  # fmt: skip


def _pushbroom(resection, covariance, camera, grid):
    """A push-broom model's sensor (in the grid's CRS) and the ``(P, P)`` covariance of all its
    parameters (:attr:`photax.PushbroomCamera.parameter_names`): a resection's covariance of those it
    adjusted, zeros for those it held."""
    names = (resection.camera if isinstance(resection, PushbroomResection) else camera).parameter_names
    adjusted = [names.index(p) for p in resection.parameters] if isinstance(resection, PushbroomResection) else None
    return _ground_sensor(
        resection, PushbroomResection, "resection", adjusted, covariance, camera, grid,
        names=tuple(names), what="a push-broom model's", of="its parameters",
    )  # fmt: skip


def _ground_sensor(result, kind, noun, adjusted, covariance, camera, grid, *, names, what, of):
    """A ground camera's sensor and the covariance of its ``names``: ``covariance`` when given, else
    ``result``'s (a ``kind``: its camera, its covariance of the parameters ``adjusted``, zeros for the
    rest); every covariance checked finite, of the right size and positive semi-definite."""
    n = len(names)
    if isinstance(result, kind):
        if camera is not None and camera is not result.camera:
            raise ValueError(f"camera: give None with a {kind.__name__} (its camera is used)")
        camera = result.camera
        if covariance is None:
            if not np.all(np.isfinite(result.covariance)):
                raise ValueError(f"the {noun} has no finite covariance (no redundancy)")
            cov = np.zeros((n, n))
            cov[np.ix_(adjusted, adjusted)] = result.covariance
        else:
            cov = np.asarray(covariance, dtype=float)
    elif result is not None:
        raise ValueError(f"exterior: None or a {kind.__name__} with this camera (it carries its own orientation)")
    else:
        cov = np.asarray(covariance, dtype=float) if covariance is not None else None
    if cov is None or cov.shape != (n, n) or not np.all(np.isfinite(cov)):
        got = None if cov is None else cov.shape
        raise ValueError(f"covariance: {what} is the finite ({n}, {n}) one of {of} ({', '.join(names)}), got {got}")
    if np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < -1e-12 * max(np.abs(cov).max(), 1e-300):
        raise ValueError("covariance must be symmetric positive semi-definite")
    if getattr(camera, "image_size", 0) is None:
        raise ValueError("the camera must have an image_size")
    return GroundSensor(camera, grid.crs), cov


def _orientation(exterior, covariance, image: int):
    if isinstance(exterior, ExteriorOrientation):
        if covariance is None:
            raise ValueError("covariance is required with an ExteriorOrientation")
        if exterior.position.shape != (3,):
            raise ValueError(f"exterior must be one orientation, got position shape {exterior.position.shape}")
        return exterior, covariance
    if hasattr(exterior, "exterior_std"):  # a BundleResult
        if exterior.exterior_std is None:
            raise ValueError("this bundle result has no exterior precision (gauge='damped')")
        eo = exterior.exterior
        one = ExteriorOrientation(np.asarray(eo.position)[image], np.asarray(eo.angles)[image], eo.convention)
        if covariance is None:
            block = getattr(exterior, "orientation_cov", None)  # exterior + intrinsics, correlated
            covariance = (
                np.asarray(block)[image]
                if block is not None
                else np.diag(np.asarray(exterior.exterior_std)[image] ** 2)
            )
        return one, covariance
    if hasattr(exterior, "covariance") and hasattr(exterior, "exterior"):  # a ResectionResult
        cov = exterior.covariance if covariance is None else covariance
        if cov is None or not np.all(np.isfinite(np.asarray(cov, dtype=float))):
            raise ValueError("the resection result has no finite covariance (zero redundancy?)")
        return exterior.exterior, cov
    raise ValueError(
        f"exterior must be an ExteriorOrientation, a ResectionResult or a BundleResult, got {type(exterior).__name__}"
    )
