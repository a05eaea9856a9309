"""Start values of a block: resection, then forward intersection."""

from __future__ import annotations

import numpy as np

from .._triangulation import triangulate
from ..collinearity import ExteriorOrientation
from ._problem import BundleProblem


def _needs_init(problem: BundleProblem) -> bool:
    eo = np.concatenate([np.asarray(problem.exterior.position), np.asarray(problem.exterior.angles)], axis=1)
    return bool(np.any(~np.isfinite(eo)) or np.any(~np.isfinite(problem.points)))


def initialize_block(problem: BundleProblem, *, min_control: int = 4) -> BundleProblem:
    """Start values for a block: resection, then forward intersection.

    Images whose orientation is NaN are resected (:func:`photax.resect`)
    from the control points they see (at least ``min_control``); then tie
    and check points whose coordinates are NaN are intersected
    (:func:`photax.intersect`) from all oriented images that see them.
    Check points are never used as control here.
    """
    pos = np.array(problem.exterior.position)
    ang = np.array(problem.exterior.angles)
    conv = problem.exterior.convention
    pts = problem.points.copy()
    ctrl = problem.roles == "control"
    todo = ~np.all(np.isfinite(np.concatenate([pos, ang], axis=1)), axis=1)
    if np.any(todo):
        from ..resection import resect

        for i in np.flatnonzero(todo):
            sel = (problem.obs_image == i) & ctrl[problem.obs_point]
            if sel.sum() < min_control:
                raise ValueError(
                    f"{problem.image_names[i]}: no start orientation and only {int(sel.sum())} control points "
                    f"(resection needs {min_control}); give its exterior orientation"
                )
            cam = problem.cameras[problem.image_camera[i]]
            res = resect(problem.obs_xy[sel], pts[problem.obs_point[sel]], cam, sigma=problem.obs_sigma[sel, 0],
                         convention=conv, throw=True)  # fmt: skip
            ext = res.exterior
            pos[i], ang[i] = np.asarray(ext.position), np.asarray(ext.angles)
    exterior = ExteriorOrientation(pos, ang, conv)
    missing = ~np.all(np.isfinite(pts), axis=1) & ~ctrl
    if np.any(missing):
        # The linear intersection of photax.intersect (without its refinement,
        # which is a bundle adjustment itself).
        sel = missing[problem.obs_point]
        new_index = np.cumsum(missing) - 1
        cams = [problem.cameras[c] for c in problem.image_camera]
        xyz, *_ = triangulate(
            problem.obs_xy[sel], problem.obs_image[sel], new_index[problem.obs_point[sel]], int(missing.sum()),
            exterior, cams,
        )  # fmt: skip
        pts[missing] = xyz
    return problem.replace(exterior=exterior, points=pts)
