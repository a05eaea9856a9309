"""Convolution, Gaussian and gradient helpers (JAX, float64).

Border modes follow ``scipy.ndimage`` (``"reflect"`` = d c b a | a b c d,
``"mirror"`` = d c b | a b c d, ``"nearest"``, ``"wrap"``, ``"constant"``),
so every operator can be compared with scipy/scikit-image value by value.
Filters are written as sums of shifted slices of a padded image: XLA fuses
them into one loop, which on CPU is faster than ``conv_general_dilated``
for the small kernels used here.
"""

from __future__ import annotations

import math
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from ._common import as_image, batched

Mode = Literal["reflect", "mirror", "nearest", "wrap", "constant"]
_NP_MODE = {"reflect": "symmetric", "mirror": "reflect", "nearest": "edge", "wrap": "wrap", "constant": "constant"}


def pad(image: jax.Array, widths, mode: Mode = "reflect", cval: float = 0.0) -> jax.Array:
    """``jnp.pad`` with scipy.ndimage's border-mode names."""
    if mode not in _NP_MODE:
        raise ValueError(f"mode: expected one of {sorted(_NP_MODE)}, got {mode!r}")
    if mode == "constant":
        return jnp.pad(image, widths, mode="constant", constant_values=cval)
    if mode == "reflect" and max(max(w) for w in widths) <= 1:
        mode = "nearest"  # one pixel of symmetric padding repeats the edge pixel
    if mode != "nearest":
        # Materialise the padded copy: fused into the stencil that reads it, XLA's
        # CPU backend recomputes the non-constant padding per tap (measured 3-8x
        # slower for a 3 x 3 Sobel on 1024 x 1024).
        return jax.lax.optimization_barrier(jnp.pad(image, widths, mode=_NP_MODE[mode]))
    # jnp.pad's "edge" mode is a concatenate of broadcasts that XLA:CPU runs 5-10x
    # slower than a constant pad (2048 x 2048 float32: 10-20 ms instead of 1.8,
    # measured; its "symmetric" mode, reversed slices, is not slow): a constant pad
    # with the border strips written into it.  The padded image is image[rows][:, cols]
    # with numpy's own index maps; each strip is taken from the image, not from the
    # padded copy, so the writes are in place (reading the copy made XLA copy it).
    rows, cols = (np.pad(np.arange(n), w, mode=_NP_MODE[mode]) for n, w in zip(image.shape, widths))
    (a, b), (c, d) = widths
    h, w = image.shape
    p = jnp.pad(image, widths)
    strips = [
        (0, 0, rows[:a], cols),
        (a + h, 0, rows[a + h :], cols),
        (a, 0, rows[a : a + h], cols[:c]),
        (a, c + w, rows[a : a + h], cols[c + w :]),
    ]
    for r0, c0, ri, ci in strips:
        if len(ri) and len(ci):
            p = jax.lax.dynamic_update_slice(p, _take(_take(image, ri, 0), ci, 1), (r0, c0))
    return jax.lax.optimization_barrier(p)


def _take(x, idx: np.ndarray, axis: int):
    """``x`` at the static indices ``idx`` along ``axis``: a slice (reversed or
    not) where they run by one, which XLA fuses, a gather otherwise."""
    step = np.diff(idx)
    if np.all(step == 1):
        return jax.lax.slice_in_dim(x, int(idx[0]), int(idx[-1]) + 1, axis=axis)
    if np.all(step == -1):
        return jax.lax.rev(jax.lax.slice_in_dim(x, int(idx[-1]), int(idx[0]) + 1, axis=axis), (axis,))
    return jnp.take(x, jnp.asarray(idx), axis=axis)


