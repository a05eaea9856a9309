"""The distortion models of :mod:`photax.camera` beyond Brown (issue 22): OpenCV's full
model (rational k4-k6, thin prism s1-s4) and the Kannala-Brandt fisheye.

References: ``cv2.projectPoints`` with OpenCV's 14-term distortion vector and
``cv2.fisheye.projectPoints`` (projection), ``jax.jacfwd`` (the closed-form
Jacobians), the forward model (undistortion round trip), and known synthetic truth
(resection, self-calibration, orthorectification).
"""

from __future__ import annotations

import warnings

import cv2
import jax
import numpy as np
import pytest

import photax as ptx
from photax.camera import (
    DISTORTION_MODELS,
    distort,
    distortion_jacobian,
    from_opencv_extrinsics,
    intrinsics_jacobian,
    undistort,
)
from photax.grid import ortho_grid
from photax.scene import synthetic_block

W, H = 1200, 900
FX, FY, CX, CY = 800.0, 812.0, 611.3, 441.7
# OpenCV's order: k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tauX tauY (tilt 0: photax has none)
CV14 = np.array([-0.21, 0.08, 1.3e-3, -8e-4, -0.012, 0.11, -0.03, 0.009, 2e-3, -1e-3, -1.5e-3, 6e-4, 0.0, 0.0])
CV_FISHEYE = np.array([0.043, -0.012, 0.0041, -0.0009])


def photax_opencv(cv14):
    """photax's 12 coefficients from OpenCV's vector: reordered, p1, s3, s4 negated (y up)."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = cv14[:12]
    return np.array([k1, k2, k3, -p1, p2, k4, k5, k6, s1, s2, -s3, -s4])


def camera(model, distortion):
    """A photax camera equal to OpenCV's K (fx != fy: the aspect in the pixel height)."""
    aspect = FX / FY
    pp = (CX - (W - 1) / 2, ((H - 1) / 2 - CY) * aspect)
    return ptx.FrameCamera(FX, pp, distortion, pixel_size=(1.0, aspect), image_size=(W, H), model=model)


def scene(n=400, max_angle_deg=60.0, seed=0):
    """Ground points seen within ``max_angle_deg`` of the axis of a tilted camera, and the
    camera's OpenCV extrinsics."""
    rng = np.random.default_rng(seed)
    rvec, tvec = np.array([0.3, -0.2, 0.1]), np.array([1.5, -2.0, 30.0])
    tan = np.tan(np.radians(rng.uniform(0, max_angle_deg, n)))
    az = rng.uniform(0, 2 * np.pi, n)
    depth = rng.uniform(10, 50, n)
    cam_pts = np.c_[tan * np.cos(az), tan * np.sin(az), np.ones(n)] * depth[:, None]  # OpenCV camera frame
    r = cv2.Rodrigues(rvec)[0]
    ground = (cam_pts - tvec) @ r  # X = R^T (x - t)
    rot, centre = from_opencv_extrinsics(r, tvec)
    return ground, ptx.ExteriorOrientation.from_rotation(centre, rot, "omega-phi-kappa"), rvec, tvec


def _pixels(cam, ground, eo):
    return np.asarray(cam.image_to_pixel(ptx.project(ground, eo, cam)))


def test_opencv_full_model_projects_as_cv2_project_points():
    ground, eo, rvec, tvec = scene(max_angle_deg=40.0)  # the rational model folds further out
    k = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    ref = cv2.projectPoints(ground, rvec, tvec, k, CV14)[0][:, 0]
    ours = _pixels(camera("opencv", photax_opencv(CV14)), ground, eo)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)
    assert np.ptp(ref[:, 0]) > 600  # wide coverage of the frame
    # and each new term matters: without the thin prism the pixels move
    no_prism = photax_opencv(np.r_[CV14[:8], np.zeros(6)])
    assert np.abs(_pixels(camera("opencv", no_prism), ground, eo) - ref).max() > 0.5


