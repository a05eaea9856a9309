"""Space resection against synthetic scenes with known truth, closed-form
statistics (Monte Carlo) and deliberate blunders and bad input."""

import json
import zlib

import numpy as np
import pytest

import photax as ptx
from photax.rotation import rotation_matrix

CAM = ptx.FrameCamera(0.15324)  # metres on the image plane, as in the issue
HALF = 0.1  # half the frame side (m): a 23 cm aerial frame, roughly
ORIGIN = np.array([512_000.0, 4_321_000.0, 0.0])  # UTM-scale coordinates


def _scene(rng, angles, convention="phi-omega-kappa", n=12, relief=40.0, height=1500.0):
    """Ground points seen by a camera ``height`` m above the terrain (Z ~ 100 m)."""
    R = np.asarray(rotation_matrix(np.asarray(angles), convention))
    axis = R @ np.array([0.0, 0.0, -1.0])  # viewing direction
    # put the centre so that the view axis hits the terrain near ORIGIN
    centre = ORIGIN + np.array([0.0, 0.0, 100.0]) - axis * height / -axis[2]
    eo = ptx.ExteriorOrientation(centre, angles, convention)
    xy = rng.uniform(-0.8 * HALF, 0.8 * HALF, (n, 2))
    z = 100.0 + rng.uniform(0.0, relief, n)
    ground = np.asarray(ptx.image_to_ground(xy, eo, CAM, height=z))
    return ground, np.asarray(ptx.project(ground, eo, CAM)), eo


def _angle_diff(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi)


CASES = [  # (phi, omega, kappa) in phi-omega-kappa, or (omega, phi, kappa)
    ("vertical", (0.02, -0.015, 0.3)),
    ("vertical", (-0.01, 0.03, -2.9)),
    ("vertical", (0.0, 0.0, np.pi)),
    ("oblique", (0.5, -0.35, 1.7)),
    ("oblique", (-0.7, 0.2, -1.2)),
]


@pytest.mark.parametrize("convention", ["phi-omega-kappa", "omega-phi-kappa"])
@pytest.mark.parametrize("kind, angles", CASES)
@pytest.mark.parametrize("relief", [0.0, 300.0])  # planar GCPs (homography start), 3-D GCPs (DLT start)
def test_noise_free_recovers_orientation(kind, angles, convention, relief):
    rng = np.random.default_rng(zlib.crc32(repr((kind, angles, convention, relief)).encode()))
    ground, xy, truth = _scene(rng, angles, convention, relief=relief)
    res = ptx.resect(xy, ground, CAM, convention=convention)
    assert res.converged and res.exterior.convention == convention
    dist = np.linalg.norm(np.asarray(truth.position) - ground.mean(0))
    assert np.linalg.norm(np.asarray(res.exterior.position) - np.asarray(truth.position)) < 1e-8 * dist
    assert np.all(_angle_diff(res.exterior.angles, truth.angles) < 1e-8)
    assert -np.pi < float(res.exterior.kappa) <= np.pi
    assert not res.outliers.any()
    assert res.rmse < 1e-12


def test_settings_cached_per_camera_follow_the_camera():
    """resect keeps the last camera's numbers and compiled options; a new camera object (even one
    equal in value) must be used as given: the points were made with CAM, so another focal length
    cannot fit them exactly, and CAM again must fit them exactly (same shapes as above: no compile)."""
    ground, xy, truth = _scene(np.random.default_rng(21), (0.02, -0.015, 0.3))
    other = ptx.FrameCamera(0.9 * CAM.focal_length)
    first, wrong = ptx.resect(xy, ground, CAM), ptx.resect(xy, ground, other, throw=False)
    again, copy = ptx.resect(xy, ground, CAM), ptx.resect(xy, ground, ptx.FrameCamera(CAM.focal_length))
    assert first.rmse < 1e-12 and again.rmse < 1e-12 and copy.rmse < 1e-12
    assert wrong.rmse > 1e-6  # the 10 % focal length error shows (planar GCPs with relief: not absorbed)
    for res in (again, copy):
        np.testing.assert_array_equal(np.asarray(res.exterior.to_vector()), np.asarray(first.exterior.to_vector()))


