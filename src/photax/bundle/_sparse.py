"""The reduced camera system of a large block as a sparse, block-tridiagonal
("banded") matrix: layout, Cholesky factor, solve and selected inversion, all
in JAX (``lax.scan`` over dense blocks: runs unchanged on a GPU).

Why banded.  The Schur complement ``S`` couples two images only where they
share points, i.e. where their footprints overlap: a block of strips is a
2-D grid of images with a short-range stencil.  Ordered strip by strip (or by
reverse Cuthill–McKee, whichever gives the narrower band), every coupling
spans at most ``c`` images (the *bandwidth*, about one strip).  Cut the
ordered images into chunks of ``c``: then ``S`` is block-tridiagonal in
chunks, plus a *border* of the unknowns shared by many images (the
intrinsics of a camera used by several images), which is ordered last::

        [ D_0  B_0^T                 C_0^T ]
        [ B_0  D_1   B_1^T           C_1^T ]
    S = [      B_1   D_2   ...       C_2^T ]         D_i, B_i: (cw, cw)
        [             ...  D_{N-1}   ...   ]         C_i: (n_b, cw)
        [ C_0  C_1   C_2   ...       E     ]         E: (n_b, n_b)

and its Cholesky factor has the same block pattern (no fill outside it):
``L_ii = chol(D_i - L_{i,i-1} L_{i,i-1}^T)``, ``L_{i+1,i} = B_i L_ii^-T``,
``L_{b,i} = (C_i - L_{b,i-1} L_{i,i-1}^T) L_ii^-T``, ``L_bb = chol(E -
sum L_{b,i} L_{b,i}^T)`` (Golub & Van Loan, *Matrix Computations*, 4th ed.,
4.5.3, block tridiagonal systems).  It costs ``N (cw^3/3 + 2 cw^3)`` flops
in dense BLAS-3 operations of size ``cw = c w`` -- for the 30 x 30 block
(8,100 unknowns, ``c = 33``, ``cw = 297``) 1.7 GFLOP against 177 GFLOP for
the dense Cholesky -- with no symbolic analysis per iteration, fixed shapes
(one compile) and nothing but ``cholesky``, ``triangular_solve`` and GEMMs,
which XLA has on CPU and GPU alike.  A general sparse Cholesky with nested
dissection does fewer flops on very large blocks (``O(n^1.5)`` against
``O(n c^2)``) but needs a host library per iteration and no such library
installs from wheels here with its factor exposed (see ``pyproject.toml``).

Selected inversion.  The blocks of ``Z = S^-1`` on the same pattern (all a
covariance needs: each image's own block, and those of images that share
points, which lie in the band) follow from the factor by Takahashi's
recurrences (Takahashi, Fagan & Chin 1973; Erisman & Tinney 1975), from
``L^T Z = L^-1`` and ``Z L = L^-T``, for ``R`` the blocks below ``i``::

    Z_Ri = -Z_RR L_Ri L_ii^-1,      Z_ii = L_ii^-T (L_ii^-1 - L_Ri^T Z_Ri)

here with ``R = {i+1, border}``: a reverse scan, the same cost as the factor.

Which solver (:func:`choose_solver`, ``linear_solver="auto"``).  Dense
Cholesky unless the banded factor's flop estimate is :data:`BAND_MARGIN`
below the dense ``n^3/3``; then the band, unless its arrays would pass
:data:`BAND_MEMORY`; then CG.  Measured on the generated BAL blocks of
``benchmarks/bench_bundle.py`` (CPU seconds, 2-core machine at load 10-13,
one BLAS thread for dense <= 1,500 unknowns and for band and CG)::

    images  unknowns  per trial step: dense  band   CG     whole adjustment: dense  band   CG
    100     900                       0.077  0.072  0.96                     1.5    1.7    11.5
    400     3,600                     0.96   0.36   4.4                      44     19     144

The band wins or ties from a few chunks on (100 images: 8 chunks, 8x
fewer flops than dense, the same time: the Schur assembly dominates both);
CG (Ceres' ITERATIVE_SCHUR with its Schur-Jacobi preconditioner) loses at
every size we ran, 7-12x per step: a block of strips has weak modes (per
image focal length against flying height, long-wavelength bending) on which
the preconditioned CG needs its full iteration budget, and its final cost
is the highest (400 images: 5.0310419e4 against 5.0310349e4).  So CG
remains only the memory fallback, and the dense factor the choice for
compact problems (problem-49-7776: one chunk of 441 unknowns).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

#: Constant of the dense Cholesky estimate ``n^3 / 3`` against the banded
#: ``N (cw^3 / 3 + 2 cw^3)``: the banded path runs a scan of ``N`` steps,
#: whose per-step overhead makes it lose below a few hundred unknowns; it is
#: chosen when its flop estimate is below the dense one divided by this
#: factor (problem-49-7776: dense; 100 images of a 10 x 10 grid: banded).
BAND_MARGIN = 2.0


class BandLayout(NamedTuple):
    """Where each camera-side unknown sits in the banded system (numpy).

    ``perm`` ``(N, cw)``: unknown at each slot of each chunk (``n_c`` =
    padding); ``border`` ``(n_b,)``: the unknowns shared by several images,
    ordered last; ``chunk`` ``(n_c,)``: chunk of each unknown (-1 in the
    border); ``offset`` ``(n_c,)``: its slot in the chunk (or the border)."""

    perm: np.ndarray
    border: np.ndarray
    chunk: np.ndarray
    offset: np.ndarray


def _bandwidth(order: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> int:
    pos = np.empty_like(order)
    pos[order] = np.arange(len(order))
    return int(np.max(np.abs(pos[ia] - pos[ib]), initial=0))


def band_layout(image_ext: np.ndarray, key_a: np.ndarray, key_b: np.ndarray, n_c: int) -> BandLayout:
    """The banded layout of a problem's reduced system.

    ``image_ext`` ``(n_img, w)``: unknowns of each image's columns;
    ``key_a, key_b``: the pairs of images that share points (the blocks of
    ``S``).  Unknowns used by one image are *private* (exterior orientation,
    intrinsics of a camera of its own); the others are the border.  Images
    are ordered as given or by reverse Cuthill–McKee on the image graph,
    whichever gives the smaller bandwidth ``c`` (images), and cut into
    chunks of ``max(c, 1)`` images."""
    n_img, w = image_ext.shape
    uses = np.bincount(image_ext.ravel(), minlength=n_c)
    private = uses[image_ext] == 1  # (n_img, w)
    border = np.flatnonzero(uses != 1)
    ia, ib = np.asarray(key_a), np.asarray(key_b)
    off = ia != ib
    ia, ib = ia[off], ib[off]
    natural = np.arange(n_img)
    graph = coo_matrix((np.ones(len(ia)), (ia, ib)), shape=(n_img, n_img)).tocsr()
    rcm = np.asarray(reverse_cuthill_mckee(graph + graph.T, symmetric_mode=True), dtype=np.int64)
    order = min((natural, rcm), key=lambda o: _bandwidth(o, ia, ib))
    c = max(_bandwidth(order, ia, ib), 1)
    n_chunks = -(-n_img // c)
    per_image = private.sum(axis=1)
    chunk_of_image = np.empty(n_img, np.int64)
    chunk_of_image[order] = np.arange(n_img) // c
    widths = np.bincount(chunk_of_image, weights=per_image, minlength=n_chunks).astype(np.int64)
    cw = max(int(widths.max(initial=0)), 1)
    perm = np.full((n_chunks, cw), n_c, np.int64)
    chunk = np.full(n_c, -1, np.int64)
    offset = np.empty(n_c, np.int64)
    fill = np.zeros(n_chunks, np.int64)
    for i in order:  # images in band order; their private columns in column order
        cols = image_ext[i][private[i]]
        k = chunk_of_image[i]
        perm[k, fill[k] : fill[k] + len(cols)] = cols
        chunk[cols], offset[cols] = k, fill[k] + np.arange(len(cols))
        fill[k] += len(cols)
    offset[border] = np.arange(len(border))
    return BandLayout(perm, border, chunk, offset)


def band_flops(n_chunks: int, cw: int, n_b: int) -> float:
    """Flops of the banded Cholesky (:func:`band_cholesky`)."""
    return n_chunks * (cw**3 / 3.0 + 2.0 * cw**3 + 2.0 * n_b * cw * cw) + n_b**3 / 3.0


def band_pays(layout_shape: tuple[int, int], n_b: int, n_c: int) -> bool:
    """The solver-choice rule: the banded factor when its flop estimate is
    below the dense Cholesky's ``n_c^3 / 3`` by :data:`BAND_MARGIN`."""
    n_chunks, cw = layout_shape
    return n_chunks >= 2 and BAND_MARGIN * band_flops(n_chunks, cw, n_b) < n_c**3 / 3.0


