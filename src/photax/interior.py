"""Interior orientation of scanned film from fiducial marks.

A scanned photograph's pixels are not the camera's image plane: the film sits
in the scanner shifted, rotated, perhaps stretched.  The calibration report
gives the fiducial marks' positions on the film (image-plane ``x`` right,
``y`` up, mm, origin at the fiducial centre: ``docs/conventions.md``);
measuring them in the scan fixes the transformation between the two.

The model is fitted in the direction of the measurement, **film -> pixel**::

    (u, v) = (x, -y)                                  (film with y down, like rows)
    similarity   c = a0 + p u - q v,          r = b0 + q u + p v          (4)
    affine       c = a0 + a1 u + a2 v,        r = b0 + b1 u + b2 v        (6)
    bilinear     c = a0 + a1 u + a2 v + a3 u v, r = b0 + b1 u + b2 v + b3 u v   (8)
    projective   c = (h11 u + h12 v + h13) / (h31 u + h32 v + 1), r likewise   (8)

so that the measured pixels are the observations and the calibrated film
coordinates error-free (a Gauss-Markov model, Kraus 2007 sec. 3.3.2; Wolf &
DeWitt 2014 app. C): residuals are in pixels and ``sigma0`` is the marks'
measuring precision.  Film coordinates are centred and scaled to unit rms
inside the model (Hartley normalisation: ``STYLE.md`` item 7); the parameters
and their covariance refer to the normalised film coordinates.

Blunders: data snooping as in the resection (:mod:`photax.resection`, Baarda
1968; Pope 1976), but one test per *mark* (both coordinates together): with
``Q_vv = I - A (A^T P A)^-1 A^T P`` and ``v_i`` the mark's two weighted
residuals, ``T_i = v_i^T (Q_vv,ii)^-1 v_i`` (a-priori ``sigma``: ``T_i ~
chi^2(2)``) or ``T_i / sigma0^2`` (``/ r ~ Beta(1, (r-2)/2)``); the worst mark
is excluded and the fit repeated while its test fails and the redundancy
allows.  The resection's per-coordinate test missed a (3, -4) px blunder on
an affine 8-mark scan (tau 2.53 < 2.68 for each coordinate): a displacement
split over both coordinates is what a wrong mark looks like.

:class:`ScannedCamera` is a :class:`photax.FrameCamera` whose pixel <->
image-plane conversion goes through the fitted transformation, so
:func:`photax.resect` (via ``camera.pixel_to_image``), :func:`photax.orthorectify`
and the bundle adjustment take scanned images as they are.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .camera import FrameCamera

Model = Literal["similarity", "affine", "bilinear", "projective"]
N_PARAMS = {"similarity": 4, "affine": 6, "bilinear": 8, "projective": 8}


# --------------------------------------------------------------------------- the transformation


def _cr(model: str, p, u, v, xp=jnp):
    """Pixel ``(c, r)`` from normalised film ``(u, v)`` (v down) with parameters ``p`` (module docstring)."""
    if model == "similarity":
        return p[0] + p[2] * u - p[3] * v, p[1] + p[3] * u + p[2] * v
    if model == "affine":
        return p[0] + p[1] * u + p[2] * v, p[3] + p[4] * u + p[5] * v
    if model == "bilinear":
        return p[0] + p[1] * u + p[2] * v + p[3] * u * v, p[4] + p[5] * u + p[6] * v + p[7] * u * v
    w = p[6] * u + p[7] * v + 1.0
    return (p[0] * u + p[1] * v + p[2]) / w, (p[3] * u + p[4] * v + p[5]) / w


class PixelTransform(eqx.Module):
    """Film (image plane, mm, y up) <-> scan pixels (column, row), fitted by :func:`interior_orientation`.

    Attributes:
        params: ``(k,)`` parameters on normalised film coordinates (module docstring).
        film_centre: ``(2,)`` centroid of the fiducials ``(u, v)`` used (mm, v = -y).
        film_scale: rms distance of the fiducials from it (mm).
        model: ``"similarity"``, ``"affine"``, ``"bilinear"`` or ``"projective"``.
    """

    params: Array
    film_centre: Array
    film_scale: Array
    model: str = eqx.field(static=True)

    def _norm(self, xy):
        xy = jnp.asarray(xy, dtype=float)
        u = (xy[..., 0] - self.film_centre[0]) / self.film_scale
        v = (-xy[..., 1] - self.film_centre[1]) / self.film_scale
        return u, v

    def pixel_from_film(self, xy) -> Array:
        """``(..., 2)`` film ``(x, y)`` mm -> pixel ``(column, row)``."""
        c, r = _cr(self.model, self.params, *self._norm(xy))
        return jnp.stack([c, r], axis=-1)

    def film_from_pixel(self, colrow, iterations: int = 6) -> Array:
        """``(..., 2)`` pixel ``(column, row)`` -> film ``(x, y)`` mm.

        Closed form for the similarity, affine and projective models; for the
        bilinear one Newton's method from the affine part (``iterations``
        steps: quadratic convergence, the ``u v`` term being a small correction).
        """
        colrow = jnp.asarray(colrow, dtype=float)
        c, r = colrow[..., 0], colrow[..., 1]
        p = self.params
        if self.model == "projective":
            h = jnp.array([[p[0], p[1], p[2]], [p[3], p[4], p[5]], [p[6], p[7], 1.0]])
            g = jnp.linalg.inv(h)
            w = g[2, 0] * c + g[2, 1] * r + g[2, 2]
            u = (g[0, 0] * c + g[0, 1] * r + g[0, 2]) / w
            v = (g[1, 0] * c + g[1, 1] * r + g[1, 2]) / w
        else:
            if self.model == "similarity":
                a = jnp.array([[p[2], -p[3]], [p[3], p[2]]])
                t = jnp.array([p[0], p[1]])
            else:
                k = 3 if self.model == "affine" else 4
                a = jnp.array([[p[1], p[2]], [p[k + 1], p[k + 2]]])
                t = jnp.array([p[0], p[k]])
            ai = jnp.linalg.inv(a)
            dc, dr = c - t[0], r - t[1]
            u = ai[0, 0] * dc + ai[0, 1] * dr
            v = ai[1, 0] * dc + ai[1, 1] * dr
            if self.model == "bilinear":
                def newton(_, uv):
                    u, v = uv
                    fc, fr = _cr("bilinear", p, u, v)
                    j11, j12 = p[1] + p[3] * v, p[2] + p[3] * u
                    j21, j22 = p[5] + p[7] * v, p[6] + p[7] * u
                    det = j11 * j22 - j12 * j21
                    ec, er = c - fc, r - fr
                    return u + (j22 * ec - j12 * er) / det, v + (j11 * er - j21 * ec) / det

                u, v = jax.lax.fori_loop(0, iterations, newton, (u, v))
        x = u * self.film_scale + self.film_centre[0]
        y = -(v * self.film_scale + self.film_centre[1])
        return jnp.stack([x, y], axis=-1)

    def scale(self) -> float:
        """Mean pixel size on the film (mm per pixel) at the centroid of the fiducials:
        ``|det J|^-1/2`` with ``J = d pixel / d film`` there (``u = v = 0``; numpy, no tracing)."""
        p = np.asarray(self.params)
        if self.model == "similarity":
            j = [[p[2], -p[3]], [p[3], p[2]]]
        elif self.model == "affine":
            j = [[p[1], p[2]], [p[4], p[5]]]
        elif self.model == "bilinear":
            j = [[p[1], p[2]], [p[5], p[6]]]
        else:  # d/du of (p0 u + p1 v + p2) / (p6 u + p7 v + 1) at 0
            j = [[p[0] - p[2] * p[6], p[1] - p[2] * p[7]], [p[3] - p[5] * p[6], p[4] - p[5] * p[7]]]
        return float(np.asarray(self.film_scale) / np.sqrt(abs(np.linalg.det(np.asarray(j)))))


class ScannedCamera(FrameCamera):
    """A :class:`photax.FrameCamera` (mm) whose pixels go through a fitted :class:`PixelTransform`.

    ``pixel_to_image`` is ``transform.film_from_pixel`` and ``image_to_pixel``
    ``transform.pixel_from_film``, so everything that converts pixels through
    the camera (:func:`photax.orthorectify`, ``LocateResult.image_sigma``,
    the resection's input ``camera.pixel_to_image(pixels)``) uses the
    interior orientation.  ``pixel_size`` is the transform's mean scale and
    ``image_size`` the scan's size (used for plausibility checks and sigma
    conversions only).  The bundle adjustment's self-calibration rebuilds a
    plain :class:`FrameCamera` for its result (the transform is not adjusted).
    """

    transform: PixelTransform

    def __init__(self, focal_length, principal_point=(0.0, 0.0), distortion=None, *, transform: PixelTransform,
                 image_size: tuple[int, int] | None = None, pixel_size=None):
        if pixel_size is None:
            pixel_size = transform.scale()
        super().__init__(focal_length, principal_point, distortion, pixel_size=pixel_size, image_size=image_size)
        self.transform = transform

    def _pixel_grid(self):
        if self.image_size is None:
            raise ValueError("this scanned camera has no image_size: give the scan's (width, height)")
        return super()._pixel_grid()

    def pixel_to_image(self, colrow) -> Array:
        """``(..., 2)`` scan pixel (column, row) -> film (x right, y up, mm)."""
        return self.transform.film_from_pixel(colrow)

    def image_to_pixel(self, xy) -> Array:
        """``(..., 2)`` film (x right, y up, mm) -> scan pixel (column, row)."""
        return self.transform.pixel_from_film(xy)


# --------------------------------------------------------------------------- the fit


def _design(model: str, p, u, v):
    """``(2n, k)`` design matrix ``d (c, r) / d p`` (rows c0, r0, c1, r1, ...)."""
    n = u.size
    one, zero = np.ones(n), np.zeros(n)
    if model == "similarity":
        dc = np.stack([one, zero, u, -v], 1)
        dr = np.stack([zero, one, v, u], 1)
    elif model == "affine":
        dc = np.stack([one, u, v, zero, zero, zero], 1)
        dr = np.stack([zero, zero, zero, one, u, v], 1)
    elif model == "bilinear":
        z4 = np.zeros((n, 4))
        dc = np.concatenate([np.stack([one, u, v, u * v], 1), z4], 1)
        dr = np.concatenate([z4, np.stack([one, u, v, u * v], 1)], 1)
    else:
        w = p[6] * u + p[7] * v + 1.0
        c = (p[0] * u + p[1] * v + p[2]) / w
        r = (p[3] * u + p[4] * v + p[5]) / w
        dc = np.stack([u / w, v / w, one / w, zero, zero, zero, -c * u / w, -c * v / w], 1)
        dr = np.stack([zero, zero, zero, u / w, v / w, one / w, -r * u / w, -r * v / w], 1)
    return np.stack([dc, dr], 1).reshape(2 * n, -1)


def _solve(model: str, u, v, obs, wgt):
    """Weighted least-squares parameters ``(k,)`` of ``model`` for ``(n, 2)`` pixels ``obs`` (weights ``1/sigma``)."""
    sw = wgt.reshape(-1)
    if model != "projective":
        a = _design(model, None, u, v) * sw[:, None]
        return np.linalg.lstsq(a, obs.reshape(-1) * sw, rcond=None)[0]
    # Start: the linear (DLT) solution, pixels normalised too; then Gauss-Newton on the pixel residuals.
    mc = obs.mean(0)
    sc = np.sqrt(np.mean(np.sum((obs - mc) ** 2, 1)))
    c, r = ((obs - mc) / sc).T
    one, zero = np.ones_like(u), np.zeros_like(u)
    rows = np.concatenate([np.stack([u, v, one, zero, zero, zero, -c * u, -c * v, -c], 1),
                           np.stack([zero, zero, zero, u, v, one, -r * u, -r * v, -r], 1)])
    h = np.linalg.svd(rows)[2][-1].reshape(3, 3)
    h = np.array([[sc, 0, mc[0]], [0, sc, mc[1]], [0, 0, 1]]) @ h
    p = (h / h[2, 2]).ravel()[:8]
    for _ in range(20):
        pc, pr = _cr(model, p, u, v, np)
        res = (obs - np.stack([pc, pr], 1)).reshape(-1) * sw
        dp = np.linalg.lstsq(_design(model, p, u, v) * sw[:, None], res, rcond=None)[0]
        p = p + dp
        if np.all(np.abs(dp) <= 1e-12 * (1 + np.abs(p))):
            break
    return p


@dataclasses.dataclass(frozen=True)
class InteriorOrientation:
    """The fitted film -> pixel transformation of one scan and its precision.

    Attributes:
        model: the transformation's name.
        transform: the :class:`PixelTransform` (film <-> pixel).
        residuals: ``(n, 2)`` measured minus fitted pixel (column, row), px,
            for every mark (excluded ones too, against the final fit).
        outliers: ``(n,)`` True for marks excluded by the blunder test.
        sigma0: a-posteriori standard deviation of unit weight (px when no
            a-priori sigma was given); NaN without redundancy.
        covariance: ``(k, k)`` covariance of ``transform.params``,
            ``sigma0^2 (A^T P A)^-1`` (sigma given: ``(A^T P A)^-1``).
        statistic: ``(n,)`` each mark's ``sqrt(T_i)`` (module docstring) in the
            final fit (excluded marks: when they were excluded).
        critical: the critical value of ``sqrt(T_i)`` in the final fit.
        redundancy: ``2 n_used - k``.
        message: what happened, in words.
    """

    model: str
    transform: PixelTransform
    residuals: np.ndarray
    outliers: np.ndarray
    sigma0: float
    covariance: np.ndarray
    statistic: np.ndarray
    critical: float
    redundancy: int
    message: str

    @property
    def rmse(self) -> float:
        """Root-mean-square residual of the marks used, px per coordinate."""
        v = self.residuals[~self.outliers]
        return float(np.sqrt(np.mean(v * v)))

    def film_from_pixel(self, colrow) -> np.ndarray:
        """``(n, 2)`` pixel -> film mm (see :meth:`PixelTransform.film_from_pixel`)."""
        return np.asarray(self.transform.film_from_pixel(colrow))

    def pixel_from_film(self, xy) -> np.ndarray:
        """``(n, 2)`` film mm -> pixel."""
        return np.asarray(self.transform.pixel_from_film(xy))

    def camera(self, focal_length, principal_point=(0.0, 0.0), distortion=None, *,
               image_size: tuple[int, int]) -> ScannedCamera:
        """The calibrated camera (``focal_length`` and ``principal_point`` in the
        fiducials' unit, mm) seeing the scan's pixels through this transformation.

        Args:
            image_size: the scan's ``(width, height)`` in pixels.
        """
        return ScannedCamera(focal_length, principal_point, distortion, transform=self.transform,
                             image_size=image_size)


def interior_orientation(pixel_xy, fiducial_xy, model: Model = "affine", *, sigma=None, alpha: float = 0.001,
                         robust: bool = True) -> InteriorOrientation:
    """Interior orientation of a scan from its measured fiducial marks.

    Args:
        pixel_xy: ``(n, 2)`` measured marks (column, row) px; NaN rows (marks
            not found) are left out of the fit and flagged as outliers.
        fiducial_xy: ``(n, 2)`` calibrated positions (film x right, y up, mm,
            from the camera's calibration report).
        model: ``"similarity"`` (4 parameters), ``"affine"`` (6),
            ``"bilinear"`` (8) or ``"projective"`` (8); see the module docstring.
        sigma: a-priori standard deviation of a mark coordinate, px (scalar,
            ``(n,)`` or ``(n, 2)``): the chi^2 test; None: the tau-type test
            on the estimated sigma0.
        alpha: significance level of each test.
        robust: False to skip the blunder test (no mark is excluded).

    Returns:
        :class:`InteriorOrientation`.

    Raises:
        ValueError: bad shapes, an unknown model, or fewer usable marks than
            the model needs (``k / 2``: 2, 3, 4, 4).
    """
    if model not in N_PARAMS:
        raise ValueError(f"model must be one of {sorted(N_PARAMS)}, got {model!r}")
    px = np.asarray(pixel_xy, dtype=float)
    fid = np.asarray(fiducial_xy, dtype=float)
    if px.ndim != 2 or px.shape[1] != 2:
        raise ValueError(f"pixel_xy must have shape (n, 2) (column, row), got {px.shape}")
    if fid.shape != px.shape:
        raise ValueError(f"fiducial_xy must have the shape of pixel_xy {px.shape}, got {fid.shape}")
    if not np.all(np.isfinite(fid)):
        raise ValueError("fiducial_xy has non-finite values")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    n, k = len(px), N_PARAMS[model]
    if sigma is None:
        s = np.ones((n, 2))
    else:
        s = np.asarray(sigma, dtype=float)
        if s.shape not in ((), (n,), (n, 2)):
            raise ValueError(f"sigma must be a scalar, (n,) or (n, 2) with n = {n}, got {s.shape}")
        s = np.broadcast_to(s[:, None] if s.ndim == 1 else s, (n, 2)).copy()
        if not np.all(np.isfinite(s) & (s > 0)):
            raise ValueError("sigma must be finite and positive")
    found = np.all(np.isfinite(px), axis=1)
    if found.sum() * 2 < k:
        raise ValueError(f"the {model} model needs at least {(k + 1) // 2} marks, got {int(found.sum())} usable of {n}")
    uv = np.column_stack([fid[:, 0], -fid[:, 1]])
    centre = uv[found].mean(0)
    scale = np.sqrt(np.mean(np.sum((uv[found] - centre) ** 2, 1)))
    if not scale > 0:
        raise ValueError("fiducial_xy: the marks coincide")
    u, v = ((uv - centre) / scale).T
    sigma_known = sigma is not None
    used = found.copy()
    stat_at = np.full(n, np.nan)
    wgt = 1.0 / s
    while True:
        p, out = _fit(model, u, v, px, wgt, used, sigma_known)
        red = 2 * int(used.sum()) - k
        crit = _critical2(alpha, sigma_known, red) if red > 0 else np.inf
        stat = np.sqrt(out["T"] if sigma_known else out["T"] / out["sigma0"] ** 2)
        worst = np.where(used & np.isfinite(stat), stat, -np.inf)
        j = int(np.argmax(worst))
        exact = out["sigma0"] < 1e-9 * (1.0 if sigma_known else 1.0 + np.abs(px[found]).max())
        if not (robust and red - 2 >= 1 and worst[j] > crit and not exact):
            break
        used[j] = False
        stat_at[j] = worst[j]
    final = np.where(used, stat, stat_at) if red > 0 else np.full(n, np.nan)
    outliers = ~used
    pc, pr = _cr(model, p, u, v, np)
    resid = px - np.stack([pc, pr], 1)
    bad = np.flatnonzero(outliers)
    if red <= 0:
        msg = f"{model}: {int(used.sum())} marks for {k} parameters: no redundancy, no blunder test"
    elif len(bad):
        msg = (f"{model}: {len(bad)} of {n} marks excluded ({', '.join(str(i) for i in bad)}); "
               f"sigma0 {out['sigma0']:.3g}")
    else:
        msg = f"{model}: all {n} marks pass the blunder test; sigma0 {out['sigma0']:.3g}"
    transform = PixelTransform(jnp.asarray(p), jnp.asarray(centre), jnp.asarray(scale), model)
    return InteriorOrientation(model=model, transform=transform, residuals=resid, outliers=outliers,
                               sigma0=float(out["sigma0"]), covariance=out["covariance"], statistic=final,
                               critical=float(crit), redundancy=int(red), message=msg)


def _fit(model, u, v, px, wgt, used, sigma_known):
    """Weighted fit with the marks ``used``: parameters, sigma0, covariance and each mark's
    test quadratic form ``T_i = v_i^T Q_vv,ii^-1 v_i`` (weighted residuals; NaN for marks not used)."""
    p = _solve(model, u[used], v[used], px[used], wgt[used])
    a = _design(model, p, u, v) * wgt.reshape(-1)[:, None]
    pc, pr = _cr(model, p, u, v, np)
    vres = ((px - np.stack([pc, pr], 1)) * wgt).reshape(-1)
    m = np.repeat(used, 2)
    au = a[m]
    q = np.linalg.inv(au.T @ au)
    red = au.shape[0] - au.shape[1]
    vu = vres[m]
    sigma0 = float(np.sqrt(vu @ vu / red)) if red > 0 else np.nan
    n = len(u)
    t = np.full(n, np.nan)
    for i in np.flatnonzero(used):
        ai = a[2 * i:2 * i + 2]
        qvv = np.eye(2) - ai @ q @ ai.T  # the mark's 2x2 block of the residuals' cofactor matrix
        vi = vres[2 * i:2 * i + 2]
        if np.linalg.det(qvv) > 1e-10:
            t[i] = vi @ np.linalg.solve(qvv, vi)
    cov = q if sigma_known else q * sigma0**2
    return p, {"sigma0": sigma0, "T": t, "covariance": cov}


def _critical2(alpha: float, sigma_known: bool, red: int) -> float:
    """Critical value of a mark's two-coordinate test, on the scale of ``sqrt(T)``.

    Known sigma: ``T ~ chi^2(2)``.  Estimated sigma0 (``T / sigma0^2``, the
    two-dimensional tau): ``T / (r sigma0^2) ~ Beta(1, (r - 2) / 2)`` (Pope
    1976 for one dimension; Koch 1999 sec. 4.4 for several), so the critical
    value is ``sqrt(r Beta^-1(1 - alpha))``; it needs ``r > 2``.
    """
    from scipy import stats  # lazily, as the resection does

    if sigma_known:
        return float(np.sqrt(stats.chi2.ppf(1.0 - alpha, 2)))
    if red <= 2:
        return np.inf
    return float(np.sqrt(red * stats.beta.ppf(1.0 - alpha, 1.0, 0.5 * (red - 2))))


# --------------------------------------------------------------------------- finding the marks


def mark_coverage(kind: str, dx, dy, size: float, width: float):
    """Whether film offsets ``(dx, dy)`` (mm from a mark's centre, any shape)
    lie on a fiducial mark: ``"cross"`` (two bars of half-length ``size`` and
    width ``width``), ``"dot"`` (a disc of radius ``size``) or ``"ring"``
    (a circle of radius ``size`` and line ``width``).  Float 0/1."""
    dx, dy = np.asarray(dx, dtype=float), np.asarray(dy, dtype=float)
    if kind == "cross":
        h = 0.5 * width
        on = ((np.abs(dx) <= h) & (np.abs(dy) <= size)) | ((np.abs(dy) <= h) & (np.abs(dx) <= size))
    elif kind == "dot":
        on = dx * dx + dy * dy <= size * size
    elif kind == "ring":
        on = np.abs(np.hypot(dx, dy) - size) <= 0.5 * width
    else:
        raise ValueError(f"mark must be 'cross', 'dot', 'ring' or a template image, got {kind!r}")
    return on.astype(float)


def mark_template(kind: str, size: float, width: float, pixel_size: float, *, bright: bool = True,
                  supersample: int = 8) -> np.ndarray:
    """A ``(2 h + 1, 2 h + 1)`` template of a mark, ``h = ceil(size / pixel_size) + 6``
    (the mark, a margin of background, and the matcher's interpolation border),
    area-sampled on a ``supersample^2`` grid per pixel; the mark at the centre pixel."""
    if not pixel_size > 0 or not size > 0:
        raise ValueError(f"pixel_size and the mark size must be positive, got {pixel_size}, {size}")
    h = int(np.ceil(size / pixel_size)) + 6
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    t = (np.arange(-h, h + 1)[:, None] + sub[None, :]).ravel() * pixel_size
    cov = mark_coverage(kind, t[None, :], -t[:, None], size, width)
    k = 2 * h + 1
    img = cov.reshape(k, supersample, k, supersample).mean(axis=(1, 3))
    return img if bright else 1.0 - img


@dataclasses.dataclass(frozen=True)
class Fiducials:
    """Fiducial marks found in a scan, and the interior orientation they give.

    Attributes:
        xy: ``(n, 2)`` measured marks (column, row) px; NaN where not found.
        located: the matcher's :class:`photax.measure.LocateResult` (NCC:
            covariance, status per mark).
        orientation: :class:`InteriorOrientation` from the marks found.
        flagged: ``(n,)`` True for marks not found or failing the pattern
            check (``orientation.outliers``): not used.
        messages: ``(n,)`` per mark: "ok", the matcher's reason, or
            "disagrees with the calibrated pattern (...)".
    """

    xy: np.ndarray
    located: object
    orientation: InteriorOrientation
    flagged: np.ndarray
    messages: list

    @property
    def rmse(self) -> float:
        """The interior orientation's residual rmse, px."""
        return self.orientation.rmse


def _approx_scale(approx: np.ndarray, fid: np.ndarray) -> float:
    """mm per pixel of a similarity through approximate positions and the calibrated ones."""
    a = approx - approx.mean(0)
    f = fid - fid.mean(0)
    return float(np.sqrt(np.sum(f * f) / np.sum(a * a)))


def find_fiducials(scan, fiducial_xy, *, pixel_size: float | None = None, approx_xy=None, mark="cross",
                   mark_size: float = 1.0, line_width: float = 0.2, bright: bool = True, search: int = 15,
                   template_blur: float = 0.7, model: Model = "affine", sigma: float | None = 0.1,
                   alpha: float = 0.001) -> Fiducials:
    """Find the fiducial marks in a scan, sub-pixel, and check them against the calibrated pattern.

    1. Approximate positions: ``approx_xy`` (n, 2) px, or from the scan size
       and the scan resolution ``pixel_size`` (mm per pixel): the fiducial
       centre at the scan's centre, film x along columns, y up.
    2. Normalised cross-correlation (:func:`photax.measure.match_ncc`) of a
       mark template (blurred by ``template_blur`` px, a scanner's PSF) within
       ``search`` px of each approximation, the peak refined to sub-pixel by
       its parabola.  On the rendered crosses of the tests (0.5 mm/px, PSF
       0.7 px, noise 1 %) this measured 0.011 px rms; least-squares matching
       (affine shape) measured 0.035-0.04 px there, and without a blurred
       template did not converge (thin bars: scale and blur trade off), so
       it is not used.
    3. The pattern check: :func:`interior_orientation` with ``model`` and its
       blunder test; a mark that disagrees (a mark of the neighbouring frame,
       a scratch, dust) is flagged and left out.

    Args:
        scan: ``(h, w)`` scanned image, any integer or float dtype.
        fiducial_xy: ``(n, 2)`` calibrated mark positions, film mm (x right, y up).
        pixel_size: scan resolution, mm per pixel (needed without
            ``approx_xy``; otherwise estimated from it).
        approx_xy: ``(n, 2)`` approximate mark positions (column, row).
        mark: ``"cross"``, ``"dot"``, ``"ring"`` (see :func:`mark_coverage`,
            sizes ``mark_size``, ``line_width`` in mm) or a template image
            ``(2 h + 1, 2 h + 1)`` with the mark at its centre.
        bright: the marks are brighter than their surroundings.
        search: NCC search radius, px.
        template_blur: Gaussian blur of a drawn template, px (0: none).
        model, alpha: the interior orientation and its test.
        sigma: a-priori precision of a mark coordinate, px, for the pattern
            check (chi^2 test).  With 8 marks and 8 parameters the
            estimated-sigma0 test (``sigma=None``) has 8 degrees of freedom
            and flagged a 0.09 px residual on a clean rendered scan: marks
            measured this way are not equally precise, and a blunder is a
            matter of pixels, not of tenths.

    Returns:
        :class:`Fiducials`.

    Raises:
        ValueError: bad shapes or arguments, or fewer marks found than the
            model needs (the message gives each mark's reason).
    """
    from scipy.ndimage import gaussian_filter

    from .measure import match_ncc

    img = np.asarray(scan)
    if img.ndim != 2:
        raise ValueError(f"scan must be one (h, w) image, got shape {img.shape}")
    fid = np.asarray(fiducial_xy, dtype=float)
    if fid.ndim != 2 or fid.shape[1] != 2 or len(fid) < 2:
        raise ValueError(f"fiducial_xy must have shape (n, 2) with n >= 2, got {fid.shape}")
    if model not in N_PARAMS:
        raise ValueError(f"model must be one of {sorted(N_PARAMS)}, got {model!r}")
    h, w = img.shape
    if approx_xy is None:
        if pixel_size is None or not pixel_size > 0:
            raise ValueError("give approx_xy or the scan resolution pixel_size (mm per pixel)")
        approx = np.column_stack([(w - 1) / 2 + fid[:, 0] / pixel_size, (h - 1) / 2 - fid[:, 1] / pixel_size])
    else:
        approx = np.asarray(approx_xy, dtype=float)
        if approx.shape != fid.shape or not np.all(np.isfinite(approx)):
            raise ValueError(f"approx_xy must be finite with the shape of fiducial_xy {fid.shape}, got {approx.shape}")
        if pixel_size is None:
            pixel_size = _approx_scale(approx, fid)
    if isinstance(mark, str):
        tmpl = mark_template(mark, mark_size, line_width, pixel_size, bright=bright)
        if template_blur > 0:
            tmpl = gaussian_filter(tmpl, template_blur, mode="nearest")
    else:
        tmpl = np.asarray(mark, dtype=float)
        if tmpl.ndim != 2 or tmpl.shape[0] != tmpl.shape[1] or tmpl.shape[0] % 2 == 0 or tmpl.shape[0] < 11:
            raise ValueError(f"mark: a template must be a square image of odd size >= 11, got {tmpl.shape}")
    half = tmpl.shape[0] // 2 - 3  # matching window: the template minus the interpolation border
    centre = np.full(fid.shape, float(tmpl.shape[0] // 2))
    ncc = match_ncc(tmpl, centre, img, approx, window=half, search=int(search))
    valid = np.asarray(ncc.valid)
    xy = np.where(valid[:, None], np.asarray(ncc.xy), np.nan)
    n_needed = (N_PARAMS[model] + 1) // 2
    if valid.sum() < n_needed:
        raise ValueError(f"fiducial marks: only {int(valid.sum())} of {len(fid)} found, the {model} model needs "
                         f"{n_needed}; per mark: {ncc.messages()}")
    io = interior_orientation(xy, fid, model, sigma=sigma, alpha=alpha)
    flagged = io.outliers | ~valid
    ncc_msg = ncc.messages()
    messages = []
    for i in range(len(fid)):
        if not valid[i]:
            messages.append(f"not found: {ncc_msg[i]}")
        elif io.outliers[i]:
            messages.append(f"disagrees with the calibrated pattern (statistic {io.statistic[i]:.1f} > "
                            f"{io.critical:.2f}, residual {np.hypot(*io.residuals[i]):.2f} px)")
        else:
            messages.append("ok")
    return Fiducials(xy=xy, located=ncc, orientation=io, flagged=flagged, messages=messages)
