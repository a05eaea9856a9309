"""Plane-to-plane models fitted to control points: polynomials of order 1-5,
the 8-parameter projective transform, the thin-plate spline (``fit_tps``) and the
piecewise-affine (Delaunay) map (``fit_piecewise_affine``).

Polynomial of order ``n`` (docs/maths.md, "Polynomial rectification")::

    X = sum_{i+j<=n} a_ij x^i y^j,    Y = sum_{i+j<=n} b_ij x^i y^j

with ``u = (n+1)(n+2)/2`` = 3, 6, 10, 15, 21 coefficients per axis, so at
least ``u`` points.  Raw monomials of projected coordinates (x ~ 5e5 m) are
hopelessly ill-conditioned (x^5 ~ 3e28 next to 1), so both point sets are
centred and scaled to about [-1, 1] per axis *inside* the model, the fit is
solved by SVD least squares (never normal equations), and the model maps
original units to original units.

Which direction to fit: rectification is indirect (docs/maths.md): for every
*output* (map) pixel the rectifier needs the *input* image position.  So fit
``fit_polynomial(map_xy, pixel_xy, order)`` (output -> input) and hand the
model to the rectifier; use ``model.inverse()`` only for the other way
(a polynomial's inverse is not a polynomial, see ``PolynomialModel.inverse``).

Projective transform (reprojection of a plane, e.g. a façade or a floor)::

    X = (h11 x + h12 y + h13) / (h31 x + h32 y + h33)
    Y = (h21 x + h22 y + h23) / (h31 x + h32 y + h33)

fitted by the Hartley-normalised DLT (Hartley & Zisserman 2003, alg. 4.2)
from 4+ points and refined by Levenberg-Marquardt (optimistix, the solver
resection falls back on) on the geometric error in the destination plane;
its inverse is the matrix inverse.

Reported quality (both models): ``residuals = model(src) - dst`` (n, 2) in
destination units, ``rmse`` and ``rmse_dof`` (see the class docstrings),
``condition`` of the normalised design matrix.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._float64 import as_float64
from .errors import RESULTS, ConvergenceError, DegenerateGeometryError, from_optimistix

MAX_ORDER = 5


def exponents(order: int) -> np.ndarray:
    """``(u, 2)`` exponents ``(i, j)`` of ``x^i y^j`` with ``i + j <= order``,
    by total degree: 1, x, y, x^2, x y, y^2, x^3, ..."""
    return np.array([(d - j, j) for d in range(order + 1) for j in range(d + 1)], dtype=int)


def n_coefficients(order: int) -> int:
    """Coefficients per axis of a polynomial of ``order``: (n+1)(n+2)/2."""
    return (order + 1) * (order + 2) // 2


def _points(name: str, xy) -> np.ndarray:
    p = as_float64(xy, name)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got {p.shape}")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise ValueError(f"{name} has NaN or infinite values at rows {np.flatnonzero(bad).tolist()}")
    return p


def _check_pairs(src_xy, dst_xy, weights, minimum: int, what: str):
    src, dst = _points("src_xy", src_xy), _points("dst_xy", dst_xy)
    if src.shape != dst.shape:
        raise ValueError(f"src_xy and dst_xy must have the same shape, got {src.shape} and {dst.shape}")
    n = src.shape[0]
    if n < minimum:
        raise ValueError(f"{what} needs at least {minimum} points, got {n}")
    _, first, counts = np.unique(src, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = sorted(first[counts > 1].tolist())
        raise ValueError(f"src_xy has duplicated points (first occurrences at rows {dup}); remove them")
    if weights is None:
        w = np.ones(n)
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (n,):
            raise ValueError(f"weights must have shape ({n},), got {w.shape}")
        if not (np.isfinite(w).all() and (w > 0).all()):
            raise ValueError("weights must be finite and positive")
    return src, dst, w


def _normaliser(p: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Centre (mean) and per-axis scale (max |deviation|) mapping ``p`` into
    [-1, 1]."""
    centre = p.mean(axis=0)
    scale = np.abs(p - centre).max(axis=0)
    if (scale == 0).any():
        axis = "xy"[int(np.argmin(scale))]
        raise DegenerateGeometryError(f"{name} points all have the same {axis}: the fit is degenerate")
    return centre, scale


def _design(u: np.ndarray, exps: np.ndarray) -> np.ndarray:
    return np.stack([u[:, 0] ** i * u[:, 1] ** j for i, j in exps], axis=-1)


def _hat_diag(a_weighted: np.ndarray) -> np.ndarray:
    """Diagonal of the hat matrix ``A (A^T A)^-1 A^T`` via thin QR."""
    q, _ = np.linalg.qr(a_weighted)
    return np.sum(q * q, axis=1)


def _query(xy) -> Array:
    """``xy`` as a float ``(..., 2)`` array of points (the models' argument)."""
    p = jnp.asarray(xy, dtype=float)
    if p.shape[-1:] != (2,):
        raise ValueError(f"xy must have shape (..., 2), got {p.shape}")
    return p


