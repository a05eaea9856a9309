"""Push-broom orthorectification (issue 23, item 4) through the sensor protocol: an image rendered from
an analytic ground pattern (each pixel's ground point by the rigorous model's inverse onto a flat,
ellipsoidal DEM) is orthorectified with the rigorous PushbroomCamera and with the RPC fitted to it;
both orthos reproduce the pattern at the grid's ground points (to the bilinear resampling's bound), a
bright spot lands at its known map position, and the two models' pixel positions agree to the RPC's
fit error."""

import jax.numpy as jnp
import numpy as np
import pytest

from photax.dem import DEM
from photax.pushbroom import fit_rpc
from photax.rectification import OrthoModel, ortho_grid, orthorectify
from photax.scene import pushbroom_scene
from photax.sensor import GroundSensor, sensor_of, utm_crs

pyproj = pytest.importorskip("pyproj")

HEIGHT = 700.0  # ellipsoidal (m), inside the scene's height range
WAVE = 200.0  # the pattern's wavelength on the ground (m): 20 GSDs
SIGMA = 25.0  # the spot's standard deviation (m)


def _pattern(lonlat, centre, spot):
    """Grey values ``(2, n)`` at ``(n, 2)`` lon, lat: band 0 a plane wave (in local metres about ``centre``)
    plus a Gaussian spot at ``spot``, band 1 the spot alone (to find it in the ortho)."""
    k = np.array([np.cos(np.radians(centre[1])), 1.0]) * 111_320.0  # m per degree, locally
    d = (lonlat - centre) * k
    s = (lonlat - spot) * k
    wave = np.sin(2 * np.pi * (0.8 * d[:, 0] + 0.6 * d[:, 1]) / WAVE)
    blob = 4.0 * np.exp(-0.5 * np.sum(s**2, 1) / SIGMA**2)
    return np.stack([10.0 + wave + blob, blob])


@pytest.fixture(scope="module")
def setup():
    scene = pushbroom_scene(roll=12.0, pitch=-10.0, gsd=10.0, image_size=(96, 80), n_gcp=6, n_check=0)
    cam = scene.camera
    w, lines = cam.image_size
    centre = np.asarray(cam.to_ground(jnp.array([(w - 1) / 2, (lines - 1) / 2]), HEIGHT))
    spot = np.asarray(cam.to_ground(jnp.array([40.3, 33.7]), HEIGHT))
    cols, rows = np.meshgrid(np.arange(w, dtype=float), np.arange(lines, dtype=float))
    ll = np.asarray(cam.to_ground(jnp.asarray(np.stack([cols, rows], -1).reshape(-1, 2)), HEIGHT))
    assert np.isfinite(ll).all()
    image = _pattern(ll, centre, spot).reshape(2, lines, w)
    (lon0, lat0), (dl, dp) = cam.ground_box()
    dem = DEM(np.full((2, 2), HEIGHT), DEM.flat(HEIGHT, (lon0 - dl, lat0 - dp, lon0 + dl, lat0 + dp)).transform,
              crs="EPSG:4979")  # fmt: skip
    crs = utm_crs(*centre)
    return scene, image, dem, crs, centre, spot


