"""resect and resect_batch: one validation, the cheap path, the robust path
for the images that need it, one finishing step.

Both run the same compiled functions on a batch of images carried on the
last axis of every array (lanes, :mod:`._lanes`; a single image is a batch
of one): :func:`._adjust.solve_cheap` for
every image, then :func:`._robust.solve_robust` for the compacted set of
images the cheap path hands over (``retry``): first those that only failed
the blunder test, from their cheap solution; then, from the LMedS start,
the rest and those the first pass left failed.  Each compiles once per
padded point count (16, 32, ... for ``resect``; the next multiple of 4 for
``resect_batch``) and batch shape (1 for ``resect``, fixed-size chunks for
``resect_batch``, whose robust chunks have their own optimised program).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from typing import NamedTuple

import jax
import numpy as np

from .._aot import disk_cached
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..errors import RESULTS, ConvergenceError
from ..rotation import Convention
from . import _adjust, _robust
from ._checks import (
    _MAX_TILT,
    _PLANAR,
    CAUSES,
    MIRROR,
    Prepared,
    _bucket,
    _critical_table,
    _frame,
    _pixel_size,
    _plausibility,
    _point_label,
    implausible,
    units_wrong,
    validate,
)
from ._result import ResectionResult
from ._types import Inputs, Options, Output, pack, unpack

_CHUNK = 1024  # images per call of the cheap path in a resect_batch of more than half this many images
# ... and in a smaller one: its program compiles in half the CPU time (LAPACK for the linear start's
# systems, _lanes.solve_spd), and a few images do not pay for 1,024 lanes.  The crossover, measured
# (robust=False, CPU ms, 64- vs 1024-image calls): 256 images 8.6 vs 13.8, 512 13.6 vs 14.3, 768 23.4
# vs 15.6, 1,000 25.2 vs 15.7 (the 64-image calls cost more per image than their lanes).
_SMALL_CHUNK = 64
_ROBUST_CHUNK = 32  # images per call of the robust path (a few per cent of a batch go there)

# The compiled solvers: a batch of images (lanes last, :mod:`._lanes`) in, a packed (L, B) float array out.
# Kept on disk when a program opts in (the command line does): tracing them was 2.4 s of a warm `photax resect`.
# XLA:CPU's classic loop emitters: the element-wise lane code compiles in about two thirds of the CPU time
# of the default (MLIR) fusion emitters and runs as fast (measured on the cheap path, 1024 images:
# first call 6.2-6.8 vs 4.2 s CPU, warm 24 vs 23-26 us per image).
_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
# The robust program runs for the few images the cheap path hands over, but every first run (a command
# with an empty cache, a notebook) compiles it: at -O0 it compiles in 5.4 instead of 8.1 CPU s (first
# resect_batch, 2,048 images, a quarter with a blunder) and that batch runs 1.2x longer warm (79 vs 65 ms);
# a batch with a few per cent of such images loses ~1 %.
_ROBUST_OPTIONS = dict(_COMPILER_OPTIONS, xla_backend_optimization_level=0)
_solve_cheap = disk_cached(
    jax.jit(lambda inp, opt: pack(_adjust.solve_cheap(inp, opt)), compiler_options=_COMPILER_OPTIONS),
    "resect_cheap",
    _COMPILER_OPTIONS,
)


def _robust_program(inp, opt):
    return pack(_robust.solve_robust(inp, opt, _robust.starts(inp, opt)))


_solve_robust = disk_cached(
    jax.jit(_robust_program, compiler_options=_ROBUST_OPTIONS), "resect_robust", _ROBUST_OPTIONS
)
# The robust chunks of a large resect_batch (_ROBUST_OPT_MIN images or more), compiled with optimisation:
# measured on the 237 of 10,000 images whose test fails (Pope's tau at alpha = 0.001, no blunder), 10.8 vs
# 20.9 ms at -O0, for about 2.7 s more CPU of first compilation, which a small batch would not win back.
_ROBUST_OPT_MIN = 2048
_solve_robust_batch = disk_cached(
    jax.jit(_robust_program, compiler_options=_COMPILER_OPTIONS), "resect_robust_batch", _COMPILER_OPTIONS
)


class _CameraInfo(NamedTuple):
    """What every call needs from the camera, read once per camera object."""

    half: np.ndarray | None  # half frame (2,) in image-plane units, None without a pixel grid
    f: float  # focal length
    pixel_size: float | None
    solver_camera: FrameCamera  # interior orientation only, on the device
    options: dict  # Options already on the device, by the settings that make them


_LAST_CAMERA: tuple = (None, None)  # (camera, _CameraInfo): scripts resect many images with one camera


def _camera_info(camera: FrameCamera) -> _CameraInfo:
    """The camera's numbers, cached for the last camera object seen (a camera
    is immutable): reading them from the device cost about a tenth of a
    single resection."""
    global _LAST_CAMERA
    last = _LAST_CAMERA
    if last[0] is camera:
        return last[1]
    half, f = _frame(camera)
    # The solvers need no pixel grid; without it (static fields of FrameCamera) every camera shares
    # one compilation (the grid is only read by the numpy-side checks, from the caller's camera).
    solver_camera = jax.device_put(
        FrameCamera(camera.focal_length, camera.principal_point, camera.distortion, model=camera.model)
    )
    info = _CameraInfo(half, f, _pixel_size(camera), solver_camera, {})
    _LAST_CAMERA = (camera, info)
    return info


def _options(prep: Prepared, camera: FrameCamera, convention, robust, alpha, max_steps, m) -> Options:
    """Every setting of the compiled solvers, in one place (on the device,
    built once per camera and settings)."""
    info = _camera_info(camera)
    sigma_known, n_ctrl = prep.sigma_known, len(prep.ctrl_idx)
    key = (
        convention,
        bool(robust),
        float(alpha),
        int(max_steps),
        m,
        sigma_known,
        prep.has_initial,
        prep.ctrl_idx.tobytes(),
    )
    opt = info.options.get(key)
    if opt is not None:
        return opt
    opt = jax.device_put(
        Options(
            critical=_critical_table(float(alpha), sigma_known, m),
            snoop=np.bool_(robust),
            scale_stat=np.bool_(not sigma_known),
            exact=np.float64(1e-10 if sigma_known else 1e-10 * info.f),  # rounding level: no test
            min_points=np.int64(3 if prep.has_initial else 4),
            min_redundancy=np.float64(1.0 if sigma_known else 2.0),
            dlt_ok=np.bool_(n_ctrl >= 6),
            pok=np.bool_(convention == "phi-omega-kappa"),
            subsets=prep.ctrl_idx[_robust.subsets(n_ctrl)],
            camera=info.solver_camera,
            max_steps=np.int64(max_steps),
        )
    )
    if len(info.options) >= 64:
        info.options.clear()
    info.options[key] = opt
    return opt


def _inputs(prep: Prepared, m: int) -> Inputs:
    """The compiled solvers' inputs: points padded to ``m``, the images last (lanes)."""
    b, n = prep.xy.shape[:2]

    def lanes(a, fill):  # (b, n, k) -> (k, m, b)
        out = np.full((a.shape[2], m, b), fill, a.dtype)
        out[:, :n] = a.transpose(2, 1, 0)
        return out

    ctrl = np.zeros((m, b), bool)
    ctrl[:n] = ~prep.is_check.T
    return Inputs(
        xy=lanes(prep.xy, 0.0),
        ground=lanes(prep.local, 0.0),
        weight=lanes(prep.weight, 1.0),
        ctrl=ctrl,
        basis=prep.basis.transpose(1, 2, 0),
        init=prep.init.T,
        use_init=np.full(b, prep.has_initial),
    )


