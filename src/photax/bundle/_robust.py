"""Robust losses of the bundle adjustment: ``rho`` and its derivatives, and
Ceres' corrector (the robustified residual and Jacobian).  Jitted by their
callers (:func:`photax.bundle._linearise._linearise` and the point pass of
:mod:`photax.bundle._solver`)."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

#: The loss as a traced code, so that changing it does not recompile.
_LOSS_CODE = {"none": 0, "huber": 1, "cauchy": 2}


def _rho(sq: Array, loss: Array, scale: Array) -> tuple[Array, Array, Array]:
    """Loss ``rho(s)``, ``rho'(s)`` and ``rho''(s)`` for squared norms ``s``;
    ``loss`` is a traced code (0 none, 1 Huber, 2 Cauchy) so changing it
    does not recompile.  Huber outside ``d^2``: ``rho' = d / sqrt(s)``,
    ``rho'' = -rho' / (2 s)``; Cauchy: ``rho' = 1 / (1 + s/d^2)``,
    ``rho'' = -rho'^2 / d^2`` (Ceres' ``HuberLoss``, ``CauchyLoss``)."""
    d2 = scale * scale
    root = jnp.sqrt(jnp.maximum(sq, d2))
    inside = sq <= d2
    h1 = jnp.where(inside, 1.0, scale / root)
    huber = (jnp.where(inside, sq, 2.0 * scale * root - d2), h1, jnp.where(inside, 0.0, -0.5 * h1 / root**2))
    c1 = 1.0 / (1.0 + sq / d2)
    cauchy = (d2 * jnp.log1p(sq / d2), c1, -c1 * c1 / d2)
    rho = jnp.select([loss == 1, loss == 2], [huber[0], cauchy[0]], sq)
    drho = jnp.select([loss == 1, loss == 2], [huber[1], cauchy[1]], jnp.ones_like(sq))
    d2rho = jnp.select([loss == 1, loss == 2], [huber[2], cauchy[2]], jnp.zeros_like(sq))
    return rho, drho, d2rho


def _corrector(r: Array, rho1: Array, rho2: Array) -> tuple[Array, Array]:
    """Ceres' robustified residual and Jacobian (``internal/ceres/
    corrector.cc``; Triggs et al. 2000, "Bundle adjustment — a modern
    synthesis", sec. 4.3) for ``(k, 2)`` residuals.

    With ``s = |r|^2``, the Hessian of ``0.5 rho(s)`` w.r.t. the residual is
    ``rho' I + 2 rho'' r r^T``: ``rho'`` across ``r`` and ``rho' D`` along it,
    ``D = 1 + 2 s rho''/rho'``.  Where ``rho'' > 0`` (``D > 1``) its square
    root is ``sqrt(rho') (I - alpha r r^T / s)`` with ``1 - alpha = sqrt(D)``::

        J~ = sqrt(rho') (I - alpha r r^T / s) J,   r~ = sqrt(rho') r / (1 - alpha)

    so ``J~^T r~ = rho' J^T r`` (the exact gradient) and ``J~^T J~`` the
    Gauss–Newton Hessian of the loss.  Where ``rho'' <= 0`` (Huber beyond its
    scale, Cauchy everywhere) ``D <= 1`` can be 0 or negative, the exact
    per-residual Hessian singular or indefinite, and Ceres reweights only:
    ``alpha = 0``, ``J~ = sqrt(rho') J``.  That model overestimates the
    curvature along ``r`` (by ``1/D``) and so majorises the loss along each
    residual: its step never pushes a residual through zero, the safe side.
    What it gets wrong (flat directions of points whose residuals lie beyond
    the scale) the solver's point pass takes care of (see
    :mod:`photax.bundle._solver`).

    Returns ``(sqrt(rho'), alpha / s)``, ``(k,)`` each; ``alpha / s`` is 0
    unless ``rho'' > 0`` (so for least squares, Huber and Cauchy)."""
    sq = jnp.sum(r * r, axis=1)
    convex = (rho2 > 0.0) & (sq > 0.0)
    alpha = 1.0 - jnp.sqrt(jnp.where(convex, 1.0 + 2.0 * sq * rho2 / rho1, 1.0))
    alpha_sq = jnp.where(convex, alpha / jnp.where(convex, sq, 1.0), 0.0)
    return jnp.sqrt(rho1), alpha_sq
