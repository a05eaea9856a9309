"""Lane-wise small linear algebra: the image axis last.

Every array here carries the batch of images as its **last** axis (``B``
lanes): a ``(k, k, B)`` matrix is ``k * k`` vectors of ``B`` numbers.  Written
so, each entry's arithmetic is one element-wise operation over ``B``
contiguous numbers, which XLA vectorises; the same algorithm written per
image and ``vmap``-ed keeps the image axis first, and the tiny trailing axes
(2, 3, 6) defeat vectorisation (measured: the Gauss-Newton loop ran at about
5 us per image-step that way).  With ``B = 1`` it is the single-image code.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def cholesky(a):
    """Jacobi-scaled Cholesky of ``a`` ``(k, k, B)`` symmetric positive
    definite: ``d = diag(a)^-1/2`` and the lower triangle ``low`` (nested
    lists of ``(B,)`` arrays) with ``D a D = L L^T`` (unit diagonal, so that
    metres and radians share one matrix), unrolled entry by entry (Golub &
    Van Loan 2013, alg. 4.2.1): about ``k^3 / 6`` element-wise operations
    over the lanes.  Not positive definite -> NaN (the square root of a
    negative pivot; callers test ``isfinite``)."""
    k = a.shape[0]
    d = [1.0 / jnp.sqrt(a[i, i]) for i in range(k)]
    low = [[None] * k for _ in range(k)]
    for j in range(k):
        acc = a[j, j] * d[j] * d[j]
        for p in range(j):
            acc = acc - low[j][p] * low[j][p]
        low[j][j] = jnp.sqrt(acc)
        inv = 1.0 / low[j][j]
        for i in range(j + 1, k):
            acc = a[i, j] * d[i] * d[j]
            for p in range(j):
                acc = acc - low[i][p] * low[j][p]
            low[i][j] = acc * inv
    return low, d


def cho_solve(a, b):
    """Solve ``a x = b`` for ``a`` ``(k, k, B)`` symmetric positive definite,
    ``b`` ``(k, r, B)``: :func:`cholesky`, then two substitutions per column,
    about ``k^3 / 6 + k^2 r`` element-wise operations over the lanes.  Not
    positive definite -> NaN."""
    k, r = a.shape[0], b.shape[1]
    low, d = cholesky(a)
    cols = []
    for c in range(r):
        y = [None] * k
        for i in range(k):  # L y = D b
            acc = b[i, c] * d[i]
            for p in range(i):
                acc = acc - low[i][p] * y[p]
            y[i] = acc / low[i][i]
        x = [None] * k
        for i in reversed(range(k)):  # L^T x = y
            acc = y[i]
            for p in range(i + 1, k):
                acc = acc - low[p][i] * x[p]
            x[i] = acc / low[i][i]
        cols.append(jnp.stack([x[i] * d[i] for i in range(k)]))
    # A barrier: XLA would otherwise fuse the whole factorisation into each consumer and recompute
    # it for every element that reads the solution (measured: the precision step 6x slower).
    return jax.lax.optimization_barrier(jnp.stack(cols, axis=1))


def inverse_factor(a):
    """``M = L^-1 D`` ``(k, k, B)`` (lower triangular) of :func:`cholesky`,
    so that ``a^-1 = M^T M`` and ``u^T a^-1 u = |M u|^2``: the cofactor
    matrix and the redundancy numbers of an adjustment come from the factor
    without solving for ``k`` right-hand sides.  Forward substitution on the
    unit vectors, unrolled (``k^3 / 6`` operations over the lanes)."""
    k = a.shape[0]
    low, d = cholesky(a)
    zero = jnp.zeros_like(d[0])
    inv = [[zero] * k for _ in range(k)]  # inv[i][j] = (L^-1)[i, j]
    for j in range(k):
        inv[j][j] = 1.0 / low[j][j]
        for i in range(j + 1, k):
            acc = low[i][j] * inv[j][j]
            for p in range(j + 1, i):
                acc = acc + low[i][p] * inv[p][j]
            inv[i][j] = -acc / low[i][i]
    m = jnp.stack([jnp.stack([inv[i][j] * d[j] if j <= i else zero for j in range(k)]) for i in range(k)])
    return jax.lax.optimization_barrier(m)  # as in cho_solve: computed once, not fused into each consumer


def sel(mask, x, y):
    """``where(mask, x, y)`` for a per-lane ``mask`` ``(B,)`` and ``x``, ``y`` ``(..., B)``."""
    x = jnp.asarray(x)
    return jnp.where(mask.reshape((1,) * (x.ndim - 1) + mask.shape), x, y)


def lane(s, ndim: int):
    """A per-lane ``(B,)`` array shaped to broadcast against ``(..., B)`` arrays of ``ndim`` axes."""
    return s.reshape((1,) * (ndim - 1) + s.shape)


def rt_times(rot, v):
    """``R^T v`` per lane: ``rot`` ``(3, 3, B)``, ``v`` ``(3, ..., B)`` -> ``(3, ..., B)``."""
    extra = (None,) * (v.ndim - 2)
    return sum(rot[i][(slice(None),) + extra] * v[i][None] for i in range(3))


def cross(a, b):
    """Cross product over the first axis (lanes and any middle axes broadcast)."""
    return jnp.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def matmul3(a, b):
    """``a @ b`` per lane for ``(3, 3, B)`` matrices (``b`` may be ``(3, B)``: a vector)."""
    if b.ndim == 2:
        return jnp.stack([sum(a[i, k] * b[k] for k in range(3)) for i in range(3)])
    return jnp.stack([jnp.stack([sum(a[i, k] * b[k, j] for k in range(3)) for j in range(3)]) for i in range(3)])


def inv3(m):
    """Inverse of ``(3, 3, B)`` matrices by cofactors (as :func:`photax._linalg.inv3`)."""
    adj = jnp.stack([cross(m[:, 1], m[:, 2]), cross(m[:, 2], m[:, 0]), cross(m[:, 0], m[:, 1])])
    return adj / lane(jnp.sum(m[:, 0] * adj[0], axis=0), 3)


def nearest_rotation(m, iterations: int = 8):
    """Orthogonal polar factor of ``(3, 3, B)`` matrices with ``det > 0`` (as
    :func:`photax._linalg.nearest_rotation`: Newton's ``Q <- (Q + Q^-T)/2``)."""
    det = jnp.sum(m[:, 0] * cross(m[:, 1], m[:, 2]), axis=0)
    q = m / lane(jnp.cbrt(jnp.abs(det)), 3)
    return jax.lax.fori_loop(0, iterations, lambda _, q: 0.5 * (q + jnp.swapaxes(inv3(q), 0, 1)), q)


def _spd_solve_lapack(a, b):
    """``a x = b`` for ``(k, k, B)`` SPD ``a`` and ``(k, B)`` ``b`` by LAPACK, one
    matrix per lane (:func:`photax._linalg.cho_solve`; for the larger
    systems, where unrolling would cost compile time)."""
    from .._linalg import cho_solve as lapack

    return lapack(jnp.transpose(a, (2, 0, 1)), b.T[:, :, None])[:, :, 0].T


# From this many lanes on (resect_batch's large chunks), :func:`solve_spd` unrolls; below it LAPACK.
UNROLL_LANES = 1024


def solve_spd(a, b):
    """``a x = b`` for ``(k, k, B)`` SPD ``a`` and ``(k, B)`` ``b``: unrolled
    (:func:`cho_solve`) for a batch of ``UNROLL_LANES`` or more, LAPACK
    (:func:`_spd_solve_lapack`) below.  Measured on 1,024 lanes: 0.20 / 0.42 us per
    lane for k = 8 / 11 unrolled, 0.85 / 1.64 by LAPACK; but unrolled, the
    two linear-start systems double the cheap path's compilation (6.4 vs
    3.1 s CPU), which only a large batch wins back."""
    if a.shape[-1] >= UNROLL_LANES:
        return cho_solve(a, b[:, None])[:, 0]
    return _spd_solve_lapack(a, b)
