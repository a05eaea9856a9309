"""Space resection: the exterior orientation of one image (or many) from GCPs.

Model (``docs/conventions.md``): the collinearity equations
:func:`photax.collinearity.project`, parameters ``p = (Xs, Ys, Zs, a1, a2, a3)``
with the angles in the chosen convention's order.  Ground coordinates are
reduced to the centroid of the control points before anything is computed
(UTM eastings/northings are ~1e6 m) and the centroid is added back at the end.

1. **Start** (no user guess needed).  Image points are undistorted to
   normalised coordinates (``camera.normalised``); then two calibrated linear
   solvers, both written in ``jax.numpy`` so they ``vmap``:

   * a homography between the control points' best-fitting plane and the
     normalised image, decomposed with the known interior orientation
     (Zhang 2000, sec. 3.1) - for (near-)planar GCPs, the common case;
   * the calibrated DLT ``x ~ [M | m] X`` with ``M`` projected onto the
     rotations (Hartley & Zisserman 2003, sec. 7.1) - for 3-D GCP sets.

   Candidates come from all control points and, with ``robust=True``, from
   32 seeded random subsets of 6 (homography on their first 4).  The
   candidate with the smallest median squared reprojection error wins
   (least median of squares, Rousseeuw 1984: no threshold needed, tolerant
   of up to half the points being blunders); candidates that put points
   behind the camera lose (cheirality).
2. **Adjustment**: Gauss-Newton through ``optimistix.GaussNewton`` on the
   weighted residuals ``v = sqrt(P) (x_obs - x(p))``, Jacobian by JAX
   autodiff, 6x6 normal equations by Cholesky; at most ``max_steps``
   iterations.  The single and batched paths run this same solver (under
   ``vmap`` for the batch).  If Gauss-Newton fails, ``resect`` retries with
   ``optimistix.LevenbergMarquardt`` (compiled only then).

   Start, adjustment, precision and the snooping rounds below are one
   traced function (:func:`_solve`): every option (robust, sigma given or
   not, check points, initial values, convention) is a traced value, so
   ``resect`` compiles once per padded point count (16, 32, ...) and
   ``resect_batch`` once per point count for any number of images.
3. **Precision** at the solution, with ``A`` the Jacobian of the weighted
   model, ``r = 2 n - 6``::

       sigma0^2 = v^T P v / r,   C_pp = sigma0^2 (A^T P A)^-1,
       r_i = diag(I - A (A^T P A)^-1 A^T P)        (redundancy numbers)

4. **Blunders** (Baarda 1968 data snooping; Pope 1976 tau test): the
   standardised residual of each coordinate ``w_i = v_i / (sigma_i sqrt(r_i))``
   (a-priori ``sigma`` given) or ``tau_i = v_i / (sigma0_hat sigma_i
   sqrt(r_i))`` (not given).  While the largest exceeds the critical value
   (``3.29`` for ``alpha = 0.001``; the tau distribution with ``r`` degrees
   of freedom) and redundancy allows, the worst point (both coordinates) is
   excluded and the adjustment repeated from the robust start (inside the
   compiled function, a ``lax.while_loop``).

5. **Plausibility**: a converged adjustment is still a failure
   (``converged=False``, the reason in ``message``) when image and ground
   evidently do not belong together: more than a third of the control
   points excluded; residuals above 2 % of the frame diagonal; control
   points behind the camera; the mirror-image solution (camera below the
   GCPs' plane - for planes flatter than 60 degrees - looking up at it;
   Z is up); image coordinates outside 1.5 times the frame, or spanning
   less than 1 % of it (without a frame: farther than 4 f from the centre,
   or spanning less than 0.005 f) - a wrong unit.  When a single-image
   resection fails, the usual GCP-file mistakes are tried (image
   column/row swapped, row direction reversed, ground E/N swapped) and
   those that make it fit are named in the message.

References: Kraus, *Photogrammetry* vol. 1 (2007) sec. 4.3; Wolf & DeWitt,
*Elements of Photogrammetry* (2014) ch. 11 and app. B; Förstner & Wrobel,
*Photogrammetric Computer Vision* (2016) sec. 4.6.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import lineax as lx
import optimistix as optx
from scipy import stats

from .camera import FrameCamera
from .collinearity import ExteriorOrientation
from ._linalg import cho_solve, inv3, nearest_rotation
from .errors import ConvergenceError
from .rotation import Convention, angles_from_matrix_unchecked, check_convention, rotation_matrix

# Gauss-Newton stops after a step below this (relative; metres and radians).
# Convergence is quadratic for small residuals, so the error left after that
# step is far below it; one more iteration would only confirm it.
_STEP_TOL = 1e-8
_CHUNK = 256  # images per resect_batch call of the compiled solver
_N_SUBSETS = 32  # random subsets for the robust start: P(all 32 contain a blunder) < 1e-4 at 20 % blunders
_SEED = 20240601  # fixed: the same input gives the same answer
_PLANAR = 0.1  # smallest / largest spread of the GCPs below this: "planar" for the 4-point minimum
_OPENCV_FLIP = np.diag([1.0, -1.0, -1.0])  # photax camera frame <-> (x right, y down, z forward)
# optimistix's result codes, described in photax's words (its own texts give
# advice about lineax/optimistix arguments that a photax user cannot act on).
_SINGULAR = "the normal equations became singular (the control points do not determine the orientation from there)"
_OPTX_WORDS = {
    "max_steps_reached": "the iteration limit was reached",
    "nonlinear_max_steps_reached": "the iteration limit was reached",
    "singular": _SINGULAR,
    "breakdown": _SINGULAR,
    "stagnation": _SINGULAR,
    "conlim": _SINGULAR,
    "nonfinite_input": "the estimate became non-finite (NaN or inf)",
    "nonfinite": "the estimate became non-finite (NaN or inf)",
    "nonlinear_divergence": "the iterations diverged",
}
_OPTX_MESSAGES = {int(item._value): _OPTX_WORDS.get(name, "the solver failed")
                  for name, item in optx.RESULTS._name_to_item.items()}
# Why the image and ground coordinates of a resection may not fit together.
_CAUSES = ("likely causes: swapped or mirrored axes (image column/row or x/y, ground E/N), wrong units "
           "(image coordinates in another unit than the camera's), or control points measured on another image")
_MAX_EXCLUDED = 1.0 / 3.0  # more blunders than this share of the control points: the data do not fit
_MAX_RMS = 0.02  # rms above this share of the frame diagonal (or of f): not a measurement error
_FRAME_MARGIN = 1.5  # image points farther out than this times the half frame: not on this camera's image
_MAX_FIELD = 4.0  # no frame known: image points farther out than this times f (152 deg field of view): wrong unit
# Image points spanning less than this share of the frame (40 px of 4000), or of f without a frame: a wrong unit
# (metres for mm shrink the points 1000-fold: a GCP set spanning the whole frame would span 1e-3 of it).
_MIN_SPREAD, _MIN_SPREAD_F = 0.01, 5e-3
_MAX_TILT = 60.0  # degrees: below this slope of the GCPs' plane, "above" and "below" it are defined


# --------------------------------------------------------------------------- result


@dataclasses.dataclass(frozen=True)
class ResectionResult:
    """Outcome of :func:`resect` (or, with a leading batch axis, :func:`resect_batch`).

    Attributes:
        exterior: the estimated :class:`~photax.ExteriorOrientation`.
        sigma0: a-posteriori standard deviation of unit weight (image-plane
            units when no ``sigma`` was given, dimensionless otherwise); NaN
            at zero redundancy.
        covariance: ``(6, 6)`` in the order (X, Y, Z, angles in convention
            order); metres and radians.
        std: ``(6,)`` standard deviations, same order.
        correlation: ``(6, 6)``.
        residuals: ``(n, 2)`` observed - computed, image-plane units, for all
            input points (outliers and check points included).
        outliers: ``(n,)`` True for points excluded by data snooping.
        check: ``(n,)`` True for check points (not used in the fit).
        redundancy: ``(n, 2)`` redundancy numbers (0 for excluded points).
        normalized: ``(n, 2)`` test statistics (Baarda's w or Pope's tau);
            for outliers the values with which they were rejected; NaN for
            check points.
        critical: critical value the statistics were tested against.
        rms: RMS reprojection error of the control inliers,
            ``sqrt(mean(vx^2 + vy^2))``, image-plane units.
        check_rms: the same for the check points (NaN without any).
        iterations: Gauss-Newton (or LM) steps of the final adjustment.
        converged: whether the estimate can be trusted.
        message: why it stopped or failed.
        names: ``(n,)`` point names.
        statistic: name of the test (``"w"`` or ``"tau"``).
        pixel_size: the camera's mean pixel size in image-plane units
            (1.0 for a camera in pixels), or None without a pixel grid:
            :meth:`summary` reports residuals in pixels with it.
    """

    exterior: ExteriorOrientation
    sigma0: Any
    covariance: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    residuals: np.ndarray
    outliers: np.ndarray
    check: np.ndarray
    redundancy: np.ndarray
    normalized: np.ndarray
    critical: Any
    rms: Any
    check_rms: Any
    iterations: Any
    converged: Any
    message: Any
    names: Sequence[str]
    statistic: str = "w"
    pixel_size: float | None = None

    # -- batches -----------------------------------------------------------
    def __len__(self) -> int:
        if np.ndim(self.converged) == 0:
            raise TypeError("a single-image ResectionResult has no len(); resect_batch results do")
        return len(self.converged)

    def __getitem__(self, i: int) -> "ResectionResult":
        """The ``i``-th image of a :func:`resect_batch` result."""
        len(self)  # a TypeError for single results
        take = lambda a: np.asarray(a)[i]  # noqa: E731
        ext = ExteriorOrientation(self.exterior.position[i], self.exterior.angles[i], self.exterior.convention)
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for k, v in fields.items():
            if k in ("exterior", "names", "statistic", "pixel_size"):
                continue
            fields[k] = v[i] if isinstance(v, (list, tuple)) else take(v)
            if isinstance(fields[k], np.generic):
                fields[k] = fields[k].item()
        fields["exterior"] = ext
        return ResectionResult(**fields)

    # -- reports -----------------------------------------------------------
    def summary(self, *, ground_unit: str | None = None, crs: str | None = None,
                camera_unit: str | None = None) -> str:
        """A readable report: parameters +- std, sigma0, residuals, blunders,
        every number with its unit.

        Args:
            ground_unit: unit of the ground coordinates (default: the unit of
                ``crs`` when it is given and known, else ``"m"``).
            crs: the ground CRS (EPSG code, WKT or PROJ string) to take the
                unit from.
            camera_unit: the camera's length unit (``"mm"``, ``"m"`` or
                ``"px"``), for labels of image-plane values.  Residuals and
                rms are shown in pixels when the camera has a pixel size,
                and also in ``camera_unit`` when that is not pixels.

        Positions and their std are in the ground unit, angles in degrees
        and their std in arc-seconds.
        """
        if np.ndim(self.converged) != 0:
            return "\n\n".join(self[i].summary(ground_unit=ground_unit, crs=crs, camera_unit=camera_unit)
                                for i in range(len(self)))
        gu = ground_unit or _crs_unit(crs)
        ps = self.pixel_size
        if ps is not None and ps == 1.0:
            camera_unit = "px"
        cu = camera_unit or "image-plane units"
        both = ps is not None and cu != "px"  # pixels first, the camera unit beside them

        def image_value(v):
            if ps is None:
                return f"{v:.4g} {cu}"
            return f"{v / ps:.3f} px" + (f" ({v:.4g} {cu})" if both else "")

        e = self.exterior
        labels = ["X", "Y", "Z", *e.convention.split("-")]
        value = np.asarray(e.to_vector())
        lines = [f"Space resection: {'converged' if self.converged else 'NOT CONVERGED'} - {self.message}"]
        lines.append(f"  {'parameter':<16}{'value':>18}{'std':>16}")
        for k, (lab, val, sd) in enumerate(zip(labels, value, self.std)):
            if k < 3:
                lines.append(f"  {lab + ' [' + gu + ']':<16}{val:>18.4f}{sd:>13.4f} {gu}")
            else:
                lines.append(f"  {lab + ' [deg]':<16}{np.degrees(val):>18.6f}{np.degrees(sd) * 3600.0:>13.2f} \"")
        n_ctrl = int(np.sum(~self.check))
        n_used = int(np.sum(~self.check & ~self.outliers))
        if self.statistic == "w":
            s0 = f"sigma0 = {self.sigma0:.4g} (unitless: a-priori sigma given)"
        else:
            s0 = f"sigma0 = {image_value(self.sigma0)}"
        lines.append(f"  {s0}   rms = {image_value(self.rms)}")
        lines.append(f"  control points used = {n_used} of {n_ctrl}   iterations = {self.iterations}")
        if ps is not None:
            heads = ["vx [px]", "vy [px]"] + ([f"vx [{cu}]", f"vy [{cu}]"] if both else [])
        else:
            heads = [f"vx [{cu}]", f"vy [{cu}]"]
        lines.append(f"  {'point':<12}{'role':<9}" + "".join(f"{h:>13}" for h in heads)
                     + f"{self.statistic + '_x':>9}{self.statistic + '_y':>9}")
        for k, name in enumerate(self.names):
            role = "check" if self.check[k] else ("OUTLIER" if self.outliers[k] else "control")
            vx, vy = self.residuals[k]
            wx, wy = self.normalized[k]
            if ps is not None:
                cols = [f"{vx / ps:.3f}", f"{vy / ps:.3f}"] + ([f"{vx:.4g}", f"{vy:.4g}"] if both else [])
            else:
                cols = [f"{vx:.4g}", f"{vy:.4g}"]
            lines.append(f"  {str(name):<12}{role:<9}" + "".join(f"{c:>13}" for c in cols) + f"{wx:>9.2f}{wy:>9.2f}")
        for k in np.flatnonzero(self.outliers):
            lines.append(f"  blunder: {self.names[k]} excluded (|{self.statistic}| = "
                         f"{_blunder_stat(self, k):.2f} > {self.critical:.2f})")
        if np.any(self.check):
            lines.append(f"  check points: rms = {image_value(self.check_rms)}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """A JSON-serialisable dict (floats, lists, strings)."""
        if np.ndim(self.converged) != 0:
            return {"images": [self[i].to_dict() for i in range(len(self))]}
        e = self.exterior
        tolist = lambda a: np.where(np.isfinite(a), a, np.nan).tolist()  # noqa: E731
        out = {
            "convention": e.convention,
            "position": np.asarray(e.position).tolist(),
            "angles_rad": np.asarray(e.angles).tolist(),
            "angles_deg": np.degrees(np.asarray(e.angles)).tolist(),
            "sigma0": float(self.sigma0),
            "std": tolist(self.std),
            "covariance": tolist(self.covariance),
            "correlation": tolist(self.correlation),
            "rms": float(self.rms),
            "check_rms": float(self.check_rms),
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "message": str(self.message),
            "statistic": self.statistic,
            "critical": float(self.critical),
            "points": [
                {
                    "name": str(self.names[k]),
                    "role": "check" if self.check[k] else "control",
                    "outlier": bool(self.outliers[k]),
                    "residual": self.residuals[k].tolist(),
                    "redundancy": self.redundancy[k].tolist(),
                    "normalized": self.normalized[k].tolist(),
                }
                for k in range(len(self.names))
            ],
        }
        json.dumps(out)  # fail here, not in the caller, if something is not serialisable
        return out


_UNIT_ABBREVIATIONS = {"metre": "m", "meter": "m", "foot": "ft", "US survey foot": "US ft", "kilometre": "km"}


def _crs_unit(crs: str | None) -> str:
    """Abbreviated linear unit of a CRS (``"m"`` when not given or not known)."""
    if crs is None:
        return "m"
    try:
        from rasterio.crs import CRS

        name = CRS.from_user_input(crs).linear_units
    except Exception:  # an unknown CRS text: the report still shows metres, the usual case
        return "m"
    if not name or name == "unknown":
        return "m"
    return _UNIT_ABBREVIATIONS.get(name, name)


def _blunder_stat(res: ResectionResult, k: int) -> float:
    return float(np.nanmax(np.abs(res.normalized[k])))


# --------------------------------------------------------------------------- linear start
# Small dense algebra (photax._linalg) is written out element-wise: on CPU every LAPACK call
# costs tens of microseconds, and element-wise code vectorises under vmap.


def _normal_equations(rows: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Normal equations for ``v`` minimising ``|rows v|`` with ``v[-1] = 1``,
    padded to 11 unknowns (so homographies and DLTs solve in one call).

    The last unknown is the depth of the centroid of the (centred) ground
    points times the scale: never zero for a camera that sees them.
    """
    a, b = rows[:, :-1], rows[:, -1]
    k = a.shape[1]
    n = jnp.eye(11).at[:k, :k].set(a.T @ a)
    return n, jnp.zeros(11).at[:k].set(-(a.T @ b))


