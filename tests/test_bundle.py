"""Bundle adjustment: the Schur step against a dense solve, recovery of a
synthetic block's truth, precision against Monte Carlo, self-calibration,
robust losses, the datum, and the BAL camera against its own formula."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import shared_file
from scipy.spatial.transform import Rotation

import photax as ptx
from photax.bundle._linearise import _linearise, _prior_residuals, _project_obs, _residuals
from photax.bundle._schur import _trial
from photax.bundle._structure import _analyse, _State
from photax.scene import synthetic_block


@pytest.fixture(scope="module")
def block():
    """The standard block: 2 strips x 4 images, 6 GCPs, 4 check points."""
    return synthetic_block(0, noise_px=0.5)


def _truth_obs(problem, truth):
    """Noise-free image coordinates of every observation."""
    out = np.empty_like(problem.obs_xy)
    for i in range(problem.n_images):
        sel = problem.obs_image == i
        eo = ptx.ExteriorOrientation(truth.exterior.position[i], truth.exterior.angles[i], truth.exterior.convention)
        out[sel] = np.asarray(ptx.project(truth.points[problem.obs_point[sel]], eo, truth.camera))
    return out


def _angle_error(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi)


def test_schur_step_equals_dense_normal_equations():
    problem, _ = synthetic_block(3, n_tie=15, noise_px=1.0, start_error=(3.0, 0.01, 2.0))
    problem = problem.replace(
        free_intrinsics=("f", "x0", "k1"),
        point_sigma=np.where(problem.roles == "control", 0.05, 0.0),
    )  # a control point with a prior, self-calibration
    fixed = np.zeros((problem.n_images, 6), dtype=bool)
    fixed[1, 2] = fixed[2, 3:] = True  # a fixed height and a fixed attitude
    # A tie point measured twice on one image: a pair of observations within one diagonal block of S.
    dup = int(np.flatnonzero(problem.roles[problem.obs_point] == "tie")[0])
    problem = problem.replace(
        fixed_exterior=fixed, obs_image=np.r_[problem.obs_image, problem.obs_image[dup]],
        obs_point=np.r_[problem.obs_point, problem.obs_point[dup]], obs_xy=np.r_[problem.obs_xy, problem.obs_xy[dup : dup + 1] + 0.7],
        obs_sigma=np.r_[problem.obs_sigma, problem.obs_sigma[dup : dup + 1]],
    )  # fmt: skip
    origin = np.round(problem.points.mean(0))
    s, n_c, _ = _analyse(problem, np.zeros((problem.n_images, 6), bool), origin)
    intr = np.stack(
        [np.r_[float(c.focal_length), np.asarray(c.principal_point), np.asarray(c.distortion)] for c in problem.cameras]
    )
    state = _State(jnp.asarray(problem.exterior.rotation), jnp.asarray(problem.exterior.position) - origin[None, :],
                   jnp.asarray(intr), jnp.asarray(problem.points - origin[None, :]))  # fmt: skip
    lam = 1e-3
    none, one = jnp.asarray(0), jnp.asarray(1.0)
    lin = _linearise(state, s, none, one, n_c)
    # The least-squares trial linearises at its candidate (kept when the step is accepted).
    new, new_cost, *_, lin_new = _trial(state, lin, s, jnp.asarray(lam), none, one, n_c, relinearise=True)

    # Dense reference: all parameters in one vector, full Jacobian by jacfwd.
    n_img, n_pts, a = problem.n_images, problem.n_points, len(s.active)

    def apply(x):  # the solver's update: R <- R Exp(dr), C <- C + R_new R^T dC (the step turns with the camera)
        dimg = x[: 6 * n_img].reshape(n_img, 6)
        dint = x[6 * n_img : n_c].reshape(-1, a)
        rot = state.rot @ ptx.axis_angle_to_matrix(dimg[:, :3])
        centre = state.centre + jnp.einsum("nij,nkj,nk->ni", rot, state.rot, dimg[:, 3:])
        return _State(rot, centre, state.intr.at[:, s.active].add(dint), state.xyz + x[n_c:].reshape(n_pts, 3))

    def residual(x):
        st = apply(x)
        return jnp.concatenate([_residuals(st, s).ravel(), _prior_residuals(st, s).ravel()])

    x0 = jnp.zeros(n_c + 3 * n_pts)
    free = np.concatenate([np.asarray(s.mask_c), np.asarray(s.mask_p).ravel()]) > 0
    J = np.asarray(jax.jit(jax.jacfwd(residual))(x0))[:, free]
    r = np.asarray(jax.jit(residual)(x0))
    H = J.T @ J
    D = np.clip(np.diag(H), 1e-6, 1e32)
    dx = np.zeros(len(free))
    dx[free] = np.linalg.solve(H + lam * np.diag(D), -J.T @ r)
    ref = apply(jnp.asarray(dx))
    np.testing.assert_allclose(new.xyz, ref.xyz, atol=1e-7)
    np.testing.assert_allclose(new.centre, ref.centre, atol=1e-7)
    np.testing.assert_allclose(new.rot, ref.rot, atol=1e-11)
    np.testing.assert_allclose(new.intr, ref.intr, rtol=1e-9, atol=1e-11)
    # ... and that linearisation is a fresh one's at the new point; its cost, the
    # candidate's, is half the squared residuals of the reference step.
    fresh = _linearise(new, s, none, one, n_c)
    for name in fresh._fields:
        np.testing.assert_allclose(getattr(lin_new, name), getattr(fresh, name), rtol=1e-12, atol=1e-12, err_msg=name)
    assert float(new_cost) == pytest.approx(
        0.5 * float(np.sum(np.asarray(jax.jit(residual)(jnp.asarray(dx))) ** 2)), rel=1e-9
    )
    # The matrix-free conjugate-gradient solver (for large blocks) gives the same step.
    # CG stops at a relative residual of 1e-8, so its step error is bounded by
    # cond(S) * 1e-8 relative: ask for 1e-3 of the step.
    cg, *_ = _trial(state, lin, s, jnp.asarray(lam), none, one, n_c, solver="cg")
    for a, b, x0 in ((cg.xyz, ref.xyz, state.xyz), (cg.centre, ref.centre, state.centre)):
        step = np.asarray(b - x0)
        assert np.linalg.norm(np.asarray(a - b)) <= 1e-3 * np.linalg.norm(step)


def test_closed_form_jacobians_equal_autodiff():
    """The hand-derived projection Jacobians (rotation on the manifold, all 8
    intrinsics, the point) against jax.jacfwd through FrameCamera.project and
    Rodrigues, for arbitrary attitudes and strong distortion."""
    problem, _ = synthetic_block(1, n_tie=20, noise_px=0.0)
    problem = problem.replace(free_intrinsics=ptx.bundle.INTRINSICS)
    origin = np.round(problem.points.mean(0))
    s, _, w = _analyse(problem, np.zeros((problem.n_images, 6), bool), origin)
    assert w == 14
    n_img = problem.n_images
    rot = Rotation.random(n_img, random_state=3).as_matrix()  # any attitude, not just near-nadir
    pts = problem.points - origin
    centre = pts.mean(0)[None, :] + 900.0 * rot[:, :, 2]  # the camera looks along its -z axis at the block
    intr = np.array([[3000.0, 12.0, -7.0, -0.08, 0.02, -0.004, 1.5e-3, -2.5e-3]])
    state = _State(jnp.asarray(rot), jnp.asarray(centre), jnp.asarray(intr), jnp.asarray(pts))
    proj, jc, jp = jax.jit(_project_obs, static_argnames="jacobians")(state, s, jacobians=True)

    def reference(z, i, p):  # z = (dr, dC, d_intrinsics, dX)
        r = state.rot[i] @ ptx.axis_angle_to_matrix(z[:3])
        k = state.intr[0] + z[6:14]
        cam = ptx.FrameCamera(k[0], k[1:3], k[3:8])
        return cam.project(r.T @ (state.xyz[p] + z[14:] - state.centre[i] - z[3:6]))

    args = (jnp.zeros(17), s.obs_image, s.obs_point)
    ref, J = jax.jit(lambda *a: (jax.vmap(reference, in_axes=(None, 0, 0))(*a),
                                 jax.vmap(jax.jacfwd(reference), in_axes=(None, 0, 0))(*a)))(*args)  # fmt: skip
    np.testing.assert_allclose(proj, ref, rtol=1e-12, atol=1e-9)
    for ours, theirs in ((jc, J[:, :, :14]), (jp, J[:, :, 14:])):
        scale = np.abs(np.asarray(theirs)).max(axis=(0, 1))  # per unknown
        np.testing.assert_allclose(np.asarray(ours) / scale, np.asarray(theirs) / scale, atol=1e-11)


def test_noise_free_block_recovers_truth():
    problem, truth = synthetic_block(0, noise_px=0.0)
    problem = problem.replace(obs_sigma=0.5)  # same structure as the `block` fixture
    res = ptx.bundle_adjust(problem)
    assert res.converged and res.cost < 1e-12
    np.testing.assert_allclose(res.points, truth.points, atol=1e-6)
    np.testing.assert_allclose(res.exterior.position, truth.exterior.position, atol=1e-6)
    assert _angle_error(res.exterior.angles, truth.exterior.angles).max() < 1e-9
    np.testing.assert_allclose(res.check_residuals, 0.0, atol=1e-6)
    # Check points are adjusted, not held: they have a nonzero precision.
    assert np.all(res.point_std[problem.roles == "check"] > 0)
    assert np.all(res.point_std[problem.roles == "control"] == 0)


def test_precision_matches_monte_carlo(block):
    problem, truth = block
    clean = _truth_obs(problem, truth)
    first = ptx.bundle_adjust(problem)
    assert 0.8 < first.sigma0 < 1.25  # obs_sigma is the true noise
    rng = np.random.default_rng(42)
    pos, ang, pts = [], [], []
    for _ in range(120):
        p = problem.replace(obs_xy=clean + 0.5 * rng.standard_normal(clean.shape))
        r = ptx.bundle_adjust(p, precision=False)
        pos.append(np.asarray(r.exterior.position))
        ang.append(np.asarray(r.exterior.angles))
        pts.append(r.points)
    pos, ang, pts = np.array(pos), np.array(ang), np.array(pts)
    # Predicted std with the a-priori sigma (sigma0 = 1): remove sigma0.
    eo_pred = first.exterior_std / first.sigma0
    pt_pred = first.point_std / first.sigma0
    mc_eo = np.concatenate([pos.std(0), ang.std(0)], axis=1)
    tie = np.flatnonzero(problem.roles == "tie")[:5]
    np.testing.assert_allclose(mc_eo[[0, 3, 5]], eo_pred[[0, 3, 5]], rtol=0.2)
    np.testing.assert_allclose(pts.std(0)[tie], pt_pred[tie], rtol=0.2)


def test_self_calibration_recovers_focal_length_and_k1():
    kw = dict(noise_px=0.0, relief=250.0, tilt_deg=8.0, distortion=(-0.04, 0.0, 0.0, 0.0, 0.0), n_control=8, n_tie=80)
    problem, truth = synthetic_block(5, **kw)
    start = ptx.FrameCamera.from_pixels(2950.0, (4000, 3000))  # 1.7 % off, no distortion
    problem = problem.replace(cameras=[start], free_intrinsics=("f", "k1"))
    res = ptx.bundle_adjust(problem)
    cam = res.cameras[0]
    assert res.converged and res.cost < 1e-10
    assert abs(float(cam.focal_length) - 3000.0) < 1e-5
    assert abs(float(cam.distortion[0]) + 0.04) < 1e-9
    np.testing.assert_allclose(res.points, truth.points, atol=1e-5)
    assert res.camera_std[0, 0] > 0 and res.camera_std[0, 1] == 0  # f free, x0 fixed


def test_huber_downweights_a_blunder(block):
    problem, truth = block
    clean = _truth_obs(problem, truth)
    rng = np.random.default_rng(7)
    obs = clean + 0.5 * rng.standard_normal(clean.shape)
    # A tie point on >= 4 images: with 2 rays an x blunder hides in the height.
    counts = np.bincount(problem.obs_point)
    bad = np.flatnonzero((problem.roles[problem.obs_point] == "tie") & (counts[problem.obs_point] >= 4))[0]
    obs[bad, 0] += 50.0  # a tie observation 50 px off
    p = problem.replace(obs_xy=obs)
    ls = ptx.bundle_adjust(p)
    hub = ptx.bundle_adjust(p, loss="huber", loss_scale=2.0)
    cau = ptx.bundle_adjust(p, loss="cauchy", loss_scale=2.0)
    ref = ptx.bundle_adjust(problem.replace(obs_xy=clean + 0.5 * np.random.default_rng(7).standard_normal(clean.shape)))
    k = problem.obs_point[bad]
    err = lambda r: np.linalg.norm(r.points[k] - truth.points[k])  # noqa: E731
    assert err(ls) > 3 * err(ref) + 0.5  # least squares is pulled away
    for robust in (hub, cau):
        assert err(robust) < err(ref) + 0.3
        assert robust.weights[bad] < 0.1
        assert np.median(robust.weights) > 0.9


def test_start_values_by_resection_and_intersection():
    """No orientations, no tie coordinates: resection from GCPs, then intersection."""
    problem, truth = synthetic_block(4, noise_px=0.5, n_control=24, unknown_start=True)
    start = ptx.initialize_block(problem)
    assert np.abs(np.asarray(start.exterior.position) - np.asarray(truth.exterior.position)).max() < 30.0
    res = ptx.bundle_adjust(problem)  # initialize="auto" does the same
    assert res.converged
    assert (
        np.abs(np.asarray(res.exterior.position) - np.asarray(truth.exterior.position)).max()
        < 4 * res.exterior_std[:, :3].max()
    )
    assert np.sqrt(np.mean(res.check_residuals**2)) < 0.5


def test_free_network_is_refused_unless_a_gauge_is_chosen():
    problem, truth = synthetic_block(2, noise_px=0.0, n_control=0, n_check=0, n_tie=60)
    with pytest.raises(ValueError, match="no datum"):
        ptx.bundle_adjust(problem)
    res = ptx.bundle_adjust(problem, gauge="fix_first_camera")
    assert res.converged and res.cost < 1e-10
    np.testing.assert_allclose(res.exterior.position[0], problem.exterior.position[0], atol=1e-12)
    assert res.exterior_std is not None and np.all(res.exterior_std[0] == 0)
    # The shape is the truth's up to a similarity: compare ratios of distances.
    d = lambda x: np.linalg.norm(x[:, None] - x[None], axis=-1)  # noqa: E731
    iu = np.triu_indices(problem.n_points, 1)
    ratio = d(res.points)[iu] / d(truth.points)[iu]
    assert ratio.std() / ratio.mean() < 1e-8
    damped = ptx.bundle_adjust(problem, gauge="damped")
    assert damped.converged and damped.cost < 1e-10 and damped.exterior_std is None


def test_bad_input_is_refused():
    problem, _ = synthetic_block(0, noise_px=0.0)
    with pytest.raises(ValueError, match="obs_point"):
        problem.replace(obs_point=problem.obs_point + problem.n_points)
    with pytest.raises(ValueError, match="free_intrinsics"):
        problem.replace(free_intrinsics=("f", "k9"))
    with pytest.raises(ValueError, match="loss"):
        ptx.bundle_adjust(problem, loss="l1")


def test_single_ray_tie_point_is_refused():
    problem, _ = synthetic_block(0, noise_px=0.0)
    tie = np.flatnonzero(problem.roles[problem.obs_point] == "tie")
    p = problem.obs_point[tie[0]]
    drop = np.flatnonzero(problem.obs_point == p)[1:]
    keep = np.setdiff1d(np.arange(problem.n_observations), drop)
    with pytest.raises(ValueError, match="observed on 1 image"):
        problem.replace(obs_image=problem.obs_image[keep], obs_point=problem.obs_point[keep],
                        obs_xy=problem.obs_xy[keep], obs_sigma=1.0)  # fmt: skip


def test_bal_camera_is_a_frame_camera():
    """BAL's projection (its own formula, Rodrigues by OpenCV) equals photax.project."""
    rng = np.random.default_rng(0)
    rvec, t = rng.normal(size=3), rng.normal(size=3) * 2
    f, k1, k2 = 500.0, -0.1, 0.02
    X = rng.normal(size=(20, 3)) + np.array([0, 0, -8.0])
    R = cv2.Rodrigues(rvec)[0]
    P = X @ R.T + t
    p = -P[:, :2] / P[:, 2:]
    n2 = np.sum(p * p, axis=1, keepdims=True)
    bal = f * (1 + k1 * n2 + k2 * n2**2) * p
    eo = ptx.ExteriorOrientation.from_rotation(-R.T @ t, R.T, "omega-phi-kappa")
    cam = ptx.FrameCamera(f, (0.0, 0.0), (k1, k2, 0.0, 0.0, 0.0))
    np.testing.assert_allclose(ptx.project(X, eo, cam), bal, rtol=1e-12, atol=1e-9)


