"""Tie points between RPC images (issue 35, "RPC stereo"): photax.match_ties on sensors, and the RPC
block adjustment fed with its ties.

Truth: two push-broom images of :func:`photax.scene.pushbroom_scene`, 15 deg forwards and backwards
at 1 m GSD, rendered from a known surface and texture by their rigorous models (``rpc_pair``, shared
with ``test_stereo_synthetic``).  The matcher sees only the RPCs fitted to them (:func:`photax.fit_rpc`)
as :class:`photax.GroundSensor` s in UTM, and a DEM of the surface.  The true correspondent of a tie's
point in image 0 is its ground point on the surface (localized by the rigorous model of image 0)
projected by the rigorous model of image 1: independent of the RPCs and of the matcher.
"""

from __future__ import annotations

import numpy as np
import pytest
from rpc_pair import on_surface, render, surface, texture

import photax
from photax.dem import DEM
from photax.errors import CRSMismatchError
from photax.matching import match_ties
from photax.pushbroom import fit_rpc
from photax.rpc_block import adjust_rpc_block
from photax.scene import pushbroom_scene
from photax.sensor import WGS84, GroundSensor, _pyproj, utm_crs

SIZE = (200, 200)
HEIGHTS = (0.0, 400.0)
WINDOW = 8  # match_ties' default half window, px
BIAS = np.array([2.5, -3.5])  # px: (sample, line) offset error put into image 1's RPC


@pytest.fixture(scope="module")
def pair():
    scenes = [
        pushbroom_scene(pitch=-15.0, gsd=1.0, image_size=SIZE, height_range=HEIGHTS, seed=0),
        pushbroom_scene(pitch=15.0, roll=2.0, gsd=1.0, image_size=SIZE, height_range=HEIGHTS, seed=1),
    ]
    fits = [fit_rpc(s.camera, HEIGHTS, grid=9, layers=4) for s in scenes]
    centre = np.asarray(fits[0].camera.ground_box()[0], dtype=float)
    crs = utm_crs(*centre)
    x0, y0 = _pyproj(centre[None], WGS84, crs)[0]
    tex = texture(7)
    images = [render(s.camera, crs, x0, y0, tex, SIZE) for s in scenes]
    cell = 2.0  # m: the DEM samples the surface; bilinear between its posts it is off by < 1 cm here
    c = cell * (np.arange(500) + 0.5) - 500.0
    heights = surface(x0 + c[None, :], y0 - c[:, None], x0, y0)
    dem = DEM(heights, (cell, 0.0, x0 - 500.0, 0.0, -cell, y0 + 500.0), crs=crs)
    return dict(
        cams=[s.camera for s in scenes],
        rpcs=[f.camera for f in fits],
        fit_error=max(f.check_max_error for f in fits),
        crs=crs,
        origin=(x0, y0),
        images=images,
        dem=dem,
    )


def _truth(pair, xy0):
    """The rigorous correspondents in image 1 of pixels ``xy0`` of image 0, and their ground (lon, lat, h)."""
    llh, _ = on_surface(pair["cams"][0], xy0, pair["crs"], *pair["origin"], tol=1e-7, steps=80)
    return np.asarray(pair["cams"][1](llh)), llh


def _tie_errors(pair, ties):
    """``(t, 2)`` matched minus true position in image 1 of every two-image track."""
    rows = ties.as_rows()
    p0 = {int(r[0]): r[2:] for r in rows if r[1] == 0}
    p1 = {int(r[0]): r[2:] for r in rows if r[1] == 1}
    ids = sorted(set(p0) & set(p1))
    true1, _ = _truth(pair, np.array([p0[i] for i in ids]))
    return np.array([p1[i] for i in ids]) - true1


def _bound(pair):
    """Largest error a correct match may have, px.  LSM fits an affine map to the window; the mapping
    between the views is affine on the plane but not on the hill, whose height's Laplacian peaks at
    2 A / s^2 (A = 40 m, s = 60 m).  Times the parallax per metre of height (dp/dh, from the rigorous
    models) it is the Laplacian of the x-parallax; a quadratic term 1/2 a u^2 left over by the best
    affine fit shifts the window's centre by 1/2 a E[u^2], E[u^2] = w (w + 1) / 3 over a window of
    half-size w.  Plus both RPCs' fit error (the truth is the rigorous models') and 0.02 px for the
    cubic resampling of the band-limited texture (Gaussian, sigma 2 px)."""
    mid = np.array([[SIZE[0] / 2, SIZE[1] / 2]])
    ll = [np.asarray(pair["cams"][0].to_ground(mid, np.array([h]))) for h in (150.0, 250.0)]
    ends = [np.asarray(pair["cams"][1](np.column_stack([g, [h]]))) for g, h in zip(ll, (150.0, 250.0))]
    dp_dh = np.linalg.norm(ends[1] - ends[0]) / 100.0
    laplacian = 2 * 40.0 / 60.0**2  # 1/m; 1 m GSD: 1/px
    return 0.5 * dp_dh * laplacian * WINDOW * (WINDOW + 1) / 3 + 2 * pair["fit_error"] + 0.02


