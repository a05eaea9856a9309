"""Sub-pixel locators of photax.measure against rendered images with known truth
and against OpenCV (cornerSubPix, matchTemplate, fitEllipse) side by side.

Every image comes from photax.scene.patterns: analytic patterns area-sampled
at 16 x 16 sub-samples per pixel (textures integrated exactly), then blurred
and noised.  Seeds are fixed; the figures are those the issue asks for.
"""

import functools

import cv2
import numpy as np
import pytest

import photax  # noqa: F401  (float64)
from photax.measure import Status, ellipse_centre_offset, locate_corners, locate_targets, match_lsm, match_ncc
from photax.scene import patterns as R


def rmse(err):
    return float(np.sqrt(np.mean(np.sum(np.asarray(err) ** 2, axis=-1))))


# --------------------------------------------------------------------------- corners

CORNER_SIZE, N_CORNERS = 45, 120
# The window grows with the blur: at blur 1.2 px (total blur with smooth=1.5: 1.9 px) the
# apex exclusion must be wider (exclude=7) and the window longer (R=20), so that as many
# straight edge pixels as at blur 0.7 remain; the patch grows to 61 px to hold it, and
# cornerSubPix gets the same window on the same images.  Chosen on seed 1 from a sweep of
# window 14-24, exclude 5-9, smooth 1-2 (and the locator's d0 from 0, 4, 7, 10); checked on
# seeds 2-4 (0.070, 0.065, 0.071 px).  The tests run on seed 2, which the sweep did not see.
WIDE = dict(size=61, window=20, exclude=7.0, smooth=1.5)


def corner_set(blur, noise, seed, size=CORNER_SIZE):
    """Corners of random orientation, opening 60-120 deg, apex within +-0.5 px
    of the patch centre; approximations up to 1 px off in each axis."""
    rng = np.random.default_rng(seed)
    centre = (size - 1) // 2
    imgs, truth = [], []
    for _ in range(N_CORNERS):
        t = centre + rng.uniform(-0.5, 0.5, 2)
        pat = R.corner(t, rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(60, 120)))
        imgs.append(R.render(pat, (size, size), blur=blur, noise=noise, rng=rng))
        truth.append(t)
    truth = np.array(truth)
    return np.array(imgs), truth, truth + rng.uniform(-1, 1, truth.shape)


def opencv_corners(imgs, approx, win):
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    return np.array(
        [
            cv2.cornerSubPix(
                im.astype(np.float32), a[None, None].astype(np.float32).copy(), (win, win), (-1, -1), crit
            )[0, 0]
            for im, a in zip(imgs, approx)
        ]
    )


@functools.cache
def corner_rmse(blur, noise, wide=False):
    """(photax rmse, cornerSubPix rmse, photax sigmas) on one corner set, computed once;
    ``wide``: the WIDE window and patch, else the defaults (window 14) on 45 px patches."""
    kw = dict(WIDE) if wide else dict(size=CORNER_SIZE, window=14)
    imgs, truth, approx = corner_set(blur, noise, seed=2, size=kw.pop("size"))
    res = locate_corners(imgs, approx[:, None, :], **(kw if wide else {}))  # a batch of images, one point each
    assert bool(np.all(res.valid))
    ours = rmse(np.asarray(res.xy)[:, 0] - truth)
    theirs = rmse(opencv_corners(imgs, approx, kw["window"]) - truth)  # the same (2R+1)^2 window
    print(f"blur {blur} noise {noise} wide {wide}: photax {ours:.4f} px, cornerSubPix {theirs:.4f} px")
    return ours, theirs, np.asarray(res.sigma)[:, 0]


@pytest.mark.parametrize("blur, noise, wide", [(0.7, 0.01, False), (1.2, 0.03, False), (1.2, 0.03, True)])
def test_corners_better_than_cornersubpix(blur, noise, wide):
    ours, theirs, sig = corner_rmse(blur, noise, wide)
    assert ours < theirs
    # the covariance comes from the adjustment: it varies point to point
    assert np.all(sig > 0) and np.std(sig[:, 0]) > 0.05 * np.mean(sig[:, 0])


@pytest.mark.parametrize(
    "blur, noise, wide, limit",
    [
        # The issue's two targets with one setting (WIDE) on a seed the sweep did not see (seed 2:
        # 0.021 and 0.070 px).  The default window 14 is marginal at blur 0.7 (0.028 px on seed 1,
        # 0.031 on seed 2) and misses at blur 1.2 (0.09 px): it is only required to beat cornerSubPix.
        (0.7, 0.01, True, 0.03),
        (1.2, 0.03, True, 0.08),
    ],
)
def test_corners_issue_precision(blur, noise, wide, limit):
    assert corner_rmse(blur, noise, wide)[0] <= limit


