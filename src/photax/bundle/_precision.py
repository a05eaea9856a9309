"""Precision: cofactor matrices of the adjusted unknowns and the map from
rotation increments to angles."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..rotation import angles_from_matrix_unchecked, axis_angle_to_matrix
from ._linearise import _Lin
from ._schur import _reduced_system
from ._structure import _Structure


@functools.partial(jax.jit, static_argnames=("n_c",))
def _covariances(lin: _Lin, s: _Structure, n_c: int):
    """Cofactor matrices (inverse normal matrix blocks) at ``lam = 0``:
    the full reduced-camera inverse ``(N, N)`` and the point blocks
    ``(n_pts, 3, 3)`` via ``Q_p = V^-1 + Y^T S^-1 Y`` with ``Y = W V^-1``."""
    S, _, vinv = _reduced_system(lin, s, jnp.zeros(()), n_c)
    S = S + jnp.diag(1.0 - s.mask_c)
    chol = (jax.lax.linalg.cholesky(S, symmetrize_input=False), True)  # S is symmetric by construction
    q_c = jax.scipy.linalg.cho_solve(chol, jnp.eye(n_c)) * (s.mask_c[:, None] * s.mask_c[None, :])
    y = jnp.einsum("kji,kjl->kil", lin.wt, vinv[s.obs_point])
    ext = s.image_ext
    eo = ext[s.obs_image]
    n_pts = lin.v.shape[0]
    qd = jnp.einsum("kia,kij,kjb->kab", y, q_c[eo[:, :, None], eo[:, None, :]], y)
    ea, eb = eo[s.pair_a], eo[s.pair_b]
    qo = jnp.einsum("pia,pij,pjb->pab", y[s.pair_a], q_c[ea[:, :, None], eb[:, None, :]], y[s.pair_b])
    q_p = vinv + jax.ops.segment_sum(qd, s.obs_point, num_segments=n_pts)
    q_p = q_p + jax.ops.segment_sum(qo + jnp.swapaxes(qo, 1, 2), s.obs_point[s.pair_a], num_segments=n_pts)
    q_p = q_p * (s.mask_p[:, :, None] * s.mask_p[:, None, :])
    return q_c, q_p, jnp.all(jnp.isfinite(chol[0]))


@functools.partial(jax.jit, static_argnames=("convention",))
def _angle_jacobian(rot: Array, convention: str) -> Array:
    """``(n, 3, 3)`` d(angles)/d(rotation increment about camera axes)."""

    def angles(dr, r):
        return angles_from_matrix_unchecked(r @ axis_angle_to_matrix(dr), convention)[0]

    return jax.vmap(jax.jacfwd(angles), in_axes=(None, 0))(jnp.zeros(3), rot)


def _standard_deviations(q_c, q_p, var0: float, rot: Array, convention: str, active: Array, n_cameras: int):
    """Standard deviations from the cofactors of :func:`_covariances` and the
    variance of unit weight ``var0``: exterior ``(n_img, 6)`` (``X, Y, Z``,
    then the convention's angles, radians), intrinsics ``(n_cam, 8)`` (0 where
    fixed), points ``(n_pts, 3)``, and the point covariances ``(n_pts, 3, 3)``."""
    q_c, q_p = np.asarray(q_c), np.asarray(q_p)
    n_img = rot.shape[0]
    blocks = np.stack([q_c[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(n_img)])
    # Reorder to (centre, rotation) and map rotation increments to angles.
    cen = blocks[:, 3:, 3:]
    jac = np.asarray(_angle_jacobian(rot, convention))
    ang = np.einsum("nij,njk,nlk->nil", jac, blocks[:, :3, :3], jac)
    eo_std = np.sqrt(var0 * np.concatenate([np.diagonal(cen, 0, 1, 2), np.diagonal(ang, 0, 1, 2)], axis=1))
    a = np.asarray(active)
    cam_std = np.zeros((n_cameras, 8))
    dq = np.diagonal(q_c)[6 * n_img :].reshape(n_cameras, len(a))
    cam_std[:, a] = np.sqrt(var0 * np.maximum(dq, 0.0))
    pt_cov = var0 * q_p
    pt_std = np.sqrt(np.maximum(np.diagonal(pt_cov, 0, 1, 2), 0.0))
    return eo_std, cam_std, pt_std, pt_cov
