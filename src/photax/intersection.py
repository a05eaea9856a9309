"""Forward intersection (space intersection, triangulation) of image rays.

The linear least-squares intersection of the rays (formula and sources in
:mod:`photax._triangulation`; Wolf, DeWitt & Wilkinson, "Elements of
Photogrammetry", ch. 11 for space intersection).  With ``refine=True`` the
points are then adjusted on their image residuals (Gauss–Newton, images
fixed), which is the maximum-likelihood estimate under Gaussian image noise
and gives each point's standard deviations.

Rays that meet at a small angle give a poorly determined point (the depth
error grows like ``1 / sin(angle)``): such points are reported with a
warning.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._float64 import as_float64
from ._triangulation import triangulate
from .bundle import BundleProblem, bundle_adjust
from .camera import FrameCamera
from .collinearity import ExteriorOrientation, project, stack_exteriors
from .errors import RESULTS, ConvergenceError


@dataclasses.dataclass(frozen=True)
class Intersection:
    """Full output of :func:`intersect` (``full_output=True``).

    Attributes:
        points: ``(n, 3)`` ground coordinates (NaN where fewer than 2 rays).
        angle_deg: ``(n,)`` largest angle between two rays of each point.
        n_rays: ``(n,)`` number of rays.
        std: ``(n, 3)`` standard deviations (``refine=True`` only, else None).
        residual_rmse: ``(n,)`` RMS image residual of each point (camera
            unit); ``residual_rms`` is its old name.
        result: the :class:`photax.RESULTS` code: the refinement's (its
            bundle adjustment's) outcome, ``successful`` without
            ``refine``; ``converged`` and ``message`` say the same in words.
    """

    points: np.ndarray
    angle_deg: np.ndarray
    n_rays: np.ndarray
    std: np.ndarray | None
    residual_rmse: np.ndarray
    result: RESULTS = RESULTS.successful
    message: str = "converged"

    @property
    def converged(self) -> bool:
        return self.result == RESULTS.successful

    @property
    def residual_rms(self) -> np.ndarray:
        """Deprecated alias of :attr:`residual_rmse` (one word for RMS errors across photax)."""
        return self.residual_rmse


def intersect(
    image_xy,
    exterior,
    cameras,
    *,
    obs_image=None,
    obs_point=None,
    n_points: int | None = None,
    sigma=1.0,
    refine: bool = False,
    min_angle_deg: float = 2.0,
    full_output: bool = False,
    throw: bool = False,
):
    """Intersect rays from several oriented images.

    Two input layouts:

    * **table**: ``image_xy`` ``(m, n, 2)``, point ``j`` as measured on
      image ``i`` (NaN where not measured);
    * **list**: ``image_xy`` ``(k, 2)`` with ``obs_image`` and ``obs_point``
      ``(k,)`` integer indices (and ``n_points``, default
      ``max(obs_point) + 1``).

    Args:
        image_xy: image-plane coordinates (x right, y up, camera unit).
        exterior: ``m`` orientations (batched :class:`ExteriorOrientation` or
            a list).
        cameras: one :class:`FrameCamera` for all images, or ``m``.
        sigma: image measurement std (scalar or per observation), for the
            refinement's weights and precision.
        refine: adjust the points on their image residuals after the linear
            solution (needs at least 2 rays per point).
        min_angle_deg: warn about points whose rays meet at less than this.
        full_output: return an :class:`Intersection` instead of the points.
        throw: raise :class:`photax.ConvergenceError` when the refinement
            fails; default False (many points: the result says it failed,
            the points are the refinement's last finite values;
            docs/architecture.md "Outcomes and throw").

    Returns:
        ``(n, 3)`` ground coordinates, NaN for points with fewer than 2 rays,
        or an :class:`Intersection`.

    Examples:
        The check points of a synthetic frame seen from two camera stations 1.5 km apart, exactly
        (the table layout: image ``i``'s coordinates of point ``j`` at ``[i, j]``):

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> second = ptx.ExteriorOrientation(np.asarray(scene.exterior.position) + [1500.0, 0.0, 0.0],
        ...                                  scene.exterior.angles)
        >>> xy = np.stack([ptx.project(scene.check_ground, e, scene.camera)
        ...                for e in (scene.exterior, second)])
        >>> points = ptx.intersect(xy, [scene.exterior, second], scene.camera)
        >>> points.shape, bool(np.abs(points - scene.check_ground).max() < 1e-6)  # metres
        ((60, 3), True)
    """
    eo = stack_exteriors(exterior)
    m = eo.position.shape[0]
    cams = [cameras] * m if isinstance(cameras, FrameCamera) else list(cameras)
    if len(cams) != m:
        raise ValueError(f"cameras must be one FrameCamera or {m} (one per image), got {len(cams)}")
    xy, ii, jj, n = _observations(image_xy, m, obs_image, obs_point, n_points)
    pts, angle, n_rays, ok = triangulate(xy, ii, jj, n, eo, cams, min_angle_deg)
    std, code, message = None, RESULTS.successful, "converged"
    if refine and ok.any():
        pts, std, code, message = _refine(pts, ok, xy, ii, jj, eo, cams, sigma)
        if throw and code != RESULTS.successful:
            raise ConvergenceError(f"intersection refinement failed: {message}")
    if not full_output:
        return pts
    res = np.zeros(n)
    for i in np.unique(ii):
        sel = ii == i
        e = ExteriorOrientation(eo.position[i], eo.angles[i], eo.convention)
        r = np.asarray(project(np.nan_to_num(pts[jj[sel]]), e, cams[i])) - xy[sel]
        np.add.at(res, jj[sel], np.sum(r * r, axis=1))
    rmse = np.where(ok, np.sqrt(res / np.maximum(n_rays, 1) / 2.0), np.nan)
    return Intersection(pts, np.where(ok, angle, np.nan), n_rays, std, rmse, code, message)


def _observations(image_xy, m: int, obs_image, obs_point, n_points):
    """:func:`intersect`'s two input layouts as one list: ``(xy (k, 2),
    image index (k,), point index (k,), number of points)``, or a
    ValueError naming the argument."""
    xy = as_float64(image_xy, "image_xy")
    if obs_image is None and obs_point is None:
        if xy.ndim != 3 or xy.shape[0] != m or xy.shape[2] != 2:
            raise ValueError(f"image_xy must be (m, n, 2) = ({m}, n, 2) in the table layout, got {xy.shape}")
        n = xy.shape[1]
        ii, jj = np.nonzero(np.all(np.isfinite(xy), axis=2))
        xy = xy[ii, jj]
    else:
        if obs_image is None or obs_point is None:
            raise ValueError("give both obs_image and obs_point (list layout), or neither (table layout)")
        ii, jj = np.asarray(obs_image), np.asarray(obs_point)
        if xy.ndim != 2 or xy.shape[1] != 2 or ii.shape != (len(xy),) or jj.shape != (len(xy),):
            raise ValueError(
                f"list layout: image_xy (k, 2), obs_image and obs_point (k,); got {xy.shape}, {ii.shape}, {jj.shape}"
            )
        if len(ii) and (ii.min() < 0 or ii.max() >= m or jj.min() < 0):
            raise ValueError(f"obs_image must be in [0, {m}) and obs_point >= 0")
        n = int(n_points if n_points is not None else (jj.max() + 1 if len(jj) else 0))
        if len(jj) and jj.max() >= n:
            raise ValueError(f"obs_point has index {jj.max()} >= n_points = {n}")
        if not np.all(np.isfinite(xy)):
            raise ValueError("image_xy has non-finite values in the list layout")
    return xy, ii, jj, n


def _refine(pts, ok, xy, ii, jj, eo, cams, sigma):
    """Adjust points on image residuals with every image fixed (a bundle
    adjustment whose reduced camera system is empty): ``(points, std,
    RESULTS code, message)``."""
    keep = ok[jj]
    new_id = np.cumsum(ok) - 1
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (len(xy),))[keep]
    uniq = list({id(c): c for c in cams}.values())
    image_camera = np.array([next(k for k, c in enumerate(uniq) if c is cams[i]) for i in range(len(cams))])
    problem = BundleProblem(
        uniq, eo, pts[ok], ii[keep], new_id[jj[keep]], xy[keep], obs_sigma=sig, image_camera=image_camera,
        fixed_exterior=np.ones(len(cams), dtype=bool),
    )  # fmt: skip
    result = bundle_adjust(problem, throw=False)
    out = pts.copy()
    out[ok] = result.points
    std = np.full(pts.shape, np.nan)
    if result.point_std is not None:
        # Weights are absolute (sigma given): no rescaling by sigma0 of a few rays.
        std[ok] = result.point_std / (result.sigma0 if np.isfinite(result.sigma0) and result.sigma0 > 0 else 1.0)
    return out, std, result.result, result.message
