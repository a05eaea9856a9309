"""Block adjustment of RPC images with tie points (issue 23, item 2): three overlapping views of a
synthetic push-broom scene, their RPCs fitted by fit_rpc, observations made with known per-image
corrections and pixel noise; checked against the truth, against refine_rpc where they must agree, and
for the refusals."""

import jax.numpy as jnp
import numpy as np
import pytest

from photax.earth import radii_of_curvature
from photax.pushbroom import fit_rpc
from photax.rpc import RPCCamera, refine_rpc
from photax.rpc_block import adjust_rpc_block
from photax.scene import pushbroom_scene

NOISE = 0.3  # px
VIEWS = [dict(roll=0.0, pitch=0.0), dict(roll=15.0, pitch=-20.0), dict(roll=-15.0, pitch=20.0)]


@pytest.fixture(scope="module")
def cameras():
    out = []
    for v in VIEWS:
        s = pushbroom_scene(image_size=(1000, 1000), n_gcp=3, n_check=3, **v)
        out.append(fit_rpc(s.camera, s.height_range, grid=9, layers=4).camera)
    return out


def _truth(model, seed=1):
    rng = np.random.default_rng(seed)
    k = np.zeros((3, 2, 3))
    k[:, :, 0] = rng.normal(0.0, 5.0, (3, 2))  # px
    if model == "shift-drift":
        k[:, :, 2] = rng.normal(0.0, 2e-3, (3, 2))  # px per row: 2 px over the image
    return k


def _points(cameras, rng, k):
    pix = rng.uniform(100.0, 900.0, (k, 2))
    h = rng.uniform(0.0, 1500.0, k)
    return np.column_stack([np.asarray(cameras[0].to_ground(jnp.asarray(pix), jnp.asarray(h))), h])


def _observe(cameras, truth, ground, rng, images=(0, 1, 2)):
    """Rows point, image, column, row: the true (corrected) projection plus noise."""
    rows = []
    for i in images:
        c = cameras[i]
        p = np.asarray(RPCCamera(c.coefficients, c.offsets, c.scales, truth[i])(jnp.asarray(ground)))
        p = p + rng.normal(0.0, NOISE, p.shape)
        rows += [[k, i, *p[k]] for k in range(len(ground))]
    return np.array(rows)


def _enu(ground, ref):
    m, n = radii_of_curvature(ref[:, 1])
    return (ground - ref) * np.column_stack(
        [np.deg2rad(n * np.cos(np.deg2rad(ref[:, 1]))), np.deg2rad(m), np.ones(len(ref))]
    )


@pytest.mark.parametrize("model", ["shift", "shift-drift"])
def test_block_recovers_the_truth(cameras, model):
    rng = np.random.default_rng(2)
    truth = _truth(model)
    tie_ground = _points(cameras, rng, 20)
    ties = _observe(cameras, truth, tie_ground, rng)
    gcp_ground = _points(cameras, rng, 4)
    gcps = (gcp_ground, _observe(cameras, truth, gcp_ground, rng))
    res = adjust_rpc_block(cameras, ties, gcps, model=model, pixel_sigma=NOISE)
    assert 0.75 < res.sigma0 < 1.25  # noise as given: the unit weight is 1
    adjusted = res.correction_sigmas > 0
    assert adjusted.sum() == 3 * 2 * (1 if model == "shift" else 2)
    z = (res.corrections - truth)[adjusted] / res.correction_sigmas[adjusted]
    assert np.all(np.abs(z) < 3.0), z
    for i in range(3):  # the per-image covariance ortho_uncertainty takes, in (a0, a1, a2, b0, b1, b2) order
        np.testing.assert_allclose(np.sqrt(np.diag(res.correction_covariance(i))), res.correction_sigmas[i].ravel())
    zt = _enu(tie_ground[res.tie_ids], res.tie_ground) / res.tie_sigmas
    assert np.mean(np.abs(zt) < 2.0) > 0.9 and np.all(np.abs(zt) < 4.0)  # ~95 % within 2 sigma
    assert np.all(res.tie_sigmas < 3.0)  # m: a few tenths of a 2 m pixel, heights from the parallax
    assert res.rmse < 2.0 * NOISE and np.abs(res.standardized).max() < 4.0
    # the refined cameras reproduce the true projection
    c = cameras[1]
    true_cam = RPCCamera(c.coefficients, c.offsets, c.scales, truth[1])
    diff = np.asarray(res.cameras[1](jnp.asarray(tie_ground))) - np.asarray(true_cam(jnp.asarray(tie_ground)))
    assert np.abs(diff).max() < 5 * NOISE / np.sqrt(3)


