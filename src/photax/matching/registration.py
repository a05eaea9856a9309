"""Registration of an image to a reference orthophoto: refine its exterior orientation.

The reference orthophoto and the DEM give ground points ``P_i = (X_i, Y_i,
Z(X_i, Y_i))`` with grey values ``g_i``; the image, resampled where the
collinearity equations put them, must show the same grey values up to a
linear radiometric change::

    v_i(p) = r0 + r1 I(pixel(P_i; EO + dEO)) - g_i,     p = (dEO (6), r0, r1)

minimised by Gauss-Newton (Levenberg-Marquardt damping) with the Jacobian
by forward-mode differentiation (``jax.jacfwd``) through the collinearity
equations and the resampling kernel -- reverse mode through
:func:`photax.resample` was seen to give NaN.  Coarse to fine: at level ``L``
both images are blurred by Gaussians of ``L / 2`` px (image) and the
equivalent on the ortho, and every ``L``-th ortho pixel is used, so the
first levels converge from several pixels off and the last one is precise.
Maximising the normalised cross-correlation is the same as this least
squares with the radiometric parameters free.

Ground points that project outside the image or behind it get zero weight.
No occlusion test.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._deprecation import alias, renamed_argument
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation, project
from ..dem import DEM
from ..errors import RESULTS, ConvergenceError
from ..resampling import resample


@dataclasses.dataclass(frozen=True)
class Registration:
    """The outcome of :func:`register_to_ortho`.

    Attributes:
        exterior: the refined exterior orientation.
        converged: ``result == RESULTS.successful``: the finest level's
            steps fell below the tolerance and the final correlation reached
            ``min_correlation``.
        steps: Gauss-Newton steps per level.
        rmse: grey-value rms of the residuals per level (after its last
            step); ``rms`` is its deprecated old name.
        correlation: correlation coefficient of image and ortho at the end.
        message: what happened, in the words of :data:`photax.RESULTS`.
        history: one dict per Gauss-Newton step: ``level``, ``rmse`` (grey
            rms of the residuals before the step) and ``shift_px`` (the most
            any ground point's image moved by the step, px): the convergence.
        result: the :class:`photax.RESULTS` code: ``successful``,
            ``max_steps_reached`` (the finest level did not settle),
            ``nonfinite`` (a step became NaN), ``implausible`` (the image
            sees almost nothing of the ortho, or the final correlation is
            below ``min_correlation``: a wrong match).

    Examples:
        :func:`register_to_ortho`'s example, step by step: one entry of ``steps`` and ``rmse`` per
        level (coarsest first), and within each level the grey residuals shrink:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> start = ptx.ExteriorOrientation(np.asarray(scene.exterior.position) + [20.0, -15.0, 0.0],
        ...                                 scene.exterior.angles)
        >>> reg = ptx.register_to_ortho(scene.image, scene.camera, start, scene.ortho, scene.ortho_transform,
        ...                             scene.dem, levels=(4, 2, 1))
        >>> len(reg.steps), len(reg.rmse), len(reg.history) == sum(reg.steps)
        (3, 3, True)
        >>> first = {h["level"]: h["rmse"] for h in reversed(reg.history)}  # before each level's first step
        >>> [bool(first[level] > end) for level, end in zip((4, 2, 1), reg.rmse)], bool(reg.correlation > 0.9)
        ([True, True, True], True)

    """

    exterior: ExteriorOrientation
    converged: bool
    steps: list
    rmse: list
    correlation: float
    message: str
    history: list = dataclasses.field(default_factory=list)
    result: RESULTS = RESULTS.successful

    rms = alias("rmse")


@partial(jax.jit, static_argnames=("method",))
def _residuals(p, base, image, ground, grey, camera, *, method):
    ext = ExteriorOrientation(base[:3] + p[:3], base[3:6] + p[3:6])
    px = camera.image_to_pixel(project(ground, ext, camera))
    s = resample(image, px[:, 0], px[:, 1], method)
    ok = jnp.isfinite(s)
    return jnp.where(ok, p[6] + p[7] * jnp.where(ok, s, 0.0) - grey, 0.0), ok


@jax.jit
def _shift(p0, p1, base, ground, camera):
    """``(m,)`` px each ground point's image moves between the parameters ``p0`` and ``p1``."""

    def pix(p):
        ext = ExteriorOrientation(base[:3] + p[:3], base[3:6] + p[3:6])
        return camera.image_to_pixel(project(ground, ext, camera))

    return jnp.linalg.norm(pix(p1) - pix(p0), axis=-1)


@partial(jax.jit, static_argnames=("method",))
def _linearise(p, base, image, ground, grey, camera, *, method):
    f = lambda q: _residuals(q, base, image, ground, grey, camera, method=method)[0]  # noqa: E731
    v, ok = _residuals(p, base, image, ground, grey, camera, method=method)
    return v, ok, jax.jacfwd(f)(p)


def register_to_ortho(
    image,
    camera: FrameCamera,
    exterior: ExteriorOrientation,
    reference_ortho,
    ortho_transform,
    dem: DEM,
    *,
    levels=(8, 4, 2, 1),
    max_steps: int = 15,
    tol: float = 1e-3,
    resampling: str = "bilinear",
    min_correlation: float = 0.8,
    throw: bool = True,
    method: str | None = None,
) -> Registration:
    """Refine ``exterior`` so that ``image`` matches ``reference_ortho`` (module docstring).

    Args:
        image: ``(H, W)`` grey image of ``camera``.
        camera: interior orientation with a pixel grid.
        exterior: approximate orientation (phi-omega-kappa or omega-phi-kappa).
        reference_ortho: ``(rows, cols)`` reference orthophoto.
        ortho_transform: its affine ``(a, b, xoff, d, e, yoff)`` (GDAL order,
            corner of the top-left pixel).
        dem: heights for the ortho's ground points.
        levels: coarse-to-fine levels, px (blur and sampling step).
        max_steps: Gauss-Newton steps per level at most.
        tol: stop a level when a step moves no ground point's image by more than ``tol`` px.
        resampling: resampling kernel (:func:`photax.resample`); ``method``
            is its deprecated old name.
        min_correlation: below this final correlation of image and ortho the
            result is reported as not converged (a wrong local minimum).
        throw: raise :class:`photax.ConvergenceError` when the registration
            fails (one estimate: ``True`` by default, docs/architecture.md);
            ``False`` returns it with ``converged=False`` and its ``result``.

    Returns:
        :class:`Registration`.

    Raises:
        photax.ConvergenceError: with ``throw=True``, when it did not converge.

    Examples:
        A start 25 m off, refined against the scene's true orthophoto and DEM:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> start = ptx.ExteriorOrientation(np.asarray(scene.exterior.position) + [20.0, -15.0, 0.0],
        ...                                 scene.exterior.angles)
        >>> reg = ptx.register_to_ortho(scene.image, scene.camera, start, scene.ortho, scene.ortho_transform,
        ...                             scene.dem, levels=(4, 2, 1))
        >>> reg.converged, reg.result.name
        (True, 'successful')
        >>> err = np.asarray(reg.exterior.position) - np.asarray(scene.exterior.position)
        >>> bool(np.all(np.abs(err) < 1.0))  # metres; the pixel is 7.5 m on the ground
        True
    """
    # Over 80 lines: argument checks, then one coarse-to-fine Gauss-Newton loop whose
    # state (parameters, damping, history) is shared by every level; kept in one piece.
    from scipy.ndimage import gaussian_filter

    method = renamed_argument("register_to_ortho", "method", method, "resampling", resampling, "bilinear")
    img = np.asarray(image, dtype=float)
    ref = np.asarray(reference_ortho, dtype=float)
    if not levels or min(levels) < 1:
        raise ValueError(f"levels must be positive integers, got {levels}")
    if img.ndim != 2 or ref.ndim != 2:
        raise ValueError(f"image and reference_ortho must be (h, w) images, got {img.shape} and {ref.shape}")
    if camera.image_size is None or img.shape != (camera.image_size[1], camera.image_size[0]):
        raise ValueError(f"image has shape {img.shape}, the camera's images are {camera.image_size} (w, h)")
    a, b, xoff, d, e, yoff = (float(t) for t in ortho_transform)
    ext0 = exterior.to_convention("phi-omega-kappa")
    base = jnp.asarray(np.concatenate([np.asarray(ext0.position), np.asarray(ext0.angles)]))
    p = np.zeros(8)
    p[7] = 1.0
    steps, rmss, history = [], [], []
    converged, finite = False, True
    overlap = True
    finest = min(levels)
    # one point count for every level (the finest's, to a power of two): one compilation
    m = max(256, 1 << (int(np.ceil(ref.shape[0] / finest) * np.ceil(ref.shape[1] / finest)) - 1).bit_length())
    for level in levels:
        img_l = gaussian_filter(img, 0.5 * level, mode="nearest") if level > 1 else img
        ref_l = (
            gaussian_filter(ref, 0.5 * level * _px_ratio(camera, ext0, a, dem), mode="nearest") if level > 1 else ref
        )
        rr, cc = np.mgrid[0 : ref.shape[0] : level, 0 : ref.shape[1] : level]
        x = xoff + a * (cc + 0.5) + b * (rr + 0.5)
        y = yoff + d * (cc + 0.5) + e * (rr + 0.5)
        z = np.asarray(dem.height(jnp.asarray(x.ravel()), jnp.asarray(y.ravel())))
        keep = np.isfinite(z) & np.isfinite(ref_l[rr, cc].ravel())
        n = int(keep.sum())
        ground = np.zeros((m, 3))
        ground[:n] = np.column_stack([x.ravel(), y.ravel(), z])[keep]
        ground[n:] = ground[0]
        grey = np.zeros(m)
        grey[:n] = ref_l[rr, cc].ravel()[keep]
        live = np.arange(m) < n
        args = (base, jnp.asarray(img_l), jnp.asarray(ground), jnp.asarray(grey), camera)
        done = False
        k = 0
        for k in range(1, max_steps + 1):  # noqa: B007 -- k, the steps taken, is kept after the loop
            v, ok, jac = (np.asarray(t) for t in _linearise(jnp.asarray(p), *args, method=method))
            w = (ok & live).astype(float)
            if w.sum() < 50:  # too few ground points inside the image to fit 8 parameters reliably
                overlap = False
                break
            jw = jac * w[:, None]
            nmat = jw.T @ jac
            g = jw.T @ v
            scale = np.sqrt(np.maximum(np.diag(nmat), 1e-30))
            ns = nmat / np.outer(scale, scale) + 1e-6 * np.eye(8)
            dp = -np.linalg.solve(ns, g / scale) / scale
            finite = bool(np.all(np.isfinite(dp)))
            if not finite:
                break
            p = p + dp
            move = np.asarray(_shift(jnp.asarray(p - dp), jnp.asarray(p), base, jnp.asarray(ground), camera))
            history.append(
                {
                    "level": level,
                    "rmse": float(np.sqrt(np.sum(w * v * v) / w.sum())),
                    "shift_px": float(np.max(move[w > 0])),
                }
            )
            if np.max(move[w > 0]) < tol:  # the step moved no ground point's image by tol px
                done = True
                break
        v, ok = (np.asarray(t) for t in _residuals(jnp.asarray(p), *args, method=method))
        sel = ok & live
        steps.append(k)
        if not overlap or not finite:
            rmss.append(float("nan"))
            break
        rmss.append(float(np.sqrt(np.mean(v[sel] ** 2))) if sel.any() else float("nan"))
        converged = done
    pred = np.asarray(_residuals(jnp.asarray(p), *args, method=method)[0])[sel] + grey[sel]
    corr = float(np.corrcoef(pred, grey[sel])[0, 1]) if sel.sum() > 2 and np.std(pred) > 0 else float("nan")
    out = ExteriorOrientation(np.asarray(base[:3]) + p[:3], np.asarray(base[3:]) + p[3:6], "phi-omega-kappa")
    out = out.to_convention(exterior.convention)
    if not overlap:
        code, detail = (
            RESULTS.implausible,
            (
                f"only {int(sel.sum())} of the ortho's ground points fall inside the image at level {level}: "
                "the orientation sees (almost) nothing of the reference orthophoto"
            ),
        )
    elif not finite:
        code, detail = RESULTS.nonfinite, f"a Gauss-Newton step at level {level}"
    elif converged and not corr >= min_correlation:
        code, detail = (
            RESULTS.implausible,
            (
                f"converged to a correlation of only {corr:.3f} (< {min_correlation}): a wrong match, "
                "the start is too far off or the ortho does not show this image's ground"
            ),
        )
    elif converged:
        code, detail = RESULTS.successful, f"correlation {corr:.4f}, grey rmse {rmss[-1]:.4g}"
    else:
        code, detail = RESULTS.max_steps_reached, (f"{max_steps} steps at the finest level (correlation {corr:.4f})")
    msg = f"{code.text}: {detail}"
    if throw and code != RESULTS.successful:
        raise ConvergenceError(f"registration failed: {msg}")
    return Registration(
        exterior=out,
        converged=code == RESULTS.successful,
        steps=steps,
        rmse=rmss,
        correlation=corr,
        message=msg,
        history=history,
        result=code,
    )


def _px_ratio(camera, ext, ortho_cell, dem) -> float:
    """Image pixels per ortho pixel (roughly): the ortho blur that matches an image blur."""
    ps = float(np.mean(np.asarray(camera.pixel_size)))
    height = float(ext.position[2]) - float(np.nanmean(np.asarray(dem.heights)))
    gsd = height * ps / float(camera.focal_length)
    return gsd / abs(ortho_cell)
