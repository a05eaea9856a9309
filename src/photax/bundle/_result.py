"""The result of a bundle adjustment."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..errors import RESULTS
from ._problem import BundleProblem


@dataclasses.dataclass(frozen=True, eq=False)
class BundleResult:
    """Adjusted block, its precision and the solver's report.

    Attributes:
        exterior: ``(n_images,)`` adjusted :class:`ExteriorOrientation`, in the
            problem's angle convention.
        rotation: ``(n_images, 3, 3)`` world_from_camera matrices (well
            defined even where angles are in gimbal lock).
        cameras: adjusted cameras (self-calibrated parameters updated).
        points: ``(n_points, 3)`` adjusted ground coordinates.
        cost: final ``0.5 sum rho(|r|^2)`` (+ control priors), weighted.
        initial_cost: the cost at the start values.
        history: one dict per iteration: ``iteration, cost, lambda,
            step_norm, gradient_max, accepted, seconds``.
        converged, message: stopping status; ``message`` names the rule.
        result: the :class:`photax.RESULTS` code (``converged`` is
            ``result == RESULTS.successful``; docs/architecture.md).
        iterations: number of iterations (accepted and rejected steps).
        residuals: ``(k, 2)`` image-plane residuals ``projected - observed``
            (camera unit).
        weights: ``(k,)`` final IRLS weights (1 without a robust loss).
        sigma0: a-posteriori standard deviation of unit weight
            ``sqrt(sum w r^2 / redundancy)``.
        redundancy: observations minus free parameters (plus the datum
            defect for ``gauge="damped"``).
        exterior_std: ``(n_images, 6)`` standard deviations of ``X, Y, Z``
            and the three angles (radians, the convention's order), or None
            when the datum is not defined (``gauge="damped"``).
        camera_std: ``(n_cameras, n_intrinsics)`` std of the problem's
            ``intrinsic_names`` (:data:`INTRINSICS` for ``"brown"``; 0 = fixed).
        point_std: ``(n_points, 3)`` std of ``X, Y, Z``.
        point_cov: ``(n_points, 3, 3)`` covariances.
        check_residuals: ``(n_check, 3)`` adjusted minus surveyed check points.
        problem: the adjusted problem (for :meth:`to_problem`).
        orientation_cov: ``(n_images, 6 + n_intrinsics, 6 + n_intrinsics)``
            covariance of each image's ``X, Y, Z``, angles (radians, the
            convention's order) and its camera's intrinsics (14 x 14 with
            :data:`INTRINSICS` for ``"brown"``; rows and columns of fixed ones 0):
            the per-image block of the inverse normal matrix times sigma0^2,
            with the exterior-intrinsics correlations; None like
            ``exterior_std``.  :func:`photax.ortho_uncertainty` uses it.
        gnss_residuals: ``(n_images, 3)`` adjusted antenna position (centre
            plus the turned lever arm) minus the GNSS observation, ground
            unit; NaN rows for images without one.
        attitude_residuals: ``(n_images, 3)`` adjusted minus observed
            attitude angles (radians, wrapped); NaN rows where none.
        dem_residuals: ``(n_points,)`` adjusted height minus the DEM's at
            the adjusted ``(X, Y)`` of each tie point with a DEM height
            observation, ground unit; NaN for the others; None without a DEM.

    Examples:
        The adjusted synthetic block of :func:`photax.bundle_adjust`: its report, its check points'
        errors against their precision, and the result as a new start:

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.scene import synthetic_block
        >>> problem, truth = synthetic_block(0)
        >>> result = ptx.bundle_adjust(problem)
        >>> print(result.report().splitlines()[0])
        bundle adjustment: 8 images, 1 camera, 110 points (6 control, 4 check), 286 observations
        >>> result.check_names, result.parts  # one connected block
        (['CHE006', 'CHE007', 'CHE008', 'CHE009'], [[0, 1, 2, 3, 4, 5, 6, 7]])
        >>> check = problem.roles == "check"
        >>> bool(np.all(np.abs(result.check_residuals) < 4 * result.point_std[check]))
        True
        >>> again = ptx.bundle_adjust(result.to_problem())  # starts at the solution: nothing left to gain
        >>> bool(abs(again.cost - result.cost) < 1e-6 * result.cost)
        True
    """

    exterior: ExteriorOrientation
    rotation: np.ndarray
    cameras: tuple[FrameCamera, ...]
    points: np.ndarray
    cost: float
    initial_cost: float
    history: list
    converged: bool
    message: str
    iterations: int
    residuals: np.ndarray
    weights: np.ndarray
    sigma0: float
    redundancy: int
    exterior_std: np.ndarray | None
    camera_std: np.ndarray | None
    point_std: np.ndarray | None
    point_cov: np.ndarray | None
    check_residuals: np.ndarray
    problem: BundleProblem
    seconds: float = 0.0
    result: RESULTS = RESULTS.successful
    orientation_cov: np.ndarray | None = None
    gnss_residuals: np.ndarray | None = None
    attitude_residuals: np.ndarray | None = None
    dem_residuals: np.ndarray | None = None

    @property
    def dem_sigma_estimate(self) -> float | None:
        """The DEM heights' sigma as the adjustment estimates it (one variance
        component): ``dem_sigma * sqrt(sum (v / dem_sigma)^2 / sum r)`` over the
        observed ties, with each observation's redundancy number
        ``r = 1 - a^T Q a / dem_sigma^2`` (``a = (-dDEM/dX, -dDEM/dY, 1)``, ``Q``
        the point's cofactor block).  Near the given ``dem_sigma`` when it fits
        the data; None without a DEM, an observed tie or the precision."""
        if self.dem_residuals is None or self.point_cov is None or not np.isfinite(self.sigma0) or self.sigma0 <= 0:
            return None
        seen = np.isfinite(self.dem_residuals)
        if not np.any(seen):
            return None
        import jax
        import jax.numpy as jnp

        x, y = (jnp.asarray(self.points[seen, k]) for k in (0, 1))
        dem = self.problem.dem
        _, dx = jax.jvp(dem.height, (x, y), (jnp.ones_like(x), jnp.zeros_like(y)))
        _, dy = jax.jvp(dem.height, (x, y), (jnp.zeros_like(x), jnp.ones_like(y)))
        a = np.column_stack([-np.asarray(dx), -np.asarray(dy), np.ones(int(seen.sum()))])
        sig = self.problem.dem_sigma[seen]
        q = self.point_cov[seen] / self.sigma0**2
        r = 1.0 - np.einsum("ni,nij,nj->n", a, q, a) / sig**2
        scale = float(np.median(sig))
        return scale * float(np.sqrt(np.sum((self.dem_residuals[seen] / sig) ** 2) / np.sum(r)))

    @property
    def parts(self) -> list[list[int]]:
        """The images grouped into parts that share tie, control or check
        points (one part for a connected block); parts beyond the first are
        held to each other only by GNSS / attitude observations or control."""
        return _image_parts(self.problem)

    @property
    def check_names(self) -> list[str]:
        return [n for n, r in zip(self.problem.point_names, self.problem.roles) if r == "check"]

    def to_problem(self) -> BundleProblem:
        """The problem with the adjusted values as start values."""
        tie = (self.problem.roles == "tie")[:, None]
        pts = np.where(tie, self.points, self.problem.points)
        return self.problem.replace(cameras=self.cameras, exterior=self.exterior, points=pts)

    def report(self, unit: str | None = None) -> str:
        """A plain-text summary: convergence, sigma0, residuals, precision.

        ``unit``: the ground CRS's unit (``"m"``, ``"ft"``...) for the
        exterior and point precision; default "ground units".
        """
        p = self.problem
        rms = np.sqrt(np.mean(self.residuals**2, axis=0))
        u = unit or "ground units"

        def n_of(n, word):  # "1 camera", "2 cameras"
            return f"{n} {word}{'' if n == 1 else 's'}"

        n_ctrl, n_chk = int(np.sum(p.roles == "control")), int(np.sum(p.roles == "check"))
        lines = [
            f"bundle adjustment: {n_of(p.n_images, 'image')}, {n_of(p.n_cameras, 'camera')}, "
            f"{n_of(p.n_points, 'point')} ({n_ctrl} control, {n_chk} check), {n_of(p.n_observations, 'observation')}",
            f"  {'converged' if self.converged else 'NOT converged'}: {self.message} after {n_of(self.iterations, 'iteration')} "
            f"({self.seconds:.2f} s)",
            f"  cost {self.initial_cost:.6g} -> {self.cost:.6g}; sigma0 {self.sigma0:.4g} (redundancy {self.redundancy})",
            f"  image residual RMS x {rms[0]:.4g}, y {rms[1]:.4g} (camera units); max |r| "
            f"{np.max(np.abs(self.residuals)):.4g}",
        ]
        if np.any(self.weights < 0.5):
            lines.append(
                f"  {n_of(int(np.sum(self.weights < 0.5)), 'observation')} down-weighted below 0.5 by the robust loss"
            )
        if self.exterior_std is not None:
            s = np.median(self.exterior_std, axis=0)
            lines.append(
                f"  median std of exterior: X {s[0]:.4g}, Y {s[1]:.4g}, Z {s[2]:.4g} {u}, angles "
                f'{np.degrees(s[3]) * 3600:.3g}" {np.degrees(s[4]) * 3600:.3g}" {np.degrees(s[5]) * 3600:.3g}"'
            )
            ps = np.median(self.point_std[p.roles != "control"], axis=0) if np.any(p.roles != "control") else None
            if ps is not None:
                lines.append(f"  median std of tie/check points: X {ps[0]:.4g}, Y {ps[1]:.4g}, Z {ps[2]:.4g} {u}")
        else:
            lines.append("  precision not reported: the datum is free (gauge='damped')")
        free = p.free_intrinsics
        for c, cam in enumerate(self.cameras):
            if free[c].any():
                vals = np.concatenate(
                    [[float(cam.focal_length)], np.asarray(cam.principal_point), np.asarray(cam.distortion)]
                )
                parts = [
                    f"{n} {vals[j]:.6g}" + (f" +- {self.camera_std[c, j]:.2g}" if self.camera_std is not None else "")
                    for j, n in enumerate(p.intrinsic_names) if free[c, j]
                ]  # fmt: skip
                lines.append(f"  camera {c}: " + ", ".join(parts))
                if c >= 5 and len(self.cameras) > 6:
                    lines.append(f"  ... ({n_of(len(self.cameras) - 6, 'more self-calibrated camera')})")
                    break
        if len(self.check_residuals):
            crms = np.sqrt(np.mean(self.check_residuals**2, axis=0))
            lines.append(
                f"  check points ({len(self.check_residuals)}): RMS X {crms[0]:.4g}, Y {crms[1]:.4g}, Z {crms[2]:.4g} {u}"
            )
        lines += self._camera_observation_lines(u)
        parts = self.parts
        if len(parts) > 1:
            sizes = ", ".join(str(len(q)) for q in parts)
            first, other = p.image_names[parts[0][0]], p.image_names[parts[1][0]]
            lines.append(
                f"  WARNING: the block falls into {len(parts)} parts that share no point (images per part: "
                f"{sizes}; e.g. {other} is not tied to {first}): their relative orientation rests on the "
                "GNSS / attitude observations and control alone"
            )
        return "\n".join(lines)

    def _camera_observation_lines(self, u: str) -> list[str]:
        """The report's lines on the GNSS positions and attitudes: RMS and largest residual."""
        lines = []
        names = self.problem.image_names
        for res, seen, what, scale, unit in (
            (self.gnss_residuals, self.problem.gnss_observed, "GNSS positions", 1.0, f" {u}"),
            (self.attitude_residuals, self.problem.attitude_observed, "attitudes", 180 / np.pi, " deg"),
        ):
            if res is None or not seen.any():
                continue
            r = res[seen] * scale
            rms = np.sqrt(np.mean(r**2, axis=0))
            worst = int(np.flatnonzero(seen)[np.argmax(np.max(np.abs(r), axis=1))])
            lines.append(
                f"  {what} ({int(seen.sum())}): residual RMS {rms[0]:.4g}, {rms[1]:.4g}, "
                f"{rms[2]:.4g}{unit}; max |r| {np.max(np.abs(r)):.4g}{unit} ({names[worst]})"
            )
        if self.dem_residuals is not None:
            r = self.dem_residuals[np.isfinite(self.dem_residuals)]
            n_tie = int(np.sum(self.problem.roles == "tie"))
            lines.append(
                f"  DEM heights ({len(r)} of {n_tie} tie points; {n_tie - len(r)} off the DEM or on nodata): "
                f"Z - DEM RMS {np.sqrt(np.mean(r**2)):.4g} {u}, mean {np.mean(r):+.4g} {u}, max |r| "
                f"{np.max(np.abs(r)):.4g} {u} (sigma {np.median(self.problem.dem_sigma):.4g} {u}"
                + (f", estimated {est:.3g} {u})" if (est := self.dem_sigma_estimate) is not None else ")")
            )
        return lines

    def to_dict(self) -> dict:
        """JSON-ready summary (lists of floats)."""
        p = self.problem
        eo = self.exterior
        out = {
            "converged": self.converged, "message": self.message, "iterations": self.iterations,
            "cost": self.cost, "initial_cost": self.initial_cost, "sigma0": self.sigma0 if math.isfinite(self.sigma0) else None,
            "redundancy": self.redundancy, "convention": eo.convention, "seconds": self.seconds,
            "history": self.history,
            "images": [
                {"name": n, "position": np.asarray(eo.position[i]).tolist(), "angles_rad": np.asarray(eo.angles[i]).tolist(),
                 **({"std": self.exterior_std[i].tolist()} if self.exterior_std is not None else {})}
                for i, n in enumerate(p.image_names)
            ],
            "cameras": [
                {"focal_length": float(c.focal_length), "principal_point": np.asarray(c.principal_point).tolist(),
                 "distortion": np.asarray(c.distortion).tolist(),
                 **({"std": self.camera_std[j].tolist()} if self.camera_std is not None else {})}
                for j, c in enumerate(self.cameras)
            ],
            "check_points": [
                {"name": n, "residual": r.tolist()} for n, r in zip(self.check_names, self.check_residuals)
            ],
            "parts": [[p.image_names[i] for i in q] for q in self.parts],
        }  # fmt: skip
        for i, img in enumerate(out["images"]):  # the cameras' own observations, where given
            if self.gnss_residuals is not None and p.gnss_observed[i]:
                img["gnss_residual"] = self.gnss_residuals[i].tolist()
            if self.attitude_residuals is not None and p.attitude_observed[i]:
                img["attitude_residual_rad"] = self.attitude_residuals[i].tolist()
        if self.dem_residuals is not None:
            seen = np.isfinite(self.dem_residuals)
            out["dem_heights"] = {
                "observed": int(seen.sum()), "not_observed": int(np.sum(p.roles == "tie") - seen.sum()),
                "rms": float(np.sqrt(np.mean(self.dem_residuals[seen] ** 2))),
                "mean": float(np.mean(self.dem_residuals[seen])), "sigma_estimate": self.dem_sigma_estimate,
            }  # fmt: skip
        return out


def _image_parts(problem: BundleProblem) -> list[list[int]]:
    """Images grouped by the points they share (connected components of the
    image-point graph), largest part first."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_img, n = problem.n_images, problem.n_images + problem.n_points
    links = (problem.obs_image, n_img + problem.obs_point)
    graph = coo_matrix((np.ones(problem.n_observations), links), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    groups: dict[int, list[int]] = {}
    for i in range(n_img):
        groups.setdefault(int(label[i]), []).append(i)
    return sorted(groups.values(), key=lambda g: (-len(g), g[0]))


#: What each way of stopping short says; the solver carries the :class:`photax.RESULTS`
#: code from where it stops (``_solver._lm_loop``, the precision step of
#: ``_solver._finish``) and :func:`stop_message` words it -- nothing reads a
#: message back.
STOP_WORDS = {
    RESULTS.max_steps_reached: "no convergence within max_steps = {max_steps}",
    RESULTS.singular: "the normal equations are singular{where} (datum defect or undetermined parameters)",
    RESULTS.solver_failed: "trust region radius below 1e-32: no decrease possible",
    RESULTS.nonfinite: "the cost at the start values is not finite (NaN or inf): check observations, sigmas, "
    "start values",
}


def stop_message(code: RESULTS, rule: str = "", *, max_steps: int = 0, at_solution: bool = False) -> str:
    """The message of an adjustment that stopped with ``code``: for
    ``successful`` the stopping rule that held (``rule``, from
    :class:`StoppingRule`), else the words of :data:`STOP_WORDS`."""
    if code == RESULTS.successful:
        return rule or RESULTS.successful.text
    words = STOP_WORDS.get(RESULTS(code), RESULTS(code).text)
    return words.format(max_steps=max_steps, where=" at the solution" if at_solution else "")
