"""photax.measure operators: edges, Hough, interest operators.

References: scikit-image (filters.sobel/prewitt/roberts/laplace,
feature.canny, corner_harris/foerstner/moravec), scipy.ndimage
(gaussian_laplace), brute-force loops written from the seed's formulas, and
synthetic images rendered by area sampling with known lines, circles and
corners.
"""

import math

import jax
import numpy as np
import pytest
import scipy.ndimage as ndi
from skimage import feature, filters

import photax as ptx

M = ptx.measure
RNG = np.random.default_rng(20261123)


def smooth_random(h, w, seed=0, scale=3.0):
    return ndi.gaussian_filter(np.random.default_rng(seed).random((h, w)), 2.0) * scale


def render(h, w, inside, ss=8):
    """Area-sample an indicator ``inside(x, y)`` (x = column, y = row, pixel
    centres at integers) with ss x ss sub-samples per pixel."""
    o = (np.arange(ss) + 0.5) / ss - 0.5
    r, c = np.mgrid[0:h, 0:w].astype(float)
    acc = np.zeros((h, w))
    for dy in o:
        for dx in o:
            acc += inside(c + dx, r + dy)
    return acc / ss**2


def f1(a, b):
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    return 2.0 * (a & b).sum() / (a.sum() + b.sum())


# ------------------------------------------------------------------ edges


@pytest.mark.parametrize("name", ["sobel", "prewitt", "roberts", "laplace"])
def test_edge_filters_match_skimage(name):
    im = smooth_random(33, 41)
    ours, ref = getattr(M, name)(im), getattr(filters, name)(im)
    assert ours.dtype == np.float64
    np.testing.assert_allclose(np.asarray(ours), ref, atol=1e-6, rtol=0)
    # integer input: photax keeps grey values, scikit-image scales by 1/255
    im8 = (im / im.max() * 255).astype(np.uint8)
    np.testing.assert_allclose(np.asarray(getattr(M, name)(im8)) / 255.0, getattr(filters, name)(im8), atol=1e-6)


def test_log_matches_scipy_and_zero_crossings_on_circle():
    im = smooth_random(30, 30, seed=1)
    resp, _ = M.log(im, 1.5)
    np.testing.assert_allclose(np.asarray(resp), ndi.gaussian_laplace(im, 1.5), atol=1e-6, rtol=0)
    cx, cy, rad = 31.3, 29.6, 14.0
    disk = render(64, 64, lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 < rad**2)
    _, edges = M.log(disk, 2.0, threshold=0.01)
    r, c = np.nonzero(np.asarray(edges))
    dist = np.hypot(c - cx, r - cy)
    assert len(dist) > 50
    assert np.all(np.abs(dist - rad) < 1.0)  # zero crossings lie on the step, to the pixel


def test_canny_matches_skimage_for_uint8_uint16_float():
    base = render(64, 72, lambda x, y: ((x - 30.4) ** 2 + (y - 33.1) ** 2 < 18.2**2) | ((x > 50.3) & (y < 20.7)))
    base = ndi.gaussian_filter(base, 0.7) + 0.02 * RNG.standard_normal(base.shape)
    base = (base - base.min()) / (base.max() - base.min())
    images = {
        "float64": base,
        "uint8": np.round(base * 255).astype(np.uint8),
        "uint16": np.round(base * 65535).astype(np.uint16),
    }
    for name, im in images.items():
        ours = np.asarray(M.canny(im, 1.2))
        ref = feature.canny(im, 1.2)  # both default to 0.1 / 0.2 of the (full) range here
        assert ref.sum() > 100, name
        assert f1(ours, ref) >= 0.99, name
    # an integer image that uses a small part of its dtype's range: scikit-image's
    # dtype-relative defaults blank it out (skimage #6871 / #3913); photax's
    # thresholds are relative to the image's own range.
    dim = np.round(base * 3000 + 500).astype(np.uint16)
    assert not feature.canny(dim, 1.2).any()
    ours = np.asarray(M.canny(dim, 1.2))
    ref = feature.canny(dim.astype(np.float64), 1.2, 0.1 * np.ptp(dim), 0.2 * np.ptp(dim))
    assert ref.sum() > 100 and f1(ours, ref) >= 0.99


