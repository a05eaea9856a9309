"""GNSS/INS-aided bundle adjustment: camera positions (with a lever arm) and
attitudes as weighted observations.  The Schur step against a dense solve
with the observations' rows written out here, a single image's adjustment
against the information-weighted mean of its resection and the
observations, a block with ties and GNSS alone against its truth, the
datum checks, bad sigmas and the CLI."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bundle_steps import LAMBDA, apply, one_step

import photax as ptx
from photax.bundle._linearise import _prior_residuals, _residuals
from photax.cli import main
from photax.io.block import write_block
from photax.scene import synthetic_block


def _gnss(truth, sigma, seed, lever=None):
    """True antenna positions (centre + R lever) plus N(0, sigma) noise."""
    rng = np.random.default_rng(seed)
    pos = np.asarray(truth.exterior.position, dtype=float)
    if lever is not None:
        pos = pos + np.einsum("nij,j->ni", np.asarray(truth.exterior.rotation), lever)
    return pos + sigma * rng.standard_normal(pos.shape)


@pytest.fixture(scope="module")
def free_block():
    """2 strips x 4 images, no control (4 check points), 0.5 px noise."""
    return synthetic_block(0, n_control=0, n_check=4)


@pytest.mark.parametrize("solver", ["dense", "band", "cg"])
def test_schur_step_with_gnss_equals_dense_normal_equations(solver):
    """One damped step with GNSS positions (lever arm, per-axis sigma) and
    attitudes on some images equals the dense solve of the whole normal
    matrix, the observations' residuals written out independently here."""
    problem, truth = synthetic_block(3, n_tie=15, noise_px=1.0, start_error=(3.0, 0.01, 2.0))
    n_img = problem.n_images
    rng = np.random.default_rng(5)
    gnss = _gnss(truth, 0.5, 6, lever=np.array([0.2, -0.4, 1.3]))
    gnss[2] = np.nan  # no fix on image 2
    att = np.asarray(truth.exterior.angles) + 0.003 * rng.standard_normal((n_img, 3))
    att[[0, 5]] = np.nan
    g_sig = rng.uniform(0.3, 1.0, (n_img, 3))
    a_sig = rng.uniform(0.001, 0.004, (n_img, 3))
    lever = np.array([0.2, -0.4, 1.3])
    problem = problem.replace(gnss_position=gnss, gnss_sigma=g_sig, attitude=att, attitude_sigma=a_sig, lever_arm=lever)
    s, n_c, origin, state, lin, new = one_step(problem, solver)

    n_pts = problem.n_points
    conv = problem.exterior.convention
    seen_g, seen_a = np.isfinite(gnss).all(1), np.isfinite(att).all(1)
    g_local = jnp.asarray(np.nan_to_num(gnss) - origin[None, :])
    r_obs = ptx.rotation_matrix(jnp.asarray(np.nan_to_num(att)), conv)

    def angle_rows(
        rot,
    ):  # angles of R_obs Exp(e) to first order in e = Log(R_obs^T R): d angles / d e at R_obs
        e = ptx.matrix_to_axis_angle(jnp.swapaxes(r_obs, 1, 2) @ rot)
        jac = jax.vmap(jax.jacfwd(lambda d, r: ptx.angles_from_matrix(r @ ptx.axis_angle_to_matrix(d), conv)),
                       in_axes=(None, 0))(jnp.zeros(3), r_obs)  # fmt: skip
        return jnp.einsum("nij,nj->ni", jac, e)

    def residual(x):
        st = apply(state, x, n_img, n_c)
        antenna = st.centre + jnp.einsum("nij,j->ni", st.rot, jnp.asarray(lever))
        r_g = ((antenna - g_local) / g_sig)[seen_g]
        r_a = (angle_rows(st.rot) / a_sig)[seen_a]
        return jnp.concatenate([_residuals(st, s).ravel(), _prior_residuals(st, s).ravel(), r_g.ravel(), r_a.ravel()])

    x0 = jnp.zeros(n_c + 3 * n_pts)
    free = np.concatenate([np.asarray(s.mask_c), np.asarray(s.mask_p).ravel()]) > 0
    J = np.asarray(jax.jit(jax.jacfwd(residual))(x0))[:, free]
    r = np.asarray(jax.jit(residual)(x0))
    assert float(lin.cost) == pytest.approx(0.5 * float(r @ r), rel=1e-10)
    H = J.T @ J
    dx = np.zeros(len(free))
    dx[free] = np.linalg.solve(H + LAMBDA * np.diag(np.clip(np.diag(H), 1e-6, 1e32)), -J.T @ r)
    ref = apply(state, jnp.asarray(dx), n_img, n_c)
    tol = {"centre": 1e-7, "rot": 1e-11, "xyz": 1e-7} if solver != "cg" else {"centre": 2e-3, "rot": 1e-7, "xyz": 2e-3}
    np.testing.assert_allclose(new.centre, ref.centre, atol=tol["centre"])
    np.testing.assert_allclose(new.rot, ref.rot, atol=tol["rot"])
    np.testing.assert_allclose(new.xyz, ref.xyz, atol=tol["xyz"])


