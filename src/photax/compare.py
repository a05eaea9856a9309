"""Collinearity + DEM against plane-to-plane models on the same control points.

Every model maps ground ``(X, Y)`` (and, for collinearity, the height) to
input pixels ``(column, row)``, the direction indirect rectification needs:

* **collinearity** with the DEM: the exterior orientation by space resection
  from the GCPs (:func:`photax.resection.resect`), or given; a ground point
  ``(X, Y)`` is projected with ``Z = DEM(X, Y)``.  6 parameters.
* **polynomials** of order 1..5 (:func:`photax.polynomial.fit_polynomial`),
  ``(n+1)(n+2)`` parameters, the **projective** transform (8), the
  **thin-plate spline** (:func:`photax.polynomial.fit_tps`) and the
  **piecewise affine** map (:func:`photax.polynomial.fit_piecewise_affine`);
  the last two interpolate the GCPs (``2 n`` parameters, no redundancy, GCP
  RMSE 0: only the check points judge them).  They see
  only ``(X, Y)``: they cannot know the height, so they cannot remove
  relief displacement.  For a vertical image a point at height ``h`` above
  the datum, imaged at radial distance ``r`` from the nadir, is displaced
  radially by (Wolf & DeWitt 2014, eq. 6-11; Kraus 2007, sec. 5.1)::

      d = r h / H              (H = flying height above the datum)

  A polynomial can absorb the part of ``d`` that is a smooth function of
  ``(X, Y)`` over the control points, not hills and valleys between them.

Per model: RMSE (``sqrt(mean |v|^2)``, radial, pixels; and ground metres
through the mean ground sampling distance) at the control points and at
independent check points, parameters, redundancy ``2n - u``, condition
number of the (normalised) design / Jacobian, and a dense error map over an
output grid: ``collinearity+DEM(X, Y) - model(X, Y)`` in pixels, i.e. how
far each rectified output pixel samples the input from where the physics
says it should.  Frames: ``docs/conventions.md``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._deprecation import alias
from .camera import FrameCamera
from .collinearity import ExteriorOrientation, project_jacobian
from .dem import DEM
from .errors import CRSMismatchError
from .grid import Grid, ortho_grid
from .polynomial import (
    PolynomialModel,
    fit_piecewise_affine,
    fit_polynomial,
    fit_projective,
    fit_tps,
    n_coefficients,
)
from .rectification import OrthoModel
from .resampling import Resampling
from .rpc import RPCCamera, refine_rpc
from .sensor import GroundSensor


@dataclasses.dataclass(frozen=True)
class ModelResult:
    """One model of a :class:`ModelComparison`.

    Attributes:
        name: ``"collinearity"``, ``"polynomial 1"`` .. ``"polynomial 5"``,
            ``"projective"``, ``"thin-plate spline"`` or ``"piecewise affine"``.
        model: callable ``(..., 2)`` ground ``(X, Y)`` -> ``(..., 2)`` pixel
            ``(column, row)`` (for collinearity an
            :class:`photax.rectification.OrthoModel`, which takes Z from the DEM).
        n_params: estimated parameters (0 for a given exterior orientation;
            ``2 n`` for the interpolating thin-plate spline and piecewise affine).
        redundancy: ``2 n_gcp - n_params``.
        condition: 2-norm condition number of the normalised design matrix
            (polynomial, projective), of the normalised spline system (TPS),
            of the worst triangle's affine system (piecewise affine) or of the
            column-equilibrated Jacobian of the collinearity equations at the
            solution.
        gcp_residuals, check_residuals: ``(n, 2)`` model - observed (computed - observed,
            docs/conventions.md), pixels.
        gcp_rmse, check_rmse: ``sqrt(mean |v|^2)`` over the points where the model has a
            value (the piecewise affine has none outside the GCPs' hull), pixels (NaN without points).
        error: ``(rows, cols, 2)`` collinearity+DEM minus this model on the
            comparison grid, pixels; NaN off the image (zeros for
            collinearity itself).
    """

    name: str
    model: Callable
    n_params: int
    redundancy: int
    condition: float
    gcp_residuals: np.ndarray
    check_residuals: np.ndarray
    gcp_rmse: float
    check_rmse: float
    error: np.ndarray

    @property
    def error_magnitude(self) -> np.ndarray:
        """``(rows, cols)`` length of the error vectors, pixels."""
        return np.hypot(self.error[..., 0], self.error[..., 1])

    @property
    def error_rmse(self) -> float:
        """RMS of the error map over the cells inside the image, pixels
        (``error_rms`` is its deprecated old name)."""
        m = self.error_magnitude
        return float(np.sqrt(np.nanmean(m**2))) if np.isfinite(m).any() else math.nan

    error_rms = alias("error_rmse")

    @property
    def error_max(self) -> float:
        m = self.error_magnitude
        return float(np.nanmax(m)) if np.isfinite(m).any() else math.nan


def _rmse(v: np.ndarray) -> float:
    v2 = np.sum(v**2, axis=1)
    v2 = v2[np.isfinite(v2)]  # the piecewise affine has no value outside the GCPs' hull
    return float(np.sqrt(np.mean(v2))) if len(v2) else math.nan


@eqx.filter_jit
def _apply(model, xy):
    return model(xy)


@dataclasses.dataclass(frozen=True)
class ModelComparison:
    """Result of :func:`compare_models`.

    Attributes:
        models: the :class:`ModelResult` s, collinearity (or the refined RPC) first.
        exterior, camera, dem: the collinearity model (an RPC: ``exterior`` None, ``camera`` the RPC
            as given).
        grid: the :class:`photax.Grid` of the error maps.
        gsd: mean ground sampling distance (ground units per pixel), used to
            express pixel RMSEs in ground units.
        gcp_ground, gcp_pixel, check_ground, check_pixel: the points.
        resection: the :class:`photax.resection.ResectionResult` (``None``
            when the exterior orientation was given; an RPC's :class:`photax.rpc.RPCRefinement`).
        skipped: ``{name: reason}`` for models that could not be fitted
            (e.g. too few GCPs for an order).
        excluded: ``(n,)`` True for GCPs the resection rejected as blunders
            (data snooping): left out of every model's fit and GCP RMSE, so
            that all models see the same points.  A polynomial cannot tell
            a blunder from relief displacement; collinearity with the DEM can.
        gcp_names: the GCPs' names, when given (reports name them).

    Examples:
        The comparison of :func:`compare_models` over 300 m of relief: each model by name, the
        relief displacement a flat-terrain model ignores, and the GCP data snooping left out:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> c = ptx.compare_models(scene.gcp_ground, scene.gcp_pixel, scene.camera, scene.dem, orders=(1, 3),
        ...                        check_ground=scene.check_ground, check_pixel=scene.check_pixel)
        >>> c["polynomial 3"].name, c.skipped
        ('polynomial 3', {})
        >>> shift = c.relief_displacement()
        >>> shift.shape == c.grid.shape + (2,), bool(np.hypot(*shift.reshape(-1, 2).T).max() > 10)  # px
        (True, True)
        >>> np.flatnonzero(c.excluded).tolist() == np.flatnonzero(c.resection.outliers).tolist()
        True
        >>> c.table("text").split()[:4]
        ['model', 'params', 'redundancy', 'condition']
    """

    models: list[ModelResult]
    exterior: ExteriorOrientation | None
    camera: FrameCamera | RPCCamera
    dem: DEM
    grid: Grid
    gsd: float
    gcp_ground: np.ndarray
    gcp_pixel: np.ndarray
    check_ground: np.ndarray
    check_pixel: np.ndarray
    resection: Any = None
    skipped: dict = dataclasses.field(default_factory=dict)
    excluded: np.ndarray | None = None
    gcp_names: tuple[str, ...] | None = None

    def __getitem__(self, name: str) -> ModelResult:
        for m in self.models:
            if m.name == name:
                return m
        raise KeyError(f"no model {name!r}; have {[m.name for m in self.models]}")

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.models]

    def relief_displacement(self, datum: float = 0.0) -> np.ndarray:
        """``(rows, cols, 2)`` pixel shift caused by the terrain on the grid.

        ``pixel(X, Y, DEM(X, Y)) - pixel(X, Y, datum)`` by the collinearity
        equations (by the refined RPC for an RPC camera): the displacement a flat-terrain model ignores.  For a
        vertical image its length is ``r h / H`` (module docstring).
        """
        xy = self.grid.xy()
        z = jnp.full(xy.shape[:2] + (1,), float(datum))
        ground = jnp.concatenate([jnp.asarray(xy), z], axis=-1).reshape(-1, 3)
        reference = self.models[0].model  # collinearity, or the refined RPC: an OrthoModel
        flat = _apply(reference.sensor, ground).reshape(xy.shape)
        return np.asarray(_apply(reference, jnp.asarray(xy))) - np.asarray(flat)

    def table(self, fmt: str = "markdown") -> str:
        """The comparison as a markdown (``fmt="markdown"``) or plain text table."""
        head = [
            "model",
            "params",
            "redundancy",
            "condition",
            "GCP RMSE [px]",
            "check RMSE [px]",
            "check RMSE [m]",
            "map RMSE [px]",
            "map max [px]",
        ]
        rows = []
        for m in self.models:
            rows.append(
                [
                    m.name,
                    str(m.n_params),
                    str(m.redundancy),
                    f"{m.condition:.3g}",
                    f"{m.gcp_rmse:.3f}",
                    f"{m.check_rmse:.3f}",
                    f"{m.check_rmse * self.gsd:.3f}",
                    f"{m.error_rmse:.2f}",
                    f"{m.error_max:.2f}",
                ]
            )
        notes = [f"{k}: {v}" for k, v in self.skipped.items()]
        if self.excluded is not None and self.excluded.any():
            idx = np.flatnonzero(self.excluded)
            which = [self.gcp_names[k] for k in idx] if self.gcp_names else [f"#{k} (0-based)" for k in idx]
            notes.append(
                f"GCP {', '.join(which)} left out of every fit: rejected as a blunder by the resection's data snooping"
            )
        notes.append(
            f"{len(self.gcp_pixel)} GCPs, {len(self.check_pixel)} check points, "
            f"GSD {self.gsd:.3g} m; map = {self.models[0].name}+DEM minus model over the output grid"
        )
        if fmt == "markdown":
            lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            lines += ["| " + " | ".join(r) + " |" for r in rows]
            return "\n".join(lines + [""] + notes)
        widths = [max(len(h), *(len(r[k]) for r in rows)) for k, h in enumerate(head)]
        fmt_row = lambda r: "  ".join(c.rjust(w) if k else c.ljust(w) for k, (c, w) in enumerate(zip(r, widths)))  # noqa: E731
        return "\n".join([fmt_row(head)] + [fmt_row(r) for r in rows] + notes)

    def to_dict(self) -> dict:
        """JSON-serialisable summary (no maps)."""
        num = lambda x: None if not math.isfinite(x) else float(x)  # noqa: E731
        return {
            "gsd": self.gsd,
            "n_gcp": int(len(self.gcp_pixel)),
            "n_check": int(len(self.check_pixel)),
            "grid": {"transform": list(tuple(self.grid.transform)[:6]), "shape": list(self.grid.shape)},
            "exterior": None
            if self.exterior is None
            else {
                "position": np.asarray(self.exterior.position).tolist(),
                "angles_rad": np.asarray(self.exterior.angles).tolist(),
                "convention": self.exterior.convention,
            },
            "models": [
                {
                    "name": m.name,
                    "n_params": m.n_params,
                    "redundancy": m.redundancy,
                    "condition": num(m.condition),
                    "gcp_rmse_px": num(m.gcp_rmse),
                    "check_rmse_px": num(m.check_rmse),
                    "check_rmse_m": num(m.check_rmse * self.gsd),
                    "map_rmse_px": num(m.error_rmse),
                    "map_max_px": num(m.error_max),
                }
                for m in self.models
            ],
            "skipped": dict(self.skipped),
            "excluded": [] if self.excluded is None else np.flatnonzero(self.excluded).tolist(),
        }

    # --- rectified images --------------------------------------------------

    def rectify(
        self,
        image,
        names: Sequence[str] | None = None,
        *,
        grid: Grid | None = None,
        resampling: Resampling | str = "bilinear",
        progress: bool | str = False,
    ) -> tuple[dict[str, np.ndarray], Grid]:
        """Rectify ``image`` with each model onto one grid.

        Args:
            image: ``(..., H, W)`` the image the GCPs were measured in
                (e.g. ``(3, H, W)`` RGB).
            names: models to use (default all).
            grid: output grid; default the image footprint on the DEM at the GSD.
            progress: one bar over all models' tiles: ``True`` (labelled
                "compare") or a label (:mod:`photax.progress`).

        Returns:
            ``({name: (..., rows, cols) array}, grid)``; collinearity gives
            the orthophoto (:func:`photax.orthorectify`).
        """
        from .progress import progress_bar
        from .rectification import rectify, tile_windows

        if grid is None:
            camera = self.camera if self.exterior is not None else self.models[0].model.sensor.camera
            grid = ortho_grid(self.exterior, camera, self.dem, self.gsd, crs=self.grid.crs)
        names = self.names if names is None else list(names)
        tiles = len(list(tile_windows(grid.shape, 1024)))  # rectify's default tile
        models = {n: self[n].model for n in names}
        # The polynomials as one order: one compiled rectification kernel for all of them, not one per order.
        top = max((m.order for m in models.values() if isinstance(m, PolynomialModel)), default=0)
        models = {n: m.padded(top) if isinstance(m, PolynomialModel) else m for n, m in models.items()}
        with progress_bar(progress, tiles * len(names), desc="compare", unit="tile") as bar:
            out = {n: rectify(image, m, grid, resampling=resampling, progress=bar) for n, m in models.items()}
        return out, grid

    # --- figures (drawn by photax.plot) ------------------------------------

    def plot_error_maps(self, names: Sequence[str] | None = None, *, vmax: float | None = None, ncols: int = 3):
        """Error maps side by side on one colour scale; the matplotlib figure
        (:func:`photax.plot.comparison_error_maps`)."""
        from .plot import comparison_error_maps

        return comparison_error_maps(self, names, vmax=vmax, ncols=ncols)

    def plot_rmse(self):
        """GCP and check-point RMSE per model, grouped bars (log scale)
        (:func:`photax.plot.comparison_rmse`)."""
        from .plot import comparison_rmse

        return comparison_rmse(self)

    def plot_rectified(
        self,
        images: dict[str, np.ndarray],
        grid: Grid,
        *,
        reference: np.ndarray | None = None,
        reference_transform=None,
        ncols: int = 3,
        window=None,
        value_range=None,
    ):
        """Rectified images side by side (from :meth:`rectify`), optionally
        with a reference orthophoto (:func:`photax.plot.comparison_rectified`)."""
        from .plot import comparison_rectified

        return comparison_rectified(
            self,
            images,
            grid,
            reference=reference,
            reference_transform=reference_transform,
            ncols=ncols,
            window=window,
            value_range=value_range,
        )


_project_jacobian = jax.jit(project_jacobian)


def _collinearity_condition(exterior: ExteriorOrientation, camera: FrameCamera, ground: np.ndarray) -> float:
    """Condition of the column-equilibrated Jacobian d image / d (X, Y, Z, angles),
    coordinates reduced to the GCP centroid (as the resection sees them)."""
    origin = ground.mean(axis=0)
    local = ExteriorOrientation(exterior.position - origin, exterior.angles, exterior.convention)
    # jitted: op by op, this closed-form Jacobian took 2 s of compare_models' first call
    _, jac = _project_jacobian(jnp.asarray(ground - origin), local, camera)  # (n, 2, 9): (C, angles, X)
    j = np.asarray(jac[..., :6]).reshape(-1, 6)
    j = j / np.linalg.norm(j, axis=0, keepdims=True)
    s = np.linalg.svd(j, compute_uv=False)
    return float(s[0] / s[-1])


def _refine_condition(refinement, pixel: np.ndarray) -> float:
    """Condition of an RPC refinement's column-equilibrated design ``[1, c, r]`` (its terms) at the
    RPC's own positions of the GCPs (``pixel`` plus the raw residuals, computed - observed)."""
    terms = {"shift": [0], "shift-drift": [0, 2], "affine": [0, 1, 2]}[refinement.model]
    design = np.column_stack([np.ones(len(pixel)), pixel + refinement.raw_residuals])[:, terms]
    return float(np.linalg.cond(design / np.linalg.norm(design, axis=0)))


def _points(name: str, a, width: int) -> np.ndarray:
    p = np.asarray(a, dtype=float)
    if p.ndim != 2 or p.shape[1] != width:
        raise ValueError(f"{name} must have shape (n, {width}), got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError(f"{name} has NaN or infinite values at rows {np.flatnonzero(~np.isfinite(p).all(1)).tolist()}")
    return p


def _check_inputs(gcp_ground, gcp_pixel, check_ground, check_pixel, camera: FrameCamera, orders):
    """:func:`compare_models`' points as float arrays ``(gg, gp, cg, cp)``
    (no check points: empty), or a ValueError naming the argument."""
    gg, gp = _points("gcp_ground", gcp_ground, 3), _points("gcp_pixel", gcp_pixel, 2)
    if len(gg) != len(gp):
        raise ValueError(f"gcp_ground has {len(gg)} points but gcp_pixel has {len(gp)}")
    if (check_ground is None) != (check_pixel is None):
        raise ValueError("give both check_ground and check_pixel, or neither")
    cg = np.zeros((0, 3)) if check_ground is None else _points("check_ground", check_ground, 3)
    cp = np.zeros((0, 2)) if check_pixel is None else _points("check_pixel", check_pixel, 2)
    if len(cg) != len(cp):
        raise ValueError(f"check_ground has {len(cg)} points but check_pixel has {len(cp)}")
    if camera.image_size is None or (isinstance(camera, FrameCamera) and camera.pixel_size is None):
        raise ValueError("camera needs pixel_size and image_size (pixels are compared)")
    for k in orders:
        if not isinstance(k, (int, np.integer)) or not 1 <= k <= 5:
            raise ValueError(f"orders must be integers from 1 to 5, got {k!r}")
    return gg, gp, cg, cp


def compare_models(
    gcp_ground,
    gcp_pixel,
    camera: FrameCamera,
    dem: DEM,
    *,
    check_ground=None,
    check_pixel=None,
    orders: Sequence[int] = (1, 2, 3, 4, 5),
    projective: bool = True,
    tps: bool = True,
    piecewise_affine: bool = True,
    grid: Grid | None = None,
    exterior: ExteriorOrientation | None = None,
    gcp_names: Sequence[str] | None = None,
    refine: str = "shift",
) -> ModelComparison:
    """Fit collinearity and plane-to-plane models to the same GCPs and compare.

    Args:
        gcp_ground: ``(n, 3)`` control points' ground ``(X, Y, Z)``.
        gcp_pixel: ``(n, 2)`` their pixel ``(column, row)`` in the image.
        camera: interior orientation with a pixel grid (``image_size``).
        dem: terrain heights, same CRS and datum as the ground points.
        check_ground, check_pixel: ``(m, 3)`` / ``(m, 2)`` independent check
            points, never used in a fit (both or neither).
        orders: polynomial orders (1..5); an order needing more GCPs than
            given is skipped and listed in ``skipped``.
        projective: also fit the 8-parameter projective transform.
        tps: also fit the interpolating thin-plate spline (3+ GCPs).
        piecewise_affine: also fit the piecewise-affine (Delaunay) map (3+ GCPs;
            NaN outside the GCPs' hull, so its check rmse is over the check points
            inside it, see :class:`photax.polynomial.PiecewiseAffineModel`).
        grid: grid of the error maps; default the image footprint on the
            DEM at 4 x the mean GSD.
        exterior: use this exterior orientation instead of resecting.
        gcp_names: ``(n,)`` names of the GCPs, for the reports.
        refine: with an RPC camera, its refinement on the GCPs (:func:`photax.rpc.refine_rpc`).

    A satellite image: ``camera`` an :class:`photax.rpc.RPCCamera`, the ground points and the DEM
    in the DEM's (projected) CRS, heights ellipsoidal. The sensor models are then ``"RPC + shift"``
    (the RPC refined on the GCPs: the reference of the error maps, in collinearity's place; its
    refinement in ``resection``) and ``"RPC"`` (as delivered, 0 parameters), beside the same
    polynomials and maps: the course's "polynomial correction of satellite images" against the
    sensor model.

    GCPs that the resection rejects as blunders (its data snooping) are left
    out of every model's fit (:attr:`ModelComparison.excluded`).

    Returns:
        :class:`ModelComparison`.

    Raises:
        ValueError: bad shapes or values, a camera without a pixel grid.
        photax.ConvergenceError: the resection failed.

    Examples:
        Over 300 m of relief only collinearity with the DEM fits the check points to the 0.3 px noise;
        plane-to-plane models leave the relief displacement:

        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> c = ptx.compare_models(scene.gcp_ground, scene.gcp_pixel, scene.camera, scene.dem, orders=(1, 3),
        ...                        check_ground=scene.check_ground, check_pixel=scene.check_pixel)
        >>> c.names
        ['collinearity', 'polynomial 1', 'polynomial 3', 'projective', 'thin-plate spline', 'piecewise affine']
        >>> min(c.models, key=lambda m: m.check_rmse).name
        'collinearity'
        >>> bool(c["collinearity"].check_rmse < 3 * scene.noise_px < c["polynomial 3"].check_rmse)
        True
    """
    # Over 80 lines only by its docstring; the body is ~55 lines, one step
    # (fit, evaluate on the grid and the points) per model.
    from .resection import resect

    gg, gp, cg, cp = _check_inputs(gcp_ground, gcp_pixel, check_ground, check_pixel, camera, orders)
    n = len(gg)

    resection = None
    used = np.ones(n, bool)
    rpc = isinstance(camera, RPCCamera)
    if rpc:  # the refined RPC plays collinearity's part
        if exterior is not None:
            raise ValueError("exterior: an RPC camera carries its own orientation; leave it out")
        if dem.crs is None:
            raise CRSMismatchError("dem: an RPC camera needs the DEM's CRS (the ground points' map CRS)")
        sensor = GroundSensor(camera, dem.crs)
        llh = lambda g: np.column_stack([np.asarray(sensor.to_lonlat(g[:, :2])), g[:, 2]])  # noqa: E731
        resection = refine_rpc(camera, llh(gg), gp, refine, names=gcp_names)
        reference_camera = resection.camera
    else:
        if exterior is None:
            resection = resect(camera.pixel_to_image(gp), gg, camera)
            exterior = resection.exterior
            used = ~np.asarray(resection.outliers, bool)  # every model fits the same, blunder-free points
        reference_camera = camera
    n_used = int(used.sum())
    crs = dem.crs if rpc else None
    footprint = ortho_grid(exterior, reference_camera, dem, crs=crs)
    gsd = abs(float(footprint.transform.a))
    grid = ortho_grid(exterior, reference_camera, dem, 4 * gsd, crs=crs) if grid is None else grid
    if not isinstance(grid, Grid):
        raise ValueError(f"grid must be a photax Grid, got {type(grid).__name__}")
    xy = jnp.asarray(grid.xy())
    w, h = camera.image_size

    # One model evaluation per model on grid + GCPs + check points: one compilation each.
    size = xy.shape[0] * xy.shape[1]
    flat_xy = jnp.concatenate([xy.reshape(-1, 2), jnp.asarray(gg[:, :2]), jnp.asarray(cg[:, :2])])
    results = []

    def add(name, model, u, cond, values):
        on_grid, at_gcp, at_check = np.split(values, [size, size + n])
        vg, vc = at_gcp - gp, at_check - cp  # computed - observed
        err = ref - on_grid.reshape(ref.shape)
        results.append(
            ModelResult(name, model, u, 2 * n_used - u, float(cond), vg, vc, _rmse(vg[used]), _rmse(vc), err)
        )

    # Collinearity (the refined RPC) with the DEM is the reference mapping of the error maps;
    # at GCPs and check points it uses their own surveyed Z, not the DEM's.
    ortho = OrthoModel(exterior, reference_camera, dem, crs)
    values = np.array(_apply(ortho, flat_xy))
    ref = values[:size].reshape(xy.shape)
    inside = (ref[..., 0] >= -0.5) & (ref[..., 0] <= w - 0.5) & (ref[..., 1] >= -0.5) & (ref[..., 1] <= h - 0.5)
    ref = np.where(inside[..., None], ref, np.nan)
    points = jnp.asarray(np.concatenate([gg, cg]))
    values[size:] = np.asarray(_apply(ortho.sensor, points))
    if rpc:
        add(f"RPC + {refine}", ortho, resection.covariance.shape[0], _refine_condition(resection, gp), values)
        raw = OrthoModel(None, camera, dem, crs)
        values = np.array(_apply(raw, flat_xy))
        values[size:] = np.asarray(_apply(raw.sensor, points))
        add("RPC", raw, 0, math.nan, values)
    else:
        cond = math.nan if resection is None else _collinearity_condition(exterior, camera, gg[used])
        add("collinearity", ortho, 0 if resection is None else 6, cond, values)

    skipped = {}
    for k in orders:
        u = n_coefficients(int(k))
        name = f"polynomial {k}"
        if n_used < u:
            skipped[name] = f"needs at least {u} GCPs, have {n_used}"
            continue
        model = fit_polynomial(gg[used, :2], gp[used], int(k))
        add(name, model, 2 * u, model.condition, np.asarray(_apply(model, flat_xy)))
    if projective:
        if n_used < 4:
            skipped["projective"] = f"needs at least 4 GCPs, have {n_used}"
        else:
            model = fit_projective(gg[used, :2], gp[used])
            add("projective", model, 8, model.condition, np.asarray(_apply(model, flat_xy)))
    for name, wanted, fit in (
        ("thin-plate spline", tps, fit_tps),
        ("piecewise affine", piecewise_affine, fit_piecewise_affine),
    ):
        if not wanted:
            continue
        if n_used < 3:
            skipped[name] = f"needs at least 3 GCPs, have {n_used}"
            continue
        model = fit(gg[used, :2], gp[used])
        add(name, model, 2 * n_used, model.condition, np.asarray(_apply(model, flat_xy)))
    names = None if gcp_names is None else tuple(str(x) for x in gcp_names)
    if names is not None and len(names) != n:
        raise ValueError(f"gcp_names has {len(names)} names for {n} GCPs")
    return ModelComparison(results, exterior, camera, dem, grid, gsd, gg, gp, cg, cp, resection, skipped, ~used, names)