def test_canny_batched_under_jit_pure_jax_hysteresis_and_constant_image():
    a, b = smooth_random(64, 72, 2), smooth_random(64, 72, 3)
    batch = np.asarray(jax.jit(lambda x: M.canny(x, 1.2, 0.05, 0.1))(np.stack([a, b])))
    assert batch.shape == (2, 64, 72)
    ref = feature.canny(b, 1.2, 0.05, 0.1)
    assert ref.sum() > 50
    np.testing.assert_array_equal(batch[1], ref)
    # the all-XLA hysteresis (label propagation) gives the same map as scipy's labels
    np.testing.assert_array_equal(np.asarray(M.canny(b, 1.2, 0.05, 0.1, hysteresis="jax")), ref)
    assert not np.asarray(M.canny(np.full((64, 72), 7, np.uint8), 1.2)).any()
    assert np.asarray(M.canny(np.where(a > a.mean(), 120, -100).astype(np.int8), 1.2)).any()  # no int8 overflow


def test_gradient_of_a_ramp_is_exact():
    r, c = np.mgrid[0:12, 0:15].astype(float)
    ramp = 0.7 * c - 1.3 * r + 5.0
    for method in ("sobel", "prewitt", "central"):
        gx, gy = M.gradient(ramp, method)
        np.testing.assert_allclose(np.asarray(gx)[1:-1, 1:-1], 0.7, atol=1e-12)
        np.testing.assert_allclose(np.asarray(gy)[1:-1, 1:-1], -1.3, atol=1e-12)


def test_bad_input_is_a_clear_error_and_constant_images_give_no_nan():
    with pytest.raises(ValueError, match="image"):
        M.sobel(np.zeros(10))
    with pytest.raises(ValueError, match="image"):
        M.canny(np.zeros((2, 3, 4, 5)))
    with pytest.raises(ValueError, match="dtype"):
        M.sobel(np.zeros((5, 5), complex))
    with pytest.raises(ValueError, match="window"):
        M.foerstner(np.zeros((9, 9)), 4)
    with pytest.raises(ValueError, match="method"):
        M.interest_points(np.zeros((9, 9)), "sift")
    flat = np.full((24, 24), 100, np.uint16)
    w, q = M.foerstner(flat)
    assert np.all(np.asarray(w) == 0) and np.all(np.asarray(q) == 0)
    resp, edges = M.log(flat)
    assert np.all(np.isfinite(np.asarray(resp))) and not np.asarray(edges).any()
    for method in ("foerstner", "harris", "moravec"):
        pts = M.interest_points(flat, method)
        assert pts.xy.shape == (0, 2) and pts.strength.shape == (0,)
    lines = M.hough_lines(np.zeros((20, 20), bool))
    assert lines.theta.shape == (0,)
    assert M.hough_circles(np.zeros((20, 20), bool), [5]).xy.shape == (0, 2)


# ------------------------------------------------------------------ Hough


def test_hough_lines_angle_and_offset_below_the_bin():
    # synthetic edge image: a one-pixel-wide line, area-sampled (weights = coverage)
    h = w = 96
    errs_t, errs_r = [], []
    for _ in range(6):
        theta = RNG.uniform(0, math.pi)
        rho = 47.5 * math.cos(theta) + 47.5 * math.sin(theta) + RNG.uniform(-15, 15)
        edges = render(h, w, lambda x, y: np.abs(x * math.cos(theta) + y * math.sin(theta) - rho) <= 0.5)
        res = M.hough_lines(edges, max_lines=1)
        t, p = res.theta[0], res.rho[0]
        dt = (t - theta + math.pi / 2) % math.pi - math.pi / 2
        if abs(t - theta) > math.pi / 2:  # same line written (theta -+ pi, -rho)
            p = -p
        errs_t.append(abs(math.degrees(dt)))
        errs_r.append(abs(p - rho))
        assert res.accumulator.shape == (len(res.thetas), len(res.rhos))
    assert max(errs_t) < 0.05 and max(errs_r) < 0.1, (errs_t, errs_r)