def test_corners_plain_foerstner_is_biased_by_blur():
    """exclude=0 is the textbook estimator (cornerSubPix's): without noise it
    is pulled into the corner by ~sigma^2 / 2R; the exclusion removes most of it."""
    imgs, truth, approx = corner_set(1.2, 0.0, seed=2)
    plain = rmse(np.asarray(locate_corners(imgs, approx[:, None], exclude=0.0).xy)[:, 0] - truth)
    ours = rmse(np.asarray(locate_corners(imgs, approx[:, None]).xy)[:, 0] - truth)
    assert ours < 0.5 * plain


def test_corners_border_constant_and_bad_input():
    # one batch, one compilation: a corner, a constant image, a straight edge
    corner = R.render(R.corner((22.2, 20.7), 0.3, 1.6), (45, 45), blur=0.7)
    edge = R.render(lambda x, y: (x > 22.3) * 1.0 + 0 * y, (45, 45), blur=0.7)
    imgs = np.stack([corner, np.full((45, 45), 0.5), edge])
    pts = np.array([[22.0, 21.0], [1.0, 1.0], [44.0, 44.0], [-50.0, 3.0], [np.nan, 3.0]])
    res = locate_corners(imgs, pts)  # the same points in each image
    st = np.asarray(res.status)
    assert st[0, 0] == Status.OK and np.allclose(np.asarray(res.xy)[0, 0], [22.2, 20.7], atol=0.05)
    assert np.all(st[:, 1:] == Status.OUTSIDE)  # cornerSubPix crashes here (opencv #26016)
    assert st[1, 0] == Status.TEXTURELESS and st[2, 0] == Status.ILL_CONDITIONED
    assert np.all(np.isnan(np.asarray(res.xy)[~np.asarray(res.valid)]))
    assert "window not inside the image" in res.messages()[1]
    # integer input gives the same as float
    u8 = np.round(imgs * 200).astype(np.uint8)
    np.testing.assert_allclose(
        np.asarray(locate_corners(u8, pts).xy[0, 0]),
        np.asarray(locate_corners(u8.astype(np.float64), pts).xy[0, 0]),
        atol=1e-12,
    )
    with pytest.raises(ValueError, match="image"):
        locate_corners(np.zeros((2, 3, 45, 45)), pts)
    with pytest.raises(ValueError, match="window"):
        locate_corners(np.zeros((20, 20)), pts)
    with pytest.raises(ValueError, match="approx_xy"):
        locate_corners(corner, [30.0, 21.0])
    with pytest.raises(ValueError, match="d0"):
        locate_corners(corner, pts, d0=-1.0)


# --------------------------------------------------------------------------- targets


@pytest.fixture(scope="module")
def disc_set():
    rng = np.random.default_rng(4)
    n, size = 120, 31
    truth = 15 + rng.uniform(-0.5, 0.5, (n, 2))
    imgs = np.array(
        [R.render(R.disc(t, 6.0), (size, size), blur=0.7, noise=0.01, rng=rng, low=0.1, high=0.9) for t in truth]
    )
    return imgs, truth, truth + rng.uniform(-1, 1, truth.shape)


def test_targets_precision(disc_set):
    imgs, truth, approx = disc_set
    out = {}
    for method in ("wong-trinder", "centroid", "ellipse"):
        res = locate_targets(imgs, approx[:, None], 6.0, method=method)
        assert bool(np.all(res.valid)), method
        out[method] = rmse(np.asarray(res.xy)[:, 0] - truth)
        pred = float(np.sqrt(np.mean(np.sum(np.asarray(res.sigma)[:, 0] ** 2, axis=-1))))
        print(method, f"rmse {out[method]:.4f} predicted {pred:.4f}")
        if method != "wong-trinder":  # binary quantisation is not in the WT covariance
            assert 1 / 1.5 < pred / out[method] < 1.5, method
    assert min(out.values()) <= 0.01
    assert out["wong-trinder"] < 0.15  # the binary centroid: quantised, coarser
    # dark targets: the same with the polarity flipped
    dark = locate_targets(1.0 - imgs[:20], approx[:20, None], 6.0, method="centroid", polarity="dark")
    np.testing.assert_allclose(np.asarray(dark.xy)[:, 0], truth[:20], atol=0.03)


def tilted_homography(tilt_deg, f=300.0, centre=(55.0, 50.0), offset=(0.0, 0.02)):
    t = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    k = np.array([[f, 0, centre[0]], [0, f, centre[1]], [0, 0, 1]])
    return k @ np.column_stack([rot[:, 0], rot[:, 1], [offset[0], offset[1], 1.0]])