class PolynomialModel(eqx.Module):
    """A 2-D polynomial mapping fitted by :func:`fit_polynomial`.

    ``model(xy)`` maps ``(..., 2)`` source points to ``(..., 2)`` destination
    points (jit/vmap friendly; float64).  Internally
    ``model(p) = M((p - src_centre) / src_scale) @ coef * dst_scale + dst_centre``
    where ``M`` holds the monomials of :func:`exponents`.

    Attributes:
        order: polynomial order n (static).
        coef: ``(u, 2)`` coefficients of the normalised model (columns X, Y).
        src_centre, src_scale, dst_centre, dst_scale: ``(2,)`` normalisation.
        residuals: ``(n, 2)`` ``model(src) - dst`` at the fitting points,
            destination units.
        rmse: radial RMS residual ``sqrt(sum_i |v_i|^2 / n)`` (unweighted).
        rmse_dof: ``sqrt(sum_i w_i |v_i|^2 / (2 (n - u)))``: the a-posteriori
            standard deviation of unit weight of one coordinate (per axis,
            X and Y pooled), adjusted for the ``u`` coefficients per axis;
            NaN without redundancy (``n == u``).
        condition: 2-norm condition number of the normalised, weighted design
            matrix (what the solver actually sees).
        condition_raw: the same for raw monomials of the unnormalised source
            coordinates, for comparison (can be astronomically large).
        loo_residuals: ``(n, 2)`` leave-one-out residuals: the prediction
            of the model fitted without point ``i`` minus ``dst_i``, computed as
            ``v_i / (1 - h_ii)`` from the hat matrix; NaN where point ``i`` is
            needed to determine the fit (``h_ii = 1``).

    Examples:
        What :func:`fit_polynomial` returns: callable on ``(n, 2)`` points, with its fit statistics
        (here an exact affine map, so the residuals vanish):

        >>> import numpy as np
        >>> import photax as ptx
        >>> rng = np.random.default_rng(0)
        >>> src = rng.uniform(0, 1000, (10, 2))
        >>> model = ptx.fit_polynomial(src, src @ np.array([[0.5, 0.1], [-0.1, 0.5]]) + [20.0, 30.0], order=1)
        >>> model.order, f"{float(model.rmse):.6f}", np.round(np.asarray(model(np.array([[100.0, 200.0]]))), 6).tolist()
        (1, '0.000000', [[50.0, 140.0]])
    """

    order: int = eqx.field(static=True)
    coef: Array
    src_centre: Array
    src_scale: Array
    dst_centre: Array
    dst_scale: Array
    residuals: Array
    rmse: Array
    rmse_dof: Array
    condition: Array
    condition_raw: Array
    loo_residuals: Array
    src_xy: Array
    dst_xy: Array

    def __call__(self, xy) -> Array:
        """``(..., 2)`` source points -> ``(..., 2)`` destination points."""
        p = _query(xy)
        return jnp.stack(self.transform(p[..., 0], p[..., 1]), axis=-1)

    @jax.jit
    def transform(self, x, y) -> tuple[Array, Array]:
        """Separate-coordinate form ``X, Y = model.transform(x, y)`` for
        arrays of one common shape (e.g. a whole output grid).

        Horner's scheme in ``x`` of Horner polynomials in ``y``,
        ``X = sum_i x^i (sum_j c_ij y^j)``: ``u`` multiply-adds per axis and
        no ``(..., u)`` monomial array, so a 4096^2 grid costs no more memory
        than its output.
        """
        x, y = jnp.asarray(x, dtype=float), jnp.asarray(y, dtype=float)
        ux = (x - self.src_centre[0]) / self.src_scale[0]
        uy = (y - self.src_centre[1]) / self.src_scale[1]
        index = {(int(i), int(j)): k for k, (i, j) in enumerate(exponents(self.order))}
        out = []
        for axis in range(2):
            c = self.coef[:, axis]
            acc = None
            for i in range(self.order, -1, -1):
                inner = None
                for j in range(self.order - i, -1, -1):
                    cij = c[index[i, j]]
                    inner = cij if inner is None else inner * uy + cij
                acc = inner if acc is None else acc * ux + inner
            out.append(acc * self.dst_scale[axis] + self.dst_centre[axis])
        return out[0], out[1]

    def padded(self, order: int) -> PolynomialModel:
        """The same mapping written as a polynomial of a higher ``order``
        (zero coefficients for the extra terms, which come last in
        :func:`exponents`).  Its values are this model's, bit for bit
        (Horner's scheme only adds ``0 * u`` terms ahead of the real ones),
        and all models padded to one order share one compiled kernel:
        :meth:`photax.compare.ModelComparison.rectify` rectifies orders 1-5
        with one compilation instead of five."""
        if order < self.order:
            raise ValueError(f"order must be >= this model's order {self.order}, got {order}")
        extra = jnp.zeros((n_coefficients(order) - self.coef.shape[0], 2), self.coef.dtype)
        return dataclasses.replace(self, order=int(order), coef=jnp.concatenate([self.coef, extra]))

    def inverse(self, method: str = "newton", *, order: int | None = None, samples: int = 50) -> PolynomialInverse:
        """The inverse mapping (destination -> source), with its error.

        The inverse of a polynomial is not a polynomial, so it is either

        * ``"fit"``: a polynomial of ``order`` (default: this model's order)
          fitted destination -> source on a ``samples x samples`` grid over
          the bounding box of the fitting points (an approximation), or
        * ``"newton"`` (default): the fitted inverse refined by 5 Newton
          steps on the forward model (exact to round-off wherever the
          forward model is invertible and the start is close).

        The returned :class:`PolynomialInverse` reports ``max_error`` and
        ``rmse``: round-trip error ``|p - inverse(model(p))|`` over the
        same grid, source units.
        """
        if method not in ("fit", "newton"):
            raise ValueError(f"method must be 'fit' or 'newton', got {method!r}")
        order = self.order if order is None else order
        src = np.asarray(self.src_xy)
        lo, hi = src.min(axis=0), src.max(axis=0)
        gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], samples), np.linspace(lo[1], hi[1], samples))
        grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
        fwd = np.asarray(self(grid))
        start = fit_polynomial(fwd, grid, order)
        inv = PolynomialInverse(self, start, 5 if method == "newton" else 0, jnp.nan, jnp.nan)
        err = np.linalg.norm(np.asarray(inv(fwd)) - grid, axis=1)
        return PolynomialInverse(
            self, start, inv.newton_steps, jnp.asarray(err.max()), jnp.asarray(np.sqrt(np.mean(err**2)))
        )


