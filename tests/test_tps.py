"""photax.fit_tps (issue 24, item 4): the thin-plate spline beside the polynomials.

References: scikit-image's ThinPlateSplineTransform (the same spline, fitted its own way), the control
points themselves (an interpolating spline passes through them), refits without each point (the
leave-one-out residuals), and an affine map (which a thin-plate spline reproduces exactly).
"""

import numpy as np
import pytest

import photax as ptx
from photax.polynomial import fit_tps


def _points(n=25, seed=0):
    rng = np.random.default_rng(seed)
    src = rng.uniform([500000, 4000000], [503000, 4002000], size=(n, 2))  # map metres: raw values are large
    u = (src - src.mean(0)) / 1000
    dst = np.stack([800 + 310 * u[:, 0] + 20 * np.sin(u[:, 1] * 2), 600 - 305 * u[:, 1] + 15 * u[:, 0] ** 2], 1)
    return src, dst


def test_interpolates_its_control_points_and_equals_scipy_and_scikit_image():
    """scipy's RBFInterpolator (thin_plate_spline, degree 1: the same spline, float64) to 1e-6 px;
    scikit-image's ThinPlateSplineTransform to its own precision: it assembles and solves its system in
    float32, so it misses its own control points by ~1e-4 px at these coordinates (measured, below)."""
    from scipy.interpolate import RBFInterpolator

    src, dst = _points()
    model = fit_tps(src, dst)
    np.testing.assert_allclose(np.asarray(model(src)), dst, atol=1e-6)
    assert float(model.rmse) < 1e-6
    rng = np.random.default_rng(1)
    q = rng.uniform([500000, 4000000], [503000, 4002000], size=(500, 2))
    origin = src.mean(0)
    scipy_ref = RBFInterpolator(src - origin, dst, kernel="thin_plate_spline", degree=1)
    np.testing.assert_allclose(np.asarray(model(q)), scipy_ref(q - origin), atol=1e-6)
    skt = pytest.importorskip("skimage.transform")
    if not hasattr(skt, "ThinPlateSplineTransform"):
        pytest.skip("this scikit-image has no ThinPlateSplineTransform")
    ref = skt.ThinPlateSplineTransform.from_estimate(src - origin, dst)
    assert ref
    own = np.abs(ref(src - origin) - dst).max()  # scikit-image's float32 misfit at its control points
    assert 1e-6 < own < 1e-3
    assert np.abs(np.asarray(model(q)) - ref(q - origin)).max() < 2 * own


def test_leave_one_out_residuals_are_refits_without_the_point():
    src, dst = _points(12, seed=3)
    model = fit_tps(src, dst)
    for i in (0, 5, 11):
        keep = np.arange(12) != i
        refit = fit_tps(src[keep], dst[keep])
        np.testing.assert_allclose(np.asarray(model.loo_residuals[i]), np.asarray(refit(src[i])) - dst[i], atol=1e-8)
    assert np.all(np.isfinite(np.asarray(model.loo_residuals)))


def test_an_affine_map_is_reproduced_and_smoothing_relaxes_interpolation():
    src, _ = _points(15, seed=4)
    a = np.array([[0.3, -0.02], [0.01, -0.31]])
    dst = (src - 500000) @ a + np.array([12.0, 4000.0])
    model = fit_tps(src, dst)
    q = np.random.default_rng(5).uniform([500000, 4000000], [503000, 4002000], size=(50, 2))
    np.testing.assert_allclose(np.asarray(model(q)), (q - 500000) @ a + [12.0, 4000.0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(model.weights), 0, atol=1e-6)  # no bending (to rounding: dst ~ 1e3)
    src, dst = _points(30, seed=6)
    dst = dst + np.random.default_rng(7).normal(0, 2, dst.shape)
    smooth = fit_tps(src, dst, smoothing=0.01)
    assert 0.1 < float(smooth.rmse) < 4 and float(fit_tps(src, dst).rmse) < 1e-6


def test_a_tps_model_rectifies_like_a_polynomial():
    """Through photax.rectify: a TPS fitted to an affine relation rectifies like the affine polynomial."""
    src, _ = _points(10, seed=8)
    a = np.array([[0.01, 0.0], [0.0, -0.01]])
    dst = (src - [500000, 4002000]) @ a + [1.0, 1.0]
    img = np.random.default_rng(9).random((40, 40)).astype(np.float32)
    grid = ptx.Grid((20.0, 0, 500000.0, 0, -20.0, 4002000.0), (30, 30))
    out_tps = ptx.rectify(img, fit_tps(src, dst), grid, approx=None)
    out_poly = ptx.rectify(img, ptx.fit_polynomial(src, dst, 1), grid, approx=None)
    np.testing.assert_allclose(out_tps, out_poly, atol=1e-5, equal_nan=True)


def test_bad_control_points_are_refused():
    src, dst = _points(6)
    with pytest.raises(ValueError, match="at least 3 points"):
        fit_tps(src[:2], dst[:2])
    with pytest.raises(ValueError, match="one line"):
        fit_tps(np.c_[np.arange(5.0), 2 * np.arange(5.0)], dst[:5])
    with pytest.raises(ValueError, match="duplicated"):
        fit_tps(np.r_[src, src[:1]], np.r_[dst, dst[:1]])
    with pytest.raises(ValueError, match="smoothing"):
        fit_tps(src, dst, smoothing=-1)