def _homography_rows(uv, plane_xy, w, scale):
    """DLT rows of the homography (plane -> normalised image)."""
    a, b = plane_xy[:, 0] / scale, plane_xy[:, 1] / scale
    u, v = uv[:, 0], uv[:, 1]
    o, z = jnp.ones_like(a), jnp.zeros_like(a)
    r1 = jnp.stack([a, b, o, z, z, z, -u * a, -u * b, -u], axis=1)
    r2 = jnp.stack([z, z, z, a, b, o, -v * a, -v * b, -v], axis=1)
    return jnp.concatenate([r1, r2], axis=0) * jnp.concatenate([w, w])[:, None]


def _pose_homography(sol, t_uv, scale, basis):
    """Calibrated homography decomposition -> (R_cv, C) (Zhang 2000, sec. 3.1).

    ``R_cv`` is OpenCV's cam_from_world (x right, y down, z forward).
    """
    h = inv3(t_uv) @ jnp.append(sol[:8], 1.0).reshape(3, 3)  # undo the image normalisation
    lam = 0.5 * (jnp.linalg.norm(h[:, 0]) + jnp.linalg.norm(h[:, 1]))
    c1, c2 = h[:, 0] / lam, h[:, 1] / lam
    r_cv = nearest_rotation(jnp.stack([c1, c2, jnp.cross(c1, c2)], axis=1)) @ basis.T
    return r_cv, -r_cv.T @ (h[:, 2] * scale / lam)