class PolynomialInverse(eqx.Module):
    """Inverse of a :class:`PolynomialModel`; see :meth:`PolynomialModel.inverse`.

    Attributes:
        forward: the model being inverted.
        start: polynomial fitted destination -> source (the ``"fit"``
            inverse, and the Newton start).
        newton_steps: Newton iterations on ``forward`` (0 for ``"fit"``).
        max_error, rmse: round-trip error over the fitting domain (maximum
            and root mean square), source units.  ``rms_error`` is the old
            name of ``rmse``.
    """

    forward: PolynomialModel
    start: PolynomialModel
    newton_steps: int = eqx.field(static=True)
    max_error: Array
    rmse: Array

    @property
    def rms_error(self) -> Array:
        """Deprecated alias of :attr:`rmse` (one word for RMS errors across photax)."""
        return self.rmse

    def __call__(self, xy) -> Array:
        """``(..., 2)`` destination points -> ``(..., 2)`` source points."""
        return _apply_inverse(self, jnp.asarray(xy, dtype=float))


def _apply_inverse(inv: PolynomialInverse, q: Array) -> Array:
    """Fitted start, then Newton steps ``p -= J(p)^-1 (P(p) - q)`` with the
    analytic 2 x 2 Jacobian (plain jnp: cheap eagerly, traceable under jit)."""
    flat_q = q.reshape(-1, 2)
    p = inv.start(flat_q)
    for _ in range(inv.newton_steps):
        (a, b), (c, d) = _jacobian(inv.forward, p)
        r = inv.forward(p) - flat_q
        det = a * d - b * c
        p = p - jnp.stack([(d * r[:, 0] - b * r[:, 1]) / det, (a * r[:, 1] - c * r[:, 0]) / det], axis=-1)
    return p.reshape(q.shape)


def _jacobian(model: PolynomialModel, p: Array):
    """``((dX/dx, dX/dy), (dY/dx, dY/dy))`` of ``model`` at ``(N, 2)`` points,
    each ``(N,)``: d(x^i y^j) = i x^(i-1) y^j dx + j x^i y^(j-1) dy."""
    u = (p - model.src_centre[None, :]) / model.src_scale[None, :]
    x, y = u[:, 0], u[:, 1]
    xp, yp = [jnp.ones_like(x)], [jnp.ones_like(y)]
    for _ in range(model.order):
        xp.append(xp[-1] * x)
        yp.append(yp[-1] * y)
    exps = exponents(model.order)
    dx = jnp.stack([float(i) * xp[i - 1] * yp[j] if i else jnp.zeros_like(x) for i, j in exps], axis=-1) @ model.coef
    dy = jnp.stack([float(j) * xp[i] * yp[j - 1] if j else jnp.zeros_like(x) for i, j in exps], axis=-1) @ model.coef
    sx, sy = model.src_scale[0], model.src_scale[1]
    return (
        (model.dst_scale[0] * dx[:, 0] / sx, model.dst_scale[0] * dy[:, 0] / sy),
        (model.dst_scale[1] * dx[:, 1] / sx, model.dst_scale[1] * dy[:, 1] / sy),
    )


def fit_polynomial(src_xy, dst_xy, order: int, *, weights=None) -> PolynomialModel:
    """Least-squares polynomial ``dst = P(src)`` of ``order`` 1..5.

    Args:
        src_xy: ``(n, 2)`` source points (for indirect rectification: map /
            output coordinates; see the module docstring).
        dst_xy: ``(n, 2)`` destination points (e.g. input-image pixels).
        order: 1 (affine) .. 5; needs ``n >= (order+1)(order+2)/2``.
        weights: ``(n,)`` positive weights (inverse variances), default 1.

    Raises:
        ValueError: wrong shapes, NaN/inf, too few or duplicated points, or a
            rank-deficient design (points on a line or a curve that cannot
            determine the polynomial).

    Examples:
        Ground ``(X, Y)`` -> pixel of an aerial frame over flat land: order 2 takes up the 2-degree
        tilt, and the check points fit to the 0.3 px measurement noise:

        >>> import numpy as np
        >>> import photax as ptx
        >>> flat = ptx.relief_scene(0.0, seed=1, image_size=(400, 300), focal_px=400.0)
        >>> model = ptx.fit_polynomial(flat.gcp_ground[:, :2], flat.gcp_pixel, order=2)
        >>> model.residuals.shape, bool(model.rmse < 3 * flat.noise_px)
        ((30, 2), True)
        >>> error = np.asarray(model(flat.check_ground[:, :2])) - flat.check_pixel_true
        >>> bool(np.sqrt(np.mean(np.sum(error**2, axis=1))) < 3 * flat.noise_px)
        True
    """
    if not isinstance(order, (int, np.integer)) or not 1 <= order <= MAX_ORDER:
        raise ValueError(f"order must be an integer from 1 to {MAX_ORDER}, got {order!r}")
    order = int(order)
    u = n_coefficients(order)
    src, dst, w = _check_pairs(src_xy, dst_xy, weights, u, f"a polynomial of order {order}")
    n = src.shape[0]
    exps = exponents(order)
    sc, ss = _normaliser(src, "src_xy")
    dc, ds = _normaliser(dst, "dst_xy")
    a = _design((src - sc) / ss, exps)
    sw = np.sqrt(w)[:, None]
    aw = a * sw
    sv = np.linalg.svd(aw, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise ValueError(
            f"rank-deficient design for order {order}: the {n} src_xy points cannot determine the polynomial "
            f"(condition {sv[0] / max(sv[-1], 1e-300):.1e}; collinear or too few distinct points?)"
        )
    coef, *_ = np.linalg.lstsq(aw, ((dst - dc) / ds) * sw, rcond=None)
    v = ((a @ coef) * ds + dc) - dst  # computed - observed (docs/conventions.md)
    h = _hat_diag(aw)
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = np.where((1 - h)[:, None] > 1e-10, v / (1 - h)[:, None], np.nan)
    sraw = np.linalg.svd(_design(src, exps), compute_uv=False)
    rmse_dof = np.sqrt(np.sum(w[:, None] * v**2) / (2 * (n - u))) if n > u else np.nan
    f = jnp.asarray
    return PolynomialModel(
        order=order,
        coef=f(coef),
        src_centre=f(sc),
        src_scale=f(ss),
        dst_centre=f(dc),
        dst_scale=f(ds),
        residuals=f(v),
        rmse=f(np.sqrt(np.sum(v**2) / n)),
        rmse_dof=f(rmse_dof),
        condition=f(sv[0] / sv[-1]),
        condition_raw=f(sraw[0] / sraw[-1] if sraw[-1] > 0 else np.inf),
        loo_residuals=f(loo),
        src_xy=f(src),
        dst_xy=f(dst),
    )


def _hartley(p: np.ndarray, name: str) -> np.ndarray:
    """3x3 similarity moving ``p``'s centroid to 0 and its mean distance to
    sqrt(2) (Hartley 1997)."""
    c = p.mean(axis=0)
    d = np.linalg.norm(p - c, axis=1).mean()
    if d == 0:
        raise ValueError(f"{name} points are all identical")
    s = np.sqrt(2) / d
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])