def _single_image():
    """One image over 12 fixed control points (0.5 px noise), start values off."""
    rng = np.random.default_rng(3)
    cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000))
    true = ptx.ExteriorOrientation(np.array([500100.0, 4000050.0, 700.0]), np.array([0.02, -0.015, 0.3]),
                                   "omega-phi-kappa")  # fmt: skip
    pts = np.column_stack([rng.uniform(-250, 250, (12, 2)) + [500100.0, 4000050.0], rng.uniform(0, 60, 12)])
    obs = np.asarray(ptx.project(pts, true, cam)) + 0.5 * rng.standard_normal((12, 2))
    start = ptx.ExteriorOrientation(np.array([[500103.0, 4000048.0, 702.0]]),
                                    np.array([[0.025, -0.01, 0.31]]),
                                    "omega-phi-kappa")  # fmt: skip
    return ptx.BundleProblem(cam, start, pts, np.zeros(12, int), np.arange(12), obs, obs_sigma=0.5,
                             roles=["control"] * 12)  # fmt: skip


def _eo_vector(result):
    return np.concatenate([np.asarray(result.exterior.position[0]), np.asarray(result.exterior.angles[0])])


@pytest.mark.parametrize("with_attitude", [False, True])
def test_single_image_is_the_information_weighted_mean_of_resection_and_observations(with_attitude):
    """Closed form: the image's resection (no GNSS) gives x_r with cofactor
    Q_r; the GNSS/INS observations x_o with weights P.  The adjustment of
    both is, to first order, (Q_r^-1 + P)^-1 (Q_r^-1 x_r + P x_o).  The
    observations are set 1-2 sigma off x_r: the fused orientation moves
    ~0.7 m and ~1e-3 rad, and the linearisation error is second order in
    that move (~1 mm, ~1e-6 rad)."""
    problem = _single_image()
    res = ptx.bundle_adjust(problem)
    x_r = _eo_vector(res)
    n_r = np.linalg.inv(res.orientation_cov[0][:6, :6] / res.sigma0**2)
    x_o = np.concatenate([x_r[:3] + [2.0, -1.5, 1.0], x_r[3:] + [0.004, -0.003, 0.005]])
    sig = np.array([0.5, 0.5, 0.8, 0.002, 0.002, 0.003])
    p = np.diag(1.0 / sig**2)
    kw = {"gnss_position": x_o[None, :3], "gnss_sigma": sig[None, :3]}
    if with_attitude:
        kw.update(attitude=x_o[None, 3:], attitude_sigma=sig[None, 3:])
    else:
        p[3:, 3:] = 0.0
    expect = np.linalg.solve(n_r + p, n_r @ x_r + p @ x_o)
    fused = ptx.bundle_adjust(problem.replace(**kw))
    x_f = _eo_vector(fused)
    assert np.all(np.abs(x_f[:3] - x_r[:3]) > 0.05)  # the observations did move it
    np.testing.assert_allclose(x_f[:3], expect[:3], atol=5e-3)
    np.testing.assert_allclose(x_f[3:], expect[3:], atol=1e-5)
    # sigma0 and the redundancy count the 3 (6) observations; the residuals are the fused minus observed
    assert fused.redundancy == res.redundancy + (6 if with_attitude else 3)
    np.testing.assert_allclose(fused.gnss_residuals[0], x_f[:3] - x_o[:3], atol=1e-9)
    wsq = res.sigma0**2 * res.redundancy
    assert fused.sigma0**2 * fused.redundancy > wsq  # the observations' residuals are in it


def test_a_very_strong_position_prior_holds_the_camera_at_the_prior():
    problem = _single_image()
    g = np.array([[500101.5, 4000049.0, 701.0]])  # 1-2 m off the truth
    res = ptx.bundle_adjust(problem.replace(gnss_position=g, gnss_sigma=1e-5))
    np.testing.assert_allclose(np.asarray(res.exterior.position), g, atol=1e-6)
    # its cofactor is the prior's: std = sigma0 x 1e-5 (sigma0 > 1: the prior is off the truth)
    np.testing.assert_allclose(res.exterior_std[0, :3] / res.sigma0, 1e-5, rtol=1e-3)