def test_hough_line_at_theta_zero_is_reported_once():
    edges = render(64, 64, lambda x, y: np.abs(x - 40.3) <= 0.5)
    res = M.hough_lines(edges, max_lines=3)
    assert len(res.theta) == 1
    t, p = res.theta[0], res.rho[0]
    x_at = p / math.cos(t)  # the column where the line crosses row 0
    assert min(t, math.pi - t) < math.radians(0.05) and abs(abs(x_at) - 40.3) < 0.1


def test_hough_lines_finds_two_lines_of_a_canny_map():
    im = render(80, 80, lambda x, y: (x > 30.3) ^ (x * 0.6 + y * 0.8 > 50.7))
    res = M.hough_lines(M.canny(im, 1.0), max_lines=2)
    assert len(res.theta) == 2
    got = sorted(zip(np.degrees(res.theta), res.rho))
    true = sorted([(0.0, 30.3), (math.degrees(math.atan2(0.8, 0.6)), 50.7)])
    for (tg, rg), (tt, rt) in zip(got, true):
        assert abs(tg - tt) < 0.5 and abs(rg - rt) < 1.0


def test_hough_circles_centres_within_a_fifth_of_a_pixel():
    for k in range(3):
        cx, cy = RNG.uniform(36, 44, 2)
        rad = [9.0, 14.0, 12.0][k]
        im = render(80, 80, lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 < rad**2)
        edges = M.canny(im, 1.0)
        res = M.hough_circles(edges, [rad - 2, rad - 1, rad, rad + 1, rad + 2], max_circles=1)
        assert res.radius[0] == rad
        assert np.hypot(*(res.xy[0] - [cx, cy])) < 0.2
        assert res.accumulator.shape == (5, 80, 80)


# -------------------------------------------------------- interest operators


def test_harris_foerstner_moravec_match_skimage():
    im = smooth_random(31, 37, seed=4)
    np.testing.assert_allclose(np.asarray(M.harris(im)), feature.corner_harris(im), atol=1e-6, rtol=0)
    np.testing.assert_allclose(
        np.asarray(M.harris(im, method="eps")), feature.corner_harris(im, method="eps"), atol=1e-6, rtol=0
    )
    w, q = M.foerstner(im, sigma=1.5)
    w_ref, q_ref = feature.corner_foerstner(im, sigma=1.5)
    np.testing.assert_allclose(np.asarray(w), w_ref, atol=1e-6, rtol=0)
    np.testing.assert_allclose(np.asarray(q), q_ref, atol=1e-6, rtol=0)
    np.testing.assert_allclose(
        np.asarray(M.moravec(im, 3, method="shift")), feature.corner_moravec(im, 1), atol=1e-6, rtol=0
    )