def test_initial_values_not_needed_for_any_kappa_batch():
    # many random attitudes at once, including strong obliques, through the batch path
    rng = np.random.default_rng(5)
    scenes = [
        _scene(
            rng,
            (rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(-np.pi, np.pi)),
            relief=rng.choice([0.0, 200.0]),
        )
        for _ in range(64)
    ]
    ground, xy = np.stack([s[0] for s in scenes]), np.stack([s[1] for s in scenes])
    res = ptx.resect_batch(xy, ground, CAM)
    truth = np.stack([np.asarray(s[2].to_vector()) for s in scenes])
    assert res.converged.all()
    np.testing.assert_allclose(np.asarray(res.exterior.position), truth[:, :3], rtol=0, atol=1e-6)
    assert np.all(_angle_diff(res.exterior.angles, truth[:, 3:]) < 1e-9)


def test_reported_precision_matches_monte_carlo():
    """300 noisy repetitions of one scene: the spread of the estimates must
    match the reported standard deviations (chi-square bounds) and
    E[sigma0^2] = 1 when the a-priori sigma is the true one."""
    rng = np.random.default_rng(11)
    ground, xy, truth = _scene(rng, (0.3, -0.2, 0.8), relief=150.0, n=12)
    sigma = 5e-6  # 5 um = half a 10-um pixel
    trials = 300
    noisy = xy[None] + rng.normal(0.0, sigma, (trials,) + xy.shape)
    res = ptx.resect_batch(noisy, np.broadcast_to(ground, noisy.shape[:2] + (3,)), CAM, sigma=sigma, robust=False)
    assert res.converged.all()
    est = np.asarray(res.exterior.to_vector())
    err = est - np.asarray(truth.to_vector())[None]
    # covariance with the a-priori sigma0 = 1 (the known sigma): independent of the trial's own noise
    predicted = np.sqrt(np.diagonal(res.covariance, axis1=1, axis2=2) / res.sigma0[:, None] ** 2).mean(0)
    ratio = err.var(axis=0, ddof=0) / predicted**2
    # var ratio ~ chi2(300)/300: 99.9 % band [0.76, 1.29]; 6 parameters -> Bonferroni, use [0.72, 1.33]
    assert np.all((ratio > 0.72) & (ratio < 1.33)), ratio
    # sigma0^2 ~ chi2(r)/r with r = 18: its mean over 300 trials is 1 +- 3*sqrt(2/18/300)
    assert abs(np.mean(res.sigma0**2) - 1.0) < 3 * np.sqrt(2 / 18 / 300)
    # redundancy numbers add up to the redundancy
    np.testing.assert_allclose(res.redundancy.sum(axis=(1, 2)), 2 * 12 - 6, atol=1e-8)


def _pixel_scene(rng, n=12):
    cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000))
    eo = ptx.ExteriorOrientation(ORIGIN + [30.0, -40.0, 900.0], [0.05, -0.04, 2.2])
    px = np.column_stack([rng.uniform(200, 3800, n), rng.uniform(200, 2800, n)])
    xy = np.asarray(cam.pixel_to_image(px))
    ground = np.asarray(ptx.image_to_ground(xy, eo, cam, height=rng.uniform(100, 130, n)))
    return cam, eo, ground, xy


@pytest.mark.parametrize("sigma", [0.5, None])  # Baarda's w with the a-priori sigma; Pope's tau without
def test_twenty_pixel_blunder_is_flagged_by_name(sigma):
    rng = np.random.default_rng(3)
    cam, eo, ground, xy = _pixel_scene(rng)
    noisy = xy + rng.normal(0.0, 0.5, xy.shape)
    noisy[7] += [14.0, -14.2]  # 20 px
    names = [f"GCP{k:02d}" for k in range(len(xy))]
    res = ptx.resect(noisy, ground, cam, sigma=sigma, names=names)
    assert res.outliers.tolist() == [k == 7 for k in range(len(xy))]
    text = res.summary()
    assert "blunder: GCP07" in text
    assert res.statistic == ("w" if sigma else "tau")
    assert np.abs(res.normalised[7]).max() > res.critical
    # the orientation is that of the clean points: within 4 reported std of the truth
    err = np.asarray(res.exterior.to_vector()) - np.asarray(eo.to_vector())
    assert np.all(np.abs(err) < 4 * res.std), err / res.std
    # the excluded point's residual shows the blunder
    assert np.hypot(*res.residuals[7]) > 15.0
    assert res.redundancy[7].tolist() == [0.0, 0.0]


