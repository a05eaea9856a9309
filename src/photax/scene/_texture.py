"""The ground texture every synthetic scene is painted with.

A function of local ground ``(x, y)`` (metres from the scene's origin), so an
image rendered through the collinearity model over a DEM shows relief
displacement as bent roads, and the "perfect orthophoto" is the texture
sampled on the ground grid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


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