def test_seed_forms_of_moravec_and_foerstner_against_loops():
    g = smooth_random(14, 16, seed=5)
    k = 2
    mor = np.zeros_like(g)
    w_ref, q_ref = np.zeros_like(g), np.zeros_like(g)
    for r in range(k, g.shape[0] - k):
        for c in range(k, g.shape[1] - k):
            v = [0.0] * 4
            a = b = d = 0.0
            for i in range(-k, k):
                v[0] += (g[r, c + i] - g[r, c + i + 1]) ** 2
                v[1] += (g[r + i, c + i] - g[r + i + 1, c + i + 1]) ** 2
                v[2] += (g[r + i, c] - g[r + i + 1, c]) ** 2
                v[3] += (g[r + i, c - i] - g[r + i + 1, c - i - 1]) ** 2
            mor[r, c] = min(v)
            for i in range(r - k, r + k):
                for j in range(c - k, c + k):
                    gu, gv = g[i + 1, j + 1] - g[i, j], g[i, j + 1] - g[i + 1, j]
                    a, b, d = a + gu * gu, b + gu * gv, d + gv * gv
            w_ref[r, c] = (a * d - b * b) / (a + d)
            q_ref[r, c] = 4 * (a * d - b * b) / (a + d) ** 2
    np.testing.assert_allclose(np.asarray(M.moravec(g, 5)), mor, atol=1e-12)
    w, q = M.foerstner(g, 5)
    np.testing.assert_allclose(np.asarray(w), w_ref, atol=1e-12)
    np.testing.assert_allclose(np.asarray(q), q_ref, atol=1e-9)
    # batched through vmap
    wb, _ = M.foerstner(np.stack([g, g[::-1]]), 5)
    np.testing.assert_allclose(np.asarray(wb[0]), w_ref, atol=1e-12)