class Band(NamedTuple):
    """A symmetric matrix in banded layout (lower blocks), or its factor,
    or blocks of its inverse: ``d`` ``(N, cw, cw)`` diagonal blocks, ``b``
    ``(N, cw, cw)`` block ``(i+1, i)`` (the last one zero), ``c`` ``(N, n_b,
    cw)`` border blocks ``(b, i)``, ``e`` ``(n_b, n_b)``."""

    d: Array
    b: Array
    c: Array
    e: Array


def flat_index(chunk: Array, offset: Array, r: Array, c: Array, n_chunks: int, cw: int, n_b: int, lower: bool):
    """Index into the flat concatenation of a :class:`Band`'s arrays of the
    entries ``(r, c)`` (unknown numbers); entries of the upper triangle are
    dropped (index past the end) when ``lower``, else taken from the
    mirrored entry."""
    if not lower:  # swap to the stored (lower) triangle
        cr, cc = chunk[r], chunk[c]
        upper = ((cr >= 0) & (cc >= 0) & (cr < cc)) | ((cr >= 0) & (cc < 0))  # D_i and E are stored whole
        r, c = jnp.where(upper, c, r), jnp.where(upper, r, c)
    cr, cc, orr, oc = chunk[r], chunk[c], offset[r], offset[c]
    nd = n_chunks * cw * cw
    total = 2 * nd + n_chunks * n_b * cw + n_b * n_b
    i_d = (cr * cw + orr) * cw + oc
    i_b = nd + (cc * cw + orr) * cw + oc
    i_c = 2 * nd + (cc * n_b + orr) * cw + oc
    i_e = 2 * nd + n_chunks * n_b * cw + orr * n_b + oc
    both = (cr >= 0) & (cc >= 0)
    idx = jnp.where(both & (cr == cc), i_d, total)
    idx = jnp.where(both & (cr == cc + 1), i_b, idx)
    idx = jnp.where((cr < 0) & (cc >= 0), i_c, idx)
    idx = jnp.where((cr < 0) & (cc < 0), i_e, idx)
    return idx


