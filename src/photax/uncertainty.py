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

    J_t = dp/dtheta (2x6),  J_c = dp/dc (2x8),  J_z = dp/dZ (2x1),
    A   = dp/d(X, Y) (2x2, the total derivative through the DEM's slope),

the error of the image position read for the pixel is, to first order
(law of propagation of variances, e.g. Mikhail, Bethel & McGlone 2001,
ch. 2; Förstner & Wrobel 2016, sec. 2.7),

    S_p = J_t S_t J_t^T + J_c S_c J_c^T + s_z^2 J_z J_z^T        (pixels^2)

and the ground point whose grey value the pixel actually shows is off by
``dg = -A^-1 dp`` (the ray through ``p`` meets the DEM elsewhere), so

    S_g = A^-1 S_p A^-T                                          (metres^2).

Cost: ``J`` and ``S_p`` vary smoothly with the ground position, so they are
computed exactly on a lattice every ``step`` output pixels (on the DEM) and
interpolated bilinearly in between, in the form ``S_p``, ``J_z``, ``T = B S_p
B^T`` and ``u = B J_z`` (``B = (dp/d(X, Y))^-1`` on flat terrain); at every
pixel only the DEM's slope ``g`` enters, by Sherman-Morrison
``A^-1 = (I - u g^T / (1 + g.u)) B``.  Interpolation error: the entries vary
on the scale of the flying height ``H`` above the terrain, so the relative
error of every standard deviation is about ``(s / H)^2`` for a lattice
spacing ``s`` on the ground (measured below ``2 (s / H)^2``, and tested).
With ``step=16`` on a 10 cm ortho from 1000 m that is 3e-6.

Error ellipses (1 sigma) are the eigen-decompositions of these 2x2
covariances: semi-axes ``sqrt(l1) >= sqrt(l2)`` and the major axis' angle.
No occlusion and no misregistration of the image itself are modelled.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .camera import FrameCamera, intrinsics_jacobian
from .collinearity import ExteriorOrientation, angle_axes, collinearity_jacobian
from .dem import DEM
from .rectification._grid import Grid

_BLOCK = 1 << 14  # points per jitted call (padded): one compilation, bounded memory
_STRIP = 1 << 15  # pixels per strip: its float64 planes stay in cache (measured 3x faster than 1 << 19)
_N_INTRINSICS = 8
_N = 6 + _N_INTRINSICS  # exterior then intrinsics: the joint covariance's size


def _node_planes(exterior, camera, g, cov):
    """At ground points ``g`` ``(n, 3)``: ``(11, n)`` planes, the pixel (2),
    ``S_p = J S J^T`` of the exterior and intrinsics (xx, xy, yy) and
    ``dp/d(X, Y, Z)`` (6, row-major 2 x 3), all in pixels; NaN behind the
    camera.  ``J = dp/d(theta, c)`` ``(2, 14)`` in closed form: the
    collinearity Jacobian (:func:`photax.collinearity.collinearity_jacobian`,
    the one bundle adjustment uses) and :func:`photax.camera.intrinsics_jacobian`,
    scaled to pixels (column right, row down); ``cov`` ``(14, 14)``."""
    axes = angle_axes(exterior.angles, exterior.convention)
    xy, jac, q = collinearity_jacobian(g, exterior.position, exterior.rotation, axes, camera)
    ji = intrinsics_jacobian(-q[:, :2] / q[:, 2:3], camera.focal_length, camera.distortion)
    s = jnp.stack([1.0 / camera.pixel_size[0], -1.0 / camera.pixel_size[1]])[None, :, None]
    j = jnp.concatenate([jac[:, :, :6], ji], axis=-1) * s  # (n, 2, 14)
    jg = jac[:, :, 6:] * s
    jc = (j.reshape(-1, _N) @ cov).reshape(j.shape)  # one (2n, 14) x (14, 14) product
    sp = [jnp.sum(jc[:, a] * j[:, b], axis=-1) for a, b in ((0, 0), (0, 1), (1, 1))]
    planes = jnp.concatenate([camera.image_to_pixel(xy).T, jnp.stack(sp), jg.reshape(-1, 6).T])
    return jnp.where((q[:, 2] < 0)[None], planes, jnp.nan)


def _finish(pix, sp, jg, sz, grad, z, camera):
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
    w, h = camera.image_size
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
def _propagate(exterior, camera, dem, xy, cov, sigma_z):
    """Every point exactly: ``(n, 2)`` ground points -> ``(6, n)`` planes
    (see :func:`_finish`), NaN off the DEM, behind the camera or off the image."""
    z, grad = _dem_slope(dem, xy[:, 0], xy[:, 1])
    g = jnp.concatenate([xy, jnp.where(jnp.isfinite(z), z, 0.0)[:, None]], axis=-1)
    pl = _node_planes(exterior, camera, g, cov)
    return _finish(pl[:2], pl[2:5], pl[5:], sigma_z, grad, z, camera)


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


def _finish_flat(f, sz, grad, z, camera):
    """:func:`_finish` from the planes of :func:`_flat_terrain`: with the
    DEM's sigma ``sz`` and gradient ``g``, ``S_p' = S_p + sz^2 J_z J_z^T``
    and, as ``A = dp/d(X, Y) = B^-1 (I + u g^T)`` (the image moves with the
    terrain's height), ``A^-1 = M B`` with ``M = I - u g^T / (1 + g.u)``
    (Sherman-Morrison), ``S_g = M (T + sz^2 u u^T) M^T``: a few flops per
    pixel on top of the interpolation."""
    s2z = sz * sz
    jz0, jz1, u0, u1 = f[5], f[6], f[10], f[11]
    sxx, sxy, syy = f[2] + s2z * jz0 * jz0, f[3] + s2z * jz0 * jz1, f[4] + s2z * jz1 * jz1
    txx, txy, tyy = f[7] + s2z * u0 * u0, f[8] + s2z * u0 * u1, f[9] + s2z * u1 * u1
    den = 1.0 + grad[0] * u0 + grad[1] * u1
    m00, m01 = 1.0 - u0 * grad[0] / den, -u0 * grad[1] / den
    m10, m11 = -u1 * grad[0] / den, 1.0 - u1 * grad[1] / den
    gxx = m00 * m00 * txx + 2 * m00 * m01 * txy + m01 * m01 * tyy
    gxy = m00 * m10 * txx + (m00 * m11 + m01 * m10) * txy + m01 * m11 * tyy
    gyy = m10 * m10 * txx + 2 * m10 * m11 * txy + m11 * m11 * tyy
    w, h = camera.image_size
    pix = f[:2]
    ok = jnp.isfinite(z) & (pix[0] >= -0.5) & (pix[0] <= w - 0.5) & (pix[1] >= -0.5) & (pix[1] <= h - 0.5)
    return tuple(jnp.where(ok, v, jnp.nan) for v in (sxx, sxy, syy, gxx, gxy, gyy))


@eqx.filter_jit
def _propagate_strip(exterior, camera, dem, transform, r0, cols, cov, sigma_z, zfill, step, rows):
    """Rows ``r0 .. r0 + rows`` of a grid (``rows`` and the padded ``cols``
    multiples of ``step``): the propagation of :func:`_node_planes` exactly
    on a lattice every ``step`` pixels (on the DEM), its smooth flat-terrain
    part (:func:`_flat_terrain`) bilinear in between (as the approximate
    ortho mapping does with its positions), and the DEM's height, slope and
    sigma at every pixel (:func:`_finish_flat`).  Returns ``(6, rows, cols)``
    planes (:func:`_finish`)."""
    a, b, xoff, d, e, yoff = (transform[i] for i in range(6))

    def xy(r, c):
        return xoff + a * c[None, :] + b * r[:, None], yoff + d * c[None, :] + e * r[:, None]

    mr, mc = rows // step, cols // step
    xn, yn = xy(r0 + step * jnp.arange(mr + 1, dtype=float) + 0.5, step * jnp.arange(mc + 1, dtype=float) + 0.5)
    zn = dem.height(xn, yn)
    g = jnp.stack([xn, yn, jnp.where(jnp.isfinite(zn), zn, zfill)], axis=-1).reshape(-1, 3)
    nodes = _flat_terrain(_node_planes(exterior, camera, g, cov)).reshape(12, mr + 1, mc + 1)
    # Bilinear, separably: along each lattice row (1/step of the pixels), then
    # between lattice rows by broadcasting (gathers here run several times slower).
    # Bilinear, separably, plane by plane (XLA:CPU concatenates large stacked
    # planes slowly): along each lattice row (1/step of the pixels), then
    # between lattice rows.
    f = jnp.arange(step, dtype=float) / step
    r = jnp.arange(rows)
    ri, fr = r // step, ((r % step).astype(float) / step)[:, None]
    full = []
    for n in nodes:
        along = (n[:, :-1, None] + (n[:, 1:, None] - n[:, :-1, None]) * f[None, None, :]).reshape(mr + 1, cols)
        full.append(along[ri] + (along[ri + 1] - along[ri]) * fr)
    x, y = xy(r0 + jnp.arange(rows, dtype=float) + 0.5, jnp.arange(cols, dtype=float) + 0.5)
    # Computed once, not fused into each of the six outputs' loops.
    z, grad, full = jax.lax.optimization_barrier((*_dem_slope(dem, x, y), full))
    return _finish_flat(full, sigma_z, grad, z, camera)


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
        NaN where the ortho has no data (off the DEM or the image).
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

        from .tiled import _dataarray

        fill = np.asarray(np.nan)
        layers = {
            "ground_sigma": self.ground_sigma, "sigma_x": self.ground_std[0], "sigma_y": self.ground_std[1],
            "ground_major": self.ground_ellipse[0], "ground_minor": self.ground_ellipse[1],
            "ground_angle": self.ground_ellipse[2], "sigma_col": self.image_std[0], "sigma_row": self.image_std[1],
        }
        return xr.Dataset({k: _dataarray(v, self.grid, fill, k) for k, v in layers.items()})


def _coarse(grid: Grid, factor: int) -> Grid:
    if factor == 1:
        return grid
    from rasterio import Affine

    shape = tuple(-(-n // factor) for n in grid.shape)
    return Grid(grid.transform * Affine.scale(factor), shape, grid.crs)


def ortho_uncertainty(
    exterior,
    covariance,
    camera: FrameCamera,
    dem: DEM,
    grid: Grid,
    *,
    camera_covariance=None,
    dem_sigma=0.0,
    coarsen: int = 1,
    step: int = 16,
    image: int = 0,
) -> OrthoUncertainty:
    """Per-pixel standard deviations and error ellipses of an ortho's geolocation.

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
            k3, p1, p2)`` jointly (:attr:`photax.BundleResult.orientation_cov`),
            or None when ``exterior`` is a result.
        camera: the interior orientation (pixel grid required).
        dem: the DEM the ortho was made with.
        grid: the ortho's grid.
        camera_covariance: ``(8, 8)`` covariance of ``(f, x0, y0, k1, k2,
            k3, p1, p2)`` (or ``(3, 3)`` of ``f, x0, y0``), image-plane units;
            default none (fixed intrinsics).
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

    Returns:
        :class:`OrthoUncertainty`.
    """
    # Over 80 lines because the docstring documents every argument; the body is ~55 lines.
    exterior, covariance = _orientation(exterior, covariance, image)
    cov = np.asarray(covariance, dtype=float)
    if cov.shape not in ((6, 6), (_N, _N)) or not np.all(np.isfinite(cov)):
        raise ValueError(f"covariance must be a finite (6, 6) or (14, 14) matrix, got shape {cov.shape}")
    if np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < -1e-12 * max(np.abs(cov).max(), 1e-300):
        raise ValueError("covariance must be symmetric positive semi-definite")
    joint = np.zeros((_N, _N))
    joint[: cov.shape[0], : cov.shape[0]] = cov
    if camera_covariance is not None:
        c = np.asarray(camera_covariance, dtype=float)
        if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] not in (3, _N_INTRINSICS):
            raise ValueError(f"camera_covariance must be (8, 8) or (3, 3), got shape {c.shape}")
        if cov.shape == (_N, _N):
            raise ValueError("camera_covariance must be None when covariance is (14, 14) (it holds the intrinsics)")
        joint[6 : 6 + c.shape[0], 6 : 6 + c.shape[0]] = c
    if camera.image_size is None or camera.pixel_size is None:
        raise ValueError("camera must have a pixel grid (pixel_size and image_size)")
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
    args = (exterior, camera, dem)
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
    cols_p = -(-cols // step) * step
    strip = min(max(step, (_STRIP // cols_p) // step * step), -(-rows // step) * step)
    heights = np.asarray(dem.heights)
    zfill = jnp.asarray(float(np.nanmean(heights)) if np.isfinite(heights).any() else 0.0)
    transform = jnp.asarray(tuple(grid.transform)[:6])
    out = np.empty((6, rows, cols))
    for r0 in range(0, rows, strip):
        h = min(strip, rows - r0)
        if scalar_sz:
            z = sz[0, 0]
        else:
            z = np.zeros((strip, cols_p))
            z[:h, :cols] = sz[r0 : r0 + h]
        planes = _propagate_strip(*args, transform, jnp.asarray(float(r0)), cols_p, *covs, jnp.asarray(z), zfill,
                                  step, strip)
        for k, plane in enumerate(planes):
            out[k, r0 : r0 + h] = np.asarray(plane)[:h, :cols]
    return OrthoUncertainty(grid, out[:3], out[3:])


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
            covariance = (np.asarray(block)[image] if block is not None
                          else np.diag(np.asarray(exterior.exterior_std)[image] ** 2))
        return one, covariance
    if hasattr(exterior, "covariance") and hasattr(exterior, "exterior"):  # a ResectionResult
        cov = exterior.covariance if covariance is None else covariance
        if cov is None or not np.all(np.isfinite(np.asarray(cov, dtype=float))):
            raise ValueError("the resection result has no finite covariance (zero redundancy?)")
        return exterior.exterior, cov
    raise ValueError(
        f"exterior must be an ExteriorOrientation, a ResectionResult or a BundleResult, got {type(exterior).__name__}")