def test_batch_agrees_with_single_and_flags_blunders():
    rng = np.random.default_rng(4)
    cam, eo, ground, xy = _pixel_scene(rng)
    noisy = xy[None] + rng.normal(0.0, 0.5, (3,) + xy.shape)
    noisy[1, 2] += [0.0, 20.0]
    g = np.broadcast_to(ground, noisy.shape[:2] + (3,))
    batch = ptx.resect_batch(noisy, g, cam, sigma=0.5)
    assert batch.outliers[1].tolist() == [k == 2 for k in range(len(xy))]
    assert not batch.outliers[[0, 2]].any()
    for i in range(3):
        one = ptx.resect(noisy[i], ground, cam, sigma=0.5)
        np.testing.assert_allclose(
            np.asarray(batch[i].exterior.to_vector()), np.asarray(one.exterior.to_vector()), rtol=0, atol=1e-7
        )
        np.testing.assert_allclose(batch[i].std, one.std, rtol=1e-6)
        assert batch[i].outliers.tolist() == one.outliers.tolist()


def test_large_batch_program_matches_the_per_lane_loop(monkeypatch):
    """resect_batch's program for large chunks (Gauss-Newton as fixed steps on every lane, the slow lanes
    gathered into groups for the per-lane loop; the linear start's systems by the unrolled Cholesky) gives
    what the small-batch program gives (the per-lane loop, LAPACK): here both on 64 lanes, the large one by
    lowering its thresholds.  Noisy images from the linear start (3-4 steps), and images from a far start
    (more steps: the group path, over several groups), with a ``max_steps`` they reach or not."""
    import jax

    from photax.resection import _adjust, _api, _lanes
    from photax.resection._types import pack

    rng = np.random.default_rng(21)
    scenes = [
        _scene(
            rng,
            (rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-np.pi, np.pi)),
            relief=rng.choice([0.0, 200.0]),
        )
        for _ in range(40)
    ]
    ground = np.stack([s[0] for s in scenes])
    xy = np.stack([s[1] for s in scenes]) + rng.normal(0.0, 5e-6, (40, 12, 2))
    truth = np.stack([np.asarray(s[2].to_vector()) for s in scenes])
    far = truth + np.where(np.arange(40)[:, None] % 2, 1.0, 0.01) * rng.normal(0.0, [30.0] * 3 + [0.05] * 3, (40, 6))
    init = ptx.ExteriorOrientation(far[:, :3], far[:, 3:])

    def run(**kw):
        return [
            ptx.resect_batch(xy, ground, CAM, robust=False, **kw),
            ptx.resect_batch(xy, ground, CAM, robust=False, initial=init, max_steps=6, **kw),
            ptx.resect_batch(xy, ground, CAM, robust=False, initial=init, max_steps=3, **kw),
        ]

    small = run()
    monkeypatch.setattr(_api, "_CHUNK", 64)
    monkeypatch.setattr(_lanes, "UNROLL_LANES", 64)
    monkeypatch.setattr(_adjust, "GROUP", 8)  # several groups
    # a new jitted function, traced with those settings (the module's own has its 64-lane program already)
    monkeypatch.setattr(_api, "_solve_cheap", jax.jit(lambda inp, opt: pack(_adjust.solve_cheap(inp, opt))))
    large = run()
    for a, b in zip(small, large):
        assert a.result.tolist() == b.result.tolist()
        assert a.iterations.tolist() == b.iterations.tolist()
        np.testing.assert_allclose(np.asarray(b.exterior.position), np.asarray(a.exterior.position), rtol=0, atol=1e-7)
        np.testing.assert_allclose(np.asarray(b.exterior.angles), np.asarray(a.exterior.angles), rtol=0, atol=1e-11)
        ok = a.converged
        np.testing.assert_allclose(b.std[ok], a.std[ok], rtol=1e-6)
        np.testing.assert_allclose(b.redundancy[ok], a.redundancy[ok], rtol=0, atol=1e-8)  # one step before
    assert small[0].converged.all() and (small[0].iterations >= 3).any() and (small[1].iterations > 4).any()
    assert not small[2].converged.all() and small[1].converged.sum() > small[2].converged.sum()
    np.testing.assert_allclose(np.asarray(small[0].exterior.position), truth[:, :3], rtol=0, atol=1.0)  # 5 um noise


