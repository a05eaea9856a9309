"""Förstner's sub-pixel corner locator: the least-squares intersection of edge-element lines.

Each pixel ``p_i`` of a window with grey-value gradient ``g_i`` lies on an
edge line through the corner ``c`` perpendicular to ``g_i``:
``g_i^T (c - p_i) = 0``.  Weighting every such line by ``|g_i|^2`` (its
precision is proportional to the gradient's strength) gives the normal
equations (Förstner & Gülch 1987; the seed's Förstner operator, docs/maths.md
"Image measurement")

    N c = b,   N = sum w_i g_i g_i^T,   b = sum w_i g_i g_i^T p_i,

with ``sigma0^2 = sum w_i (g_i^T (c - p_i))^2 / (n - 2)`` and
``Cov(c) = sigma0^2 N^-1``.  This is the method of OpenCV's ``cornerSubPix``.

Blur bias and the apex exclusion: near the apex of a blurred corner the two
edges overlap and the gradients there point into the corner's inside, which
pulls the plain estimate towards it by about ``sigma_blur^2 / (2 R)`` for a
window of half-size ``R`` (0.1 px at blur 1.2 px, R = 7).  The weights
``w_i = (1 - exp(-|p_i - c|^2 / (2 e^2)))`` therefore fade out the pixels
within ``e = exclude`` px of the current estimate (iterated: ``c`` moves,
the exclusion follows), leaving the straight parts of the edges, whose lines
pass through the true apex whatever the blur.  Beyond ``e`` the weights fall
as ``(e^2 + d0^2) / (d^2 + d0^2)``: noise ``dg`` in a gradient turns its line
by ``|dg| / |g|``, which moves the line's passage near the corner by
``d |dg| / |g|``; in addition the noise moves the edge's position across its
profile (the ``|g|^2``-weighted pixels locate it) by an amount independent of
``d``.  The equation ``g^T (c - p) = 0`` thus has a variance
``~ sigma_g^2 (d^2 + d0^2)`` and the Gauss-Markov weight ``1 / (d^2 + d0^2)``.
``d0 = 10`` px was chosen on seed 1 from {0, 4, 7, 10} (plain ``1/d^2`` is
``d0 = 0``) and checked on seeds 2-4.  Measured on area-sampled
corners (tests/test_measure_locators.py): with the defaults, the exclusion
brings the noise-free bias at blur 1.2 px from ~0.15 px to ~0.02 px; with 3 %
noise the gradient-direction noise of the edge pixels, levered by their
distance from the corner, then dominates.

The window grows with the blur: the exclusion must widen with the total blur
(optics plus ``smooth``), and only a longer window keeps enough straight edge
pixels beyond it.  Measured on 120 area-sampled corners per setting
(tests/test_measure_locators.py; settings chosen on seed 1, tested on seed 2):
blur 0.7 px / noise 1 %, defaults (window 14): 0.028 / 0.031 px RMSE (seeds 1 /
2); blur 1.2 px / noise 3 %, defaults 0.090 px, but
``window=20, exclude=7, smooth=1.5`` (on 61 px patches) 0.069 px (seeds 2-4:
0.065-0.071), against ``cornerSubPix`` with the same window 0.165 px; the same
wide setting gives 0.021 px at blur 0.7.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax import Array

from ._filters import _gradient2d, gradient_margin
from ._result import LocateResult, Status, as_images, as_points, check_window, finish, patch, round_centre

_F = jnp.float32  # arithmetic on the windows, positions relative to the window's centre pixel


def _gradient(p: Array, sigma: float) -> tuple[Array, Array]:
    """Gradient of a patch on its interior (``_margin(sigma)`` px smaller on
    every side): derivative of Gaussian, or central differences for ``sigma = 0``."""
    return _gradient2d(p, "gaussian" if sigma > 0 else "central", "valid", sigma)


def _margin(sigma: float) -> int:
    return gradient_margin("gaussian" if sigma > 0 else "central", sigma)


def _corner_one(img, xy0, *, half, exclude, iterations, q_min, smooth, d0):
    ci = round_centre(xy0)
    cf = ci.astype(jnp.float64)
    p, inside = patch(img, ci, half + _margin(smooth))
    p = p.astype(_F)  # the image keeps its dtype: only the windows are converted
    finite = jnp.all(jnp.isfinite(p))
    p = jnp.where(finite, p, 0.0)
    gx, gy = _gradient(p, smooth)
    off = jnp.arange(-half, half + 1, dtype=_F)
    # pixel positions from the window's centre pixel cf: small numbers, no
    # cancellation of large image coordinates in the sums
    px = off[None, :]
    py = off[:, None]
    disk = (off[None, :] ** 2 + off[:, None] ** 2) <= (half + 0.5) ** 2  # circular window: no preferred direction
    gxx, gxy, gyy = gx * gx, gx * gy, gy * gy
    # The structure tensor is all an iteration reads: the weights and the right-hand
    # side's positions are recomputed in the same pass (cheaper than reading them).
    g3 = jnp.stack([gxx, gxy, gyy])

    def weights(c):  # c from cf
        d2 = (px - c[0]) ** 2 + (py - c[1]) ** 2
        # Gauss-Markov weight 1 / (d^2 + d0^2) of an equation with a position and a direction error
        lever = 1.0 if math.isinf(d0) else (exclude**2 + d0**2) / (jnp.maximum(d2, exclude**2) + d0**2)
        ramp = jnp.clip(jnp.sqrt(d2) - exclude + 1.0, 0.0, 1.0) * lever
        return jnp.where(disk, ramp, 0.0) if exclude > 0 else disk.astype(_F)

    def solve(c):
        w = weights(c)
        s = jnp.sum(g3 * w[None], axis=(1, 2))
        n = jnp.array([[s[0], s[1]], [s[1], s[2]]])
        b = jnp.sum(jnp.stack([g3[0] * px + g3[1] * py, g3[1] * px + g3[2] * py]) * w[None], axis=(1, 2))
        det = n[0, 0] * n[1, 1] - n[0, 1] ** 2
        tr = n[0, 0] + n[1, 1]
        safe = det > 1e-9 * tr**2
        det_s = jnp.where(safe, det, 1.0)
        c_new = jnp.array([n[1, 1] * b[0] - n[0, 1] * b[1], n[0, 0] * b[1] - n[0, 1] * b[0]]) / det_s
        return jnp.where(safe, c_new, c), (n, det, tr)

    # Each iteration carries its normal matrix: the covariance takes the last one (the
    # weights of the estimate before the last step, < 1e-4 px away), not a final solve.
    def body(state):
        c, _, k, _, _ = state
        c_new, last = solve(c)
        step = jnp.max(jnp.abs(c_new - c))
        return c_new, step, k + 1, jnp.all(jnp.isfinite(c_new)), last

    def cond(state):
        _, step, k, ok, _ = state
        return (k < iterations) & (step > 1e-4) & ok

    c0 = (xy0 - cf).astype(_F) if exclude > 0 else jnp.zeros(2, _F)
    last0 = (jnp.zeros((2, 2), _F), jnp.zeros((), _F), jnp.zeros((), _F))  # iterations=0: NOT_CONVERGED
    init = (jnp.where(jnp.isfinite(c0), c0, 0.0), jnp.inf, 0, True, last0)
    c, step, k, ok, (n, det, tr) = jax.lax.while_loop(cond, body, init)
    w = weights(c)
    # is there a point at all? Förstner's roundness of the plain window's structure matrix
    ww = disk.astype(_F)
    n0 = jnp.array([jnp.sum(ww * gxx), jnp.sum(ww * gxy), jnp.sum(ww * gyy)])
    tr0 = n0[0] + n0[2]
    q = 4.0 * (n0[0] * n0[2] - n0[1] ** 2) / jnp.where(tr0 > 0, tr0**2, 1.0)
    r = gx * (c[0] - px) + gy * (c[1] - py)
    dof = jnp.maximum(jnp.sum(w > 1e-3) - 2, 1).astype(_F)
    s0sq = jnp.sum(w * r * r) / dof
    ninv = jnp.array([[n[1, 1], -n[0, 1]], [-n[0, 1], n[0, 0]]]) / jnp.where(det > 0, det, 1.0)
    cov = s0sq * ninv
    status = jnp.select(
        [
            ~inside,
            ~finite,
            tr0 <= 1e-12 * (1.0 + jnp.max(jnp.abs(p)) ** 2),
            q < q_min,
            ~(det > 1e-9 * tr**2) | (step > 1e-4) | ~ok,
            jnp.max(jnp.abs(c.astype(jnp.float64) + cf - xy0)) > half,
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
    f64 = jnp.float64
    return c.astype(f64) + cf, cov.astype(f64), status, jnp.sqrt(s0sq).astype(f64), k


@functools.partial(
    jax.jit,
    static_argnames=("half", "exclude", "iterations", "q_min", "smooth", "d0"),
    compiler_options={"xla_cpu_experimental_ynn_fusion_type": ""},
)
def _corners(images, xy, *, half, exclude, iterations, q_min, smooth, d0):
    one = functools.partial(
        _corner_one, half=half, exclude=exclude, iterations=iterations, q_min=q_min, smooth=smooth, d0=d0
    )
    per_image = jax.vmap(one, in_axes=(None, 0))  # points
    c, cov, st, s0, k = jax.vmap(per_image)(images, xy)  # images
    return finish(c, cov, st, s0, k)


def locate_corners(
    image,
    approx_xy,
    *,
    window: int = 14,
    exclude: float = 6.0,
    iterations: int = 20,
    q_min: float = 0.1,
    smooth: float = 1.0,
    d0: float = 10.0,
) -> LocateResult:
    """Sub-pixel corners (or crossing points) by Förstner's least-squares
    intersection of edge-element lines.

    Args:
        image: ``(h, w)`` or a batch ``(b, h, w)``, any integer or float dtype.
        approx_xy: ``(n, 2)`` approximate positions (column, row) in pixels
            (docs/conventions.md), or ``(b, n, 2)`` for a batch; within about
            ``window / 2`` px of the corner.
        window: half-size ``R`` of the circular window (``2R + 1`` px across),
            centred on the rounded approximation.
        exclude: radius ``e`` px of the apex exclusion (module docstring);
            ``0`` gives the plain Förstner / ``cornerSubPix`` estimate, one
            step from the window centre.  Pixels closer than ``e - 1`` px get
            no weight, a linear ramp to full weight at ``e``, then ``e^2/d^2``.  Needs about 4x
            the total blur (optics plus ``smooth``); the edges must run
            straight from ``e`` to ``window`` px from the corner (for blur
            ~1.2 px use ``window=20, exclude=7, smooth=1.5``: module docstring).
        iterations: maximum re-weighting iterations (stop when the position
            changes by less than 1e-4 px).
        q_min: minimum roundness ``q = 4 det N / tr(N)^2`` of the error
            ellipse; below it the window holds an edge, not a point.
        smooth: sigma (px) of the derivative-of-Gaussian gradient; 0 for
            central differences (anisotropic: biased for rotated corners).
        d0: distance (px) at which an edge pixel's direction error, levered
            by its distance ``d`` from the corner, equals its position error
            across the edge; weights ``(e^2 + d0^2) / (d^2 + d0^2)`` beyond
            ``e`` (module docstring).  ``inf`` weights all pixels alike.

    Returns:
        :class:`LocateResult` with ``xy`` ``(n, 2)`` (or ``(b, n, 2)``),
        ``covariance = sigma0^2 N^-1`` (px^2), ``status`` and ``sigma0``
        (grey value x px).  Failed points (window outside the image, flat
        window, an edge only, no convergence) are NaN with ``valid = False``.
        The windows are computed in float32 with positions relative to the
        window's centre pixel (rounding ~1e-6 px); results are float64.

    Source: Förstner & Gülch (1987), "A fast operator for detection and
    precise location of distinct points, corners and centres of circular
    features"; seed 004 (Förstner operator).

    Examples:
        Förstner's sub-pixel corner of a chequerboard crossing at (20.3, 19.6), from 1 px off:

        >>> import numpy as np
        >>> from photax.measure import locate_corners
        >>> r, c = np.mgrid[0:41, 0:41].astype(float)
        >>> image = 100.0 + 80.0 * np.tanh(2.0 * (c - 20.3)) * np.tanh(2.0 * (r - 19.6))
        >>> res = locate_corners(image, np.array([[21.0, 19.0]]))
        >>> print(np.round(np.asarray(res.xy), 1), bool(res.valid[0]))
        [[20.3 19.6]] True
    """
    if window < 2:
        raise ValueError(f"window: half-size must be >= 2 px, got {window}")
    if exclude < 0:
        raise ValueError(f"exclude: must be >= 0, got {exclude}")
    if not d0 >= 0:
        raise ValueError(f"d0: must be >= 0, got {d0}")
    images, batched = as_images(image, convert=False)
    check_window(2 * (window + _margin(smooth)) + 1, images.shape[1:])
    xy = as_points(approx_xy, images.shape[0], batched)
    res = _corners(
        images,
        xy,
        half=int(window),
        exclude=float(exclude),
        iterations=int(iterations),
        q_min=float(q_min),
        smooth=float(smooth),
        d0=float(d0),
    )
    return res if batched else jax.tree_util.tree_map(lambda a: a[0], res)
