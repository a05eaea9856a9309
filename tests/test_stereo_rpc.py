"""RPC stereo (issue 35 item 4, issue 36 items 2-3): s2p's affine epipolar pair of two RPCs, and the
triangulation of its disparities.

Truth: two push-broom images of :func:`photax.scene.pushbroom_scene` looking 12 deg forwards and
backwards (and 3 deg across), their RPCs fitted by :func:`photax.fit_rpc`.  The rectification and the
triangulation use the RPCs only; the checks use the rigorous push-broom models: ground points on a
known surface (a plane with a bump) are localized and projected by them, independently of the code
under test.
"""

from __future__ import annotations

import numpy as np
import pytest

import photax
from photax.pushbroom import fit_rpc
from photax.scene import pushbroom_scene
from photax.sensor import WGS84, _pyproj, utm_crs
from photax.stereo import disparity_to_points, height_per_disparity, rasterize_points, triangulate_pair

SIZE = (400, 400)
HEIGHTS = (0.0, 400.0)


@pytest.fixture(scope="module")
def scenes():
    a = pushbroom_scene(pitch=-12.0, image_size=SIZE, height_range=HEIGHTS, seed=0)
    b = pushbroom_scene(pitch=12.0, roll=3.0, image_size=SIZE, height_range=HEIGHTS, seed=1)
    rpcs = [fit_rpc(s.camera, HEIGHTS, grid=9, layers=4).camera for s in (a, b)]
    return a.camera, b.camera, rpcs


def surface(x, y, x0, y0):
    """A plane at 150 m tilted 5 %, with a 120 m bump of 250 m radius, over UTM metres."""
    return 150.0 + 0.05 * (x - x0) + 120.0 * np.exp(-((x - x0 - 50) ** 2 + (y - y0 + 40) ** 2) / (2 * 250.0**2))


def on_surface(camera, pixel, crs, x0, y0):
    """Left pixels -> lon, lat, h on the surface, by the rigorous camera (fixed point on h)."""
    h = np.full(len(pixel), 200.0)
    for _ in range(60):
        ll = np.asarray(camera.to_ground(pixel, h))
        xy = _pyproj(ll, WGS84, crs)
        new = surface(xy[:, 0], xy[:, 1], x0, y0)
        if np.max(np.abs(new - h)) < 1e-6:
            break
        h = new
    return np.column_stack([ll, h]), xy


def test_rpc_epipolar_pair_rows_agree(scenes):
    true_a, true_b, (rpc_a, rpc_b) = scenes
    img = np.random.default_rng(0).random(SIZE[::-1])
    with pytest.raises(ValueError, match="camera_right"):
        photax.epipolar_pair(img, img, rpc_a, None, None)
    pair = photax.epipolar_pair(img, img, rpc_a, None, None, camera_right=rpc_b, bounds=(50, 50, 350, 350),
                                heights=HEIGHTS)  # fmt: skip
    assert isinstance(pair, photax.AffineEpipolarPair)
    assert pair.vertical_residual <= 0.5
    # independent check: points of the rigorous models at random heights share their epipolar row
    rng = np.random.default_rng(3)
    px = rng.uniform(50, 350, (200, 2))
    h = rng.uniform(*HEIGHTS, 200)
    ll = np.asarray(true_a.to_ground(px, h))
    pr = np.asarray(true_b(np.column_stack([ll, h])))
    el, er = pair.to_epipolar("left", px), pair.to_epipolar("right", pr)
    dv = el[:, 1] - er[:, 1]
    assert np.max(np.abs(dv)) <= 0.5, np.max(np.abs(dv))
    d = el[:, 0] - er[:, 0]
    lo, hi = pair.disparity_range
    assert lo <= d.min() and d.max() <= hi  # the range covers the heights
    # the arrays hold the images resampled: the left array at a point's epipolar pixel is the image there
    k = np.all((el > 2) & (el < np.array(pair.left.shape[::-1]) - 3), axis=1)
    got = photax.resample(pair.left, el[k, 0], el[k, 1], "nearest")
    want = photax.resample(img, *pair.from_epipolar("left", np.round(el[k])).T, "cubic")
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-9)


