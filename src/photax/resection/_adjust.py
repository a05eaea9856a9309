"""Least-squares adjustment of a batch of images: Gauss-Newton, precision, the blunder test.

Every array carries the images as its **last** axis (:mod:`._lanes`): the
parameters are ``(6, B)``, image points ``(2, m, B)``, the Jacobian
``(6, 2, m, B)``; one image is ``B = 1``.  Each image keeps its own
iteration count and result, exactly as if it were adjusted alone.

Gauss-Newton on the weighted residuals ``v = sqrt(P) (x_obs - x(p))``
(observed - computed) with the closed-form collinearity Jacobian
(:func:`evaluate`, the formulas of
:func:`photax.collinearity.collinearity_jacobian`), the 6x6 normal
equations solved by a Jacobi-scaled Cholesky (:func:`._lanes.cho_solve`);
an image stops after a step ``|dp_i| <= 1e-8 (1 + |p_i|)`` (metres,
radians) or ``max_steps`` iterations.  The solution is differentiable with
respect to the data: it is wrapped in ``jax.lax.custom_root`` on the normal
equations' gradient ``A^T v = 0`` (implicit function theorem; the loop
itself is not differentiated).

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

from ..camera import distort, distortion_jacobian
from ..collinearity import angle_axes_of
from ..errors import RESULTS, from_optimistix
from . import _lanes, _linear
from ._types import Inputs, Options, Output

# Gauss-Newton stops after a step below this (relative; metres and radians).
# Convergence is quadratic for small residuals, so the error left after that
# step is far below it; one more iteration would only confirm it.
STEP_TOL = 1e-8


def wrap(a):
    """Angles to (-pi, pi]."""
    return jnp.pi - jnp.mod(jnp.pi - a, 2.0 * jnp.pi)


def rotation(p, pok):
    """world_from_camera ``(3, 3, B)`` of parameters ``p`` ``(6, B)``."""
    return jnp.transpose(_linear.rotation(p[3:].T, pok), (1, 2, 0))


def evaluate(p, inp: Inputs, used, opt: Options):
    """At ``p`` ``(6, B)``: weighted residuals ``v`` ``(2, m, B)``, their model
    derivative ``A = -dv/dp`` ``(6, 2, m, B)``, the prediction ``(2, m, B)``
    and the depths ``(m, B)`` (zero rows for points not ``used``).

    The collinearity equations and their Jacobian, written out (as
    :func:`photax.collinearity.collinearity_jacobian`; tested against
    ``jax.jacfwd``): ``d = X - C``, ``q = R^T d``, ``xn = -q_xy / q_z``,
    ``x = x0 + f D(xn)``, ``dq/dC = -R^T``, ``dq/da_k = R^T (d x w_k)``,
    ``dx/dq = f D'(xn) (-1/q_z) [[1, 0, xn], [0, 1, yn]]``.
    """
    cam = opt.camera
    rot = rotation(p, opt.pok)
    axes = jnp.transpose(angle_axes_of(p[3:].T, jnp.transpose(rot, (2, 0, 1)), opt.pok), (1, 2, 0))  # (k, 3, B)
    d = inp.ground - p[:3, None, :]  # (3, m, B)
    q = _lanes.rt_times(rot, d)
    x, y = -q[0] / q[2], -q[1] / q[2]
    xn = jnp.stack([x, y], axis=-1)  # (m, B, 2)
    xd, yd = jnp.moveaxis(distort(xn, cam.distortion), -1, 0)
    jd = distortion_jacobian(xn, cam.distortion)  # D' (m, B, 2, 2)
    jxx, jxy, jyx, jyy = jd[..., 0, 0], jd[..., 0, 1], jd[..., 1, 0], jd[..., 1, 1]
    g = -cam.focal_length / q[2]
    dx_dq = (
        jnp.stack([jnp.stack([jxx, jxy, jxx * x + jxy * y]), jnp.stack([jyx, jyy, jyx * x + jyy * y])]) * g[None, None]
    )  # (2, 3, m, B)
    dq_da = [_lanes.rt_times(rot, _lanes.cross(d, axes[k][:, None, :])) for k in range(3)]  # (3, m, B) each
    cols = [-sum(dx_dq[:, c] * rot[i, c][None, None] for c in range(3)) for i in range(3)]  # dq_c/dC_i = -R[i, c]
    cols += [sum(dx_dq[:, c] * dq_da[k][c][None] for c in range(3)) for k in range(3)]
    jac = jnp.stack(cols)  # (6, 2, m, B)
    pred = cam.principal_point[:, None, None] + cam.focal_length * jnp.stack([xd, yd])
    sw = jnp.where(used[None], jnp.sqrt(inp.weight), 0.0)
    return (inp.xy - pred) * sw, jac * sw[None], pred, -q[2]


def _normal(a, v):
    """``N = A^T A`` ``(6, 6, B)``, ``g = A^T v`` ``(6, B)``."""
    return jnp.sum(a[:, None] * a[None, :], axis=(2, 3)), jnp.sum(a * v[None], axis=(1, 2))


def _finite(n, g):
    """Lanes whose normal equations are finite (a non-finite residual or
    Jacobian entry makes them so; checking the ``(6, 6, B)`` matrix is
    cheaper than the ``(6, 2, m, B)`` Jacobian)."""
    return jnp.all(jnp.isfinite(n), axis=(0, 1)) & jnp.all(jnp.isfinite(g), axis=0)


def _iterate(start, inp: Inputs, used, opt: Options, active=None, steps0=None):
    """The Gauss-Newton loop over the lanes: ``(p, steps, RESULTS code,
    (evaluation at p, normal equations at p))`` (they spare
    :func:`precision` computing them again).  ``active`` ``(B,)``: lanes to
    adjust (the others are left as they start, and do not keep the loop
    running).  ``steps0`` ``(B,)``: steps already taken to reach ``start``
    (they count towards ``max_steps``; default none).

    The loop's first pass evaluates the start and takes no step, so that
    :func:`evaluate` is traced once (each copy was most of a second of
    compilation)."""
    m, b = used.shape
    ev0 = (jnp.zeros((2, m, b)), jnp.zeros((6, 2, m, b)), jnp.zeros((2, m, b)), jnp.zeros((m, b)))
    ne0 = (jnp.eye(6)[:, :, None] * jnp.ones((1, 1, b)), jnp.zeros((6, b)))
    done0 = jnp.zeros(b, bool) if active is None else ~active
    zeros = jnp.zeros(b, int)

    def cond(c):
        _, _, _, k, done, _, first = c
        return first | jnp.any(~done & (k < opt.max_steps))

    def body(c):
        p, ev, ne, k, done, code, first = c
        run = ~done & (first | (k < opt.max_steps))
        dp = jnp.where(first, 0.0, _lanes.cho_solve(ne[0], ne[1][:, None])[:, 0])
        solvable = jnp.all(jnp.isfinite(dp), axis=0)
        p_new = _lanes.sel(solvable, p + dp, p)
        ev_new = evaluate(p_new, inp, used, opt)
        ne_new = _normal(ev_new[1], ev_new[0])
        finite = _finite(*ne_new)
        code_new = jnp.where(~solvable, RESULTS.singular, jnp.where(finite, RESULTS.successful, RESULTS.nonfinite))
        small = jnp.all(jnp.abs(dp) <= STEP_TOL * (1.0 + jnp.abs(p_new)), axis=0)
        keep = run & ((solvable & finite) | first)  # a failed step leaves the last finite estimate
        ev, ne = jax.tree_util.tree_map(lambda x, y: _lanes.sel(keep, x, y), (ev_new, ne_new), (ev, ne))
        p = _lanes.sel(keep, p_new, p)
        stop = jnp.where(first, ~finite, small | (code_new != RESULTS.successful))
        return (
            p,
            ev,
            ne,
            k + (run & ~first).astype(int),
            jnp.where(run, stop, done),
            jnp.where(run, code_new, code),
            jnp.array(False),
        )

    carry = (start, ev0, ne0, zeros if steps0 is None else steps0, done0, zeros + RESULTS.successful, jnp.array(True))
    p, ev, ne, steps, done, code, _ = jax.lax.while_loop(cond, body, carry)
    code = jnp.where(done, code, RESULTS.max_steps_reached)
    return p, steps, code, (ev, ne)


# The cheap path's Gauss-Newton: a fixed number of steps for every lane, then the stopping rule
# checked once.  From the linear start, 3 steps and the solve of a 4th that is below STEP_TOL settle
# ~97 % of images (quadratic convergence); the rest are adjusted again, compacted GROUP lanes at a
# time, by the per-lane loop (:func:`_iterate`).
FIXED_STEPS = 3
GROUP = 64


def _iterate_fixed(start, inp: Inputs, used, opt: Options):
    """:func:`_iterate` for the cheap path, in two parts: ``FIXED_STEPS``
    Gauss-Newton steps on every lane at once (no per-lane bookkeeping in the
    loop: a lane that has converged keeps taking rounding-level steps), then
    the solve of the next step; where it is below ``STEP_TOL`` the lane has
    converged: that step is :func:`_iterate`'s confirming step, added
    without evaluating the model there again.  Every other lane is handed
    to :func:`_iterate`, ``GROUP`` lanes gathered at a time: one that only
    needs more steps goes on from where it is (its ``FIXED_STEPS`` counted),
    one whose step became non-finite or singular, or that reached
    ``max_steps`` first, starts again from its start; either way its result
    is the per-lane loop's.

    Returns ``(p, steps, code, (evaluation at p, normal equations at p))``
    as :func:`_iterate`."""
    m, b = used.shape

    def body(i, c):  # step, evaluate there, solve the next step
        p, dp, _, _, first_small = c
        p = p + dp
        ev = evaluate(p, inp, used, opt)
        ne = _normal(ev[1], ev[0])
        dp = _lanes.cho_solve(ne[0], ne[1][:, None])[:, 0]
        small = jnp.all(jnp.abs(dp) <= STEP_TOL * (1.0 + jnp.abs(p + dp)), axis=0)
        return p, dp, ev, ne, jnp.where((first_small == 0) & small, i + 1, first_small)

    ev0 = (jnp.zeros((2, m, b)), jnp.zeros((6, 2, m, b)), jnp.zeros((2, m, b)), jnp.zeros((m, b)))
    ne0 = (jnp.zeros((6, 6, b)), jnp.zeros((6, b)))
    zeros = jnp.zeros(b, int)
    p, dp, ev, ne, first_small = jax.lax.fori_loop(
        0, FIXED_STEPS + 1, body, (start, jnp.zeros_like(start), ev0, ne0, zeros)
    )
    # converged: the last solved step is small, none was non-finite, the rule fired within max_steps
    done = (first_small > 0) & (first_small <= opt.max_steps) & jnp.all(jnp.isfinite(dp), axis=0)
    done &= _finite(*ne)
    steps = jnp.where(done, first_small, zeros)
    code = zeros + RESULTS.successful
    # The small step is taken without evaluating there (that evaluation only confirmed it): p is then
    # the per-lane loop's answer to rounding, and the residuals and normal equations kept are those one
    # step before, which differ from them by less than STEP_TOL's effect (~1e-8 relative).
    p = p + jnp.where(done, dp, 0.0)
    # Lanes that only need more steps go on from p (the per-lane loop would have reached the same point
    # in FIXED_STEPS steps); the others (non-finite, max_steps reached) start again from their start.
    go_on = (first_small == 0) & (FIXED_STEPS < opt.max_steps) & jnp.all(jnp.isfinite(p), axis=0)
    go_on &= jnp.all(jnp.isfinite(dp), axis=0) & _finite(*ne)
    go_on_p, go_on_k = _lanes.sel(go_on, p, start), jnp.where(go_on, FIXED_STEPS, 0)

    g = min(GROUP, b)

    def again(c):  # the next GROUP lanes not yet done: the per-lane loop (going on, or from their start)
        p, steps, code, ev, ne, done = c
        idx = jnp.nonzero(~done, size=g, fill_value=b)[0]
        valid = idx < b
        take = jnp.minimum(idx, b - 1)
        sub = jax.tree_util.tree_map(lambda a: a[..., take], inp)
        p_g, steps_g, code_g, (ev_g, ne_g) = _iterate(
            go_on_p[:, take], sub, used[:, take], opt, active=valid, steps0=go_on_k[take]
        )
        put = lambda full, part: full.at[..., idx].set(part, mode="drop")  # noqa: E731 (fill lanes dropped)
        ev, ne = jax.tree_util.tree_map(put, (ev, ne), (ev_g, ne_g))
        return put(p, p_g), put(steps, steps_g), put(code, code_g), ev, ne, put(done, valid)

    p, steps, code, ev, ne, _ = jax.lax.while_loop(lambda c: ~jnp.all(c[5]), again, (p, steps, code, ev, ne, done))
    return p, steps, code, (ev, ne)


def gauss_newton(start, inp: Inputs, used, opt: Options, active=None, fixed=False):
    """Gauss-Newton from ``start`` ``(6, B)``: ``(p, steps, code, evaluation at p)``;
    ``p`` differentiable with respect to ``inp`` and ``opt.camera`` through
    the optimality condition ``A(p)^T v(p) = 0`` (``jax.lax.custom_root``);
    the evaluation (:func:`evaluate` at ``p``, from the loop) is not."""

    def gradient(p):  # A^T v: zero at the solution
        v, a, _, _ = evaluate(p, inp, used, opt)
        return _normal(a, v)[1]

    # The loop runs on values only (no tangents enter the while_loop, which reverse mode cannot
    # differentiate); custom_root then attaches the implicit derivative at its solution.
    nograd = jax.lax.stop_gradient
    args = nograd(start), jax.tree_util.tree_map(nograd, inp), used, jax.tree_util.tree_map(nograd, opt)
    # Only resect_batch's large chunks take the fixed steps; a single resect (one lane) and small
    # batches keep the per-lane loop: the fixed steps would save little there, and cost a second loop's
    # kernels and compilation.
    fixed = fixed and start.shape[-1] >= _lanes.UNROLL_LANES
    p, steps, code, ev = _iterate_fixed(*args) if fixed else _iterate(*args, active)

    def tangent_solve(g, y):  # only traced under differentiation; the lanes are independent systems
        eye = jnp.eye(6)[:, :, None] * jnp.ones((1, 1, y.shape[-1]))
        jac = jax.vmap(g, out_axes=1)(eye)  # (6, 6, B): column j = g(e_j), g traced once
        return jnp.linalg.solve(jnp.transpose(jac, (2, 0, 1)), y.T[..., None])[..., 0].T

    p = jax.lax.custom_root(gradient, p, lambda _, x0: x0, tangent_solve)
    return p, steps, code, ev


def precision(p, inp: Inputs, used, opt: Options, ev=None) -> dict:
    """sigma0, Q_xx, redundancy numbers and w at ``p`` (module docstring),
    in :class:`Output`'s per-image shapes with the lanes last; ``ev``:
    :func:`evaluate` and :func:`_normal` at ``p`` if already known (the same
    numbers: wrapping the angles changes none)."""
    p = jnp.concatenate([p[:3], wrap(p[3:])])
    if ev is None:
        ev = evaluate(p, inp, used, opt)
        ev = (ev, _normal(ev[1], ev[0]))
    (v, a, pred, depth), (n, _) = ev
    # From the Cholesky factor, per lane (:func:`._lanes.inverse_factor`): N^-1 = M^T M with M = L^-1 D,
    # so Q_xx = M^T M and diag(A Q_xx A^T) = |M a|^2 for each observation's row a (21 products instead
    # of 36, no LAPACK call per image; a broadcast (6, 6, 2, m, B) product reduced over its leading axes
    # ran 15x slower on XLA:CPU).
    mf = _lanes.inverse_factor(n)
    qxx = jnp.stack(
        [jnp.stack([sum(mf[i, j] * mf[i, k] for i in range(max(j, k), 6)) for k in range(6)]) for j in range(6)]
    )
    red = 2.0 * jnp.sum(used.astype(float), axis=0) - 6.0
    sigma0 = jnp.where(red > 0, jnp.sqrt(jnp.sum(v * v, axis=(0, 1)) / jnp.where(red > 0, red, 1.0)), jnp.nan)
    ma = [sum(mf[i, j][None, None] * a[j] for j in range(i + 1)) for i in range(6)]  # (2, m, B) each
    # a barrier: otherwise XLA recomputes r_i inside each transposing copy that reads it (the outputs'
    # redundancy and w: measured, those two copies were 1 us per image)
    r_i = jax.lax.optimization_barrier(jnp.where(used[None], 1.0 - sum(x * x for x in ma), 0.0))
    ok = r_i > 1e-10
    # v is observed - computed (the Gauss-Newton form); w and residuals are reported computed - observed.
    w = jnp.where(ok, -v / jnp.sqrt(jnp.where(ok, r_i, 1.0)), jnp.nan)
    axis = -rotation(p, opt.pok)[:, 2]
    tr = functools.partial(jnp.transpose, axes=(1, 0, 2))  # (2, m, B) -> Output's (m, 2, B)
    return dict(
        params=p,
        sigma0=sigma0,
        qxx=qxx,
        residuals=tr(pred - inp.xy),
        redundancy=tr(r_i),
        w=tr(w),
        depth=depth,
        axis=axis,
    )


def adjust(start, inp: Inputs, used, opt: Options, active=None, fixed=False) -> dict:
    """Gauss-Newton from ``start`` with the points ``used``, then precision
    (``fixed``: :func:`_iterate_fixed`, the cheap path's loop)."""
    p, steps, code, ev = gauss_newton(start, inp, used, opt, active, fixed)
    return dict(precision(p, inp, used, opt, ev), result=code, steps=steps)


def test(out: dict, used, opt: Options):
    """The blunder test per lane: ``(exclude?, points to exclude (m, B), |statistic| (m, 2, B),
    critical value)``.

    Exclusion only while redundancy allows (a point costs 2) and the
    adjustment succeeded; not for rounding-level residuals.

    The worst point is excluded, and with it every point whose statistic
    would exceed the critical value even without the other flagged points'
    pull on it, so that a large set is not refitted once per point (10,000
    GCPs at alpha = 0.001 flag ~30 points by chance alone; the loop ran
    30 adjustments).  To first order a blunder ``e_l`` shows in observation
    ``j``'s residual as ``-h_jl e_l`` (``H = A Q_xx A^T P``, ``r = 1 - h``),
    ``|h_jl| <= sqrt(h_jj h_ll)`` (Cauchy-Schwarz) and ``e_l ~ w_l / sqrt(r_l)``,
    so the flagged observations ``F`` move ``w_j`` by at most
    ``sqrt(h_jj / r_j) * sum_{l in F, not j's point} sqrt(h_ll / r_l) |w_l|``:
    ``j`` goes now if its statistic less that bound still exceeds the
    critical value.  With few points (``h`` near 1) the bound is large and
    only the worst goes, as in Baarda's one-at-a-time snooping; with many
    (``h ~ 6 / 2n``) every clearly flagged point goes in one round.
    """
    m = used.shape[0]
    n_used = jnp.sum(used.astype(int), axis=0)
    c = opt.critical[n_used]
    stat = jnp.abs(out["w"]) / _lanes.lane(jnp.where(opt.scale_stat, out["sigma0"], 1.0), 3)
    finite = jnp.where(used[:, None], jnp.where(jnp.isnan(stat), -jnp.inf, stat), -jnp.inf)  # (m, 2, B)
    worst = jnp.max(finite, axis=1)  # (m, B)
    k = jnp.argmax(worst, axis=0)
    red = 2.0 * n_used.astype(float) - 6.0
    go = opt.snoop & (jnp.max(worst, axis=0) > c) & ~(out["sigma0"] < opt.exact)
    go &= (out["result"] == RESULTS.successful) & (n_used - 1 >= opt.min_points) & (red - 2.0 >= opt.min_redundancy)
    r = out["redundancy"]
    ok = (r > 1e-10) & (finite > c[None, None])
    pull = jnp.where(ok, jnp.sqrt(jnp.clip(1.0 - r, 0.0, None) / jnp.where(ok, r, 1.0)), 0.0)  # (m, 2, B)
    share = jnp.where(ok, pull * finite, 0.0)
    others = jnp.sum(share, axis=(0, 1))[None] - jnp.sum(share, axis=1)  # (m, B): flagged, not this point
    clean = jnp.max(finite - pull * others[:, None], axis=1)
    single = jnp.arange(m)[:, None] == k[None]
    many = used & (single | (clean > c[None]))
    n_out = jnp.sum(many.astype(int), axis=0)
    fits = (n_used - n_out >= opt.min_points) & (red - 2.0 * n_out.astype(float) >= opt.min_redundancy)
    return go, jnp.where(fits[None], many, single), stat, c


def solve_cheap(inp: Inputs, opt: Options) -> Output:
    """The cheap path for a batch of lanes: linear start from all control
    points, one adjustment, the test.  ``retry`` asks for the robust path
    (:mod:`._robust`) when, with ``opt.snoop``, the test fails (1), or the
    adjustment fails, or the start or the solution puts a control point
    behind the camera (2)."""
    lin, lin_ok = _linear.linear_start_lanes(inp, opt)
    start = _lanes.sel(inp.use_init, inp.init, lin)
    out = adjust(start, inp, inp.ctrl, opt, fixed=True)
    go, _, _, c = test(out, inp.ctrl, opt)
    behind = jnp.any(inp.ctrl & ~(out["depth"] > 0), axis=0)
    bad_start = ~inp.use_init & ~lin_ok
    # Only the test failed: data snooping can start from this solution (1). Anything else needs the
    # robust start as well (2).
    hard = (out["result"] != RESULTS.successful) | behind | bad_start
    retry = jnp.where(opt.snoop, jnp.where(hard, 2, jnp.where(go, 1, 0)), 0)
    nan = jnp.full((inp.xy.shape[1], 2, inp.xy.shape[2]), jnp.nan)
    return Output(**out, start=start, used=inp.ctrl, stat_at=nan, critical=c, retry=retry)


@functools.partial(jax.jit, static_argnames="max_steps")
def levenberg_marquardt(inp: Inputs, out: Output, opt: Options, max_steps: int) -> Output:
    """Fallback when Gauss-Newton failed: optimistix's Levenberg-Marquardt
    from the same start with the same points, for one image (one lane;
    ``out`` in lanes too; autodiff Jacobian: it runs rarely, and is compiled
    only then)."""
    import lineax as lx
    import optimistix as optx

    used = out.used

    def residuals(p, _):
        v, _, _, _ = evaluate(p[:, None], inp, used, opt)
        return v.reshape(-1) / opt.camera.focal_length  # dimensionless: tolerances independent of the unit

    algo = optx.LevenbergMarquardt(rtol=1e-11, atol=1e-11, linear_solver=lx.QR())
    sol = optx.least_squares(residuals, algo, out.start[:, 0], max_steps=max_steps, throw=False)
    code = jnp.where(jnp.all(jnp.isfinite(sol.value)), from_optimistix(sol.result), RESULTS.nonfinite)
    fields = precision(sol.value[:, None], inp, used, opt)
    return Output(
        **fields,
        result=code[None],
        steps=sol.stats["num_steps"][None],
        start=out.start,
        used=used,
        stat_at=out.stat_at,
        critical=out.critical,
        retry=out.retry,
    )
