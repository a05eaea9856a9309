"""Polynomial and projective plane-to-plane fits against known truth and
independent implementations (scikit-image, OpenCV, plain numpy)."""

import cv2
import equinox as eqx
import jax
import numpy as np
import pytest
from skimage.transform import AffineTransform, PolynomialTransform, ProjectiveTransform

import photax
from photax.polynomial import exponents, fit_polynomial, fit_projective, n_coefficients

RNG = np.random.default_rng(7)
UTM = np.array([500000.0, 4000000.0])  # a UTM-scale origin


def _random_poly(order, rng):
    """A mildly nonlinear mapping on [-1, 1]^2 written with its own
    monomials (independent of photax's evaluation): an affine part plus
    decaying higher-order terms."""
    exps = exponents(order)
    coef = rng.normal(size=(len(exps), 2)) * (0.3 ** exps.sum(axis=1))[:, None] * 50
    coef[1:3] += [[900, 40], [-30, 950]]

    def f(p, centre, half):
        u = (p - centre) / half
        return np.stack([u[:, 0] ** i * u[:, 1] ** j for i, j in exps], axis=1) @ coef + 2000

    return f


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5])
def test_recovers_exact_polynomials(order):
    """Noise-free data from a polynomial of the same order: the fit is the
    truth at fresh points (to round-off)."""
    f = _random_poly(order, RNG)
    centre, half = np.array([300.0, 200.0]), 250.0
    src = RNG.uniform(50, 550, (n_coefficients(order) + 8, 2)) - [0, 100]
    m = fit_polynomial(src, f(src, centre, half), order)
    check = RNG.uniform(60, 540, (300, 2)) - [0, 100]
    np.testing.assert_allclose(np.asarray(m(check)), f(check, centre, half), rtol=0, atol=1e-8)
    assert float(m.rmse) < 1e-9 and np.asarray(m.residuals).shape == src.shape


def test_order5_on_utm_coordinates_needs_normalisation():
    """x ~ 5e5 m, y ~ 4e6 m, 5 km block: raw monomials reach 1e33, the raw
    design's condition number is beyond 1/eps, and a plain least-squares fit
    (numpy's SVD lstsq, or the normal equations) on them is wrong by metres;
    the normalised fit inside photax is exact to round-off."""
    f = _random_poly(5, RNG)
    centre, half = UTM + 2500, 2500.0
    src = UTM + RNG.uniform(0, 5000, (60, 2))
    dst = f(src, centre, half)
    check = UTM + RNG.uniform(100, 4900, (300, 2))
    truth = f(check, centre, half)

    m = fit_polynomial(src, dst, 5)
    ours = np.abs(np.asarray(m(check)) - truth).max()
    assert ours < 1e-6
    assert float(m.condition) < 1e4

    raw = lambda p: np.stack([p[:, 0] ** i * p[:, 1] ** j for i, j in exponents(5)], axis=1)  # noqa: E731
    coef, *_ = np.linalg.lstsq(raw(src), dst, rcond=None)
    naive = np.abs(raw(check) @ coef - truth).max()
    normal = np.abs(raw(check) @ np.linalg.solve(raw(src).T @ raw(src), raw(src).T @ dst) - truth).max()
    assert float(m.condition_raw) > 1e30
    assert naive > 1e-2 and normal > 1e-2
    assert naive > 1e5 * ours


def test_matches_skimage_polynomial_and_affine():
    """scikit-image's PolynomialTransform (order 2) and AffineTransform
    (= order 1) on the same points predict the same positions.

    scikit-image solves the homogeneous system ``[M | -X] [c; 1] = 0`` by
    SVD, i.e. *total* least squares, which differs from ordinary least
    squares once there is noise; so the data here are exact (noise-free)
    mappings, and the OLS solution is checked against numpy in
    ``test_weights_match_row_scaled_lstsq``.
    """
    src = RNG.uniform(0, 100, (30, 2))
    check = RNG.uniform(0, 100, (50, 2))
    quad = lambda p: np.c_[
        3 + 1.1 * p[:, 0] + 0.2 * p[:, 1] + 1e-3 * p[:, 0] ** 2 - 2e-3 * p[:, 0] * p[:, 1],  # noqa: E731
        -2 + 0.9 * p[:, 1] - 0.1 * p[:, 0] + 3e-3 * p[:, 1] ** 2,
    ]
    sk2 = PolynomialTransform.from_estimate(src, quad(src), order=2)
    np.testing.assert_allclose(np.asarray(fit_polynomial(src, quad(src), 2)(check)), sk2(check), rtol=0, atol=1e-8)
    aff = lambda p: p @ np.array([[1.1, -0.1], [0.2, 0.9]]) + [3.0, -2.0]  # noqa: E731
    sk1 = AffineTransform.from_estimate(src, aff(src))
    np.testing.assert_allclose(np.asarray(fit_polynomial(src, aff(src), 1)(check)), sk1(check), rtol=0, atol=1e-8)