def _take(tree, idx):  # images idx of a batch-first (unpacked) tree
    return jax.tree_util.tree_map(lambda a: a[idx], tree)


def _call(fn, inp: Inputs, opt: Options, chunk: int | None, m: int) -> Output:
    """``fn`` over the images of ``inp`` in chunks of ``chunk`` (the last one
    padded with copies of the first image; None: one call, any size)."""
    # np.asarray of a result still being computed waited for it at a full core (measured: 0.2 ms of CPU
    # per single resection); block_until_ready waits without spinning.
    b = inp.use_init.shape[0]
    if chunk is None:
        return unpack(np.array(np.asarray(jax.block_until_ready(fn(inp, opt))).T), m)  # a copy (_merge_one writes)
    nb = -(-b // chunk) * chunk
    # Whole chunks as slices (views); the last one padded with copies of the first image.
    parts = [fn(inp.take(slice(i, i + chunk)), opt) for i in range(0, b - chunk + 1, chunk)]  # asynchronous
    if nb - b:
        rest = b - b % chunk
        parts.append(fn(inp.take(np.concatenate([np.arange(rest, b), np.zeros(nb - b, int)])), opt))
    return unpack(np.concatenate([np.asarray(x).T for x in jax.block_until_ready(parts)])[:b], m)


def _merge_one(a: np.ndarray, idx, x) -> np.ndarray:
    a[idx] = x  # in place: the arrays of an unpacked output are this call's own
    return a


def _merge(out: Output, idx, again: Output) -> Output:
    return jax.tree_util.tree_map(lambda a, x: _merge_one(a, idx, x), out, again)


def _solve(prep: Prepared, opt: Options, m: int, batch: bool, robust: bool, camera: FrameCamera):
    """The cheap path for every image, the robust path for those it hands over.

    Returns the output and its plausibility screen (:func:`_screen`), or
    None for the screen with ``robust=False`` (:func:`_finish` computes it).
    """
    inp = _inputs(prep, m)
    if robust and not batch:
        # A command resects one image; when its robust program is not made yet (first run, empty
        # cache), compile it beside the cheap one: most first runs on real data need both.
        _solve_robust.prefetch(inp, opt)
    b = len(prep.xy)
    out = _call(_solve_cheap, inp, opt, (_CHUNK if 2 * b > _CHUNK else _SMALL_CHUNK) if batch else None, m)
    if not robust:
        return out, None
    screened = _screen(prep, out, camera)
    # A converged but implausible cheap result (e.g. a local minimum far from a poor linear start) also
    # goes to the full robust path: its LMedS start is what the real data of test_resection_real needs.
    robust_fn = _solve_robust_batch if batch and b >= _ROBUST_OPT_MIN else _solve_robust
    full = (out.retry == 2) | screened[0]
    quick = np.flatnonzero((out.retry == 1) & ~full)
    chunk = _ROBUST_CHUNK if batch else None
    if quick.size:
        # Only the blunder test failed: snoop from the cheap solution, without the LMedS start (its
        # least-squares solution is the start data snooping is defined from; Baarda 1968).
        sub = dataclasses.replace(inp.take(quick), init=out.params[quick].T, use_init=np.ones(quick.size, bool))
        again = _call(robust_fn, sub, opt, chunk, m)
        out = _merge(out, quick, again)
        # What this does not settle (failed, implausible, points behind the camera) gets the full path.
        failed = _screen(_take_prep(prep, quick), again, camera)[0] | (again.result != RESULTS.successful)
        failed |= np.any(again.used[:, : prep.xy.shape[1]] & ~(again.depth[:, : prep.xy.shape[1]] > 0), axis=1)
        full[quick[failed]] = True
    idx = np.flatnonzero(full)
    if idx.size:
        out = _merge(out, idx, _call(robust_fn, inp.take(idx), opt, chunk, m))
    changed = np.union1d(quick, idx)
    if changed.size:  # screen again only the images the robust path changed
        again = _screen(_take_prep(prep, changed), _take(out, changed), camera)
        screened = tuple(_merge_one(a, changed, x) for a, x in zip(screened, again))
    return out, screened


def _take_prep(prep: Prepared, idx) -> Prepared:
    """The images ``idx`` of a prepared batch."""
    per_image = ("xy", "ground", "weight", "is_check", "origin", "basis", "planar", "init")
    return dataclasses.replace(prep, **{k: getattr(prep, k)[idx] for k in per_image})


@functools.lru_cache(maxsize=4096)
def _message(result: int, steps: int, solver: str) -> tuple[bool, str]:
    """The adjustment's own message: converged, or why not."""
    name = {"gn": "Gauss-Newton", "lm": "Levenberg-Marquardt"}[solver]
    if result == RESULTS.successful:
        return True, f"{name} converged in {steps} steps"
    return False, f"{name} did not converge after {steps} steps: {RESULTS(result).text}"


def _screen(prep: Prepared, out: Output, camera):
    """Converged images that fail the vectorised plausibility screen ``(b,)``; also the finite
    parameters, rms, squared residuals and the adjustment's result code it computed on the way."""
    n = prep.xy.shape[1]
    ctrl = ~prep.is_check
    used = out.used[:, :n]
    finite = np.all(np.isfinite(out.params), axis=1)
    p = np.where(finite[:, None], out.params, np.nan_to_num(out.start))  # finite values; the status says it failed
    adjustment = np.where(finite, out.result, RESULTS.nonfinite)
    res = out.residuals[:, :n]
    d2 = res[..., 0] ** 2 + res[..., 1] ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.sum(d2 * used, axis=1) / used.sum(1))
    half, f = _camera_info(camera)[:2]
    bad = implausible(prep.xy, ctrl, ctrl & ~used, p[:, :3], out.axis, prep.basis[:, :, 2], prep.planar, rms, half, f)
    return (adjustment == RESULTS.successful) & bad, p, rms, d2, adjustment