def test_fisheye_projects_as_cv2_fisheye_project_points():
    ground, eo, rvec, tvec = scene(max_angle_deg=85.0)
    k = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    ref = cv2.fisheye.projectPoints(ground[:, None, :], rvec, tvec, k, CV_FISHEYE)[0][:, 0]
    ours = _pixels(camera("fisheye", CV_FISHEYE), ground, eo)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)
    # a point on the axis (the closed form's 0/0: its Taylor series)
    on_axis = -(tvec @ cv2.Rodrigues(rvec)[0])[None] + cv2.Rodrigues(rvec)[0][2] * 20.0
    ref0 = cv2.fisheye.projectPoints(on_axis[:, None, :], rvec, tvec, k, CV_FISHEYE)[0][:, 0]
    np.testing.assert_allclose(_pixels(camera("fisheye", CV_FISHEYE), on_axis, eo), ref0, rtol=0, atol=1e-9)


MODELS = {
    "brown": np.array([-0.2, 0.05, -0.01, 1e-3, -2e-3]),
    "opencv": photax_opencv(CV14),
    "fisheye": CV_FISHEYE,
}


@pytest.mark.parametrize("model", sorted(MODELS))
def test_closed_form_jacobians_equal_jacfwd(model):
    d = MODELS[model]
    rng = np.random.default_rng(1)
    xn = np.r_[rng.uniform(-0.7, 0.7, (60, 2)), [[0.0, 0.0], [3e-4, -2e-4], [1.2e-3, 0.0]]]  # near the axis too
    jd = jax.vmap(jax.jacfwd(lambda p: distort(p, d)))(xn)
    np.testing.assert_allclose(np.asarray(distortion_jacobian(xn, d)), np.asarray(jd), rtol=0, atol=1e-12)
    k = np.r_[1.7, 0.1, -0.2, d]
    ji = jax.vmap(lambda p: jax.jacfwd(lambda k: k[1:3] + k[0] * distort(p, k[3:]))(k))(xn)
    ours = np.asarray(intrinsics_jacobian(xn, k[0], d))
    assert ours.shape == (len(xn), 2, 3 + len(DISTORTION_MODELS[model]))
    np.testing.assert_allclose(ours, np.asarray(ji), rtol=0, atol=1e-12)
    # the collinearity Jacobian (resection, bundle adjustment, uncertainty) with this camera
    cam = camera(model, d)
    ground, eo, _, _ = scene(n=30, max_angle_deg=35.0)
    _, jac = ptx.collinearity.project_jacobian(ground, eo, cam)

    def f(params):
        e = ptx.ExteriorOrientation(params[:3], params[3:6], eo.convention)
        return ptx.project(params[6:].reshape(-1, 3), e, cam)

    p = np.r_[np.asarray(eo.position), np.asarray(eo.angles), ground.ravel()]
    full = np.asarray(jax.jacfwd(f)(p))  # (n, 2, 6 + 3n)
    n = len(ground)
    np.testing.assert_allclose(np.asarray(jac[:, :, :6]), full[:, :, :6], rtol=1e-9, atol=1e-9)
    for i in range(n):
        np.testing.assert_allclose(np.asarray(jac[i, :, 6:]), full[i, :, 6 + 3 * i : 9 + 3 * i], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("model", sorted(MODELS))
def test_undistortion_round_trip(model):
    """pixel -> ray -> pixel to 1e-6 px over the whole frame (the ray is Newton's inverse)."""
    cam = camera(model, MODELS[model])
    cols, rows = np.meshgrid(np.linspace(0, W - 1, 41), np.linspace(0, H - 1, 31))
    pix = np.c_[cols.ravel(), rows.ravel()]
    ray = np.asarray(cam.ray(cam.pixel_to_image(pix)))
    assert np.all(np.isfinite(ray))
    back = np.asarray(cam.image_to_pixel(cam.project(ray)))
    np.testing.assert_allclose(back, pix, rtol=0, atol=1e-6)


def test_undistortion_agrees_with_cv2_and_refuses_past_the_fold():
    cam = camera("fisheye", CV_FISHEYE)
    pix = np.random.default_rng(2).uniform([0, 0], [W - 1, H - 1], (200, 2))
    k = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    ref = cv2.fisheye.undistortPoints(pix[:, None, :], k, CV_FISHEYE)[:, 0]
    xn = np.asarray(cam.normalised(cam.pixel_to_image(pix)))
    np.testing.assert_allclose(xn * [1, -1], ref, rtol=0, atol=1e-8)  # OpenCV's y down
    # Brown with a strong barrel: past the radius where D folds back, no ray maps one to one.
    d = np.array([-0.5, 0.0, 0.0, 0.0, 0.0])  # r_d = r (1 - 0.5 r^2) peaks at r = 0.8165, r_d = 0.5443
    xn = undistort(np.array([[0.5, 0.0], [0.6, 0.0], [0.0, -0.56]]), d)
    assert np.all(np.isfinite(xn[0])) and np.all(np.isnan(xn[1:]))
    np.testing.assert_allclose(np.asarray(distort(xn[:1], d)), [[0.5, 0.0]], rtol=0, atol=1e-12)


def test_model_checks():
    with pytest.raises(ValueError, match=r"\(k1, k2, k3, k4\) for the fisheye model"):
        ptx.FrameCamera(1.0, distortion=np.zeros(5), model="fisheye")
    with pytest.raises(ValueError, match="for the brown model"):
        ptx.FrameCamera(1.0, distortion=np.zeros(12))  # never silently another model
    with pytest.raises(ValueError, match="model must be one of"):
        ptx.FrameCamera(1.0, model="kannala")
    cam = ptx.FrameCamera.from_pixels(900.0, (W, H), model="opencv")
    assert cam.model == "opencv" and cam.distortion.shape == (12,)
    assert cam.intrinsic_names[3:] == DISTORTION_MODELS["opencv"]
    assert ptx.FrameCamera(1.0).model == "brown"


@pytest.mark.parametrize("model", ["opencv", "fisheye"])
def test_resection_with_the_new_models(model):
    """An image of a known camera resected from 12 control points: the orientation is the truth."""
    cam = camera(model, MODELS[model])
    ground, eo, _, _ = scene(n=12, max_angle_deg=50.0 if model == "fisheye" else 35.0, seed=3)
    xy = np.asarray(ptx.project(ground, eo, cam))
    res = ptx.resect(xy, ground, cam, convention="omega-phi-kappa", robust=False)  # compiles less
    np.testing.assert_allclose(np.asarray(res.exterior.position), np.asarray(eo.position), rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(res.exterior.rotation), np.asarray(eo.rotation), rtol=0, atol=1e-9)


def _self_calibrate(model, truth_d, free):
    problem, truth = synthetic_block(5, noise_px=0.0, relief=250.0, tilt_deg=8.0, n_control=8, n_tie=80)
    true_cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000), distortion=truth_d, model=model)
    obs = np.empty_like(problem.obs_xy)
    for i in range(problem.n_images):
        sel = problem.obs_image == i
        eo = ptx.ExteriorOrientation(truth.exterior.position[i], truth.exterior.angles[i], truth.exterior.convention)
        obs[sel] = np.asarray(ptx.project(truth.points[problem.obs_point[sel]], eo, true_cam))
    start = ptx.FrameCamera.from_pixels(2950.0, (4000, 3000), model=model)  # 1.7 % off, no distortion
    problem = problem.replace(cameras=[start], obs_xy=obs, free_intrinsics=free)
    assert problem.intrinsic_names == true_cam.intrinsic_names
    return ptx.bundle_adjust(problem), truth, problem


