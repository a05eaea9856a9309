"""Edge operators: Roberts, Sobel, Prewitt, Laplace, Laplacian of Gaussian
(with zero crossings) and Canny.

Scales and border modes are those of scikit-image (``skimage.filters``,
``skimage.feature.canny``) so the responses can be compared value by value,
except that integer images are *not* rescaled to [0, 1]: photax keeps grey
values in their own units (thresholds too).  Course notes: seed 004,
"线特征提取算子"; Canny, IEEE TPAMI 8 (1986) 679-714.
"""

from __future__ import annotations

from functools import partial
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
import scipy.ndimage as ndi

from ._common import as_image, batched, inner_mask
from ._filters import Mode, convolve2d, correlate1d, gaussian, gaussian_kernel1d, pad, sobel_pair

_SQRT2 = float(np.sqrt(2.0))


def _edge_magnitude(image, edge, smooth, mode):
    # edge = [-1, 0, 1] in scipy's correlate sense (convolve with [1, 0, -1])
    gy, gx = sobel_pair(image, mode, smooth=smooth)
    return jnp.sqrt(gx * gx + gy * gy) / _SQRT2


@partial(jax.jit, static_argnames=("mode",))
def _sobel(img, mode):
    return _edge_magnitude(img, [-1.0, 0.0, 1.0], [0.25, 0.5, 0.25], mode)


@partial(jax.jit, static_argnames=("mode",))
def _prewitt(img, mode):
    return _edge_magnitude(img, [-1.0, 0.0, 1.0], [1 / 3, 1 / 3, 1 / 3], mode)


def sobel(image, *, mode: Mode = "reflect"):
    """Sobel edge magnitude.

    ``sqrt((Gx^2 + Gy^2) / 2)`` with ``G = [1 0 -1] x [1 2 1]/4`` along and
    across the axis (seed 004, Sobel 算子; the scale of
    ``skimage.filters.sobel``).

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype.
        mode: border mode (scipy.ndimage names), scikit-image's default.

    Returns:
        float64 magnitude of the shape of ``image``: ``sqrt(2) |grad g|``
        (grey values per pixel) on a linear ramp.

    Examples:
        On a ramp of 2 grey levels per column the magnitude is ``sqrt(2) |grad g| = 2 sqrt(2)``:

        >>> import numpy as np
        >>> from photax.measure import sobel
        >>> print(np.round(np.asarray(sobel(np.tile(2.0 * np.arange(8.0), (6, 1))))[3, 2:6], 6))  # 2 sqrt(2)
        [2.828427 2.828427 2.828427 2.828427]
    """
    img, b = as_image(image, convert=False)
    return _sobel(img, mode) if not b else jax.vmap(lambda i: _sobel(i, mode))(img)


def prewitt(image, *, mode: Mode = "reflect"):
    """Prewitt edge magnitude ``sqrt((Gx^2 + Gy^2) / 2)``, ``G = [1 0 -1] x
    [1 1 1]/3`` (seed 004; the scale of ``skimage.filters.prewitt``).
    Shapes as :func:`sobel`.

    Examples:
        The same ramp as :func:`sobel`'s example, Prewitt's weights:

        >>> import numpy as np
        >>> from photax.measure import prewitt
        >>> print(np.round(np.asarray(prewitt(np.tile(2.0 * np.arange(8.0), (6, 1))))[3, 2:6], 6))  # 2 sqrt(2)
        [2.828427 2.828427 2.828427 2.828427]
    """
    img, b = as_image(image, convert=False)
    return _prewitt(img, mode) if not b else jax.vmap(lambda i: _prewitt(i, mode))(img)


@jax.jit
def _roberts(img):
    pos = convolve2d(img, [[1.0, 0.0], [0.0, -1.0]], "reflect")
    neg = convolve2d(img, [[0.0, 1.0], [-1.0, 0.0]], "reflect")
    return jnp.sqrt((pos * pos + neg * neg) / 2.0)


def roberts(image):
    """Roberts cross edge magnitude ``sqrt((d1^2 + d2^2) / 2)`` with
    ``d1 = g[r, c] - g[r+1, c+1]`` and ``d2 = g[r, c+1] - g[r+1, c]``, the
    2 x 2 kernels of seed 004 as ``skimage.filters.roberts`` applies them
    (``scipy.ndimage.convolve``, mode ``"reflect"``).  The difference
    belongs to the half-pixel position (c + 1/2, r + 1/2) and is stored at
    pixel (c, r).  Shapes as :func:`sobel`.

    Examples:
        On a ramp of 3 grey levels per column both diagonal differences are 3 in size, so the
        magnitude ``sqrt((d1^2 + d2^2) / 2)`` is 3:

        >>> import numpy as np
        >>> from photax.measure import roberts
        >>> print(np.round(np.asarray(roberts(np.tile(3.0 * np.arange(6.0), (5, 1))))[2, 1:4], 6))
        [3. 3. 3.]
    """
    img, b = as_image(image)
    return batched(_roberts, img, b)