def test_weights_match_row_scaled_lstsq():
    """Weighted fit = ordinary least squares on rows scaled by sqrt(w)
    (numpy lstsq on the normalised monomials built here)."""
    src = RNG.uniform(0, 10, (20, 2))
    dst = src @ [[1.0, 0.2], [-0.1, 0.8]] + 0.05 * src**2 + RNG.normal(scale=0.1, size=(20, 2))
    w = RNG.uniform(0.2, 5.0, 20)
    m = fit_polynomial(src, dst, 2, weights=w)
    a = np.stack([src[:, 0] ** i * src[:, 1] ** j for i, j in exponents(2)], axis=1)
    coef, *_ = np.linalg.lstsq(a * np.sqrt(w)[:, None], dst * np.sqrt(w)[:, None], rcond=None)
    np.testing.assert_allclose(np.asarray(m(src)), a @ coef, rtol=0, atol=1e-10)
    v = dst - a @ coef
    np.testing.assert_allclose(float(m.rmse_dof), np.sqrt(np.sum(w[:, None] * v**2) / (2 * (20 - 6))), rtol=1e-10)
    np.testing.assert_allclose(float(m.rmse), np.sqrt(np.sum(v**2) / 20), rtol=1e-10)


@pytest.mark.parametrize("order, weighted", [(1, False), (3, False), (2, True)])
def test_leave_one_out_equals_refits(order, weighted):
    src = UTM + RNG.uniform(0, 2000, (n_coefficients(order) + 6, 2))
    dst = RNG.uniform(0, 1, (len(src), 2)) + (src - UTM) @ [[0.5, 0.01], [0.02, -0.5]]
    w = RNG.uniform(0.5, 2, len(src)) if weighted else None
    m = fit_polynomial(src, dst, order, weights=w)
    loo = np.asarray(m.loo_residuals)
    for i in range(len(src)):
        keep = np.arange(len(src)) != i
        refit = fit_polynomial(src[keep], dst[keep], order, weights=None if w is None else w[keep])
        np.testing.assert_allclose(loo[i], np.asarray(refit(src[i : i + 1]))[0] - dst[i], rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("order", [1, 2, 3, 5])
def test_inverse_round_trip(order):
    """Map -> pixel model of a smooth distortion; the Newton inverse is exact
    and the fitted one reports an error that bounds the measured one on
    fresh points inside the domain."""
    src = UTM + RNG.uniform(0, 3000, (40, 2))
    u = (src - UTM - 1500) / 1500
    dst = np.c_[
        2000 + 1800 * u[:, 0] + 100 * u[:, 1] + 30 * u[:, 0] ** 2 - 20 * u[:, 0] * u[:, 1] + 5 * u[:, 1] ** 3,
        2000 - 50 * u[:, 0] + 1900 * u[:, 1] + 25 * u[:, 1] ** 2 + 8 * u[:, 0] ** 3,
    ]
    m = fit_polynomial(src, dst, order)
    lo, hi = src.min(axis=0), src.max(axis=0)
    fresh = lo + RNG.uniform(0, 1, (500, 2)) * (hi - lo)
    q = np.asarray(m(fresh))
    newton = m.inverse("newton")
    assert float(newton.max_error) < 1e-6
    np.testing.assert_allclose(np.asarray(newton(q)), fresh, rtol=0, atol=1e-6)
    fitted = m.inverse("fit")
    err = np.linalg.norm(np.asarray(fitted(q)) - fresh, axis=1)
    assert err.max() <= 1.5 * float(fitted.max_error) + 1e-9
    assert float(fitted.rmse) <= float(fitted.max_error)
    assert fitted.rms_error is fitted.rmse  # the old name still works
    if order == 1:  # the inverse of an affine map is affine: exact
        assert float(fitted.max_error) < 1e-6


def test_model_is_a_pytree_usable_under_jit_and_vmap():
    src = RNG.uniform(0, 100, (12, 2))
    m = fit_polynomial(src, src**1.5 / 10, 2)
    p = RNG.uniform(0, 100, (7, 3, 2))
    np.testing.assert_allclose(np.asarray(eqx.filter_jit(lambda mm, x: mm(x))(m, p)), np.asarray(m(p)), atol=1e-12)
    np.testing.assert_allclose(np.asarray(jax.vmap(m)(p[:, 0])), np.asarray(m(p[:, 0])), atol=1e-12)
    x, y = m.transform(p[..., 0], p[..., 1])
    np.testing.assert_allclose(np.stack([x, y], axis=-1), np.asarray(m(p)), atol=1e-12)
    assert photax.fit_polynomial is fit_polynomial and photax.PolynomialModel is type(m)


def test_polynomial_input_errors():
    src = RNG.uniform(0, 100, (30, 2))
    for order in range(1, 6):
        u = n_coefficients(order)
        with pytest.raises(ValueError, match=f"at least {u} points"):
            fit_polynomial(src[: u - 1], src[: u - 1], order)
    with pytest.raises(ValueError, match="order"):
        fit_polynomial(src, src, 6)
    bad = src.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"src_xy has NaN.*\[4\]"):
        fit_polynomial(bad, src, 1)
    with pytest.raises(ValueError, match="dst_xy"):
        fit_polynomial(src, np.where(np.arange(30)[:, None] == 2, np.inf, src), 1)
    dup = src.copy()
    dup[9] = dup[3]
    with pytest.raises(ValueError, match="duplicated"):
        fit_polynomial(dup, src, 2)
    line = np.c_[np.linspace(0, 10, 30), 2 * np.linspace(0, 10, 30) + 1]
    with pytest.raises(ValueError, match="rank-deficient"):
        fit_polynomial(line, src, 1)
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        fit_polynomial(src[:, :1], src, 1)
    with pytest.raises(ValueError, match="weights"):
        fit_polynomial(src, src, 1, weights=-np.ones(30))


