"""Linearisation (jitted; sizes are static, so same-shaped problems share a
compile): projection with closed-form Jacobians, the robust losses through
Ceres' corrector (:mod:`photax.bundle._robust`), the normal-equation blocks."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ._robust import _LOSS_CODE as _LOSS_CODE, _corrector, _rho
from ._structure import _State, _Structure


def _project_obs(state: _State, s: _Structure, jacobians: bool = False):
    """Image-plane projection of every observation's point, and optionally
    the closed-form Jacobians ``(k, 2, 6 + a)`` w.r.t. the camera-side
    unknowns ``(dr, dC, d_intr_active)`` and ``(k, 2, 3)`` w.r.t. the point.

    With ``q = R^T (X - C)`` (camera frame) and ``R <- R Exp(dr)``::

        dq/ddr = [q]_x,   dq/dC = -R^T,   dq/dX = R^T
        u = -q_xy / q_z,  du/dq = -1/q_z [I_2 | u]

    then the Brown–Conrady distortion (:mod:`photax.camera`) and
    ``x = x0 + f d(u)``, differentiated by hand (no autodiff through
    Rodrigues: 3-5x faster on CPU)."""
    rot = state.rot[s.obs_image]
    k = state.intr[s.image_camera[s.obs_image]]
    q = jnp.einsum("kji,kj->ki", rot, state.xyz[s.obs_point] - state.centre[s.obs_image])
    x, y = -q[:, 0] / q[:, 2], -q[:, 1] / q[:, 2]
    f, k1, k2, k3, p1, p2 = k[:, 0], k[:, 3], k[:, 4], k[:, 5], k[:, 6], k[:, 7]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    proj = k[:, 1:3] + f[:, None] * jnp.stack([xd, yd], axis=1)
    if not jacobians:
        return proj
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    dxx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    dxy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y  # = d yd / dx
    dyy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    g = -f / q[:, 2]
    # d image / d q: f Dd du/dq, rows x and y.
    jq = jnp.stack(
        [jnp.stack([dxx, dxy, dxx * x + dxy * y], axis=1), jnp.stack([dxy, dyy, dxy * x + dyy * y], axis=1)], axis=1
    ) * g[:, None, None]
    qx = jnp.stack([jnp.cross(q, e[None, :]) for e in jnp.eye(3)], axis=-1)  # [q]_x: column i is q x e_i
    j_rot = jnp.einsum("kri,kij->krj", jq, qx)
    jp = jnp.einsum("kri,kji->krj", jq, rot)  # jq R^T
    one, zero = jnp.ones_like(x), jnp.zeros_like(x)
    r4 = r2 * r2
    j_intr = jnp.stack(
        [
            jnp.stack([xd, one, zero, f * x * r2, f * x * r4, f * x * r4 * r2, 2.0 * f * x * y, f * (r2 + 2.0 * x * x)], 1),
            jnp.stack([yd, zero, one, f * y * r2, f * y * r4, f * y * r4 * r2, f * (r2 + 2.0 * y * y), 2.0 * f * x * y], 1),
        ],
        axis=1,
    )  # fmt: skip
    jc = jnp.concatenate([j_rot, -jp, j_intr[:, :, s.active]], axis=2)
    return proj, jc, jp


def _residuals(state: _State, s: _Structure) -> Array:
    """``(k, 2)`` weighted residuals ``(projected - observed) / sigma``."""
    return (_project_obs(state, s) - s.obs_xy) / s.obs_sigma


def _prior_residuals(state: _State, s: _Structure) -> Array:
    return (state.xyz - s.prior_xyz) * jnp.sqrt(s.prior_w)


@jax.jit
def _cost(state: _State, s: _Structure, loss: Array, scale: Array) -> Array:
    r = _residuals(state, s)
    rho, _, _ = _rho(jnp.sum(r * r, axis=1), loss, scale)
    return 0.5 * jnp.sum(rho) + 0.5 * jnp.sum(_prior_residuals(state, s) ** 2)


def _outer_sum(a: Array, b: Array) -> Array:
    """``(n, p, q)`` batched ``a @ b^T`` for ``a (n, p, L)``, ``b (n, q, L)``
    with small ``L``, written as ``L`` fused outer products: XLA on CPU runs
    this faster than a batched dot of tiny matrices."""
    return sum(a[:, :, None, l] * b[:, None, :, l] for l in range(a.shape[2]))



class _Lin(NamedTuple):
    cost: Array
    r: Array  # (k, 2) residuals (projected - observed) / sigma, not robustified
    weight: Array  # (k,) rho'(|r|^2) (1 without a robust loss)
    wt: Array  # (k, 3, w) W^T per observation: Jp^T Jc
    u_img: Array  # (n_img, w, w) sum of Jc^T Jc per image
    v: Array  # (n_pts, 3, 3)
    g_img: Array  # (n_img, w)
    g_c: Array  # (N,)
    g_p: Array  # (n_pts, 3)
    d_c: Array  # (N,) diag(J^T J), clamped
    d_p: Array  # (n_pts, 3)
    gmax: Array  # max |g|


@functools.partial(jax.jit, static_argnames=("n_c",))
def _linearise(state: _State, s: _Structure, loss: Array, scale: Array, n_c: int) -> _Lin:
    n_img, n_pts = state.centre.shape[0], state.xyz.shape[0]
    w = 6 + s.active.shape[0]
    proj, jc, jp = _project_obs(state, s, jacobians=True)
    r0 = (proj - s.obs_xy) / s.obs_sigma
    rho, weight, rho2 = _rho(jnp.sum(r0 * r0, axis=1), loss, scale)
    rp = _prior_residuals(state, s)
    cost = 0.5 * jnp.sum(rho) + 0.5 * jnp.sum(rp * rp)
    sqrt_rho1, alpha_sq = _corrector(r0, weight, rho2)
    # Corrected Jacobian sqrt(rho') (I - alpha r r^T / s) J / sigma (see
    # _corrector); the gradient rho' J^T r / sigma is formed from J itself,
    # which equals J~^T r~ without dividing by 1 - alpha.
    rg = r0 * weight[:, None]

    def correct(j, mask):
        j = j / s.obs_sigma[:, :, None] * mask[:, None, :]
        g = jnp.einsum("kri,kr->ki", j, rg)
        j = j - (alpha_sq[:, None] * r0)[:, :, None] * jnp.einsum("kr,krj->kj", r0, j)[:, None, :]
        return j * sqrt_rho1[:, None, None], g

    jc, g_obs_c = correct(jc, s.mask_c[s.image_ext[s.obs_image]])
    jp, g_obs_p = correct(jp, s.mask_p[s.obs_point])
    seg = functools.partial(jax.ops.segment_sum, num_segments=n_img)
    segp = functools.partial(jax.ops.segment_sum, num_segments=n_pts)
    jct, jpt = jnp.swapaxes(jc, 1, 2), jnp.swapaxes(jp, 1, 2)
    # U_i = sum Jc^T Jc over the image's observations: GEMMs over chunks of them.
    jcc = jnp.take(jc, s.image_chunk, axis=0, mode="fill", fill_value=0.0).reshape(s.image_chunk.shape[0], -1, w)
    u_img = jax.ops.segment_sum(jax.lax.dot_general(jcc, jcc, (((1,), (1,)), ((0,), (0,)))), s.image_of_chunk,
                                num_segments=n_img, indices_are_sorted=True)  # fmt: skip
    g_img = seg(g_obs_c, s.obs_image)
    pw = s.prior_w * s.mask_p
    v = segp(_outer_sum(jpt, jpt), s.obs_point) + pw[:, :, None] * jnp.eye(3)[None, :, :]
    g_p = segp(g_obs_p, s.obs_point) + pw * (state.xyz - s.prior_xyz)
    flat = s.image_ext.ravel()
    g_c = jnp.zeros(n_c).at[flat].add(g_img.ravel())
    # LM damping D: the diagonal of the normal matrix J~^T J~ (Ceres).
    d_c = jnp.zeros(n_c).at[flat].add(jnp.diagonal(u_img, axis1=1, axis2=2).ravel())
    d_p = jnp.diagonal(v, axis1=1, axis2=2)
    clamp = functools.partial(jnp.clip, min=1e-6, max=1e32)
    gmax = jnp.maximum(jnp.max(jnp.abs(g_c), initial=0.0), jnp.max(jnp.abs(g_p), initial=0.0))
    return _Lin(cost, r0, weight, _outer_sum(jpt, jct), u_img, v, g_img, g_c, g_p, clamp(d_c), clamp(d_p), gmax)
