"""Area-sampling renderer of analytic patterns, for tests, benchmarks and notebooks.

A pattern is a function ``f(col, row) -> [0, 1]`` of continuous pixel
coordinates (docs/conventions.md: the centre of the top-left pixel at (0, 0),
so pixel ``(c, r)`` covers ``[c - 1/2, c + 1/2] x [r - 1/2, r + 1/2]``).
:func:`render` averages ``f`` over each pixel on a ``supersample^2`` grid
(16 x 16 by default: the "rendered at 16x and averaged down" of the tests),
then blurs with a Gaussian of ``blur`` px (the lens / detector PSF) and adds
white Gaussian noise of ``noise`` times the grey-value range.  Textures made
of Gaussian blobs are integrated over each pixel exactly (erf), no supersampling.

Everything here is plain NumPy (and ``scipy.ndimage.gaussian_filter``): the
renderer is a test fixture, not part of the measuring pipeline.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.special import erf

Pattern = Callable[[np.ndarray, np.ndarray], np.ndarray]


def corner(xy, direction: float, opening: float) -> Pattern:
    """A bright wedge with its apex at ``xy`` (col, row): the points whose
    direction from the apex lies within ``[direction, direction + opening]``
    (radians, measured from the +column axis towards +row)."""
    x0, y0 = map(float, xy)

    def f(x, y):
        a = np.mod(np.arctan2(y - y0, x - x0) - direction, 2 * np.pi)
        return (a < opening).astype(float)

    return f


def disc(xy, radius: float) -> Pattern:
    """A bright disc of ``radius`` px centred at ``xy``."""
    x0, y0 = map(float, xy)
    return lambda x, y: ((x - x0) ** 2 + (y - y0) ** 2 <= radius**2).astype(float)


def ring(xy, inner: float, outer: float) -> Pattern:
    """A bright ring between radii ``inner`` and ``outer`` px."""
    x0, y0 = map(float, xy)

    def f(x, y):
        r2 = (x - x0) ** 2 + (y - y0) ** 2
        return ((r2 >= inner**2) & (r2 <= outer**2)).astype(float)

    return f


def projected_disc(homography, radius: float) -> Pattern:
    """The image of a disc of ``radius`` (plane units) centred at the origin
    of a plane, seen through ``homography`` (3x3, plane (u, v, 1) -> pixel
    (col, row, 1)): an ellipse whose centre is *not* the image of the disc's
    centre ``H (0, 0, 1)``."""
    hinv = np.linalg.inv(np.asarray(homography, dtype=float))

    def f(x, y):
        w = hinv[2, 0] * x + hinv[2, 1] * y + hinv[2, 2]
        u = (hinv[0, 0] * x + hinv[0, 1] * y + hinv[0, 2]) / w
        v = (hinv[1, 0] * x + hinv[1, 1] * y + hinv[1, 2]) / w
        return (u**2 + v**2 <= radius**2).astype(float)

    return f


def render(
    pattern: Pattern,
    shape: tuple[int, int],
    *,
    blur: float = 0.0,
    noise: float = 0.0,
    low: float = 0.0,
    high: float = 1.0,
    supersample: int = 16,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """``(h, w)`` float64 image of ``pattern``: ``low + (high - low) *
    mean_over_pixel(pattern)``, blurred by a Gaussian of ``blur`` px, plus
    N(0, (noise * (high - low))^2) noise.  ``rng`` is required when
    ``noise > 0``."""
    h, w = shape
    s = supersample
    sub = (np.arange(s) + 0.5) / s - 0.5  # sub-sample offsets inside a pixel
    out = np.empty((h, w))
    xs = (np.arange(w)[:, None] + sub[None, :]).ravel()
    for r0 in range(0, h, 16):  # row blocks keep memory small for big images
        r1 = min(r0 + 16, h)
        ys = (np.arange(r0, r1)[:, None] + sub[None, :]).ravel()
        v = pattern(xs[None, :], ys[:, None])
        out[r0:r1] = v.reshape(r1 - r0, s, w, s).mean(axis=(1, 3))
    return _finish(out, blur, noise, low, high, rng)


def texture(
    shape,
    *,
    blobs: int | None = None,
    sigma=(1.0, 3.0),
    shift=(0.0, 0.0),
    seed: int = 0,
    blur: float = 0.0,
    noise: float = 0.0,
    low: float = 0.0,
    high: float = 1.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """A random texture of Gaussian blobs, integrated exactly over each pixel.

    The blobs (positive and negative, standard deviation drawn from
    ``sigma`` px) are drawn from ``seed`` over the image plus a margin, so the
    same seed with a different ``shift`` (col, row) renders the same texture
    moved by ``shift``: ``T_shift(x) = T(x - shift)``.  The result is scaled so
    that the unshifted texture spans about ``[low, high]``.
    """
    h, w = shape
    g = np.random.default_rng(seed)
    n = blobs if blobs is not None else max(8, int(h * w / 12))
    cx = g.uniform(-6, w + 6, n)
    cy = g.uniform(-6, h + 6, n)
    s = g.uniform(*sigma, n)
    a = g.choice([-1.0, 1.0], n) * g.uniform(0.5, 1.0, n)
    x_edges = np.arange(w + 1) - 0.5
    y_edges = np.arange(h + 1) - 0.5
    out = np.zeros((h, w))
    for cx_i, cy_i, s_i, a_i in zip(cx + shift[0], cy + shift[1], s, a):
        k = np.sqrt(2.0) * s_i
        ex = np.diff(erf((x_edges - cx_i) / k)) * (np.sqrt(np.pi / 2) * s_i)
        ey = np.diff(erf((y_edges - cy_i) / k)) * (np.sqrt(np.pi / 2) * s_i)
        out += a_i * ey[:, None] * ex[None, :]
    # scale from the seed's blob amplitudes only (not from this image), so
    # shifted copies share one grey-value scale
    # (density x E[a^2 * integral of a blob squared] = the variance of a shot-noise field)
    std = np.sqrt(n / ((w + 12) * (h + 12)) * np.mean(a**2 * np.pi * s**2))
    out = 0.5 + out / (6.0 * std)
    return _finish(out, blur, noise, low, high, rng)


def _finish(img, blur, noise, low, high, rng):
    if blur > 0:
        img = gaussian_filter(img, blur, mode="nearest")
    img = low + (high - low) * img
    if noise > 0:
        if rng is None:
            raise ValueError("rng: a numpy Generator is required when noise > 0")
        img = img + rng.normal(0.0, noise * (high - low), img.shape)
    return img