def _dlt_rows(uv, ground, w, scale):
    """Rows of the calibrated DLT ``x ~ [M | m] X``."""
    x = ground / scale
    u, v = uv[:, 0], uv[:, 1]
    xh = jnp.concatenate([x, jnp.ones_like(u)[:, None]], axis=1)
    z4 = jnp.zeros_like(xh)
    r1 = jnp.concatenate([xh, z4, -u[:, None] * xh], axis=1)
    r2 = jnp.concatenate([z4, xh, -v[:, None] * xh], axis=1)
    return jnp.concatenate([r1, r2], axis=0) * jnp.concatenate([w, w])[:, None]


def _pose_dlt(sol, t_uv, scale):
    """DLT solution -> (R_cv, C) (Hartley & Zisserman 2003, sec. 7.1)."""
    p = inv3(t_uv) @ jnp.append(sol, 1.0).reshape(3, 4)
    m = p[:, :3] / scale
    lam = jnp.mean(jnp.linalg.norm(m, axis=1))
    r_cv = nearest_rotation(m)
    return r_cv, -r_cv.T @ (p[:, 3] / lam)


def _sq_errors(r_cv, c, uv, ground):
    """Squared normalised reprojection errors; +inf behind the camera."""
    p = (ground - c[None, :]) @ r_cv.T
    front = p[:, 2] > 0
    zs = jnp.where(front, p[:, 2], 1.0)
    e = jnp.sum((p[:, :2] / zs[:, None] - uv) ** 2, axis=1)
    return jnp.where(front & jnp.isfinite(e), e, jnp.inf)