@partial(jax.jit, static_argnames=("mode",))
def _laplace(img, mode):
    return convolve2d(img, [[0.0, -1.0, 0.0], [-1.0, 4.0, -1.0], [0.0, -1.0, 0.0]], mode)


def laplace(image, *, mode: Mode = "reflect"):
    """Laplace operator ``4 g[r, c] - g[r-1, c] - g[r+1, c] - g[r, c-1] -
    g[r, c+1]`` (seed 004, 拉普拉斯算子; ``skimage.filters.laplace`` with
    ``ksize=3``: note the sign, minus the second derivative).
    Shapes as :func:`sobel`.

    Examples:
        Minus the Laplacian: on ``x**2 + y**2`` it is -4 everywhere inside:

        >>> import numpy as np
        >>> from photax.measure import laplace
        >>> r, c = np.mgrid[0:7, 0:7].astype(float)
        >>> print(np.round(np.asarray(laplace(c**2 + r**2))[2:5, 3], 6))
        [-4. -4. -4.]
    """
    img, b = as_image(image)
    return _laplace(img, mode) if not b else jax.vmap(lambda i: _laplace(i, mode))(img)


@partial(jax.jit, static_argnames=("sigma", "mode", "truncate"))
def _log(img, sigma, mode, truncate):
    # float32 where it holds the grey values exactly (8- and 16-bit images), as in
    # Canny: half the bytes and twice the SIMD lanes of float64 for the four 17-tap passes
    dt = _work_dtype(img.dtype)
    if not jnp.issubdtype(img.dtype, jnp.integer):  # integers are padded as they are, converted by the first pass
        img = img.astype(dt)
    k0 = gaussian_kernel1d(sigma, 0, truncate)
    k2 = gaussian_kernel1d(sigma, 2, truncate)
    return correlate1d(correlate1d(img, k2, 0, mode, dtype=dt), k0, 1, mode) + correlate1d(
        correlate1d(img, k0, 0, mode, dtype=dt), k2, 1, mode
    )


@jax.jit
def _zero_crossings(resp, threshold):
    # A crossing between two 4-neighbours with opposite signs and a jump of at
    # least `threshold` is marked at the pixel of the pair closer to zero.
    h, w = resp.shape
    mark = jnp.zeros(resp.shape, bool)
    for axis in (0, 1):
        a = jax.lax.slice_in_dim(resp, 0, resp.shape[axis] - 1, axis=axis)
        c = jax.lax.slice_in_dim(resp, 1, resp.shape[axis], axis=axis)
        cross = (a * c < 0.0) & (jnp.abs(a - c) >= threshold)
        first = cross & (jnp.abs(a) <= jnp.abs(c))
        second = cross & (jnp.abs(a) > jnp.abs(c))
        pad_first = [(0, 0), (0, 0)]
        pad_first[axis] = (0, 1)
        pad_second = [(0, 0), (0, 0)]
        pad_second[axis] = (1, 0)
        mark = mark | jnp.pad(first, pad_first) | jnp.pad(second, pad_second)
    return mark


