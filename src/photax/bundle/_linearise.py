"""Linearisation (jitted; sizes are static, so same-shaped problems share a
compile): projection with closed-form Jacobians, the robust losses through
Ceres' corrector (:mod:`photax.bundle._robust`), the normal-equation blocks."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from ..camera import distort, intrinsics_jacobian
from ..collinearity import collinearity_rows
from ..rotation import matrix_to_axis_angle
from ._robust import _LOSS_CODE as _LOSS_CODE
from ._robust import _corrector, _rho
from ._structure import _State, _Structure


def _project_obs(state: _State, s: _Structure, jacobians: bool = False):
    """Image-plane projection of every observation's point, and optionally
    the closed-form Jacobians ``(k, 2, 6 + a)`` w.r.t. the camera-side
    unknowns ``(dr, dC, d_intr_active)`` and ``(k, 2, 3)`` w.r.t. the point.

    The maths is the package's one implementation, with the orientation and
    camera given per observation: :func:`photax.collinearity.collinearity_rows`
    (:func:`~photax.collinearity.collinearity_jacobian`) and
    :func:`photax.camera.intrinsics_jacobian`.  The rotation is updated on the
    manifold, ``R <- R Exp(dr)``: that is the collinearity Jacobian's angle
    columns for the axes ``w_k = R e_k`` (``axes = R^T``), since
    ``R^T (d x R e_k) = q x e_k = dq/ddr_k`` with ``q = R^T (X - C)``.
    Closed form, not autodiff through Rodrigues: 3-5x faster on CPU."""
    rot = state.rot[s.obs_image]
    k = state.intr[s.image_camera[s.obs_image]]
    xyz, centre = state.xyz[s.obs_point], state.centre[s.obs_image]
    if not jacobians:
        q = jnp.einsum("kji,kj->ki", rot, xyz - centre)
        return k[:, 1:3] + k[:, :1] * distort(-q[:, :2] / q[:, 2:3], k[:, 3:])
    proj, jac, q = collinearity_rows(xyz, centre, rot, None, k[:, 0], k[:, 1:3], k[:, 3:], dots=True)
    j_intr = intrinsics_jacobian(-q[:, :2] / q[:, 2:3], k[:, 0], k[:, 3:])
    jc = jnp.concatenate([jac[:, :, 3:6], jac[:, :, :3], j_intr[:, :, s.active]], axis=2)  # jac: (C, angles, X)
    return proj, jc, jac[:, :, 6:]


def _residuals(state: _State, s: _Structure) -> Array:
    """``(k, 2)`` weighted residuals ``(projected - observed) / sigma``."""
    return (_project_obs(state, s) - s.obs_xy) / s.obs_sigma


def _prior_residuals(state: _State, s: _Structure) -> Array:
    return (state.xyz - s.prior_xyz) * jnp.sqrt(s.prior_w)


def _dem_residuals(state: _State, s: _Structure, jacobians: bool = False):
    """``(n_pts,)`` weighted residuals ``(Z - DEM(X, Y)) / sigma`` of the tie
    points' DEM height observations (0 where a point has none) and, with
    ``jacobians``, their Jacobian ``(n_pts, 3)`` w.r.t. the point,
    ``(-dDEM/dX, -dDEM/dY, 1) / sigma`` (the bilinear slopes, by JAX).  A
    point that leaves the DEM gets a NaN residual: the step that moved it
    there has no finite cost and is rejected."""
    xs, ys = state.xyz[:, 0], state.xyz[:, 1]  # the points without an observation: NaN or not, masked below
    seen = s.dem_w > 0

    def height(x, y):
        return s.dem.height(x, y)

    h, dhdx = jax.jvp(height, (xs, ys), (jnp.ones_like(xs), jnp.zeros_like(ys)))
    r = jnp.where(seen, (state.xyz[:, 2] - h) * s.dem_w, 0.0)
    if not jacobians:
        return r
    _, dhdy = jax.jvp(height, (xs, ys), (jnp.zeros_like(xs), jnp.ones_like(ys)))
    j = jnp.stack([-dhdx, -dhdy, jnp.ones_like(h)], axis=1) * s.dem_w[:, None] * s.mask_p
    return r, jnp.where(seen[:, None], j, 0.0)


def _cross_matrix(v: Array) -> Array:
    """``(n, 3, 3)`` ``[v]x`` (``[v]x u = v x u``) of ``v`` ``(n, 3)``: its columns are ``v x e_k``."""
    return jnp.swapaxes(jnp.cross(v[:, None, :], jnp.eye(3)[None]), 1, 2)


def _camera_prior(state: _State, s: _Structure, jacobians: bool = False):
    """``(n_img, 6)`` weighted residuals of the images' GNSS positions and
    attitudes (0 where an image has none) and, with ``jacobians``, their
    Jacobian ``(n_img, 6, 6)`` w.r.t. the image's ``(dr, dC)`` (masked).

    Position: ``(C + R l - G) / sigma`` with ``l`` the lever arm; with
    ``R <- R Exp(dr)`` and the centre step ``dC`` (world frame to first
    order, see :func:`photax.bundle._schur._trial`) its Jacobian is
    ``-R [l]x`` on ``dr`` and the identity on ``dC``, over sigma.
    Attitude: ``M e`` with ``e = Log(R_obs^T R)`` and ``M`` the structure's
    ``att_map`` (angle differences over their sigmas, to first order); on
    ``dr`` its Jacobian is ``M J_r^-1(e)``, the inverse right Jacobian of
    SO(3): ``I + [e]x / 2 + (1/t^2 - (1 + cos t) / (2 t sin t)) [e]x^2``."""
    arm = jnp.einsum("nij,nj->ni", state.rot, s.lever)
    r_pos = (state.centre + arm - s.gnss_xyz) * s.gnss_w
    e = matrix_to_axis_angle(jnp.swapaxes(s.att_rot, 1, 2) @ state.rot)
    r = jnp.concatenate([r_pos, jnp.einsum("nij,nj->ni", s.att_map, e)], axis=1)
    if not jacobians:
        return r
    t2 = jnp.sum(e * e, axis=1)
    small = t2 < 1e-8
    t = jnp.sqrt(jnp.where(small, 1.0, t2))
    c = jnp.where(small, 1.0 / 12.0 + t2 / 720.0, 1.0 / t**2 - (1.0 + jnp.cos(t)) / (2.0 * t * jnp.sin(t)))
    k = _cross_matrix(e)
    jr_inv = jnp.eye(3)[None] + 0.5 * k + c[:, None, None] * (k @ k)
    w = s.gnss_w[:, :, None]
    top = jnp.concatenate([-(state.rot @ _cross_matrix(s.lever)) * w, w * jnp.eye(3)[None]], axis=2)
    bottom = jnp.concatenate([s.att_map @ jr_inv, jnp.zeros_like(jr_inv)], axis=2)
    mask = s.mask_c[s.image_ext[:, :6]]
    return r, jnp.concatenate([top, bottom], axis=1) * mask[:, None, :]


@jax.jit
def _cost(state: _State, s: _Structure, loss: Array, scale: Array) -> Array:
    r = _residuals(state, s)
    rho, _, _ = _rho(jnp.sum(r * r, axis=1), loss, scale)
    prior = jnp.sum(_prior_residuals(state, s) ** 2) + jnp.sum(_camera_prior(state, s) ** 2)
    return 0.5 * jnp.sum(rho) + 0.5 * prior + 0.5 * jnp.sum(_dem_residuals(state, s) ** 2)


def _outer_sum(a: Array, b: Array) -> Array:
    """``(n, p, q)`` batched ``a @ b^T`` for ``a (n, p, L)``, ``b (n, q, L)``
    with small ``L``, written as ``L`` fused outer products: XLA on CPU runs
    this faster than a batched dot of tiny matrices."""
    return sum(a[:, :, None, i] * b[:, None, :, i] for i in range(a.shape[2]))


class _Lin(NamedTuple):
    cost: Array
    r: Array  # (k, 2) residuals (projected - observed) / sigma, not robustified
    weight: Array  # (k,) rho'(|r|^2) (1 without a robust loss)
    jc: Array  # (k, 2, w) corrected, masked camera-side Jacobian J~c / sigma
    jp: Array  # (k, 2, 3) the same for the point
    u_diag: Array  # (n_img, w) diagonal of U_i = sum Jc^T Jc per image (U itself: _u_of; the Schur
    # products add it into S's diagonal blocks, see photax.bundle._schur._pair_products)
    v: Array  # (n_pts, 3, 3)
    g_img: Array  # (n_img, w)
    g_c: Array  # (N,)
    g_p: Array  # (n_pts, 3)
    d_c: Array  # (N,) diag(J^T J), clamped
    d_p: Array  # (n_pts, 3)
    gmax: Array  # max |g|
    u_cam: Array  # (n_img, 6, 6) J^T J of the GNSS / attitude observations on (dr, dC), added to U's
    # diagonal blocks (photax.bundle._schur._scatter_schur; in g_img, u_diag and cost already)

    @property
    def wt(self) -> Array:
        """``(k, 3, w)`` ``W^T = Jp^T Jc`` per observation, formed on use:
        the solver's passes use the rank-2 factors ``jc``, ``jp`` directly
        (fewer bytes and flops; :func:`photax.bundle._schur._schur_blocks`)."""
        return _wt_of(self.jc, self.jp)


def _wt_of(jc: Array, jp: Array) -> Array:
    """``(m, 3, w)`` ``W^T = Jp^T Jc`` of observations from their Jacobians
    ``(m, 2, w)``, ``(m, 2, 3)``."""
    return _outer_sum(jnp.swapaxes(jp, 1, 2), jnp.swapaxes(jc, 1, 2))


def _observation_terms(state: _State, s: _Structure, loss: Array, scale: Array):
    """Per-observation terms of the normal equations for the observations of
    ``s``: residuals ``r0`` ``(m, 2)``, ``rho`` and ``rho'`` ``(m,)``, the
    corrected Jacobians ``jc`` ``(m, 2, w)`` and ``jp`` ``(m, 2, 3)``, and the
    gradient contributions ``(m, w)``, ``(m, 3)``."""
    proj, jc, jp = _project_obs(state, s, jacobians=True)
    r0 = (proj - s.obs_xy) / s.obs_sigma
    jc = jc / s.obs_sigma[:, :, None] * s.mask_c[s.image_ext[s.obs_image]][:, None, :]
    jp = jp / s.obs_sigma[:, :, None] * s.mask_p[s.obs_point][:, None, :]

    def rdot(r, j):  # (m, cols) r^T j per observation, the 2 rows summed out (a batched dot is slower on CPU)
        return r[:, 0, None] * j[:, 0] + r[:, 1, None] * j[:, 1]

    def plain(r0, jc, jp):  # least squares: rho = s, rho' = 1, no correction (~20 % of the pass)
        return jnp.sum(r0 * r0, axis=1), jnp.ones(r0.shape[0]), jc, jp, rdot(r0, jc), rdot(r0, jp)

    def robust(r0, jc, jp):
        rho, weight, rho2 = _rho(jnp.sum(r0 * r0, axis=1), loss, scale)
        sqrt_rho1, alpha_sq = _corrector(r0, weight, rho2)
        # Corrected Jacobian sqrt(rho') (I - alpha r r^T / s) J / sigma (see
        # _corrector); the gradient rho' J^T r / sigma is formed from J itself,
        # which equals J~^T r~ without dividing by 1 - alpha.
        rg = r0 * weight[:, None]

        def correct(j):
            j = j - (alpha_sq[:, None] * r0)[:, :, None] * rdot(r0, j)[:, None, :]
            return j * sqrt_rho1[:, None, None]

        return rho, weight, correct(jc), correct(jp), rdot(rg, jc), rdot(rg, jp)

    # One branch runs (XLA's conditional): the loss stays a traced code, no recompilation per loss.
    rho, weight, jc, jp, g_obs_c, g_obs_p = jax.lax.cond(loss == 0, plain, robust, r0, jc, jp)
    return r0, rho, weight, jc, jp, g_obs_c, g_obs_p


def _finish_lin(state, s, n_c, cost_obs, r0, weight, jc, jp, u_diag, v, g_img, g_p) -> _Lin:
    """The :class:`_Lin` from the sums over observations: priors, ``g_c``,
    the damping diagonal and ``max |g|``."""
    rp = _prior_residuals(state, s)
    rc, jcam = _camera_prior(state, s, jacobians=True)
    u_cam = jnp.einsum("nki,nkj->nij", jcam, jcam)
    g_img = g_img.at[:, :6].add(jnp.einsum("nki,nk->ni", jcam, rc))
    u_diag = u_diag.at[:, :6].add(jnp.diagonal(u_cam, axis1=1, axis2=2))
    pw = s.prior_w * s.mask_p
    v = v + pw[:, :, None] * jnp.eye(3)[None, :, :]
    g_p = g_p + pw * (state.xyz - s.prior_xyz)
    rd, jd = _dem_residuals(state, s, jacobians=True)  # the DEM heights: the point blocks of V and g_p
    v = v + jd[:, :, None] * jd[:, None, :]
    g_p = g_p + jd * rd[:, None]
    flat = s.image_ext.ravel()
    g_c = jnp.zeros(n_c).at[flat].add(g_img.ravel())
    # LM damping D: the diagonal of the normal matrix J~^T J~ (Ceres).
    d_c = jnp.zeros(n_c).at[flat].add(u_diag.ravel())
    d_p = jnp.diagonal(v, axis1=1, axis2=2)
    clamp = functools.partial(jnp.clip, min=1e-6, max=1e32)
    gmax = jnp.maximum(jnp.max(jnp.abs(g_c), initial=0.0), jnp.max(jnp.abs(g_p), initial=0.0))
    cost = cost_obs + 0.5 * jnp.sum(rp * rp) + 0.5 * jnp.sum(rc * rc) + 0.5 * jnp.sum(rd * rd)
    return _Lin(cost, r0, weight, jc, jp, u_diag, v, g_img, g_c, g_p, clamp(d_c), clamp(d_p), gmax, u_cam)


#: Observations beyond which :func:`_linearise` runs in chunks of
#: :data:`LIN_CHUNK` (:func:`_linearise_chunked`): its whole-problem form
#: holds several ``(k, 2, w)`` Jacobian copies at once (1.7 GB of transients
#: at 2,500 images, ~7 GB at 10,000); below it the whole form is kept for its
#: speed.
LIN_WHOLE = 1 << 20
LIN_CHUNK = 1 << 16


@functools.partial(jax.jit, static_argnames=("n_c",))
def _linearise(state: _State, s: _Structure, loss: Array, scale: Array, n_c: int) -> _Lin:
    if s.obs_image.shape[0] > LIN_WHOLE:
        return _linearise_chunked(state, s, loss, scale, n_c, LIN_CHUNK)
    n_img, n_pts = state.centre.shape[0], state.xyz.shape[0]
    r0, rho, weight, jc, jp, g_obs_c, g_obs_p = _observation_terms(state, s, loss, scale)
    seg = functools.partial(jax.ops.segment_sum, num_segments=n_img)
    segp = functools.partial(jax.ops.segment_sum, num_segments=n_pts)
    jpt = jnp.swapaxes(jp, 1, 2)
    u_diag = seg(jc[:, 0] ** 2 + jc[:, 1] ** 2, s.obs_image)  # U itself is summed in the Schur pass
    g_img = seg(g_obs_c, s.obs_image)
    v = segp(_outer_sum(jpt, jpt), s.obs_point)
    g_p = segp(g_obs_p, s.obs_point)
    return _finish_lin(state, s, n_c, 0.5 * jnp.sum(rho), r0, weight, jc, jp, u_diag, v, g_img, g_p)


def _u_of(jc: Array, s: _Structure, n_img: int) -> Array:
    """``(n_img, w, w)`` ``U_i = sum Jc^T Jc`` over each image's observations
    (GEMMs over chunks of them), for the paths that need ``U`` alone (CG)."""
    w = jc.shape[2]
    jcc = jnp.take(jc, s.image_chunk, axis=0, mode="fill", fill_value=0.0).reshape(s.image_chunk.shape[0], -1, w)
    return jax.ops.segment_sum(jax.lax.dot_general(jcc, jcc, (((1,), (1,)), ((0,), (0,)))), s.image_of_chunk,
                               num_segments=n_img, indices_are_sorted=True)  # fmt: skip


def _linearise_chunked(state: _State, s: _Structure, loss: Array, scale: Array, n_c: int, chunk: int) -> _Lin:
    """:func:`_linearise` in a scan over ``chunk`` observations at a time:
    only ``r``, ``rho'`` and the Jacobians are kept per observation (written in
    place into the scan's carry), the sums ``U``, ``V``, ``g`` are added
    chunk by chunk, so the transients are one chunk's.  The last chunk
    starts at ``k - chunk`` (no padding) and adds only the observations the
    others did not."""
    n_img, n_pts, k = state.centre.shape[0], state.xyz.shape[0], s.obs_image.shape[0]
    w = 6 + s.active.shape[0]
    chunk = min(chunk, k)
    n_steps = -(-k // chunk)

    def step(carry, i):
        r_all, wgt_all, jc_all, jp_all, u, v, g_img, g_p, cost = carry
        first = jnp.minimum(i * chunk, k - chunk)
        new = (first + jnp.arange(chunk)) >= i * chunk  # not done by the previous chunk
        sl = functools.partial(jax.lax.dynamic_slice_in_dim, start_index=first, slice_size=chunk)
        sub = s._replace(obs_image=sl(s.obs_image), obs_point=sl(s.obs_point), obs_xy=sl(s.obs_xy),
                         obs_sigma=sl(s.obs_sigma))  # fmt: skip
        r0, rho, weight, jc, jp, g_obs_c, g_obs_p = _observation_terms(state, sub, loss, scale)
        m = new.astype(float)
        jct, jpt = jnp.swapaxes(jc, 1, 2) * m[:, None, None], jnp.swapaxes(jp, 1, 2)
        u = u.at[sub.obs_image].add(jct[:, :, 0] ** 2 + jct[:, :, 1] ** 2)  # diag(U)
        v = v.at[sub.obs_point].add(_outer_sum(jpt * m[:, None, None], jpt))
        g_img = g_img.at[sub.obs_image].add(g_obs_c * m[:, None])
        g_p = g_p.at[sub.obs_point].add(g_obs_p * m[:, None])
        upd = functools.partial(jax.lax.dynamic_update_slice_in_dim, start_index=first, axis=0)
        carry = (upd(r_all, r0), upd(wgt_all, weight), upd(jc_all, jc), upd(jp_all, jp), u, v, g_img, g_p,
                 cost + 0.5 * jnp.sum(rho * m))  # fmt: skip
        return carry, None

    init = (jnp.zeros((k, 2)), jnp.zeros(k), jnp.zeros((k, 2, w)), jnp.zeros((k, 2, 3)), jnp.zeros((n_img, w)),
            jnp.zeros((n_pts, 3, 3)), jnp.zeros((n_img, w)), jnp.zeros((n_pts, 3)), jnp.zeros(()))  # fmt: skip
    (r0, weight, jc, jp, u_diag, v, g_img, g_p, cost), _ = jax.lax.scan(step, init, jnp.arange(n_steps))
    return _finish_lin(state, s, n_c, cost, r0, weight, jc, jp, u_diag, v, g_img, g_p)