def _linear_start(uv, ground, ctrl, basis, subsets, robust, dlt_ok, convention):
    """Linear start as a 6-vector ``(C, angles)``.

    Candidates: homography and DLT from all control points, plus (if
    ``subsets`` is not empty) from each subset.  With ``robust`` the winner
    has the least median squared error, otherwise the least sum.
    """
    wf = ctrl.astype(float)
    n_ctrl = jnp.sum(wf)
    # Hartley normalisation of the image points; the ground is centred.
    mu = jnp.sum(uv * wf[:, None], axis=0) / n_ctrl
    su = jnp.sqrt(jnp.sum(wf * jnp.sum((uv - mu[None, :]) ** 2, axis=1)) / (2.0 * n_ctrl))
    t_uv = jnp.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]) / su
    t_uv = t_uv.at[:2, 2].set(-mu / su).at[2, 2].set(1.0)
    uvn = (uv - mu[None, :]) / su
    centre = jnp.sum(ground * wf[:, None], axis=0) / n_ctrl
    g = (ground - centre[None, :]) * wf[:, None]
    scale = jnp.sqrt(jnp.sum(g * g) / n_ctrl)
    rel = ground - centre[None, :]
    plane = rel @ basis[:, :2]

    # All systems (homography, DLT; all points, then each subset) in one batched solve.
    systems = [_normal_equations(_homography_rows(uvn, plane, wf, scale)),
               _normal_equations(_dlt_rows(uvn, rel, wf, scale))]
    k = subsets.shape[0]
    if k:
        w4 = jnp.ones(subsets.shape[1]).at[4:].set(0.0)  # homography on the first 4
        w6 = jnp.ones(subsets.shape[1])
        systems.append(jax.vmap(lambda s: _normal_equations(_homography_rows(uvn[s], plane[s], w4, scale)))(subsets))
        systems.append(jax.vmap(lambda s: _normal_equations(_dlt_rows(uvn[s], rel[s], w6, scale)))(subsets))
    mats = jnp.concatenate([m[None] for m, _ in systems[:2]] + [m for m, _ in systems[2:]])
    rhs = jnp.concatenate([v[None] for _, v in systems[:2]] + [v for _, v in systems[2:]])
    sols = cho_solve(mats, rhs[..., None])[..., 0]
    is_dlt = np.array([False, True] + [False] * k + [True] * k)
    hom = jax.vmap(lambda s: _pose_homography(s, t_uv, scale, basis))(sols[~is_dlt])
    dlt = jax.vmap(lambda s: _pose_dlt(s, t_uv, scale))(sols[is_dlt])
    order = np.argsort(np.argsort(is_dlt, kind="stable"), kind="stable")  # back to the is_dlt order
    r_all = jnp.concatenate([hom[0], dlt[0]])[order]
    c_all = jnp.concatenate([hom[1], dlt[1]])[order]
    err = jax.vmap(lambda r, c: _sq_errors(r, c, uv, rel))(r_all, c_all)
    err = jnp.where(ctrl[None, :], err, jnp.inf)
    total = jnp.sum(jnp.where(ctrl[None, :], err, 0.0), axis=1)
    if k:
        # Least median of squares (Rousseeuw 1984).
        median = jnp.take(jnp.sort(err, axis=1), (n_ctrl.astype(int) - 1) // 2, axis=1)
        from_subset = np.arange(len(is_dlt)) >= 2
        score = jnp.where(robust, median, jnp.where(from_subset, jnp.inf, total))
    else:
        score = total
    score = jnp.where(jnp.asarray(is_dlt) & ~dlt_ok, jnp.inf, score)
    best = jnp.argmin(jnp.where(jnp.isnan(score), jnp.inf, score))
    r_world = r_all[best].T @ jnp.asarray(_OPENCV_FLIP)  # world_from_camera
    angles = _angles(r_world, convention)
    return jnp.concatenate([c_all[best] + centre, angles])


# --------------------------------------------------------------------------- adjustment


def _wrap(a):
    """Angles to (-pi, pi]."""
    return jnp.pi - jnp.mod(jnp.pi - a, 2.0 * jnp.pi)


def _rotation(angles, pok):
    # The convention is a traced flag (``pok``: phi-omega-kappa), not a static
    # choice, so both conventions share one compilation.
    return jnp.where(pok, rotation_matrix(angles, "phi-omega-kappa"), rotation_matrix(angles, "omega-phi-kappa"))


def _angles(matrix, pok):
    a = angles_from_matrix_unchecked(matrix, "phi-omega-kappa")[0]
    b = angles_from_matrix_unchecked(matrix, "omega-phi-kappa")[0]
    return jnp.where(pok, a, b)


def _model(xy, ground, weight, ctrl, camera, convention):
    """``weighted(p)``: sqrt(P) (x_obs - x(p)) of the control points, flattened, and ``predict(p)``."""
    sqrt_w = jnp.sqrt(weight)

    def predict(p):  # the collinearity equations, as photax.project
        return camera.project((ground - p[None, :3]) @ _rotation(p[3:], convention))

    def weighted(p):
        return jnp.where(ctrl[:, None], (xy - predict(p)) * sqrt_w, 0.0).reshape(-1)

    return weighted, predict


def _solver_scale(weight, ctrl, camera):
    # optimistix sees dimensionless residuals (relative weights over f), so
    # its tolerances do not depend on the image unit.
    mean_w = jnp.sum(jnp.where(ctrl[:, None], weight, 0.0)) / (2.0 * jnp.sum(ctrl.astype(float)))
    return 1.0 / (camera.focal_length * jnp.sqrt(mean_w))


def _precision(p, weighted, predict, xy, ground, ctrl, convention):
    """sigma0, Q_xx, redundancy numbers, w statistics (Kraus 2007, app. B)."""
    v = weighted(p)
    a = jax.jacfwd(weighted)(p)
    red = 2.0 * jnp.sum(ctrl.astype(float)) - 6.0
    qxx = cho_solve(jnp.sum(a[:, :, None] * a[:, None, :], axis=0), jnp.eye(6))
    qxx = 0.5 * (qxx + qxx.T)
    sigma0 = jnp.where(red > 0, jnp.sqrt(jnp.sum(v * v) / jnp.where(red > 0, red, 1.0)), jnp.nan)
    r_i = 1.0 - jnp.sum((a @ qxx) * a, axis=1)
    r_i = jnp.where(ctrl[:, None], r_i.reshape(-1, 2), 0.0)
    ok = r_i > 1e-10
    w = jnp.where(ok, v.reshape(-1, 2) / jnp.sqrt(jnp.where(ok, r_i, 1.0)), jnp.nan)
    depth = -((ground - p[None, :3]) @ _rotation(p[3:], convention))[:, 2]
    return dict(params=p, sigma0=sigma0, qxx=qxx, residuals=xy - predict(p), redundancy=r_i, w=w, depth=depth)


def _gauss_newton(weighted, start, max_steps, scale):
    """Gauss-Newton through ``optimistix.GaussNewton``, at most ``max_steps``.

    The residuals are scaled to be dimensionless (:func:`_solver_scale`) and
    the normal equations solved by Cholesky (``lx.Normal(lx.Cholesky())``:
    6 unknowns, well conditioned after the reduction to a local origin).
    optimistix stops on its Cauchy criterion with ``rtol = atol =
    _STEP_TOL``.  Returns the parameters, the number of steps and
    optimistix's result code (0 successful; ``nonfinite`` also when the
    parameters are not finite).
    """
    solver = optx.GaussNewton(rtol=_STEP_TOL, atol=_STEP_TOL, linear_solver=lx.Normal(lx.Cholesky()))
    sol = optx.least_squares(lambda p, _: weighted(p) * scale, solver, start, max_steps=max_steps, throw=False)
    p = sol.value
    status = jnp.where(jnp.all(jnp.isfinite(p)), sol.result._value, optx.RESULTS.nonfinite._value)
    return p, sol.stats["num_steps"], status


def _solve(xy, ground, weight, ctrl, basis, subsets, init, use_init, robust, dlt_ok, crit, snoop, scale_stat, exact,
           min_pts, min_red, max_steps, camera, pok):
    """One image, ground already local: start, Gauss-Newton, precision and
    data snooping rounds, all traced (one compilation for every option).

    ``crit[k]``: critical value with ``k`` control points in use;
    ``scale_stat``: True to divide w by sigma0 (Pope's tau); ``exact``:
    sigma0 below which residuals are rounding noise (no test).  The
    snooping loop excludes the worst point and re-adjusts from the same
    start until the test passes, redundancy runs out or Gauss-Newton fails.
    """
    xn = camera.normalised(xy)
    uv = jnp.stack([xn[:, 0], -xn[:, 1]], axis=1)  # OpenCV's normalised frame (y down)
    start = jnp.where(use_init, init, _linear_start(uv, ground, ctrl, basis, subsets, robust, dlt_ok, pok))

    def adjust(used):
        weighted, predict = _model(xy, ground, weight, used, camera, pok)
        p, steps, status = _gauss_newton(weighted, start, max_steps, _solver_scale(weight, used, camera))
        out = _precision(jnp.concatenate([p[:3], _wrap(p[3:])]), weighted, predict, xy, ground, used, pok)
        return dict(out, result=status, steps=steps)

    def test(out, used):
        n_used = jnp.sum(used.astype(int))
        c = crit[n_used]
        stat = jnp.abs(out["w"]) / jnp.where(scale_stat, out["sigma0"], 1.0)
        worst = jnp.max(jnp.where(jnp.isnan(stat), -jnp.inf, stat), axis=1)
        worst = jnp.where(used, worst, -jnp.inf)
        k = jnp.argmax(worst)
        red = 2.0 * n_used.astype(float) - 6.0
        go = snoop & (worst[k] > c) & ~(out["sigma0"] < exact) & (out["result"] == 0)
        go &= (n_used - 1 >= min_pts) & (red - 2.0 >= min_red)  # excluding a point costs 2 redundancy
        return go, k, stat, c

    def body(carry):  # adjust; test; exclude the worst point if the test fails
        _, used, stat_at, _, _ = carry
        out = adjust(used)
        go, k, stat, c = test(out, used)
        used = jnp.where(go, used.at[k].set(False), used)
        stat_at = jnp.where(go, stat_at.at[k].set(stat[k]), stat_at)
        return out, used, stat_at, go, c

    # One adjust() in the loop body (traced once: half the code to compile).
    blank = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(adjust, ctrl))
    carry = (blank, ctrl, jnp.full(xy.shape, jnp.nan), jnp.array(True), jnp.array(0.0))
    out, used, stat_at, _, c = jax.lax.while_loop(lambda s: s[3], body, carry)
    return dict(out, start=start, used=used, stat_at=stat_at, critical=c)