def correlate1d(
    image: jax.Array,
    weights,
    axis: int,
    mode: Mode | Literal["valid"] = "reflect",
    cval: float = 0.0,
    origin: int = 0,
    dtype=jnp.float64,
) -> jax.Array:
    """``scipy.ndimage.correlate1d`` on a 2-D image: ``out[i] = sum_j w[j] in[i + j - c]``
    with ``c = len(w) // 2 + origin``.  ``weights`` are static (numpy).

    ``mode="valid"`` pads nothing and returns only the positions whose taps
    all lie inside the image (``len(w) - 1`` fewer along ``axis``), as
    ``numpy.correlate(..., "valid")``: what the locators need on a patch that
    already carries its margin.  ``dtype``: what an integer image is
    converted to (a float image keeps its own)."""
    weights = np.asarray(weights, dtype=np.float64)
    n = len(weights)
    if mode == "valid":
        p, size = image, image.shape[axis] - n + 1
        if size < 1:
            raise ValueError(f"image: {image.shape[axis]} px along axis {axis} is less than the kernel's {n}")
    else:
        c = n // 2 + origin
        if mode == "constant" and cval != 0.0:
            image = image.astype(jnp.promote_types(image.dtype, dtype))  # cval need not be an integer grey value
        widths = [(0, 0), (0, 0)]
        widths[axis] = (c, n - 1 - c)
        p = pad(image, widths, mode, cval)
        size = image.shape[axis]
    if not jnp.issubdtype(p.dtype, jnp.floating):  # an integer image is padded as it is, converted here (fused)
        p = p.astype(dtype)

    out = None
    for j, wj in enumerate(weights):
        if wj == 0.0:
            continue
        term = jax.lax.slice_in_dim(p, j, j + size, axis=axis) * float(wj)  # a Python float keeps the image's dtype
        out = term if out is None else out + term
    if out is None:
        return jnp.zeros_like(jax.lax.slice_in_dim(p, 0, size, axis=axis))
    return out


def correlate2d(image: jax.Array, kernel, mode: Mode = "reflect", cval: float = 0.0, origin=(0, 0)) -> jax.Array:
    """``scipy.ndimage.correlate`` on a 2-D image with a small static kernel."""
    kernel = np.asarray(kernel, dtype=np.float64)
    kh, kw = kernel.shape
    cr, cc = kh // 2 + origin[0], kw // 2 + origin[1]
    p = pad(image, [(cr, kh - 1 - cr), (cc, kw - 1 - cc)], mode, cval)
    h, w = image.shape
    out = None
    for i in range(kh):
        for j in range(kw):
            if kernel[i, j] == 0.0:
                continue
            term = p[i : i + h, j : j + w] * float(kernel[i, j])
            out = term if out is None else out + term
    return jnp.zeros_like(image) if out is None else out


def convolve2d(image: jax.Array, kernel, mode: Mode = "reflect", cval: float = 0.0) -> jax.Array:
    """``scipy.ndimage.convolve``: correlation with the flipped kernel; for an
    even kernel side scipy moves the origin by one, done the same here."""
    kernel = np.asarray(kernel, dtype=np.float64)[::-1, ::-1]
    origin = tuple(-1 if s % 2 == 0 else 0 for s in kernel.shape)
    return correlate2d(image, kernel, mode, cval, origin)


def gaussian_kernel1d(sigma: float, order: int = 0, truncate: float = 4.0) -> np.ndarray:
    """Sampled Gaussian (or its ``order``-th derivative), normalised so the
    order-0 weights sum to 1, radius ``int(truncate * sigma + 0.5)``: the
    kernel of ``scipy.ndimage.gaussian_filter1d``."""
    if not sigma > 0:
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    p = np.polynomial.Polynomial([0, 0, -0.5 / (sigma * sigma)])
    phi = np.exp(p(x))
    phi /= phi.sum()
    q = np.polynomial.Polynomial([1])
    for _ in range(order):
        q = q.deriv() + q * p.deriv()
    return (q(x) * phi)[::-1]  # gaussian_filter1d reverses the kernel before correlating


def gaussian(
    image: jax.Array, sigma: float, mode: Mode = "reflect", cval: float = 0.0, truncate: float = 4.0, dtype=jnp.float64
) -> jax.Array:
    """Separable Gaussian smoothing of a 2-D image (``scipy.ndimage.gaussian_filter``);
    ``dtype`` as :func:`correlate1d`."""
    k = gaussian_kernel1d(sigma, 0, truncate)
    return correlate1d(correlate1d(image, k, 0, mode, cval, dtype=dtype), k, 1, mode, cval, dtype=dtype)