def _apply_h(h: Array, p: Array) -> Array:
    """Homography ``h`` (3, 3) on ``(..., 2)`` points."""
    x, y = p[..., 0], p[..., 1]
    den = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return jnp.stack(
        [(h[0, 0] * x + h[0, 1] * y + h[0, 2]) / den, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / den], axis=-1
    )


class ProjectiveModel(eqx.Module):
    """A plane projective transform fitted by :func:`fit_projective`.

    ``model(xy)`` maps ``(..., 2)`` source points to destination points.
    Internally ``T_dst^-1 H_n T_src`` with Hartley normalisations ``T``.

    Attributes:
        h_normalised: ``(3, 3)`` homography between normalised points.
        src_norm, dst_norm: ``(3, 3)`` Hartley similarity transforms.
        residuals: ``(n, 2)`` ``model(src) - dst`` (computed - observed).
        rmse: ``sqrt(sum_i |v_i|^2 / n)``.
        rmse_dof: ``sqrt(sum_i w_i |v_i|^2 / (2n - 8))``, NaN for 4 points.
        condition: ratio of the largest to the 8th singular value of the
            normalised DLT matrix (the 9th is ~0 for a consistent fit).
        result: the :class:`photax.RESULTS` code of the geometric
            refinement (``successful`` without one); ``converged`` and
            ``message`` say the same.

    Examples:
        What :func:`fit_projective` returns: callable on ``(n, 2)`` points, with its residuals:

        >>> import numpy as np
        >>> import photax as ptx
        >>> src = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        >>> dst = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [1.5, 1.2]])  # four points fix a homography
        >>> model = ptx.fit_projective(src, dst)
        >>> print(np.round(np.asarray(model(src)), 6) + 0.0, f"{float(model.rmse):.6f}")
        [[0.  0. ]
         [2.  0. ]
         [0.  2. ]
         [1.5 1.2]] 0.000000
    """

    h_normalised: Array
    src_norm: Array
    dst_norm: Array
    residuals: Array
    rmse: Array
    rmse_dof: Array
    condition: Array
    result: RESULTS = eqx.field(static=True, default=RESULTS.successful)

    @property
    def converged(self) -> bool:
        return self.result == RESULTS.successful

    @property
    def message(self) -> str:
        return self.result.text if self.converged else f"projective refinement: {self.result.text}"

    @property
    def matrix(self) -> Array:
        """``(3, 3)`` homography in original units, scaled to ``h33 = 1``
        (as OpenCV's ``findHomography`` and scikit-image report it)."""
        h = jnp.linalg.solve(self.dst_norm, self.h_normalised @ self.src_norm)
        return h / h[2, 2]

    def __call__(self, xy) -> Array:
        """``(..., 2)`` source points -> ``(..., 2)`` destination points."""
        p = _query(xy)
        q = _apply_h(self.h_normalised, _apply_h(self.src_norm, p))
        return _apply_h(jnp.linalg.inv(self.dst_norm), q)

    def inverse(self) -> ProjectiveModel:
        """The exact inverse (destination -> source), by matrix inversion.

        The quality figures (``residuals``, ``rmse``, ...) are those of the
        forward fit, in destination units.
        """
        return ProjectiveModel(
            jnp.linalg.inv(self.h_normalised),
            self.dst_norm,
            self.src_norm,
            self.residuals,
            self.rmse,
            self.rmse_dof,
            self.condition,
            self.result,
        )