@pytest.mark.parametrize(
    "model,truth_d,free",
    [
        (
            "opencv",
            np.r_[-0.04, 0.0, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0, 1e-3, 0.0, -8e-4, 0.0],
            ("f", "k1", "k4", "s1", "s3"),
        ),
        ("fisheye", np.r_[0.03, -0.01, 0.0, 0.0], ("f", "x0", "y0", "k1", "k2")),
    ],
)
def test_self_calibration_recovers_a_subset(model, truth_d, free):
    res, truth, problem = _self_calibrate(model, truth_d, free)
    cam = res.cameras[0]
    assert res.converged and res.cost < 1e-10
    assert cam.model == model
    assert abs(float(cam.focal_length) - 3000.0) < 1e-4
    np.testing.assert_allclose(np.asarray(cam.distortion), truth_d, rtol=0, atol=1e-7)
    np.testing.assert_allclose(res.points, truth.points, atol=1e-4)
    names = problem.intrinsic_names
    assert res.camera_std.shape == (1, len(names)) and res.orientation_cov.shape[1:] == (6 + len(names),) * 2
    assert all((res.camera_std[0, j] > 0) == (n in free) for j, n in enumerate(names))


def test_bundle_refuses_mixed_models():
    problem, _ = synthetic_block(0, n_tie=15)
    cams = [ptx.FrameCamera.from_pixels(3000.0, (4000, 3000), model="fisheye"), problem.cameras[0]]
    with pytest.raises(ValueError, match="share one distortion model"):
        problem.replace(cameras=cams, image_camera=np.arange(problem.n_images) % 2)
    with pytest.raises(ValueError, match="free_intrinsics must be names from"):
        problem.replace(free_intrinsics=("f", "s1"))  # a brown camera has no thin prism