def sobel_raw(image: jax.Array, axis: int, mode: Mode = "reflect", cval: float = 0.0) -> jax.Array:
    """``scipy.ndimage.sobel``: unnormalised, 8 x the derivative along ``axis``
    (0 = rows, 1 = columns)."""
    return sobel_pair(image, mode, cval, smooth=(1.0, 2.0, 1.0))[axis]


def sobel_pair(
    image: jax.Array, mode: Mode | Literal["valid"] = "reflect", cval: float = 0.0, smooth=(1.0, 2.0, 1.0), dtype=None
):
    """``(d_rows, d_cols)``: ``[-1 0 1]`` along the axis times ``smooth``
    across it, from one padded copy so XLA fuses both into a single pass;
    computed in ``dtype`` (None: float64, or the image's own float type for
    ``mode="valid"``, which pads nothing and returns the ``(h - 2, w - 2)``
    inner pixels)."""
    if mode == "valid":
        h, w = image.shape[0] - 2, image.shape[1] - 2
        p = image if dtype is None and jnp.issubdtype(image.dtype, jnp.floating) else image.astype(dtype or jnp.float64)
        return _sobel_taps(p, h, w, smooth)
    dtype = dtype or jnp.float64
    h, w = image.shape
    # an integer image is padded as it is (a quarter of the float64 copy's bytes) and
    # converted inside the fused stencil
    if mode == "constant" and cval != 0.0:
        image = image.astype(jnp.promote_types(image.dtype, dtype))  # cval is not an integer grey value
    p = pad(image, [(1, 1), (1, 1)], mode, cval).astype(dtype)
    return _sobel_taps(p, h, w, smooth)


def _sobel_taps(p, h, w, smooth):
    def s(dr, dc):
        return p[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]

    a, b, c = smooth
    d_rows = a * (s(1, -1) - s(-1, -1)) + b * (s(1, 0) - s(-1, 0)) + c * (s(1, 1) - s(-1, 1))
    d_cols = a * (s(-1, 1) - s(-1, -1)) + b * (s(0, 1) - s(0, -1)) + c * (s(1, 1) - s(1, -1))
    return d_rows, d_cols