def log(image, sigma: float = 2.0, *, threshold: float = 0.0, mode: Mode = "reflect", truncate: float = 4.0):
    """Laplacian of Gaussian and its zero crossings (Marr-Hildreth; seed 004,
    高斯-拉普拉斯算子).

    ``L = d2/dr2 (G_sigma * g) + d2/dc2 (G_sigma * g)`` with the sampled
    Gaussian-derivative kernels of ``scipy.ndimage.gaussian_laplace``
    (same ``truncate`` and border mode, so the responses agree with it).

    8- and 16-bit (and float16 / float32) images are filtered in float32,
    which holds their grey values exactly (the response then agrees with
    scipy's float64 one to ~1e-7 of ``sum |kernel weights|`` times the grey
    values, float32's rounding); float64 and 32/64-bit integer images in
    float64.

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype.
        sigma: Gaussian standard deviation in pixels.
        threshold: minimal jump ``|L[p] - L[q]|`` across a zero crossing, in
            grey values per pixel^2 (0 keeps every sign change).
        mode: border mode (scipy.ndimage names).

    Returns:
        ``(response, edges)``: the LoG response (float32 or float64, as
        above) and a boolean map of
        zero crossings (the pixel of each sign-changing 4-neighbour pair that
        is closer to zero), both of the shape of ``image``.  A constant
        image gives no edge and a response of about -1.7e-4 times its grey
        value at sigma 2, as scipy's: the sampled, truncated second-derivative
        kernels do not sum to exactly zero.

    Examples:
        The response equals SciPy's ``gaussian_laplace`` (the same sampled kernels and border mode);
        ``(response, zero crossings)``:

        >>> import numpy as np
        >>> from scipy import ndimage
        >>> from photax.measure import log
        >>> image = np.random.default_rng(0).uniform(0, 1, (32, 32))
        >>> response, crossings = log(image, sigma=2.0)
        >>> bool(np.allclose(np.asarray(response), ndimage.gaussian_laplace(image, 2.0), atol=1e-12))
        True
    """
    img, b = as_image(image, convert=False)
    sigma = float(sigma)
    if not sigma > 0:
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    thr = jnp.asarray(threshold, jnp.float64)

    def one(im):
        resp = _log(im, sigma, mode, float(truncate))
        return resp, _zero_crossings(resp, thr.astype(resp.dtype))

    return batched(one, img, b)


# ----------------------------------------------------------------- Canny


def _shift(p, dr, dc, h, w):
    """``m[r + dr, c + dc]`` from ``p`` = ``m`` padded by one pixel."""
    return p[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]


def _nonmax_bilinear(isobel, jsobel, mag_p, low):
    """Non-maximum suppression along the gradient with linear interpolation
    between the two neighbours it points between (scikit-image's
    ``_nonmaximum_suppression_bilinear``, vectorised).  ``mag_p``: the
    magnitude with a one-pixel frame around the image (whatever its values:
    they only reach the outer border, never an edge).  Returns the kept
    pixels (magnitude >= low, local maximum, not on the outer border)."""
    h, w = isobel.shape
    s = partial(_shift, mag_p, h=h, w=w)
    mag = s(0, 0)
    ai, aj = jnp.abs(isobel), jnp.abs(jsobel)
    cond1 = (isobel > 0) == (jsobel > 0)  # both components of the same sign

    def ratio(num, den):
        return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)

    a = cond1 & (ai > aj)
    bb = cond1 & ~(ai > aj)
    c = ~cond1 & (ai < aj)
    # d = ~cond1 & ~(ai < aj)
    wgt = jnp.where(a, ratio(aj, ai), jnp.where(bb, ratio(ai, aj), jnp.where(c, ratio(ai, aj), ratio(aj, ai))))
    n11 = jnp.where(a, s(1, 0), jnp.where(bb, s(0, 1), jnp.where(c, s(0, 1), s(-1, 0))))
    n12 = jnp.where(a | bb, s(1, 1), s(-1, 1))
    n21 = jnp.where(a, s(-1, 0), jnp.where(bb, s(0, -1), jnp.where(c, s(0, -1), s(1, 0))))
    n22 = jnp.where(a | bb, s(-1, -1), s(1, -1))
    c_plus = n12 * wgt + n11 * (1.0 - wgt) <= mag
    c_minus = n22 * wgt + n21 * (1.0 - wgt) <= mag
    border = inner_mask((h, w), 1)
    return border & (mag >= low) & c_plus & c_minus


def _hysteresis(low_mask, high_mask):
    """Keep the 8-connected components of ``low_mask`` that contain a pixel
    of ``high_mask``.

    Connected components by min-label propagation with pointer jumping
    (each pixel's label is the smallest flat index in its component): one
    3 x 3 minimum plus two ``label = label[label]`` jumps per sweep, in a
    ``while_loop`` until nothing changes.  Jumping lets labels travel far
    along a chain in one sweep, so long edges need few sweeps, and the whole
    operator stays jittable and vmappable (no host callback).
    """
    h, w = low_mask.shape
    n = h * w
    big = jnp.int32(n) if n < 2**31 - 1 else jnp.int64(n)
    idx = jnp.arange(n, dtype=big.dtype).reshape(h, w)
    lab0 = jnp.where(low_mask, idx, big)

    def sweep(lab):
        m = jax.lax.reduce_window(lab, big, jax.lax.min, (3, 3), (1, 1), [(1, 1), (1, 1)])
        lab = jnp.where(low_mask, m, big)
        flat = jnp.concatenate([lab.reshape(-1), big[None]])
        for _ in range(2):
            lab = flat[lab]
            flat = jnp.concatenate([lab.reshape(-1), big[None]])
        return lab

    def cond(state):
        return state[1]

    def body(state):
        lab, _ = state
        new = sweep(lab)
        return new, jnp.any(new != lab)

    lab, _ = jax.lax.while_loop(cond, body, (lab0, jnp.array(True)))
    seeded = jnp.zeros(n + 1, bool).at[jnp.where(high_mask, lab, big).reshape(-1)].max(high_mask.reshape(-1))
    return low_mask & seeded[lab]