def _out_shapes(m: int) -> dict:
    return dict(params=(6,), sigma0=(), qxx=(6, 6), residuals=(m, 2), redundancy=(m, 2), w=(m, 2), depth=(m,),
                result=(), steps=(), start=(6,), used=(m,), stat_at=(m, 2), critical=())


def _packed(*args):
    # One flat float64 vector: a single device-to-host copy instead of 13.
    out = _solve(*args)
    return jnp.concatenate([jnp.ravel(out[k]).astype(float) for k in _out_shapes(0)])


def _unpack(flat: np.ndarray, m: int) -> dict:
    """Inverse of :func:`_packed` (any leading batch axes)."""
    out, i = {}, 0
    for k, shape in _out_shapes(m).items():
        size = int(np.prod(shape))
        v = flat[..., i : i + size].reshape(flat.shape[:-1] + shape)
        out[k] = v.astype(int) if k in ("result", "steps") else (v > 0.5 if k == "used" else v)
        i += size
    return out


_MAX_STEPS_ARG = 16  # position of max_steps in _solve: static, optimistix needs a Python int


def _packed_batch(*args):
    max_steps = args[_MAX_STEPS_ARG]
    rest = args[:_MAX_STEPS_ARG] + args[_MAX_STEPS_ARG + 1 :]

    def one(*a):
        return _packed(*a[:_MAX_STEPS_ARG], max_steps, *a[_MAX_STEPS_ARG:])

    return jax.vmap(one, in_axes=(0, 0, 0, 0, 0, None, 0, 0) + (None,) * 10)(*rest)


_solve_one = jax.jit(_packed, static_argnums=(_MAX_STEPS_ARG,))
_solve_many = jax.jit(_packed_batch, static_argnums=(_MAX_STEPS_ARG,))


@functools.partial(jax.jit, static_argnames=("max_steps",))
def _levenberg_marquardt(xy, ground, weight, used, start, max_steps, camera, pok):
    """Fallback when Gauss-Newton fails: optimistix's Levenberg-Marquardt."""
    weighted, predict = _model(xy, ground, weight, used, camera, pok)
    scale = _solver_scale(weight, used, camera)
    algo = optx.LevenbergMarquardt(rtol=1e-11, atol=1e-11, linear_solver=lx.QR())
    sol = optx.least_squares(lambda p, _: weighted(p) * scale, algo, start, max_steps=max_steps, throw=False)
    p = jnp.concatenate([sol.value[:3], _wrap(sol.value[3:])])
    out = _precision(p, weighted, predict, xy, ground, used, pok)
    return dict(out, result=sol.result._value, steps=sol.stats["num_steps"])


# --------------------------------------------------------------------------- input checks


def _as_points(a, name: str, width: int, batch: bool) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    want = 3 if batch else 2
    if a.ndim != want or a.shape[-1] != width:
        shape = "(b, n, %d)" % width if batch else "(n, %d)" % width
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _point_label(names, k: int) -> str:
    return f"{names[k]!r} (index {k})" if names is not None else f"index {k}"


def _sigma_weights(sigma, shape, name="sigma") -> np.ndarray:
    """A-priori sigmas -> weights 1/sigma^2 with the shape of the image points."""
    if sigma is None:
        return np.ones(shape)
    s = np.asarray(sigma, dtype=float)
    if s.ndim == len(shape) - 1 and s.shape == shape[:-1]:
        s = s[..., None]
    elif s.ndim > 0 and s.shape != shape:
        raise ValueError(f"{name} must be a scalar, (n,) or (n, 2) like the image points {shape}, got {s.shape}")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"{name} must be finite and positive")
    return np.broadcast_to(1.0 / s**2, shape).copy()


def _n_distinct(rows: np.ndarray) -> int:
    """Number of distinct rows (a lexicographic sort: cheaper than np.unique(axis=0))."""
    s = rows[np.lexsort(rows.T[::-1])]
    return 1 + int(np.sum(np.any(s[1:] != s[:-1], axis=1)))


def _check_geometry(ground: np.ndarray, xy: np.ndarray, ctrl: np.ndarray, names, need_init: bool) -> np.ndarray:
    """Degenerate configurations -> ValueError.

    Returns the ``(3, 3)`` right-handed principal axes of the control points
    (the last one the normal of their best-fitting plane).
    """
    idx = np.flatnonzero(ctrl)
    g, x = ground[idx], xy[idx]
    rows = np.concatenate([g, x], axis=1)
    if _n_distinct(rows) < len(rows):
        dup = [k for k in idx if np.sum(np.all(rows == rows[np.searchsorted(idx, k)], axis=1)) > 1]
        raise ValueError("duplicated control points (same ground and image coordinates): "
                         + ", ".join(_point_label(names, k) for k in dup))
    distinct = _n_distinct(g)
    if distinct < 3:
        raise ValueError(f"need at least 3 distinct control points, got {distinct}")
    _, s, vt = np.linalg.svd(g - g.mean(0), full_matrices=False)
    if s[0] == 0 or s[1] < 1e-6 * s[0]:
        raise ValueError("the control points are (nearly) collinear: the orientation is not determined; "
                         "points " + ", ".join(_point_label(names, k) for k in idx))
    planar = distinct < 4 or s[2] < _PLANAR * s[0]
    if need_init:
        if planar and distinct < 4:
            raise ValueError(f"the automatic start needs at least 4 distinct control points, got {distinct}; "
                             "give initial= to resect from 3")
        if not planar and distinct < 6:
            raise ValueError(f"the automatic start needs at least 6 control points for a non-planar GCP set "
                             f"(relief {s[2] / s[0]:.2f} of the extent), got {distinct}; give initial= or more points")
    return np.stack([vt[0], np.cross(vt[2], vt[0]), vt[2]], axis=1)


