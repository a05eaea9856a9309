"""Per-pixel geolocation uncertainty of an orthophoto, by first-order propagation.

An ortho pixel at ground ``g = (X, Y)`` shows the image at
``p = pi(theta, c, X, Y, Z(X, Y) + dz)``: ``theta`` the exterior orientation
``(X0, Y0, Z0, a1, a2, a3)`` (angles in the convention's order), ``c`` the
intrinsics (:data:`photax.bundle.INTRINSICS`: ``f, x0, y0, k1, k2, k3, p1,
p2``), ``Z`` the DEM's bilinear height and ``dz`` its error; ``pi`` is the
collinearity model with lens distortion (:func:`photax.project`) and the
camera's pixel grid.  With the Jacobians (``jax.jacfwd``, exact derivatives
of that very code)

    J_t = dp/dtheta (2x6),  J_c = dp/dc (2x8),  J_z = dp/dZ (2x1),
    A   = dp/d(X, Y) (2x2, the total derivative through the DEM's slope),

the error of the image position read for the pixel is, to first order
(law of propagation of variances, e.g. Mikhail, Bethel & McGlone 2001,
ch. 2; Förstner & Wrobel 2016, sec. 2.7),

    S_p = J_t S_t J_t^T + J_c S_c J_c^T + s_z^2 J_z J_z^T        (pixels^2)

and the ground point whose grey value the pixel actually shows is off by
``dg = -A^-1 dp`` (the ray through ``p`` meets the DEM elsewhere), so

    S_g = A^-1 S_p A^-T                                          (metres^2).

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

from .camera import FrameCamera
from .collinearity import ExteriorOrientation, depth, project
from .dem import DEM
from .rectification._grid import Grid

_BLOCK = 1 << 14  # points per jitted call (padded): one compilation, bounded memory
_STRIP = 1 << 19  # pixels per strip of the lattice evaluation (~60 MB of float64 fields)
_N_INTRINSICS = 8


def _intrinsics(camera: FrameCamera):
    return jnp.concatenate([camera.focal_length[None], camera.principal_point, camera.distortion])


def _pixel(theta, intr, xy, dz, exterior, camera, dem, height=True):
    """The image pixel ``(2,)`` of ground ``xy`` on the DEM plus ``dz`` (or
    at height ``dz`` when not ``height``)."""
    ext = ExteriorOrientation.from_vector(theta, exterior.convention)
    cam = eqx.tree_at(lambda c: (c.focal_length, c.principal_point, c.distortion), camera,
                      (intr[0], intr[1:3], intr[3:]))
    z = dem.height(xy[0], xy[1]) + dz if height else dz
    g = jnp.concatenate([xy, z[None]])[None]
    return cam.image_to_pixel(project(g, ext, cam))[0]


def _node(exterior, camera, p, cov_t, cov_c):
    """At one ground point ``p`` ``(3,)``: the pixel ``(2,)``, ``S_p`` of the
    exterior and the intrinsics ``(2, 2)`` and ``dp/d(X, Y, Z)`` ``(2, 3)``."""
    theta0, intr0 = exterior.to_vector(), _intrinsics(camera)
    flat = DEM.flat(0.0, (-1.0, -1.0, 1.0, 1.0))  # unused: the height is given

    def pix(theta, intr, g):
        return _pixel(theta, intr, g[:2], g[2], exterior, camera, flat, height=False)

    jt, jc, jg = jax.jacfwd(pix, argnums=(0, 1, 2))(theta0, intr0, p)
    return pix(theta0, intr0, p), jt @ cov_t @ jt.T + jc @ cov_c @ jc.T, jg


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


def _planes(pix, sp, jg):
    """Node values -> ``(11, n)`` planes: pixel (2), S_p xx, xy, yy (3), jg (6)."""
    return jnp.concatenate([pix.T, jnp.stack([sp[:, 0, 0], sp[:, 0, 1], sp[:, 1, 1]]), jg.reshape(-1, 6).T])


@eqx.filter_jit
def _propagate(exterior, camera, dem, xy, cov_t, cov_c, sigma_z):
    """Every point exactly: ``(n, 2)`` ground points -> ``(6, n)`` planes
    (see :func:`_finish`), NaN off the DEM, behind the camera or off the image."""
    z, grad = _dem_slope(dem, xy[:, 0], xy[:, 1])
    g = jnp.concatenate([xy, jnp.where(jnp.isfinite(z), z, 0.0)[:, None]], axis=-1)
    pix, sp, jg = jax.vmap(lambda p: _node(exterior, camera, p, cov_t, cov_c))(g)
    pl = jnp.where((depth(g, exterior) > 0)[None], _planes(pix, sp, jg), jnp.nan)
    return _finish(pl[:2], pl[2:5], pl[5:], sigma_z, grad, z, camera)


@eqx.filter_jit
def _propagate_strip(exterior, camera, dem, transform, r0, cols, cov_t, cov_c, sigma_z, zfill, step, rows):
    """Rows ``r0 .. r0 + rows`` of a grid (``rows`` and the padded ``cols``
    multiples of ``step``): the Jacobians on a lattice every ``step`` pixels,
    bilinear in between (as the approximate ortho mapping does with its
    positions); the DEM height, slope and sigma at every pixel.  Returns
    ``(6, rows, cols)`` planes (:func:`_finish`)."""
    a, b, xoff, d, e, yoff = (transform[i] for i in range(6))

    def xy(r, c):
        return xoff + a * c[None, :] + b * r[:, None], yoff + d * c[None, :] + e * r[:, None]

    mr, mc = rows // step, cols // step
    xn, yn = xy(r0 + step * jnp.arange(mr + 1, dtype=float) + 0.5, step * jnp.arange(mc + 1, dtype=float) + 0.5)
    zn = dem.height(xn, yn)
    g = jnp.stack([xn, yn, jnp.where(jnp.isfinite(zn), zn, zfill)], axis=-1).reshape(-1, 3)
    pix, sp, jg = jax.vmap(lambda p: _node(exterior, camera, p, cov_t, cov_c))(g)
    nodes = jnp.where((depth(g, exterior) > 0)[None], _planes(pix, sp, jg), jnp.nan).reshape(11, mr + 1, mc + 1)
    f = jnp.arange(step, dtype=float) / step
    # Along rows, then between rows (one cell = step x step pixels).
    along = nodes[:, :, :-1, None] + (nodes[:, :, 1:, None] - nodes[:, :, :-1, None]) * f[None, None, None, :]
    along = along.reshape(11, mr + 1, cols)
    full = along[:, :-1, None, :] + (along[:, 1:, None, :] - along[:, :-1, None, :]) * f[None, None, :, None]
    full = full.reshape(11, rows, cols)
    x, y = xy(r0 + jnp.arange(rows, dtype=float) + 0.5, jnp.arange(cols, dtype=float) + 0.5)
    z, grad = _dem_slope(dem, x, y)
    return _finish(full[:2], full[2:5], full[5:], sigma_z, grad, z, camera)


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
            or a :class:`photax.BundleResult` (image ``image``; its
            ``exterior_std`` only: the bundle keeps no per-image covariance
            block, so correlations are dropped).
        covariance: ``(6, 6)`` covariance of ``(X0, Y0, Z0, a1, a2, a3)``
            (metres, radians; angles in the exterior's convention order), or
            None when ``exterior`` is a result.
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
        step: the Jacobians of the collinearity model are evaluated every
            ``step`` pixels and interpolated bilinearly in between (they vary
            smoothly; as the approximate ortho mapping does with positions),
            while the DEM height, slope and sigma enter at every pixel;
            ``step=1``: everything at every pixel (~50x slower).
        image: which image of a bundle result.

    Returns:
        :class:`OrthoUncertainty`.
    """
    # Over 80 lines because the docstring documents every argument; the body is ~55 lines.
    exterior, covariance = _orientation(exterior, covariance, image)
    cov_t = np.asarray(covariance, dtype=float)
    if cov_t.shape != (6, 6) or not np.all(np.isfinite(cov_t)):
        raise ValueError(f"covariance must be a finite (6, 6) matrix, got shape {cov_t.shape}")
    if np.min(np.linalg.eigvalsh(0.5 * (cov_t + cov_t.T))) < -1e-12 * max(np.abs(cov_t).max(), 1e-300):
        raise ValueError("covariance must be symmetric positive semi-definite")
    cov_c = np.zeros((_N_INTRINSICS, _N_INTRINSICS))
    if camera_covariance is not None:
        c = np.asarray(camera_covariance, dtype=float)
        if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] not in (3, _N_INTRINSICS):
            raise ValueError(f"camera_covariance must be (8, 8) or (3, 3), got shape {c.shape}")
        cov_c[: c.shape[0], : c.shape[0]] = c
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
    sz = np.broadcast_to(sz, grid.shape)
    rows, cols = grid.shape
    args = (exterior, camera, dem)
    covs = (jnp.asarray(cov_t), jnp.asarray(cov_c))
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
        z = np.zeros((strip, cols_p))
        z[:h, :cols] = sz[r0 : r0 + h]
        planes = _propagate_strip(*args, transform, jnp.asarray(float(r0)), cols_p, *covs, jnp.asarray(z), zfill,
                                  step, strip)
        out[:, r0 : r0 + h] = np.asarray(planes)[:, :h, :cols]
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
        cov = np.diag(np.asarray(exterior.exterior_std)[image] ** 2) if covariance is None else covariance
        return one, cov
    if hasattr(exterior, "covariance") and hasattr(exterior, "exterior"):  # a ResectionResult
        cov = exterior.covariance if covariance is None else covariance
        if cov is None or not np.all(np.isfinite(np.asarray(cov, dtype=float))):
            raise ValueError("the resection result has no finite covariance (zero redundancy?)")
        return exterior.exterior, cov
    raise ValueError(
        f"exterior must be an ExteriorOrientation, a ResectionResult or a BundleResult, got {type(exterior).__name__}")