def _label_host(low_mask, high_mask):
    low_mask, high_mask = np.asarray(low_mask), np.asarray(high_mask)
    labels, count = ndi.label(low_mask, structure=np.ones((3, 3), bool))
    # read and write only the candidate pixels (a few % of the image), not whole-image label maps
    idx = np.flatnonzero(low_mask)
    lab = labels.reshape(-1)[idx]
    good = np.zeros(count + 1, bool)
    good[lab[high_mask.reshape(-1)[idx]]] = True
    out = np.zeros(low_mask.shape, bool)
    out.reshape(-1)[idx] = good[lab]
    return out


def _hysteresis_host(low_mask, high_mask):
    """Hysteresis by ``scipy.ndimage.label`` (union-find, one pass over the
    image) through ``jax.pure_callback``: still jittable and vmappable
    (sequentially over a batch)."""
    return jax.pure_callback(
        _label_host, jax.ShapeDtypeStruct(low_mask.shape, jnp.bool_), low_mask, high_mask, vmap_method="sequential"
    )


def _work_dtype(dtype) -> type:
    """float32 for images whose grey values it holds exactly (integers of up to
    16 bits, float16 / float32), float64 for the rest (float64, 32- and 64-bit
    integers)."""
    if jnp.issubdtype(dtype, jnp.integer) or dtype == jnp.bool_:
        return jnp.float32 if jnp.dtype(dtype).itemsize <= 2 else jnp.float64
    return jnp.float32 if jnp.dtype(dtype).itemsize <= 4 else jnp.float64


def _scale_border(a, inv, axis: int, r: int):
    """``a * inv`` along ``axis`` where ``inv`` differs from 1: only the ``r``
    rows (columns) at each end, written in place (a broadcast multiply of the
    whole image costs XLA:CPU 3x the smoothing pass it follows, measured)."""
    n = a.shape[axis]
    shape = [1, 1]
    shape[axis] = -1
    if r == 0:
        return a
    if n <= 2 * r:
        return a * jnp.asarray(inv, a.dtype).reshape(shape)
    for lo in (0, n - r):
        strip = jax.lax.slice_in_dim(a, lo, lo + r, axis=axis) * jnp.asarray(inv[lo : lo + r], a.dtype).reshape(shape)
        start = [0, 0]
        start[axis] = lo
        a = jax.lax.dynamic_update_slice(a, strip, start)
    return a


@partial(jax.jit, static_argnames=("sigma", "mode", "cval", "hysteresis"))
def _canny(img, low, high, sigma, mode, cval, hysteresis="host"):
    # float32 where it holds the grey values exactly (8- and 16-bit images): half
    # the bytes and twice the SIMD lanes of float64; the edge map is scikit-image's
    # (float64) on the benchmark's 4-MPix uint8 image, pixel for pixel.
    dt = _work_dtype(img.dtype)
    if not jnp.issubdtype(img.dtype, jnp.integer):
        img = img.astype(dt)
    smoothed = gaussian(img, sigma, mode, cval, dtype=dt)
    if mode == "constant":
        # scikit-image divides by the smoothed all-ones image so the dark
        # zero padding does not pull the border down ("bleed-over").
        if cval == 0.0:  # separable: the outer product of two 1-D profiles, 1 inside
            k = gaussian_kernel1d(sigma)
            r = len(k) // 2
            for axis, n in enumerate(img.shape):
                prof = ndi.correlate1d(np.ones(n), k, mode="constant")
                smoothed = _scale_border(smoothed, 1.0 / (prof + np.finfo(np.float64).eps), axis, r)
        else:
            smoothed = smoothed / (gaussian(jnp.ones(img.shape, dt), sigma, mode, cval, dtype=dt) + np.finfo(dt).eps)
    # The magnitude on the image plus a one-pixel frame, straight from a two-pixel
    # padded copy (NMS reads the neighbours' magnitudes: no padded copy of it), the
    # gradient's components recomputed where NMS needs them (cheaper than storing them).
    h, w = smoothed.shape
    # its inner pixel is scipy.ndimage.sobel's (reflect) border; the outer one only reaches the frame
    p = pad(smoothed, [(2, 2), (2, 2)], "nearest")
    i_p, j_p = sobel_pair(p, "valid")
    mag_p = jax.lax.optimization_barrier(jnp.sqrt(i_p * i_p + j_p * j_p))
    isobel, jsobel = sobel_pair(p[1:-1, 1:-1], "valid")
    mag = mag_p[1:-1, 1:-1]
    # Nothing on a flat image: rounding noise of the smoothing (~1e-16 of the
    # grey level in float64, 1e-7 in float32) must not pass a zero threshold
    # (scikit-image floors at 1e-14).
    floor = 1e-12 if dt == jnp.float64 else 1e-5
    low = jnp.maximum(low.astype(dt), floor * jnp.max(jnp.abs(img.astype(dt))) + np.finfo(dt).tiny)
    low_mask = _nonmax_bilinear(isobel, jsobel, mag_p, low)
    high_mask = low_mask & (mag >= high.astype(dt))
    if hysteresis == "jax":
        return _hysteresis(low_mask, high_mask)
    return _hysteresis_host(low_mask, high_mask)