def test_check_points_and_reports():
    rng = np.random.default_rng(6)
    cam, eo, ground, xy = _pixel_scene(rng, n=14)
    noisy = xy + rng.normal(0.0, 0.3, xy.shape)
    check = np.zeros(14, bool)
    check[[1, 5]] = True
    check_xy = noisy.copy()
    check_xy[1] += 50.0  # a check point is never used: its error must not move the fit
    names = [f"P{k}" for k in range(14)]
    res = ptx.resect(check_xy, ground, cam, check=check, names=names, sigma=0.3)
    ref = ptx.resect(noisy[~check], ground[~check], cam, sigma=0.3)
    np.testing.assert_allclose(np.asarray(res.exterior.to_vector()), np.asarray(ref.exterior.to_vector()), atol=1e-9)
    assert res.check_rmse > 30 and res.rmse < 1.0 and not res.outliers.any()
    assert np.all(np.isnan(res.normalised[check])) and np.all(res.redundancy[check] == 0)
    d = json.loads(json.dumps(res.to_dict()))
    assert [p["role"] for p in d["points"]].count("check") == 2 and d["converged"] is True
    np.testing.assert_allclose(d["correlation"], np.asarray(res.correlation))
    assert "check points: rmse" in res.summary() and "P5" in res.summary()
    # correlation is the normalised covariance
    np.testing.assert_allclose(np.diag(res.correlation), 1.0)


def test_three_points_need_initial_and_report_zero_redundancy():
    rng = np.random.default_rng(8)
    cam, eo, ground, xy = _pixel_scene(rng, n=3)
    with pytest.raises(ValueError, match="initial="):
        ptx.resect(xy, ground, cam)
    start = ptx.ExteriorOrientation(np.asarray(eo.position) + [5.0, -5.0, 10.0], np.asarray(eo.angles) + 0.01)
    res = ptx.resect(xy, ground, cam, initial=start)
    assert res.converged and "zero redundancy" in res.message and np.isnan(res.sigma0)
    np.testing.assert_allclose(np.asarray(res.exterior.position), np.asarray(eo.position), atol=1e-6)


# ----------------------------------------------------------------------------- bad input


def test_bad_input_raises_clear_errors():
    rng = np.random.default_rng(9)
    cam, eo, ground, xy = _pixel_scene(rng, n=8)
    names = [f"T{k}" for k in range(8)]
    with pytest.raises(ValueError, match="at least 3"):
        ptx.resect(xy[:2], ground[:2], cam, initial=eo)
    with pytest.raises(ValueError, match="image_xy must have shape"):
        ptx.resect(ground, ground, cam)
    with pytest.raises(ValueError, match="8 points but ground_xyz has 7"):
        ptx.resect(xy, ground[:7], cam)
    bad = xy.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match="'T4'"):
        ptx.resect(bad, ground, cam, names=names)
    g = ground.copy()
    g[2] = np.inf
    with pytest.raises(ValueError, match="index 2"):
        ptx.resect(xy, g, cam)
    line = ORIGIN + np.outer(np.linspace(0, 100, 8), [1.0, 2.0, 0.1])
    with pytest.raises(ValueError, match="collinear"):
        ptx.resect(xy, line, cam)
    dup_xy, dup_g = xy.copy(), ground.copy()
    dup_xy[6], dup_g[6] = xy[3], ground[3]
    with pytest.raises(ValueError, match="duplicated.*'T3'.*'T6'"):
        ptx.resect(dup_xy, dup_g, cam, names=names)
    with pytest.raises(ValueError, match="sigma"):
        ptx.resect(xy, ground, cam, sigma=np.ones(5))
    with pytest.raises(ValueError, match="check"):
        ptx.resect(xy, ground, cam, check=np.ones(3, bool))
    with pytest.raises(ValueError, match="convention"):
        ptx.resect(xy, ground, cam, convention="kappa-phi-omega")
    with pytest.raises(ValueError, match="3 control points"):
        ptx.resect(xy, ground, cam, check=np.arange(8) > 1)


