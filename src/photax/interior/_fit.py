"""The adjustment of an interior orientation and its per-mark blunder test (see :mod:`photax.interior`)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ._transform import N_PARAMS, Model, PixelTransform, ScannedCamera, _cr, _design, _solve


@dataclasses.dataclass(frozen=True)
class InteriorOrientation:
    """The fitted film -> pixel transformation of one scan and its precision.

    Attributes:
        model: the transformation's name.
        transform: the :class:`PixelTransform` (film <-> pixel).
        residuals: ``(n, 2)`` fitted minus measured pixel (computed - observed, as every photax residual) (column, row), px,
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

    Examples:
        What :func:`interior_orientation` returns: the fitted transformation, its residuals and
        test, and a camera that goes through it (a :class:`ScannedCamera`):

        >>> import numpy as np
        >>> import photax as ptx
        >>> film = np.array([[-106.0, -106.0], [106.0, -106.0], [106.0, 106.0], [-106.0, 106.0], [0.0, 110.0]])
        >>> pixel = film * [50.0, -50.0] + [5600.0, 5620.0]
        >>> io = ptx.interior_orientation(pixel, film, "similarity")
        >>> print(f"{io.rmse:.6f}", np.round(np.asarray(io.pixel_from_film(np.array([[0.0, 0.0]]))), 6))
        0.000000 [[5600. 5620.]]
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

    def camera(
        self, focal_length, principal_point=(0.0, 0.0), distortion=None, *, image_size: tuple[int, int]
    ) -> ScannedCamera:
        """The calibrated camera (``focal_length`` and ``principal_point`` in the
        fiducials' unit, mm) seeing the scan's pixels through this transformation.

        Args:
            image_size: the scan's ``(width, height)`` in pixels.
        """
        return ScannedCamera(focal_length, principal_point, distortion, transform=self.transform, image_size=image_size)


def interior_orientation(
    pixel_xy, fiducial_xy, model: Model = "affine", *, sigma=None, alpha: float = 0.001, robust: bool = True
) -> InteriorOrientation:
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

    Examples:
        The affine film -> scan transformation from four fiducial marks of a scan at 50 px/mm, turned
        by half a degree and offset (the marks' measurements exact here, so the residuals vanish):

        >>> import numpy as np
        >>> import photax as ptx
        >>> film = np.array([[-106.0, -106.0], [106.0, -106.0], [106.0, 106.0], [-106.0, 106.0]])  # mm, y up
        >>> a = np.radians(0.5)
        >>> rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        >>> pixel = (film * [1.0, -1.0]) @ rot.T * 50.0 + [5600.0, 5620.0]  # column right, row down
        >>> io = ptx.interior_orientation(pixel, film, "affine")
        >>> print(f"{io.rmse:.6f}", np.round(np.asarray(io.film_from_pixel(pixel[:1])), 6))
        0.000000 [[-106. -106.]]
    """
    # Over 80 lines because the docstring documents every argument; the body is ~60 lines.
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
    resid = np.stack([pc, pr], 1) - px  # computed - observed (docs/conventions.md)
    bad = np.flatnonzero(outliers)
    if red <= 0:
        msg = f"{model}: {int(used.sum())} marks for {k} parameters: no redundancy, no blunder test"
    elif len(bad):
        msg = (
            f"{model}: {len(bad)} of {n} marks excluded ({', '.join(str(i) for i in bad)}); sigma0 {out['sigma0']:.3g}"
        )
    else:
        msg = f"{model}: all {n} marks pass the blunder test; sigma0 {out['sigma0']:.3g}"
    transform = PixelTransform(jnp.asarray(p), jnp.asarray(centre), jnp.asarray(scale), model)
    return InteriorOrientation(
        model=model,
        transform=transform,
        residuals=resid,
        outliers=outliers,
        sigma0=float(out["sigma0"]),
        covariance=out["covariance"],
        statistic=final,
        critical=float(crit),
        redundancy=int(red),
        message=msg,
    )


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
        ai = a[2 * i : 2 * i + 2]
        qvv = np.eye(2) - ai @ q @ ai.T  # the mark's 2x2 block of the residuals' cofactor matrix
        vi = vres[2 * i : 2 * i + 2]
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
    # Both quantiles in closed form (no scipy.stats import): chi^2(2) is the
    # exponential distribution of mean 2, P(T > c) = exp(-c / 2); Beta(1, b)
    # has P(X > x) = (1 - x)^b.
    if sigma_known:
        return float(np.sqrt(-2.0 * np.log(alpha)))
    if red <= 2:
        return np.inf
    return float(np.sqrt(red * (1.0 - alpha ** (2.0 / (red - 2)))))


# --------------------------------------------------------------------------- finding the marks