@pytest.fixture(scope="module")
def fisheye_view():
    """A relief scene's pinhole image re-rendered through a fisheye camera of the same
    orientation: the fisheye pixel's ray (undistortion) sampled in the pinhole image."""
    from scipy.ndimage import map_coordinates

    s = ptx.relief_scene(150.0, seed=2, image_size=(400, 300), focal_px=400.0, noise_px=0.0)
    fish = ptx.FrameCamera.from_pixels(480.0, (400, 300), distortion=(0.05, -0.02, 0.004, -0.001), model="fisheye")
    cols, rows = np.meshgrid(np.arange(400.0), np.arange(300.0))
    pix = np.c_[cols.ravel(), rows.ravel()]
    xn = np.asarray(fish.normalised(fish.pixel_to_image(pix)))
    src = np.asarray(s.camera.image_to_pixel(np.asarray(s.camera.principal_point) + float(s.camera.focal_length) * xn))
    image = map_coordinates(s.image, [src[:, 1], src[:, 0]], order=3, mode="nearest").reshape(300, 400)
    assert src.min() > -1 and src[:, 0].max() < 400 and src[:, 1].max() < 300  # inside the pinhole image
    return s, fish, image


def test_fisheye_ortho_equals_the_pinhole_ortho(fisheye_view):
    """orthorectify with the fisheye camera (forward projection; its footprint through the
    undistortion) gives the pinhole ortho of the same ground, and the Dask ortho is it bit
    for bit (exact mapping) although the chunks' edges bend in the fisheye image."""
    s, fish, image = fisheye_view
    grid = ptx.Grid(s.ortho_transform, s.ortho.shape)
    ref, _ = ptx.orthorectify(s.image, s.exterior, s.camera, s.dem, grid)
    ours, _ = ptx.orthorectify(image, s.exterior, fish, s.dem, grid, approx=None)
    both = np.isfinite(ref) & np.isfinite(ours)
    assert both.mean() > 0.3
    d = ours[both] - ref[both]
    assert np.abs(d).mean() < 0.02 * np.ptp(ref[both]) and abs(d.mean()) < 0.005 * np.ptp(ref[both])
    assert np.corrcoef(ours[both], ref[both])[0, 1] > 0.99
    own_grid = ortho_grid(s.exterior, fish, s.dem, 15.0)  # the footprint: undistorted image corners
    assert np.all(np.isfinite(own_grid.transform))
    lazy = ptx.orthorectify_dask(image, s.exterior, fish, s.dem, grid, chunks=64, approx=None).compute()
    np.testing.assert_array_equal(np.asarray(lazy), ours)