def _homography_points(h, n, rng, noise=0.0):
    src = rng.uniform(0, 1000, (n, 2)) + UTM / 100
    d = np.c_[src, np.ones(n)] @ h.T
    return src, d[:, :2] / d[:, 2:] + rng.normal(scale=noise, size=(n, 2))


H_TRUE = np.array([[1.2, 0.15, 30.0], [-0.05, 0.95, -12.0], [2e-5, 4e-5, 1.0]])


def test_projective_exact_four_points_matches_opencv():
    """OpenCV takes float32 points and solves the raw 8 x 8 system (no
    normalisation), so the points here are small float32-exact numbers and
    the comparison is on predicted positions; at UTM-scale coordinates the
    4 points are still fitted exactly by ours."""
    rng = np.random.default_rng(7)  # local: the result must not depend on test order
    src = rng.uniform(0, 100, (4, 2)).astype(np.float32)
    d = np.c_[src, np.ones(4)] @ H_TRUE.T
    dst = (d[:, :2] / d[:, 2:]).astype(np.float32)
    m = fit_projective(src.astype(float), dst.astype(float))
    ref = cv2.getPerspectiveTransform(src, dst)
    check = rng.uniform(0, 100, (50, 2))
    np.testing.assert_allclose(np.asarray(m(check)), cv2.perspectiveTransform(check[None], ref)[0], rtol=0, atol=1e-6)
    # Entries compared absolutely: an error e in h31/h32 moves a point by
    # ~100 e / 1 px at these coordinates, so 1e-9 is far below 1e-6 px.
    np.testing.assert_allclose(np.asarray(m.matrix), ref / ref[2, 2], rtol=1e-6, atol=1e-9)
    src, dst = _homography_points(H_TRUE, 4, rng)
    m = fit_projective(src, dst)
    # At ~4e4 coordinates the matrix entries are determined only to ~1e-8
    # relative; what must hold is that the true mapping is reproduced.
    fresh, truth = _homography_points(H_TRUE, 50, rng)
    np.testing.assert_allclose(np.asarray(m(fresh)), truth, rtol=0, atol=1e-6)
    assert float(m.rmse) < 1e-8 and np.isnan(float(m.rmse_dof))