def _sensors(pair, rpcs=None):
    return [GroundSensor(r, pair["crs"]) for r in (rpcs or pair["rpcs"])]


def test_rpc_ties_agree_with_the_rigorous_correspondences(pair):
    ties = match_ties(pair["images"], _sensors(pair), pair["dem"], max_points=60)
    assert ties.pair_status[0, 1] == "ok" and ties.image_status == ["ok", "ok"]
    # the overlap against the rigorous models' own: the share of a 16 x 16 grid of each image whose
    # surface point the other image sees (the matcher's grid; points on the edge may fall either way)
    u = np.linspace(0.0, SIZE[0] - 1.0, 16)
    grid = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    share = []
    for i, j in ((0, 1), (1, 0)):
        llh, _ = on_surface(pair["cams"][i], grid, pair["crs"], *pair["origin"], tol=1e-7, steps=80)
        pj = np.asarray(pair["cams"][j](llh))
        share.append(np.mean(np.all((pj >= 0) & (pj <= np.array(SIZE) - 1), axis=1)))
    assert ties.pair_overlap[0, 1] == pytest.approx(np.mean(share), abs=2 / 256)
    err = _tie_errors(pair, ties)
    tol = _bound(pair)
    print(f"RPC ties: {len(err)} tracks, error |d| median {np.median(np.linalg.norm(err, axis=1)):.3f} px, "
          f"max {np.abs(err).max():.3f} px (bound {tol:.3f} px)")  # fmt: skip
    assert len(err) >= 30
    assert np.abs(err).max() <= tol
    # the ground points are the DEM's: on the surface, in the sensors' UTM
    g = ties.ground
    np.testing.assert_allclose(g[:, 2], surface(g[:, 0], g[:, 1], *pair["origin"]), atol=0.05)


def test_a_biased_rpc_is_matched_and_the_block_recovers_the_bias(pair):
    r0, r1 = pair["rpcs"]
    off = np.asarray(r1.offsets).copy()
    off[3:] += BIAS  # the RPC of image 1 now images every point BIAS px away from where it is
    biased = [r0, r1.replace(offsets=off)]
    ties = match_ties(pair["images"], _sensors(pair, biased), pair["dem"], max_points=60)
    err = _tie_errors(pair, ties)
    assert len(err) >= 30 and np.abs(err).max() <= _bound(pair)  # the images decide, not the prediction
    # two GCPs on the surface, measured (rigorous models, no noise) in both images
    gxy = np.array([[60.0, 70.0], [140.0, 130.0]])
    g1, gll = _truth(pair, gxy)
    obs = np.array([[0, 0, *gxy[0]], [1, 0, *gxy[1]], [0, 1, *g1[0]], [1, 1, *g1[1]]])
    res = adjust_rpc_block(biased, ties, (gll, obs), model="shift", pixel_sigma=0.05)
    expected = np.zeros((2, 2))
    expected[1] = -BIAS  # the correction that takes the biased RPC back onto the images
    got, sig = res.corrections[:, :, 0], res.correction_sigmas[:, :, 0]
    print(f"block: corrections {got.round(4).tolist()} +- {sig.round(4).tolist()}, sigma0 {res.sigma0:.2f}, "
          f"tie rmse {res.rmse:.3f} px")  # fmt: skip
    assert np.all(np.abs(got - expected) <= 3 * sig + 2 * pair["fit_error"]), (got, sig)
    assert np.all(sig < 0.05)  # px: dozens of sub-pixel ties pin the shifts far below a pixel
    assert res.rmse <= _bound(pair)
    # the same from the rows and the RPC cameras (what adjust_rpc_block took before TiePoints)
    again = adjust_rpc_block([s.camera for s in _sensors(pair, biased)], ties.as_rows(), (gll, obs), pixel_sigma=0.05)
    np.testing.assert_array_equal(again.corrections, res.corrections)


def test_bad_sensor_lists_are_refused(pair):
    images, dem = pair["images"], pair["dem"]
    s = _sensors(pair)
    with pytest.raises(ValueError, match="1 sensors for 2 images"):
        match_ties(images, s[:1], dem)
    other = GroundSensor(pair["rpcs"][1], "EPSG:32633" if "32632" in str(pair["crs"]) else "EPSG:32632")
    with pytest.raises(CRSMismatchError, match="sensors\\[1\\]"):
        match_ties(images, [s[0], other], dem)
    with pytest.raises(ValueError, match="photax sensor"):
        match_ties(images, [s[0], pair["rpcs"][1]], dem)
    with pytest.raises(ValueError, match="give the DEM"):
        match_ties(images, s)
    with pytest.raises(ValueError, match="shape"):
        match_ties([images[0], images[1][:-1]], s, dem)
    with pytest.raises(ValueError, match="RPCCamera"):  # a push-broom model is not an RPC: fit_rpc first
        adjust_rpc_block([pair["cams"][0], pair["rpcs"][1]], np.zeros((0, 4)), correction_sigma=1.0)
    assert photax.match_ties is match_ties
