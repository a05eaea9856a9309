"""Image matching: normalised cross-correlation and least-squares matching (Gruen 1985).

Both take a template window of ``(2 window + 1)^2`` px centred on
``template_xy`` in ``template_image`` (NCC samples it by cubic-spline
interpolation when ``template_xy`` is not integer; LSM keeps the window on its
integer pixels and carries the sub-pixel centre through the fitted affine map) and return where its centre lies in
``search_image``, for many points in one vectorised call.

* :func:`match_ncc`: the correlation coefficient
  ``rho = sum (s - s_mean)(t - t_mean) / sqrt(sum (s - s_mean)^2 sum (t - t_mean)^2)``
  at every integer shift within ``search`` px of the approximation, the
  maximum, and a parabola through it and its neighbours in each direction
  (``d = (rho_- - rho_+) / (2 (rho_- - 2 rho_0 + rho_+))``).  Covariance
  (Förstner 1984): noise-to-signal ``sigma_n^2 = var(t) (1 - rho) / rho``
  and ``Cov = sigma_n^2 (sum grad t grad t^T)^-1``.  It does not include
  the parabola's own systematic error (measured ~0.06 px rms on the textures
  of the tests, where LSM reaches 0.02 px): use NCC as the approximation for LSM.
* :func:`match_lsm`: Gruen's adaptive least-squares matching,
  ``g1(x, y) + v = r0 + r1 g2(a0 + (1 + a1) x + a2 y, b0 + b1 x + (1 + b2) y)``
  (6 affine, 2 radiometric parameters; ``x, y`` template offsets from its
  centre), linearised with the cubic-spline-resampled search image's gradients and
  iterated.  ``sigma0^2 = v^T v / (n - 8)``, ``Cov = f sigma0^2 (A^T A)^-1``,
  of which the ``(a0, b0)`` block is the shift's covariance; ``f = n / n_eff
  = 1 + sum rho`` over the residuals' correlation with their 8 neighbours
  (resampling correlates them).

Source: Gruen (1985), "Adaptive least squares correlation: a powerful image
matching technique", S. Afr. J. Photogramm. 14(3); seed 004 / docs/maths.md.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..kernels import kernel_weights
from ._filters import _gradient2d
from ._result import Status, as_images, as_points, check_window, finish, patch, round_centre

PAD = 4  # px read beyond the sampled area: the spline prefilter's mirror boundary
# decays by 2 - sqrt(3) = 0.27 per px, so at 4 px its effect on the samples is < 0.5 %


@functools.cache
def _prefilter_matrix(m: int) -> np.ndarray:
    """``(m, m)`` matrix turning ``m`` samples into cubic B-spline coefficients:
    the inverse of the interpolation condition ``(c[i-1] + 4 c[i] + c[i+1]) / 6 = s[i]``
    with a mirror boundary (``c[-1] = c[1]``)."""
    t = 4 / 6 * np.eye(m)
    for i in range(m):
        for j in (i - 1, i + 1):
            t[i, -j if j < 0 else (2 * (m - 1) - j if j >= m else j)] += 1 / 6
    return np.linalg.inv(t)


def _spline(p):
    """Cubic B-spline coefficients of a square patch ``p`` (m, m, k), channels last, in
    float32 (what :func:`_spline_sample` reads; half the time of float64)."""
    q = jnp.asarray(_prefilter_matrix(p.shape[0]), jnp.float32)
    return jnp.einsum("ij,jlc,kl->ikc", q, p.astype(jnp.float32), q)


def _correlation_factor(v):
    """``n / n_eff`` for residuals ``v`` (k, k) correlated with their 8 neighbours:
    ``1 + sum_{d != 0, |d| <= 1} rho(d)`` (at least 1), the variance of a sum of
    ``n`` observations relative to ``n`` independent ones.  Resampling the search
    (and a sub-pixel template) correlates neighbouring residuals; without it
    ``sigma0^2 (A^T A)^-1`` was optimistic by 0.75-0.95x at 1 % noise."""
    k = v.shape[0]
    c0 = jnp.sum(v * v)
    c = c0
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                y0, y1, x0, x1 = max(0, -dy), k - max(0, dy), max(0, -dx), k - max(0, dx)
                c = c + jnp.sum(v[y0:y1, x0:x1] * v[y0 + dy : y1 + dy, x0 + dx : x1 + dx])
    return jnp.maximum(c / jnp.where(c0 > 0, c0, 1.0), 1.0)


def _spline_sample(c, x, y):
    """The cubic B-spline with coefficients ``c`` (h, w, k) at patch coordinates
    ``x`` (col), ``y`` (row) (any shape; ``(..., k)`` out).

    Cubic-spline interpolation (Unser 1999, "Splines: a perfect fit for signal
    and image processing") rather than Keys' cubic convolution: on the textures
    of the tests Keys' phase error moved LSM's shift by 0.011 px rms, the
    spline's by 0.0007 px."""
    h, w, k = c.shape
    x0, y0 = jnp.floor(x), jnp.floor(y)
    # the taps in float32 (the sums of 16 weighted taps lose ~1e-7 of the grey values, far
    # below the spline's own error), one 4 x 4 block per sample, and the weights applied one
    # axis at a time as two contractions: 0.65x the time of a gather per tap and an einsum
    # over their outer product, float64
    f32 = jnp.float32
    c = c.astype(f32)
    wx = jnp.stack(kernel_weights("bspline", x - x0, xp=jnp), axis=-1).astype(f32)
    wy = jnp.stack(kernel_weights("bspline", y - y0, xp=jnp), axis=-1).astype(f32)
    ix = jnp.clip(x0.astype(jnp.int32) - 1, 0, w - 4)
    iy = jnp.clip(y0.astype(jnp.int32) - 1, 0, h - 4)

    def block(r, col):
        return jax.lax.dynamic_slice(c, (r, col, jnp.int32(0)), (4, 4, k))

    for _ in range(x.ndim):
        block = jax.vmap(block)
    vals = block(iy, ix)  # (..., 4, 4, k) [row tap, col tap]
    rows = jnp.einsum("...ijc,...j->...ic", vals, wx)
    return jnp.einsum("...i,...ic->...c", wy, rows).astype(jnp.float64)


def _sample_rows(f, half, size):
    """``(2 half + 1, size)`` matrix taking ``size`` samples to the cubic spline (mirror
    boundary, :func:`_prefilter_matrix`) at ``centre + off + f``, ``off = -half .. half``,
    ``centre = size // 2``, ``-0.5 <= f <= 0.5``: the B-spline weights applied to rows of the
    prefilter.  A window shifted by one fraction is separable, ``My p Mx^T``: two small
    matrix products instead of a 4 x 4 gather per pixel."""
    q = jnp.asarray(_prefilter_matrix(size))
    fl = jnp.floor(f)
    w = kernel_weights("bspline", f - fl, xp=jnp)  # taps at floor(x) - 1 .. floor(x) + 2
    first = size // 2 - half - 1 + fl.astype(jnp.int32)
    return sum(wk * jax.lax.dynamic_slice_in_dim(q, first + k, 2 * half + 1) for k, wk in enumerate(w))


def _template(img, xy, half, interpolate=True):
    """Template window around ``xy`` (cubic spline when sub-pixel, the pixels themselves
    when not), whether it is inside and finite.  ``interpolate=False`` takes the pixels
    around the rounded ``xy`` (for callers that know every centre is integer)."""
    ci = round_centre(xy)
    cf = ci.astype(jnp.float64)
    big = half + 2 + PAD
    p, inside = patch(img, ci, big)
    p = p.astype(jnp.float64)
    fin = jnp.all(jnp.isfinite(p))
    p = jnp.where(fin, p, 0.0)
    t = p[big - half : big + half + 1, big - half : big + half + 1]
    if interpolate:
        frac = jnp.where(jnp.all(jnp.isfinite(xy)), xy - cf, 0.0)
        size = 2 * big + 1
        spline = _sample_rows(frac[1], half, size) @ p @ _sample_rows(frac[0], half, size).T
        t = jnp.where(jnp.all(frac == 0), t, spline)
    return t, inside, fin


def _templates(img, xy, half):
    """:func:`_template` for every point of a batch ``(b, n, 2)``; the interpolation is
    skipped (one branch for the whole batch) when every centre is integer, the usual case."""

    def run(interpolate):
        one = functools.partial(_template, half=half, interpolate=interpolate)
        return jax.vmap(jax.vmap(one, in_axes=(None, 0)))(img, xy)

    integer = jnp.all(~jnp.isfinite(xy) | (xy == jnp.round(xy)))
    return jax.lax.cond(integer, lambda: run(False), lambda: run(True))


# --------------------------------------------------------------------------- NCC


def _ncc_one(t, t_in, t_fin, simg, sxy, *, half, search):
    t = jnp.where(t_fin, t, 0.0)
    n = (2 * half + 1) ** 2
    t0 = t - jnp.mean(t)
    tt = jnp.sum(t0 * t0)
    ci = round_centre(sxy)
    cf = ci.astype(jnp.float64)
    big = half + search + 1
    s, s_in = patch(simg, ci, big)
    s = s.astype(jnp.float64)
    s_fin = jnp.all(jnp.isfinite(s))
    s = jnp.where(s_fin, s, 0.0)
    k = 2 * half + 1
    m = 2 * (search + 1) + 1  # shifts -(search+1) .. search+1
    # cross products at every shift by FFT (exact here: the window never
    # wraps, dy + i < m + k - 1 = patch size); correlate2d under vmap became
    # a grouped convolution that XLA:CPU ran ~1000x slower.  In float32, of the
    # search window less its mean (OpenCV's matchTemplate computes in float32 too):
    # half the time of float64, ~1e-6 in rho.
    size = s.shape
    f32 = jnp.float32
    tpad = jnp.pad(t0.astype(f32), ((0, size[0] - k), (0, size[1] - k)))
    sc = (s - jnp.mean(s)).astype(f32)
    cross = jnp.fft.irfft2(jnp.fft.rfft2(sc) * jnp.conj(jnp.fft.rfft2(tpad)), s=size)[:m, :m].astype(jnp.float64)

    # window sums of s and s^2 as sums of shifted slices, rows then columns (XLA fuses
    # them; the integral image's cumsum was 20x slower)
    def box(a):
        r = sum(a[:, j : j + m] for j in range(k))
        return sum(r[i : i + m] for i in range(k))

    ss = box(s * s) - box(s) ** 2 / n
    rho = cross / jnp.sqrt(jnp.where((ss > 0) & (tt > 0), ss * tt, 1.0))
    rho = jnp.where(ss > 1e-12 * (1 + jnp.max(jnp.abs(s))) ** 2 * n, rho, -1.0)
    inner = rho[1:-1, 1:-1]
    j = jnp.argmax(inner)
    iy, ix = j // (m - 2) + 1, j % (m - 2) + 1
    r0 = rho[iy, ix]

    def para(a, b, c):
        den = a - 2 * b + c
        return jnp.where(den < 0, 0.5 * (a - c) / jnp.where(den < 0, den, -1.0), 0.0)

    dx = para(rho[iy, ix - 1], r0, rho[iy, ix + 1])
    dy = para(rho[iy - 1, ix], r0, rho[iy + 1, ix])
    xy = cf + jnp.array([(ix - (search + 1)).astype(jnp.float64) + dx, (iy - (search + 1)).astype(jnp.float64) + dy])
    gx, gy = _gradient2d(t, "central", "nearest")
    mm = jnp.array([[jnp.sum(gx * gx), jnp.sum(gx * gy)], [jnp.sum(gx * gy), jnp.sum(gy * gy)]])
    det = mm[0, 0] * mm[1, 1] - mm[0, 1] ** 2
    minv = jnp.array([[mm[1, 1], -mm[0, 1]], [-mm[0, 1], mm[0, 0]]]) / jnp.where(det > 0, det, 1.0)
    rc = jnp.clip(r0, 1e-6, 1.0)
    sn2 = tt / n * (1.0 - rc) / rc
    cov = sn2 * minv
    edge = (ix == 1) | (ix == m - 2) | (iy == 1) | (iy == m - 2)
    status = jnp.select(
        [
            ~(t_in & s_in),
            ~(t_fin & s_fin),
            tt <= 1e-12 * (1 + jnp.max(jnp.abs(t))) ** 2 * n,
            ~(r0 > 0) | (det <= 0),
            edge,
        ],
        [Status.OUTSIDE, Status.NOT_FINITE, Status.TEXTURELESS, Status.ILL_CONDITIONED, Status.LEFT_WINDOW],
        Status.OK,
    )
    return xy, cov, status, jnp.sqrt(sn2), jnp.zeros((), jnp.int32), r0


@functools.partial(jax.jit, static_argnames=("half", "search"))
def _ncc(timg, txy, simg, sxy, *, half, search):
    t, t_in, t_fin = _templates(timg, txy, half)
    one = functools.partial(_ncc_one, half=half, search=search)
    xy, cov, st, s0, k, rho = jax.vmap(jax.vmap(one, in_axes=(0, 0, 0, None, 0)))(t, t_in, t_fin, simg, sxy)
    return finish(xy, cov, st, s0, k), jnp.where(st == Status.OK, rho, jnp.nan)


def match_ncc(
    template_image, template_xy, search_image, approx_xy, *, window: int = 10, search: int = 5, return_rho: bool = False
):
    """Match template windows into a search image by normalised cross-correlation.

    Args:
        template_image, search_image: ``(h, w)`` images (or ``(b, h, w)``
            batches of the same length), any integer or float dtype.
        template_xy: ``(n, 2)`` centres (column, row) px of the template
            windows (``(b, n, 2)`` for batches).
        approx_xy: ``(n, 2)`` approximate positions in the search image.
        window: half-size of the ``(2 window + 1)^2`` template.
        search: integer shifts up to ``search`` px in each direction.
        return_rho: also return the ``(n,)`` peak correlation coefficients.

    Returns:
        :class:`LocateResult` (``xy`` in the search image; ``sigma0`` is the
        noise level ``sigma_n`` in grey values; a peak on the border of the
        search range gets ``Status.LEFT_WINDOW``), and ``rho`` if asked.

    Examples:
        A template found in a shifted copy of its image (by 3 columns, -2 rows), to the pixel:

        >>> import numpy as np
        >>> from photax.measure import match_ncc
        >>> rng = np.random.default_rng(0)
        >>> a = rng.normal(size=(60, 60))
        >>> b = np.roll(a, (-2, 3), axis=(0, 1))
        >>> res = match_ncc(a, np.array([[30.0, 30.0]]), b, np.array([[31.0, 29.0]]), window=8, search=4)
        >>> print(np.round(np.asarray(res.xy), 1) + 0.0)
        [[33. 28.]]
    """
    res, rho = _pair(
        template_image,
        template_xy,
        search_image,
        approx_xy,
        window,
        window + search + 1,
        lambda ti, tx, si, sx: _ncc(ti, tx, si, sx, half=int(window), search=int(search)),
    )
    if search < 1:
        raise ValueError(f"search: must be >= 1 px, got {search}")
    return (res, rho) if return_rho else res


# --------------------------------------------------------------------------- LSM


def _lsm_one(timg, txy, simg, sxy, *, half, margin, iterations, tol):
    # The template on its integer pixels (never resampled: its noise stays white, and no
    # interpolation error enters); the sub-pixel centre ``ft`` goes through the fitted affine map.
    tc = round_centre(txy)
    ft = jnp.where(jnp.all(jnp.isfinite(txy)), txy - tc.astype(jnp.float64), 0.0)
    g1, t_in, t_fin = _template(timg, txy, half, interpolate=False)
    g1 = jnp.where(t_fin, g1, 0.0)
    ci = round_centre(sxy)
    cf = ci.astype(jnp.float64)
    big = half + margin
    s, s_in = patch(simg, ci, big + PAD)
    s = s.astype(jnp.float64)
    s_fin = jnp.all(jnp.isfinite(s))
    s = jnp.where(s_fin, s, 0.0)
    # value and gradient in one gather per iteration; central differences, not the
    # spline's own derivative, which amplifies the noise (LSM's error grew 1.4-1.9x with it)
    gxs, gys = _gradient2d(s, "central", "nearest")
    # the spline in float32 (_spline) of the window less its mean, added back to the samples
    # (the spline reproduces constants): rounding relative to the window's contrast, not its level
    level = jnp.array([jnp.mean(s), 0.0, 0.0])
    sg = _spline(jnp.stack([s - level[0], gxs, gys], axis=-1))

    def sample(xs, ys):
        return _spline_sample(sg, xs, ys) + level[None, :]

    big = big + PAD  # patch coordinates of the approximation
    off = jnp.arange(-half, half + 1, dtype=jnp.float64)
    x = jnp.broadcast_to(off[None, :], g1.shape).ravel()
    y = jnp.broadcast_to(off[:, None], g1.shape).ravel()
    xn, yn = x / half, y / half  # scaled for the conditioning of the normal equations
    g1 = g1.ravel()
    frac = jnp.where(jnp.all(jnp.isfinite(sxy)), sxy - cf, 0.0) - ft  # where the integer centre lies
    p0 = jnp.array([frac[0], 0.0, 0.0, frac[1], 0.0, 0.0, 0.0, 1.0])
    # initial radiometry from the window means / spreads
    s0win = sample(x + frac[0] + big, y + frac[1] + big)[:, 0]
    r1 = jnp.std(g1) / jnp.where(jnp.std(s0win) > 0, jnp.std(s0win), 1.0)
    p0 = p0.at[7].set(jnp.where(r1 > 0, r1, 1.0))
    p0 = p0.at[6].set(jnp.mean(g1) - p0[7] * jnp.mean(s0win))

    def design(p):
        xs = p[0] + (1 + p[1]) * x + p[2] * y + big
        ys = p[3] + p[4] * x + (1 + p[5]) * y + big
        val = sample(xs, ys)
        g2, gx, gy = val[:, 0], val[:, 1] * p[7], val[:, 2] * p[7]
        a = jnp.stack([gx, gx * xn, gx * yn, gy, gy * xn, gy * yn, jnp.ones_like(g2), g2], axis=1)
        v = g1 - (p[6] + p[7] * g2)
        return a, v

    scale = jnp.array([1.0, half, half, 1.0, half, half, 1.0, 1.0])  # d(param) = d(scaled) / scale

    def step(p):
        a, v = design(p)
        n = a.T @ a
        dp = jnp.linalg.solve(n, a.T @ v) / scale
        return p + dp, dp

    def cond(st):
        _, dp, k = st
        return (k < iterations) & (jnp.max(jnp.abs(dp[jnp.array([0, 3])])) > tol) & jnp.all(jnp.isfinite(dp))

    def body(st):
        p, _, k = st
        p, dp = step(p)
        return p, dp, k + 1

    p, dp, k = jax.lax.while_loop(cond, body, (p0, jnp.full(8, 1e3), 0))
    a, v = design(p)
    n = a.T @ a
    dof = g1.size - 8
    s02 = jnp.sum(v * v) / dof
    q = jnp.linalg.inv(n)
    idx = jnp.array([0, 3])
    # the template centre's position and its covariance: J q J^T with J = d(xy)/d(scaled parameters)
    fx, fy = ft[0] / half, ft[1] / half
    jac = jnp.array([[1.0, fx, fy, 0, 0, 0, 0, 0], [0, 0, 0, 1.0, fx, fy, 0, 0]])
    cov = s02 * (jac @ q @ jac.T)
    cov = cov * _correlation_factor(v.reshape(2 * half + 1, 2 * half + 1))
    xy = cf + jnp.array([p[0] + p[1] * ft[0] + p[2] * ft[1], p[3] + p[4] * ft[0] + p[5] * ft[1]]) + ft
    tflat = jnp.std(g1) <= 1e-9 * (1 + jnp.max(jnp.abs(g1)))
    status = jnp.select(
        [
            ~(t_in & s_in),
            ~(t_fin & s_fin),
            tflat,
            ~jnp.all(jnp.isfinite(p)) | ~(p[7] > 0) | ~jnp.all(jnp.isfinite(cov)),
            jnp.max(jnp.abs(dp[idx])) > tol,
            (jnp.max(jnp.abs(p[idx])) > margin - 3) | (jnp.max(jnp.abs(p[jnp.array([1, 2, 4, 5])])) > 0.5),
        ],
        [
            Status.OUTSIDE,
            Status.NOT_FINITE,
            Status.TEXTURELESS,
            Status.ILL_CONDITIONED,
            Status.NOT_CONVERGED,
            Status.LEFT_WINDOW,
        ],
        Status.OK,
    )
    return xy, cov, status, jnp.sqrt(s02), k, p


@functools.partial(jax.jit, static_argnames=("half", "margin", "iterations", "tol"))
def _lsm(timg, txy, simg, sxy, *, half, margin, iterations, tol):
    one = functools.partial(_lsm_one, half=half, margin=margin, iterations=iterations, tol=tol)
    xy, cov, st, s0, k, p = jax.vmap(jax.vmap(one, in_axes=(None, 0, None, 0)))(timg, txy, simg, sxy)
    return finish(xy, cov, st, s0, k), jnp.where((st == Status.OK)[..., None], p, jnp.nan)


def match_lsm(
    template_image,
    template_xy,
    search_image,
    approx_xy,
    *,
    window: int = 10,
    margin: int | None = None,
    iterations: int = 30,
    tol: float = 1e-3,
    return_params: bool = False,
):
    """Least-squares matching (Gruen 1985): 6 affine + 2 radiometric parameters.

    Args:
        template_image, search_image: ``(h, w)`` images (or ``(b, h, w)``
            batches of the same length), any integer or float dtype.
        template_xy: ``(n, 2)`` template centres (column, row) px.
        approx_xy: ``(n, 2)`` approximate positions in the search image,
            within ``margin - 3`` px of the match (e.g. from :func:`match_ncc`).
        window: half-size of the ``(2 window + 1)^2`` template (10: 21 x 21).
        margin: search-patch border around the template size; default
            ``max(5, window // 2)``.  The affine window must stay inside it.
        iterations: maximum Gauss-Newton iterations.
        tol: stop when the shift update is below ``tol`` px.
        return_params: also return the ``(n, 8)`` parameters
            ``(a0, a1, a2, b0, b1, b2, r0, r1)`` with ``a1, a2, b1, b2`` per
            ``window`` px (i.e. for ``x / window``) and ``a0, b0`` relative to
            the rounded approximation.

    Returns:
        :class:`LocateResult`: ``xy`` = where the template centre lies in the
        search image; ``covariance = f sigma0^2 (A^T A)^-1`` (shift block,
        ``f = n / n_eff`` from the residuals' neighbour correlation);
        ``sigma0`` in grey values; ``iterations`` used.  Points whose
        parameters run away (shift beyond the margin, scale/shear > 0.5,
        gain <= 0) get ``Status.LEFT_WINDOW`` / ``ILL_CONDITIONED``.

    Examples:
        Least-squares matching finds a sub-pixel shift of a smooth texture to a few thousandths of a
        pixel (here the search image is the template moved by (1.3, -0.7) px):

        >>> import numpy as np
        >>> from photax.measure import match_lsm
        >>> r, c = np.mgrid[0:64, 0:64].astype(float)
        >>> def texture(c, r):
        ...     return 100 + 40 * np.sin(c / 3.0) * np.cos(r / 4.0) + 20 * np.sin((c + r) / 5.0)
        >>> res = match_lsm(texture(c, r), np.array([[32.0, 32.0]]), texture(c - 1.3, r + 0.7), np.array([[33.0, 31.0]]))
        >>> print(np.round(np.asarray(res.xy), 2), bool(res.valid[0]))
        [[33.3 31.3]] True
    """
    margin = int(margin) if margin is not None else max(5, window // 2)
    if window < 2:
        raise ValueError(f"window: half-size must be >= 2 px, got {window}")
    res, p = _pair(
        template_image,
        template_xy,
        search_image,
        approx_xy,
        window,
        window + margin + 2 + PAD,
        lambda ti, tx, si, sx: _lsm(
            ti, tx, si, sx, half=int(window), margin=margin, iterations=int(iterations), tol=float(tol)
        ),
    )
    return (res, p) if return_params else res


def _mirror_small(img, xy, size):
    """``img`` and ``xy`` as they are when a ``size`` px window fits, else (a window cut to the size
    the interpolation needed before its spline prefilter: ``PAD`` px less on each side) mirrored by
    ``PAD`` px, the points moved with it: the spline reproduces the samples at whole pixels
    whatever its boundary, so windows cut for the old size still match."""
    if min(img.shape[1:]) >= size:
        return img, xy
    check_window(size - 2 * PAD, img.shape[1:], "window")
    return jnp.pad(jnp.asarray(img), ((0, 0), (PAD, PAD), (PAD, PAD)), mode="reflect"), xy + PAD


def _pair(template_image, template_xy, search_image, approx_xy, half_t, half_s, run):
    # the images keep their dtype (and a numpy image stays on the host until the call):
    # only the windows are converted to float64
    timg, tb = as_images(template_image, "template_image", convert=False)
    simg, sb = as_images(search_image, "search_image", convert=False)
    if tb != sb or timg.shape[0] != simg.shape[0]:
        raise ValueError(
            f"template_image {timg.shape} and search_image {simg.shape}: give both as single images "
            "or both as batches of the same length"
        )
    txy = as_points(template_xy, timg.shape[0], tb, "template_xy")
    sxy = as_points(approx_xy, simg.shape[0], sb, "approx_xy")
    timg, txy = _mirror_small(timg, txy, 2 * (half_t + 2 + PAD) + 1)
    mirrored = min(simg.shape[1:]) < 2 * half_s + 1
    simg, sxy = _mirror_small(simg, sxy, 2 * half_s + 1)
    if txy.shape != sxy.shape:
        raise ValueError(f"template_xy {txy.shape} and approx_xy {sxy.shape}: one approximation per template point")
    res, extra = run(timg, txy, simg, sxy)
    if mirrored:  # back to the search image's own pixels
        res = dataclasses.replace(res, xy=res.xy - PAD)
    if tb:
        return res, extra
    return jax.tree_util.tree_map(lambda a: a[0], res), extra[0]
