"""Resection of façade, oblique and upward-looking views (issue 21, item 5).

A mirror image is decided from the geometry that defines it - the
handedness of the image-ground correspondence, which a proper camera
(a rotation, not a reflection) cannot reverse - never from "the camera is
above the control points": a street-level camera looking up at a building
is below most of its points.  Rendered scenes with known truth: control
points on a building (walls with windows and balconies, a corner), the
camera at street level; the recovered orientation must equal the truth
within 3 sigma, and the same measurements mirrored (image x or y reversed,
ground E and N swapped) must still be refused.  The camera is the 4000 x
3000 px grid of ``test_resection_status`` (one compilation for both files).
"""

import numpy as np
import pytest

import photax as ptx

ORIGIN = np.array([512_000.0, 4_321_000.0, 100.0])  # street level at the building's corner
CAMERA = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000))
NOISE = 0.5  # px


def _building(kind, rng, n=16):
    """Control points on a building: the wall y = 0 (east-west) and, for ``corner``, the wall x = 0."""
    if kind == "terrain":  # level ground with 6 m of relief, 240 m across
        x, y, z = rng.uniform(-120, 120, n), rng.uniform(-60, 60, n), rng.uniform(0, 6, n)
        return ORIGIN + np.column_stack([x, y, z])
    if kind == "facade":  # one wall, 24 m wide, floors 2-14 m; windows 0.3 m in, balconies 1.2 m out
        x, z = rng.uniform(-12, 12, n), rng.uniform(2, 14, n)
        y = rng.choice([0.0, -0.3, -1.2], n)
    else:  # the upper floors of a corner, 8-12 m up: less spread in height than across
        on_south = np.arange(n) % 2 == 0
        x = np.where(on_south, rng.uniform(1, 15, n), 0.0)
        y = np.where(on_south, 0.0, rng.uniform(1, 15, n))
        z = rng.uniform(8, 12, n)
    return ORIGIN + np.column_stack([x, y, z])


VIEWS = {  # ground points, camera position, point looked at (all relative to ORIGIN)
    "facade, horizontal axis": ("facade", [0, -35, 1.6], [0, 0, 1.6]),
    "facade, oblique 45 deg": ("facade", [-25, -25, 1.6], [0, 0, 1.6]),
    "facade, looking up 20 deg": ("facade", [0, -22, 1.6], [0, 0, 9.6]),
    "corner, looking up 25 deg": ("corner", [-10, -10, 1.6], [5, 5, 10]),
    "terrain, oblique 45 deg down": ("terrain", [0, -300, 300], [0, 0, 0]),
}


def _view(name, seed=0):
    kind, position, target = VIEWS[name]
    rng = np.random.default_rng(seed)
    ground = _building(kind, rng)
    eo = ptx.look_at(ORIGIN + position, ORIGIN + target, kappa_up=[0.0, 0.0, 1.0])  # upright
    xy = np.asarray(ptx.project(ground, eo, CAMERA))
    px = np.asarray(CAMERA.image_to_pixel(xy))
    assert np.all((px > 0) & (px < [4000, 3000])), "a control point is off the image"
    assert np.all(np.asarray(ptx.depth(ground, eo)) > 0)
    return eo, ground, xy + rng.normal(0.0, NOISE, xy.shape)


@pytest.mark.parametrize("name", list(VIEWS))
def test_terrestrial_views_equal_truth_within_sigma(name):
    eo, ground, xy = _view(name)
    res = ptx.resect(xy, ground, CAMERA, sigma=NOISE, throw=False)
    assert res.converged, res.message
    conv = res.exterior.convention
    angles = np.asarray(eo.to_convention(conv).angles)
    # one rotation, two angle triplets (a, b, c) and (a + pi, pi - b, c + pi): the one nearer the result
    other = angles + [np.pi, np.pi - 2 * angles[1], np.pi]
    np.testing.assert_allclose(ptx.rotation_matrix(other, conv), ptx.rotation_matrix(angles, conv), atol=1e-12)
    got = np.asarray(res.exterior.angles)
    d_ang = min(((got - a + np.pi) % (2 * np.pi) - np.pi for a in (angles, other)), key=lambda d: np.abs(d).max())
    diff = np.concatenate([np.asarray(res.exterior.position) - np.asarray(eo.position), d_ang])
    assert np.all(np.abs(diff) < 3.0 * res.std), (diff, res.std)
    assert res.outliers.sum() == 0


MIRRORS = {
    "image x reversed": lambda xy, g: (xy * [-1.0, 1.0], g),
    "image y reversed": lambda xy, g: (xy * [1.0, -1.0], g),
    "ground E and N swapped": lambda xy, g: (xy, g[:, [1, 0, 2]]),
}


@pytest.mark.parametrize("mirror", list(MIRRORS))
@pytest.mark.parametrize("name", ["facade, looking up 20 deg", "corner, looking up 25 deg"])
def test_mirrored_terrestrial_views_are_refused(name, mirror):
    # A proper camera fits a mirrored building only approximately (here rmse ~45 px on the façade,
    # converged all the same, before the mirrored fit was compared); the mirror is named.
    _, ground, xy = _view(name)
    xy_m, ground_m = MIRRORS[mirror](xy, ground)
    res = ptx.resect(xy_m, ground_m, CAMERA, throw=False)
    assert not res.converged and "mirror" in res.message, res.message
    with pytest.raises(ptx.ConvergenceError, match="mirror"):
        ptx.resect(xy_m, ground_m, CAMERA)
