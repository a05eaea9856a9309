"""photax.fit_piecewise_affine (issue 24, item 4): one affine per Delaunay triangle of the control points.

References: scikit-image's PiecewiseAffineTransform (the same construction, its own code), the control
points themselves, refits without each point (the leave-one-out residuals), an affine map (which every
triangle must carry unchanged), and scipy's Delaunay for the hull outside which the map is NaN.
"""

import numpy as np
import pytest

import photax as ptx
from photax.polynomial import fit_piecewise_affine


def _points(n=25, seed=0):
    rng = np.random.default_rng(seed)
    src = rng.uniform([500000, 4000000], [503000, 4002000], size=(n, 2))  # map metres: raw values are large
    u = (src - src.mean(0)) / 1000
    dst = np.stack([800 + 310 * u[:, 0] + 20 * np.sin(u[:, 1] * 2), 600 - 305 * u[:, 1] + 15 * u[:, 0] ** 2], 1)
    return src, dst


def test_exact_at_control_points_and_equals_scikit_image_inside_the_hull():
    from scipy.spatial import Delaunay

    src, dst = _points()
    model = fit_piecewise_affine(src, dst)
    np.testing.assert_allclose(np.asarray(model(src)), dst, atol=1e-9)
    assert float(model.rmse) < 1e-9
    q = np.random.default_rng(1).uniform([500000, 4000000], [503000, 4002000], size=(2000, 2))
    origin = src.mean(0)
    hull = Delaunay(src - origin).find_simplex(q - origin) >= 0
    assert 500 < hull.sum() < len(q)  # both kinds of points are exercised
    np.testing.assert_array_equal(np.asarray(model.inside(q)), hull)
    skt = pytest.importorskip("skimage.transform")
    ref = skt.PiecewiseAffineTransform.from_estimate(src - origin, dst)
    assert ref
    np.testing.assert_allclose(np.asarray(model(q[hull])), ref(q[hull] - origin), rtol=0, atol=1e-9)


def test_outside_the_hull_it_is_nan():
    """No extrapolation (issue 24 follow-up): NaN exactly where scipy's Delaunay finds no triangle."""
    from scipy.spatial import Delaunay

    src, dst = _points(12, seed=2)
    model = fit_piecewise_affine(src, dst)
    q = np.random.default_rng(3).uniform([499000, 3999000], [504000, 4003000], size=(300, 2))
    origin = src.mean(0)
    hull = Delaunay(src - origin).find_simplex(q - origin) >= 0
    assert 50 < (~hull).sum() < 290  # both kinds
    values = np.asarray(model(q))
    assert np.isnan(values[~hull]).all() and np.isfinite(values[hull]).all()
    assert np.isfinite(np.asarray(model(src))).all()  # the hull vertices themselves have values
    # the hull's vertices have no leave-one-out residual (outside the others' hull); the rest have one
    on_hull = np.zeros(len(src), bool)
    on_hull[Delaunay(src - origin).convex_hull.ravel()] = True
    loo = np.asarray(model.loo_residuals)
    assert np.isnan(loo[on_hull]).all() and np.isfinite(loo[~on_hull]).all()


def test_an_affine_field_is_reproduced_exactly():
    src, _ = _points(15, seed=4)
    a = np.array([[0.3, -0.02], [0.01, -0.31]])
    dst = (src - 500000) @ a + np.array([12.0, 4000.0])
    model = fit_piecewise_affine(src, dst)
    q = np.random.default_rng(5).uniform([499000, 3999000], [504000, 4003000], size=(200, 2))  # in and out
    inside = np.asarray(model.inside(q))
    assert 20 < inside.sum() < len(q)
    np.testing.assert_allclose(np.asarray(model(q[inside])), (q[inside] - 500000) @ a + [12.0, 4000.0], atol=1e-8)
    loo = np.asarray(model.loo_residuals)
    np.testing.assert_allclose(loo[np.isfinite(loo)], 0, atol=1e-8)


def test_leave_one_out_residuals_rebuild_the_triangulation():
    src, dst = _points(12, seed=3)
    model = fit_piecewise_affine(src, dst)
    for i in range(12):
        keep = np.arange(12) != i
        refit = fit_piecewise_affine(src[keep], dst[keep])
        np.testing.assert_allclose(np.asarray(model.loo_residuals[i]), np.asarray(refit(src[i])) - dst[i], atol=1e-8)
    assert np.nanmax(np.abs(np.asarray(model.loo_residuals))) > 0.1  # a non-affine field: the refits miss


def test_it_rectifies_like_the_affine_polynomial_on_an_affine_field():
    src, _ = _points(10, seed=8)
    a = np.array([[0.01, 0.0], [0.0, -0.01]])
    dst = (src - [500000, 4002000]) @ a + [1.0, 1.0]
    img = np.random.default_rng(9).random((40, 40)).astype(np.float32)
    grid = ptx.Grid((100.0, 0, 500000.0, 0, -100.0, 4002000.0), (30, 20))  # the points' bounding box
    out = ptx.rectify(img, ptx.fit_piecewise_affine(src, dst), grid, approx=None)
    out_poly = ptx.rectify(img, ptx.fit_polynomial(src, dst, 1), grid, approx=None)
    valid = np.isfinite(out)  # no-data outside the GCPs' hull
    assert 0.2 < valid.mean() < np.isfinite(out_poly).mean()
    np.testing.assert_allclose(out[valid], out_poly[valid], atol=1e-5)


def test_bad_control_points_are_refused():
    src, dst = _points(6)
    with pytest.raises(ValueError, match="at least 3 points"):
        fit_piecewise_affine(src[:2], dst[:2])
    with pytest.raises(ValueError, match="one line"):
        fit_piecewise_affine(np.c_[np.arange(5.0), 2 * np.arange(5.0)], dst[:5])
    with pytest.raises(ValueError, match="duplicated"):
        fit_piecewise_affine(np.r_[src, src[:1]], np.r_[dst, dst[:1]])
