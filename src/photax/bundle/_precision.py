"""Precision: cofactor matrices of the adjusted unknowns, mapped to angles
by :func:`photax.bundle._structure._angle_jacobian`."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._linearise import _Lin, _wt_of
from ._schur import _band_shape, _reduced_band, _reduced_system, _yt_of
from ._sparse import band_cholesky, band_selected_inverse, band_take, flat_index
from ._structure import _angle_jacobian, _Structure


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
    return (
        q_c[ext[:, :, None], ext[:, None, :]],
        jnp.diagonal(q_c)[6 * ext.shape[0] :],
        q_p,
        jnp.all(jnp.isfinite(chol[0])),
    )


@functools.partial(jax.jit, static_argnames=("n_c",))
def _covariances_band(lin: _Lin, s: _Structure, n_c: int):
    """:func:`_covariances` for blocks of any size: the blocks of the
    reduced-camera inverse on its pattern by selected inversion of the
    banded factor (:func:`._sparse.band_selected_inverse`), and the point
    blocks from them by the same Schur relation, summed over observation
    pairs in the pieces of the Schur assembly (memory bounded whatever the
    block's size).  Returns each image's block
    ``(n_img, w, w)`` (its unknowns in ``image_ext`` order), the intrinsics'
    diagonal ``(a n_cam,)``, the point blocks and whether the factor is
    finite."""
    shape = _band_shape(s)
    m, _, vinv = _reduced_band(lin, s, jnp.zeros(()), n_c, 1.0 - s.mask_c)
    f = band_cholesky(m)
    ok = jnp.all(jnp.isfinite(f.d)) & jnp.all(jnp.isfinite(f.e))
    z = band_selected_inverse(f)
    mask = s.mask_c

    def q(r, c):  # entries (r, c) of the reduced-camera cofactor matrix, fixed unknowns 0
        return band_take(z, flat_index(s.band_chunk, s.band_offset, r, c, *shape, lower=False)) * mask[r] * mask[c]

    ext = s.image_ext
    q_img = q(ext[:, :, None], ext[:, None, :])
    cam = jnp.arange(6 * ext.shape[0], n_c)
    q_cam = q(cam, cam)
    n_pts = lin.v.shape[0]
    # Pairs (a, a) -- each observation with itself, weight 1/2 as the sum adds
    # each term and its transpose -- and (a, b), a < b, weight 1: those of the
    # Schur assembly's chunks (padding: index k, gathered as zeros), a piece
    # at a time, Y^T = V^-1 W^T formed per piece (nothing per observation stored).
    take = functools.partial(jnp.take, axis=0, mode="fill", fill_value=0)
    n_pieces, piece, _ = s.chunk_a.shape
    weights = jnp.where(s.key_off[s.chunk_key] > 0, 1.0, 0.5).reshape(n_pieces, piece)

    def add_pairs(acc, x):
        a, b, wgt = x
        a, b = a.ravel(), b.ravel()
        pt = jnp.take(s.obs_point, a, mode="fill", fill_value=n_pts)  # padding: dropped by the scatter
        yta = _yt_of(take(vinv, pt), _wt_of(take(lin.jc, a), take(lin.jp, a)))  # (m, 3, w)
        ytb = _yt_of(take(vinv, pt), _wt_of(take(lin.jc, b), take(lin.jp, b)))  # same point
        ea, eb = ext[take(s.obs_image, a)], ext[take(s.obs_image, b)]
        qo = (
            jnp.einsum("pai,pij,pbj->pab", yta, q(ea[:, :, None], eb[:, None, :]), ytb)
            * jnp.repeat(wgt, a.shape[0] // piece)[:, None, None]
        )
        return acc.at[pt].add(qo + jnp.swapaxes(qo, 1, 2), mode="drop"), None  # in place

    q_p, _ = jax.lax.scan(add_pairs, vinv, (s.chunk_a, s.chunk_b, weights))
    q_p = q_p * (s.mask_p[:, :, None] * s.mask_p[:, None, :])
    return q_img, q_cam, q_p, ok


def _standard_deviations(
    q_img, q_cam, q_p, var0: float, rot: Array, convention: str, active: Array, n_cameras: int, n_intr: int = 8
):
    """Standard deviations from the cofactors of :func:`_covariances` (each
    image's block ``q_img``, the intrinsics' diagonal ``q_cam``, the point
    blocks ``q_p``) and the variance of unit weight ``var0``: exterior
    ``(n_img, 6)`` (``X, Y, Z``, then the convention's angles, radians),
    intrinsics ``(n_cam, n_intr)`` (0 where fixed), points ``(n_pts, 3)``, and the
    point covariances ``(n_pts, 3, 3)``."""
    q_p = np.asarray(q_p)
    blocks = np.asarray(q_img)[:, :6, :6]
    # Reorder to (centre, rotation) and map rotation increments to angles.
    cen = blocks[:, 3:, 3:]
    jac = np.asarray(_angle_jacobian(rot, convention))
    ang = np.einsum("nij,njk,nlk->nil", jac, blocks[:, :3, :3], jac)
    eo_std = np.sqrt(var0 * np.concatenate([np.diagonal(cen, 0, 1, 2), np.diagonal(ang, 0, 1, 2)], axis=1))
    a = np.asarray(active)
    cam_std = np.zeros((n_cameras, n_intr))
    dq = np.asarray(q_cam).reshape(n_cameras, len(a))
    cam_std[:, a] = np.sqrt(var0 * np.maximum(dq, 0.0))
    pt_cov = var0 * q_p
    pt_std = np.sqrt(np.maximum(np.diagonal(pt_cov, 0, 1, 2), 0.0))
    return eo_std, cam_std, pt_std, pt_cov


def _orientation_covariances(
    q_img, var0: float, rot: Array, convention: str, active: Array, n_intr: int = 8
) -> np.ndarray:
    """``(n_img, 6 + n_intr, 6 + n_intr)`` covariance of each image's ``(X, Y, Z, a1, a2, a3,
    f, x0, y0, k1, k2, k3, p1, p2)`` (centre, the convention's angles in
    radians, the intrinsics of its camera, :data:`INTRINSICS` for
    ``"brown"``; rows and columns of fixed
    intrinsics 0) from its cofactor block ``q_img`` ``(n_img, w, w)`` (order
    rotation increment, centre, active intrinsics), as ``var0 T Q T^T`` with
    ``T`` the map to that order (angles through :func:`_angle_jacobian`)."""
    q = np.asarray(q_img)
    n, w = q.shape[:2]
    a = np.asarray(active)
    t = np.zeros((n, 6 + n_intr, w))
    t[:, 0:3, 3:6] = np.eye(3)
    t[:, 3:6, 0:3] = np.asarray(_angle_jacobian(rot, convention))
    t[:, 6 + a, 6 + np.arange(len(a))] = 1.0
    return var0 * np.einsum("nij,njk,nlk->nil", t, q, t)