def test_weighted_gcps(cameras):
    """GCPs as weighted observations: nearly fixed ones give the fixed GCPs' adjustment; loose ones
    move within their sigma and the corrections stay on the truth."""
    rng = np.random.default_rng(7)
    truth = _truth("shift")
    tie_ground = _points(cameras, rng, 12)
    ties = _observe(cameras, truth, tie_ground, rng)
    g = _points(cameras, rng, 4)
    gcps = (g, _observe(cameras, truth, g, rng))
    fixed = adjust_rpc_block(cameras, ties, gcps, pixel_sigma=NOISE)
    tight = adjust_rpc_block(cameras, ties, gcps, pixel_sigma=NOISE, gcp_sigma=1e-5)
    np.testing.assert_allclose(tight.corrections, fixed.corrections, atol=1e-4)
    assert tight.redundancy == fixed.redundancy  # 3 unknowns and 3 observations more per GCP
    assert np.all(fixed.gcp_residuals == 0.0)
    loose = adjust_rpc_block(cameras, ties, gcps, pixel_sigma=NOISE, gcp_sigma=[1.0, 1.0, 2.0])
    assert np.all(np.isfinite(loose.gcp_residuals)) and np.abs(loose.gcp_residuals).max() < 3 * 2.0
    adjusted = loose.correction_sigmas > 0
    q_loose, q_fixed = loose.correction_sigmas / loose.sigma0, fixed.correction_sigmas / fixed.sigma0
    assert np.all(q_loose[adjusted] > q_fixed[adjusted])  # less control: larger cofactors
    z = (loose.corrections - truth)[adjusted] / loose.correction_sigmas[adjusted]
    assert np.all(np.abs(z) < 3.0), z


@pytest.mark.filterwarnings("ignore:.*GCP\\(s\\) outside the .* image, inside the RPC")  # views that see less
def test_without_ties_each_image_equals_refine_rpc(cameras):
    """Fixed GCPs, no ties: the block falls apart into refine_rpc's separate least-squares fits."""
    rng = np.random.default_rng(3)
    truth = _truth("shift-drift")
    gcp_ground = _points(cameras, rng, 6)
    obs = _observe(cameras, truth, gcp_ground, rng)
    res = adjust_rpc_block(cameras, np.zeros((0, 4)), (gcp_ground, obs), model="shift-drift")
    for i in range(3):
        o = obs[obs[:, 1] == i]
        ref = refine_rpc(cameras[i], gcp_ground[o[:, 0].astype(int)], o[:, 2:], "shift-drift")
        np.testing.assert_allclose(res.corrections[i], ref.correction, atol=1e-7)
        np.testing.assert_allclose(res.residuals[res.image == i], ref.residuals, atol=1e-7)
    # pooled over the images, sigma0 is the root of the summed v'v over the summed redundancy
    assert res.redundancy == 3 * (2 * 6 - 4)


@pytest.mark.filterwarnings("ignore:.*GCP\\(s\\) outside the .* image, inside the RPC")  # views that see less
def test_ties_carry_the_datum_to_images_without_gcps(cameras):
    """Two GCPs, each seen in one image only; image 2 has none: refined alone, image 2 cannot be
    corrected; in the block the ties carry the GCPs' datum to it, and the check points show it."""
    rng = np.random.default_rng(4)
    truth = _truth("shift")
    tie_ground = _points(cameras, rng, 15)
    ties = _observe(cameras, truth, tie_ground, rng)
    control = _points(cameras, rng, 2)
    check = _points(cameras, rng, 8)
    obs0 = _observe(cameras, truth, control[:1], rng, images=(0,))
    obs1 = _observe(cameras, truth, control[1:], rng, images=(1,))
    obs1[:, 0] = 1
    check_obs = _observe(cameras, truth, check, rng)
    check_obs[:, 0] += 2
    ground = np.concatenate([control, check])
    is_check = np.arange(len(ground)) >= 2
    res = adjust_rpc_block(
        cameras, ties, (ground, np.concatenate([obs0, obs1, check_obs])), check=is_check, pixel_sigma=NOISE
    )
    # alone: images 0 and 1 shifted on their one GCP, image 2 left as it is
    single = [
        refine_rpc(cameras[0], control[:1], obs0[:, 2:]).camera,
        refine_rpc(cameras[1], control[1:], obs1[:, 2:]).camera,
        cameras[2],
    ]
    single_res = np.array([np.asarray(single[int(o[1])](jnp.asarray(ground[int(o[0])]))) - o[2:] for o in check_obs])
    single_rmse = np.sqrt(np.mean(np.sum(single_res**2, 1)))
    assert res.check_rmse < 0.5 * single_rmse
    # two single-ray GCPs are a weak datum: the check residuals are the corrections' own uncertainty
    # (up to ~0.6 px in image 2) over the noise -- their mean per image and axis within 3 sigma of it
    for i in range(3):
        mean = res.check_residuals[res.check_image == i].mean(0)
        spread = np.sqrt(res.correction_sigmas[i, :, 0] ** 2 + NOISE**2 / len(check))
        assert np.all(np.abs(mean) < 3 * spread), (i, mean, spread)
    assert len(res.check_residuals) == len(check_obs)
    # each check point, intersected with the refined cameras, lands near its known ground (m; 2 m pixels,
    # the height the weakest: the datum's uncertainty along the rays)
    assert np.all(np.isfinite(res.check_ground_residuals[2:])) and np.all(np.isnan(res.check_ground_residuals[:2]))
    assert np.abs(res.check_ground_residuals[2:, :2]).max() < 3.0
    assert np.abs(res.check_ground_residuals[2:, 2]).max() < 10.0
    z = (res.corrections - truth)[:, :, 0] / res.correction_sigmas[:, :, 0]
    assert np.all(np.abs(z) < 3.0), z