def test_rpc_triangulation_recovers_the_surface(scenes):
    true_a, true_b, (rpc_a, rpc_b) = scenes
    img = np.zeros(SIZE[::-1])
    pair = photax.epipolar_pair(img, img, rpc_a, None, None, camera_right=rpc_b, bounds=(20, 20, 380, 380),
                                heights=HEIGHTS)  # fmt: skip
    crs = utm_crs(*np.asarray(rpc_a.ground_box()[0]))
    x0, y0 = _pyproj(np.asarray(rpc_a.ground_box()[0])[None], WGS84, crs)[0]
    # the exact disparity of every 8th left epipolar pixel, from the rigorous models on the surface
    rows, cols = pair.left.shape
    disparity = np.full((rows, cols), np.nan)
    rr, cc = np.mgrid[0:rows:8, 0:cols:8]
    el = np.column_stack([cc.ravel(), rr.ravel()]).astype(float)
    pl = pair.from_epipolar("left", el)
    inside = np.all((pl >= 20) & (pl <= 380), axis=1)
    llh, _ = on_surface(true_a, pl[inside], crs, x0, y0)
    er = pair.to_epipolar("right", np.asarray(true_b(llh)))
    disparity[rr.ravel()[inside], cc.ravel()[inside]] = el[inside, 0] - er[:, 0]
    pts = disparity_to_points(pair, disparity, crs=crs, colour=False)
    assert len(pts) >= 0.95 * inside.sum()
    dz = pts.z - surface(pts.x, pts.y, x0, y0)
    # the RPC fit (< 0.01 px) and the affine rows (|dv| <= vertical_residual) leave centimetres
    assert np.median(np.abs(dz)) < 0.1, np.median(np.abs(dz))
    assert np.max(pts.residual) <= pair.vertical_residual + 0.05
    # height sigma: a disparity error of 0.3 px moves the height by 0.3 px / (dd / dh)
    # (dd / dh from the rigorous models: one left pixel localized 100 m apart, projected right)
    mid = pair.from_epipolar("left", np.array([[cols / 2, rows / 2]]))
    ends = [np.column_stack([np.asarray(true_a.to_ground(mid, np.array([h]))), [h]]) for h in (150.0, 250.0)]
    d_true = [
        pair.to_epipolar("left", mid)[0, 0] - pair.to_epipolar("right", np.asarray(true_b(e)))[0, 0] for e in ends
    ]
    dh_dd = 100.0 / abs(d_true[1] - d_true[0])
    assert height_per_disparity(pair) == pytest.approx(dh_dd, rel=0.01)
    np.testing.assert_allclose(pts.sigma_z, 0.3 * dh_dd, rtol=0.01)
    # and into a DSM on a 10 m grid: the surface at the cell centres
    grid = photax.Grid.from_bounds((pts.x.min(), pts.y.min(), pts.x.max(), pts.y.max()), 10.0, crs)
    dsm = rasterize_points(pts, grid, fill=0)
    xy = grid.xy()
    err = dsm.heights - surface(xy[..., 0], xy[..., 1], x0, y0)
    assert np.nanmedian(np.abs(err)) < 1.0  # a cell's points lie up to 7 m from its centre on a 5-10 % slope


def test_triangulate_pair_closed_form(scenes):
    """Known ground points projected by the RPCs themselves come back to the millimetre."""
    _, _, (rpc_a, rpc_b) = scenes
    rng = np.random.default_rng(5)
    ll = np.asarray(rpc_a.to_ground(rng.uniform(0, 399, (50, 2)), rng.uniform(*HEIGHTS, 50)))
    llh = np.column_stack([ll, rng.uniform(*HEIGHTS, 50)])
    got, res = triangulate_pair(rpc_a, rpc_b, np.asarray(rpc_a(llh)), np.asarray(rpc_b(llh)), heights=HEIGHTS)
    np.testing.assert_allclose(got[:, 2], llh[:, 2], atol=1e-3)
    np.testing.assert_allclose(got[:, :2], llh[:, :2], atol=1e-8)
    assert np.max(res) < 1e-6
    with pytest.raises(ValueError, match="shape"):
        triangulate_pair(rpc_a, rpc_b, np.zeros((3, 2)), np.zeros((2, 2)))


def test_a_pair_of_ground_sensors_is_the_pair_of_their_cameras(scenes):
    """``epipolar_pair(a, b, GroundSensor, GroundSensor)`` is the ``camera, camera_right=`` call; a frame
    sensor and a ground sensor are no pair."""
    from photax.sensor import FrameSensor, GroundSensor

    _, _, (rpc_a, rpc_b) = scenes
    crs = utm_crs(*np.asarray(rpc_a.ground_box()[0], dtype=float))
    img = np.random.default_rng(0).random(SIZE[::-1])
    kw = dict(bounds=(50, 50, 350, 350), heights=HEIGHTS)
    old = photax.epipolar_pair(img, img, rpc_a, None, None, camera_right=rpc_b, **kw)
    new = photax.epipolar_pair(img, img, GroundSensor(rpc_a, crs), GroundSensor(rpc_b, crs), **kw)
    np.testing.assert_array_equal(new.left, old.left)
    np.testing.assert_array_equal(new.right, old.right)
    assert new.disparity_range == old.disparity_range and new.vertical_residual == old.vertical_residual
    cam = photax.FrameCamera.from_pixels(300.0, SIZE)
    frame = FrameSensor(photax.ExteriorOrientation([0.0, 0.0, 500.0], [0.0, 0.0, 0.0]), cam)
    with pytest.raises(ValueError, match="no stereo pair"):
        photax.epipolar_pair(img, img, GroundSensor(rpc_a, crs), frame)
