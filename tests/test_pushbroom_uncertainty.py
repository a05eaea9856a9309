"""``ortho_uncertainty`` of a push-broom image (issue 23): the covariance of the orbit and attitude that
:func:`photax.resect_pushbroom` adjusted, propagated through the rigorous model (``jax.jacfwd``), against
a Monte Carlo of those parameters on the synthetic scene (:func:`photax.pushbroom_scene`).

The reference: 500 draws of the adjusted parameters from ``N(estimate, covariance)``; per ortho pixel the
spread of (image) the pixel each drawn camera reads for the ground point and (ground) the ground point
each drawn camera puts under the pixel the adjusted one reads, on the flat DEM. The standard deviation
of a standard deviation from ``N`` draws is ``1 / sqrt(2 N)`` = 3.2 % of it: the tolerance is 10 %
(3 of those; the model is linear to far better over these few-metre, few-microradian spreads).
``step=1`` (every pixel exact): the default lattice (exact every 16 pixels) assumes the fields smooth over
16 pixels, and 16 pixels of this 96 x 80 pixel toy image are a sixth of it."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photax.dem import DEM
from photax.pushbroom import resect_pushbroom
from photax.rectification import ortho_grid
from photax.scene import pushbroom_scene
from photax.sensor import GroundSensor, utm_crs
from photax.uncertainty import ortho_uncertainty

pyproj = pytest.importorskip("pyproj")

HEIGHT = 700.0
DRAWS = 500


@pytest.fixture(scope="module")
def setup():
    scene = pushbroom_scene(roll=12.0, pitch=-10.0, gsd=10.0, image_size=(96, 80), n_gcp=8, n_check=0)
    res = resect_pushbroom(scene.start, scene.gcp_ground, scene.gcp_pixel, position_order=1, position_sigma=10.0,
                           sigma=scene.noise_px)  # fmt: skip
    cam = res.camera
    w, lines = cam.image_size
    centre = np.asarray(cam.to_ground(jnp.array([(w - 1) / 2, (lines - 1) / 2]), HEIGHT))
    crs = utm_crs(*centre)
    box = GroundSensor(cam, crs).box()
    dem = DEM(np.full((2, 2), HEIGHT), DEM.flat(HEIGHT, box).transform, crs=crs)
    grid = ortho_grid(None, cam, dem, 60.0, crs=crs)
    return res, dem, grid, crs


def test_pushbroom_uncertainty_equals_a_monte_carlo(setup):
    res, dem, grid, crs = setup
    u = ortho_uncertainty(res, None, None, dem, grid, step=1)
    cam = res.camera
    names = cam.parameter_names
    index = np.array([names.index(p) for p in res.parameters])
    theta0 = np.asarray(cam.parameters())
    rng = np.random.default_rng(1)
    draws = np.tile(theta0, (DRAWS, 1))
    draws[:, index] += rng.multivariate_normal(np.zeros(len(index)), res.covariance, DRAWS)

    xy = grid.xy().reshape(-1, 2)
    g = jnp.asarray(np.column_stack([xy, np.full(len(xy), HEIGHT)]))
    sensor = GroundSensor(cam, crs)
    p0 = np.asarray(sensor(g))
    seen = np.isfinite(u.image_std[0]).ravel()
    assert seen.mean() > 0.5 and np.isfinite(p0[seen]).all()

    @jax.jit
    def image_of(theta):  # where a drawn camera images the ground points
        return eqx.tree_at(lambda s: s.camera, sensor, cam.with_parameters(theta))(g)

    @jax.jit
    def ground_of(theta):  # where a drawn camera puts the adjusted camera's pixels
        return cam.with_parameters(theta).invert(jnp.asarray(p0[seen]), jnp.full(int(seen.sum()), HEIGHT))[0]

    pix = np.stack([np.asarray(image_of(jnp.asarray(t))) for t in draws])  # (DRAWS, n, 2)
    ll = np.stack([np.asarray(ground_of(jnp.asarray(t))) for t in draws])  # (DRAWS, m, 2)
    to_map = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    x, y = to_map.transform(ll[..., 0], ll[..., 1])

    mc_image = pix[:, seen].std(0).T  # (2, m)
    mc_ground = np.stack([x.std(0), y.std(0)])
    ours_image = u.image_std.reshape(2, -1)[:, seen]
    ours_ground = u.ground_std.reshape(2, -1)[:, seen]
    assert mc_image.min() > 0.02 and mc_ground.min() > 0.2  # the propagation has something to show
    np.testing.assert_allclose(ours_image, mc_image, rtol=0.10)
    np.testing.assert_allclose(ours_ground, mc_ground, rtol=0.10)


def test_pushbroom_uncertainty_bad_input(setup):
    res, dem, grid, _ = setup
    p = len(res.camera.parameter_names)
    with pytest.raises(ValueError, match=rf"finite \({p}, {p}\) one of its parameters \(position\[0\].X"):
        ortho_uncertainty(None, np.eye(3), res.camera, dem, grid)
    with pytest.raises(ValueError, match="give None with a PushbroomResection"):
        ortho_uncertainty(res, None, res.camera.with_parameters(res.camera.parameters() + 1e-6), dem, grid)
    # a camera given with its full covariance: the same as the resection's embedded one
    names = res.camera.parameter_names
    index = [names.index(q) for q in res.parameters]
    full = np.zeros((p, p))
    full[np.ix_(index, index)] = res.covariance
    a = ortho_uncertainty(None, full, res.camera, dem, grid, coarsen=4)
    b = ortho_uncertainty(res, None, None, dem, grid, coarsen=4)
    np.testing.assert_array_equal(a.ground_var, b.ground_var)