def test_dubrovnik_cost_is_ceres_cost():
    """On a real BAL problem, result.cost is 0.5 sum of BAL residuals^2 (recomputed in numpy)."""
    from photax.io.bal import bal_to_photax, read_bal_arrays

    d = read_bal_arrays(shared_file("dubrovnik-3-7-pre.txt"))
    cams, eo = bal_to_photax(d.cameras)
    problem = ptx.BundleProblem(cams, eo, d.points, d.camera_index, d.point_index, d.observations,
                                free_intrinsics=("f", "k1", "k2"))  # fmt: skip
    with pytest.raises(ValueError, match="no datum"):
        ptx.bundle_adjust(problem)
    # 38 residuals for 48 unknowns: under-determined, LM creeps on; cap it.
    res = ptx.bundle_adjust(problem, gauge="damped", max_steps=10, throw=False)
    assert res.cost < 0.1 * res.initial_cost
    rows = np.array([np.r_[cv2.Rodrigues(np.asarray(R).T)[0].ravel(), -np.asarray(R).T @ np.asarray(C),
                           float(c.focal_length), np.asarray(c.distortion)[:2]]
                     for R, C, c in zip(res.rotation, res.exterior.position, res.cameras)])  # fmt: skip
    R = np.array([cv2.Rodrigues(r[:3])[0] for r in rows])
    P = np.einsum("kij,kj->ki", R[d.camera_index], res.points[d.point_index]) + rows[d.camera_index, 3:6]
    p = -P[:, :2] / P[:, 2:]
    n2 = np.sum(p * p, axis=1, keepdims=True)
    c = rows[d.camera_index]
    pred = c[:, 6:7] * (1 + c[:, 7:8] * n2 + c[:, 8:9] * n2**2) * p
    np.testing.assert_allclose(res.cost, 0.5 * np.sum((pred - d.observations) ** 2), rtol=1e-9)
    np.testing.assert_allclose(res.residuals, pred - d.observations, atol=1e-6)