def test_no_datum_is_refused_unless_a_prior_is_given(cameras):
    rng = np.random.default_rng(5)
    truth = _truth("shift")
    tie_ground = _points(cameras, rng, 12)
    ties = _observe(cameras, truth, tie_ground, rng)
    with pytest.raises(ValueError, match="no datum"):
        adjust_rpc_block(cameras, ties)
    g = _points(cameras, rng, 2)
    with pytest.raises(ValueError, match="no datum"):  # check points only
        adjust_rpc_block(cameras, ties, (g, _observe(cameras, truth, g, rng)), check=[True, True])
    # a prior on the corrections: their differences between images come from the ties alone
    res = adjust_rpc_block(cameras, ties, correction_sigma=10.0, pixel_sigma=NOISE)
    cov = res.covariance  # order: image, axis (one shift term per axis)
    for i in (1, 2):
        for axis in range(2):
            a, b = 2 * i + axis, axis
            sd = np.sqrt(cov[a, a] + cov[b, b] - 2 * cov[a, b])
            d = (res.corrections[i, axis, 0] - res.corrections[0, axis, 0]) - (truth[i, axis, 0] - truth[0, axis, 0])
            assert abs(d) < 3 * sd, (i, axis, d, sd)


def test_a_blunder_in_a_tie_is_flagged(cameras):
    rng = np.random.default_rng(6)
    truth = _truth("shift")
    tie_ground = _points(cameras, rng, 15)
    ties = _observe(cameras, truth, tie_ground, rng)
    ties[17, 2] += 4.0  # px, in one tie measurement
    g = _points(cameras, rng, 4)
    res = adjust_rpc_block(cameras, ties, (g, _observe(cameras, truth, g, rng)), pixel_sigma=NOISE)
    w = np.abs(res.standardized)
    k = np.unravel_index(np.nanargmax(w), w.shape)
    assert k == (17, 0) and w[k] > 4.0


def test_bad_input(cameras):
    ties = np.array([[0, 0, 10.0, 10.0], [0, 1, 12.0, 10.0], [1, 2, 50.0, 50.0]])
    g = (np.array([[10.0, 45.0, 100.0]]), np.array([[0, 0, 500.0, 500.0]]))
    with pytest.raises(ValueError, match="point 1 is measured in 1 image"):
        adjust_rpc_block(cameras, ties, g)
    with pytest.raises(ValueError, match="model"):
        adjust_rpc_block(cameras, ties[:2], g, model="cubic")
    with pytest.raises(ValueError, match="image indices"):
        adjust_rpc_block(cameras, np.array([[0, 0, 1.0, 1.0], [0, 3, 1.0, 1.0]]), g)
    with pytest.raises(ValueError, match="gcp indices"):
        adjust_rpc_block(cameras, ties[:2], (g[0], np.array([[1, 0, 5.0, 5.0]])))
    with pytest.raises(ValueError, match="singular"):  # affine: one GCP in one image fixes nothing else
        adjust_rpc_block(cameras, ties[:2], g, model="affine")
