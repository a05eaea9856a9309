"""Per-pixel geolocation uncertainty (photax.uncertainty) against a Monte
Carlo propagation on a rendered scene: the same error sources drawn 4000
times, the image position recomputed by the collinearity model and the
ground position by monoplotting (photax.image_to_ground) the pixel that the
ortho reads onto the (perturbed) DEM -- no Jacobian involved."""

import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photax
from photax.rectification import ortho_grid
from photax.uncertainty import ortho_uncertainty

DRAWS = 4000


def _covariance(std, seed):
    """A correlated covariance with the given standard deviations."""
    a = np.random.default_rng(seed).normal(size=(len(std), len(std)))
    c = a @ a.T + len(std) * np.eye(len(std))
    d = 1 / np.sqrt(np.diag(c))
    return np.outer(std, std) * (d[:, None] * c * d[None, :])


@pytest.fixture(scope="module")
def setup():
    s = photax.relief_scene(300.0, image_size=(120, 96), focal_px=120.0, n_gcp=3, n_check=0, tilt_deg=4.0)
    grid = ortho_grid(s.exterior, s.camera, s.dem)
    cov = _covariance([1.0, 1.0, 0.5, 4e-4, 4e-4, 2.5e-4], 0)  # metres, radians
    cov_c = _covariance([0.8, 0.5, 0.5], 1)  # f, x0, y0 in pixels
    return s, grid, cov, cov_c


def test_first_order_matches_monte_carlo(setup):
    s, grid, cov, cov_c = setup
    dem_sigma = 1.5
    u = ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c, dem_sigma=dem_sigma,
                          coarsen=3)  # Jacobians on a 16-pixel lattice (the default), interpolated
    exact = ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c,
                              dem_sigma=dem_sigma, coarsen=3, step=1)  # at every pixel
    assert u.grid.transform.a == 3 * grid.transform.a and u.image_cov.shape == u.grid.shape + (2, 2)
    assert u.image_var.shape == (3, *u.grid.shape)
    xy = u.grid.xy().reshape(-1, 2)
    ext, cam, dem = s.exterior, s.camera, s.dem
    z0 = dem.height(jnp.asarray(xy[:, 0]), jnp.asarray(xy[:, 1]))
    ground = jnp.concatenate([jnp.asarray(xy), z0[:, None]], axis=-1)
    p0 = cam.image_to_pixel(photax.project(ground, ext, cam))  # what the ortho reads

    rng = np.random.default_rng(7)
    theta = rng.multivariate_normal(np.asarray(ext.to_vector()), cov, DRAWS)
    intr = rng.multivariate_normal(np.zeros(3), cov_c, DRAWS)
    dz = rng.normal(0.0, dem_sigma, DRAWS)

    @jax.jit
    def draw(th, dc, d):
        e = photax.ExteriorOrientation.from_vector(th, ext.convention)
        c = eqx.tree_at(lambda m: (m.focal_length, m.principal_point), cam,
                        (cam.focal_length + dc[0], cam.principal_point + dc[1:]))
        pix = c.image_to_pixel(photax.project(ground.at[:, 2].add(d), e, c))
        shifted = eqx.tree_at(lambda m: m.heights, dem, dem.heights + d)
        g = photax.image_to_ground(c.pixel_to_image(p0), e, c, dem=shifted, tol=1e-6)
        return pix, g[:, :2]

    pix, g = jax.lax.map(lambda a: draw(*a), (jnp.asarray(theta), jnp.asarray(intr), jnp.asarray(dz)))
    mc_p, mc_g = np.asarray(pix).std(axis=0).T, np.asarray(g).std(axis=0).T
    # (the interpolated and the exact image position may disagree on a footprint-edge pixel)
    ok = np.isfinite(u.image_std[0].reshape(-1)) & np.isfinite(exact.image_std[0].reshape(-1))
    assert ok.mean() > 0.5 and np.isfinite(mc_g[:, ok]).all()
    for v in (u, exact):
        lin_p, lin_g = v.image_std.reshape(2, -1), v.ground_std.reshape(2, -1)
        np.testing.assert_allclose(lin_p[:, ok], mc_p[:, ok], rtol=0.1)
        np.testing.assert_allclose(lin_g[:, ok], mc_g[:, ok], rtol=0.1)
    # The ellipse's semi-major axis against the Monte Carlo's largest principal std.
    gc = np.asarray(g)[:, ok] - np.asarray(g)[:, ok].mean(axis=0)
    mc_major = np.sqrt(np.linalg.eigvalsh(np.einsum("dni,dnj->nij", gc, gc) / DRAWS)[:, 1])
    np.testing.assert_allclose(u.ground_ellipse[0].reshape(-1)[ok], mc_major, rtol=0.1)
    # Off the image (by more than a pixel) or off the DEM: NaN like the ortho's nodata.
    w, h = s.camera.image_size
    c, r = np.asarray(p0).T
    off = ~np.isfinite(np.asarray(z0)) | (c < -1.5) | (c > w + 0.5) | (r < -1.5) | (r > h + 0.5)
    assert off.sum() > 10 and np.isnan(exact.ground_sigma.reshape(-1)[off]).all()


def test_results_stand_for_exterior_and_covariance(setup):
    s, grid, cov, _ = setup
    ref = ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, coarsen=6)
    resection = types.SimpleNamespace(exterior=s.exterior, covariance=cov)  # the fields photax.resect returns
    np.testing.assert_array_equal(ortho_uncertainty(resection, None, s.camera, s.dem, grid, coarsen=6).ground_cov,
                                  ref.ground_cov)
    eo = s.exterior
    bundle = types.SimpleNamespace(
        exterior=photax.ExteriorOrientation(jnp.stack([eo.position] * 2), jnp.stack([eo.angles] * 2), eo.convention),
        exterior_std=np.sqrt(np.stack([np.diag(cov)] * 2)))
    diag = ortho_uncertainty(s.exterior, np.diag(np.diag(cov)), s.camera, s.dem, grid, coarsen=6)
    np.testing.assert_allclose(ortho_uncertainty(bundle, None, s.camera, s.dem, grid, coarsen=6, image=1)
                               .ground_cov, diag.ground_cov, rtol=1e-12)
    with pytest.raises(ValueError, match="covariance"):
        ortho_uncertainty(s.exterior, np.eye(5), s.camera, s.dem, grid)
    with pytest.raises(ValueError, match="covariance"):
        ortho_uncertainty(s.exterior, -np.eye(6), s.camera, s.dem, grid)
    with pytest.raises(ValueError, match="coarsen"):
        ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, coarsen=0)
    with pytest.raises(ValueError, match="dem_sigma"):
        ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, dem_sigma=np.ones(3))