def test_ties_and_gnss_alone_recover_the_block(free_block):
    """No control: refused without GNSS ("no datum"); with GNSS positions of
    sigma 0.5 m (truth + that noise), converged, every centre within 3x its
    reported sigma of the truth, check points too, and the report and the
    JSON carry the GNSS residuals."""
    problem, truth = free_block
    with pytest.raises(ValueError, match="no datum"):
        ptx.bundle_adjust(problem)
    sigma = 0.5
    gp = problem.replace(gnss_position=_gnss(truth, sigma, 1), gnss_sigma=sigma)
    res = ptx.bundle_adjust(gp)
    assert res.converged
    err = np.asarray(res.exterior.position) - np.asarray(truth.exterior.position)
    assert np.all(np.abs(err) < 3 * res.exterior_std[:, :3]), (err, res.exterior_std[:, :3])
    chk = problem.roles == "check"
    assert np.all(np.abs(res.check_residuals) < 3 * res.point_std[chk])
    # redundancy: 2 per image observation + 3 per GNSS position - 6 per image - 3 per point
    assert (
        res.redundancy
        == 2 * problem.n_observations + 3 * problem.n_images - 6 * problem.n_images - 3 * problem.n_points
    )
    assert 0.8 < res.sigma0 < 1.2
    report = res.report(unit="m")
    assert f"GNSS positions ({problem.n_images}): residual RMS" in report
    assert np.all(np.isfinite(res.gnss_residuals))
    assert all("gnss_residual" in img for img in res.to_dict()["images"])
    assert "parts" not in report and len(res.parts) == 1
    # the banded path (large blocks; its selected inversion for the precision) sees the GNSS too
    band = ptx.bundle_adjust(gp, linear_solver="band")
    np.testing.assert_allclose(band.exterior.position, res.exterior.position, atol=1e-6)
    np.testing.assert_allclose(band.exterior_std, res.exterior_std, rtol=1e-6)


def test_lever_arm_is_applied(free_block):
    """GNSS antennas 2.5 m above the camera (camera frame z back: up for a
    nadir image): with the lever arm the centres are recovered, without it
    they sit ~2.5 m high."""
    problem, truth = free_block
    lever = np.array([0.3, -0.2, 2.5])
    gnss = _gnss(truth, 0.3, 2, lever=lever)
    ok = ptx.bundle_adjust(problem.replace(gnss_position=gnss, gnss_sigma=0.3, lever_arm=lever))
    err = np.asarray(ok.exterior.position) - np.asarray(truth.exterior.position)
    assert np.all(np.abs(err) < 3 * ok.exterior_std[:, :3])
    off = ptx.bundle_adjust(problem.replace(gnss_position=gnss, gnss_sigma=0.3))
    dz = np.asarray(off.exterior.position)[:, 2] - np.asarray(truth.exterior.position)[:, 2]
    assert np.all(np.abs(dz - 2.5) < 0.5)


def test_one_strip_with_gnss_alone_is_refused_until_attitudes_fix_its_roll():
    problem, truth = synthetic_block(1, strips=1, images_per_strip=5, n_control=0, n_check=2, n_tie=60)
    gp = problem.replace(gnss_position=_gnss(truth, 0.5, 3), gnss_sigma=0.5)
    with pytest.raises(ValueError, match="one line"):
        ptx.bundle_adjust(gp)
    two = gp.replace(gnss_position=np.where(np.arange(5)[:, None] < 2, np.nan, gp.gnss_position))
    with pytest.raises(ValueError, match="no datum"):  # 3 positions on a line: no datum either
        ptx.bundle_adjust(two)
    att = np.asarray(truth.exterior.angles) + np.radians(0.01) * np.random.default_rng(4).standard_normal((5, 3))
    res = ptx.bundle_adjust(gp.replace(attitude=att, attitude_sigma=np.radians(0.01)))
    assert res.converged
    assert "attitudes (5): residual RMS" in res.report()


