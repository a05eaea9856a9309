"""The banded (sparse block-tridiagonal) reduced camera system of large
blocks (photax.bundle._sparse): layout, solve, selected inversion and the
precision it gives, against numpy's dense solve and inverse of the same
Schur complement, and the adjustment against the dense path."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photax
from photax.bundle._linearise import _linearise
from photax.bundle._schur import _band_shape, _reduced_band, _reduced_system, _solve_band, _solve_cg
from photax.bundle._solver import _start_state
from photax.bundle._sparse import band_cholesky, band_selected_inverse, choose_solver, flat_index
from photax.io.bal import BALData, bal_problem, photax_to_bal
from photax.scene import synthetic_block


def _bal_like(strips=3, per_strip=6):
    """A block where every image is its own BAL camera (f, k1, k2 free): no border."""
    b = photax.scene.block_scene(1, strips=strips, images_per_strip=per_strip, n_tie=60 * strips * per_strip,
                                 n_control=0, n_check=0, forward_overlap=0.7, side_overlap=0.4)  # fmt: skip
    origin = np.round(b.start_points.mean(axis=0))
    eo = b.start_exterior
    cams = photax_to_bal([b.camera] * len(b.image_names), np.asarray(eo.rotation), np.asarray(eo.position) - origin)
    return bal_problem(BALData(cams, b.start_points - origin, b.obs_image, b.obs_point, np.asarray(b.obs_xy)))


def _shared_camera():
    """One camera for all images with free intrinsics: a border of shared unknowns."""
    problem, _ = synthetic_block(0, strips=3, images_per_strip=5, n_tie=300)
    return problem.replace(free_intrinsics=("f", "x0", "y0", "k1"))


@functools.cache
def _system(name):
    """The problem's linearisation at its start and the damped dense reduced
    system (the reference), built once per session and name."""
    problem = _bal_like() if name == "bal_like" else _shared_camera()
    gauge = "fix_first_camera" if name == "bal_like" else None
    s, n_c, _, origin = problem.analyse(gauge)
    lin = _linearise(_start_state(problem, origin), s, jnp.asarray(0), jnp.asarray(1.0), n_c=n_c)
    lam = jnp.asarray(1e-3)
    S, rhs, _ = jax.jit(_reduced_system, static_argnames="n_c")(lin, s, lam, n_c)
    damp = lam * lin.d_c * s.mask_c + (1.0 - s.mask_c)
    return name, s, n_c, lin, lam, np.asarray(S) + np.diag(np.asarray(damp)), np.asarray(rhs), damp


@pytest.fixture(scope="module", params=["bal_like", "shared_camera"])
def system(request):
    return _system(request.param)


def test_layout_is_block_tridiagonal(system):
    """Every pair of images that share points lies in one chunk or two adjacent ones, and
    each unknown has exactly one place (a slot of a chunk or the border)."""
    name, s, n_c, *_ = system
    n_chunks, cw, n_b = _band_shape(s)
    assert n_chunks >= 2  # the test blocks are long enough to be banded
    assert (n_b > 0) == (name == "shared_camera")
    chunk = np.asarray(s.band_chunk)
    ext = np.asarray(s.image_ext)
    for a, b in zip(np.asarray(s.key_a), np.asarray(s.key_b)):
        ca, cb = chunk[ext[a]], chunk[ext[b]]
        ca, cb = ca[ca >= 0], cb[cb >= 0]
        assert np.abs(ca[:, None] - cb[None, :]).max(initial=0) <= 1
    perm = np.asarray(s.band_perm)
    slots = np.concatenate([perm[perm < n_c], np.asarray(s.band_border)])
    assert np.array_equal(np.sort(slots), np.arange(n_c))


def test_band_solve_matches_dense(system):
    """The banded Cholesky solve of the damped reduced system equals numpy's dense solve."""
    _, s, n_c, lin, lam, S, rhs, _ = system
    x, _ = jax.jit(_solve_band, static_argnames="n_c")(lin, s, lam, n_c)
    ref = np.linalg.solve(S, rhs)
    np.testing.assert_allclose(np.asarray(x), ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def test_schur_jacobi_cg_matches_dense():
    """CG with the Schur-Jacobi preconditioner (private blocks, border diagonal) converges to the dense solve.
    One block (one compile): the one with a border exercises both parts of the preconditioner."""
    _, s, n_c, lin, lam, S, rhs, _ = _system("shared_camera")
    x, _ = jax.jit(_solve_cg, static_argnames="n_c")(lin, s, lam, n_c)
    ref = np.linalg.solve(S, rhs)
    np.testing.assert_allclose(np.asarray(x), ref, rtol=0, atol=1e-5 * np.abs(ref).max())


def test_selected_inverse_matches_dense_inverse(system):
    """Takahashi's recurrences on the banded factor give the blocks of S^-1 on
    the pattern (every pair of images that share points, the border) as numpy's
    inverse of the dense matrix does."""
    _, s, n_c, lin, lam, S, _, damp = system

    @jax.jit
    def blocks(lin, s, lam, damp):
        m, _, _ = _reduced_band(lin, s, lam, n_c, damp)
        z = band_selected_inverse(band_cholesky(m))
        zflat = jnp.concatenate([z.d.ravel(), z.b.ravel(), z.c.ravel(), z.e.ravel()])
        ext = s.image_ext
        ra, cb = ext[s.key_a][:, :, None], ext[s.key_b][:, None, :]
        idx = flat_index(s.band_chunk, s.band_offset, ra, cb, *_band_shape(s), lower=False)
        return zflat[idx], ra, cb

    z, ra, cb = blocks(lin, s, lam, damp)
    ref = np.linalg.inv(S)[np.asarray(ra), np.asarray(cb)]
    np.testing.assert_allclose(np.asarray(z), ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def test_adjustment_and_precision_banded_vs_dense():
    """A whole adjustment on the banded path, its precision by selected
    inversion, and the dense path's (dense inverse) agree."""
    problem = _shared_camera()
    dense = photax.bundle_adjust(problem, linear_solver="dense")
    band = photax.bundle_adjust(problem, linear_solver="band")
    assert band.iterations == dense.iterations
    assert band.cost == pytest.approx(dense.cost, rel=1e-10)
    for field in ("exterior_std", "camera_std", "point_std", "point_cov"):
        a, b = getattr(dense, field), getattr(band, field)
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-7 * np.abs(a).max(), err_msg=field)


def test_solver_choice_by_cost():
    """Dense where the band would not pay (few, all-overlapping images), banded
    for a long block, CG only when the band would not fit in memory."""
    assert choose_solver((1, 441), 0, 441) == "dense"  # problem-49-7776: one chunk
    assert choose_solver((3, 300), 0, 900) == "dense"  # band flops above the dense ones
    assert choose_solver((28, 297), 0, 8100) == "band"  # the 30 x 30 BAL block
    assert choose_solver((97, 927), 0, 90000) == "band"  # 100 x 100
    assert choose_solver((300, 2700), 0, 810000) == "cg"  # 300 x 300: tens of GB


def test_band_path_is_pure_jax(system):
    """The banded solve is XLA operations only (no host callback): it runs on a GPU unchanged."""
    _, s, n_c, lin, lam, *_ = system
    jaxpr = str(jax.make_jaxpr(lambda lin, s, lam: _solve_band(lin, s, lam, n_c))(lin, s, lam))
    assert "callback" not in jaxpr and "cholesky" in jaxpr and "scan" in jaxpr


def test_block_visibility_matches_projecting_every_point_into_every_image():
    """The generator's vectorised visibility (only the images within reach of
    each point are projected) finds exactly the observations of projecting
    every point into every image with :func:`photax.collinearity.project`."""
    from photax.collinearity import ExteriorOrientation, project
    from photax.scene._block import _visible

    rng = np.random.default_rng(3)
    cam = photax.FrameCamera.from_pixels(3000.0, (4000, 3000))
    col_x, row_y = 240.0 * np.arange(4), 360.0 * np.arange(3)
    n = 3000
    xyz = np.column_stack([rng.uniform(-600, 1300, n), rng.uniform(-500, 1200, n), rng.uniform(0, 150, n)])
    pos = np.array([[x, y, 675.0] for y in row_y for x in col_x])
    eo = ExteriorOrientation(pos, rng.uniform(-0.035, 0.035, (len(pos), 3)), "omega-phi-kappa")
    reach = 750.0 * (0.5 * np.hypot(4000, 3000) / 3000.0 + np.tan(np.radians(2.0)) + 0.1)
    obs_i, obs_p, obs_xy = _visible(xyz, 1000, n, col_x, row_y, reach, eo, cam, 1920.0, 1440.0)  # all points
    ref_i, ref_p, ref_xy = [], [], []
    for i in range(len(pos)):
        xy = np.asarray(project(xyz, ExteriorOrientation(pos[i], eo.angles[i], "omega-phi-kappa"), cam))
        inside = np.flatnonzero((np.abs(xy[:, 0]) < 1920.0) & (np.abs(xy[:, 1]) < 1440.0))
        ref_i.append(np.full(len(inside), i)), ref_p.append(inside), ref_xy.append(xy[inside])
    assert len(obs_i) > 1.5 * n
    np.testing.assert_array_equal(obs_i, np.concatenate(ref_i))
    np.testing.assert_array_equal(obs_p, np.concatenate(ref_p))
    np.testing.assert_allclose(obs_xy, np.concatenate(ref_xy), rtol=0, atol=1e-9)


def test_chunked_linearisation_matches_whole():
    """Large problems are linearised in chunks of observations (the last one
    overlapping the one before): the same normal-equation blocks as the
    whole-problem form, with a Huber loss so the corrector is exercised."""
    from photax.bundle._linearise import _linearise_chunked

    _, s, n_c, _, _, _, _, _ = _system("shared_camera")
    problem = _shared_camera()
    state = _start_state(problem, problem.analyse(None)[3])
    loss, scale = jnp.asarray(1), jnp.asarray(1.0)
    whole = _linearise(state, s, loss, scale, n_c=n_c)
    k = s.obs_image.shape[0]
    chunked = jax.jit(_linearise_chunked, static_argnums=(4, 5))(state, s, loss, scale, n_c, k // 3 + 7)
    for name, a, b in zip(whole._fields, whole, chunked):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(a))), err_msg=name)


def test_streamed_schur_blocks_match_stored():
    """Large problems form ``Y^T`` piece by piece and add each piece's
    products as they come: the same blocks of ``S`` as forming it whole."""
    from photax.bundle._schur import _schur_blocks

    _, s, n_c, lin, lam, _, _, _ = _system("shared_camera")
    f = jax.jit(_schur_blocks, static_argnames=("n_c", "stream"))
    stored, streamed = f(lin, s, lam, n_c, stream=False), f(lin, s, lam, n_c, stream=True)
    for a, b in zip(stored, streamed):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(a))))
