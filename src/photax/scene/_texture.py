"""The ground texture every synthetic scene is painted with.

A function of local ground ``(x, y)`` (metres from the scene's origin), so an
image rendered through the collinearity model over a DEM shows relief
displacement as bent roads, and the "perfect orthophoto" is the texture
sampled on the ground grid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


@jax.jit
def texture(x, y):
    """Ground texture at local ground offsets ``(x, y)`` (metres), in [0, 1].

    A 500 m checkerboard (two greys), dark 12 m roads every 250 m with
    smooth edges (so the rendered image is not aliased) and a 37 m ripple.
    """
    checker = 0.5 + 0.12 * jnp.sign(jnp.sin(jnp.pi * x / 500.0) * jnp.sin(jnp.pi * y / 500.0))
    ripple = 0.08 * jnp.sin(2 * jnp.pi * (x + 0.6 * y) / 37.0)
    # distance to the nearest road centre line (roads along x = k 250, y = k 250)
    dx = jnp.abs((x + 125.0) % 250.0 - 125.0)
    dy = jnp.abs((y + 125.0) % 250.0 - 125.0)
    road = jax.nn.sigmoid((6.0 - jnp.minimum(dx, dy)) / 1.5)
    return jnp.clip((checker + ripple) * (1.0 - road) + 0.08 * road, 0.0, 1.0)


_texture = jax.jit(texture)


# Plane waves (wavelength m, direction deg) of :func:`detailed_texture`: incommensurate, so their sum has
# gradients in every direction at every place (a least-squares matcher needs both; the ripple of
# :func:`texture` alone runs one way).
_WAVES = ((5.3, 17.0), (7.1, 71.0), (9.7, 133.0), (4.3, 101.0), (12.9, 163.0), (6.1, 41.0))


def detailed_texture(x, y):
    """:func:`texture` with fine two-dimensional detail (metre-scale waves), in [0, 1].

    For rendered images that are matched (epipolar pairs, tie points):
    ``texture + 0.07 sum_k sin(2 pi (x cos a_k + y sin a_k) / l_k)``, clipped.
    """
    d = 0.0
    for lam, deg in _WAVES:
        a = jnp.deg2rad(deg)
        d = d + jnp.sin(2 * jnp.pi * (x * jnp.cos(a) + y * jnp.sin(a)) / lam)
    return jnp.clip(texture(x, y) + 0.07 * d, 0.0, 1.0)