def canny(
    image,
    sigma: float = 1.0,
    low_threshold=None,
    high_threshold=None,
    *,
    mode: Mode = "constant",
    cval: float = 0.0,
    hysteresis: Literal["host", "jax"] = "host",
):
    """Canny edge detector: Gaussian smoothing, Sobel gradient magnitude and
    direction, non-maximum suppression along the gradient (interpolated
    between neighbours) and hysteresis (8-connected).

    The steps and defaults are those of ``skimage.feature.canny`` (border
    mode ``"constant"`` with bleed-over correction, the outer one-pixel
    frame never an edge); the magnitude is that of the unnormalised Sobel
    kernels (8 x the gradient in grey values per pixel), as in scikit-image
    and OpenCV.  8- and 16-bit (and float16 / float32) images are smoothed
    and differentiated in float32, which holds their grey values exactly,
    float64 images in float64.

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype, grey
            values kept as they are (no rescaling to [0, 1]).
        sigma: Gaussian standard deviation in pixels.
        low_threshold, high_threshold: hysteresis thresholds on the
            magnitude, in the image's grey units.  ``None`` means 0.1 and 0.2
            times the image's range (max - min; per image in a batch): for a
            float image spanning [0, 1] and for a full-range integer image
            these are scikit-image's defaults, and unlike scikit-image's
            dtype-based defaults they do not blank out integer images that
            use a small part of their dtype's range (skimage #6871, #3913).
        mode, cval: border handling of the smoothing.

    Returns:
        Boolean edge map of the shape of ``image``.  A constant image has no
        edge.

        hysteresis: ``"host"`` (default): connected components by
            ``scipy.ndimage.label`` through ``jax.pure_callback``, which
            still works under ``jit`` and ``vmap``.  ``"jax"``: label
            propagation with pointer jumping in a ``while_loop``, pure XLA
            (for accelerators), but on CPU it needs one full-image sweep per
            few pixels of the longest chain: ~13 s instead of ~20 ms on a
            1024 x 1024 image (measured), so not the default.

    Examples:
        The edges of a bright square: found on its border, none in its flat inside:

        >>> import numpy as np
        >>> from photax.measure import canny
        >>> image = np.zeros((40, 40)); image[10:30, 10:30] = 1.0
        >>> edges = np.asarray(canny(image, sigma=1.0))
        >>> bool(edges[10:30, 9:11].any()), bool(edges[15:25, 15:25].any())
        (True, False)
    """
    if hysteresis not in ("host", "jax"):
        raise ValueError(f"hysteresis: expected 'host' or 'jax', got {hysteresis!r}")
    img, b = as_image(image, convert=False)
    sigma = float(sigma)
    if not sigma > 0:
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    if low_threshold is not None and high_threshold is not None and high_threshold < low_threshold:
        raise ValueError("low_threshold must not exceed high_threshold")

    def one(im):
        rng = jnp.max(im).astype(jnp.float64) - jnp.min(im).astype(jnp.float64)  # no integer overflow
        lo = 0.1 * rng if low_threshold is None else jnp.asarray(low_threshold, jnp.float64)
        hi = 0.2 * rng if high_threshold is None else jnp.asarray(high_threshold, jnp.float64)
        return _canny(im, lo, hi, sigma, mode, float(cval), hysteresis)

    return batched(one, img, b)
