"""The Schur complement: the reduced camera system, solved densely (Cholesky)
or matrix-free (conjugate gradients), and one damped step."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import Array

from .._linalg import inv3
from ..rotation import axis_angle_to_matrix
from ._linearise import _cost, _Lin, _linearise, _u_of
from ._sparse import Band, band_add, band_cholesky, band_solve, flat_index
from ._structure import _State, _Structure


def _damped_vinv(lin: _Lin, s: _Structure, lam: Array):
    """``(n_pts, 3, 3)`` damped ``V^-1`` (fixed points: identity)."""
    v = lin.v + (lam * lin.d_p * s.mask_p + (1.0 - s.mask_p))[:, :, None] * jnp.eye(3)[None, :, :]
    return jax.vmap(inv3)(v)  # by the adjugate: elementwise, faster than batched LU on CPU


def _yt_of(vinv_obs: Array, wt: Array) -> Array:
    """``Y^T = V^-1 W^T`` ``(m, 3, w)`` of observations, from their points'
    ``V^-1`` ``(m, 3, 3)`` and ``W^T`` ``(m, 3, w)``; unrolled over the
    3-long axis: faster than a batched dot of tiny matrices on XLA CPU."""
    return sum(vinv_obs[:, :, j, None] * wt[:, None, j, :] for j in range(3))


def _jc_dot(jc: Array, x: Array) -> Array:
    """``(m, 2)`` ``J x`` per observation for ``J`` ``(m, 2, n)``, ``x`` ``(m, n)``
    (unrolled over ``n``: XLA CPU's reductions over a short minor axis are slow)."""
    return sum(jc[:, :, j] * x[:, None, j] for j in range(x.shape[1]))


def _jt_dot(j: Array, t: Array) -> Array:
    """``(m, n)`` ``J^T t`` per observation for ``J`` ``(m, 2, n)``, ``t`` ``(m, 2)``."""
    return j[:, 0] * t[:, 0, None] + j[:, 1] * t[:, 1, None]


def _h_of(vinv_obs: Array, jp: Array) -> Array:
    """``(m, 2, 3)`` ``H = Jp V^-1`` of observations (their points' ``V^-1``)."""
    return sum(jp[:, :, j, None] * vinv_obs[:, None, j, :] for j in range(3))


def _reduced_rhs(lin: _Lin, s: _Structure, vinv: Array, n_c: int):
    """The reduced right-hand side ``g_c - W V^-1 g_p`` (in unknown order);
    ``W_a V^-1 g_p = Jc^T (Jp V^-1 g_p)`` per observation (rank 2)."""
    n_img = lin.g_img.shape[0]
    vg = sum(vinv[:, :, j] * lin.g_p[:, j, None] for j in range(3))[
        s.obs_point
    ]  # V^-1 g_p per observation (unrolled: see _yt_of)
    t = _jc_dot(lin.jp, vg)  # Jp V^-1 g_p, (k, 2)
    rhs_img = lin.g_img - jax.ops.segment_sum(_jt_dot(lin.jc, t), s.obs_image, num_segments=n_img)
    return jnp.zeros(n_c).at[s.image_ext.ravel()].add(rhs_img.ravel())


#: Bytes of a stored ``H = Jp V^-1`` ``(k, 2, 3)`` up to which
#: :func:`_schur_blocks` forms it once per step; above it (10,000 images:
#: 380 MB), ``H`` is formed piece by piece inside the loop (memory).
SCHUR_STORE_BYTES = 1 << 28


def _pair_products(h_a: Array, jc_a: Array, jp_b: Array, jc_b: Array, same: Array, piece: int) -> Array:
    """``(piece, w, w)``: ``sum (W_a V^-1 W_b^T - [a = b] Jc_a^T Jc_a)``
    over each chunk's pairs of observations ``(a, b)`` of one point, from
    the rank-2 factors ``W_a = Jc_a^T Jp_a``::

        W_a V^-1 W_b^T = Jc_a^T M_ab Jc_b,   M_ab = H_a Jp_b^T (2 x 2),  H_a = Jp_a V^-1

    so each chunk's sum is one GEMM ``(w x 2 CHUNK) (2 CHUNK x w)`` of
    ``P_ab = (M_ab - [a = b] I)^T Jc_a`` and ``Jc_b`` (K = 2 per pair
    instead of 3 for ``Y_a^T W_b^T``, 48 numbers gathered per pair instead
    of 54).  The pairs ``(a, a)`` thereby also subtract ``U_i = sum Jc^T
    Jc``, so a diagonal block comes out as ``-S_ii`` whole and the
    linearisation need not form ``U`` (900-image block: the Schur pass
    -15 % and the linearisation -25 % CPU with the rest of this layout).
    Inputs ``(m, 2, 3)``, ``(m, 2, w)`` per pair slot, ``same`` ``(m,)``
    1.0 where ``a = b`` (padding slots: zero Jacobians), ``m = piece *
    CHUNK``."""
    w = jc_a.shape[2]
    m_ab = sum(h_a[:, :, None, t] * jp_b[:, None, :, t] for t in range(3))  # (m, 2, 2): M[r, s]
    m_ab = m_ab - same[:, None, None] * jnp.eye(2)[None]
    p = sum(m_ab[:, r, :, None] * jc_a[:, r, None, :] for r in range(2))  # (m, 2, w): P[s] = sum_r M[r, s] Jc_a[r]
    p, jb = p.reshape(piece, -1, w), jc_b.reshape(piece, -1, w)
    return jax.lax.dot_general(p, jb, (((1,), (1,)), ((0,), (0,))))


def _schur_blocks(lin: _Lin, s: _Structure, lam: Array, n_c: int, stream: bool | None = None):
    """The blocks ``sum W_a V^-1 W_b^T - [i = j] U_i = -S_ij`` of the Schur
    complement, one per key ``(key_a, key_b)`` (see :func:`_reduced_system`), ``(n_keys, w,
    w)``, the reduced right-hand side and the damped ``V^-1``; each chunk's
    sum by :func:`_pair_products`.

    ``stream`` (default: when ``H`` would pass :data:`SCHUR_STORE_BYTES`):
    nothing per observation is stored beyond the Jacobians themselves: ``H
    = Jp V^-1`` is formed piece by piece inside the loop over the pieces of
    chunks, and each piece's products are added into the blocks at once (a
    scan)."""
    vinv = _damped_vinv(lin, s, lam)
    rhs = _reduced_rhs(lin, s, vinv, n_c)
    n_pieces, piece, _ = s.chunk_a.shape
    k = lin.jc.shape[0]
    take = functools.partial(jnp.take, axis=0, mode="fill", fill_value=0)  # index k pads the chunks: zeros
    if stream is None:
        stream = 8 * k * 6 > SCHUR_STORE_BYTES
    if not stream:
        h = _h_of(vinv[s.obs_point], lin.jp)

        def products(idx):  # (piece, w, w): W_a V^-1 W_b^T summed over each chunk
            a, b = idx[0].ravel(), idx[1].ravel()
            return _pair_products(
                take(h, a), take(lin.jc, a), take(lin.jp, b), take(lin.jc, b), (a == b).astype(float), piece
            )

        prod = jax.lax.map(products, (s.chunk_a, s.chunk_b))
        prod = prod.reshape(n_pieces * piece, *prod.shape[2:])
        blocks = jax.ops.segment_sum(prod, s.chunk_key, num_segments=s.key_a.shape[0], indices_are_sorted=True)
        return blocks, rhs, vinv
    keys = s.chunk_key.reshape(n_pieces, piece)
    w = lin.jc.shape[2]

    def add_piece(blocks, x):  # the chunks' sums of the piece, added to their blocks
        a, b, key = x
        a, b = a.ravel(), b.ravel()
        h_a = _h_of(take(vinv, take(s.obs_point, a)), take(lin.jp, a))
        prod = _pair_products(h_a, take(lin.jc, a), take(lin.jp, b), take(lin.jc, b), (a == b).astype(float), piece)
        return blocks.at[key].add(prod, indices_are_sorted=True), None

    blocks0 = jnp.zeros((s.key_a.shape[0], w, w))
    blocks, _ = jax.lax.scan(add_piece, blocks0, (s.chunk_a, s.chunk_b, keys))
    return blocks, rhs, vinv


def _scatter_schur(put, lin: _Lin, s: _Structure, blocks: Array):
    """Add the blocks (``-S_ij``; those of an image with itself include
    ``U_i``, :func:`_pair_products`) to a reduced system through
    ``put(rows, cols, values)``: blocks of pairs ``a < b`` with their
    transposes."""
    ext = s.image_ext
    ra, cb = ext[s.key_a], ext[s.key_b]
    put(ra[:, :, None], cb[:, None, :], -blocks)
    put(cb[:, :, None], ra[:, None, :], -jnp.swapaxes(blocks, 1, 2) * s.key_off[:, None, None])
    put(ext[:, :6, None], ext[:, None, :6], lin.u_cam)  # GNSS / attitude observations: U's diagonal blocks


def _reduced_system(lin: _Lin, s: _Structure, lam: Array, n_c: int):
    """Dense Schur complement ``S`` (undamped diagonal) and right-hand side.

    ``S = U - W V^-1 W^T``, block ``(i, j)`` summed over the points seen
    by images ``i`` and ``j``: ``- sum W_a V^-1 W_b^T`` over pairs of
    observations ``(a, b)`` of one point (``a == b`` included, with ``U``).
    The pairs come in chunks of one block each, so the sum is batched GEMMs
    of ``(w x 2 CHUNK) (2 CHUNK x w)`` products (:func:`_pair_products`)
    and a small sorted segment sum; blocks of pairs ``a < b`` are added
    with their transposes."""
    blocks, rhs, vinv = _schur_blocks(lin, s, lam, n_c)
    S = [jnp.zeros((n_c, n_c))]

    def put(rows, cols, values):
        S[0] = S[0].at[rows, cols].add(values)

    _scatter_schur(put, lin, s, blocks)
    return S[0], rhs, vinv


def _band_shape(s: _Structure):
    n_chunks, cw = s.band_perm.shape
    return n_chunks, cw, s.band_border.shape[0]


def _reduced_band(lin: _Lin, s: _Structure, lam: Array, n_c: int, diag: Array):
    """The reduced system in the banded layout of :mod:`._sparse` (lower
    blocks only), with ``diag`` ``(N,)`` added to its diagonal and 1 on the
    padding slots; the right-hand side and ``V^-1``."""
    blocks, rhs, vinv = _schur_blocks(lin, s, lam, n_c)
    shape = _band_shape(s)
    n_chunks, cw, n_b = shape
    pad = (s.band_perm == n_c).astype(float)  # padding slots: 1 on the diagonal
    m = [Band(pad[:, :, None] * jnp.eye(cw)[None], jnp.zeros((n_chunks, cw, cw)), jnp.zeros((n_chunks, n_b, cw)),
              jnp.zeros((n_b, n_b)))]  # fmt: skip

    def put(rows, cols, values):  # scattered into each array in place: no concatenated copy
        idx = flat_index(s.band_chunk, s.band_offset, rows, cols, *shape, lower=True)
        m[0] = band_add(m[0], jnp.broadcast_to(idx, values.shape), values)

    _scatter_schur(put, lin, s, blocks)
    every = jnp.arange(n_c)
    put(every, every, diag)
    return m[0], rhs, vinv


def _solve_band(lin: _Lin, s: _Structure, lam: Array, n_c: int):
    """Solve the damped reduced system by the banded Cholesky of
    :mod:`._sparse`."""
    damp = lam * lin.d_c * s.mask_c + (1.0 - s.mask_c)
    m, rhs, vinv = _reduced_band(lin, s, lam, n_c, damp)
    f = band_cholesky(m)
    xc, xb = band_solve(f, jnp.append(rhs, 0.0)[s.band_perm], rhs[s.band_border])
    x = jnp.zeros(n_c + 1).at[s.band_perm.ravel()].set(xc.ravel()).at[s.band_border].set(xb)[:n_c]
    return x, vinv


def _solve_cg(lin: _Lin, s: _Structure, lam: Array, n_c: int):
    """Solve the damped reduced system matrix-free by conjugate gradients
    (Ceres' ITERATIVE_SCHUR with its Schur–Jacobi preconditioner): ``S x``
    is ``U x - W (V^-1 (W^T x))`` with per-observation blocks, so ``S`` is
    never formed; memory stays linear in the observations.  The
    preconditioner is the inverse of each image's diagonal block of ``S``
    over its private unknowns (exterior orientation, intrinsics of a camera
    of its own), and of the diagonal for the unknowns shared by several
    images (:mod:`._sparse`'s border)."""
    vinv = _damped_vinv(lin, s, lam)
    rhs = _reduced_rhs(lin, s, vinv, n_c)
    wt = lin.wt  # (k, 3, w) formed once
    yt = _yt_of(vinv[s.obs_point], wt)  # (k, 3, w): the memory fallback stores it (only this path)
    ext, n_img, n_pts, wo = s.image_ext, lin.g_img.shape[0], lin.v.shape[0], jnp.swapaxes(wt, 1, 2)
    w = ext.shape[1]
    u_img = _u_of(lin.jc, s, n_img).at[:, :6, :6].add(lin.u_cam)  # with the GNSS / attitude observations
    damp = lam * lin.d_c * s.mask_c + (1.0 - s.mask_c)
    block = u_img - jax.ops.segment_sum(jnp.einsum("kai,kaj->kij", wt, yt), s.obs_image, num_segments=n_img)
    diag_img = jnp.diagonal(block, axis1=1, axis2=2)
    diag = jnp.zeros(n_c).at[ext.ravel()].add(diag_img.ravel()) + damp
    private = (s.band_chunk[ext] >= 0).astype(float)  # (n_img, w)
    pm = private[:, :, None] * private[:, None, :]
    block = block * pm + jnp.eye(w)[None] * (damp[ext] * private + (1.0 - private))[:, None, :]
    block_inv = jnp.linalg.inv(block)  # (n_img, w, w), small
    shared = (s.band_chunk < 0).astype(float)

    def precondition(v):
        z = jnp.einsum("nij,nj->ni", block_inv, v[ext] * private) * private
        return jnp.zeros(n_c).at[ext.ravel()].add(z.ravel()) + shared * v / diag

    def matvec(x):
        xe = x[ext]  # (n_img, w)
        ux = jnp.einsum("nij,nj->ni", u_img, xe)
        t = jax.ops.segment_sum(jnp.einsum("kij,ki->kj", wo, xe[s.obs_image]), s.obs_point, num_segments=n_pts)
        z = jnp.einsum("pij,pj->pi", vinv, t)
        wz = jax.ops.segment_sum(jnp.einsum("kij,kj->ki", wo, z[s.obs_point]), s.obs_image, num_segments=n_img)
        return jnp.zeros(n_c).at[ext.ravel()].add((ux - wz).ravel()) + damp * x

    x, _ = jax.scipy.sparse.linalg.cg(matvec, rhs, tol=1e-8, maxiter=200, M=precondition)
    return x, vinv


@functools.partial(jax.jit, static_argnames=("n_c", "solver", "relinearise"))
def _trial(state: _State, lin: _Lin, s: _Structure, lam: Array, loss: Array, scale: Array, n_c: int,
           solver: str = "dense", relinearise: bool = False):  # fmt: skip
    """One damped step: returns the candidate state, its cost, the predicted
    decrease, the step norm, the parameter norm, and with ``relinearise``
    the candidate's linearisation (its cost is the candidate's: one
    projection pass instead of two when the step is accepted as is, else
    None)."""
    if solver == "dense":
        S, rhs, vinv = _reduced_system(lin, s, lam, n_c)
        S = S + jnp.diag(lam * lin.d_c * s.mask_c + (1.0 - s.mask_c))
        chol = (jax.lax.linalg.cholesky(S, symmetrize_input=False), True)  # S is symmetric by construction
        dc = -jax.scipy.linalg.cho_solve(chol, rhs) * s.mask_c
    elif solver == "band":
        x, vinv = _solve_band(lin, s, lam, n_c)
        dc = -x * s.mask_c
    else:
        x, vinv = _solve_cg(lin, s, lam, n_c)
        dc = -x * s.mask_c
    dce = dc[s.image_ext]  # (n_img, w)
    # W^T dc per observation = Jp^T (Jc dc), summed per point
    wdc = jax.ops.segment_sum(_jt_dot(lin.jp, _jc_dot(lin.jc, dce[s.obs_image])), s.obs_point,
                              num_segments=state.xyz.shape[0])  # fmt: skip
    dp = -jnp.sum(vinv * (lin.g_p + wdc)[:, None, :], axis=2) * s.mask_p
    n_img, n_cam = state.centre.shape[0], state.intr.shape[0]
    a = s.active.shape[0]
    dimg = dc[: 6 * n_img].reshape(n_img, 6)
    dintr = dc[6 * n_img :].reshape(n_cam, a)
    # The centre step is taken in the camera frame and turns with the
    # camera: C <- C + R' R^T dC, R' = R Exp(dr) (the same first-order step,
    # so J, D and the model are unchanged), i.e. in camera coordinates the
    # translation adds after the rotation, as Ceres/COLMAP's cam_from_world
    # t does.  C + dC would move the camera along its old axes: with a free
    # focal length per image, whose weak mode is a move along the optical
    # axis traded against f, a step that also tilts the camera then leaves
    # the valley sideways (400-image block: gain ratios 0.6-0.9 and 27
    # iterations; with this update 15, on Ceres' path; see _solver).
    rot = state.rot @ axis_angle_to_matrix(dimg[:, :3])
    new = _State(
        rot,
        state.centre + jnp.einsum("nij,nkj,nk->ni", rot, state.rot, dimg[:, 3:]),
        state.intr.at[:, s.active].add(dintr),
        state.xyz + dp,
    )
    # Model decrease L(0) - L(h) = 0.5 h^T (lam D h - g)  (Madsen et al. 2004).
    pred = 0.5 * (jnp.sum(dc * (lam * lin.d_c * dc - lin.g_c)) + jnp.sum(dp * (lam * lin.d_p * dp - lin.g_p)))
    step = jnp.sqrt(jnp.sum(dc * dc) + jnp.sum(dp * dp))
    xnorm = jnp.sqrt(jnp.sum(new.centre**2) + jnp.sum(new.intr**2) + jnp.sum(new.xyz**2))
    if relinearise:
        lin_new = _linearise(new, s, loss, scale, n_c)
        new_cost = lin_new.cost
    else:
        lin_new, new_cost = None, _cost(new, s, loss, scale)
    ok = jnp.isfinite(new_cost) & jnp.isfinite(step)
    return new, jnp.where(ok, new_cost, jnp.inf), pred, step, xnorm, lin_new