def test_non_planar_needs_six_points():
    rng = np.random.default_rng(10)
    ground, xy, eo = _scene(rng, (0.1, 0.1, 0.5), n=5, relief=400.0)
    with pytest.raises(ValueError, match="6 control points"):
        ptx.resect(xy, ground, CAM)


def test_points_behind_the_camera_are_a_failure_not_an_answer():
    rng = np.random.default_rng(12)
    cam, eo, ground, xy = _pixel_scene(rng, n=8)
    # mirror the ground through the projection centre: same image, points behind
    behind = 2 * np.asarray(eo.position)[None] - ground
    xy_b = np.asarray(ptx.project(behind, eo, cam))
    np.testing.assert_allclose(xy_b, xy, atol=1e-6)
    with pytest.raises(ptx.ConvergenceError, match="behind the camera"):
        ptx.resect(xy_b, behind, cam, initial=eo)
    res = ptx.resect(xy_b, behind, cam, initial=eo, throw=False)
    assert not res.converged and "behind" in res.message


def test_non_convergence_is_a_status():
    rng = np.random.default_rng(13)
    ground, xy, eo = _scene(rng, (0.2, -0.1, 1.0), relief=100.0)
    far = ptx.ExteriorOrientation(np.asarray(eo.position) + [900.0, -700.0, 2000.0], [0.9, -0.8, -2.0])
    g = np.broadcast_to(ground, (2,) + ground.shape)
    init = ptx.ExteriorOrientation(np.stack([eo.position, far.position]), np.stack([eo.angles, far.angles]))
    res = ptx.resect_batch(np.broadcast_to(xy, (2,) + xy.shape), g, CAM, initial=init, max_steps=2)
    assert res.converged.tolist() == [True, False]
    assert "did not converge" in res.message[1]
    with pytest.raises(ptx.ConvergenceError, match="1 of 2 images"):
        ptx.resect_batch(np.broadcast_to(xy, (2,) + xy.shape), g, CAM, initial=init, max_steps=2, throw=True)


