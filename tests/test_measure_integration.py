"""photax.measure results in the rest of photax: target homographies from a camera and
an exterior orientation, and measured targets feeding resect.

References: photax.project (the collinearity equations) for the homography, a conic
fitted by numpy to projected circle points for the ellipse-centre offset, and the known
orientation of a rendered scene for the resection.
"""

import numpy as np
import pytest

import photax as ptx
from photax.scene import patterns

CAMERA = ptx.FrameCamera(8.0, (0.02, -0.015), pixel_size=0.01, image_size=(320, 240))  # mm
EXTERIOR = ptx.ExteriorOrientation([10.0, -5.0, 100.0], np.radians([3.0, -2.0, 20.0]))


def _pixels(ground, exterior=EXTERIOR):
    return np.asarray(CAMERA.image_to_pixel(ptx.project(np.asarray(ground, float), exterior, CAMERA)))


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (0.3, -0.5, 1.0), (1.0, 0.1, 0.05)])
def test_target_homography_matches_project(normal):
    """H (u, v, 1) equals photax.project of centre + u e1 + v e2 (the documented plane axes)."""
    centre = np.array([[12.0, -3.0, 1.5], [-4.0, 6.0, -2.0]])
    h = ptx.measure.target_homography(CAMERA, EXTERIOR, centre, normal)
    assert h.shape == (2, 3, 3)
    e1, e2 = _axes(np.asarray(normal) / np.linalg.norm(normal))
    uv = np.random.default_rng(0).uniform(-2, 2, (20, 2))
    for i in range(2):
        want = _pixels(centre[i] + uv[:, :1] * e1 + uv[:, 1:] * e2)
        p = np.c_[uv, np.ones(len(uv))] @ h[i].T
        np.testing.assert_allclose(p[:, :2] / p[:, 2:], want, atol=1e-8)


def test_target_homography_rejects_bad_input():
    with pytest.raises(ValueError, match="normal"):
        ptx.measure.target_homography(CAMERA, EXTERIOR, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="centre"):
        ptx.measure.target_homography(CAMERA, EXTERIOR, [0.0, 0.0], [0.0, 0.0, 1.0])


def _axes(n):
    """The plane axes target_homography documents: e1 = (a x n)/|a x n|, e2 = n x e1."""
    a = np.array([0.0, 1.0, 0.0]) if abs(n[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(a, n)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _conic_centre(pts):
    """Centre of the conic a u^2 + b uv + c v^2 + d u + e v = 1 through (K, 2) points (numpy lstsq)."""
    o = pts.mean(0)
    u, v = (pts - o).T
    a, b, c, d, e = np.linalg.lstsq(np.stack([u * u, u * v, v * v, u, v], 1), np.ones_like(u), rcond=None)[0]
    return o + np.linalg.solve([[2 * a, b], [b, 2 * c]], [-d, -e])


def test_oblique_offset_from_camera_equals_projected_circle():
    """ellipse_centre_offset(target_homography(...)) against the centre of a conic fitted to the
    projected rim of a tilted ground circle (photax.project, no homography involved)."""
    oblique = ptx.ExteriorOrientation([0.0, -40.0, 30.0], np.radians([0.0, -50.0, 0.0]), "omega-phi-kappa")
    camera = ptx.FrameCamera(8.0, pixel_size=0.01, image_size=(320, 240))
    centre, radius = np.array([0.0, 0.0, 0.0]), 1.5
    h = ptx.measure.target_homography(camera, oblique, centre)
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    e1, e2 = _axes(np.array([0.0, 0.0, 1.0]))
    rim = centre + radius * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    rim_px = np.asarray(camera.image_to_pixel(ptx.project(rim, oblique, camera)))
    c_px = np.asarray(camera.image_to_pixel(ptx.project(centre[None], oblique, camera)))[0]
    want = _conic_centre(rim_px) - c_px
    got = ptx.measure.ellipse_centre_offset(h, radius)
    assert np.linalg.norm(want) > 0.05  # the test means something: a visible offset
    np.testing.assert_allclose(got, want, atol=1e-6)


def _render_targets(camera, exterior, ground, radius, shape, rng, blur=0.7, noise=0.01, half=14):
    """Area-sampled discs on the ground, rendered patch by patch through target_homography."""
    img = np.zeros(shape)
    hs = ptx.measure.target_homography(camera, exterior, ground)
    for h in hs:
        c = h @ [0.0, 0.0, 1.0]
        cc, rr = np.round(c[:2] / c[2]).astype(int)
        pat = patterns.projected_disc(h, radius)
        c0, r0 = cc - half, rr - half
        img[r0 : r0 + 2 * half + 1, c0 : c0 + 2 * half + 1] = patterns.render(
            lambda x, y, pat=pat, c0=c0, r0=r0: pat(x + c0, y + r0), (2 * half + 1, 2 * half + 1)
        )
    img = patterns._finish(img, blur, 0.0, 0.0, 1.0, None)
    return img + rng.normal(0.0, noise, img.shape), hs


def test_measured_targets_feed_resect():
    """Targets on the ground, imaged by a known camera + orientation, measured with
    locate_targets, corrected for obliquity, and resected with their own sigma: the
    orientation comes back within its standard deviations (and a few cm / mdeg)."""
    rng = np.random.default_rng(7)
    # ground points under a 4 x 3 pixel grid (30 px from the border), heights +-3 m
    pc, pr = np.meshgrid(np.linspace(30, 289, 4), np.linspace(30, 209, 3))
    px = np.stack([pc.ravel(), pr.ravel()], 1) + rng.uniform(-5, 5, (12, 2))
    ground = np.asarray(ptx.image_to_ground(CAMERA.pixel_to_image(px), EXTERIOR, CAMERA, height=rng.uniform(-3, 3, 12)))
    radius = 0.7  # m: ~5.6 px at ~100 m with 8 mm / 10 um
    image, hs = _render_targets(CAMERA, EXTERIOR, ground, radius, (240, 320), rng)
    truth = _pixels(ground)
    approx = truth + rng.uniform(-1.5, 1.5, truth.shape)
    res = ptx.measure.locate_targets(image, approx, 6.0, method="ellipse")
    assert bool(np.all(res.valid)), res.summary()
    xy = np.asarray(res.xy) - ptx.measure.ellipse_centre_offset(hs, radius)
    err = np.linalg.norm(xy - truth, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.05
    sigma = np.asarray(res.image_sigma(CAMERA))
    out = ptx.resect(CAMERA.pixel_to_image(xy), ground, CAMERA, sigma=sigma)
    assert out.converged
    d = np.asarray(out.exterior.to_vector() - EXTERIOR.to_vector())
    assert np.all(np.abs(d) < 4 * np.asarray(out.std)), (d, out.std)
    assert np.all(np.abs(d[:3]) < 0.05) and np.all(np.degrees(np.abs(d[3:])) < 0.02)
    # the measured sigmas are honest: sigma0 of the weighted resection near 1
    assert 0.4 < float(out.sigma0) < 2.5
