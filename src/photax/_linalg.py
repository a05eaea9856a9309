"""Small dense linear algebra shared by resection and bundle adjustment:
3x3 inverses by the adjugate (elementwise, vectorises under ``vmap``),
the nearest rotation, and a Jacobi-scaled Cholesky solve.

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def inv3(m: jax.Array) -> jax.Array:
    """Inverse of one ``(3, 3)`` matrix by cofactors: ``adj(m) / det(m)``."""
    adj = jnp.stack([jnp.cross(m[:, 1], m[:, 2]), jnp.cross(m[:, 2], m[:, 0]), jnp.cross(m[:, 0], m[:, 1])])
    return adj / jnp.sum(m[:, 0] * adj[0])


def nearest_rotation(m: jax.Array, iterations: int = 8) -> jax.Array:
    """Orthogonal polar factor of one ``(3, 3)`` matrix with ``det > 0``, by
    Newton's iteration ``Q <- (Q + Q^-T)/2`` (Higham 1986); quadratic once
    close, so 8 steps reach rounding level from a linear estimate.  A
    ``fori_loop``, traced once: unrolled, it cost compile time."""
    q = m / jnp.cbrt(jnp.abs(jnp.sum(m[:, 0] * jnp.cross(m[:, 1], m[:, 2]))))
    return jax.lax.fori_loop(0, iterations, lambda _, q: 0.5 * (q + inv3(q).T), q)


def cho_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve ``a x = b``, ``a`` ``(..., k, k)`` symmetric positive definite,
    ``b`` ``(..., k, r)``: Jacobi-scaled (unit diagonal: metres and radians in
    one matrix), then LAPACK's Cholesky.  Not positive definite -> NaN (the
    caller tests ``isfinite``).

    An element-by-element factor (tried: it fuses under ``vmap``) made XLA
    spend about two thirds of the resection's compile time on the 11x11 and
    6x6 systems (sample: 19.8 s -> 8.7 s CPU for both compiled paths); the
    LAPACK call costs microseconds at run time instead.
    """
    d = 1.0 / jnp.sqrt(jnp.diagonal(a, axis1=-2, axis2=-1))
    low = jnp.linalg.cholesky(a * d[..., :, None] * d[..., None, :])
    return jax.scipy.linalg.cho_solve((low, True), b * d[..., :, None]) * d[..., :, None]


def solve2(m: jax.Array, b: jax.Array) -> jax.Array:
    """``m^-1 b`` for one ``(2, 2)`` matrix by Cramer's rule: no LAPACK call, so a program using it
    loads without JAX's LAPACK initialisation (photax._aot); singular ``m`` -> inf or NaN."""
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    return jnp.stack([m[1, 1] * b[0] - m[0, 1] * b[1], m[0, 0] * b[1] - m[1, 0] * b[0]]) / det