def test_interest_points_find_the_corners_of_squares():
    corners = []
    boxes = [(8.3, 10.6, 30.2, 27.9), (40.7, 36.4, 60.1, 58.3)]  # x0, y0, x1, y1 (pixel edges in pixel coords)
    im = render(72, 72, lambda x, y: sum(((x > x0) & (x < x1) & (y > y0) & (y < y1)) for x0, y0, x1, y1 in boxes) > 0)
    im = (im * 200 + 20).astype(np.uint8)
    for x0, y0, x1, y1 in boxes:
        corners += [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
    corners = np.array(corners)
    for method in ("foerstner", "harris", "moravec"):
        pts = M.interest_points(im, method, max_points=8)
        assert pts.xy.shape == (8, 2), method
        assert np.all(np.diff(pts.strength) <= 0)
        # an operator picks the pixel whose window holds the corner (the seed: the
        # sub-pixel position is the locator's job), so each point lies within
        # half a window (5 // 2 px, plus the half pixel of a corner between pixels)
        d = np.abs(pts.xy[:, None, :] - corners[None]).max(axis=-1).min(axis=1)
        assert np.all(d <= 2.5), (method, d)
        # and the eight corners are all found
        assert len(set(np.abs(pts.xy[:, None, :] - corners[None]).max(axis=-1).argmin(axis=1))) == 8


def test_non_maximum_suppression_matches_a_maximum_filter():
    resp = smooth_random(25, 30, seed=6)
    ours = np.asarray(M.non_maximum_suppression(resp, 5, 0.5))
    ref = (resp == ndi.maximum_filter(resp, 5, mode="constant", cval=-np.inf)) & (resp > 0.5)
    np.testing.assert_array_equal(ours, ref)
    assert ref.any()


# --------------------------------------------------------------------------- gradient (the package's one gradient)


@pytest.mark.parametrize("method", ["sobel", "prewitt", "central", "gaussian"])
@pytest.mark.parametrize("mode", ["reflect", "valid"])
def test_gradient_ramp_and_valid_shape(method, mode):
    """A ramp a c + b r gives (a, b) exactly inside; "valid" crops gradient_margin px per side."""
    from photax.measure._filters import gradient_margin

    r, c = np.mgrid[0:20, 0:24].astype(float)
    gx, gy = ptx.measure.gradient(0.7 * c - 1.3 * r, method, sigma=1.2, mode=mode)
    m = gradient_margin(method, 1.2)
    if mode == "valid":
        assert gx.shape == gy.shape == (20 - 2 * m, 24 - 2 * m)
        inner = (slice(None), slice(None))
    else:
        assert gx.shape == (20, 24)
        inner = (slice(m, -m), slice(m, -m))
    np.testing.assert_allclose(np.asarray(gx)[inner], 0.7, atol=1e-12)
    np.testing.assert_allclose(np.asarray(gy)[inner], -1.3, atol=1e-12)


def test_gradient_gaussian_closed_form():
    """d/dcol of g = c r^2 with the derivative-of-Gaussian gradient: the odd kernel (unit
    ramp response) gives r^2 along, the Gaussian across adds its variance: r^2 + sum g(s) s^2."""
    from photax.measure._filters import derivative_of_gaussian

    sigma = 1.3
    g, _ = derivative_of_gaussian(sigma)
    s = np.arange(len(g)) - len(g) // 2
    r, c = np.mgrid[0:30, 0:30].astype(float)
    gx, gy = ptx.measure.gradient(c * r**2, "gaussian", sigma=sigma, mode="valid")
    m = len(g) // 2
    want_x = r[m:-m, m:-m] ** 2 + np.sum(g * s**2)
    want_y = 2 * r[m:-m, m:-m] * c[m:-m, m:-m]  # odd kernel on a quadratic: exact; Gaussian on a linear: exact
    np.testing.assert_allclose(np.asarray(gx), want_x, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(gy), want_y, rtol=1e-12, atol=1e-9)
    with pytest.raises(ValueError, match="method"):
        ptx.measure.gradient(c, "scharr")


def test_thinning_keeps_what_comparing_every_pair_keeps():
    """interest_points' plateau thinning (an occupancy image) against the definition, written out as
    the pairwise loop: the strongest first, a point dropped when a kept one is within d in row and
    column; random maxima with ties and clusters, with and without max_points."""
    from photax.measure._interest import _thin

    rng = np.random.default_rng(5)
    for trial in range(20):
        n, d, shape = rng.integers(1, 400), int(rng.integers(0, 6)), (60, 80)
        rows, cols = rng.integers(0, shape[0], n), rng.integers(0, shape[1], n)
        score = rng.integers(0, 30, n).astype(float)  # many equal scores: the stable order decides
        cap = None if trial % 2 else int(rng.integers(1, 50))
        ref = []
        for i in np.argsort(-score, kind="stable"):
            if any(abs(rows[i] - rows[j]) <= d and abs(cols[i] - cols[j]) <= d for j in ref):
                continue
            ref.append(i)
            if cap is not None and len(ref) >= cap:
                break
        assert _thin(rows, cols, score, d, cap, shape).tolist() == ref


def test_border_padding_is_numpys_for_every_mode_and_width():
    """The filters' padding (a constant pad with the border strips copied in, for speed) against
    numpy.pad, whose mode it names: widths of 0, 1, several and wider than the image."""
    from photax.measure._filters import _NP_MODE, pad

    x = np.random.default_rng(7).random((7, 5))
    for mode, np_mode in _NP_MODE.items():
        for widths in ([(1, 1), (1, 1)], [(3, 0), (0, 2)], [(9, 12), (6, 11)], [(0, 0), (0, 0)]):
            want = np.pad(x, widths, mode=np_mode)
            np.testing.assert_array_equal(np.asarray(jax.jit(lambda v, w=widths, m=mode: pad(v, w, m))(x)), want)


def test_canny_in_float32_on_8_and_16_bit_images_is_scikit_images_map():
    """8- and 16-bit images are smoothed and differentiated in float32 (float64 images in float64):
    on a textured image with edges in every direction the map is scikit-image's (float64), pixel for
    pixel, and a float64 image still gives it exactly."""
    base = smooth_random(96, 112, seed=11, scale=1.0)
    base = (base - base.min()) / np.ptp(base)
    for im in (np.round(base * 255).astype(np.uint8), np.round(base * 65535).astype(np.uint16)):
        lo, hi = 0.05 * np.ptp(im), 0.1 * np.ptp(im)
        ref = feature.canny(im.astype(np.float64), 1.4, lo, hi)
        assert ref.sum() > 200
        np.testing.assert_array_equal(np.asarray(M.canny(im, 1.4, lo, hi)), ref)
        for mode in ("reflect", "nearest"):
            ref = feature.canny(im.astype(np.float64), 1.4, lo, hi, mode=mode)
            np.testing.assert_array_equal(np.asarray(M.canny(im, 1.4, lo, hi, mode=mode)), ref)


@pytest.mark.parametrize("mode", ["reflect", "mirror", "nearest", "wrap", "constant"])
def test_log_matches_scipy_in_every_border_mode_and_below_the_kernel_size(mode):
    """The LoG pads once for its four passes: scipy.ndimage.gaussian_laplace's response in every
    border mode, for float and uint8 images, down to images smaller than the kernel's radius."""
    rng = np.random.default_rng(3)
    for shape in [(40, 33), (3, 2)]:
        x = ndi.gaussian_filter(rng.random(shape), 1.5) * 100
        np.testing.assert_allclose(
            np.asarray(M.log(x, 2.0, mode=mode)[0]), ndi.gaussian_laplace(x, 2.0, mode=mode), atol=1e-10
        )
        u = (x * 2).astype(np.uint8)
        want = ndi.gaussian_laplace(u.astype(np.float64), 1.3, mode=mode)
        got = M.log(u, 1.3, mode=mode)[0]
        assert got.dtype == np.float32  # 8-bit images are filtered in float32, as Canny smooths them
        np.testing.assert_allclose(np.asarray(got), want, atol=_f32_log_tol(u, 1.3))


def _f32_log_tol(image, sigma):
    """Rounding bound of a float32 LoG: each output is a sum of products of grey values and kernel
    weights, so its error is at most a few float32 epsilons (1.19e-7) times sum |weights| (the two
    separable terms: 2 sum|k2| sum|k0|) times the largest grey value; 4 eps for the two passes and the sum."""
    k0, k2 = np.abs(ndi_kernel(sigma, 0)), np.abs(ndi_kernel(sigma, 2))
    return 4 * np.finfo(np.float32).eps * 2 * k2.sum() * k0.sum() * float(np.max(np.abs(image)))


def ndi_kernel(sigma, order, truncate=4.0):
    """scipy.ndimage's 1-D Gaussian (derivative) kernel: its response to a unit impulse."""
    r = int(truncate * sigma + 0.5)
    e = np.zeros(2 * r + 1)
    e[r] = 1.0
    return ndi.gaussian_filter1d(e, sigma, order=order, truncate=truncate, mode="constant")


@pytest.mark.parametrize(
    "dtype", [np.uint8, np.int8, np.uint16, np.int16, np.float16, np.float32, np.float64, np.int32]
)
def test_log_works_in_float32_for_8_16_bit_and_float32_images_float64_otherwise(dtype):
    """The LoG's working type is Canny's: float32 where it holds the grey values exactly. Against
    scipy's float64 gaussian_laplace: float32 at the float32 rounding bound, float64 at 1e-10; the
    zero crossings of a textured image are the float64 ones, pixel for pixel."""
    x = ndi.gaussian_filter(np.random.default_rng(5).random((64, 72)), 2.0)
    x = (x - x.min()) / (x.max() - x.min()) * (100 if np.dtype(dtype).itemsize == 1 else 1000)
    im = x.astype(dtype)
    resp, edges = M.log(im, 2.0, threshold=0.01)
    want = ndi.gaussian_laplace(im.astype(np.float64), 2.0)
    f32 = dtype not in (np.float64, np.int32)
    assert resp.dtype == (np.float32 if f32 else np.float64)
    np.testing.assert_allclose(np.asarray(resp), want, atol=_f32_log_tol(im, 2.0) if f32 else 1e-10, rtol=0)
    _, edges64 = M.log(im.astype(np.float64), 2.0, threshold=0.01)
    assert np.asarray(edges).sum() > 100
    np.testing.assert_array_equal(np.asarray(edges), np.asarray(edges64))