@functools.lru_cache(maxsize=128)
def _subsets(n_ctrl: int) -> np.ndarray:
    """Seeded random subsets of 6 control points (distinct when there are 6)."""
    rng = np.random.default_rng(_SEED + n_ctrl)
    return rng.random((_N_SUBSETS, n_ctrl)).argsort(axis=1)[:, np.arange(6) % n_ctrl]


def _bucket(n: int) -> int:
    # Pad to a few sizes so a new number of points rarely means a new compilation.
    return max(16, 1 << (n - 1).bit_length())


def _critical(alpha: float, sigma_known: bool, red: float) -> float:
    """Baarda's normal critical value, or Pope's tau with ``red`` dof."""
    if sigma_known:
        return float(stats.norm.ppf(1.0 - alpha / 2.0))
    if red < 2:
        return np.inf
    t = stats.t.ppf(1.0 - alpha / 2.0, red - 1)
    return float(t * np.sqrt(red) / np.sqrt(red - 1 + t * t))


def _message(result: int, steps: int, solver: str) -> tuple[bool, str]:
    name = {"gn": "Gauss-Newton", "lm": "Levenberg-Marquardt"}[solver]
    if result == 0:
        return True, f"{name} converged in {steps} steps"
    why = _OPTX_MESSAGES.get(result, "the solver failed")
    return False, f"{name} did not converge after {steps} steps: {why}"


def _pixel_size(camera: FrameCamera) -> float | None:
    return None if camera.pixel_size is None else float(np.mean(np.asarray(camera.pixel_size)))


def _frame(camera: FrameCamera) -> tuple[np.ndarray | None, float]:
    """Half frame ``(2,)`` in image-plane units (None without a pixel grid) and f."""
    f = float(camera.focal_length)
    if camera.pixel_size is None or camera.image_size is None:
        return None, f
    return 0.5 * np.asarray(camera.image_size, float) * np.asarray(camera.pixel_size, float), f


def _viewing_axis(angles, convention) -> np.ndarray:
    """``(..., 3)`` viewing direction in the world (camera z points backwards)."""
    return -np.asarray(rotation_matrix(np.asarray(angles), convention))[..., :, 2]


def _plausibility(xy, ctrl, outliers, centre, axis, normal, rms, half, f):
    """Checks that make a converged adjustment a failure, with the reason.

    A resection can converge to a wrong answer when image and ground do not
    belong together: it then excludes many points as blunders, fits with
    residuals no measurement has, or finds the mirror image of the true
    orientation (the camera below the GCPs' plane, looking up at it:
    swapping x/y or E/N reflects the scene, and a reflected planar scene is
    seen exactly from the mirrored camera).  Returns None when it passes.

    ``xy`` (n, 2) image points; ``ctrl``, ``outliers`` (n,) masks;
    ``centre`` (3,) projection centre relative to a point of the GCPs'
    plane; ``axis`` (3,) viewing direction;
    ``normal`` (3,) normal of the GCPs' best-fitting plane; ``rms`` of the
    control inliers; ``half`` half frame or None; ``f`` focal length.
    """
    c = xy[ctrl]
    spread = np.ptp(c, axis=0).max() if len(c) else 0.0
    if half is not None:
        out = np.abs(c) > _FRAME_MARGIN * half[None, :]
        if np.any(out):
            swapped = np.all(np.abs(c[:, ::-1]) <= _FRAME_MARGIN * half[None, :])
            return (f"image coordinates of {int(np.any(out, axis=1).sum())} control points lie outside the camera's "
                    f"frame (half size {half[0]:.4g} x {half[1]:.4g}): "
                    + ("they would fit with x and y (column and row) swapped" if swapped else
                       "wrong units (e.g. pixels or micrometres for a mm camera), or a camera file that does not "
                       "belong to these measurements"))
        if spread < _MIN_SPREAD * 2.0 * half.max():
            return (f"the control points span only {spread:.3g} on the image plane, {spread / (2 * half.max()):.1e} of "
                    "the frame: wrong units (e.g. metres for a mm camera)")
    elif np.any(np.hypot(*c.T) > _MAX_FIELD * f):
        return (f"image coordinates up to {np.hypot(*c.T).max():.4g} from the centre with a focal length of {f:.4g} "
                f"(a field of view over {2 * np.degrees(np.arctan(_MAX_FIELD)):.0f} degrees): wrong units "
                "(e.g. mm or pixels for a camera in metres)")
    elif spread < _MIN_SPREAD_F * f:
        return (f"the control points span only {spread:.3g} on the image plane, {spread / f:.1e} of the focal length: "
                "wrong units (e.g. metres for a mm camera)")
    n_ctrl, n_out = int(ctrl.sum()), int(outliers.sum())
    if n_out > _MAX_EXCLUDED * n_ctrl:
        return (f"{n_out} of {n_ctrl} control points had to be excluded as blunders (more than a third): "
                "image and ground coordinates do not fit together")
    size = 2.0 * np.hypot(*half) if half is not None else f
    if rms > _MAX_RMS * size:
        return (f"the residuals (rms {rms:.4g}) are {rms / size:.1%} of the {'frame diagonal' if half is not None else 'focal length'}, "
                "far beyond measurement error: image and ground coordinates do not fit together")
    n = normal if normal[2] >= 0 else -normal
    if n[2] > np.cos(np.radians(_MAX_TILT)):
        if float(centre @ n) < 0 and float(axis @ n) > 0:
            return ("the solution is a mirror image: the camera is below the control points' plane, looking up at it "
                    "(Z must be up, and a swap of image column/row or x/y, or of ground E/N, mirrors the scene)")
    return None