def _parts(m: Band, idx: Array):
    """Each of a :class:`Band`'s arrays (flattened) with the positions of the
    flat indices ``idx`` (:func:`flat_index`) that fall in it (others: past
    its end)."""
    out, first = [], 0
    for a in m:
        last = first + a.size
        out.append((a, jnp.where((idx >= first) & (idx < last), idx - first, a.size)))
        first = last
    return out


def band_add(m: Band, idx: Array, values: Array) -> Band:
    """``m`` with ``values`` added at the flat indices ``idx``
    (:func:`flat_index`; past the end: dropped), array by array: no
    concatenated copy of the matrix (at 10,000 images each of ``d`` and
    ``b`` is 0.66 GB)."""
    return Band(
        *(a.ravel().at[i].add(values, mode="drop").reshape(a.shape) if a.size else a for a, i in _parts(m, idx))
    )


def band_take(m: Band, idx: Array) -> Array:
    """The entries of ``m`` at the flat indices ``idx`` (:func:`flat_index`)."""
    out = jnp.zeros(idx.shape)
    for a, i in _parts(m, idx):
        if a.size:  # no border: c and e are empty
            out = out + jnp.take(a.ravel(), i, mode="fill", fill_value=0.0)
    return out


def _tri(a, b, *, left, lower, transpose_a=False):
    return jax.lax.linalg.triangular_solve(a, b, left_side=left, lower=lower, transpose_a=transpose_a)


def band_cholesky(m: Band) -> Band:
    """Cholesky factor of a banded symmetric positive definite matrix (see
    the module docstring); NaN where it is not positive definite."""
    n_b = m.e.shape[0]

    def step(carry, x):
        l_prev, lb_prev, g = carry  # L_{i,i-1}, L_{b,i-1}, sum L_{b,j} L_{b,j}^T
        d, b, c = x
        lii = jnp.linalg.cholesky(d - l_prev @ l_prev.T)
        l_next = _tri(lii, b, left=False, lower=True, transpose_a=True)  # B_i L_ii^-T
        lb = _tri(lii, c - lb_prev @ l_prev.T, left=False, lower=True, transpose_a=True)
        return (l_next, lb, g + lb @ lb.T), (lii, l_next, lb)

    cw = m.d.shape[1]
    init = (jnp.zeros((cw, cw)), jnp.zeros((n_b, cw)), jnp.zeros((n_b, n_b)))
    (_, _, g), (ld, lb_, lc) = jax.lax.scan(step, init, (m.d, m.b, m.c))
    le = jnp.linalg.cholesky(m.e - g) if n_b else m.e
    return Band(ld, lb_, lc, le)