def fit_projective(src_xy, dst_xy, *, weights=None, refine: bool = True, throw: bool = True) -> ProjectiveModel:
    """Projective (homography) ``dst = H(src)`` from 4+ point pairs.

    Hartley-normalised DLT (H&Z alg. 4.2): each pair gives two rows of
    ``A h = 0``, ``h`` is the right singular vector of the smallest singular
    value.  With more than 4 points and ``refine=True`` the 8 parameters are
    then refined by Levenberg-Marquardt (optimistix) on the geometric
    (destination) error, which the DLT's algebraic error only approximates.
    ``throw=True`` (one estimate: docs/architecture.md) raises
    :class:`photax.ConvergenceError` when the refinement fails; with
    ``throw=False`` the model carries the code in ``result``.

    Raises:
        ValueError: wrong shapes, NaN/inf, fewer than 4 or duplicated points,
            or a degenerate configuration (3 of 4 points collinear).

    Examples:
        A plane maps projectively: ground ``(X, Y)`` -> pixel of a frame over flat land, checked on
        the noise-free projections of the check points:

        >>> import numpy as np
        >>> import photax as ptx
        >>> flat = ptx.relief_scene(0.0, seed=1, image_size=(400, 300), focal_px=400.0)
        >>> model = ptx.fit_projective(flat.gcp_ground[:, :2], flat.gcp_pixel)
        >>> model.converged, model.result.name
        (True, 'successful')
        >>> error = np.asarray(model(flat.check_ground[:, :2])) - flat.check_pixel_true
        >>> print(f"check points off by {np.sqrt(np.mean(np.sum(error**2, axis=1))):.1f} px")
        check points off by 0.1 px
    """
    src, dst, w = _check_pairs(src_xy, dst_xy, weights, 4, "a projective transform")
    n = src.shape[0]
    ts, td = _hartley(src, "src_xy"), _hartley(dst, "dst_xy")
    ps = src @ ts[:2, :2].T + ts[:2, 2][None, :]
    pd = dst @ td[:2, :2].T + td[:2, 2][None, :]
    one, zero = np.ones(n), np.zeros(n)
    x, y, xd, yd = ps[:, 0], ps[:, 1], pd[:, 0], pd[:, 1]
    rows_x = np.stack([x, y, one, zero, zero, zero, -xd * x, -xd * y, -xd], axis=1)
    rows_y = np.stack([zero, zero, zero, x, y, one, -yd * x, -yd * y, -yd], axis=1)
    sw = np.sqrt(w)[:, None]
    a = np.concatenate([rows_x * sw, rows_y * sw])
    _, sv, vt = np.linalg.svd(a)
    if sv[7] <= 1e-10 * sv[0]:
        raise DegenerateGeometryError("degenerate configuration for a projective transform: 3 or more points collinear")
    hn = vt[-1].reshape(3, 3)
    hn = hn / hn[2, 2] if abs(hn[2, 2]) > 1e-12 * np.abs(hn).max() else hn / np.abs(hn).max()
    code = RESULTS.successful
    if refine and n > 4:
        hn, code = _refine(hn, ps, pd, w)
        if throw and code != RESULTS.successful:
            raise ConvergenceError(f"projective refinement failed: {code.text}")
    model = ProjectiveModel(jnp.asarray(hn), jnp.asarray(ts), jnp.asarray(td), *(jnp.zeros(()),) * 4)
    v = np.asarray(model(src)) - dst  # computed - observed
    rmse_dof = np.sqrt(np.sum(w[:, None] * v**2) / (2 * n - 8)) if n > 4 else np.nan
    f = jnp.asarray
    return ProjectiveModel(f(hn), f(ts), f(td), f(v), f(np.sqrt(np.sum(v**2) / n)), f(rmse_dof), f(sv[0] / sv[7]), code)


#: Iteration limit of the projective refinement (Levenberg-Marquardt from the
#: DLT, which is already close: a handful of steps in practice).
REFINE_MAX_STEPS = 100


@jax.jit
def _refine_solve(p8, h33, ps, pd, sw):
    """optimistix's Levenberg-Marquardt on ``sum w |H(ps) - pd|^2`` over the
    first eight entries of ``H`` (``h33`` fixed): ``(p8, RESULTS code)``.
    Autodiff Jacobian (8 unknowns: cheap); padded rows have ``sw = 0``."""
    import optimistix as optx

    def resid(p, _):
        h = jnp.concatenate([p, h33[None]]).reshape(3, 3)
        return ((_apply_h(h, ps) - pd) * sw[:, None]).reshape(-1)

    solver = optx.LevenbergMarquardt(rtol=1e-12, atol=1e-12)
    sol = optx.least_squares(resid, solver, p8, max_steps=REFINE_MAX_STEPS, throw=False)
    ok = jnp.all(jnp.isfinite(sol.value))
    return sol.value, jnp.where(ok, from_optimistix(sol.result), RESULTS.nonfinite)


def _refine(hn: np.ndarray, ps: np.ndarray, pd: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, RESULTS]:
    """The geometric refinement of the normalised homography ``hn`` (the
    one shared solver, optimistix, as resection's fallback): ``(H, code)``;
    ``H`` is the DLT's where the solver did not end on finite values.  The
    points are padded to a power of two (zero weight) so that fits of
    similar size share one compilation."""
    n = len(ps)
    size = max(8, 1 << (n - 1).bit_length())
    pad = lambda a: np.concatenate([a, np.zeros((size - n,) + a.shape[1:])])  # noqa: E731
    ps_p, pd_p = pad(ps), pad(pd)
    ps_p[n:] = ps[0]  # finite positions for the padded rows (weight 0)
    fixed = float(hn[2, 2])
    p, code = _refine_solve(jnp.asarray(hn.reshape(-1)[:8]), jnp.asarray(fixed), jnp.asarray(ps_p), jnp.asarray(pd_p),
                            jnp.asarray(pad(np.sqrt(w))))  # fmt: skip
    code = RESULTS(int(code))
    if code == RESULTS.nonfinite:
        return hn, code
    return np.concatenate([np.asarray(p), [fixed]]).reshape(3, 3), code