def test_ellipse_centre_offset_against_fitellipse():
    """Closed form vs OpenCV's fitEllipse on many projected circle points."""
    h = tilted_homography(30.0)
    a = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    pts = h @ np.stack([0.05 * np.cos(a), 0.05 * np.sin(a), np.ones_like(a)])
    pts = (pts[:2] / pts[2]).T
    (cx, cy), _, _ = cv2.fitEllipse(pts.astype(np.float32))
    centre = h[:2, 2] / h[2, 2]
    np.testing.assert_allclose(centre + ellipse_centre_offset(h, 0.05), [cx, cy], atol=2e-3)


def test_oblique_target_corrected():
    h = tilted_homography(30.0)
    img = R.render(R.projected_disc(h, 0.05), (110, 110), blur=0.7)
    truth = h[:2, 2] / h[2, 2]
    res = locate_targets(img, [truth + [0.6, -0.4]], 16.0, method="ellipse")
    raw = np.asarray(res.xy)[0] - truth
    corrected = raw - ellipse_centre_offset(h, 0.05)
    assert np.linalg.norm(raw) > 0.1  # the uncorrected ellipse centre is visibly off
    assert np.linalg.norm(corrected) <= 0.02


def test_targets_bad_input():
    img = R.render(R.disc((20.3, 19.6), 5.0), (40, 40), blur=0.7)
    res = locate_targets(np.stack([img, np.zeros((40, 40))]), [[20, 20], [2, 2], [39, 20]], 5.0, method="centroid")
    assert list(np.asarray(res.status)[0]) == [Status.OK, Status.OUTSIDE, Status.OUTSIDE]
    assert int(res.status[1, 0]) == Status.TEXTURELESS
    with pytest.raises(ValueError, match="method"):
        locate_targets(img, [[20, 20]], 5.0, method="hough")
    with pytest.raises(ValueError, match="window"):
        locate_targets(img, [[20, 20]], 30.0)


# --------------------------------------------------------------------------- matching

N_MATCH, M_SIZE, M_C = 120, 45, 22


def match_set(noise, seed):
    """Texture pairs: the search image is the template moved by a random
    sub-pixel shift, with gain 0.9 and offset 0.05."""
    rng = np.random.default_rng(seed)
    shift = rng.uniform(-2, 2, (N_MATCH, 2))
    tmpl = np.array([R.texture((M_SIZE, M_SIZE), seed=1000 * seed + i, noise=noise, rng=rng) for i in range(N_MATCH)])
    srch = np.array(
        [
            0.9 * R.texture((M_SIZE, M_SIZE), seed=1000 * seed + i, shift=s, noise=noise / 0.9, rng=rng) + 0.05
            for i, s in enumerate(shift)
        ]
    )
    truth = M_C + shift
    approx = np.round(truth) + rng.integers(-1, 2, truth.shape)
    return tmpl, srch, np.full((N_MATCH, 1, 2), float(M_C)), truth, approx[:, None]


@pytest.mark.parametrize("noise, limit", [(0.0, 0.002), (0.01, 0.025)])
def test_lsm_precision(noise, limit):
    tmpl, srch, txy, truth, approx = match_set(noise, seed=5)
    res = match_lsm(tmpl, txy, srch, approx, window=10)  # 21 x 21 templates
    assert bool(np.all(res.valid))
    err = rmse(np.asarray(res.xy)[:, 0] - truth)
    pred = float(np.sqrt(np.mean(np.sum(np.asarray(res.sigma)[:, 0] ** 2, axis=-1))))
    print(f"LSM noise {noise}: rmse {err:.4f} px, predicted {pred:.4f} px")
    assert err <= limit  # cubic-spline resampling; Keys' cubic convolution gave 0.008 px without noise
    assert 1 / 1.5 < pred / err < 1.5


@pytest.mark.parametrize("noise, limit", [(0.0, 0.002), (0.01, 0.03)])
def test_lsm_sigma_held_out(noise, limit):
    """Pairs of another seed with sub-pixel template centres: sigma within 1.5x
    of the error with and without noise, >= 98 % valid."""
    tmpl, srch, txy, truth, approx = match_set(noise, seed=9)
    frac = np.random.default_rng(9).uniform(-0.5, 0.5, txy.shape)
    res = match_lsm(tmpl, txy + frac, srch, approx, window=10)
    valid = np.asarray(res.valid)[:, 0]
    err = rmse((np.asarray(res.xy)[:, 0] - truth - frac[:, 0])[valid])
    pred = float(np.sqrt(np.mean(np.sum(np.asarray(res.sigma)[valid, 0] ** 2, axis=-1))))
    print(f"LSM held out, noise {noise}: {valid.mean():.1%} valid, rmse {err:.4f} px, predicted {pred:.4f} px")
    assert valid.mean() >= 0.98
    assert err <= limit
    assert 1 / 1.5 < pred / err < 1.5


