"""Per-pixel geolocation uncertainty (photax.uncertainty) against a Monte
Carlo propagation on a rendered scene: the same error sources drawn 800
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

DRAWS = 800  # Monte Carlo std to ~2.5 % (1 / sqrt(2 DRAWS)), against the 10 % asked
COARSEN = 6  # 17 x 21 pixels of the 102 x 124 ortho grid: every draw at every pixel in one vectorised call


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


def _monte_carlo(s, xy, cov, cov_c, dem_sigma, seed=7):
    """Std ``(2, n)`` of the image position and of the ground position that
    the ortho pixels at ground ``xy`` ``(n, 2)`` show, over DRAWS draws of
    the exterior, intrinsics (f, x0, y0) and a DEM height offset: the image
    position by the collinearity model, the ground position by monoplotting
    (photax.image_to_ground) the pixel the ortho reads onto the shifted DEM;
    all draws in one vmapped call.  Also the pixel the ortho reads, and the
    samples ``(DRAWS, n, 2)`` of the ground position."""
    ext, cam, dem = s.exterior, s.camera, s.dem
    z0 = dem.height(jnp.asarray(xy[:, 0]), jnp.asarray(xy[:, 1]))
    ground = jnp.concatenate([jnp.asarray(xy), z0[:, None]], axis=-1)
    p0 = cam.image_to_pixel(photax.project(ground, ext, cam))  # what the ortho reads
    rng = np.random.default_rng(seed)
    theta = rng.multivariate_normal(np.asarray(ext.to_vector()), cov, DRAWS)
    intr = rng.multivariate_normal(np.zeros(3), cov_c, DRAWS)
    dz = rng.normal(0.0, dem_sigma, DRAWS)

    def draw(th, dc, d):
        e = photax.ExteriorOrientation.from_vector(th, ext.convention)
        c = eqx.tree_at(
            lambda m: (m.focal_length, m.principal_point), cam, (cam.focal_length + dc[0], cam.principal_point + dc[1:])
        )
        pix = c.image_to_pixel(photax.project(ground.at[:, 2].add(d), e, c))
        shifted = eqx.tree_at(lambda m: m.heights, dem, dem.heights + d)
        g = photax.image_to_ground(c.pixel_to_image(p0), e, c, dem=shifted, tol=1e-6)
        return pix, g[:, :2]

    pix, g = jax.jit(jax.vmap(draw))(jnp.asarray(theta), jnp.asarray(intr), jnp.asarray(dz))
    pix, g = np.asarray(pix), np.asarray(g)
    return pix.std(axis=0).T, g.std(axis=0).T, np.asarray(p0), np.asarray(z0), g


def test_first_order_matches_monte_carlo(setup):
    s, grid, cov, cov_c = setup
    dem_sigma = 1.5
    # Exact on a lattice every 2 (coarse) pixels, interpolated (error < 2 (s / H)^2 = 2 %); and at every pixel.
    u = ortho_uncertainty(
        s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c, dem_sigma=dem_sigma, coarsen=COARSEN, step=2
    )
    exact = ortho_uncertainty(
        s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c, dem_sigma=dem_sigma, coarsen=COARSEN, step=1
    )
    assert u.grid.transform.a == COARSEN * grid.transform.a and u.image_cov.shape == u.grid.shape + (2, 2)
    assert u.image_var.shape == (3, *u.grid.shape)
    mc_p, mc_g, p0, z0, g = _monte_carlo(s, u.grid.xy().reshape(-1, 2), cov, cov_c, dem_sigma)
    # (the interpolated and the exact image position may disagree on a footprint-edge pixel)
    ok = np.isfinite(u.image_std[0].reshape(-1)) & np.isfinite(exact.image_std[0].reshape(-1))
    assert ok.sum() > 150 and np.isfinite(mc_g[:, ok]).all()
    for v in (u, exact):
        lin_p, lin_g = v.image_std.reshape(2, -1), v.ground_std.reshape(2, -1)
        np.testing.assert_allclose(lin_p[:, ok], mc_p[:, ok], rtol=0.1)
        np.testing.assert_allclose(lin_g[:, ok], mc_g[:, ok], rtol=0.1)
    # The ellipse's semi-major axis against the Monte Carlo's largest principal std.
    gc = g[:, ok] - g[:, ok].mean(axis=0)
    mc_major = np.sqrt(np.linalg.eigvalsh(np.einsum("dni,dnj->nij", gc, gc) / DRAWS)[:, 1])
    np.testing.assert_allclose(u.ground_ellipse[0].reshape(-1)[ok], mc_major, rtol=0.1)
    # Off the image (by more than a pixel) or off the DEM: NaN like the ortho's nodata.
    w, h = s.camera.image_size
    c, r = p0.T
    off = ~np.isfinite(z0) | (c < -1.5) | (c > w + 0.5) | (r < -1.5) | (r > h + 0.5)
    assert off.sum() > 10 and np.isnan(exact.ground_sigma.reshape(-1)[off]).all()


def test_lattice_interpolation_error_bound(setup):
    """The documented bound of the lattice interpolation: relative error of
    every std below 2 (s / H)^2 (s the lattice spacing on the ground, H the
    flying height above the mean terrain), against the propagation at every
    pixel, for two spacings (the error grows with s^2: 4x for twice s)."""
    s, grid, cov, cov_c = setup
    exact = ortho_uncertainty(
        s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c, dem_sigma=1.5, coarsen=COARSEN, step=1
    )
    height = float(s.exterior.position[2]) - float(np.nanmean(np.asarray(s.dem.heights)))
    errors = []
    for step in (2, 4):
        u = ortho_uncertainty(
            s.exterior, cov, s.camera, s.dem, grid, camera_covariance=cov_c, dem_sigma=1.5, coarsen=COARSEN, step=step
        )
        ok = np.isfinite(u.ground_sigma) & np.isfinite(exact.ground_sigma)
        err = max(
            np.abs(v / e - 1)[:, ok].max()
            for v, e in ((u.image_std, exact.image_std), (u.ground_std, exact.ground_std))
        )
        bound = 2 * (step * u.grid.transform.a / height) ** 2
        assert 0 < err <= bound, (step, err, bound)
        errors.append(err)
    assert errors[1] > 2 * errors[0]  # the bound's order is the error's: not vacuous


def test_results_stand_for_exterior_and_covariance(setup):
    s, grid, cov, _ = setup
    ref = ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, coarsen=6)
    resection = types.SimpleNamespace(exterior=s.exterior, covariance=cov)  # the fields photax.resect returns
    np.testing.assert_array_equal(
        ortho_uncertainty(resection, None, s.camera, s.dem, grid, coarsen=6).ground_cov, ref.ground_cov
    )
    eo = s.exterior
    bundle = types.SimpleNamespace(
        exterior=photax.ExteriorOrientation(jnp.stack([eo.position] * 2), jnp.stack([eo.angles] * 2), eo.convention),
        exterior_std=np.sqrt(np.stack([np.diag(cov)] * 2)),
    )
    diag = ortho_uncertainty(s.exterior, np.diag(np.diag(cov)), s.camera, s.dem, grid, coarsen=6)
    np.testing.assert_allclose(
        ortho_uncertainty(bundle, None, s.camera, s.dem, grid, coarsen=6, image=1).ground_cov,
        diag.ground_cov,
        rtol=1e-12,
    )
    with pytest.raises(ValueError, match="covariance"):
        ortho_uncertainty(s.exterior, np.eye(5), s.camera, s.dem, grid)
    with pytest.raises(ValueError, match="covariance"):
        ortho_uncertainty(s.exterior, -np.eye(6), s.camera, s.dem, grid)
    with pytest.raises(ValueError, match="coarsen"):
        ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, coarsen=0)
    with pytest.raises(ValueError, match="dem_sigma"):
        ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, dem_sigma=np.ones(3))


def test_bundle_result_gives_each_image_its_covariance_block():
    """BundleResult.orientation_cov (from the Schur-reduced, selectively
    inverted normal matrix and the rotation-increment -> angle map) against
    the dense inverse of J^T W J built independently by autodiff through
    photax.project in the convention's angles, on the self-calibrating block
    of test_bundle_sparse (same shapes: its compilations are reused); then
    ortho_uncertainty of the result uses that block, correlations included."""
    from rasterio import Affine

    from photax.rectification import Grid
    from photax.scene import synthetic_block

    problem, _ = synthetic_block(0, strips=3, images_per_strip=5, n_tie=300)
    problem = problem.replace(free_intrinsics=("f", "x0", "y0", "k1"))
    res = photax.bundle_adjust(problem, linear_solver="band")
    n_img = problem.n_images
    free = np.asarray(problem.roles) != "control"
    eo, cam = res.exterior, res.cameras[0]
    theta0 = np.concatenate([np.asarray(eo.position), np.asarray(eo.angles)], axis=1)
    intr0 = np.array([float(cam.focal_length), *np.asarray(cam.principal_point), float(cam.distortion[0])])
    xyz0 = np.asarray(res.points)
    oi, op = np.asarray(problem.obs_image), np.asarray(problem.obs_point)
    sig = np.asarray(problem.obs_sigma) * np.ones((len(oi), 2))
    assert np.all(np.asarray(problem.image_camera) == 0)

    def residuals(x):
        theta = x[: 6 * n_img].reshape(n_img, 6)
        intr = x[6 * n_img : 6 * n_img + 4]
        pts = jnp.asarray(xyz0).at[np.flatnonzero(free)].set(x[6 * n_img + 4 :].reshape(-1, 3))
        c = eqx.tree_at(
            lambda m: (m.focal_length, m.principal_point, m.distortion),
            cam,
            (intr[0], intr[1:3], cam.distortion.at[0].set(intr[3])),
        )

        def one(t, p):
            return photax.project(p[None], photax.ExteriorOrientation.from_vector(t, eo.convention), c)[0]

        return (jax.vmap(one)(theta[oi], pts[op]) / sig).ravel()

    x0 = jnp.asarray(np.concatenate([theta0.ravel(), intr0, xyz0[free].ravel()]))
    jac = np.asarray(jax.jacfwd(residuals)(x0))
    q = np.linalg.inv(jac.T @ jac) * res.sigma0**2
    for i in (0, 7, n_img - 1):
        idx = np.r_[6 * i : 6 * i + 6, 6 * n_img : 6 * n_img + 4]
        ref = q[np.ix_(idx, idx)]
        got = res.orientation_cov[i][np.ix_(np.r_[0:6, 6:10], np.r_[0:6, 6:10])]
        d = np.sqrt(np.diag(ref))  # compared as correlations (metres, radians and pixels mixed)
        np.testing.assert_allclose(got / np.outer(d, d), ref / np.outer(d, d), rtol=0, atol=1e-6)
        assert np.all(res.orientation_cov[i][10:] == 0)  # k2, k3, p1, p2 fixed
    np.testing.assert_allclose(
        np.sqrt(np.diagonal(res.orientation_cov[:, :6, :6], 0, 1, 2)), res.exterior_std, rtol=1e-9
    )
    # ortho_uncertainty of the result = of the image with that (14, 14) block.
    i = 7
    one = photax.ExteriorOrientation(theta0[i, :3], theta0[i, 3:], eo.convention)
    x, y = theta0[i, :2]
    dem = photax.DEM.flat(float(np.mean(xyz0[:, 2])), (x - 1e5, y - 1e5, x + 1e5, y + 1e5))
    grid = ortho_grid(one, cam, dem)
    small = Grid(grid.transform * Affine.scale(grid.shape[1] / 8, grid.shape[0] / 6), (6, 8), grid.crs)
    a = ortho_uncertainty(res, None, cam, dem, small, image=i, step=1)
    b = ortho_uncertainty(one, res.orientation_cov[i], cam, dem, small, step=1)
    diag = ortho_uncertainty(one, np.diag(np.diag(res.orientation_cov[i])), cam, dem, small, step=1)
    np.testing.assert_array_equal(a.ground_var, b.ground_var)
    assert np.isfinite(a.ground_sigma).sum() >= 8  # (the corners of the footprint's box are off the image)
    assert np.nanmax(np.abs(diag.ground_sigma / a.ground_sigma - 1)) > 0.01  # the correlations count


def test_nodata_dem_and_rotated_grid_match_every_pixel(setup):
    """The interpolated path's two other ways of reading the DEM's slope, against the propagation at
    every pixel (step=1, :func:`photax.uncertainty._dem_slope` there): a DEM with a nodata hole (the
    separable read's nodata rule, :meth:`photax.DEM.height`'s) and a grid rotated against the DEM
    (no separable read: the slope at every pixel).  Same no-data pixels (the hole included) and the
    lattice's error bound (within 5 % next to the hole), on the coarse grid of the tests above (same
    shapes: compiled once)."""
    from rasterio import Affine
    from scipy import ndimage

    from photax.rectification import Grid

    s, grid, cov, cov_c = setup
    g = ortho_uncertainty(s.exterior, cov, s.camera, s.dem, grid, coarsen=COARSEN, step=1).grid
    cx, cy = g.transform * (g.shape[1] / 2, g.shape[0] / 2)
    heights = np.array(s.dem.heights)
    c, r = (int(v) for v in s.dem.ground_to_pixel(cx, cy))
    heights[r - 40 : r + 40, c - 40 : c + 40] = np.nan  # a hole of ~5 x 5 coarse pixels in the middle
    holed = photax.DEM(heights, s.dem.transform, s.dem.crs)
    turned = Grid(
        Affine.translation(cx, cy) * Affine.rotation(20) * Affine.translation(-cx, -cy) * g.transform, g.shape, g.crs
    )
    height = float(s.exterior.position[2]) - float(np.nanmean(np.asarray(s.dem.heights)))
    for dem, gr, coarsen in ((holed, grid, COARSEN), (s.dem, turned, 1)):
        kw = dict(camera_covariance=cov_c, dem_sigma=1.5, coarsen=coarsen)
        u = ortho_uncertainty(s.exterior, cov, s.camera, dem, gr, step=2, **kw)
        exact = ortho_uncertainty(s.exterior, cov, s.camera, dem, gr, step=1, **kw)
        nan_u, nan_e = np.isnan(u.ground_sigma), np.isnan(exact.ground_sigma)
        assert np.mean(nan_u != nan_e) < 0.01 and 0.05 < nan_e.mean() < 0.95
        ok = ~nan_u & ~nan_e
        near = np.zeros_like(ok)
        if dem is holed:
            xy = u.grid.xy()
            hole = np.isnan(np.asarray(dem.height(xy[..., 0], xy[..., 1])))
            assert hole.sum() >= 4 and nan_u[hole].all() and nan_e[hole].all()
            # Lattice nodes in the hole take the DEM's mean height: within a cell of it the bound is not
            # the smooth fields' one, but still far inside the 10 % asked.
            near = ndimage.binary_dilation(hole, iterations=2) & ok
            assert near.sum() >= 4
        err = [
            max(
                np.abs(v / e - 1)[:, m].max(initial=0)
                for v, e in ((u.image_std, exact.image_std), (u.ground_std, exact.ground_std))
            )
            for m in (ok & ~near, near)
        ]
        assert err[0] <= 2 * (2 * np.hypot(u.grid.transform.a, u.grid.transform.d) / height) ** 2, err
        assert err[1] < 0.05, err
