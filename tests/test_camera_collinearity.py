"""Camera and collinearity: OpenCV's projectPoints as the independent reference."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photax as ptx
from photax.camera import OPENCV_FROM_PHOTAX, from_opencv_extrinsics, opencv_extrinsics


def _scene(rng, n=30):
    ground = np.column_stack([rng.uniform(-200, 200, n), rng.uniform(-150, 150, n), rng.uniform(0, 40, n)])
    ground += np.array([500_000.0, 4_000_000.0, 100.0])
    eo = ptx.look_at(ground.mean(0) + np.array([60.0, -80.0, 900.0]), ground.mean(0))
    return ground, eo


def _opencv_pose(eo):
    # OpenCV camera frame: x right, y down, z forward = ours with y, z flipped.
    r_cv, t_cv = opencv_extrinsics(eo.rotation, eo.position)
    return cv2.Rodrigues(r_cv)[0], t_cv


def test_opencv_extrinsics_round_trip_and_frame():
    ground, eo = _scene(np.random.default_rng(2))
    r_cv, t_cv = opencv_extrinsics(eo.rotation, eo.position)
    # OpenCV's camera looks along +z with y down: depth is +z there, -z in photax's frame.
    in_cv = ground @ r_cv.T + t_cv
    in_photax = np.asarray(eo.points_in_camera(jnp.asarray(ground)))
    np.testing.assert_allclose(in_cv, in_photax * np.array([1.0, -1.0, -1.0]), atol=1e-6)
    assert np.all(in_cv[:, 2] > 0)
    r_back, c_back = from_opencv_extrinsics(r_cv, t_cv[:, None])  # cv2 gives tvec as (3, 1)
    np.testing.assert_allclose(r_back, np.asarray(eo.rotation), atol=1e-12)
    np.testing.assert_allclose(c_back, np.asarray(eo.position), rtol=1e-12)
    with pytest.raises(ValueError):
        OPENCV_FROM_PHOTAX[0, 0] = 2.0  # shared constant: read-only


@pytest.mark.parametrize("with_distortion", [False, True])
def test_project_matches_opencv(with_distortion):
    rng = np.random.default_rng(1)
    ground, eo = _scene(rng)
    k1, k2, k3, p1, p2 = (-0.12, 0.05, -0.01, 3e-4, -2e-4) if with_distortion else (0,) * 5
    cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000), (2010.3, 1490.6), (k1, k2, k3, p1, p2))
    ours_px = cam.image_to_pixel(ptx.project(ground, eo, cam))
    rvec, tvec = _opencv_pose(eo)
    K = np.array([[3000.0, 0, 2010.3], [0, 3000.0, 1490.6], [0, 0, 1]])
    dist_cv = np.array([k1, k2, -p1, p2, k3])  # OpenCV's p1 is minus ours (its y is down)
    ref, _ = cv2.projectPoints(ground, rvec, tvec, K, dist_cv)
    np.testing.assert_allclose(ours_px, ref[:, 0, :], atol=1e-6)


def test_pixel_image_round_trip_and_centre():
    cam = ptx.FrameCamera(0.12, (0.0, 0.0), pixel_size=1e-5, image_size=(640, 480))
    assert np.allclose(cam.pixel_to_image(jnp.array([[319.5, 239.5]])), 0.0)
    # row down <-> y up
    assert cam.pixel_to_image(jnp.array([[319.5, 0.0]]))[0, 1] > 0
    px = jnp.array([[0.0, 0.0], [639.0, 479.0], [12.25, 300.5]])
    np.testing.assert_allclose(cam.image_to_pixel(cam.pixel_to_image(px)), px, atol=1e-10)


def test_undistort_inverts_distort():
    cam = ptx.FrameCamera(1.0, (0.0, 0.0), (-0.2, 0.05, 0.0, 1e-3, -5e-4))
    xn = jnp.asarray(np.random.default_rng(0).uniform(-0.6, 0.6, (50, 2)))
    np.testing.assert_allclose(cam.undistort_normalised(cam.distort_normalised(xn)), xn, atol=1e-10)


def test_camera_rejects_bad_shapes():
    with pytest.raises(ValueError, match="principal_point"):
        ptx.FrameCamera(1.0, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="positive"):
        ptx.FrameCamera(-1.0)
    with pytest.raises(ValueError, match="pixel grid"):
        ptx.FrameCamera(1.0).pixel_to_image(jnp.zeros((1, 2)))


@pytest.mark.parametrize("convention", ["phi-omega-kappa", "omega-phi-kappa"])
def test_design_formula_and_monoplotting_round_trip(convention):
    rng = np.random.default_rng(2)
    ground, eo = _scene(rng)
    eo = eo.to_convention(convention)
    cam = ptx.FrameCamera(0.153, (1e-4, -2e-4), (-0.05, 0.0, 0.0, 0.0, 0.0))
    xy = ptx.project(ground, eo, cam)
    # the DESIGN.md equations written out element by element
    R = np.asarray(eo.rotation)
    d = ground - np.asarray(eo.position)
    num_x, num_y, den = d @ R[:, 0], d @ R[:, 1], d @ R[:, 2]
    xn = np.column_stack([-num_x / den, -num_y / den])
    np.testing.assert_allclose(np.asarray(cam.normalised(xy)), xn, atol=1e-12)
    assert np.all(ptx.depth(ground, eo) > 0)
    back = ptx.image_to_ground(xy, eo, cam, height=jnp.asarray(ground[:, 2]))
    np.testing.assert_allclose(back, ground, atol=1e-6)


def test_monoplotting_on_a_dem():
    # a tilted-plane DEM: Z = 100 + 0.05 X' - 0.02 Y' is exact under bilinear
    x = np.linspace(-500, 500, 101) + 500_000
    y = np.linspace(500, -500, 101) + 4_000_000
    Z = 100 + 0.05 * (x[None, :] - 500_000) - 0.02 * (y[:, None] - 4_000_000)
    dem = ptx.DEM(Z, (10.0, 0, x[0] - 5, 0, -10.0, y[0] + 5))
    g = np.array([[500_010.0, 4_000_020.0], [499_800.0, 3_999_900.0], [500_300.0, 4_000_100.0]])
    gz = np.asarray(dem.height(jnp.asarray(g[:, 0]), jnp.asarray(g[:, 1])))
    ground = np.column_stack([g, gz])
    eo = ptx.look_at(np.array([500_050.0, 3_999_950.0, 1500.0]), ground.mean(0))
    cam = ptx.FrameCamera(0.1)
    back = ptx.image_to_ground(ptx.project(ground, eo, cam), eo, cam, dem=dem)
    np.testing.assert_allclose(back, ground, atol=1e-3)


def test_project_is_jittable_and_differentiable():
    rng = np.random.default_rng(3)
    ground, eo = _scene(rng, 5)
    cam = ptx.FrameCamera(0.1)

    def f(v):
        return ptx.project(ground, ptx.ExteriorOrientation.from_vector(v), cam).sum()

    g = jax.jit(jax.grad(f))(eo.to_vector())
    assert g.shape == (6,) and np.all(np.isfinite(g))


@pytest.mark.parametrize("convention", ["phi-omega-kappa", "omega-phi-kappa"])
def test_closed_form_jacobian_matches_autodiff(convention):
    """collinearity_jacobian (and the distortion's derivative in it) against jax.jacfwd of project."""
    from photax.collinearity import project_jacobian

    rng = np.random.default_rng(4)
    ground, eo = _scene(rng, 7)
    eo = eo.to_convention(convention)
    cam = ptx.FrameCamera(0.15, (1e-3, -2e-3), (-0.1, 0.03, -0.01, 2e-3, -1e-3))
    xy, jac = project_jacobian(ground, eo, cam)
    np.testing.assert_allclose(xy, ptx.project(ground, eo, cam), rtol=0, atol=1e-15)

    def of_params(v):
        return ptx.project(ground, ptx.ExteriorOrientation(v[:3], v[3:], convention), cam)

    ref = jax.jacfwd(of_params)(eo.to_vector())  # (n, 2, 6)
    ref_ground = jax.vmap(jax.jacfwd(lambda x: ptx.project(x[None], eo, cam)[0]))(jnp.asarray(ground))  # (n, 2, 3)
    np.testing.assert_allclose(jac[..., :6], ref, rtol=0, atol=1e-13 * float(jnp.abs(ref).max()))
    np.testing.assert_allclose(jac[..., 6:], ref_ground, rtol=0, atol=1e-13 * float(jnp.abs(ref_ground).max()))


def test_intrinsics_and_per_row_jacobians_match_autodiff():
    """camera.intrinsics_jacobian (bundle's self-calibration columns) and
    collinearity_rows with one camera and orientation per row (as bundle
    adjustment calls it, rotation increments about the camera axes) against
    jax.jacfwd of FrameCamera.project."""
    from photax.camera import intrinsics_jacobian
    from photax.collinearity import collinearity_rows

    rng = np.random.default_rng(5)
    ground, eo = _scene(rng, 6)
    intr = np.array([0.15, 1e-3, -2e-3, -0.1, 0.03, -0.01, 2e-3, -1e-3]) * (1 + 0.1 * rng.random((6, 8)))
    rot = np.broadcast_to(np.asarray(eo.rotation), (6, 3, 3))
    pos = np.broadcast_to(np.asarray(eo.position), (6, 3))

    def one(k, x, dr):  # R <- R Exp(dr), bundle adjustment's update; Exp(dr) = I + [dr]x + O(dr^2) at dr = 0
        r = jnp.asarray(eo.rotation) @ (jnp.eye(3) + jnp.cross(jnp.eye(3), dr))
        cam = ptx.FrameCamera(k[0], k[1:3], k[3:])
        return cam.project(r.T @ (x - eo.position))

    rows = jax.jit(collinearity_rows, static_argnames=("wrt_ground", "dots"))  # one compilation each, not op by op
    xy, jac, q = rows(jnp.asarray(ground), pos, rot, None, intr[:, 0], intr[:, 1:3], intr[:, 3:], dots=True)
    ref = jax.jit(
        jax.vmap(lambda k, x: (one(k, x, jnp.zeros(3)), jax.jacfwd(one, argnums=(0, 1, 2))(k, x, jnp.zeros(3))))
    )(jnp.asarray(intr), jnp.asarray(ground))
    np.testing.assert_allclose(xy, ref[0], rtol=0, atol=1e-15)
    scale = float(jnp.abs(ref[1][1]).max())
    np.testing.assert_allclose(jac[..., 6:], ref[1][1], rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(jac[..., :3], -ref[1][1], rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(jac[..., 3:6], ref[1][2], rtol=0, atol=1e-13 * float(jnp.abs(ref[1][2]).max()))
    xn = -q[:, :2] / q[:, 2:3]
    np.testing.assert_allclose(jax.jit(intrinsics_jacobian)(xn, intr[:, 0], intr[:, 3:]), ref[1][0], rtol=0, atol=1e-14)
    # The element-wise contraction (resection's, under vmap) gives the same numbers.
    _, jac_e, _ = rows(jnp.asarray(ground), pos, rot, None, intr[:, 0], intr[:, 1:3], intr[:, 3:])
    np.testing.assert_allclose(jac_e, jac, rtol=0, atol=1e-14 * float(jnp.abs(jac).max()))
