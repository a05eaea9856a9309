"""Resampling: grey values of an image at fractional pixel positions.

Pixel convention (``docs/conventions.md``): ``(col, row)`` with the integer
positions at pixel *centres*, column right, row down; pixel ``[r, c]`` covers
``[c - 0.5, c + 0.5] x [r - 0.5, r + 0.5]``.  This is the convention of
OpenCV's ``remap`` and of ``scipy.ndimage.map_coordinates``.

Kernels (``t`` = distance in pixels from the sample to a neighbour centre):

* ``"nearest"``: ``k = floor(x + 0.5)``.
* ``"bilinear"``: ``W(t) = 1 - |t|`` for ``|t| <= 1`` (2 x 2 neighbours).
* ``"cubic"``: cubic convolution (Keys 1981) on 4 x 4 neighbours::

      W(t) = (a+2)|t|^3 - (a+3)|t|^2 + 1          |t| <= 1
      W(t) = a|t|^3 - 5a|t|^2 + 8a|t| - 4a         1 < |t| <= 2

  ``a = -0.5`` (default) is Keys' choice: third-order accurate, reproduces
  quadratics, and is GDAL's cubic.  ``a = -1`` is the course text's kernel
  (sharper, only first-order accurate); OpenCV's INTER_CUBIC uses ``-0.75``.
* ``"lanczos"``: Lanczos-3, ``W(t) = sinc(t) sinc(t/3)`` for ``|t| < 3``
  (6 x 6 neighbours), weights normalised to sum to one per axis (as GDAL
  and Pillow do) so that constant images stay constant.
* ``"lanczos4"``: Lanczos-4, ``W(t) = sinc(t) sinc(t/4)`` for ``|t| < 4``
  (8 x 8 neighbours), normalised likewise: OpenCV's ``INTER_LANCZOS4``.
* ``"bspline"``: cubic B-spline ``beta3`` on 4 x 4 spline coefficients.  The
  coefficients come from the recursive (IIR) prefilter of Unser, Aldroubi &
  Eden (1991) / Unser (1999), pole ``z = sqrt(3) - 2``, run along each axis
  once per image.  The spline interpolates: at integer positions it returns
  the pixel values exactly.

Edges, the same for every kernel:

* A position is **valid** when it lies in the image footprint,
  ``-0.5 <= col <= W - 0.5`` and ``-0.5 <= row <= H - 0.5``; any other
  position (or NaN) gets ``nodata``.
* Neighbours beyond the edge take the value of the nearest edge pixel
  (replicate / clamp; OpenCV ``BORDER_REPLICATE``, scipy ``mode="nearest"``).
  For the B-spline the image is padded with 12 replicated pixels before the
  prefilter, whose own boundary is "mirror" (whole-sample symmetric), exactly
  like ``scipy.ndimage.map_coordinates(order=3, mode="nearest")``; the
  mirror is then ``z^12 ~ 1e-7`` away from the image.

Precision: sampling positions are split into integer pixel and fraction in
float64 (float32 would lose ~2e-4 px at column 4000); the fractions, the
kernel weights and the weighted sums over grey values are computed in
float32 for integer and float32 images (integer grey values up to 2^16 lose
nothing visible: relative error ~6e-8) and in float64 for float64 images.
Integer results are rounded to nearest and clipped to the dtype's range.

Speed: the image is padded once so that every neighbour of a valid
position is in bounds (no per-neighbour clamping), all taps of one output
pixel come from one flat base index plus constant offsets, and the output is
evaluated in chunks with ``lax.map`` so the working set stays in cache.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._deprecation import renamed_argument
from .kernels import (  # noqa: F401  (re-exported: the kernel layer's names, where they always were)
    BSPLINE_PAD,
    RESAMPLING,
    Resampling,
    kernel_weights,
    pad_width,
    resample_grid,
)

# BSPLINE_PAD, THREADS, bspline_coefficients, gather_source, compute_dtype and interpolate are the kernel
# layer photax.rectification (and uncertainty's thread pool) build on: public names, not in photax.__all__.
_CHUNK = 4096  # output samples per lax.map step (measured best of 4096 / 65536)
THREADS = min(os.cpu_count() or 1, 8)
_BUCKET = 1 << 15  # below: pad to a power of two; above: split over threads


def _weights(method: str, t: Array, a: float) -> list[Array]:
    return kernel_weights(method, t, a, xp=jnp)


def _bspline_prefilter_axis(c: Array, axis: int) -> Array:
    """Unser's cubic B-spline prefilter along ``axis`` with mirror boundary.

    Causal ``c+[k] = s[k] + z c+[k-1]``, anticausal
    ``c-[k] = z (c-[k+1] - c+[k])``, gain ``(1 - z)(1 - 1/z) = 6``; the
    causal start is the truncated mirror sum ``sum_k z^k s[k]`` and the
    anticausal start ``z / (z^2 - 1) (c+[N-1] + z c+[N-2])`` (Unser 1999).
    """
    z = float(np.sqrt(3.0) - 2.0)
    c = jnp.moveaxis(c, axis, 0) * 6.0
    n = c.shape[0]
    horizon = min(n, int(np.ceil(np.log(1e-16) / np.log(abs(z)))))
    zk = jnp.asarray(z ** np.arange(horizon), dtype=c.dtype)
    first = jnp.tensordot(zk, c[:horizon], axes=1)

    def causal(prev, s):
        cur = s + z * prev
        return cur, cur

    _, cp = jax.lax.scan(causal, first, c[1:])
    cp = jnp.concatenate([first[None], cp])
    last = (z / (z * z - 1.0)) * (cp[-1] + z * cp[-2])

    def anticausal(nxt, s):
        cur = z * (nxt - s)
        return cur, cur

    _, cm = jax.lax.scan(anticausal, last, cp[:-1], reverse=True)
    cm = jnp.concatenate([cm, last[None]])
    return jnp.moveaxis(cm, 0, axis)


_pad_width = pad_width


def _aligned_empty(shape, dtype) -> np.ndarray:
    """``np.empty`` whose data start at a 64-byte boundary: such an array
    is handed to XLA:CPU by :func:`jax.device_put` without a copy
    (measured 0.05 ms for 16 MiB, against 4-17 ms for numpy's default
    16-byte alignment, which ``device_put`` copies into fresh pages)."""
    dtype = np.dtype(dtype)
    n = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(n + 64, dtype=np.uint8)
    at = -raw.ctypes.data % 64
    return raw[at : at + n].view(dtype).reshape(shape)


def _to_device(a: np.ndarray) -> Array:
    """``a`` as a jax array, zero-copy when it is 64-byte aligned (it must
    not be written to afterwards: the jax array shares its memory)."""
    return jax.device_put(a)


def bspline_coefficients(img: np.ndarray, compute) -> Array:
    """:func:`_prepare` for ``"bspline"`` on a concrete image, in numpy:
    scipy's ``spline_filter1d`` (mode ``"mirror"``) is the same recursive
    filter as :func:`_bspline_prefilter_axis` and much faster than a
    ``lax.scan`` over rows; ``map_coordinates(mode="nearest")`` does exactly
    this padding and filtering."""
    from scipy import ndimage

    p = BSPLINE_PAD
    c = np.pad(img, ((0, 0), (p, p), (p, p)), mode="edge").astype(np.float64)
    for axis in (1, 2):
        c = ndimage.spline_filter1d(c, 3, axis=axis, mode="mirror", output=np.float64)
    out = _aligned_empty(c.shape, compute)
    out[...] = c
    return _to_device(out.reshape(c.shape[0], -1))


def _edge_pad(img: np.ndarray, p: int) -> np.ndarray:
    """``np.pad(img, ((0, 0), (p, p), (p, p)), mode="edge")`` of a
    ``(B, H, W)`` image into a 64-byte aligned array (see
    :func:`_aligned_empty`), a few times faster than ``np.pad``."""
    b, h, w = img.shape
    out = _aligned_empty((b, h + 2 * p, w + 2 * p), img.dtype)
    out[:, p : p + h, p : p + w] = img
    out[:, p : p + h, :p] = img[:, :, :1]
    out[:, p : p + h, p + w :] = img[:, :, -1:]
    out[:, :p] = out[:, p : p + 1]
    out[:, p + h :] = out[:, p + h - 1 : p + h]
    return out


def gather_source(img, method: str, compute) -> Array:
    """The padded flat gather source of a ``(B, H, W)`` image: the B-spline
    prefilter in numpy when the image is concrete, else :func:`_prepare`.
    A concrete image (numpy or jax) is padded in numpy (numpy's edge pad is
    ~10x faster than XLA's) into memory that XLA then uses in place."""
    if isinstance(img, jax.core.Tracer):
        return _prepare(img, method=method, compute=compute)
    if method == "bspline":
        return bspline_coefficients(np.asarray(img), compute)
    img = _edge_pad(np.asarray(img), _pad_width(method))
    return _to_device(img.reshape(img.shape[0], -1))


def compute_dtype(dtype):
    """Weights and sums: float64 for float64 images, else float32."""
    return jnp.float64 if dtype == jnp.float64 else jnp.float32


@partial(jax.jit, static_argnames=("method", "compute"))
def _prepare(img, *, method, compute):
    """``(B, H, W)`` image -> ``(B, (H+2p)(W+2p))`` padded flat gather source.

    Integer images stay integer (4x less memory traffic per gather than
    float32); B-spline coefficients are in the compute dtype.
    """
    p = _pad_width(method)
    img = jnp.pad(img, ((0, 0), (p, p), (p, p)), mode="edge")
    if method == "bspline":
        img = _bspline_prefilter_axis(_bspline_prefilter_axis(img.astype(compute), 1), 2)
    return img.reshape(img.shape[0], -1)


def interpolate(flat, x, y, fill, lo, hi, off, *, shape, method, a, compute, out_dtype):
    """Grey values at positions ``x, y`` (any one shape ``S``, any float
    dtype): the core shared with :mod:`photax.rectification`.

    ``flat`` is the ``(B, Hp*Wp)`` image from :func:`_prepare` of original
    ``shape`` (H, W).  Positions may be relative to a local origin, so that
    float32 keeps its precision: the image pixel of ``x`` is ``x + off[0]``
    (``off``: ``(2,)`` int32 column, row offsets).  Samples outside
    ``lo <= (x, y) <= hi`` (``(2,)`` bounds in the positions' frame, the
    footprint) or NaN get ``fill`` (``(B,)``).  Returns ``(B, *S)``.

    Everything here is elementwise but the gathers, so XLA fuses it into
    one loop over ``S`` (positions too, when the caller computes them from
    a few broadcast arrays, as the approximate mapping does): give it the
    natural shape of the positions rather than a flattened one, so the
    fused loop needs no index division to find its broadcast inputs.
    """
    h, w = shape
    pad = _pad_width(method)
    wp = w + 2 * pad
    taps = Resampling(method).taps
    first = 0 if method == "nearest" else taps // 2 - 1
    offsets = [(j + pad) * wp + (k + pad) for j in range(-first, taps - first) for k in range(-first, taps - first)]
    valid = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
    if method == "nearest":
        x0, y0 = jnp.floor(x + 0.5), jnp.floor(y + 0.5)
    else:
        x0, y0 = jnp.floor(x), jnp.floor(y)
    # Invalid samples read pixel 0 and are masked below; the clip keeps every
    # tap in bounds whatever the caller's footprint (so no per-tap check).
    x0 = jnp.where(valid, x0, 0)
    y0 = jnp.where(valid, y0, 0)
    wx = _weights(method, (x - x0).astype(compute), a)
    wy = _weights(method, (y - y0).astype(compute), a)
    # Taps of x0 span x0 - first .. x0 - first + taps - 1, padded by ``pad``.
    lo_i, hi_i = first - pad, pad - 1 - (taps - 1 - first)
    xi = jnp.clip(x0.astype(jnp.int32) + off[0], lo_i, w + hi_i)
    yi = jnp.clip(y0.astype(jnp.int32) + off[1], lo_i, h + hi_i)
    base = yi * wp + xi
    if method == "nearest":
        # one tap of weight 1: the grey value itself, no arithmetic (the float
        # round trip of the general path cost nearest more than bilinear's 4 taps)
        g = flat.at[:, base + offsets[0]].get(mode="promise_in_bounds")
        return jnp.where(valid[None], g.astype(out_dtype), fill.reshape((-1,) + (1,) * valid.ndim))
    acc = None
    for j in range(taps):
        row = None
        for k in range(taps):
            # Scalar gathers, one per tap: measured faster on XLA:CPU than
            # gathering 4-wide slices or 4x4 windows.
            g = flat.at[:, base + offsets[j * taps + k]].get(mode="promise_in_bounds").astype(compute)
            v = g * wx[k][None]
            row = v if row is None else row + v
        term = row * wy[j][None]
        acc = term if acc is None else acc + term
    if jnp.issubdtype(out_dtype, jnp.integer):
        info = jnp.iinfo(out_dtype)
        acc = jnp.clip(jnp.round(acc), info.min, info.max)
    return jnp.where(valid[None], acc.astype(out_dtype), fill.reshape((-1,) + (1,) * valid.ndim))


@partial(jax.jit, static_argnames=("shape", "method", "a", "compute", "out_dtype", "chunk", "size"))
def _sample(flat, cols, rows, fill, start, *, shape, method, a, compute, out_dtype, chunk, size):
    """Samples ``start : start + size`` of the flattened ``cols``/``rows``
    from the prepared ``flat`` (B, Hp*Wp) image of original ``shape``
    (H, W); returns ``(B, size)``.

    A ``fori_loop`` over chunks of ``chunk`` samples (the last chunk is
    shifted back to end at ``size``, recomputing a few samples) slices the
    coordinates in place: no padded copy of the coordinate arrays.
    """
    h, w = shape
    cols, rows = cols.reshape(-1), rows.reshape(-1)
    lo = jnp.array([-0.5, -0.5], dtype=cols.dtype)
    hi = jnp.array([w - 0.5, h - 0.5], dtype=cols.dtype)
    off = jnp.zeros(2, dtype=jnp.int32)

    def body(i, out):
        at = jnp.minimum(i * chunk, size - chunk)
        x = jax.lax.dynamic_slice(cols, (start + at,), (chunk,))
        y = jax.lax.dynamic_slice(rows, (start + at,), (chunk,))
        v = interpolate(
            flat, x, y, fill, lo, hi, off, shape=shape, method=method, a=a, compute=compute, out_dtype=out_dtype
        )
        return jax.lax.dynamic_update_slice(out, v, (0, at))

    out = jnp.empty((flat.shape[0], size), dtype=out_dtype)
    return jax.lax.fori_loop(0, -(-size // chunk), body, out)


def resample(
    image,
    cols,
    rows,
    resampling: Resampling | str = "bilinear",
    *,
    nodata=None,
    a: float = -0.5,
    method: Resampling | str | None = None,
) -> Array:
    """Sample ``image`` at fractional pixel positions ``(cols, rows)``.

    Args:
        image: ``(..., H, W)`` grey values; leading axes are bands (rasterio's
            ``(bands, H, W)``), any integer or float dtype.
        cols, rows: fractional column and row of each sample, pixel-centre
            convention (see the module docstring); broadcast to a common
            shape ``S``.
        resampling: ``"nearest"``, ``"bilinear"``, ``"cubic"`` (cubic convolution
            with parameter ``a``), ``"lanczos"`` (Lanczos-3), ``"lanczos4"``
            (Lanczos-4, OpenCV's) or ``"bspline"`` (prefiltered cubic
            B-spline); ``method`` is its deprecated old name (the word of
            :func:`photax.rectify` and the CLI is ``resampling``).
        nodata: value of samples outside the footprint
            ``[-0.5, W-0.5] x [-0.5, H-0.5]``; default NaN for float images,
            0 for integer images.
        a: cubic-convolution parameter (``resampling="cubic"`` only): -0.5 Keys
            (default, GDAL), -0.75 OpenCV, -1 the course text.

    Returns:
        ``(..., *S)`` array of ``image``'s dtype (integers rounded to nearest
        and clipped to the dtype's range).

    Examples:
        Grey values at fractional (column, row) positions; bilinear reproduces a linear ramp exactly:

        >>> import numpy as np
        >>> import photax as ptx
        >>> image = np.add.outer(np.arange(5.0), 10.0 * np.arange(6.0))  # value = row + 10 col
        >>> print(np.asarray(ptx.resample(image, np.array([1.5, 2.25]), np.array([0.5, 3.0]), "bilinear")))
        [15.5 25.5]
    """
    # Over 80 lines because the docstring documents every argument; the body is ~50 lines.
    resampling = renamed_argument("resample", "method", method, "resampling", resampling, "bilinear")
    method = Resampling.check(resampling, "resampling").value
    # numpy stays numpy: gather_source pads it in numpy anyway, and jnp.asarray
    # would first copy it whole (~10 ms for 4096^2).
    image = image if isinstance(image, (jax.Array, np.ndarray)) else np.asarray(image)
    if image.ndim < 2 or min(image.shape[-2:]) < 1:
        raise ValueError(f"image must have shape (..., H, W) with H, W >= 1, got {image.shape}")
    dtype = image.dtype
    if not (jnp.issubdtype(dtype, jnp.integer) or jnp.issubdtype(dtype, jnp.floating)):
        raise ValueError(f"image must have an integer or float dtype, got {dtype}")
    if dtype == jnp.bool_:
        raise ValueError("image must not be boolean; cast it to uint8 first")
    cols = jnp.asarray(cols, dtype=float)
    rows = jnp.asarray(rows, dtype=float)
    shape = jnp.broadcast_shapes(cols.shape, rows.shape)
    if cols.shape != shape or rows.shape != shape:
        cols, rows = jnp.broadcast_to(cols, shape), jnp.broadcast_to(rows, shape)
    n = int(np.prod(shape))
    is_int = jnp.issubdtype(dtype, jnp.integer)
    if nodata is None:
        nodata = 0 if is_int else np.nan
    if is_int and not np.isfinite(nodata):
        raise ValueError(f"nodata={nodata} cannot be stored in an {dtype} image; give an integer nodata")
    lead = image.shape[:-2]
    h, w = image.shape[-2:]
    if n == 0:
        return jnp.zeros(lead + shape, dtype=dtype)
    compute = compute_dtype(dtype)
    flat = gather_source(image.reshape((-1, h, w)), method, compute)
    fill = jnp.full((flat.shape[0],), nodata, dtype=dtype)
    if n < _BUCKET:
        # Small requests are padded to a power of two: a handful of
        # compilations instead of one per sample count.
        m = max(64, 1 << (n - 1).bit_length())
        cols, rows = (jnp.pad(v.reshape(-1), (0, m - n), constant_values=jnp.nan) for v in (cols, rows))
    parts = min(THREADS, n // _BUCKET)
    if parts < 2 or any(isinstance(v, jax.core.Tracer) for v in (cols, rows, flat)):
        parts = 1
    size = -(-cols.size // parts)
    run = partial(
        _sample,
        flat,
        cols,
        rows,
        fill,
        shape=(h, w),
        method=method,
        a=float(a),
        compute=compute,
        out_dtype=np.dtype(dtype),
        chunk=min(_CHUNK, size),
        size=size,
    )
    if parts == 1:
        out = run(0)[:, :n]
    else:
        # XLA:CPU runs the gather loop on one thread; concurrent calls on
        # equal slices of the samples (one compilation; the last slice is
        # shifted back to end at n) run in parallel, the GIL released.
        starts = [min(k * size, n - size) for k in range(parts)]
        with ThreadPoolExecutor(parts) as pool:
            pieces = list(pool.map(lambda s: jax.block_until_ready(run(s)), starts))
        out = jnp.concatenate([p[:, k * size - s :] for k, (p, s) in enumerate(zip(pieces, starts))], axis=1)
    return out.reshape(lead + shape)
