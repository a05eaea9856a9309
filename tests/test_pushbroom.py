"""Rigorous push-broom model (issue 23, item 4): projection against a brute-force line search and
pyproj's geodesy, forward / inverse round trip, resection of the orbit and attitude on a synthetic
scene with known truth, and the RPC fitted to it."""

import jax.numpy as jnp
import numpy as np
import pytest

from photax.earth import ecef_to_geodetic, geodetic_to_ecef
from photax.pushbroom import PushbroomCamera, fit_rpc, resect_pushbroom
from photax.rotation import rotation_matrix
from photax.scene import pushbroom_scene

# a nadir view, and one looking 20 deg off nadir across the track and 15 deg forward along it
VIEWS = {"nadir": dict(roll=0.0, pitch=0.0), "oblique": dict(roll=20.0, pitch=-15.0)}


@pytest.fixture(scope="module", params=list(VIEWS))
def scene(request):
    return pushbroom_scene(altitude=620e3, image_size=(2000, 2000), seed=3, **VIEWS[request.param])


def test_geodesy_matches_pyproj():
    pyproj = pytest.importorskip("pyproj")
    rng = np.random.default_rng(0)
    g = np.column_stack([rng.uniform(-180, 180, 50), rng.uniform(-89, 89, 50), rng.uniform(-500, 7e5, 50)])
    x, y, z = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(*g.T)
    ecef = np.column_stack([x, y, z])
    np.testing.assert_allclose(np.asarray(geodetic_to_ecef(jnp.asarray(g))), ecef, atol=1e-6)
    back = np.asarray(ecef_to_geodetic(jnp.asarray(ecef)))
    np.testing.assert_allclose(back[:, :2], g[:, :2], atol=1e-10)  # degrees: ~10 um
    np.testing.assert_allclose(back[:, 2], g[:, 2], atol=1e-6)


def _brute_force(camera: PushbroomCamera, xyz: np.ndarray) -> np.ndarray:
    """Column, row of one ECEF point by scanning every line (numpy): the line where the point's distance
    from the array changes sign, refined by linear interpolation on a 1/100-line grid around it."""
    w, lines = camera.image_size
    pos, ang = np.asarray(camera.position), np.asarray(camera.angles)
    ref, f = np.asarray(camera.reference), float(camera.focal_length)
    x0, y0 = np.asarray(camera.principal_point)

    def in_camera(rows):
        tau = (rows - (lines - 1) / 2) / ((lines - 1) / 2)
        c = (tau[:, None] ** np.arange(len(pos))) @ pos
        a = (tau[:, None] ** np.arange(len(ang))) @ ang
        r = ref @ np.asarray(rotation_matrix(jnp.asarray(a), camera.convention))
        return np.einsum("nji,nj->ni", r, xyz - c)

    def off(rows):
        q = in_camera(rows)
        return y0 - f * q[:, 1] / q[:, 2]

    rows = np.arange(-50.0, lines + 50.0)
    g = off(rows)
    i = np.flatnonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]
    fine = np.linspace(rows[i], rows[i + 1], 101)
    gf = off(fine)
    j = np.flatnonzero(np.sign(gf[:-1]) != np.sign(gf[1:]))[0]
    row = fine[j] - gf[j] * (fine[j + 1] - fine[j]) / (gf[j + 1] - gf[j])
    q = in_camera(np.array([row]))[0]
    return np.array([(w - 1) / 2 + x0 - f * q[0] / q[2], row])


def test_projection_matches_brute_force(scene):
    cam = scene.camera
    xyz = np.asarray(geodetic_to_ecef(jnp.asarray(scene.check_ground)))
    ref = np.array([_brute_force(cam, p) for p in xyz])
    np.testing.assert_allclose(np.asarray(cam(jnp.asarray(scene.check_ground))), ref, atol=1e-3)


def test_forward_inverse_round_trip(scene):
    cam = scene.camera
    rng = np.random.default_rng(1)
    w, lines = cam.image_size
    pix = rng.uniform([0, 0], [w - 1, lines - 1], (200, 2))
    h = rng.uniform(*scene.height_range, 200)
    lonlat = np.asarray(cam.to_ground(jnp.asarray(pix), jnp.asarray(h)))
    ground = np.column_stack([lonlat, h])
    np.testing.assert_allclose(np.asarray(cam(jnp.asarray(ground))), pix, atol=1e-6)
    # and ground -> pixel -> ground at the same height
    back = np.asarray(cam.to_ground(cam(jnp.asarray(ground)), jnp.asarray(h)))
    np.testing.assert_allclose(back, lonlat, atol=1e-11)  # degrees: ~1 um


def test_scene_centre_in_the_middle(scene):
    centre = np.asarray(scene.camera(jnp.array([10.0, 45.0, 0.0])))
    np.testing.assert_allclose(centre, [999.5, 999.5], atol=0.01)


def _within(res, truth, k=3.0):
    err = res.estimate - truth
    assert np.all(np.abs(err) < k * res.std), dict(zip(res.parameters, err / res.std, strict=True))