def test_projective_least_squares_matches_opencv_and_skimage():
    """Noisy points: OpenCV's findHomography(method=0) minimises the
    geometric error (DLT then Levenberg-Marquardt) like our refined fit;
    scikit-image's ProjectiveTransform is the normalised DLT (algebraic
    error), like ours with ``refine=False``.  OpenCV does not normalise, so
    it is compared on small coordinates; at large ones ours must reach a
    geometric error no larger than OpenCV's."""
    rmse = lambda pred, dst: np.sqrt(np.mean(np.sum((pred - dst) ** 2, axis=1)))  # noqa: E731
    for offset in (np.zeros(2), UTM / 100):
        src, dst = _homography_points(H_TRUE, 30, RNG, noise=0.5)
        src, dst = src - UTM / 100 + offset, None
        d = np.c_[src, np.ones(30)] @ H_TRUE.T
        dst = d[:, :2] / d[:, 2:] + RNG.normal(scale=0.5, size=(30, 2))
        check = RNG.uniform(0, 1000, (50, 2)) + offset
        ours = fit_projective(src, dst)
        cv_h, _ = cv2.findHomography(src, dst, 0)
        cv_rmse = rmse(cv2.perspectiveTransform(src[None], cv_h)[0], dst)
        assert float(ours.rmse) <= cv_rmse * (1 + 1e-9)
        if not offset.any():
            np.testing.assert_allclose(
                np.asarray(ours(check)), cv2.perspectiveTransform(check[None], cv_h)[0], rtol=0, atol=1e-3
            )
        dlt = fit_projective(src, dst, refine=False)
        sk = ProjectiveTransform.from_estimate(src, dst)
        # same estimator; ~1e-8 relative differences from the two SVD set-ups
        np.testing.assert_allclose(np.asarray(dlt(check)), sk(check), rtol=1e-7, atol=1e-4)
        assert float(ours.rmse) <= float(dlt.rmse) + 1e-12  # refinement only lowers the geometric error
        assert np.isfinite(float(ours.rmse_dof)) and float(ours.condition) > 1


def test_projective_inverse_is_exact():
    src, dst = _homography_points(H_TRUE, 8, RNG, noise=0.1)
    m = fit_projective(src, dst)
    p = RNG.uniform(0, 1000, (100, 2)) + UTM / 100
    np.testing.assert_allclose(np.asarray(m.inverse()(m(p))), p, rtol=0, atol=1e-7)
    np.testing.assert_allclose(
        np.asarray(m.inverse().matrix),
        np.linalg.inv(np.asarray(m.matrix)) / np.linalg.inv(np.asarray(m.matrix))[2, 2],
        rtol=1e-9,
        atol=1e-12,
    )


def test_projective_errors():
    sq = np.array([[0.0, 0], [1, 0], [2, 0], [0, 1]])  # three collinear
    with pytest.raises(ValueError, match="collinear"):
        fit_projective(sq, sq + 1)
    with pytest.raises(ValueError, match="at least 4"):
        fit_projective(sq[:3], sq[:3])
    with pytest.raises(ValueError, match="same shape"):
        fit_projective(sq, np.ones((5, 2)))


def test_residual_sign_and_projective_outcome():
    """Residuals are computed - observed (docs/conventions.md); the projective
    refinement (optimistix) reports a RESULTS code and lowers the geometric
    error below the DLT's."""
    import photax as ptx

    src = UTM + RNG.uniform(0, 1000, (12, 2))
    h = np.array([[0.9, 0.05, 3.0], [-0.04, 1.1, -2.0], [1e-4, -2e-4, 1.0]])
    p = np.column_stack([src - UTM, np.ones(len(src))]) @ h.T
    dst = p[:, :2] / p[:, 2:] + RNG.normal(0, 0.5, (len(src), 2))
    poly = fit_polynomial(src, dst, 2)
    np.testing.assert_allclose(poly.residuals, np.asarray(poly(src)) - dst, atol=1e-9)
    proj = fit_projective(src, dst)
    np.testing.assert_allclose(proj.residuals, np.asarray(proj(src)) - dst, atol=1e-9)
    assert proj.result == ptx.RESULTS.successful and proj.converged
    assert proj.inverse().result == proj.result
    assert float(proj.rmse) < float(fit_projective(src, dst, refine=False).rmse)


@pytest.mark.parametrize("order", [1, 3])
def test_padded_model_is_the_same_mapping_bit_for_bit(order):
    """compare.rectify pads every polynomial to the highest order (one kernel):
    the padded model must give exactly the values of the model itself."""
    rng = np.random.default_rng(order)
    src = rng.uniform(0, 4000, (40, 2)) + [500_000.0, 4_000_000.0]
    dst = rng.uniform(0, 1000, (40, 2))
    m = fit_polynomial(src, dst, order)
    p = m.padded(5)
    assert p.order == 5 and p.coef.shape == (n_coefficients(5), 2)
    xy = rng.uniform(-500, 4500, (2000, 2)) + [500_000.0, 4_000_000.0]
    np.testing.assert_array_equal(np.asarray(p(xy)), np.asarray(m(xy)))
    with pytest.raises(ValueError, match="order"):
        p.padded(4)