def _finish(prep: Prepared, out: Output, camera, convention, batch: bool, solver="gn", gn_failure=None, screened=None):
    """Numbers and words of the result for every image (vectorised; words
    formatted only where something failed).  Shared by resect and resect_batch.
    ``screened``: :func:`_screen` of ``out`` if already computed."""
    b, n = prep.xy.shape[:2]
    ctrl = ~prep.is_check
    used = out.used[:, :n]
    outliers = ctrl & ~used
    screen, p, rms, d2, adjustment = _screen(prep, out, camera) if screened is None else screened
    code = adjustment.copy()
    resid = out.residuals[:, :n]
    n_used = used.sum(1)
    behind = used & ~(out.depth[:, :n] > 0)
    code[(code == RESULTS.successful) & np.any(behind, axis=1)] = RESULTS.behind_camera
    half, f = _camera_info(camera)[:2]
    normal = prep.basis[:, :, 2]
    reasons = {}
    for i in np.flatnonzero((code == RESULTS.successful) & screen):
        why = _plausibility(
            prep.xy[i], ctrl[i], outliers[i], p[i, :3], out.axis[i], normal[i], prep.planar[i], rms[i], half, f
        )
        if why is not None:
            reasons[i] = why
            code[i] = RESULTS.implausible
    red = 2.0 * n_used - 6.0
    sigma_known = prep.sigma_known
    cov = out.sigma0[:, None, None] ** 2 * out.qxx
    if not np.all(red > 0):  # (the where only when needed: it cost a fifth of this function on 10,000 images)
        cov = np.where((red > 0)[:, None, None], cov, out.qxx if sigma_known else np.nan)
    std = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / (std[:, :, None] * std[:, None, :])
        check_rms = np.sqrt(np.sum(d2 * prep.is_check, axis=1) / prep.is_check.sum(1))
        # sigma0 = 0 exactly (exact data from an exact start): tau is 0/0, undefined (NaN)
        stat = out.w[:, :n] / (1.0 if sigma_known else out.sigma0[:, None, None])
    if not used.all():
        stat = np.where(used[:, :, None], stat, out.stat_at[:, :n])
    # one message per distinct (result, steps), spread over the images by one index
    uniq, inv = np.unique(adjustment.astype(np.int64) * 1_000_000 + out.steps, return_inverse=True)
    texts = np.array([_message(int(u // 1_000_000), int(u % 1_000_000), solver)[1] for u in uniq], object)
    messages = texts[inv.reshape(-1)].tolist()
    for i in np.flatnonzero((code != RESULTS.successful) | (red <= 0)):
        m = messages[i] if gn_failure is None else f"{gn_failure}; then {messages[i]}"
        if code[i] == RESULTS.behind_camera:
            m = (
                "the solution puts control points behind the camera: "
                + ", ".join(_point_label(prep.names, k) for k in np.flatnonzero(behind[i]))
                + "; "
                + CAUSES
            )
        elif code[i] == RESULTS.implausible:
            m = f"{reasons[i]}; {CAUSES} (the adjustment itself: {m})"
        elif code[i] != RESULTS.successful:
            m += "; " + CAUSES
        if red[i] <= 0:
            m += "; zero redundancy: sigma0 and blunder tests undefined" + (
                ", covariance from the a-priori sigma" if sigma_known else ", covariance unknown"
            )
        messages[i] = m
    names = prep.names if prep.names is not None else [f"P{k}" for k in range(n)]
    fields = dict(
        sigma0=out.sigma0,
        covariance=cov,
        std=std,
        correlation=corr,
        residuals=resid,
        outliers=outliers,
        check=prep.is_check,
        redundancy=out.redundancy[:, :n],
        normalised=stat,
        critical=out.critical,
        rmse=rms,
        check_rmse=check_rms,
        iterations=out.steps,
        converged=code == RESULTS.successful,
        message=messages,
        result=code,
    )
    common = dict(
        names=list(names), statistic="w" if sigma_known else "tau", pixel_size=_camera_info(camera).pixel_size
    )
    if batch:
        ext = ExteriorOrientation(p[:, :3] + prep.origin, p[:, 3:], convention)
        return ResectionResult(exterior=ext, **fields, **common)
    one = {k: v[0] for k, v in fields.items()}
    for k in ("sigma0", "critical", "rmse", "check_rmse"):
        one[k] = float(one[k])
    one.update(iterations=int(one["iterations"]), converged=bool(one["converged"]), result=RESULTS(int(one["result"])))
    # numpy in: ExteriorOrientation's own conversion is the one transfer (through jax.device_put first,
    # its conversion of the device arrays still cost an operation each: 180 instead of 127 us)
    ext = ExteriorOrientation(p[0, :3] + prep.origin[0], p[0, 3:], convention)
    return ResectionResult(exterior=ext, **one, **common)


def resect(
    image_xy,
    ground_xyz,
    camera: FrameCamera,
    *,
    sigma=None,
    check=None,
    names=None,
    initial: ExteriorOrientation | None = None,
    convention: Convention = "phi-omega-kappa",
    robust: bool = True,
    alpha: float = 0.001,
    max_steps: int = 50,
    throw: bool = True,
    corrections=None,
) -> ResectionResult:
    """Space resection of one image from ground control points.

    Args:
        image_xy: ``(n, 2)`` image-plane coordinates (x right, y up, the
            camera's unit; convert pixels with ``camera.pixel_to_image``).
        ground_xyz: ``(n, 3)`` ground coordinates (X east, Y north, Z up).
        camera: interior orientation (distortion is taken into account).
        sigma: a-priori standard deviations of the image coordinates:
            scalar, ``(n,)`` or ``(n, 2)``; weights are ``1/sigma^2``.  With
            it, blunders are tested with Baarda's w (a-priori sigma0 = 1);
            without it, with Pope's tau (a-posteriori sigma0).
        check: ``(n,)`` bool, True for check points: not used in the fit,
            their residuals reported separately.
        names: ``(n,)`` point names for messages and reports.
        initial: a start orientation; optional (needed only for 3 points).
        convention: angle convention of the result.
        robust: test for blunders; where the test fails (or the cheap path
            does), a least-median-of-squares start over random subsets and
            data snooping (exclude the worst point while the test fails).
        alpha: significance level of each test (0.001 -> 3.29 for w).
        max_steps: maximum Gauss-Newton / LM steps per adjustment.
        throw: raise :class:`photax.ConvergenceError` on failure; otherwise
            return the result with ``converged=False``, the reason in
            ``message`` and its :class:`photax.RESULTS` code in ``result``.
            Failure includes an implausible solution (package docstring,
            step 5).
        corrections: a :class:`photax.ImageCorrections` (earth curvature,
            atmospheric refraction) for ground in a map projection; None (the
            default) or nothing active: none.  The image coordinates are
            corrected with the orientation of a plain least-squares resection
            (:func:`photax.correct_image`, which needs it), resected again
            until the corrections change by less than 1e-9 of the focal
            length (at most 5 rounds), then resected as asked; the result
            names them.

    Returns:
        :class:`ResectionResult` (finite values also when it failed).

    Raises:
        ValueError: bad shapes, NaN/inf (naming the points), too few or
            degenerate (collinear, duplicated) control points.
        ConvergenceError: with ``throw=True`` on failure; whatever
            ``throw``, if the compiled solver itself raises (the original
            exception is its ``__cause__``).

    Examples:
        An aerial frame over hills with known truth (:func:`photax.relief_scene`), its control points
        measured with 0.3 px noise; the camera is in pixels, so ``sigma`` is in pixels too:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> xy = scene.camera.pixel_to_image(scene.gcp_pixel)
        >>> res = ptx.resect(xy, scene.gcp_ground, scene.camera, sigma=scene.noise_px)
        >>> res.converged, res.result.name
        (True, 'successful')
        >>> err = np.asarray(res.exterior.position) - np.asarray(scene.exterior.position)
        >>> bool(np.all(np.abs(err) < 3 * res.std[:3]))  # the truth within 3 sigma
        True
        >>> print(f"sigma0 {res.sigma0:.1f}")  # the noise as given: about 1
        sigma0 1.0
    """
    settings = dict(
        camera=camera,
        sigma=sigma,
        check=check,
        names=names,
        initial=initial,
        convention=convention,
        robust=robust,
        alpha=alpha,
        max_steps=max_steps,
    )
    if corrections is not None and corrections.active:
        return _resect_corrected(image_xy, ground_xyz, corrections, throw, settings)
    res = _resect_one(image_xy, ground_xyz, fallback=True, **settings)
    if res.converged:
        res = _mirror_test(res, np.asarray(image_xy, float), np.asarray(ground_xyz, float), settings)
    units = res.result == RESULTS.implausible and _units_wrong(image_xy, ground_xyz, settings)
    if not res.converged and initial is None and not units:  # wrong units: no swap helps
        hint = _swap_hint(np.asarray(image_xy, float), np.asarray(ground_xyz, float), settings)
        if hint:
            res = dataclasses.replace(res, message=f"{hint}; {res.message}")
    if throw and not res.converged:
        raise ConvergenceError(res.message)
    return res


def _resect_one(
    image_xy, ground_xyz, *, camera, sigma, check, names, initial, convention, robust, alpha, max_steps, fallback
) -> ResectionResult:
    """Validate, solve (then Levenberg-Marquardt if Gauss-Newton failed and ``fallback``), finish."""
    prep = validate(image_xy, ground_xyz, camera, sigma, check, names, initial, convention, alpha, batch=False)
    m = _bucket(prep.xy.shape[1])
    opt = _options(prep, camera, convention, robust, alpha, max_steps, m)
    with _solver_errors():
        out, screened = _solve(prep, opt, m, batch=False, robust=robust, camera=camera)
        if out.result[0] == RESULTS.successful or not fallback:
            return _finish(prep, out, camera, convention, batch=False, screened=screened)
        # Gauss-Newton failed: Levenberg-Marquardt from the same start, same points
        gn = _message(int(out.result[0]), int(out.steps[0]), "gn")[1]
        lanes = jax.tree_util.tree_map(lambda a: np.moveaxis(a, 0, -1), out)  # the one image as one lane
        lm = _adjust.levenberg_marquardt(_inputs(prep, m), lanes, opt, int(max_steps))
        out = jax.tree_util.tree_map(lambda a: np.moveaxis(np.asarray(a), -1, 0), jax.device_get(lm))
    return _finish(prep, out, camera, convention, batch=False, solver="lm", gn_failure=gn)


def _mirror_test(res: ResectionResult, xy, ground, settings) -> ResectionResult:
    """A converged resection refused when the image reversed in x fits far better (rmse below half,
    no more points excluded): the correspondence of image and ground has the wrong handedness.

    A mirrored image of GCPs with relief is fitted only approximately by a proper camera (a rotation,
    not a reflection), so the mirrored fit reveals it, wherever the camera is: a façade, an oblique or
    upward-looking view.  Level planar GCPs are left to the plausibility check (their mirror fits
    exactly, from below the ground); a planar GCP set of another slope is seen exactly as well from
    either side: nothing in the data tells its mirror apart.  Gauss-Newton only (the compiled program
    of the first resection), from the linear start.
    """
    ctrl = np.ones(len(ground), bool) if settings["check"] is None else ~np.asarray(settings["check"])
    g = ground[ctrl] - ground[ctrl].mean(axis=0)
    _, sv, vt = np.linalg.svd(g, full_matrices=False)
    if sv[2] < _PLANAR * sv[0] and abs(vt[2, 2]) > np.cos(np.radians(_MAX_TILT)):
        return res
    try:
        mirrored = _resect_one(xy * [-1.0, 1.0], ground, fallback=False, **{**settings, "initial": None})
    except (ValueError, ConvergenceError):
        return res
    if not (mirrored.converged and mirrored.rmse < 0.5 * res.rmse and mirrored.outliers.sum() <= res.outliers.sum()):
        return res
    unit = (lambda r: f"{r / res.pixel_size:.3g} px") if res.pixel_size else (lambda r: f"{r:.3g}")
    why = (
        f"{MIRROR}: the control points fit far better with the image x axis reversed (rmse "
        f"{unit(mirrored.rmse)} against {unit(res.rmse)}): the image or the ground is mirrored"
    )
    return dataclasses.replace(
        res,
        converged=False,
        result=RESULTS.implausible,
        message=f"{why}; {CAUSES} (the adjustment itself: {res.message})",
    )


def _units_wrong(image_xy, ground_xyz, settings) -> bool:
    """Whether the image coordinates are in a wrong unit (:func:`._checks.units_wrong`):
    decided on the points, not on the failure's message."""
    s = settings
    prep = validate(image_xy, ground_xyz, s["camera"], s["sigma"], s["check"], s["names"], s["initial"],
                    s["convention"], s["alpha"], batch=False)  # fmt: skip
    half, f = _camera_info(s["camera"])[:2]
    return units_wrong(prep.xy[0], ~prep.is_check[0], half, f)


def _swap_hint(xy, ground, settings) -> str | None:
    """Name the swap that makes a failed resection fit, if one does.

    The usual mistakes in a GCP file are tried (Gauss-Newton only: no new
    compilation, milliseconds each): image column/row swapped (x/y
    without a pixel grid), the row counted upwards (y mirrored), ground E
    and N swapped.  A hypothesis counts when its resection passes every
    check of :func:`._checks._plausibility` (in particular, at most a third
    of the points excluded).
    """
    camera = settings["camera"]
    if camera.pixel_size is not None and camera.image_size is not None:
        colrow = np.asarray(camera.image_to_pixel(xy))
        swapped_xy = np.asarray(camera.pixel_to_image(colrow[:, ::-1]))
        swap_name = "the image column and row are swapped"
    else:
        swapped_xy, swap_name = xy[:, ::-1], "the image x and y are swapped"
    ground_en = ground[:, [1, 0, 2]]
    hypotheses = [
        (swap_name, swapped_xy, ground),
        ("the image y (row) axis is reversed", xy * [1.0, -1.0], ground),
        ("the ground E and N (X and Y) are swapped", xy, ground_en),
    ]
    fits = []
    for text, xy_h, ground_h in hypotheses:
        try:
            res = _resect_one(xy_h, ground_h, fallback=False, **settings)
        except (ValueError, ConvergenceError):
            continue
        if res.converged:
            rms = f"{res.rmse / res.pixel_size:.3g} px" if res.pixel_size else f"{res.rmse:.3g}"
            k = int(res.outliers.sum())
            fits.append(f"{text} (then rmse {rms}, {k} point{'' if k == 1 else 's'} excluded)")
    if not fits:
        return None
    # For (nearly) planar GCPs any mirroring of the image undoes any mirroring of the ground: name all that fit.
    return "probably swapped or mirrored axes: the control points fit if " + " - or if ".join(fits)


@contextlib.contextmanager
def _solver_errors():
    """Errors raised inside the compiled solver (JAX/XLA, equinox checks,
    optimistix, lineax) -> :class:`ConvergenceError` in photax's words, the
    original kept as ``__cause__``.  The solver runs with ``throw=False``,
    so this is a safety net: failures are normally a status, not an error.
    """
    try:
        yield
    except (ValueError, TypeError, KeyboardInterrupt):
        raise  # input errors and Ctrl-C keep their type
    except Exception as exc:
        raise ConvergenceError(
            f"the resection failed inside its solver ({type(exc).__name__}); "
            f"the orientation could not be computed from these points; {CAUSES}"
        ) from exc


def resect_batch(
    image_xy,
    ground_xyz,
    camera: FrameCamera,
    *,
    sigma=None,
    initial: ExteriorOrientation | None = None,
    convention: Convention = "phi-omega-kappa",
    robust: bool = True,
    alpha: float = 0.001,
    max_steps: int = 20,
    throw: bool = False,
) -> ResectionResult:
    """Space resection of many images with the same number of GCPs, in one call.

    The same compiled solvers as :func:`resect`, over chunks of images
    (one compilation for any batch size): every image takes the
    cheap path (linear start from all points, Gauss-Newton with at most
    ``max_steps`` iterations, precision, the blunder test); with
    ``robust=True`` the images whose test or adjustment fails are gathered
    into a second, compacted batch for the robust path (least-median-of-
    squares start over random subsets, data snooping).  Each image has its
    own ``converged``, ``result`` and ``message``.  Unlike :func:`resect`
    there is no Levenberg-Marquardt fallback (a failed image is reported,
    not retried), the swap hints are not tried and the mirrored fit is not
    compared (:func:`resect`'s mirror test for GCPs with relief); the
    plausibility checks apply per image.

    Args:
        image_xy: ``(b, n, 2)`` image-plane coordinates.
        ground_xyz: ``(b, n, 3)`` ground coordinates.
        camera: one interior orientation for all images.
        sigma: scalar, ``(b, n)`` or ``(b, n, 2)`` a-priori sigmas.
        initial: optional start with batch shape ``(b,)``.
        convention, robust, alpha: as in :func:`resect`.
        max_steps: Gauss-Newton iterations at most.
        throw: raise :class:`photax.ConvergenceError` if any image failed
            (default False: a batch does not die because one image failed).

    Returns:
        A :class:`ResectionResult` whose arrays have a leading axis ``b``
        (``result[i]`` is the ``i``-th image's result).

    Examples:
        Two images' control points in one call: exact and with 0.3 px noise.

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> xy = np.stack([scene.camera.pixel_to_image(p) for p in (scene.gcp_pixel_true, scene.gcp_pixel)])
        >>> res = ptx.resect_batch(xy, np.stack([scene.gcp_ground] * 2), scene.camera)
        >>> res.converged.tolist(), len(res)
        ([True, True], 2)
        >>> err = np.abs(np.asarray(res.exterior.position) - np.asarray(scene.exterior.position))
        >>> bool(err[0].max() < 1e-6), bool(np.all(err[1] < 3 * res.std[1, :3]))  # exact; within 3 sigma
        (True, True)
    """
    prep = validate(image_xy, ground_xyz, camera, sigma, None, None, initial, convention, alpha, batch=True)
    m = _bucket(prep.xy.shape[1], batch=True)
    opt = _options(prep, camera, convention, robust, alpha, max_steps, m)
    with _solver_errors():
        out, screened = _solve(prep, opt, m, batch=True, robust=robust, camera=camera)
    res = _finish(prep, out, camera, convention, batch=True, screened=screened)
    if throw and not np.all(res.converged):
        bad = np.flatnonzero(~res.converged)
        raise ConvergenceError(
            f"{len(bad)} of {len(res.converged)} images failed, e.g. image {bad[0]}: {res.message[bad[0]]}"
        )
    return res


def _resect_corrected(image_xy, ground_xyz, corrections, throw, settings) -> ResectionResult:
    """:func:`resect` with image-space corrections: resect, correct with that orientation, resect again."""
    from ..earth import correct_image

    observed = np.asarray(image_xy, float)
    ground = np.asarray(ground_xyz, float)
    if ground.ndim != 2 or ground.shape[1] != 3:
        raise ValueError(f"ground_xyz: expected shape (n, 3), got {ground.shape}")
    camera = settings["camera"]
    # The orientation for the corrections: plain least squares (the uncorrected residuals, pixels of
    # curvature and refraction, would fail a blunder test), corrected and solved again until the
    # corrections settle; then the resection as asked, on the corrected coordinates.
    quick = dict(settings, robust=False)
    xy = observed
    for _ in range(5):
        res = resect(xy, ground, throw=False, **quick)
        if not res.converged:
            break
        new = correct_image(observed, res.exterior, camera, ground[:, 2], corrections)
        if not np.all(np.isfinite(new)):
            raise ValueError("corrections: a ray of the image misses the earth (NaN correction)")
        settled = float(np.max(np.abs(new - xy))) < 1e-9 * float(camera.focal_length)
        xy = new
        if settled:
            break
    res = resect(xy, ground, throw=throw, **settings)
    return dataclasses.replace(res, corrections=corrections, image_corrections=xy - observed)
