"""Least-squares adjustment of one image: Gauss-Newton, precision, the blunder test.

Gauss-Newton on the weighted residuals ``v = sqrt(P) (x_obs - x(p))``
(observed - computed) with the closed-form collinearity Jacobian
(:func:`photax.collinearity.collinearity_jacobian`), the 6x6 normal
equations solved by a Jacobi-scaled Cholesky (:func:`photax._linalg.cho_solve`); it
stops after a step ``|dp_i| <= 1e-8 (1 + |p_i|)`` (metres, radians) or
``max_steps`` iterations.  The solution is differentiable with respect to the
data: it is wrapped in ``jax.lax.custom_root`` on the normal equations'
gradient ``A^T v = 0`` (implicit function theorem; the loop itself is not
differentiated).

Precision at the solution (Kraus 2007, app. B), ``r = 2 n - 6``::

    sigma0^2 = v^T v / r,   Q_xx = (A^T A)^-1,
    r_i = 1 - diag(A Q_xx A^T)_i          (redundancy numbers)
    w_i = v_i / sqrt(r_i)                 (Baarda's w; / sigma0: Pope's tau)

Levenberg-Marquardt (``optimistix``) is the fallback of a single
:func:`photax.resect` whose Gauss-Newton failed; its outcome is read through
optimistix's public ``RESULTS`` items.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from .._linalg import cho_solve
from ..collinearity import _angle_axes, collinearity_jacobian
from ..errors import RESULTS, from_optimistix
from . import _linear
from ._types import Inputs, Options, Output

# Gauss-Newton stops after a step below this (relative; metres and radians).
# Convergence is quadratic for small residuals, so the error left after that
# step is far below it; one more iteration would only confirm it.
STEP_TOL = 1e-8


def wrap(a):
    """Angles to (-pi, pi]."""
    return jnp.pi - jnp.mod(jnp.pi - a, 2.0 * jnp.pi)


def evaluate(p, inp: Inputs, used, opt: Options):
    """Weighted residuals ``v`` ``(m, 2)``, their model derivative ``A = -dv/dp``
    ``(m, 2, 6)``, the prediction ``(m, 2)`` and the depths ``(m,)`` at ``p``
    (zero rows for points not ``used``)."""
    rot = _linear.rotation(p[3:], opt.pok)
    axes = _angle_axes(p[3:], rot, opt.pok)
    pred, jac, q = collinearity_jacobian(inp.ground, p[:3], rot, axes, opt.camera, wrt_ground=False)
    sw = jnp.where(used[:, None], jnp.sqrt(inp.weight), 0.0)
    return (inp.xy - pred) * sw, jac * sw[:, :, None], pred, -q[:, 2]


def _normal(a, v):
    """``N = A^T A``, ``g = A^T v`` as element-wise sums (fused under vmap, no tiny dots)."""
    a = a.reshape(-1, 6)
    return jnp.sum(a[:, :, None] * a[:, None, :], axis=0), jnp.sum(a * v.reshape(-1)[:, None], axis=0)


def _iterate(start, inp: Inputs, used, opt: Options):
    """The Gauss-Newton loop: ``(p, steps, RESULTS code, evaluation at p)``
    (the evaluation, :func:`evaluate`'s four arrays, spares :func:`precision` one)."""
    ev0 = evaluate(start, inp, used, opt)
    ok0 = jnp.all(jnp.isfinite(ev0[0])) & jnp.all(jnp.isfinite(ev0[1]))
    code0 = jnp.where(ok0, RESULTS.successful, RESULTS.nonfinite)

    def cond(c):
        _, _, k, done, _ = c
        return ~done & (k < opt.max_steps)

    def body(c):
        p, ev, k, _, _ = c
        n, g = _normal(ev[1], ev[0])
        dp = cho_solve(n, g[:, None])[:, 0]
        solvable = jnp.all(jnp.isfinite(dp))
        p_new = jnp.where(solvable, p + dp, p)
        ev_new = evaluate(p_new, inp, used, opt)
        finite = jnp.all(jnp.isfinite(ev_new[0])) & jnp.all(jnp.isfinite(ev_new[1]))
        code = jnp.where(~solvable, RESULTS.singular, jnp.where(finite, RESULTS.successful, RESULTS.nonfinite))
        small = jnp.all(jnp.abs(dp) <= STEP_TOL * (1.0 + jnp.abs(p_new)))
        keep = solvable & finite  # a failed step leaves the last finite estimate
        ev = jax.tree_util.tree_map(lambda x, y: jnp.where(keep, x, y), ev_new, ev)
        return jnp.where(keep, p_new, p), ev, k + 1, small | (code != RESULTS.successful), code

    carry = (start, ev0, jnp.array(0), ~ok0, code0)
    p, ev, steps, done, code = jax.lax.while_loop(cond, body, carry)
    code = jnp.where(done, code, RESULTS.max_steps_reached)
    return p, steps, code, ev


def gauss_newton(start, inp: Inputs, used, opt: Options):
    """Gauss-Newton from ``start``: ``(p, steps, code, evaluation at p)``;
    ``p`` differentiable with respect to ``inp`` and ``opt.camera`` through
    the optimality condition ``A(p)^T v(p) = 0`` (``jax.lax.custom_root``);
    the evaluation (:func:`evaluate` at ``p``, from the loop) is not."""

    def gradient(p):  # A^T v: zero at the solution
        v, a, _, _ = evaluate(p, inp, used, opt)
        return _normal(a, v)[1]

    # The loop runs on values only (no tangents enter the while_loop, which reverse mode cannot
    # differentiate); custom_root then attaches the implicit derivative at its solution.
    nograd = jax.lax.stop_gradient
    p, steps, code, ev = _iterate(nograd(start), jax.tree_util.tree_map(nograd, inp), used,
                                  jax.tree_util.tree_map(nograd, opt))

    def tangent_solve(g, y):  # only traced under differentiation
        return jnp.linalg.solve(jax.jacfwd(g)(y), y)

    p = jax.lax.custom_root(gradient, p, lambda _, x0: x0, tangent_solve)
    return p, steps, code, ev


def precision(p, inp: Inputs, used, opt: Options, ev=None) -> dict:
    """sigma0, Q_xx, redundancy numbers and w at ``p`` (module docstring);
    ``ev``: :func:`evaluate` at ``p`` if already known (the same numbers:
    wrapping the angles changes none)."""
    p = jnp.concatenate([p[:3], wrap(p[3:])])
    v, a, pred, depth = evaluate(p, inp, used, opt) if ev is None else ev
    n, _ = _normal(a, v)
    qxx = cho_solve(n, jnp.eye(6))
    qxx = 0.5 * (qxx + qxx.T)
    red = 2.0 * jnp.sum(used.astype(float)) - 6.0
    sigma0 = jnp.where(red > 0, jnp.sqrt(jnp.sum(v * v) / jnp.where(red > 0, red, 1.0)), jnp.nan)
    a = a.reshape(-1, 6)
    aq = jnp.sum(a[:, :, None] * qxx[None, :, :], axis=1)  # A Q_xx, element-wise (no tiny dots under vmap)
    r_i = jnp.where(used[:, None], (1.0 - jnp.sum(aq * a, axis=1)).reshape(-1, 2), 0.0)
    ok = r_i > 1e-10
    # v is observed - computed (the Gauss-Newton form); w and residuals are reported computed - observed.
    w = jnp.where(ok, -v / jnp.sqrt(jnp.where(ok, r_i, 1.0)), jnp.nan)
    axis = -_linear.rotation(p[3:], opt.pok)[:, 2]
    return dict(params=p, sigma0=sigma0, qxx=qxx, residuals=pred - inp.xy, redundancy=r_i, w=w, depth=depth,
                axis=axis)


def adjust(start, inp: Inputs, used, opt: Options) -> dict:
    """Gauss-Newton from ``start`` with the points ``used``, then precision."""
    p, steps, code, ev = gauss_newton(start, inp, used, opt)
    return dict(precision(p, inp, used, opt, ev), result=code, steps=steps)


def test(out: dict, used, opt: Options):
    """The blunder test: ``(exclude?, worst point, |statistic| (m, 2), critical value)``.

    Exclusion only while redundancy allows (a point costs 2) and the
    adjustment succeeded; not for rounding-level residuals.
    """
    n_used = jnp.sum(used.astype(int))
    c = opt.critical[n_used]
    stat = jnp.abs(out["w"]) / jnp.where(opt.scale_stat, out["sigma0"], 1.0)
    worst = jnp.max(jnp.where(jnp.isnan(stat), -jnp.inf, stat), axis=1)
    worst = jnp.where(used, worst, -jnp.inf)
    k = jnp.argmax(worst)
    red = 2.0 * n_used.astype(float) - 6.0
    go = opt.snoop & (worst[k] > c) & ~(out["sigma0"] < opt.exact) & (out["result"] == RESULTS.successful)
    go &= (n_used - 1 >= opt.min_points) & (red - 2.0 >= opt.min_redundancy)
    return go, k, stat, c


def solve_cheap(inp: Inputs, opt: Options) -> Output:
    """The cheap path: linear start from all control points, one adjustment,
    the test.  ``retry`` asks for the robust path (:mod:`._robust`) when,
    with ``opt.snoop``, the test fails (1), or the adjustment fails, or the
    start or the solution puts a control point behind the camera (2)."""
    uv = _linear.opencv_uv(inp.xy, opt.camera)
    lin, lin_ok = _linear.linear_start(uv, inp.ground, inp.ctrl, inp.basis, opt.dlt_ok, opt.pok)
    start = jnp.where(inp.use_init, inp.init, lin)
    out = adjust(start, inp, inp.ctrl, opt)
    go, _, _, c = test(out, inp.ctrl, opt)
    behind = jnp.any(inp.ctrl & ~(out["depth"] > 0))
    bad_start = ~inp.use_init & ~lin_ok
    # Only the test failed: data snooping can start from this solution (1). Anything else needs the
    # robust start as well (2).
    hard = (out["result"] != RESULTS.successful) | behind | bad_start
    retry = jnp.where(opt.snoop, jnp.where(hard, 2, jnp.where(go, 1, 0)), 0)
    return Output(**out, start=start, used=inp.ctrl, stat_at=jnp.full(inp.xy.shape, jnp.nan), critical=c,
                  retry=retry)


@functools.partial(jax.jit, static_argnames="max_steps")
def levenberg_marquardt(inp: Inputs, out: Output, opt: Options, max_steps: int) -> Output:
    """Fallback when Gauss-Newton failed: optimistix's Levenberg-Marquardt
    from the same start with the same points (autodiff Jacobian: it runs
    rarely, and is compiled only then)."""
    import lineax as lx
    import optimistix as optx

    used = out.used

    def residuals(p, _):
        v, _, _, _ = evaluate(p, inp, used, opt)
        return v.reshape(-1) / opt.camera.focal_length  # dimensionless: tolerances independent of the unit

    algo = optx.LevenbergMarquardt(rtol=1e-11, atol=1e-11, linear_solver=lx.QR())
    sol = optx.least_squares(residuals, algo, out.start, max_steps=max_steps, throw=False)
    code = jnp.where(jnp.all(jnp.isfinite(sol.value)), from_optimistix(sol.result), RESULTS.nonfinite)
    fields = precision(sol.value, inp, used, opt)
    return Output(**fields, result=code, steps=sol.stats["num_steps"], start=out.start, used=used,
                  stat_at=out.stat_at, critical=out.critical, retry=out.retry)