def band_solve(f: Band, rhs_chunks: Array, rhs_border: Array) -> tuple[Array, Array]:
    """Solve ``L L^T x = r`` with the factor of :func:`band_cholesky`;
    ``r`` in layout order ``(N, cw)`` and ``(n_b,)``."""
    n_b = f.e.shape[0]

    def fwd(carry, x):
        y_prev, l_prev, acc = carry
        lii, l_next, lb, r = x
        y = _tri(lii, (r - l_prev @ y_prev)[:, None], left=True, lower=True)[:, 0]
        return (y, l_next, acc + lb @ y), y

    cw = f.d.shape[1]
    (_, _, acc), y = jax.lax.scan(
        fwd, (jnp.zeros(cw), jnp.zeros((cw, cw)), jnp.zeros(n_b)), (f.d, f.b, f.c, rhs_chunks)
    )
    if n_b:
        yb = _tri(f.e, (rhs_border - acc)[:, None], left=True, lower=True)[:, 0]
        xb = _tri(f.e, yb[:, None], left=True, lower=True, transpose_a=True)[:, 0]
    else:
        xb = rhs_border

    def back(x_next, x):
        lii, l_next, lb, yi = x
        xi = _tri(lii, (yi - l_next.T @ x_next - lb.T @ xb)[:, None], left=True, lower=True, transpose_a=True)[:, 0]
        return xi, xi

    _, xs = jax.lax.scan(back, jnp.zeros(cw), (f.d, f.b, f.c, y), reverse=True)
    return xs, xb


def band_selected_inverse(f: Band) -> Band:
    """The blocks of ``S^-1`` on the banded pattern from the factor of
    :func:`band_cholesky`, by Takahashi's recurrences (module docstring)."""
    n_b, cw = f.e.shape[0], f.d.shape[1]
    if n_b:
        le_inv = _tri(f.e, jnp.eye(n_b), left=True, lower=True)
        zbb = le_inv.T @ le_inv
    else:
        zbb = f.e

    def step(carry, x):
        z_next, zb_next = carry  # Z_{i+1,i+1}, Z_{b,i+1}
        lii, l_next, lb = x
        lii_inv = _tri(lii, jnp.eye(cw), left=True, lower=True)
        z_sub = -(z_next @ l_next + zb_next.T @ lb) @ lii_inv  # Z_{i+1,i}
        z_b = -(zb_next @ l_next + zbb @ lb) @ lii_inv  # Z_{b,i}
        z_ii = lii_inv.T @ (lii_inv - l_next.T @ z_sub - lb.T @ z_b)
        z_ii = 0.5 * (z_ii + z_ii.T)
        return (z_ii, z_b), (z_ii, z_sub, z_b)

    init = (jnp.zeros((cw, cw)), jnp.zeros((n_b, cw)))
    _, (zd, zs, zc) = jax.lax.scan(step, init, (f.d, f.b, f.c), reverse=True)
    return Band(zd, zs, zc, zbb)


#: Bytes of the banded path's arrays beyond which ``linear_solver="auto"``
#: takes matrix-free conjugate gradients instead: the matrix, its factor and
#: (for the precision) its inverse blocks, 8 bytes each.
BAND_MEMORY = 8e9


def choose_solver(band_perm_shape: tuple[int, int], n_b: int, n_c: int) -> str:
    """``linear_solver="auto"``: ``"dense"`` Cholesky unless the banded
    factor's flop estimate is :data:`BAND_MARGIN` times below it
    (:func:`band_pays`); then ``"band"``, unless its arrays would exceed
    :data:`BAND_MEMORY` (a block far beyond 10,000 images): ``"cg"``."""
    if not band_pays(band_perm_shape, n_b, n_c):
        return "dense"
    n_chunks, cw = band_perm_shape
    if 3 * 8.0 * (2 * n_chunks * cw * cw + n_chunks * n_b * cw + n_b * n_b) > BAND_MEMORY:
        return "cg"
    return "band"