# --------------------------------------------------------------------------- public API


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
        robust: least-median-of-squares start over random subsets, and data
            snooping (exclude the worst point while a test fails).
        alpha: significance level of each test (0.001 -> 3.29 for w).
        max_steps: maximum Gauss-Newton / LM steps per adjustment.
        throw: raise :class:`photax.ConvergenceError` on failure; otherwise
            return the result with ``converged=False`` and the reason.
            Failure includes an implausible solution (module docstring,
            step 5).

    Returns:
        :class:`ResectionResult` (finite values also when it failed).

    Raises:
        ValueError: bad shapes, NaN/inf (naming the points), too few or
            degenerate (collinear, duplicated) control points.
        ConvergenceError: with ``throw=True`` on failure; whatever
            ``throw``, if the compiled solver itself raises (the original
            exception is its ``__cause__``).
    """
    check_convention(convention)
    xy = _as_points(image_xy, "image_xy", 2, False)
    ground = _as_points(ground_xyz, "ground_xyz", 3, False)
    n = len(xy)
    if len(ground) != n:
        raise ValueError(f"image_xy has {n} points but ground_xyz has {len(ground)}")
    if names is not None:
        names = [str(s) for s in names]
        if len(names) != n:
            raise ValueError(f"names has {len(names)} entries for {n} points")
    bad = ~(np.all(np.isfinite(xy), axis=1) & np.all(np.isfinite(ground), axis=1))
    if np.any(bad):
        raise ValueError("non-finite (NaN/inf) coordinates at points "
                         + ", ".join(_point_label(names, k) for k in np.flatnonzero(bad)))
    if not isinstance(camera, FrameCamera):
        raise ValueError(f"camera must be a photax.FrameCamera, got {type(camera).__name__}")
    weight = _sigma_weights(sigma, xy.shape)
    is_check = np.zeros(n, bool) if check is None else np.asarray(check)
    if is_check.shape != (n,) or is_check.dtype != bool:
        raise ValueError(f"check must be a boolean array of shape ({n},), got {is_check.dtype} {is_check.shape}")
    ctrl = ~is_check
    if ctrl.sum() < 3:
        raise ValueError(f"need at least 3 control points, got {int(ctrl.sum())} (of {n}, the rest are check points)")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    basis = _check_geometry(ground, xy, ctrl, names, initial is None)

    if initial is not None:
        if not isinstance(initial, ExteriorOrientation):
            raise ValueError("initial must be a photax.ExteriorOrientation")
        initial = initial.to_convention(convention)
        if not np.all(np.isfinite(np.asarray(initial.to_vector()))):
            raise ValueError("initial has non-finite values")
    sigma_known = sigma is not None
    m = _bucket(n)
    ctrl_idx = np.flatnonzero(ctrl)
    pad = lambda a, fill=0.0: np.concatenate([a, np.full((m - n,) + a.shape[1:], fill, a.dtype)])  # noqa: E731
    options = _options(alpha, sigma_known, m, robust, camera, initial is not None)
    pok = convention == "phi-omega-kappa"

    def run(xy, ground, basis, fallback):
        """Start, Gauss-Newton and snooping (then Levenberg-Marquardt if it failed and ``fallback``)."""
        origin = ground[ctrl].mean(axis=0)
        init = np.zeros(6) if initial is None else np.concatenate(
            [np.asarray(initial.position) - origin, np.asarray(initial.angles)])
        args = (pad(xy), pad(ground - origin), pad(weight, 1.0), pad(ctrl, False), basis,
                ctrl_idx[_subsets(len(ctrl_idx))], init, initial is not None, robust, len(ctrl_idx) >= 6)
        with _solver_errors():
            out = _unpack(np.asarray(_solve_one(*args, *options, int(max_steps), camera, pok)), m)
        out["solver"] = "gn"
        if out["result"] != 0 and fallback:  # Gauss-Newton failed: Levenberg-Marquardt from the same start, same points
            gn = _message(int(out["result"]), int(out["steps"]), "gn")[1]
            with _solver_errors():
                lm = jax.device_get(_levenberg_marquardt(*args[:2], args[2], out["used"], out["start"], max_steps,
                                                         camera, pok))
            out.update(lm, solver="lm", gn_failure=gn)
        used = out["used"][:n]
        return _finish(out, n, origin, used, ctrl & ~used, out["stat_at"][:n], is_check, names,
                       float(out["critical"]), sigma_known, convention, False, xy, basis[:, 2], camera)

    res = run(xy, ground, basis, True)
    if not res.converged and initial is None and "wrong units (e.g." not in res.message:  # units: no swap helps
        hint = _swap_hint(xy, ground, ctrl, camera, names, run)
        if hint:
            res = dataclasses.replace(res, message=f"{hint}; {res.message}")
    if throw and not res.converged:
        raise ConvergenceError(res.message)
    return res


def _swap_hint(xy, ground, ctrl, camera, names, run) -> str | None:
    """Name the swap that makes a failed resection fit, if one does.

    The usual mistakes in a GCP file are tried (Gauss-Newton only: no new
    compilation, milliseconds each): image column/row swapped (x/y
    without a pixel grid), the row counted upwards (y mirrored), ground E
    and N swapped.  A hypothesis counts when its resection passes every
    check of :func:`_plausibility` (in particular, at most a third of the
    points excluded).
    """
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
            basis = _check_geometry(ground_h, xy_h, ctrl, names, True)
            res = run(xy_h, ground_h, basis, False)
        except (ValueError, ConvergenceError):
            continue
        if res.converged:
            rms = f"{res.rms / res.pixel_size:.3g} px" if res.pixel_size else f"{res.rms:.3g}"
            k = int(res.outliers.sum())
            fits.append(f"{text} (then rms {rms}, {k} point{'' if k == 1 else 's'} excluded)")
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
        raise ConvergenceError(f"the resection failed inside its solver ({type(exc).__name__}); "
                               f"the orientation could not be computed from these points; {_CAUSES}") from exc


@functools.lru_cache(maxsize=64)
def _critical_table(alpha: float, sigma_known: bool, m: int) -> np.ndarray:
    """Critical values indexed by the number of control points in use (0..m)."""
    return np.array([_critical(alpha, sigma_known, 2.0 * k - 6.0) for k in range(m + 1)])


def _options(alpha, sigma_known, m, robust, camera, has_initial):
    """The traced options of :func:`_solve` after ``dlt_ok``: crit, snoop,
    scale_stat, exact, min_pts, min_red."""
    exact = 1e-10 if sigma_known else 1e-10 * float(camera.focal_length)  # rounding-level residuals: no test
    return (_critical_table(float(alpha), sigma_known, m), bool(robust), not sigma_known, exact,
            3 if has_initial else 4, 1.0 if sigma_known else 2.0)


def _finish(out, n, origin, used, outliers, stat_at, is_check, names, crit, sigma_known, convention, throw,
            xy, normal, camera):
    p = out["params"]
    if not np.all(np.isfinite(p)):  # keep the values finite (the start), the status says it failed
        p = np.where(np.isfinite(p), p, np.nan_to_num(out["start"]))
    converged, message = _message(int(out["result"]), int(out["steps"]), out["solver"])
    if "gn_failure" in out:
        message = f"{out['gn_failure']}; then {message}"
    if not converged:
        message += "; " + _CAUSES
    behind = used & ~(out["depth"][:n] > 0)
    resid = out["residuals"][:n]
    d2 = np.sum(resid**2, axis=1)
    rms = float(np.sqrt(np.mean(d2[used]))) if used.any() else np.nan
    if converged and np.any(behind):
        converged = False
        message = ("the solution puts control points behind the camera: " + ", ".join(
            _point_label(names, k) for k in np.flatnonzero(behind)) + "; " + _CAUSES)
    if converged:
        half, f = _frame(camera)
        why = _plausibility(xy, ~is_check, outliers, p[:3], _viewing_axis(p[3:], convention), normal, rms, half, f)
        if why is not None:
            converged, message = False, f"{why}; {_CAUSES} (the adjustment itself: {message})"
    red = 2.0 * used.sum() - 6.0
    sigma0 = float(out["sigma0"])
    if red <= 0:
        message += "; zero redundancy: sigma0 and blunder tests undefined" + (
            ", covariance from the a-priori sigma" if sigma_known else ", covariance unknown")
        cov = out["qxx"] if sigma_known else np.full((6, 6), np.nan)
    else:
        cov = sigma0**2 * out["qxx"]
    std = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    stat = out["w"][:n] / (1.0 if sigma_known else sigma0)
    stat = np.where(used[:, None], stat, stat_at)
    check_rms = float(np.sqrt(np.mean(d2[is_check]))) if is_check.any() else np.nan
    if names is None:
        names = [f"P{k}" for k in range(n)]
    res = ResectionResult(
        exterior=ExteriorOrientation(p[:3] + origin, p[3:], convention),
        sigma0=sigma0,
        covariance=cov,
        std=std,
        correlation=corr,
        residuals=resid,
        outliers=outliers,
        check=is_check,
        redundancy=out["redundancy"][:n],
        normalized=stat,
        critical=crit,
        rms=rms,
        check_rms=check_rms,
        iterations=int(out["steps"]),
        converged=bool(converged),
        message=message,
        names=list(names),
        statistic="w" if sigma_known else "tau",
        pixel_size=_pixel_size(camera),
    )
    if throw and not converged:
        raise ConvergenceError(message)
    return res


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

    The same compiled solver as :func:`resect`, ``jax.vmap``-ed over chunks
    of 256 images (one compilation for any batch size): start, Gauss-Newton
    (at most ``max_steps`` iterations), precision and data snooping rounds,
    each image with its own ``converged`` flag and ``message``.  Unlike
    :func:`resect`, the start comes from all points (no random subsets:
    with ``robust=True`` blunders are still found by data snooping, but a
    gross blunder may spoil the start), and there is no Levenberg-Marquardt
    fallback: a failed image is reported, not retried.  The plausibility
    checks of :func:`resect` (module docstring, step 5) apply per image;
    the swap hints are not tried.

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
    """
    check_convention(convention)
    xy = _as_points(image_xy, "image_xy", 2, True)
    ground = _as_points(ground_xyz, "ground_xyz", 3, True)
    b, n = xy.shape[:2]
    if ground.shape[:2] != (b, n):
        raise ValueError(f"image_xy has shape {xy.shape} but ground_xyz has {ground.shape}")
    if n < 4 and initial is None:
        raise ValueError(f"the automatic start needs at least 4 points per image, got {n}")
    if n < 3:
        raise ValueError(f"need at least 3 points per image, got {n}")
    bad = ~(np.all(np.isfinite(xy), axis=2) & np.all(np.isfinite(ground), axis=2))
    if np.any(bad):
        where = [f"image {i} point {k}" for i, k in zip(*np.nonzero(bad))][:10]
        raise ValueError("non-finite (NaN/inf) coordinates at " + ", ".join(where))
    weight = _sigma_weights(sigma, xy.shape)
    origin = ground.mean(axis=1)
    local = ground - origin[:, None, :]
    _, s, vt = np.linalg.svd(local, full_matrices=False)
    collinear = (s[:, 0] == 0) | (s[:, 1] < 1e-6 * s[:, 0])
    if np.any(collinear):
        raise ValueError(f"collinear control points in images {np.flatnonzero(collinear)[:10].tolist()}")
    if initial is None and n < 6:
        flat = s[:, 2] < _PLANAR * s[:, 0]
        if not np.all(flat):
            raise ValueError(f"images {np.flatnonzero(~flat)[:10].tolist()} have non-planar GCPs: "
                             "the automatic start needs 6 points for them")
    basis = np.stack([vt[:, 0], np.cross(vt[:, 2], vt[:, 0]), vt[:, 2]], axis=2)
    if initial is not None:
        e0 = initial.to_convention(convention)
        init = np.concatenate([np.asarray(e0.position) - origin, np.asarray(e0.angles)], axis=-1)
        if init.shape != (b, 6):
            raise ValueError(f"initial must have batch shape ({b},), got {init.shape[:-1]}")
    else:
        init = np.zeros((b, 6))
    m = _bucket(n)
    padn = lambda a, fill=0.0: np.concatenate([a, np.full(a.shape[:1] + (m - n,) + a.shape[2:], fill, a.dtype)], 1)  # noqa: E731
    sigma_known = sigma is not None
    # Fixed-size chunks of images: one compilation for any batch size, and a
    # slow image holds up only its own chunk's while-loops.
    nb = -(-b // _CHUNK) * _CHUNK
    padb = lambda a: np.concatenate([a, np.repeat(a[:1], nb - b, axis=0)]) if nb > b else a  # noqa: E731
    per_image = [padb(a) for a in (padn(xy), padn(local), padn(weight, 1.0), padn(np.ones((b, n), bool), False), basis,
                                    init, np.full(b, initial is not None))]
    options = (False, n >= 6, *_options(alpha, sigma_known, m, robust, camera, initial is not None), int(max_steps),
               camera, convention == "phi-omega-kappa")  # robust=False: no random subsets (start from all points)
    no_subsets = np.zeros((0, 6), int)
    with _solver_errors():
        chunks = [_solve_many(*[a[i : i + _CHUNK] for a in per_image[:5]], no_subsets,
                              *[a[i : i + _CHUNK] for a in per_image[5:]], *options)
                  for i in range(0, nb, _CHUNK)]  # dispatched asynchronously, gathered once
        out = _unpack(np.concatenate([np.asarray(c) for c in chunks])[:b], m)
    used = out["used"][:, :n]
    return _finish_batch(out, n, origin, used, ~used, out["stat_at"][:, :n], out["critical"], sigma_known,
                         convention, throw, xy, basis[:, :, 2], camera)


def _finish_batch(out, n, origin, used, outliers, stat_at, crit, sigma_known, convention, throw, xy, normal, camera):
    b = len(origin)
    finite = np.all(np.isfinite(out["params"]), axis=1)
    # keep the values finite (the start), the status says it failed
    p = np.where(finite[:, None], out["params"], np.nan_to_num(out["start"]))
    red = 2.0 * used.sum(1) - 6.0
    sigma0 = out["sigma0"]
    cov = np.where((red > 0)[:, None, None], sigma0[:, None, None] ** 2 * out["qxx"],
                   out["qxx"] if sigma_known else np.nan)
    std = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / (std[:, :, None] * std[:, None, :])
    resid = out["residuals"][:, :n]
    stat = out["w"][:, :n] / (1.0 if sigma_known else sigma0[:, None, None])
    stat = np.where(used[:, :, None], stat, stat_at)
    d2 = np.sum(resid**2, axis=2)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.sum(d2 * used, axis=1) / used.sum(1))
    behind = np.any(used & ~(out["depth"][:, :n] > 0), axis=1)
    ok = (out["result"] == 0) & ~behind & finite
    steps = out["steps"]
    half, f = _frame(camera)
    axis = _viewing_axis(p[:, 3:], convention)
    messages = []
    for i in range(b):
        converged, message = _message(int(out["result"][i]), int(steps[i]), "gn")
        if not converged:
            message += "; " + _CAUSES
        elif behind[i]:
            message = "the solution puts control points behind the camera; " + _CAUSES
        else:
            why = _plausibility(xy[i], np.ones(n, bool), outliers[i], p[i, :3], axis[i], normal[i], rms[i], half, f)
            if why is not None:
                ok[i] = False
                message = f"{why}; {_CAUSES} (the adjustment itself: {message})"
        messages.append(message)
    res = ResectionResult(
        exterior=ExteriorOrientation(p[:, :3] + origin, p[:, 3:], convention),
        sigma0=sigma0, covariance=cov, std=std, correlation=corr, residuals=resid, outliers=outliers,
        check=np.zeros((b, n), bool), redundancy=out["redundancy"][:, :n], normalized=stat, critical=crit,
        rms=rms, check_rms=np.full(b, np.nan), iterations=steps, converged=ok, message=messages,
        names=[f"P{k}" for k in range(n)], statistic="w" if sigma_known else "tau", pixel_size=_pixel_size(camera),
    )
    if throw and not np.all(ok):
        bad = np.flatnonzero(~ok)
        raise ConvergenceError(f"{len(bad)} of {b} images failed, e.g. image {bad[0]}: {messages[bad[0]]}")
    return res
