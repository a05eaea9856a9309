"""One damped Schur step of the bundle solver from a problem's start values, and
the solver's update applied to a correction vector: what the tests that compare a
step with the dense normal equations (GNSS, attitude, DEM rows) share."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import photax as ptx
from photax.bundle._linearise import _linearise
from photax.bundle._schur import _trial
from photax.bundle._structure import _analyse, _State

LAMBDA = 1e-3


def one_step(problem, solver: str):
    """``(s, n_c, origin, state, lin, new)``: the problem's structure, its
    camera-parameter count, the local origin, the start state, its
    linearisation and the state after one step with damping :data:`LAMBDA`."""
    origin = np.round(problem.points.mean(0))
    s, n_c, _ = _analyse(problem, np.zeros((problem.n_images, 6), bool), origin)
    intr = np.stack([np.r_[float(c.focal_length), np.asarray(c.principal_point), np.asarray(c.distortion)]
                     for c in problem.cameras])  # fmt: skip
    state = _State(
        jnp.asarray(problem.exterior.rotation), jnp.asarray(problem.exterior.position) - origin[None, :],
        jnp.asarray(intr), jnp.asarray(problem.points - origin[None, :]),
    )  # fmt: skip
    none, one = jnp.asarray(0), jnp.asarray(1.0)
    lin = _linearise(state, s, none, one, n_c)
    new, *_ = _trial(state, lin, s, jnp.asarray(LAMBDA), none, one, n_c, solver=solver)
    return s, n_c, origin, state, lin, new


def apply(state, x, n_img: int, n_c: int):
    """The solver's update of ``state`` by ``x`` (no intrinsics): R <- R Exp(dr),
    C <- C + R_new R^T dC (see test_bundle.test_schur_step_equals_dense_normal_equations)."""
    dimg = x[: 6 * n_img].reshape(n_img, 6)
    rot = state.rot @ ptx.axis_angle_to_matrix(dimg[:, :3])
    centre = state.centre + jnp.einsum("nij,nkj,nk->ni", rot, state.rot, dimg[:, 3:])
    return _State(rot, centre, state.intr, state.xyz + x[n_c:].reshape(-1, 3))