def test_pushbroom_ortho_reproduces_the_ground_and_its_rpc(setup):
    scene, image, dem, crs, centre, spot = setup
    cam = scene.camera
    assert isinstance(sensor_of(None, cam, crs), GroundSensor)
    grid = ortho_grid(None, cam, dem, 5.0, crs=crs)
    ortho, grid = orthorectify(image, None, cam, dem, grid, approx=None)  # exact mapping: errors are the models'
    fit = fit_rpc(cam, scene.height_range)
    ortho_rpc, _ = orthorectify(image, None, fit.camera, dem, grid, approx=None)

    # the grid's pixel centres on the ground, their lon, lat by pyproj
    rows, cols = np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]] + 0.5
    a, b, xoff, d, e, yoff = tuple(grid.transform)[:6]
    x, y = xoff + a * cols + b * rows, yoff + d * cols + e * rows
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)
    truth = _pattern(np.stack([lon, lat], -1).reshape(-1, 2), centre, spot).reshape(2, *grid.shape)
    seen = np.isfinite(ortho[0])
    assert seen.mean() > 0.3  # the image is a tilted quadrilateral in its bounding grid
    # bilinear interpolation's error bound, h^2/8 (|f_cc| + |f_rr|): the wave's and the spot's second
    # derivatives per image pixel (pixel side < 1.3 GSD at these view angles)
    px = 1.3 * 10.0
    bound = ((2 * np.pi * px / WAVE) ** 2 + 4.0 * (px / SIGMA) ** 2) * 2 / 8
    err = np.abs(ortho[0] - truth[0])[seen]
    print(f"push-broom ortho - pattern: max {err.max():.4f}, mean {err.mean():.4f} (bound {bound:.3f})")
    assert err.max() < bound
    assert np.isfinite(ortho_rpc[0][seen]).mean() > 0.99
    both = seen & np.isfinite(ortho_rpc[0])
    diff = np.abs(ortho[0] - ortho_rpc[0])[both]
    print(f"push-broom ortho - its RPC's: max {diff.max():.2e} (fit check max {fit.check_max_error:.2e} px)")

    # the pixel positions of the two models at the grid's points: the RPC's fit error
    xy = np.column_stack([x[seen], y[seen]])
    p_pb = np.asarray(OrthoModel(None, cam, dem, crs)(jnp.asarray(xy)))
    p_rpc = np.asarray(OrthoModel(None, fit.camera, dem, crs)(jnp.asarray(xy)))
    ll_xy = np.column_stack([lon[seen], lat[seen], np.full(len(xy), HEIGHT)])
    np.testing.assert_allclose(p_pb, np.asarray(cam(jnp.asarray(ll_xy))), rtol=0, atol=1e-6)
    moved = np.abs(p_pb - p_rpc).max()
    assert moved <= 2 * fit.check_max_error
    # so the orthos differ by at most the bilinear image's Lipschitz constant times that
    lipschitz = np.hypot(np.abs(np.diff(image[0], axis=1)).max(), np.abs(np.diff(image[0], axis=0)).max())
    assert diff.max() <= lipschitz * np.sqrt(2) * moved + 1e-12

    # the spot's centroid lands at its map position (to a hundredth of an output pixel)
    sx, sy = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(*spot)
    near = np.hypot(x - sx, y - sy) < 4 * SIGMA
    assert seen[near].all()
    for o in (ortho, ortho_rpc):
        wgt = np.where(near, o[1], 0.0)
        cx, cy = (wgt * x).sum() / wgt.sum(), (wgt * y).sum() / wgt.sum()
        print(f"spot centroid off its map position by ({cx - sx:.2e}, {cy - sy:.2e}) m")
        assert np.hypot(cx - sx, cy - sy) < 0.01 * abs(a)  # 5 cm


def test_pushbroom_ortho_dask_equals_whole(setup):
    """orthorectify_dask takes the push-broom camera too: the whole-image ortho (exact mapping) to 1e-9 grey
    levels (not bit for bit as for a frame: the line search's Newton steps compile differently per chunk
    shape, last-bit differences of the position, 5e-11 grey levels here), the same pixels with data."""
    pytest.importorskip("dask")
    from photax.rectification import orthorectify_dask

    scene, image, dem, crs, _, _ = setup
    grid = ortho_grid(None, scene.camera, dem, 10.0, crs=crs)
    whole, _ = orthorectify(image[0], None, scene.camera, dem, grid, approx=None)
    lazy = orthorectify_dask(image[0], None, scene.camera, dem, grid, chunks=64, approx=None)
    got = np.asarray(lazy.compute())
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(whole))
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-9)


def test_pushbroom_ortho_defaults_and_bad_input(setup):
    """The default grid CRS is the scene's UTM zone; an exterior orientation or a missing CRS is refused."""
    scene, _, dem, crs, _, _ = setup
    assert ortho_grid(None, scene.camera, dem, 20.0).crs == crs
    with pytest.raises(ValueError, match="carries its own orientation"):
        sensor_of(object(), scene.camera, crs)
    with pytest.raises(ValueError, match="needs the output grid's CRS"):
        sensor_of(None, scene.camera, None)
