"""Forward intersection against the closed form of two rays, OpenCV's
triangulatePoints and a per-point scipy least-squares refinement."""

import cv2
import jax
import numpy as np
import pytest
import scipy.optimize

import photax as ptx
from photax.camera import opencv_extrinsics


def _two_images():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-100, 100, 12), rng.uniform(-80, 80, 12), rng.uniform(0, 30, 12)])
    ground += np.array([500_000.0, 4_000_000.0, 50.0])
    centre = ground.mean(0)
    eos = [
        ptx.look_at(centre + np.array([-60.0, 5.0, 400.0]), centre),
        ptx.look_at(centre + np.array([70.0, -8.0, 410.0]), centre),
    ]
    cam = ptx.FrameCamera.from_pixels(2500.0, (3000, 2000))
    xy = np.stack([np.asarray(ptx.project(ground, e, cam)) for e in eos])
    return ground, eos, cam, xy


def _closest_point_of_two_rays(c1, d1, c2, d2):
    """Midpoint of the common perpendicular (the textbook closed form)."""
    w0 = c1 - c2
    a, b, c = d1 @ d1, d1 @ d2, d2 @ d2
    d, e = d1 @ w0, d2 @ w0
    s = (b * e - c * d) / (a * c - b * b)
    t = (a * e - b * d) / (a * c - b * b)
    return 0.5 * (c1 + s * d1 + c2 + t * d2)


def test_two_rays_closed_form_with_noise():
    ground, eos, cam, xy = _two_images()
    xy = xy + np.random.default_rng(1).normal(0, 2.0, xy.shape)  # rays no longer meet
    pts = ptx.intersect(xy, eos, cam)
    for j in range(len(ground)):
        rays = [np.asarray(e.rotation) @ np.r_[xy[i, j] / 2500.0, -1.0] for i, e in enumerate(eos)]
        ref = _closest_point_of_two_rays(np.asarray(eos[0].position), rays[0], np.asarray(eos[1].position), rays[1])
        np.testing.assert_allclose(pts[j], ref, atol=1e-6)


def test_noise_free_matches_opencv_triangulate():
    ground, eos, cam, xy = _two_images()
    K = np.array([[2500.0, 0, 1499.5], [0, 2500.0, 999.5], [0, 0, 1]])
    origin = ground.mean(0)
    proj = []
    for e in eos:
        r, t = opencv_extrinsics(e.rotation, np.asarray(e.position) - origin)  # OpenCV camera: y down, z forward
        proj.append(K @ np.hstack([r, t[:, None]]))
    px = [np.asarray(cam.image_to_pixel(xy[i])).T for i in range(2)]
    h = cv2.triangulatePoints(proj[0], proj[1], px[0], px[1])
    ref = (h[:3] / h[3]).T + origin
    pts = ptx.intersect(xy, eos, cam)
    np.testing.assert_allclose(pts, ref, atol=1e-5)
    np.testing.assert_allclose(pts, ground, atol=1e-6)


def test_refined_points_match_scipy_least_squares():
    ground, eos, cam, xy = _two_images()
    eos.append(ptx.look_at(ground.mean(0) + np.array([0.0, 90.0, 380.0]), ground.mean(0)))
    xy = np.concatenate([xy, np.asarray(ptx.project(ground, eos[2], cam))[None]])
    xy = xy + np.random.default_rng(3).normal(0, 1.0, xy.shape)
    xy[2, :4] = np.nan  # some points on two images only
    out = ptx.intersect(xy, eos, cam, refine=True, full_output=True)
    # One compiled projection for scipy's many evaluations (op by op, this
    # test took minutes on a busy machine).
    project = jax.jit(lambda X, eo: ptx.project(X, eo, cam))
    for j in range(len(ground)):
        seen = [i for i in range(3) if np.isfinite(xy[i, j, 0])]

        def res(X):
            return np.concatenate([np.asarray(project(X[None], eos[i]))[0] - xy[i, j] for i in seen])

        fit = scipy.optimize.least_squares(res, ground[j] + 1.0, xtol=1e-14, ftol=1e-14)
        np.testing.assert_allclose(out.points[j], fit.x, atol=1e-5)
        # RMS image residual per coordinate, from scipy's residual vector
        np.testing.assert_allclose(out.residual_rmse[j], np.sqrt(np.mean(fit.fun**2)), rtol=1e-6)
    assert out.n_rays.tolist() == [2] * 4 + [3] * 8
    assert np.all(out.std > 0) and np.all(out.angle_deg > 10)
    assert out.residual_rms is out.residual_rmse  # the old name still works
    assert (
        out.result == ptx.RESULTS.successful and out.converged and "tolerance" in out.message
    )  # the refinement's stop


def test_list_layout_single_ray_and_narrow_angle():
    ground, eos, cam, xy = _two_images()
    k = len(ground)
    obs_xy = np.concatenate([xy[0], xy[1, :-1]])
    img = np.r_[np.zeros(k, int), np.ones(k - 1, int)]
    pt = np.r_[np.arange(k), np.arange(k - 1)]
    pts = ptx.intersect(obs_xy, eos, cam, obs_image=img, obs_point=pt)
    np.testing.assert_allclose(pts[:-1], ground[:-1], atol=1e-6)
    assert np.all(np.isnan(pts[-1]))  # one ray: not intersected
    near = [eos[0], ptx.ExteriorOrientation(np.asarray(eos[0].position) + np.array([1.0, 0, 0]), eos[0].angles,
                                            eos[0].convention)]  # fmt: skip
    xy2 = np.stack([np.asarray(ptx.project(ground, e, cam)) for e in near])
    with pytest.warns(RuntimeWarning, match="poorly determined"):
        ptx.intersect(xy2, near, cam)
    with pytest.raises(ValueError, match="image_xy"):
        ptx.intersect(xy[0], eos, cam)
