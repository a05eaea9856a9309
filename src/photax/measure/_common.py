"""Input checking shared by the measurement operators.

Images are ``(h, w)`` or a batch ``(b, h, w)``; rows down, columns right,
the centre of the top-left pixel at (0, 0) (docs/conventions.md).  Any
integer, boolean or float dtype is accepted and converted to float64
*without rescaling* (grey values keep their units; thresholds are in the
same units).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np


def as_image(image, name: str = "image", *, min_size: int = 1, convert: bool = True) -> tuple[jax.Array, bool]:
    """``image`` as a float64 JAX array and whether it is a batch.

    ``convert=False`` leaves the dtype alone, for jitted callers that cast
    inside (the cast then fuses with the first filter instead of writing a
    float64 copy of the image).

    Raises ``ValueError`` naming ``name`` for a wrong rank, a non-numeric
    dtype or an image smaller than ``min_size`` pixels on a side.
    """
    dtype = getattr(image, "dtype", None)
    if dtype is None:
        image = np.asarray(image)
        dtype = image.dtype
    if not (
        jnp.issubdtype(dtype, jnp.integer) or jnp.issubdtype(dtype, jnp.floating) or np.issubdtype(dtype, np.bool_)
    ):
        raise ValueError(f"{name}: expected an integer, boolean or float image, got dtype {dtype}")
    ndim = len(image.shape)
    if ndim not in (2, 3):
        raise ValueError(f"{name}: expected shape (h, w) or a batch (b, h, w), got shape {tuple(image.shape)}")
    h, w = image.shape[-2:]
    if h < min_size or w < min_size:
        raise ValueError(f"{name}: image of shape {tuple(image.shape)} is smaller than {min_size} x {min_size} pixels")
    arr = jnp.asarray(image)
    return (arr.astype(jnp.float64) if convert else arr), ndim == 3


def batched(fn2d: Callable, image: jax.Array, is_batch: bool):
    """Apply a single-image function to an image or, with ``vmap``, a batch."""
    return jax.vmap(fn2d)(image) if is_batch else fn2d(image)


def check_odd_window(window: int, name: str = "window") -> int:
    if int(window) != window or window < 3 or window % 2 == 0:
        raise ValueError(f"{name}: expected an odd integer >= 3, got {window!r}")
    return int(window)


def inner_mask(shape: tuple[int, int], margin: int) -> jax.Array:
    """True at least ``margin`` pixels inside the image border.  Built from
    iotas so XLA does not constant-fold an (h, w) array into the program."""
    h, w = shape
    r = jax.lax.broadcasted_iota(jnp.int32, (h, w), 0)
    c = jax.lax.broadcasted_iota(jnp.int32, (h, w), 1)
    return (r >= margin) & (r < h - margin) & (c >= margin) & (c < w - margin)
