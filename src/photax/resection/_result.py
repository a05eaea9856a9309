"""The outcome of a resection: :class:`ResectionResult`, its report and its JSON form."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._deprecation import alias
from ..collinearity import ExteriorOrientation
from ..errors import RESULTS


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
        residuals: ``(n, 2)`` computed - observed (docs/conventions.md), image-plane units, for all
            input points (outliers and check points included).
        outliers: ``(n,)`` True for points excluded by data snooping.
        check: ``(n,)`` True for check points (not used in the fit).
        redundancy: ``(n, 2)`` redundancy numbers (0 for excluded points).
        normalised: ``(n, 2)`` test statistics (Baarda's w or Pope's tau);
            for outliers the values with which they were rejected; NaN for
            check points.
        critical: critical value the statistics were tested against.
        rmse: RMS reprojection error of the control inliers,
            ``sqrt(mean(vx^2 + vy^2))``, image-plane units.
        check_rmse: the same for the check points (NaN without any).
        rms, check_rms, normalized: the deprecated old names of ``rmse``,
            ``check_rmse`` and ``normalised`` (docs/conventions.md, "Words").
        iterations: Gauss-Newton (or LM) steps of the final adjustment.
        converged: whether the estimate can be trusted.
        message: why it stopped or failed.
        result: the outcome as a :class:`photax.RESULTS` code (an ``int``
            array for a batch): ``successful`` exactly when ``converged``.
        names: ``(n,)`` point names.
        statistic: name of the test (``"w"`` or ``"tau"``).
        pixel_size: the camera's mean pixel size in image-plane units
            (1.0 for a camera in pixels), or None without a pixel grid:
            :meth:`summary` reports residuals in pixels with it.
        corrections: the :class:`photax.ImageCorrections` applied (earth
            curvature, refraction), or None; ``residuals`` are then those of
            the corrected image coordinates.
        image_corrections: ``(n, 2)`` corrected minus observed image
            coordinates (image-plane units), or None.

    Examples:
        A resection whose first control point was measured 15 px off: data snooping rejects it,
        its residual shows the blunder, and the report names it:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> xy = np.array(scene.camera.pixel_to_image(scene.gcp_pixel))
        >>> xy[0, 0] += 15.0  # the camera is in pixels
        >>> res = ptx.resect(xy, scene.gcp_ground, scene.camera, sigma=scene.noise_px)
        >>> res.names[0], bool(res.outliers[0]), f"{res.residuals[0, 0]:.0f} px"
        ('P0', True, '-15 px')
        >>> [line.split()[:2] for line in res.summary().splitlines() if line.strip().startswith("P0 ")]
        [['P0', 'OUTLIER']]
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
    normalised: np.ndarray
    critical: Any
    rmse: Any
    check_rmse: Any
    iterations: Any
    converged: Any
    message: Any
    names: Sequence[str]
    statistic: str = "w"
    pixel_size: float | None = None
    result: Any = RESULTS.successful
    corrections: Any = None
    image_corrections: np.ndarray | None = None

    rms = alias("rmse")
    check_rms = alias("check_rmse")
    normalized = alias("normalised")

    # -- batches -----------------------------------------------------------
    def __len__(self) -> int:
        if np.ndim(self.converged) == 0:
            raise TypeError("a single-image ResectionResult has no len(); resect_batch results do")
        return len(self.converged)

    def __getitem__(self, i: int) -> ResectionResult:
        """The ``i``-th image of a :func:`resect_batch` result."""
        len(self)  # a TypeError for single results
        take = lambda a: np.asarray(a)[i]  # noqa: E731
        ext = ExteriorOrientation(self.exterior.position[i], self.exterior.angles[i], self.exterior.convention)
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for k, v in fields.items():
            if k in ("exterior", "names", "statistic", "pixel_size", "corrections", "image_corrections"):
                continue
            fields[k] = v[i] if isinstance(v, (list, tuple)) else take(v)
            if isinstance(fields[k], np.generic):
                fields[k] = fields[k].item()
        fields["result"] = RESULTS(int(fields["result"]))
        fields["exterior"] = ext
        return ResectionResult(**fields)

    # -- reports -----------------------------------------------------------
    def summary(self, *, ground_unit: str | None = None, crs: str | None = None, camera_unit: str | None = None) -> str:
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
            return "\n\n".join(
                self[i].summary(ground_unit=ground_unit, crs=crs, camera_unit=camera_unit) for i in range(len(self))
            )
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
                lines.append(f'  {lab + " [deg]":<16}{np.degrees(val):>18.6f}{np.degrees(sd) * 3600.0:>13.2f} "')
        n_ctrl = int(np.sum(~self.check))
        n_used = int(np.sum(~self.check & ~self.outliers))
        if self.statistic == "w":
            s0 = f"sigma0 = {self.sigma0:.4g} (unitless: a-priori sigma given)"
        else:
            s0 = f"sigma0 = {image_value(self.sigma0)}"
        lines.append(f"  {s0}   rmse = {image_value(self.rmse)}")
        lines.append(f"  control points used = {n_used} of {n_ctrl}   iterations = {self.iterations}")
        if self.corrections is not None:
            largest = float(np.max(np.hypot(*np.asarray(self.image_corrections).T)))
            names = ", ".join(self.corrections.names)
            lines.append(f"  image corrected for {names} (largest shift {image_value(largest)})")
        if ps is not None:
            heads = ["vx [px]", "vy [px]"] + ([f"vx [{cu}]", f"vy [{cu}]"] if both else [])
        else:
            heads = [f"vx [{cu}]", f"vy [{cu}]"]
        rows = []
        # Python floats, not numpy scalars: formatting those was most of a 10^5-point report's time
        for name, check, outlier, (vx, vy), (wx, wy) in zip(
            self.names,
            np.asarray(self.check, bool).tolist(),
            np.asarray(self.outliers, bool).tolist(),
            np.asarray(self.residuals).tolist(),
            np.asarray(self.normalised).tolist(),
        ):
            role = "check" if check else ("OUTLIER" if outlier else "control")
            if ps is not None:
                cols = [f"{vx / ps:.3f}", f"{vy / ps:.3f}"] + ([f"{vx:.4g}", f"{vy:.4g}"] if both else [])
            else:
                cols = [f"{vx:.4g}", f"{vy:.4g}"]
            rows.append([str(name), role, *cols, f"{wx:.2f}", f"{wy:.2f}"])
        lines += _table(["point", "role", *heads, self.statistic + "_x", self.statistic + "_y"], rows, left=2)
        for k in np.flatnonzero(self.outliers):
            lines.append(
                f"  blunder: {self.names[k]} excluded (|{self.statistic}| = "
                f"{_blunder_stat(self, k):.2f} > {self.critical:.2f})"
            )
        if np.any(self.check):
            lines.append(f"  check points: rmse = {image_value(self.check_rmse)}")
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
            "rmse": float(self.rmse),
            "check_rmse": float(self.check_rmse),
            "iterations": int(self.iterations),
            "converged": bool(self.converged),
            "message": str(self.message),
            "result": RESULTS(int(self.result)).name,
            "statistic": self.statistic,
            "critical": float(self.critical),
            "corrections": list(self.corrections.names) if self.corrections is not None else [],
        }
        json.dumps(out)  # fail here, not in the caller, if something is not serialisable
        # the points: built from lists of Python values (one tolist per array, not per point)
        out["points"] = [
            {
                "name": str(name),
                "role": "check" if check else "control",
                "outlier": outlier,
                "residual": v,
                "redundancy": r,
                "normalised": w,
            }
            for name, check, outlier, v, r, w in zip(
                self.names,
                np.asarray(self.check, bool).tolist(),
                np.asarray(self.outliers, bool).tolist(),
                np.asarray(self.residuals).tolist(),
                np.asarray(self.redundancy).tolist(),
                np.asarray(self.normalised).tolist(),
            )
        ]
        return out


def _table(heads: list[str], rows: list[list[str]], left: int) -> list[str]:
    """Lines of a table indented by two spaces: the first ``left`` columns
    left-aligned, the others right-aligned, each as wide as its widest entry
    (header included) and two spaces apart."""
    width = [max(len(c) for c in col) for col in zip(heads, *rows)]

    def line(cells):
        return (
            "  "
            + "  ".join(c.ljust(w) if j < left else c.rjust(w) for j, (c, w) in enumerate(zip(cells, width))).rstrip()
        )

    return [line(heads)] + [line(r) for r in rows]


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
    return float(np.nanmax(np.abs(res.normalised[k])))
