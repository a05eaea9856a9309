"""Linear intersection of image rays, and the pairs of observations of a point.

Shared by :mod:`photax.intersection` (the public :func:`photax.intersect`)
and :mod:`photax.bundle` (structure analysis and start values), so that
neither imports the other: ``intersection -> bundle -> _triangulation``.

Each measurement ``xy`` on an oriented image defines a ray from the
projection centre ``C`` along ``d = R (xn, yn, -1)`` (``R``
world_from_camera, ``(xn, yn)`` the undistorted normalised coordinates;
``docs/conventions.md``).  The linear least-squares intersection minimises
the sum of squared perpendicular distances of ``X`` to the rays::

    sum_i |(I - u_i u_i^T)(X - C_i)|^2,   u_i = d_i / |d_i|
    =>  [sum_i (I - u_i u_i^T)] X = sum_i (I - u_i u_i^T) C_i

(Hartley & Zisserman, "Multiple View Geometry", 2nd ed., sec. 12.2).

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).
"""

from __future__ import annotations

import warnings

import numpy as np

from .camera import FrameCamera
from .collinearity import ExteriorOrientation


def observation_pairs(obs_point: np.ndarray, obs_image: np.ndarray, n_img: int):
    """All pairs ``a < b`` of observations of one point, sorted by image pair.

    Args:
        obs_point, obs_image: ``(k,)`` point and image index of each observation.
        n_img: number of images.

    Returns:
        ``(pa, pb, key_id, image_a, image_b)``: ``(n_pairs,)`` observation
        indices of each pair, the index of its image pair, and ``(n_keys,)``
        the two images of each image pair.
    """
    order = np.argsort(obs_point, kind="stable")
    counts = np.bincount(obs_point)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pa, pb = [], []
    for n in np.unique(counts):
        if n < 2:
            continue
        sel = starts[counts == n]
        ia, ib = np.triu_indices(n, 1)
        pa.append(order[(sel[:, None] + ia[None, :]).ravel()])
        pb.append(order[(sel[:, None] + ib[None, :]).ravel()])
    pa = np.concatenate(pa) if pa else np.zeros(0, np.int64)
    pb = np.concatenate(pb) if pb else np.zeros(0, np.int64)
    key = obs_image[pa] * n_img + obs_image[pb]
    srt = np.argsort(key, kind="stable")
    pa, pb, key = pa[srt], pb[srt], key[srt]
    uniq, key_id = np.unique(key, return_inverse=True)
    return pa, pb, key_id, uniq // n_img, uniq % n_img


def triangulate(
    xy: np.ndarray,
    obs_image: np.ndarray,
    obs_point: np.ndarray,
    n_points: int,
    exterior: ExteriorOrientation,
    cameras: list[FrameCamera],
    min_angle_deg: float = 2.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Linear intersection of validated observations (list layout).

    Args:
        xy: ``(k, 2)`` finite image-plane coordinates (camera unit, y up).
        obs_image, obs_point: ``(k,)`` indices into ``exterior`` / the points.
        n_points: number of points ``n``.
        exterior: batched ``(m, 3)`` orientations.
        cameras: ``m`` cameras, one per image.
        min_angle_deg: warn (``RuntimeWarning``) about points whose rays meet
            at less than this: their depth error grows like ``1 / sin(angle)``.

    Returns:
        ``(points, angle_deg, n_rays, ok)``: ``(n, 3)`` ground coordinates
        (NaN where fewer than 2 rays), ``(n,)`` largest angle between two
        rays (0 there), ``(n,)`` ray counts and ``(n,)`` the mask of points
        with at least 2 rays.
    """
    ii, jj, n, m = obs_image, obs_point, n_points, len(cameras)
    r_world_from_camera = np.asarray(exterior.rotation)
    centre = np.asarray(exterior.position)
    origin = centre.mean(axis=0)
    # Ray directions in the ground frame, one camera at a time (distortion removed).
    d = np.empty((len(xy), 3))
    for c in {id(c): c for c in cameras}.values():
        sel = np.array([cameras[i] is c for i in ii], dtype=bool)
        if sel.any():
            if c.has_distortion:
                ray = np.asarray(c.ray(xy[sel]))
            else:  # numpy: no eager JAX dispatch for the common case
                xn = (xy[sel] - np.asarray(c.principal_point)[None, :]) / float(c.focal_length)
                ray = np.concatenate([xn, -np.ones((len(xn), 1))], axis=1)
            d[sel] = np.einsum("kij,kj->ki", r_world_from_camera[ii[sel]], ray)
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    c_loc = centre[ii] - origin[None, :]
    a = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    np.add.at(a, jj, proj)
    np.add.at(b, jj, np.einsum("kij,kj->ki", proj, c_loc))
    n_rays = np.bincount(jj, minlength=n)
    ok = n_rays >= 2
    pts = np.full((n, 3), np.nan)
    if ok.any():
        pts[ok] = np.linalg.solve(a[ok], b[ok][:, :, None])[:, :, 0] + origin[None, :]
    # Largest angle between two rays of each point.
    angle = np.zeros(n)
    if ok.any():
        pa, pb, *_ = observation_pairs(jj, ii, m)
        cosang = np.clip(np.sum(u[pa] * u[pb], axis=1), -1.0, 1.0)
        np.maximum.at(angle, jj[pa], np.degrees(np.arccos(cosang)))
    narrow = ok & (angle < min_angle_deg)
    if narrow.any():
        warnings.warn(
            f"{int(narrow.sum())} of {n} points are intersected by rays meeting at less than {min_angle_deg} degrees "
            f"(smallest {angle[narrow].min():.3g}): their depth is poorly determined",
            RuntimeWarning,
            stacklevel=3,
        )
    return pts, angle, n_rays, ok