def test_a_block_held_together_only_by_gnss_is_reported(free_block):
    """Drop every point seen on both halves of the block (images 1-2 and
    3-4 of each strip): two parts, each with its own ties, linked only by
    the GNSS positions.  The adjustment runs (GNSS is a datum for each) and
    the report says so."""
    problem, truth = free_block
    strip = (np.arange(problem.n_images) % 4) // 2
    both = np.zeros(problem.n_points, bool)
    for p in range(problem.n_points):
        both[p] = len(set(strip[problem.obs_image[problem.obs_point == p]])) > 1
    keep_obs = ~both[problem.obs_point]
    new_id = np.cumsum(~both) - 1
    sub = ptx.BundleProblem(
        problem.cameras, problem.exterior, problem.points[~both], problem.obs_image[keep_obs],
        new_id[problem.obs_point[keep_obs]], problem.obs_xy[keep_obs], obs_sigma=problem.obs_sigma[keep_obs],
        roles=problem.roles[~both], gnss_position=_gnss(truth, 0.5, 5), gnss_sigma=0.5,
    )  # fmt: skip
    res = ptx.bundle_adjust(sub)
    assert sorted(len(q) for q in res.parts) == [4, 4]
    half = sub.replace(gnss_position=np.where(strip[:, None] == 1, np.nan, sub.gnss_position))
    with pytest.raises(ValueError, match="no datum of the part of 4 image"):  # GNSS on one part only
        ptx.bundle_adjust(half)
    assert "falls into 2 parts that share no point" in res.report()
    assert len(res.to_dict()["parts"]) == 2


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"gnss_sigma": 0.0}, "gnss_sigma must be positive"),
        ({"gnss_sigma": -1.0}, "gnss_sigma must be positive"),
        ({"gnss_sigma": np.nan}, "gnss_sigma must be positive"),
        ({}, "needs gnss_sigma"),
        ({"gnss_sigma": 1.0, "lever_arm": [0, 0]}, "lever_arm"),
    ],
)
def test_bad_gnss_sigma_is_refused(free_block, kw, match):
    problem, truth = free_block
    with pytest.raises(ValueError, match=match):
        ptx.BundleProblem(
            problem.cameras, problem.exterior, problem.points, problem.obs_image, problem.obs_point,
            problem.obs_xy, gnss_position=np.asarray(truth.exterior.position), **kw,
        )  # fmt: skip


@pytest.mark.parametrize("sigma", [0.0, -0.1])
def test_bad_attitude_sigma_is_refused(free_block, sigma):
    problem, truth = free_block
    with pytest.raises(ValueError, match="attitude_sigma must be positive"):
        problem.replace(attitude=np.asarray(truth.exterior.angles), attitude_sigma=sigma)


def test_cli_position_sigma_takes_the_start_positions_as_gnss(free_block, tmp_path, capsys):
    """`photax bundle BLOCK --position-sigma 5`: the block's start positions
    (truth + 5 m noise) as GNSS of sigma 5 m: no "no datum" refusal, the
    report carries the GNSS residuals; without it exit 2; a sigma <= 0 exit 2."""
    problem, truth = free_block
    folder = write_block(problem, tmp_path / "blk")
    assert main(["bundle", str(folder), "--quiet", "--no-progress"]) == 2
    assert "no datum" in capsys.readouterr().err
    assert main(["bundle", str(folder), "--position-sigma", "0", "--quiet", "--no-progress"]) == 2
    assert "--position-sigma must be a positive number" in capsys.readouterr().err
    assert main(["bundle", str(folder), "--position-sigma", "5", "--attitude-sigma", "-0.1", "--quiet"]) == 2
    assert "--attitude-sigma must be a positive number" in capsys.readouterr().err
    assert main(["bundle", str(folder), "--lever-arm", "0", "0", "1", "--quiet"]) == 2
    assert "--lever-arm needs --position-sigma" in capsys.readouterr().err
    out = tmp_path / "res.json"
    assert main(["bundle", str(folder), "--position-sigma", "5", "--quiet", "--no-progress", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "GNSS positions (8): residual RMS" in text
    images = json.loads(out.read_text())["images"]
    pos = np.array([img["position"] for img in images])
    std = np.array([img["std"][:3] for img in images])
    assert np.all(np.abs(pos - np.asarray(truth.exterior.position)) < 3 * std)


def test_robust_adjustment_counts_the_gnss_in_its_cost(free_block):
    """Huber (with its point pass): the final cost is 0.5 sum rho(|r|^2) of
    the image residuals plus 0.5 sum of the squared GNSS residuals over their
    sigma, recomputed here from the result; the centres within 3 sigma."""
    problem, truth = free_block
    sigma, d = 0.5, 1.5
    res = ptx.bundle_adjust(problem.replace(gnss_position=_gnss(truth, sigma, 7), gnss_sigma=sigma),
                            loss="huber", loss_scale=d)  # fmt: skip
    s2 = np.sum((res.residuals / problem.obs_sigma) ** 2, axis=1)
    rho = np.where(s2 <= d**2, s2, 2 * d * np.sqrt(s2) - d**2)
    expect = 0.5 * np.sum(rho) + 0.5 * np.sum((res.gnss_residuals / sigma) ** 2)
    assert res.cost == pytest.approx(expect, rel=1e-9)
    err = np.asarray(res.exterior.position) - np.asarray(truth.exterior.position)
    assert np.all(np.abs(err) < 3 * res.exterior_std[:, :3])
