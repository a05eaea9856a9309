"""Georeferencing a free network: the 7-parameter similarity and the GCP-constrained bundle
(photax.bundle._georeference), on a synthetic block with known truth moved into a model frame."""

from __future__ import annotations

import numpy as np
import pytest

import photax as ptx
from photax.io import GCPTable
from photax.scene import synthetic_block


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_similarity_recovers_scale_rotation_translation():
    rng = np.random.default_rng(0)
    r, s, t = _rotation(rng), 37.5, np.array([500_000.0, 4_000_000.0, 120.0])
    src = rng.normal(0, 10, (8, 3))
    sim = ptx.similarity_transform(src, s * src @ r.T + t)
    assert sim.scale == pytest.approx(s, rel=1e-13)
    np.testing.assert_allclose(sim.rotation, r, atol=1e-13)
    np.testing.assert_allclose(sim.translation, t, rtol=0, atol=1e-8)
    assert sim.rms < 1e-8
    # a reflection is never returned: the closest proper rotation
    mirrored = ptx.similarity_transform(src, src * [1, 1, -1])
    assert np.linalg.det(mirrored.rotation) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="one line"):
        ptx.similarity_transform(np.outer(np.arange(4.0), [1, 2, 3]), rng.normal(size=(4, 3)))
    with pytest.raises(ValueError, match="at least 3"):
        ptx.similarity_transform(src[:2], src[:2])


def _model_and_gcps(noise_px: float, seed: int = 0):
    """The synthetic block's truth (UTM-like) moved by a known similarity into a small model frame
    (as COLMAP leaves it), its tie points only; the control and check points as a GCP table of
    pixel measurements."""
    prob, truth = synthetic_block(seed, noise_px=noise_px)
    rng = np.random.default_rng(42)
    to_model = ptx.Similarity(0.013, _rotation(rng), np.array([3.0, -2.0, 1.5]), np.zeros((0, 3)))
    eo = truth.exterior
    tie = prob.roles == "tie"
    sel = tie[prob.obs_point]
    new = np.cumsum(tie) - 1
    model = ptx.BundleProblem(
        truth.camera,
        ptx.ExteriorOrientation(to_model.apply(np.asarray(eo.position)),
                                np.asarray(ptx.rotation.angles_from_matrix(to_model.rotation @ np.asarray(eo.rotation),
                                                                           eo.convention)), eo.convention),
        to_model.apply(truth.points[tie]), prob.obs_image[sel], new[prob.obs_point[sel]], prob.obs_xy[sel],
        obs_sigma=prob.obs_sigma[sel], image_names=[f"images/{n}.jpg" for n in prob.image_names],
        point_names=[str(k + 1) for k in range(int(tie.sum()))],
    )  # fmt: skip
    g = ~sel
    px = np.asarray(truth.camera.image_to_pixel(prob.obs_xy[g]))
    k = prob.obs_point[g]
    table = GCPTable(
        names=np.array([prob.point_names[j] for j in k]), images=np.array([prob.image_names[i] for i in prob.obs_image[g]]),
        ground=truth.points[k], pixel=px, image_xy=None, sigma=np.full(len(k), np.nan), role=prob.roles[k].astype(str),
    )  # fmt: skip
    return model, table, truth, to_model


def test_noise_free_model_is_put_back_exactly():
    model, gcps, truth, to_model = _model_and_gcps(noise_px=0.0)
    geo = ptx.georeference(model, gcps)
    sim = geo.similarity
    assert sim.scale == pytest.approx(1 / to_model.scale, rel=1e-9)
    np.testing.assert_allclose(sim.rotation, to_model.rotation.T, atol=1e-9)
    np.testing.assert_allclose(sim.apply(to_model.apply(truth.points)), truth.points, rtol=0, atol=1e-5)
    res = geo.result
    assert res.converged
    np.testing.assert_allclose(res.exterior.position, truth.exterior.position, rtol=0, atol=1e-5)
    np.testing.assert_allclose(res.check_residuals, 0.0, atol=1e-5)


def test_noisy_model_check_points_within_their_sigma():
    model, gcps, truth, _ = _model_and_gcps(noise_px=0.5, seed=1)
    geo = ptx.georeference(model, gcps.__class__(**{**gcps.__dict__, "sigma": np.full(len(gcps), 0.5)}))
    res = geo.result
    assert res.converged
    check = geo.problem.roles == "check"
    assert check.sum() == 4
    z = res.check_residuals / res.point_std[check]
    assert np.all(np.abs(z) < 3.5), z  # each residual within 3.5 of its own sigma
    assert np.abs(res.check_residuals).max() > 1e-3  # noise reached them: not a trivial pass
    assert np.all(res.point_std[check] < 0.5)  # metres: the block is georeferenced, not floating
    rep = geo.report()
    assert "check point residuals" in rep and "similarity model -> ground" in rep


def test_gnss_positions_alone_georeference():
    model, gcps, truth, _ = _model_and_gcps(noise_px=0.0)
    gnss = {n: p for n, p in zip(model.image_names, np.asarray(truth.exterior.position))}
    geo = ptx.georeference(model, gnss={n.split("/")[-1]: p for n, p in gnss.items()}, gnss_sigma=0.05)
    assert geo.result.converged and geo.similarity.rms < 1e-6
    tie_truth = geo.similarity.apply(model.points)  # exact here: the similarity is, and the model is the truth moved
    np.testing.assert_allclose(geo.result.points, tie_truth, rtol=0, atol=1e-5)
    np.testing.assert_allclose(geo.result.exterior.position, truth.exterior.position, rtol=0, atol=1e-5)


def test_too_few_points_is_an_error():
    model, gcps, _, _ = _model_and_gcps(noise_px=0.0)
    keep = np.isin(gcps.names, np.unique(gcps.names[gcps.role == "control"])[:2]) | (gcps.role == "check")
    with pytest.raises(ValueError, match="needs 3 points"):
        ptx.georeference(model, gcps.subset(keep))
    with pytest.raises(ValueError, match="GCPs .* or GNSS"):
        ptx.georeference(model)