class TPSModel(eqx.Module):
    """A thin-plate spline ``dst = f(src)`` fitted by :func:`fit_tps`.

    ``f(p) = a_0 + a_1 x + a_2 y + sum_i w_i U(|p - c_i|)``, ``U(r) = r^2 log r`` (Bookstein 1989), per
    destination axis, on source points centred and scaled by one factor (an isotropic normalisation leaves
    the interpolating spline unchanged: ``U(s r) = s^2 U(r) + s^2 log(s) r^2``, and the side conditions
    ``sum w_i = 0``, ``sum w_i c_i = 0`` turn the ``r^2`` term into a constant).  ``model(xy)``: ``(..., 2)``
    source -> ``(..., 2)`` destination points, jax-traceable (a :func:`photax.rectify` model); its cost
    grows with the number of control points per evaluated point.

    Attributes:
        centres: ``(n, 2)`` normalised control points ``c_i``.
        weights: ``(n, 2)`` spline weights ``w_i`` (columns X, Y).
        affine: ``(3, 2)`` ``a_0, a_1, a_2``.
        src_centre: ``(2,)``; src_scale: ``()`` the normalisation.
        smoothing: ``lambda`` added to the kernel's diagonal (0: interpolation).
        residuals: ``(n, 2)`` ``model(src) - dst`` (0 to rounding when ``smoothing == 0``).
        rmse: radial RMS of ``residuals``.
        loo_residuals: ``(n, 2)`` leave-one-out residuals: the spline fitted without point ``i``,
            evaluated at it, minus ``dst_i`` (NaN where the other points cannot carry a spline).
        src_xy, dst_xy: the control points.

    Examples:
        What :func:`fit_tps` returns: a map through every control point, smooth between them:

        >>> import numpy as np
        >>> import photax as ptx
        >>> src = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 5.0]])
        >>> dst = src + [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [1.0, -1.0]]  # the middle one moved
        >>> tps = ptx.fit_tps(src, dst)
        >>> print(np.round(np.asarray(tps(src[4:])), 6))
        [[6. 4.]]
    """

    centres: Array
    weights: Array
    affine: Array
    src_centre: Array
    src_scale: Array
    smoothing: float = eqx.field(static=True)
    residuals: Array
    rmse: Array
    loo_residuals: Array
    src_xy: Array
    dst_xy: Array

    def __call__(self, xy) -> Array:
        """``(..., 2)`` source points -> ``(..., 2)`` destination points."""
        p = _query(xy)
        one = (1,) * (p.ndim - 1)  # explicit broadcasting (photax runs with rank promotion as an error)
        u = (p - self.src_centre.reshape(one + (2,))) / self.src_scale.reshape(one + (1,))
        centres = self.centres.reshape(one + self.centres.shape)
        d2 = jnp.sum((u[..., None, :] - centres) ** 2, axis=-1)  # (..., n)
        return self.affine[0].reshape(one + (2,)) + u @ self.affine[1:] + _tps_kernel(d2) @ self.weights

    def transform(self, x, y) -> tuple[Array, Array]:
        """Separate-coordinate form ``X, Y = model.transform(x, y)``."""
        out = self(jnp.stack([jnp.asarray(x, dtype=float), jnp.asarray(y, dtype=float)], axis=-1))
        return out[..., 0], out[..., 1]

    @property
    def condition(self) -> float:
        """2-norm condition number of the spline's system ``[[K + lambda I, P], [P^T, 0]]`` (normalised)."""
        u = np.asarray(self.centres)
        k = _tps_kernel(np.sum((u[:, None] - u[None]) ** 2, axis=-1), np) + self.smoothing * np.eye(len(u))
        p = np.concatenate([np.ones((len(u), 1)), u], axis=1)
        return float(np.linalg.cond(np.block([[k, p], [p.T, np.zeros((3, 3))]])))


def _tps_kernel(d2, xp=jnp):
    """``U = r^2 log r = d2 log(d2) / 2`` of squared distances, 0 at 0 (double-where: finite gradients);
    ``xp``: jax.numpy (traceable) or numpy (the fit: no compilation per point count)."""
    safe = xp.where(d2 > 0, d2, 1.0)
    return xp.where(d2 > 0, 0.5 * safe * xp.log(safe), 0.0)