def test_ncc_equals_matchtemplate_plus_parabola():
    tmpl, srch, txy, truth, approx = match_set(0.01, seed=6)
    tmpl, srch, txy, truth, approx = tmpl[:30], srch[:30], txy[:30], truth[:30], approx[:30]
    w, s = 10, 4
    res, rho = match_ncc(tmpl, txy, srch, approx, window=w, search=s, return_rho=True)
    ref = []
    for t_img, s_img, a in zip(tmpl, srch, approx[:, 0].astype(int)):
        t = t_img[M_C - w : M_C + w + 1, M_C - w : M_C + w + 1].astype(np.float32)
        big = s_img[a[1] - w - s - 1 : a[1] + w + s + 2, a[0] - w - s - 1 : a[0] + w + s + 2].astype(np.float32)
        cc = cv2.matchTemplate(big, t, cv2.TM_CCOEFF_NORMED).astype(np.float64)
        inner = cc[1:-1, 1:-1]
        iy, ix = np.unravel_index(np.argmax(inner), inner.shape)
        iy, ix = iy + 1, ix + 1
        dx = 0.5 * (cc[iy, ix - 1] - cc[iy, ix + 1]) / (cc[iy, ix - 1] - 2 * cc[iy, ix] + cc[iy, ix + 1])
        dy = 0.5 * (cc[iy - 1, ix] - cc[iy + 1, ix]) / (cc[iy - 1, ix] - 2 * cc[iy, ix] + cc[iy + 1, ix])
        ref.append(a + [ix - s - 1 + dx, iy - s - 1 + dy])
    # float32 inside OpenCV: agreement to ~1e-3 px
    np.testing.assert_allclose(np.asarray(res.xy)[:, 0], np.array(ref), atol=2e-3)
    assert rmse(np.asarray(res.xy)[:, 0] - truth) < 0.15
    assert np.all(np.asarray(rho) > 0.9)


def test_matching_bad_input():
    tmpl, srch, txy, truth, approx = match_set(0.0, seed=5)  # the shapes of test_lsm_precision: no new compilation
    tmpl, approx = tmpl.copy(), approx.copy()
    tmpl[0] = 0.3  # textureless template
    approx[1] = [3.0, 3.0]  # search window outside the image
    res = match_lsm(tmpl, txy, srch, approx, window=10)
    st = np.asarray(res.status)[:, 0]
    assert st[0] == Status.TEXTURELESS and st[1] == Status.OUTSIDE and np.all(st[2:] == Status.OK)
    assert np.all(np.isnan(np.asarray(res.xy)[:2]))
    t, s = tmpl[2], srch[2]
    pts = np.array([[22.0, 22.0], [3.0, 3.0]])
    with pytest.raises(ValueError, match="window"):
        match_lsm(t, pts, s, pts, window=30)
    with pytest.raises(ValueError, match="batches"):
        match_lsm(tmpl[:2], txy[:2], s, pts[:1], window=10)
    with pytest.raises(ValueError, match="approx_xy"):
        match_lsm(t, pts, s, pts[:1], window=10)


def test_windows_cut_to_the_size_before_the_spline_prefilter_still_match():
    """Templates and search windows cut with only the 2 px margin the matchers used to read (callers
    such as tie matching and fiducials cut them so) give the matches of the whole images, in the
    search window's own pixels."""
    from scipy.ndimage import gaussian_filter, shift

    rng = np.random.default_rng(5)
    img = gaussian_filter(rng.normal(0.0, 1.0, (160, 160)), 2.0)
    half, search, margin = 6, 4, 5
    c = 80
    true = np.array([[c + 1.3, c - 0.7]])  # where the template's centre lies in the search image
    shifted = shift(img, (-0.7, 1.3), order=3, mode="nearest")  # the content moved by (1.3, -0.7) px
    ht = half + 2
    tmpl = img[c - ht : c + ht + 1, c - ht : c + ht + 1]
    hs = half + margin + 2  # the search window LSM read before
    srch = shifted[c - hs : c + hs + 1, c - hs : c + hs + 1]
    approx = np.array([[c + 1.0, c - 1.0]])
    whole = match_lsm(img, [[c, c]], shifted, approx, window=half, margin=margin)
    cut = match_lsm(tmpl, [[ht, ht]], srch, approx - (c - hs), window=half, margin=margin)
    np.testing.assert_allclose(np.asarray(cut.xy) + (c - hs), np.asarray(whole.xy), atol=0.02)
    np.testing.assert_allclose(np.asarray(whole.xy), true, atol=0.05)
    n_whole = match_ncc(img, [[c, c]], shifted, approx, window=half, search=search)
    n_cut = match_ncc(tmpl, [[ht, ht]], shifted, approx, window=half, search=search)
    np.testing.assert_allclose(np.asarray(n_cut.xy), np.asarray(n_whole.xy), atol=1e-9)
