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

    Examples:
        Two images of unknown orientation (NaN) and a tie point of unknown position: each image is
        resected from the four control points it sees, then the tie point intersected; exact
        observations give the truth back:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera(focal_length=0.1)
        >>> truth = [ptx.ExteriorOrientation([x, 0.0, 1000.0], [0.0, 0.0, 0.0]) for x in (0.0, 600.0)]
        >>> points = np.array([[-200.0, -200, 0], [800, -200, 10], [800, 200, 0], [-200, 200, 30], [300, 0, 20]])
        >>> xy = np.concatenate([np.asarray(ptx.project(points, e, camera)) for e in truth])
        >>> unknown = ptx.ExteriorOrientation(np.full((2, 3), np.nan), np.full((2, 3), np.nan))
        >>> start = np.vstack([points[:4], [np.nan] * 3])
        >>> problem = ptx.BundleProblem(camera, unknown, start, [0] * 5 + [1] * 5, [0, 1, 2, 3, 4] * 2, xy,
        ...                             roles=["control"] * 4 + ["tie"])
        >>> filled = ptx.initialize_block(problem)
        >>> print(np.round(np.asarray(filled.exterior.position), 6) + 0.0, np.round(filled.points[4], 6) + 0.0)
        [[   0.    0. 1000.]
         [ 600.    0. 1000.]] [300.   0.  20.]
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