def test_gauss_newton_and_report(block):
    problem, truth = block
    res = ptx.bundle_adjust(problem, method="gauss-newton", verbose=True)
    assert res.converged
    text = res.report()
    assert "sigma0" in text and "check points (4)" in text
    assert [h["iteration"] for h in res.history] == list(range(1, res.iterations + 1))
    costs = [h["cost"] for h in res.history]
    assert costs[-1] <= costs[0]


def test_analysis_is_cached_and_shared_by_replicates():
    """BundleProblem.analyse runs once per problem and gauge; a replicate that
    only changes the measurements reuses the index arrays, and its structure
    equals a fresh analysis of the same problem."""
    problem, _ = synthetic_block(0, n_tie=20, noise_px=0.5)
    a = problem.analyse()
    assert problem.analyse() is a
    assert problem.analyse("fix_first_camera") is not a
    rep = problem.replace(obs_xy=problem.obs_xy + 0.1)
    b = rep.analyse()
    assert b.structure.chunk_a is a.structure.chunk_a  # shared, not recomputed
    fresh, n_c, w = _analyse(rep, np.zeros((rep.n_images, 6), bool), b.origin)
    assert (n_c, w) == (b.n_c, b.w)
    for x, y in zip(b.structure, fresh):
        np.testing.assert_array_equal(x, y)
    # Other links: analysed anew.
    keep = np.arange(rep.n_observations) != int(np.flatnonzero(problem.roles[problem.obs_point] == "control")[0])
    other = problem.replace(obs_image=problem.obs_image[keep], obs_point=problem.obs_point[keep],
                            obs_xy=problem.obs_xy[keep], obs_sigma=problem.obs_sigma[keep])  # fmt: skip
    assert other.analyse().structure.chunk_a is not a.structure.chunk_a
    assert other.analyse().structure.obs_image.shape == (problem.n_observations - 1,)


