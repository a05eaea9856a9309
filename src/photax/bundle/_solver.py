"""The Levenberg–Marquardt loop of :func:`bundle_adjust`, its point pass for
robust losses, and the assembly of its result.

The loop is Ceres' LevenbergMarquardtStrategy and TrustRegionMinimizer
line by line (checked against trust_region_minimizer.cc and
levenberg_marquardt_strategy.cc): damping ``diag(J^T J)/mu`` clamped to
``[1e-6, 1e32]`` (Ceres' Jacobi scaling of the columns gives the same
unscaled step), the model decrease ``L(0) - L(h)`` (equal to Ceres'
``-(J h)^T (r + J h / 2)`` for the exact solve, measured to 7 digits),
acceptance at gain ratio ``> 1e-3``, Nielsen's radius update, the function
tolerance on accepted steps.

Where photax differed from Ceres was the update of each image: Ceres (in
COLMAP's parametrisation) adds the translation in the camera frame after
the rotation; photax added ``dC`` in the world frame.  The two agree to
first order, but on a block where every image has its own focal length the
weakest mode of each image is a move along its optical axis traded against
``f``, and a step that also tilts the camera moved it along the *old*
axis, leaving that valley sideways: on the 400-image block the undamped
Gauss–Newton step had a gain ratio of -177 where Ceres' near-undamped steps
had 1.1, the radius stalled at 1e7 with gain ratios 0.6-0.9, and photax
took 27 iterations to Ceres' 15 (900 images: 34 to 28, final cost 1.9e-5
above Ceres').  The centre step now turns with the camera, ``C <- C + R'
R^T dC`` (:func:`photax.bundle._schur._trial`): 15 iterations on the same
path as Ceres (same radii and costs to 4 digits), 27 to 28 at 900 images.

A least-squares step is not extended when its gain ratio exceeds 1 (it
was, 2026-11-24, doubling the step while the cost fell: 14 and 26
iterations at 400 and 900 images instead of 15 and 28).  Since the trial
linearises at its candidate (one projection pass per accepted step instead
of two, see :func:`_lm_loop`), an extension costs that linearisation and a
cost pass per multiple, more than the iteration it saves: the whole
adjustment took 0.75x (400 images) and 0.85x (900 images) the CPU time
without it, to final costs still 0.9e-6 and 1.9e-6 below Ceres'.

Why the robust adjustment converges, and fast
---------------------------------------------
Each step is Ceres' trust-region step on the robustified model
(:func:`photax.bundle._robust._corrector`): for Huber and Cauchy plain
reweighting, whose quadratic model majorises the loss along every residual.
With a robust loss the trial point is then improved by a *point pass*
(:func:`_point_pass`): given the trial cameras, the cost is a sum of
independent 3-unknown problems, one per point, and each point moves to the
best of a few multiples ``a`` (:data:`POINT_STEPS`, 0 included) of its own
reweighted Gauss–Newton step, judged on its own robust cost.

* Global convergence is the trust region's: the pass only lowers the cost
  (``a = 0`` keeps every point where the trial put it), and the gain ratio
  credits its decrease to both the actual and the predicted decrease::

      rho = (f(x) - f(x_pass)) / (m(0) - m(h) + f(x + h) - f(x_pass))

  so the ratio (and the damping) still measures the model of the step,
  while the iterate may be any point no worse than the trial point: the
  "magical steps" of Conn, Gould & Toint, *Trust-Region Methods* (SIAM
  2000), sec. 10.4.1.  A trial point whose cost or step is not finite is
  rejected before the pass: no NaN step is taken.
* The speed comes from where the reweighted model is wrong.  Beyond the loss
  scale Huber's cost is linear in ``|r|`` (Cauchy's concave): a point whose
  residuals lie there has a direction (for two rays: along which each
  residual changes only in length) where the true cost is linear up to a
  residual crossing the scale, while every quadratic model curves, so LM
  advances a fixed short distance per iteration (gain ratio 2: ``data/block``,
  Huber, took 23 iterations with Triggs' correction floored at 0.1 and 163
  in Ceres).  These directions belong to single points, and given the
  cameras the points are separable: the pass's longer multiples cross such a
  flat stretch in one iteration, its shorter ones (and 0) stop a point that
  the model pushed past a residual's scale, without rejecting the whole
  step.  The cameras, each fitted to many residuals, fared well with the
  reweighted curvature in our measurements (below).  This is the "embedded point iterations" of
  Jeong et al., "Pushing the envelope of modern methods for bundle
  adjustment" (PAMI 2012), with a per-point search instead of a full solve.
  A point moves at most half its distance to its nearest camera per pass,
  so points whose cost keeps falling with depth (near infinity) recede
  gradually instead of being thrown out.

Measured (``iterations``, Ceres 2.2 with the same loss, scale and stopping
rule in brackets; photax's final cost is the lower in all four):
``data/block`` Huber 9 (163), Cauchy 13 (44); BAL problem-49-7776 (damped
gauge) Huber 20 (86), Cauchy 54 (61).  Without the pass (2026-11-24, the
centre update above): 155, 26, 105 and 117, with higher final costs in
three of the four.  Least squares does not use the pass (its Gauss–Newton
model has no flat directions of this kind), nor does the 900-image block.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import sys
import time
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._linalg import inv3
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..errors import RESULTS, ConvergenceError
from ..rotation import angles_from_matrix_unchecked, rotation_matrix
from ._linearise import LIN_WHOLE, _camera_prior, _dem_residuals, _linearise, _prior_residuals, _project_obs
from ._precision import _covariances, _covariances_band, _orientation_covariances, _standard_deviations
from ._problem import BundleProblem, Gauge, Loss
from ._result import BundleResult, _image_parts, stop_message
from ._robust import _LOSS_CODE, _corrector, _rho
from ._schur import _trial
from ._sparse import choose_solver
from ._start import _needs_init, initialize_block
from ._structure import _State


def _datum_constraints(problem: BundleProblem, images=None) -> int:
    """Rough count of datum constraints (a network needs 7) of the whole
    block or of some ``images`` (a part): control points (seen by them),
    fixed orientations, GNSS positions and attitudes, 3 each."""
    ctrl = problem.roles == "control"
    if images is None:
        images = np.arange(problem.n_images)
    else:
        seen = np.isin(problem.obs_image, images)
        ctrl = ctrl & np.isin(np.arange(problem.n_points), problem.obs_point[seen])
    n_cam = int(problem.gnss_observed[images].sum() + problem.attitude_observed[images].sum())
    return 3 * int(ctrl.sum()) + int(problem.fixed_exterior[images].sum()) + 3 * n_cam


def _gnss_on_a_line(problem: BundleProblem, images) -> bool:
    """Whether the datum of ``images`` rests on GNSS positions alone (no
    control, fixed orientation or attitude) and they lie on one line within
    3 sigma (one straight strip): the roll about it is then free."""
    if _datum_constraints(problem, images) != 3 * int(problem.gnss_observed[images].sum()):
        return False
    seen = images[problem.gnss_observed[images]]
    d = problem.gnss_position[seen] - problem.gnss_position[seen].mean(axis=0)
    if len(d) < 3:
        return False
    _, _, vt = np.linalg.svd(d, full_matrices=False)
    off_line = d - np.outer(d @ vt[0], vt[0])
    spread = math.sqrt(np.mean(np.sum(off_line**2, axis=1)))
    return spread < 3.0 * float(np.median(problem.gnss_sigma[seen]))


def _datum_defect(problem: BundleProblem) -> str:
    """Why the block (or one of its parts that share no point with the
    rest) has no datum of its own, or ``""``."""
    if _datum_constraints(problem) < 7:
        return (
            "the network has no datum: fewer than 3 control points or GNSS positions and no fixed "
            "orientations (7 parameters: translation, rotation, scale are free). Add control points, GNSS "
            "positions (gnss_position=, --position-sigma), fix orientations (fixed_exterior=), or choose "
            "gauge='fix_first_camera' or gauge='damped' (LM damping handles the defect, as Ceres does "
            "for BAL)"
        )
    parts = [np.asarray(q) for q in _image_parts(problem)]
    for q in parts:
        where = "" if len(parts) == 1 else (
            f" of the part of {len(q)} image(s) from {problem.image_names[q[0]]} that shares no point with "
            "the rest of the block"
        )  # fmt: skip
        if _datum_constraints(problem, q) < (7 if len(q) > 1 else 6):  # one image: no scale to fix
            return (
                f"the network has no datum{where}: give it control points or GNSS positions of its own, "
                "or tie it to the rest"
            )
        if _gnss_on_a_line(problem, q):
            return (
                f"the network has no datum{where}: its only datum, the GNSS positions, lie on one line "
                "(within 3 sigma), so the roll about that line is free. Add attitude observations "
                "(attitude=, --attitude-sigma), control points, or a second strip"
            )
    return ""


def _blas_threads(n_c: int, solver: str = "dense"):
    """One BLAS thread for the small dense factorisations of the reduced
    system: OpenBLAS' thread pool spins, and on a busy 2-core machine a
    441 x 441 Cholesky took 10-100x longer with 2 threads than with 1.
    The banded path's Cholesky and triangular solves are of one chunk
    (a few hundred unknowns) at a time: one thread there too (400 BAL
    images, load 14: a trial step 2.0 -> 0.82 s wall, 0.84 -> 0.38 CPU s).
    Only a large dense factor gains from threads."""
    if solver == "dense" and n_c > 1500:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, user_api="blas")


def bundle_adjust(
    problem: BundleProblem,
    *,
    loss: Loss = "none",
    loss_scale: float = 1.0,
    method: Literal["levenberg-marquardt", "gauss-newton"] = "levenberg-marquardt",
    gauge: Gauge | None = None,
    max_steps: int = 50,
    function_tolerance: float = 1e-6,
    gradient_tolerance: float = 1e-10,
    parameter_tolerance: float = 1e-8,
    initial_trust_radius: float = 1e4,
    linear_solver: Literal["auto", "dense", "band", "cg"] = "auto",
    precision: bool = True,
    initialize: bool | Literal["auto"] = "auto",
    verbose: bool = False,
    progress: bool | str = False,
    throw: bool = True,
    max_iterations: int | None = None,
) -> BundleResult:
    """Adjust a block by (robust) Levenberg–Marquardt with a Schur complement.

    Args:
        problem: the :class:`BundleProblem`.
        loss: ``"none"`` (least squares), ``"huber"`` or ``"cauchy"``.
        loss_scale: ``d``, the residual norm (in sigmas) where the robust loss
            starts to down-weight.
        method: ``"levenberg-marquardt"`` (Ceres-like trust region) or
            ``"gauss-newton"`` (undamped steps, all accepted).
        gauge: the datum of a network without enough control:
            ``"fix_first_camera"`` fixes the first image's orientation and
            the largest baseline component of the second image's centre (7
            parameters); ``"damped"`` leaves the 7-parameter datum defect to
            the LM damping, as Ceres does for BAL problems (the solution is
            one of the equivalent ones; precision is not reported).  ``None``
            (default) refuses a network whose datum is not defined by control
            points, fixed orientations or GNSS positions / attitudes (each
            part of a block that shares no point with the rest needs its
            own; GNSS positions alone on one line leave the roll free).
        max_steps: iterations counted as Ceres does (accepted and
            rejected steps).  ``max_iterations`` is its old name (still
            accepted).
        function_tolerance, gradient_tolerance, parameter_tolerance: the
            stopping rule (Ceres' defaults), tested after each step::

                |cost_old - cost_new| <= function_tolerance * cost_old      (accepted steps)
                max |g| <= gradient_tolerance,  g = J^T r                   (at each new point)
                |dx| <= parameter_tolerance * (|x| + parameter_tolerance)   (each computed step)

            ``|x|`` is the norm of centres, intrinsics and points (local
            origin).
        initial_trust_radius: ``mu``; the damping is ``lambda = 1/mu``.  After
            a step with gain ratio ``rho > 1e-3``: ``mu /= max(1/3, 1 -
            (2 rho - 1)^3)``, else ``mu /= nu, nu *= 2`` (Nielsen; Ceres).
        linear_solver: how the reduced camera system ``S`` is solved:
            ``"dense"`` Cholesky (``S`` formed, ``N^2`` memory), ``"band"``
            sparse block-tridiagonal Cholesky in a bandwidth-reducing image
            order (:mod:`photax.bundle._sparse`; blocks of strips),
            ``"cg"`` matrix-free conjugate gradients with a Schur–Jacobi
            preconditioner (``S`` never formed), ``"auto"``: by estimated
            cost (:func:`photax.bundle._sparse.choose_solver`: banded when
            its flops are well below the dense ones, CG only when the band
            would not fit in memory).
        precision: compute sigma0 and standard deviations (the blocks of
            ``S^-1`` on its pattern: the dense inverse, or for the banded
            and CG paths selected inversion of the banded factor).
        initialize: fill NaN orientations / points with
            :func:`initialize_block` (``"auto"``: only when some are NaN).
        verbose: print one line per iteration.
        progress: a progress bar counting the iterations, with the cost (no
            total: ``max_steps`` is a limit, not a forecast): ``True``
            (labelled "bundle"), a label, or an open bar (:mod:`photax.progress`).
        throw: raise :class:`photax.ConvergenceError` when the adjustment fails
            (no convergence within ``max_steps``, singular normal
            equations); else return the result with ``converged=False``.

    Returns:
        :class:`BundleResult`.

    Examples:
        A synthetic block (2 strips of 4 images, 6 control and 4 check points, 100 ties, 0.5 px noise;
        :func:`photax.scene.synthetic_block`) from perturbed start values:

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.scene import synthetic_block
        >>> problem, truth = synthetic_block(0)
        >>> result = ptx.bundle_adjust(problem)
        >>> result.converged, result.result.name
        (True, 'successful')
        >>> print(f"sigma0 {result.sigma0:.1f}")  # the 0.5 px noise in units of its sigma: about 1
        sigma0 1.0
        >>> ties = problem.roles == "tie"
        >>> bool(np.all(np.abs(result.points - truth.points)[ties] < 5 * result.point_std[ties]))
        True
    """
    # Over 80 lines only by its signature and docstring (the reference for
    # every option); the work is in _check_options, _start_state and _lm_loop.
    # photax says max_steps (as optimistix and resect do); the loop below still
    # counts in Ceres' word, max_iterations.
    max_iterations = max_steps if max_iterations is None else max_iterations
    _check_options(problem, loss, loss_scale, method, gauge)
    if initialize is True or (initialize == "auto" and _needs_init(problem)):
        problem = initialize_block(problem)
    if _needs_init(problem):
        raise ValueError("problem has NaN orientations or points: give start values or initialize=True")
    t_start = time.perf_counter()
    s, n_c, _, origin = problem.analyse(gauge)  # cached on the problem
    state = _start_state(problem, origin)
    if linear_solver not in ("auto", "dense", "band", "cg"):
        raise ValueError(f"linear_solver must be 'auto', 'dense', 'band' or 'cg', got {linear_solver!r}")
    solver = linear_solver if linear_solver != "auto" else choose_solver(s.band_perm.shape, s.band_border.shape[0], n_c)
    rule = StoppingRule(function_tolerance, gradient_tolerance, parameter_tolerance, max_iterations)
    kw = dict(loss=jnp.asarray(_LOSS_CODE[loss]), scale=jnp.asarray(float(loss_scale)), n_c=n_c)
    with _blas_threads(n_c, solver):
        with contextlib.ExitStack() as bars:
            bar = None
            if progress:  # one bar, labelled "bundle" or by the caller (photax.progress)
                from ..progress import progress_bar

                # Leaving the stack closes a bar of its own, not a caller's.  No total: the loop
                # stops long before max_iterations as a rule, so a percentage and an ETA would lie.
                bar = bars.enter_context(progress_bar(progress, None, desc="bundle", unit="it"))
            lin = _linearise(state, s, **kw)
            initial_cost = float(lin.cost)
            state, lin, cost, history, code, rule_text, it = _lm_loop(
                state, lin, s, kw, solver, rule, method == "gauss-newton", float(initial_trust_radius),
                loss != "none", verbose, bar,
            )  # fmt: skip
        message = stop_message(code, rule_text, max_steps=max_iterations)
        return _finish(problem, state, lin, s, n_c, origin, gauge, precision, cost, initial_cost, history,
                       code, message, it, throw, time.perf_counter() - t_start, solver)  # fmt: skip


def _check_options(problem: BundleProblem, loss, loss_scale, method, gauge) -> None:
    """ValueError for an unknown option or a network without a datum."""
    if loss not in ("none", "huber", "cauchy"):
        raise ValueError(f"loss must be 'none', 'huber' or 'cauchy', got {loss!r}")
    if method not in ("levenberg-marquardt", "gauss-newton"):
        raise ValueError(f"method must be 'levenberg-marquardt' or 'gauss-newton', got {method!r}")
    if gauge not in (None, "fix_first_camera", "damped"):
        raise ValueError(f"gauge must be None, 'fix_first_camera' or 'damped', got {gauge!r}")
    if not loss_scale > 0:
        raise ValueError(f"loss_scale must be positive, got {loss_scale}")
    defect = _datum_defect(problem) if gauge is None else ""
    if defect:
        raise ValueError(defect)


def _start_state(problem: BundleProblem, origin: np.ndarray) -> _State:
    """The problem's start values as solver state, ground coordinates relative to ``origin``."""
    intr = np.stack(
        [
            np.concatenate([[float(c.focal_length)], np.asarray(c.principal_point), np.asarray(c.distortion)])
            for c in problem.cameras
        ]
    )
    return _State(
        _rotation(problem.exterior.angles, convention=problem.exterior.convention),
        jnp.asarray(np.asarray(problem.exterior.position) - origin[None, :]),
        jnp.asarray(intr), jnp.asarray(problem.points - origin[None, :]),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class StoppingRule:
    """When the Levenberg–Marquardt loop of :func:`bundle_adjust` stops
    (Ceres' rule and defaults).  Converged when, after a step::

        |cost_old - cost_new| <= function_tolerance * cost_old      (accepted steps)
        max |g| <= gradient_tolerance,  g = J^T r                   (at the start and each new point)
        |dx| <= parameter_tolerance * (|x| + parameter_tolerance)   (each computed step)

    tested in this order, ``|x|`` the norm of centres, intrinsics and points
    (local origin); not converged after ``max_iterations`` steps (accepted
    and rejected).  The failures (singular equations, trust radius below
    1e-32) are the loop's own."""

    function_tolerance: float = 1e-6
    gradient_tolerance: float = 1e-10
    parameter_tolerance: float = 1e-8
    max_iterations: int = 50

    def at_start(self, gmax: float) -> str:
        """The convergence message at the start values, or ``""``."""
        if gmax <= self.gradient_tolerance:
            return f"gradient tolerance: max|g| = {gmax:.3g} <= {self.gradient_tolerance:g}"
        return ""

    def after_step(self, accepted: bool, old: float, cost: float, gmax: float, step: float, xnorm: float) -> str:
        """The convergence message after a step, or ``""``."""
        if accepted and abs(old - cost) <= self.function_tolerance * old:
            return f"function tolerance: |dcost|/cost = {abs(old - cost) / max(old, 1e-300):.3g} <= {self.function_tolerance:g}"
        if accepted and gmax <= self.gradient_tolerance:
            return f"gradient tolerance: max|g| = {gmax:.3g} <= {self.gradient_tolerance:g}"
        if math.isfinite(step) and step <= self.parameter_tolerance * (xnorm + self.parameter_tolerance):
            return f"parameter tolerance: |dx| = {step:.3g} <= {self.parameter_tolerance:g} (|x| + tol)"
        return ""


def _lm_loop(state, lin, s, kw, solver, rule: StoppingRule, gn: bool, mu: float, robust: bool, verbose: bool, bar):
    """Levenberg–Marquardt (or Gauss–Newton, ``gn``) steps from ``state``
    and its linearisation ``lin`` until ``rule`` or a failure stops them.
    ``mu`` is the trust radius (damping ``1/mu``; Nielsen's update as in
    Ceres); with a ``robust`` loss each finite trial point is improved by
    :func:`_point_pass` (see the module docstring).  Returns ``(state, lin,
    cost, history, code, rule, iterations)``: ``code`` the
    :class:`photax.RESULTS` code of the stop, set where it happens, and
    ``rule`` the stopping rule's words when it converged."""
    cost, nu = float(lin.cost), 2.0
    if not math.isfinite(cost):  # no step can be judged from a NaN or infinite cost
        return state, lin, cost, [], RESULTS.nonfinite, "", 0
    # Least squares: the trial linearises at its candidate (whose cost comes
    # with it), kept when the step is accepted, so each step projects the
    # observations once, not twice (its cost, then the linearisation at the
    # new point): 900-image block 0.89x the CPU time (interleaved runs at
    # load 4-5; 0.76x with the step extension it made unprofitable removed,
    # see the module docstring).  Not with a robust loss
    # (the point pass moves the candidate), nor where the linearisation is
    # chunked for memory (two would coexist: 10,000 images).
    fuse = not robust and s.obs_image.shape[0] <= LIN_WHOLE
    history: list[dict] = []
    gmax = float(lin.gmax)
    message = rule.at_start(gmax)
    code = RESULTS.successful if message else RESULTS.max_steps_reached
    it = 0
    while not message and it < rule.max_iterations:
        it += 1
        t0 = time.perf_counter()
        lam = 0.0 if gn else 1.0 / mu
        new, new_cost, pred, step, xnorm, lin_new = _trial(state, lin, s, jnp.asarray(lam), **kw, solver=solver,
                                                            relinearise=fuse)  # fmt: skip
        new_cost, pred, step, xnorm = float(new_cost), float(pred), float(step), float(xnorm)
        gain = 0.0  # decrease by the point pass, credited to the prediction too
        if robust and math.isfinite(new_cost):
            passed, pass_cost = _point_pass(new, s, kw["loss"], kw["scale"])
            pass_cost = float(pass_cost)
            if pass_cost < new_cost:  # finite and lower (a = 0 keeps the trial point)
                new, gain, new_cost = passed, new_cost - pass_cost, pass_cost
        rho = (cost - new_cost) / (pred + gain) if pred > 0 else -1.0
        accepted = (gn and math.isfinite(new_cost)) or (rho > 1e-3 and math.isfinite(new_cost))
        old = cost
        if accepted:
            state, cost = new, new_cost
            lin = lin_new if lin_new is not None else _linearise(state, s, **kw)  # the candidate's own: see fuse
            gmax = float(lin.gmax)
            mu = mu / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            mu, nu = min(mu, 1e16), 2.0
        else:
            mu, nu = mu / nu, nu * 2.0
        lin_new = None  # a rejected candidate's linearisation is freed before the next trial
        history.append(dict(iteration=it, cost=cost, candidate_cost=new_cost if math.isfinite(new_cost) else None, relative_decrease=rho, trust_radius=mu,
                            step_norm=step, gradient_max=gmax, accepted=bool(accepted),
                            seconds=time.perf_counter() - t0))  # fmt: skip
        if verbose:
            _print_step(bar, it, cost, old, gmax, step, mu, accepted, new_cost)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(cost=f"{cost:.4g}")
        if not math.isfinite(step) and (gn or mu < 1e-32):
            return state, lin, cost, history, RESULTS.singular, "", it
        message = rule.after_step(accepted, old, cost, gmax, step, xnorm)
        if message:
            code = RESULTS.successful
        elif not gn and mu < 1e-32:  # the trust region shrank to nothing: no decrease possible
            return state, lin, cost, history, RESULTS.solver_failed, "", it
    return state, lin, cost, history, code, message, it


#: Multiples of its reweighted Gauss–Newton step among which the point pass
#: picks, per point, the one of lowest robust cost.  0 keeps the point (so the
#: pass never raises a point's cost); fractions stop a point that the model
#: pushed past a residual's loss scale; the powers of 2 up to 64 let a point
#: cross a flat stretch of the loss (where the model's step is a fixed short
#: distance) in one pass.  A geometric grid: the search brackets the best
#: multiple within a factor 2 at the cost of ten cost evaluations (cheap next
#: to one linearisation).
POINT_STEPS = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)


@jax.jit
def _point_costs(state: _State, s, loss, scale):
    """``(n_pts,)`` each point's share of the cost: ``0.5 sum rho`` over its
    observations plus its control prior and DEM height.  With the cameras'
    observations they sum to the cost."""
    r = (_project_obs(state, s) - s.obs_xy) / s.obs_sigma
    rho, _, _ = _rho(jnp.sum(r * r, axis=1), loss, scale)
    per_point = jax.ops.segment_sum(0.5 * rho, s.obs_point, num_segments=state.xyz.shape[0])
    prior = 0.5 * jnp.sum(_prior_residuals(state, s) ** 2, axis=1) + 0.5 * _dem_residuals(state, s) ** 2
    return per_point + prior  # GNSS: _point_pass adds it


@jax.jit
def _point_pass(state: _State, s, loss, scale):
    """The point pass of a robust adjustment (see the module docstring).

    Per point ``p``, with the cameras of ``state`` fixed: the reweighted
    Gauss–Newton step ``dX_p = -V_p^-1 g_p`` (``V_p = sum J~^T J~`` and
    ``g_p = sum rho' J^T r`` over its observations, plus its prior and DEM height, as in
    :func:`photax.bundle._linearise._linearise`; fixed coordinates masked),
    then ``X_p + a dX_p`` for the ``a`` of :data:`POINT_STEPS` with the
    lowest cost of that point, among those that move it by at most half its
    distance to the nearest camera that sees it.  A step that is not finite
    (singular ``V_p``) is not taken.  Returns the new state and its cost."""
    proj, _, jp = _project_obs(state, s, jacobians=True)
    r = (proj - s.obs_xy) / s.obs_sigma
    _, rho1, rho2 = _rho(jnp.sum(r * r, axis=1), loss, scale)
    sqrt_rho1, alpha_sq = _corrector(r, rho1, rho2)
    j = jp / s.obs_sigma[:, :, None]
    jt = j - (alpha_sq[:, None] * r)[:, :, None] * jnp.einsum("kr,krj->kj", r, j)[:, None, :]
    jt = jt * sqrt_rho1[:, None, None]  # J~ (Ceres' corrector; sqrt(rho') J for Huber, Cauchy)
    n_pts = state.xyz.shape[0]
    segp = functools.partial(jax.ops.segment_sum, segment_ids=s.obs_point, num_segments=n_pts)
    m, pw = s.mask_p, s.prior_w * s.mask_p
    eye = jnp.eye(3)[None, :, :]
    rd, jd = _dem_residuals(state, s, jacobians=True)
    v = segp(jnp.einsum("kri,krj->kij", jt, jt)) + pw[:, :, None] * eye + jd[:, :, None] * jd[:, None, :]
    v = v * m[:, :, None] * m[:, None, :] + (1.0 - m)[:, :, None] * eye  # fixed coordinates: identity rows
    g = (segp(jnp.einsum("kri,kr->ki", j, r * rho1[:, None])) + pw * (state.xyz - s.prior_xyz) + jd * rd[:, None]) * m
    dx = -jnp.einsum("pij,pj->pi", jax.vmap(inv3)(v), g)
    dx = jnp.where(jnp.all(jnp.isfinite(dx), axis=1, keepdims=True), dx, 0.0)
    # A point moves at most half its distance to the nearest camera that sees
    # it: it cannot reach a camera, and a point whose cost keeps falling with
    # depth (near infinity, little parallax) recedes by at most 1.5x per pass
    # instead of being thrown out by the long multiples (problem-49-7776:
    # points at 1e15 and a false stop on the parameter tolerance without it).
    dist = jnp.linalg.norm(state.xyz[s.obs_point] - state.centre[s.obs_image], axis=1)
    reach = 0.5 * jax.ops.segment_min(dist, s.obs_point, num_segments=n_pts)
    steps = jnp.asarray(POINT_STEPS)
    costs = jax.lax.map(lambda a: _point_costs(state._replace(xyz=state.xyz + a * dx), s, loss, scale), steps)
    allowed = steps[:, None] * jnp.linalg.norm(dx, axis=1)[None, :] <= reach[None, :]
    costs = jnp.where(allowed & jnp.isfinite(costs), costs, jnp.inf)
    best = jnp.argmin(costs, axis=0)  # a = 0, the trial point (finite cost), is always allowed
    new = state._replace(xyz=state.xyz + steps[best][:, None] * dx)
    cameras = 0.5 * jnp.sum(_camera_prior(state, s) ** 2)  # the cameras' observations: the pass keeps them
    return new, jnp.sum(jnp.min(costs, axis=0)) + cameras


def _gnss_residuals(problem: BundleProblem, position, rot: np.ndarray) -> np.ndarray:
    """``(n_img, 3)`` adjusted antenna position ``C + R l`` minus the GNSS
    observation (NaN where none)."""
    antenna = np.asarray(position) + np.einsum("nij,nj->ni", rot, problem.lever_arm)
    return antenna - problem.gnss_position


def _attitude_residuals(problem: BundleProblem, eo: ExteriorOrientation) -> np.ndarray:
    """``(n_img, 3)`` adjusted minus observed attitude angles, radians,
    wrapped to ``[-pi, pi)`` (NaN where none)."""
    d = np.asarray(eo.angles) - problem.attitude
    return (d + np.pi) % (2 * np.pi) - np.pi


def _print_step(bar, it, cost, old, gmax, step, mu, accepted, new_cost) -> None:
    """One line per iteration (``verbose=True``)."""
    status = "ok" if accepted else "rejected" if math.isfinite(new_cost) else "rejected (no finite step)"
    line = (f"{it:4d}  cost {cost:.6e}  cost_change {old - cost:+.3e}  |g| {gmax:.2e}  |step| {step:.2e}  "
            f"tr_radius {mu:.2e}  {status}")  # fmt: skip
    if hasattr(bar, "write"):  # through the bar, which clears and redraws itself around the line
        bar.write(line, file=sys.stdout)
    else:
        print(line, flush=True)


# Jitted once: eagerly, each of their few dozen jnp operations compiles on first use.
_camera_prior_jit = jax.jit(_camera_prior)
_dem_residuals_jit = jax.jit(_dem_residuals)
_rotation = jax.jit(rotation_matrix, static_argnames="convention")
_angles = jax.jit(angles_from_matrix_unchecked, static_argnames="convention")


def _with_intrinsics(camera: FrameCamera, k) -> FrameCamera:
    """``camera`` with the adjusted intrinsics ``k`` (f, x0, y0, coefficients: its ``intrinsic_names``), its
    type and everything else kept: a :class:`photax.interior.ScannedCamera` keeps its film -> scan
    transformation (self-calibration adjusts the camera, not the scanner)."""
    return eqx.tree_at(
        lambda c: (c.focal_length, c.principal_point, c.distortion),
        camera,
        (jnp.asarray(k[0]), jnp.asarray(k[1:3]), jnp.asarray(k[3:])),
    )


def _finish(problem, state, lin, s, n_c, origin, gauge, precision, cost, initial_cost, history, code, message,
            iterations, throw, seconds, solver="dense") -> BundleResult:  # fmt: skip
    """The :class:`BundleResult` of the loop's stop (``code`` and its ``message``); a
    singular normal matrix at the solution turns it into ``RESULTS.singular``."""
    conv = problem.exterior.convention
    rot = np.asarray(state.rot)
    angles, _ = _angles(state.rot, convention=conv)
    eo = ExteriorOrientation(np.asarray(state.centre) + origin[None, :], np.asarray(angles), conv)
    intr = np.asarray(state.intr)
    n_intr = intr.shape[1]
    cams = tuple(_with_intrinsics(c, k) for k, c in zip(intr, problem.cameras))
    pts = np.asarray(state.xyz) + origin[None, :]
    weight = np.asarray(lin.weight)
    residuals = np.asarray(lin.r) * problem.obs_sigma
    n_free = int(np.asarray(s.mask_c).sum() + np.asarray(s.mask_p).sum())
    # GNSS positions and attitudes are observations: 3 each in the redundancy, their residuals in sigma0
    n_cam_obs = 3 * int(problem.gnss_observed.sum() + problem.attitude_observed.sum())
    # ... and so are the tie points' DEM heights, one each
    n_prior = int(np.sum(np.asarray(s.prior_w) > 0)) + n_cam_obs + int(np.sum(np.asarray(s.dem_w) > 0))
    redundancy = 2 * problem.n_observations + n_prior - n_free + (7 if gauge == "damped" else 0)
    wsq = float(
        np.sum(weight[:, None] * np.asarray(lin.r) ** 2)
        + np.sum((np.asarray(state.xyz) - np.asarray(s.prior_xyz)) ** 2 * np.asarray(s.prior_w))
    )
    wsq += float(np.sum(np.asarray(_camera_prior_jit(state, s)) ** 2))
    r_dem, w_dem = np.asarray(_dem_residuals_jit(state, s)), np.asarray(s.dem_w)
    wsq += float(np.sum(r_dem**2))
    dem_res = np.where(w_dem > 0, r_dem / np.maximum(w_dem, 1e-300), np.nan) if problem.dem is not None else None
    sigma0 = math.sqrt(wsq / redundancy) if redundancy > 0 else float("nan")
    eo_std = cam_std = pt_std = pt_cov = eo_cov = None
    if precision and gauge != "damped":
        cov = _covariances(lin, s, n_c) if solver == "dense" else _covariances_band(lin, s, n_c)
        q_img, q_cam, q_p, ok = cov
        if not bool(ok):
            code = RESULTS.singular
            message = stop_message(code, at_solution=True)
        else:
            var0 = sigma0**2 if redundancy > 0 else 1.0
            eo_std, cam_std, pt_std, pt_cov = _standard_deviations(
                q_img, q_cam, q_p, var0, state.rot, conv, s.active, problem.n_cameras, n_intr
            )
            eo_cov = _orientation_covariances(q_img, var0, state.rot, conv, s.active, n_intr)
    check = problem.roles == "check"
    result = BundleResult(
        exterior=eo, rotation=rot, cameras=cams, points=pts, cost=float(cost), initial_cost=float(initial_cost),
        history=history, converged=code == RESULTS.successful, message=message, iterations=iterations,
        residuals=residuals,
        weights=weight, sigma0=sigma0, redundancy=redundancy, exterior_std=eo_std, camera_std=cam_std,
        point_std=pt_std, point_cov=pt_cov, check_residuals=pts[check] - problem.points[check], problem=problem,
        seconds=seconds, result=RESULTS(code), orientation_cov=eo_cov,
        gnss_residuals=_gnss_residuals(problem, eo.position, rot),
        attitude_residuals=_attitude_residuals(problem, eo),
        dem_residuals=dem_res,
    )  # fmt: skip
    if throw and not result.converged:
        raise ConvergenceError(f"bundle adjustment failed: {message}")
    return result