def derivative_of_gaussian(sigma: float, truncate: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Correlation weights ``(g, d)`` of a sampled Gaussian of ``sigma`` px and
    of its derivative, radius ``ceil(truncate * sigma)``.  ``g`` sums to 1;
    ``d(t) = t g(t) / sum(t^2 g(t))`` is scaled so that a unit ramp has
    gradient exactly 1 (``sum_t d(t) (x + t) = 1``), so the gradient is in grey
    values per pixel whatever ``sigma`` (scipy's order-1 kernel is the
    derivative of the continuous Gaussian instead, ~1 % off for sigma ~ 1)."""
    if not sigma > 0:
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    m = math.ceil(truncate * float(sigma))
    t = np.arange(-m, m + 1, dtype=np.float64)
    g = np.exp(-(t**2) / (2.0 * sigma**2))
    g /= g.sum()
    d = t * g
    d /= np.sum(d * t)
    return g, d


def gradient_margin(method: str, sigma: float = 1.0) -> int:
    """Pixels lost on each side by ``gradient(..., mode="valid")``."""
    return math.ceil(3.0 * float(sigma)) if method == "gaussian" else 1


_SMOOTH = {"sobel": np.array([1.0, 2.0, 1.0]) / 4.0, "prewitt": np.array([1.0, 1.0, 1.0]) / 3.0}


def _gradient2d(image, method, mode, sigma=1.0):
    """``(gx, gy)`` of one 2-D image; ``mode="valid"`` crops the margin instead of padding."""
    if method == "sobel" and mode != "valid":
        gy, gx = sobel_pair(image, mode)  # one padded copy, one fused pass
        return gx / 8.0, gy / 8.0
    if method in _SMOOTH:
        diff, smooth = np.array([-0.5, 0.0, 0.5]), _SMOOTH[method]
    elif method == "central":
        diff, smooth = np.array([-0.5, 0.0, 0.5]), None
    elif method == "gaussian":
        smooth, diff = derivative_of_gaussian(sigma)
    else:
        raise ValueError(f"method: expected 'sobel', 'prewitt', 'central' or 'gaussian', got {method!r}")
    if smooth is None:
        if mode == "valid":  # the other axis loses its margin too, so gx and gy share a shape
            return (correlate1d(image[1:-1, :], diff, 1, mode), correlate1d(image[:, 1:-1], diff, 0, mode))
        return correlate1d(image, diff, 1, mode), correlate1d(image, diff, 0, mode)
    # Materialise the first pass (padding does it in the other modes): fused, XLA
    # would recompute it for every tap of the second, len(smooth) x the work.
    first = jax.lax.optimization_barrier((correlate1d(image, diff, 1, mode), correlate1d(image, diff, 0, mode)))
    return correlate1d(first[0], smooth, 0, mode), correlate1d(first[1], smooth, 1, mode)


def gradient(
    image,
    method: Literal["sobel", "prewitt", "central", "gaussian"] = "sobel",
    *,
    sigma: float = 1.0,
    mode: Mode | Literal["valid"] = "reflect",
):
    """Image gradient ``(gx, gy)``: derivatives along columns (x, right) and
    rows (y, down), in grey values per pixel, at the pixel centres.

    The one gradient of ``photax.measure``: the corner locator uses
    ``"gaussian"`` and the matchers ``"central"`` (through :func:`_gradient2d`).

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype.
        method: ``"sobel"`` (``[-1 0 1]/2`` times ``[1 2 1]/4`` across),
            ``"prewitt"`` (``[-1 0 1]/2`` times ``[1 1 1]/3``),
            ``"central"`` (``(g[c+1] - g[c-1]) / 2``, no smoothing) or
            ``"gaussian"`` (derivative of a sampled Gaussian of ``sigma`` px
            along the axis, the Gaussian across it, radius ``ceil(3 sigma)``;
            see :func:`derivative_of_gaussian`).  Only ``"gaussian"`` is
            isotropic enough for sub-pixel work on rotated edges.
        sigma: px, for ``"gaussian"`` only.
        mode: border handling, scipy.ndimage names; or ``"valid"``: no
            padding, the result is ``gradient_margin(method, sigma)`` px
            smaller on every side.

    Returns:
        ``(gx, gy)``, each float64 of the shape of ``image`` (smaller for
        ``"valid"``).  A linear ramp ``g = a c + b r`` gives exactly
        ``(a, b)`` away from the border, for every method.

    Examples:
        Derivatives along columns and rows of a plane ``g = 3 col - 2 row`` (grey levels per pixel):

        >>> import numpy as np
        >>> from photax.measure import gradient
        >>> r, c = np.mgrid[0:8, 0:8].astype(float)
        >>> gx, gy = gradient(3.0 * c - 2.0 * r)
        >>> print(np.round(np.asarray(gx)[4, 4], 6), np.round(np.asarray(gy)[4, 4], 6))
        3.0 -2.0
    """
    img, is_batch = as_image(image)
    return batched(lambda im: _gradient2d(im, method, mode, sigma), img, is_batch)


def max_filter(image: jax.Array, size: int) -> jax.Array:
    """Maximum over a ``size`` x ``size`` window centred on each pixel;
    outside the image counts as -inf."""
    r = size // 2
    return jax.lax.reduce_window(
        image, -jnp.inf, jax.lax.max, (size, size), (1, 1), [(r, size - 1 - r), (r, size - 1 - r)]
    )


def box_sum(image: jax.Array, size: int, mode: Mode = "constant") -> jax.Array:
    """Sum over a ``size`` x ``size`` window centred on each pixel (odd size)."""
    ones = np.ones(size)
    return correlate1d(correlate1d(image, ones, 0, mode), ones, 1, mode)