def test_stopping_rule_follows_its_formula():
    """StoppingRule against its documented rule, on hand-picked numbers either
    side of each threshold."""
    rule = ptx.bundle.StoppingRule(function_tolerance=1e-3, gradient_tolerance=1e-6, parameter_tolerance=1e-4)
    assert rule.at_start(1e-7).startswith("gradient tolerance") and rule.at_start(1e-5) == ""
    # |dcost| <= 1e-3 cost_old, accepted steps only.
    assert rule.after_step(True, 100.0, 99.95, 1.0, 1.0, 1.0).startswith("function tolerance")
    assert rule.after_step(False, 100.0, 99.95, 1.0, 1.0, 1.0) == ""
    assert rule.after_step(True, 100.0, 99.0, 1.0, 1.0, 1.0) == ""
    assert rule.after_step(True, 100.0, 99.0, 1e-7, 1.0, 1.0).startswith("gradient tolerance")
    # |dx| <= 1e-4 (|x| + 1e-4), on any computed step.
    assert rule.after_step(False, 100.0, 99.0, 1.0, 0.9e-4 * (1.0 + 1e-4), 1.0).startswith("parameter tolerance")
    assert rule.after_step(False, 100.0, 99.0, 1.0, 1.1e-4 * (1.0 + 1e-4), 1.0) == ""
    assert rule.after_step(False, 100.0, 99.0, 1.0, float("nan"), 1.0) == ""