def _tps_solve(u: np.ndarray, v: np.ndarray, smoothing: float) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``(n, 2)`` and affine part ``(3, 2)`` of the spline through ``v`` at normalised ``u``:
    ``[[K + lambda I, P], [P^T, 0]] [w; a] = [v; 0]``, ``P = [1, x, y]``."""
    n = u.shape[0]
    d2 = np.sum((u[:, None] - u[None]) ** 2, axis=-1)
    k = _tps_kernel(d2, np) + smoothing * np.eye(n)
    p = np.concatenate([np.ones((n, 1)), u], axis=1)
    m = np.block([[k, p], [p.T, np.zeros((3, 3))]])
    sol = np.linalg.solve(m, np.concatenate([v, np.zeros((3, 2))]))
    return sol[:n], sol[n:]


def fit_tps(src_xy, dst_xy, smoothing: float = 0.0) -> TPSModel:
    """Thin-plate spline ``dst = f(src)`` through the control points (Bookstein 1989; GDAL's ``-tps``).

    With ``smoothing == 0`` the spline interpolates: ``f(src_i) = dst_i``; ``smoothing > 0`` (in
    normalised units: the source points are scaled to a largest distance of 1 from their centre) trades
    that for a smoother map.  Fit ``fit_tps(map_xy, pixel_xy)`` for indirect rectification, as for
    :func:`fit_polynomial`.

    Raises:
        ValueError: wrong shapes, NaN/inf, duplicated or fewer than 3 points, points all on one line, or a
            negative smoothing.

    Examples:
        A thin-plate spline passes through every control point (no smoothing) and reproduces an
        affine map exactly:

        >>> import numpy as np
        >>> import photax as ptx
        >>> rng = np.random.default_rng(0)
        >>> src = rng.uniform(0, 100, (12, 2))
        >>> dst = src @ np.array([[1.1, 0.2], [-0.1, 0.9]]) + [5.0, -3.0]
        >>> tps = ptx.fit_tps(src, dst)
        >>> bool(np.allclose(tps(src), dst)), bool(np.allclose(tps(np.array([[50.0, 50.0]])), [[55.0, 52.0]]))
        (True, True)
    """
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise ValueError(f"smoothing must be finite and >= 0, got {smoothing!r}")
    src, dst, _ = _check_pairs(src_xy, dst_xy, None, 3, "a thin-plate spline")
    centre = src.mean(axis=0)
    scale = float(np.sqrt(np.sum((src - centre) ** 2, axis=1)).max())
    u = (src - centre) / scale
    if np.linalg.matrix_rank(np.concatenate([np.ones((len(u), 1)), u], axis=1), tol=1e-10) < 3:
        raise ValueError("src_xy points all lie on one line: a thin-plate spline needs them spread in 2-D")
    w, a = _tps_solve(u, dst, float(smoothing))
    model = TPSModel(
        jnp.asarray(u),
        jnp.asarray(w),
        jnp.asarray(a),
        jnp.asarray(centre),
        jnp.asarray(scale),
        float(smoothing),
        jnp.zeros_like(jnp.asarray(dst)),
        jnp.asarray(0.0),
        jnp.full(dst.shape, jnp.nan),
        jnp.asarray(src),
        jnp.asarray(dst),
    )
    v = np.asarray(model(src)) - dst
    loo = np.full(dst.shape, np.nan)
    for i in range(len(u)):
        keep = np.arange(len(u)) != i
        if keep.sum() < 3 or np.linalg.matrix_rank(np.c_[np.ones(keep.sum()), u[keep]], tol=1e-10) < 3:
            continue
        wi, ai = _tps_solve(u[keep], dst[keep], float(smoothing))
        d2 = np.sum((u[i] - u[keep]) ** 2, axis=-1)
        loo[i] = ai[0] + u[i] @ ai[1:] + _tps_kernel(d2, np) @ wi - dst[i]
    rmse = np.sqrt(np.sum(v**2) / len(v))
    return dataclasses.replace(model, residuals=jnp.asarray(v), rmse=jnp.asarray(rmse), loo_residuals=jnp.asarray(loo))


class PiecewiseAffineModel(eqx.Module):
    """A piecewise-affine map ``dst = f(src)`` fitted by :func:`fit_piecewise_affine`.

    The control points are triangulated (Delaunay, on source points centred and scaled by one factor, which
    leaves the triangulation unchanged) and each triangle carries the affine map through its three corners'
    ``dst``: continuous inside the convex hull, exact at the control points.  Outside the hull it is NaN
    (as scikit-image's ``PiecewiseAffineTransform``): the nearest triangle's affine would jump where the
    nearest triangle changes and is only as good as a one-triangle affine far from the points, so a
    rectification leaves those pixels no-data rather than guess.  :meth:`inside` tells the two apart.
    ``model(xy)``: ``(..., 2)`` source -> ``(..., 2)`` destination points, jax-traceable (a
    :func:`photax.rectify` model); its cost grows with the number of triangles per evaluated point.

    Attributes:
        corners: ``(t, 3, 2)`` normalised triangle corners.
        affine: ``(t, 3, 2)`` per triangle ``dst = a_0 + u a_1 + v a_2`` in normalised ``(u, v)``.
        src_centre: ``(2,)``; src_scale: ``()`` the normalisation.
        simplices: ``(t, 3)`` indices of the corners into ``src_xy``.
        residuals: ``(n, 2)`` ``model(src) - dst`` (0 to rounding).
        rmse: radial RMS of ``residuals``.
        loo_residuals: ``(n, 2)`` leave-one-out residuals: the model rebuilt (triangulation included)
            without point ``i``, evaluated at it, minus ``dst_i`` (NaN for a hull vertex, which lies outside
            the others' hull, and where the other points cannot be triangulated).
        src_xy, dst_xy: the control points.

    Examples:
        What :func:`fit_piecewise_affine` returns; outside the triangles of the control points
        (their convex hull) it gives NaN:

        >>> import numpy as np
        >>> import photax as ptx
        >>> src = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
        >>> model = ptx.fit_piecewise_affine(src, src + 1.0)
        >>> print(np.asarray(model(np.array([[2.0, 2.0], [20.0, 20.0]]))))
        [[ 3.  3.]
         [nan nan]]
    """

    corners: Array
    affine: Array
    src_centre: Array
    src_scale: Array
    simplices: Array
    residuals: Array
    rmse: Array
    loo_residuals: Array
    src_xy: Array
    dst_xy: Array

    def _normalised(self, xy) -> Array:
        p = _query(xy)
        one = (1,) * (p.ndim - 1)
        return (p - self.src_centre.reshape(one + (2,))) / self.src_scale.reshape(one + (1,))

    def __call__(self, xy) -> Array:
        """``(..., 2)`` source points -> ``(..., 2)`` destination points; NaN outside the control points'
        convex hull."""
        value, dist = _pwa_eval(self.corners, self.affine, self._normalised(xy))
        return jnp.where((dist <= 1e-12)[..., None], value, jnp.nan)

    def inside(self, xy) -> Array:
        """``(...)`` True where ``xy`` lies in the convex hull of the control points (interpolated, not
        extrapolated)."""
        return _pwa_eval(self.corners, self.affine, self._normalised(xy))[1] <= 1e-12

    def transform(self, x, y) -> tuple[Array, Array]:
        """Separate-coordinate form ``X, Y = model.transform(x, y)``."""
        out = self(jnp.stack([jnp.asarray(x, dtype=float), jnp.asarray(y, dtype=float)], axis=-1))
        return out[..., 0], out[..., 1]

    @property
    def condition(self) -> float:
        """Largest 2-norm condition number of the triangles' ``[1, u, v]`` systems (normalised): a sliver
        triangle carries an ill-determined affine."""
        c = np.asarray(self.corners)
        return float(np.linalg.cond(np.concatenate([np.ones(c.shape[:2] + (1,)), c], axis=-1)).max())


def _pwa_eval(corners, affine, u, xp=jnp):
    """Values ``(..., 2)`` and distance ``(...)`` to the nearest of the triangles ``corners`` ``(t, 3, 2)``
    at normalised points ``u`` ``(..., 2)``, with that triangle's affine ``(t, 3, 2)``; ``xp``: jax.numpy
    (traceable) or numpy (the fit's leave-one-out loop: no dispatch per operation)."""
    corners, affine, u = xp.asarray(corners), xp.asarray(affine), xp.asarray(u)
    q = u[..., None, :]  # (..., 1, 2) against (t, 2) per corner
    one = (1,) * (u.ndim - 1)
    c = corners.reshape(one + corners.shape)
    a, b, d = c[..., 0, :], c[..., 1, :], c[..., 2, :]

    def cross(e, f):
        return e[..., 0] * f[..., 1] - e[..., 1] * f[..., 0]

    area = cross(b - a, d - a)  # signed twice the area
    bary = xp.stack([cross(b - q, d - q), cross(d - q, a - q), cross(a - q, b - q)], axis=-1) / area[..., None]
    inside = xp.min(bary, axis=-1) >= -1e-12

    def seg2(p0, p1):  # squared distance of q to the segment p0-p1
        e = p1 - p0
        t = xp.clip(xp.sum((q - p0) * e, axis=-1) / xp.sum(e * e, axis=-1), 0.0, 1.0)
        return xp.sum((q - p0 - t[..., None] * e) ** 2, axis=-1)

    dist2 = xp.where(inside, 0.0, xp.minimum(xp.minimum(seg2(a, b), seg2(b, d)), seg2(d, a)))  # (..., t)
    k = xp.argmin(dist2, axis=-1)
    coef = affine[k]  # (..., 3, 2)
    value = coef[..., 0, :] + u[..., :1] * coef[..., 1, :] + u[..., 1:] * coef[..., 2, :]
    return value, xp.sqrt(xp.take_along_axis(dist2, k[..., None], axis=-1)[..., 0])


def _pwa_build(u: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Delaunay triangles ``(t, 3)`` of ``u``, their corners ``(t, 3, 2)`` and affines ``(t, 3, 2)``."""
    from scipy.spatial import Delaunay, QhullError

    try:
        tri = Delaunay(u)
    except QhullError as e:
        raise ValueError("src_xy points cannot be triangulated (all on one line?)") from e
    simplices = np.asarray(tri.simplices)
    corners = u[simplices]
    design = np.concatenate([np.ones(simplices.shape + (1,)), corners], axis=-1)  # (t, 3, 3)
    affine = np.linalg.solve(design, dst[simplices])
    return simplices, corners, affine


def fit_piecewise_affine(src_xy, dst_xy) -> PiecewiseAffineModel:
    """Piecewise-affine map ``dst = f(src)``: one affine per Delaunay triangle of the control points (as
    scikit-image's ``PiecewiseAffineTransform``); NaN outside their convex hull (:class:`PiecewiseAffineModel`).  Fit ``fit_piecewise_affine(map_xy,
    pixel_xy)`` for indirect rectification, as for :func:`fit_polynomial`.

    Raises:
        ValueError: wrong shapes, NaN/inf, duplicated or fewer than 3 points, points all on one line.

    Examples:
        One affine map per Delaunay triangle of the control points: exact at the points, and inside
        a triangle the affine map of its corners:

        >>> import numpy as np
        >>> import photax as ptx
        >>> src = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
        >>> dst = 2.0 * src + [1.0, 1.0]
        >>> model = ptx.fit_piecewise_affine(src, dst)
        >>> print(np.asarray(model(np.array([[2.5, 5.0], [10.0, 10.0]]))))
        [[ 6. 11.]
         [21. 21.]]
    """
    src, dst, _ = _check_pairs(src_xy, dst_xy, None, 3, "a piecewise-affine map")
    centre = src.mean(axis=0)
    scale = float(np.sqrt(np.sum((src - centre) ** 2, axis=1)).max())
    u = (src - centre) / scale
    if np.linalg.matrix_rank(np.concatenate([np.ones((len(u), 1)), u], axis=1), tol=1e-10) < 3:
        raise ValueError("src_xy points all lie on one line: a piecewise-affine map needs them spread in 2-D")
    simplices, corners, affine = _pwa_build(u, dst)
    v = _pwa_eval(corners, affine, u, np)[0] - dst
    loo = np.full(dst.shape, np.nan)
    for i in range(len(u)):
        keep = np.arange(len(u)) != i
        if keep.sum() < 3 or np.linalg.matrix_rank(np.c_[np.ones(keep.sum()), u[keep]], tol=1e-10) < 3:
            continue
        _, ci, ai = _pwa_build(u[keep], dst[keep])
        value, dist = _pwa_eval(ci, ai, u[i], np)
        loo[i] = value - dst[i] if dist <= 1e-12 else np.nan  # a hull vertex: outside the others' hull
    return PiecewiseAffineModel(
        jnp.asarray(corners),
        jnp.asarray(affine),
        jnp.asarray(centre),
        jnp.asarray(scale),
        jnp.asarray(simplices),
        jnp.asarray(v),
        jnp.asarray(np.sqrt(np.sum(v**2) / len(v))),
        jnp.asarray(loo),
        jnp.asarray(src),
        jnp.asarray(dst),
    )