def test_gauss_newton_is_differentiable():
    """Reverse-mode derivative of the adjusted orientation with respect to the image coordinates
    (implicit function theorem through ``lax.custom_root``; the loop itself is not differentiated)
    against the closed form ``(A^T A)^-1 A^T`` of a noise-free least-squares problem."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from photax.resection import _adjust, _api, _checks

    rng = np.random.default_rng(14)
    ground, xy, truth = _scene(rng, (0.1, -0.05, 0.4), relief=50.0, n=8)
    prep = _checks.validate(xy, ground, CAM, None, None, None, None, "phi-omega-kappa", 0.001, batch=False)
    opt = jax.tree_util.tree_map(jnp.asarray, _api._options(prep, CAM, "phi-omega-kappa", False, 0.001, 20, 16))
    inp = jax.tree_util.tree_map(jnp.asarray, _api._inputs(prep, 16))  # one image: one lane
    start = jnp.concatenate([truth.position - prep.origin[0], truth.angles])[:, None] + 1e-3

    def solve(x):
        return _adjust.gauss_newton(start, eqx.tree_at(lambda i: i.xy, inp, x), inp.ctrl, opt)[0][:, 0]

    @jax.jit  # one program, not op by op
    def derivative_and_design(x):
        return jax.jacrev(solve)(x), _adjust.evaluate(solve(x)[:, None], inp, inp.ctrl, opt)[1]

    jac, a = derivative_and_design(inp.xy)
    jac = jac[..., 0].transpose(0, 2, 1)  # (6, 16, 2)
    a = np.asarray(a)[..., 0].transpose(2, 1, 0).reshape(-1, 6)  # rows (point, coordinate)
    ref = np.linalg.solve(a.T @ a, a.T).reshape(6, 16, 2)
    np.testing.assert_allclose(jac, ref, rtol=0, atol=1e-7 * np.abs(ref).max())


def test_lane_jacobian_and_solve_match_autodiff_and_lapack():
    """The code written per lane (images on the last axis), with distortion, for both conventions: the
    linear start on noise-free 3-D control against the truth; the closed-form collinearity Jacobian
    against ``jax.jacfwd`` of ``ptx.project`` (an independent implementation); the Cholesky solve of the
    normal equations against numpy's ``solve``, and the inverse it gives the precision (``M^T M``, ``M = L^-1 D``)
    against numpy's ``inv``."""
    import jax
    import jax.numpy as jnp

    from photax.resection import _api, _checks, _linear
    from photax.resection._adjust import _lanes, _normal, evaluate

    @jax.jit  # one program for the three pieces under test
    def lanes(inp, opt, p):
        v, a, pred, _ = evaluate(p, inp, inp.ctrl, opt)
        n, g = _normal(a, v)
        return (
            _linear.linear_start_lanes(inp, opt),
            (a, pred, n, g),
            _lanes.cho_solve(n, g[:, None])[:, 0],
            _lanes.inverse_factor(n),
        )

    cam = ptx.FrameCamera(0.15324, (1e-4, -2e-4), (0.05, -0.02, 0.01, 1e-4, -2e-4))
    rng = np.random.default_rng(8)
    for convention in ("phi-omega-kappa", "omega-phi-kappa"):
        scenes = [_scene(rng, a, convention, n=9, relief=300.0) for a in ((0.5, -0.35, 1.7), (0.02, -0.015, 0.3))]
        ground = np.stack([s[0] for s in scenes])
        xy = np.stack([np.asarray(ptx.project(g, s[2], cam)) for g, s in zip(ground, scenes)])  # with distortion
        prep = _checks.validate(xy, ground, cam, None, None, None, None, convention, 0.001, batch=True)
        opt = jax.tree_util.tree_map(jnp.asarray, _api._options(prep, cam, convention, False, 0.001, 20, 16))
        inp = jax.tree_util.tree_map(jnp.asarray, _api._inputs(prep, 16))
        p = np.stack([np.concatenate([s[2].position - o, s[2].angles]) for s, o in zip(scenes, prep.origin)], axis=1)
        start, ok = lanes(inp, opt, jnp.zeros((6, 2)))[0]  # noise-free: the linear start is exact
        assert np.all(ok)
        np.testing.assert_allclose(start[:3], p[:3], rtol=0, atol=1e-6)
        np.testing.assert_allclose(start[3:], p[3:], rtol=0, atol=1e-9)
        p = p + rng.normal(0.0, [[3.0], [3.0], [3.0], [0.01], [0.01], [0.01]], p.shape)  # away from the solution
        _, (a, pred, n, g), x, mf = lanes(inp, opt, jnp.asarray(p))

        def model(q, g, o):
            return ptx.project(g, ptx.ExteriorOrientation(q[:3] + o, q[3:], convention), cam)

        args = (jnp.asarray(p.T), jnp.asarray(ground), jnp.asarray(prep.origin))
        want_xy, want = jax.jit(jax.vmap(lambda *x: (model(*x), jax.jacfwd(model)(*x))))(*args)  # (2, n, 2 [, 6])
        np.testing.assert_allclose(np.asarray(pred)[:, :9].transpose(2, 1, 0), want_xy, rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            np.asarray(a)[:, :, :9].transpose(3, 2, 1, 0), want, rtol=1e-9, atol=1e-9 * np.abs(want).max()
        )
        want = np.linalg.solve(np.transpose(np.asarray(n), (2, 0, 1)), np.asarray(g).T[..., None])[..., 0].T
        np.testing.assert_allclose(x, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
        mf = np.transpose(np.asarray(mf), (2, 0, 1))
        inv = np.linalg.inv(np.transpose(np.asarray(n), (2, 0, 1)))
        np.testing.assert_allclose(np.swapaxes(mf, 1, 2) @ mf, inv, rtol=1e-8, atol=1e-12 * np.abs(inv).max())