def test_outcome_codes_and_throw(block):
    """RESULTS codes on BundleResult: successful when converged, the iteration
    limit named when it stops there (throw=False), ConvergenceError with throw=True."""
    problem, _ = block
    short = ptx.bundle_adjust(problem, max_steps=1, throw=False)
    assert not short.converged and short.result == ptx.RESULTS.max_steps_reached
    assert "max_steps = 1" in short.message
    with pytest.raises(ptx.ConvergenceError, match="bundle adjustment failed"):
        ptx.bundle_adjust(problem, max_steps=1)
    assert ptx.bundle_adjust(problem).result == ptx.RESULTS.successful


def test_stop_code_is_carried_not_read_from_the_message(block, monkeypatch):
    """The code comes from where the loop stops and the message is made from it: other words for
    every stop leave the codes as they were (issue 26: the code used to be parsed from the text)."""
    from photax.bundle import _result

    problem, _ = block
    words = {code: f"stop {code.name} #{{max_steps}}{{where}}" for code in _result.STOP_WORDS}
    monkeypatch.setattr(_result, "STOP_WORDS", words)
    short = ptx.bundle_adjust(problem, max_steps=1, throw=False)
    assert short.result == ptx.RESULTS.max_steps_reached and short.message == "stop max_steps_reached #1"
    # each failure's words name it, and the converged message names the rule that held
    assert _result.stop_message(ptx.RESULTS.singular, at_solution=True) == "stop singular #0 at the solution"
    rule = "function tolerance: |dcost|/cost = 1e-07 <= 1e-06"
    assert _result.stop_message(ptx.RESULTS.successful, rule) == rule
    full = ptx.bundle_adjust(problem)
    assert full.converged and full.message.startswith(("function", "gradient", "parameter"))