def test_resection_attitude_recovers_truth(scene):
    start = PushbroomCamera(scene.camera.position, scene.start.angles, scene.camera.reference,
                            scene.camera.focal_length, image_size=scene.camera.image_size)  # fmt: skip
    res = resect_pushbroom(start, scene.gcp_ground, scene.gcp_pixel, attitude_order=1, position_order=None,
                           sigma=scene.noise_px, check=np.arange(20) >= 15)  # fmt: skip
    assert res.converged and res.statistic == "w" and res.redundancy == 2 * 15 - 6
    _within(res, -scene.attitude_error.ravel())
    assert 0.5 < res.sigma0 < 1.6  # the noise as given (chi-square with 24 d.o.f.: 0.68..1.33 at 95 %)
    assert not res.outliers.any()
    assert res.check_rmse < 3 * scene.noise_px
    start_err = np.linalg.norm(np.asarray(start(jnp.asarray(scene.check_ground))) - scene.check_pixel, axis=1)
    assert np.sqrt(np.mean(start_err**2)) > 5.0  # the start was far off: the adjustment did the work


def test_resection_orbit_and_attitude_with_priors(scene):
    res = resect_pushbroom(scene.start, scene.gcp_ground, scene.gcp_pixel, attitude_order=1, position_order=1,
                           position_sigma=10.0, sigma=scene.noise_px)  # fmt: skip
    assert res.converged
    assert res.redundancy == 2 * 20 + 6 - 12
    truth = np.concatenate([-scene.position_error.ravel(), -scene.attitude_error.ravel()])
    _within(res, truth)
    assert res.rmse < 2 * scene.noise_px
    # the orbit and the attitude are strongly correlated (along-track position vs pitch): the prior holds them
    assert np.max(np.abs(res.correlation[np.triu_indices(12, 1)])) > 0.9


def test_resection_finds_a_blunder(scene):
    pixel = scene.gcp_pixel.copy()
    pixel[7] += [12.0, -9.0]
    start = PushbroomCamera(scene.camera.position, scene.start.angles, scene.camera.reference,
                            scene.camera.focal_length, image_size=scene.camera.image_size)  # fmt: skip
    res = resect_pushbroom(start, scene.gcp_ground, pixel, position_order=None, sigma=scene.noise_px)
    assert res.converged
    assert np.flatnonzero(res.outliers).tolist() == [7]
    assert np.nanmax(np.abs(res.normalised[7])) > res.critical
    _within(res, -scene.attitude_error.ravel())
    assert "P7" in res.summary()


def test_resection_bad_input(scene):
    cam = scene.start
    with pytest.raises(ValueError, match="outside the image"):
        resect_pushbroom(cam, scene.gcp_ground, scene.gcp_pixel + [0.0, 5000.0])
    with pytest.raises(ValueError, match="need at least 3 control points, got 2"):
        resect_pushbroom(cam, scene.gcp_ground[:2], scene.gcp_pixel[:2], position_order=None)
    g = scene.gcp_ground.copy()
    g[4, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite GCP coordinates: P4"):
        resect_pushbroom(cam, g, scene.gcp_pixel)
    with pytest.raises(ValueError, match="cannot project P0"):
        resect_pushbroom(cam, scene.gcp_ground[:, [1, 0, 2]], scene.gcp_pixel)  # lat, lon swapped
    with pytest.raises(ValueError, match="not a rotation"):
        PushbroomCamera(cam.position, cam.angles, 2 * np.eye(3), cam.focal_length, image_size=(10, 10))


def test_fitted_rpc_reproduces_the_rigorous_model(scene):
    fit = fit_rpc(scene.camera, scene.height_range)
    assert fit.check_max_error <= 0.01 and fit.max_error <= 0.01
    assert fit.check_residuals.shape == (fit.check_points, 2)
    np.testing.assert_allclose(np.asarray(scene.camera(jnp.asarray(fit.check_ground))), fit.check_pixel, atol=1e-6)
    # independently: random pixels at random heights over the scene and its height range
    rng = np.random.default_rng(2)
    w, lines = scene.camera.image_size
    pix = rng.uniform([0, 0], [w - 1, lines - 1], (500, 2))
    h = rng.uniform(*scene.height_range, 500)
    ground = np.column_stack([np.asarray(scene.camera.to_ground(jnp.asarray(pix), jnp.asarray(h))), h])
    err = np.linalg.norm(np.asarray(fit.camera(jnp.asarray(ground))) - pix, axis=1)
    assert err.max() <= 0.01
    # the RPC's own inverse lands on the rigorous model's ground point
    back = np.asarray(fit.camera.to_ground(jnp.asarray(pix), jnp.asarray(h)))
    assert np.max(np.abs(back - ground[:, :2])) < 0.01 * 2.0 / 111e3  # 0.01 px of 2 m, in degrees


def test_fit_rpc_bad_input(scene):
    with pytest.raises(ValueError, match="h_max > h_min"):
        fit_rpc(scene.camera, (100.0, 100.0))


def test_resection_failure_is_not_a_result(scene):
    from photax.errors import ConvergenceError

    with pytest.raises(ConvergenceError, match="did not converge"):
        resect_pushbroom(scene.start, scene.gcp_ground, scene.gcp_pixel, max_steps=1)
    res = resect_pushbroom(scene.start, scene.gcp_ground, scene.gcp_pixel, max_steps=1, throw=False)
    assert not res.converged and "did not converge" in res.message


@pytest.mark.parametrize("name", ["resect_pushbroom", "fit_rpc"])
def test_examples_run(name):
    """The docstring Examples run (as tests/test_doctests.py does for the older entry points)."""
    import doctest

    import photax

    tests = doctest.DocTestFinder(recurse=False).find(getattr(photax, name), name, globs={})
    assert sum(len(t.examples) for t in tests) >= 3
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for t in tests:
        runner.run(t)
    assert runner.failures == 0