def test_uncertainty_propagates_fisheye_coefficients(fisheye_view):
    """ortho_uncertainty with a fisheye camera's intrinsics covariance: the image variance
    is J S J^T with J the jacfwd of the projection w.r.t. (f, x0, y0, k1 ... k4)."""
    s, fish, _ = fisheye_view
    grid = ptx.Grid(s.ortho_transform, s.ortho.shape)
    cam_cov = np.diag([4.0, 1.0, 1.0, 1e-4, 1e-5, 1e-6, 1e-7])
    u = ptx.ortho_uncertainty(s.exterior, np.zeros((6, 6)), fish, s.dem, grid, camera_covariance=cam_cov, step=1)
    r, c = np.argwhere(np.isfinite(u.image_var[0]))[[0, -1, 500]].T
    x, y = (
        s.ortho_transform[2] + (c + 0.5) * s.ortho_transform[0],
        s.ortho_transform[5] + (r + 0.5) * s.ortho_transform[4],
    )
    ground = np.c_[x, y, np.asarray(s.dem.height(x, y))]

    def pixels(k):
        cam = ptx.FrameCamera(
            k[0], k[1:3], k[3:], pixel_size=fish.pixel_size, image_size=fish.image_size, model="fisheye"
        )
        return cam.image_to_pixel(ptx.project(ground, s.exterior, cam))

    k = np.r_[float(fish.focal_length), np.asarray(fish.principal_point), np.asarray(fish.distortion)]
    j = np.asarray(jax.jacfwd(pixels)(k))  # (n, 2, 7)
    var = np.einsum("nij,jk,nlk->nil", j, cam_cov, j)
    np.testing.assert_allclose(u.image_var[0][r, c], var[:, 0, 0], rtol=1e-9)
    np.testing.assert_allclose(u.image_var[2][r, c], var[:, 1, 1], rtol=1e-9)
    with pytest.raises(ValueError, match=r"camera_covariance must be \(7, 7\)"):
        ptx.ortho_uncertainty(s.exterior, np.zeros((6, 6)), fish, s.dem, grid, camera_covariance=np.eye(8))


def test_ortho_leaves_out_ground_past_the_fold_of_the_distortion():
    """A strong barrel (k1 = -0.5: r_d = r (1 - r^2 / 2) folds at r = 0.816) maps ground far
    outside the field of view (r = 1.2 -> r_d = 0.34) back into the image: the ortho has no
    data there, and everywhere inside the fold it is the forward model's pixel."""
    s = ptx.relief_scene(0.0, seed=4, image_size=(400, 300), focal_px=400.0, tilt_deg=0.0, noise_px=0.0)
    barrel = ptx.FrameCamera.from_pixels(400.0, (400, 300), distortion=(-0.5, 0.0, 0.0, 0.0, 0.0))
    big = ptx.Grid.from_bounds(
        tuple(np.r_[np.asarray(s.exterior.position[:2]) - 3000.0, np.asarray(s.exterior.position[:2]) + 3000.0]),
        20.0,
    )
    with warnings.catch_warnings():  # the corners past the fold see beyond the DEM: a PartialDEMWarning
        warnings.simplefilter("ignore", ptx.PartialDEMWarning)
        ortho, _ = ptx.orthorectify(s.image, s.exterior, barrel, s.dem, big, approx=None)
    xy = big.xy()
    ground = np.c_[xy.reshape(-1, 2), np.zeros(xy.shape[0] * xy.shape[1])]
    q = np.asarray(s.exterior.points_in_camera(ground))
    r = np.hypot(q[:, 0], q[:, 1]) / -q[:, 2]
    pix = np.asarray(barrel.image_to_pixel(ptx.project(ground, s.exterior, barrel)))
    inside = (pix[:, 0] > 1) & (pix[:, 0] < 398) & (pix[:, 1] > 1) & (pix[:, 1] < 298)
    inside &= np.isfinite(np.asarray(s.dem.height(ground[:, 0], ground[:, 1])))  # on the DEM
    seen = np.isfinite(ortho.ravel())
    ghost = inside & (r > 0.8165)
    assert ghost.sum() > 100 and not seen[ghost].any()
    assert seen[inside & (r < 0.81)].all()
