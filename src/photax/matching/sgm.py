"""Dense stereo matching of an epipolar pair: semi-global matching (SGM).

Hirschmüller (2008), "Stereo processing by semiglobal matching and mutual
information", IEEE TPAMI 30(2), with the census cost of Zabih & Woodfill
(1994) or zero-mean normalised cross-correlation, as s2p, ASP and OpenCV's
``StereoSGBM`` use it.

Convention (docs/conventions.md, "Stereo"): the images are rectified
(epipolar: corresponding points share a row); the disparity of the left pixel
``(col, row)`` is ``d = col_left - col_right``, so the point is seen in the right
image at ``(col - d, row)``; the result has the left image's geometry, NaN
where no reliable match was found.

The algorithm:

1. matching cost ``C(p, d)`` for every left pixel ``p`` and integer disparity
   ``d`` in ``[dmin, dmax]``: census (``window`` x ``window`` bit string of
   "neighbour darker than centre", cost the Hamming distance, in bits) or
   ``1 - ZNCC`` scaled to the census' range (``window`` x ``window`` patches).
   A candidate outside the right image or touching a NaN pixel costs half the
   maximum (neither attractive nor forbidden);
2. aggregation along ``paths`` (4 or 8) straight lines r::

       L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d +- 1) + P1,
                                 min_k L_r(p-r, k) + P2(p)) - min_k L_r(p-r, k)

   with ``P2(p) = max(P1, p2 / (1 + |I(p) - I(p-r)| / g))`` adaptive to the
   image gradient along the path (``g``: the median absolute horizontal
   difference of the left image, so the same on every tile), ``S = sum_r L_r``.
   Every path is one :func:`jax.lax.scan` over rows or columns, vectorised
   over the other axis and the disparities (no Python loop over pixels):
   the 3 vertical and diagonal paths of one direction share one scan over
   the rows (a carry each, the cost row and the running sum read once for
   all three), each horizontal path is one scan over the columns of the
   transposed volume;
3. winner-take-all ``d* = argmin_d S(p, d)``; sub-pixel by the parabola
   through ``S(d*-1), S(d*), S(d*+1)``; rejected when another disparity
   ``|d - d*| > 1`` has ``S(d) * (1 - uniqueness) < S(d*)``;
4. left-right check: the right image's disparities come from the same ``S``
   (``S_R(q, d) = S(q + d, d)``), a left disparity is kept when the right
   one at ``col - d`` agrees to ``lr_check`` px;
5. speckle removal: 4-connected regions of valid disparities whose
   neighbours differ by at most ``speckle_range`` px, smaller than
   ``speckle_size`` pixels, are set to NaN (scipy's connected components).

Memory and precision: the cost volume and the aggregated costs are int16, as
OpenCV's: a census cost is a bit count (at most ``window^2 - 1``), a ZNCC cost
is rounded to the same scale, P1 and P2 to integers, and every path's
``L_r`` stays below ``max C + P2``, so the sum of 8 paths is exact while
``8 (window^2 - 1 + p2) < 32767`` (checked).  Half the memory of float32 and
about 3x faster on a CPU (twice the SIMD lanes); the winner's sub-pixel
parabola is float32, and the disparities come back as float32 (to ~1e-5 px).
A tile of ``h x w`` pixels and ``n`` disparities holds about ``5 h w n``
int16 at once; big images are cut into tiles with ``overlap`` pixels on
every side (the aggregation paths run across the overlap, and only the
tile's core is kept), so memory is bounded whatever the image size.
"""

from __future__ import annotations

import warnings
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["disparity", "disparity_range_from_ties"]

_BIG = 8000  # "no such disparity" in the aggregation, int16: above any real cost, room for + P1 / P2
_TILE_BUDGET = 2**25  # entries of one tile's cost volume (64 MiB of int16) before tiling kicks in


def _census(image, valid, window: int):
    """Census bit strings ``(h, w, words)`` uint32 and their validity ``(h, w)``:
    bit = neighbour < centre over a ``window`` x ``window`` neighbourhood
    (the centre left out); a window touching a NaN or the border is invalid."""
    r = window // 2
    h, w = image.shape
    pad = jnp.pad(image, r, mode="edge")
    vpad = jnp.pad(valid, r, mode="constant", constant_values=False)
    offsets = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)]
    words = []
    ok = valid
    for j in range(0, len(offsets), 32):
        word = jnp.zeros((h, w), jnp.uint32)
        for k, (dy, dx) in enumerate(offsets[j : j + 32]):
            nb = pad[r + dy : r + dy + h, r + dx : r + dx + w]
            word = word | ((nb < image).astype(jnp.uint32) << jnp.uint32(k))
        words.append(word)
    for dy, dx in offsets:
        ok = ok & vpad[r + dy : r + dy + h, r + dx : r + dx + w]
    return jnp.stack(words, -1), ok


def _box(a, r: int):
    """Sum over a ``(2r+1)`` square window along the first two axes (zero outside)."""
    c = jnp.pad(a, [(r + 1, r), (r + 1, r)] + [(0, 0)] * (a.ndim - 2))
    c = jnp.cumsum(jnp.cumsum(c, 0), 1)
    n = 2 * r + 1
    return c[n:, n:] - c[:-n, n:] - c[n:, :-n] + c[:-n, :-n]


def _cost_volume(left, right, dmin: int, ndisp: int, cost: str, window: int):
    """``(C (h, n, wl) int16, left validity (h, wl), every candidate on the right image's data (h, wl))``
    for the disparities
    ``dmin + k``, ``k < n`` (right column = left column - d), disparity-major
    so that the aggregation's minima over ``d`` run across contiguous rows."""
    h, wl = left.shape
    wr = right.shape[1]
    vl, vr = jnp.isfinite(left), jnp.isfinite(right)
    left, right = jnp.where(vl, left, 0.0), jnp.where(vr, right, 0.0)
    nbits = window * window - 1
    # right columns x - d for x < wl, d = dmin + k: pad the right image so every one is a static slice
    lo = max(dmin + ndisp - 1, 0)  # columns needed left of 0
    hi = max(wl - dmin - wr, 0)  # and right of wr - 1

    # (n, wl) column of the padded right image for each candidate (zncc): one gather (64 slices and a stack are 3x slower)
    idx = lo - dmin - jnp.arange(ndisp)[:, None] + jnp.arange(wl)[None, :]

    def shifted(a, fill):
        """``a[:, x - d]`` as ``(h, n, wl)``, ``fill`` outside ``a``."""
        a = jnp.pad(a, [(0, 0), (lo, hi)], constant_values=fill)
        return a[:, idx]

    # a perfectly flat window matches every disparity alike: no match there (not the range's edge)
    r = window // 2
    win = (window, window)
    hi_, lo_ = (jax.lax.reduce_window(left, v, op, win, (1, 1), [(r, r), (r, r)])
                for v, op in ((-jnp.inf, jax.lax.max), (jnp.inf, jax.lax.min)))  # fmt: skip
    flat = hi_ <= lo_
    none = jnp.int16(nbits // 2)  # the cost of a candidate without data
    if cost == "census":
        cl, okl = _census(left, vl, window)
        cr, okr = _census(right, vr, window)
        okl = okl & ~flat
        words = cl.shape[-1]
        flag = nbits - 32 * (words - 1) < 32  # a free bit in the last word: the right pixel's "no data" there
        if flag:  # the candidate's bits and whether it has data in one slice (bit 31 set: no data)
            cr = cr.at[..., -1].set(jnp.where(okr, cr[..., -1], cr[..., -1] | jnp.uint32(1 << 31)))
        fills = [1 << 31 if flag and j == words - 1 else 0 for j in range(words)]
        crp = [jnp.pad(cr[..., j], [(0, 0), (lo, hi)], constant_values=f) for j, f in zip(range(words), fills)]
        okp = None if flag else jnp.pad(okr, [(0, 0), (lo, hi)], constant_values=False)

        def one(k, vol):
            """The costs of disparity ``dmin + k`` written into the volume: a loop over the
            disparities, whose body XLA cannot fuse the census into (as a gather's operand it was,
            recomputing it for every candidate: 3x slower)."""
            start = lo - dmin - k
            x = [cl[..., j] ^ jax.lax.dynamic_slice_in_dim(a, start, wl, 1) for j, a in enumerate(crp)]
            if flag:
                seen = (x[-1] >> 31) == 0
                x[-1] = x[-1] & jnp.uint32((1 << 31) - 1)
            else:
                seen = jax.lax.dynamic_slice_in_dim(okp, start, wl, 1)
            ck = sum(jax.lax.population_count(v).astype(jnp.int16) for v in x)
            ck = jnp.where(seen & okl, ck, none)
            return jax.lax.dynamic_update_index_in_dim(vol, ck, k, 1)

        c = jax.lax.fori_loop(0, ndisp, one, jnp.zeros((h, ndisp, wl), jnp.int16), unroll=8)
    else:  # zncc on window x window patches, 1 - rho scaled to the census' bit count
        n = float(window * window)
        okl = vl & (_box(vl.astype(jnp.float32), r) == n) & ~flat
        okr = vr & (_box(vr.astype(jnp.float32), r) == n)
        ml, mr = _box(left, r) / n, _box(right, r) / n
        sl = jnp.sqrt(jnp.maximum(_box(left * left, r) / n - ml * ml, 0.0))
        sr = jnp.sqrt(jnp.maximum(_box(right * right, r) / n - mr * mr, 0.0))
        okr = okr & (sr > 0)
        rs = shifted(right, 0.0)  # (h, n, wl): the right pixel of each candidate
        cross = _box(jnp.moveaxis(left[:, None, :] * rs, 1, 2), r) / n  # (h, wl, n)
        mrs = shifted(mr, 0.0)
        srs = shifted(jnp.where(okr, sr, jnp.nan), jnp.nan)  # NaN: the candidate has no data
        rho = (jnp.moveaxis(cross, 2, 1) - ml[:, None, :] * mrs) / jnp.maximum(sl[:, None, :] * srs, 1e-6)
        c = jnp.round(jnp.clip(1.0 - rho, 0.0, 2.0) * (nbits / 2.0)).astype(jnp.int16)
        c = jnp.where(jnp.isfinite(srs) & okl[:, None, :], c, none)
    # every candidate has data: okr over the right columns x - dmin - n + 1 ... x - dmin, a sliding minimum
    okp = jnp.pad(okr, [(0, 0), (lo, hi)], constant_values=False)
    whole = jax.lax.reduce_window(okp, True, jax.lax.bitwise_and, (1, ndisp), (1, 1), "valid")
    whole = whole[:, lo - dmin - ndisp + 1 : lo - dmin - ndisp + 1 + wl]
    return c, okl, whole


def _aggregate_step(prev, c, p1, p2):
    """One SGM recursion step: ``prev``, ``c`` ``(n, w)`` int16, ``p2`` ``(1, w)``."""
    m = prev.min(0, keepdims=True)
    big = jnp.full((1, prev.shape[1]), _BIG, prev.dtype)
    lo = jnp.concatenate([big, prev[:-1]], 0)
    hi = jnp.concatenate([prev[1:], big], 0)
    best = jnp.minimum(jnp.minimum(prev, jnp.minimum(lo, hi) + p1), m + p2)
    return c + (best - m)


def _shift(a, dx: int, fill=0):
    """``a[..., x - dx]`` along the last axis, ``fill`` where that falls outside."""
    if dx == 0:
        return a
    z = jnp.full_like(a[..., :1], fill)
    return jnp.concatenate([z, a[..., :-1]], -1) if dx > 0 else jnp.concatenate([a[..., 1:], z], -1)


def _paths(c, img, total, p1, p2, g, dxs: tuple, reverse: bool):
    """``total + sum_r L_r`` (``total`` None: 0) for the paths stepping one row along the leading axis
    of ``c`` ``(m, n, k)`` (backwards when ``reverse``) and ``dx`` along ``k``, one per ``dxs``, in
    one scan: a carry per path, the cost row and the running total read once per step for all of them."""
    _, n, k = c.shape
    p1i = jnp.int16(round(p1))

    def body(carry, x):
        prevs, prev_img = carry
        (cr, ir), tr = x[:2], (x[2] if total is not None else None)
        news = []
        for prev, dx in zip(prevs, dxs):
            pen = jnp.maximum(p2 / (1.0 + jnp.abs(ir - _shift(prev_img, dx)) / g), p1)
            pen = jnp.round(pen).astype(jnp.int16)[None, :]
            news.append(_aggregate_step(_shift(prev, dx), cr, p1i, pen))
        out = sum(news[1:], news[0]) if tr is None else sum(news, tr)
        return (tuple(news), ir), out

    init = (tuple(jnp.zeros((n, k), jnp.int16) for _ in dxs), img[-1 if reverse else 0])
    xs = (c, img) if total is None else (c, img, total)
    return jax.lax.scan(body, init, xs, reverse=reverse)[1]


def _aggregate(c, image, p1, p2, g, paths: int):
    """``S = sum_r L_r`` ``(h, n, w)`` int16 over 4 or 8 paths of the costs ``c`` ``(h, n, w)`` int16.

    One :func:`jax.lax.scan` per direction with a ``(n, w)`` carry per path: the vertical and
    diagonal paths of one direction step over the rows together (a diagonal shifts its carry by one
    column per row), the horizontal ones over the columns of the transposed volume.  Each scan adds
    its paths' ``L_r`` to the running total row by row (the sum of int16 is exact, so the order of
    the additions does not matter)."""
    img = jnp.where(jnp.isfinite(image), image, 0.0).astype(jnp.float32)
    dxs = (0,) if paths == 4 else (0, 1, -1)
    ct = jnp.transpose(c, (2, 1, 0))  # (w, n, h)
    st = _paths(ct, img.T, None, p1, p2, g, (0,), False)
    st = _paths(ct, img.T, st, p1, p2, g, (0,), True)
    s = jnp.transpose(st, (2, 1, 0))
    for reverse in (False, True):
        s = _paths(c, img, s, p1, p2, g, dxs, reverse)
    return s


def _wta(row, n: int, dmin: int, uniqueness):
    """Sub-pixel winner over the disparities ``k < n`` of the costs ``row(k)`` ``(h, w)`` int16 and its
    uniqueness flag ``(h, w)``.

    Two passes over the ``n`` slices, elementwise over ``(h, w)`` (which vectorises; reductions over
    the volume's middle axis and argmin's (value, index) reduction do not, 5-10x slower): the least
    cost and its first ``k`` (:func:`jnp.argmin`'s), then the costs at ``k -+ 1`` and the least
    one more than 1 px from ``k``."""
    itype = jnp.int16 if n < 32000 else jnp.int32

    def first(i, carry):  # a fori_loop, not n unrolled slices: compiling those grows with n
        s0, k = carry
        si = row(i)
        better = si < s0  # strict: the first of equal minima, as argmin
        return jnp.where(better, si, s0), jnp.where(better, i.astype(itype), k)

    s0 = row(0)
    s0, k = jax.lax.fori_loop(1, n, first, (s0, jnp.zeros(s0.shape, itype)), unroll=16)
    none = jnp.int16(jnp.iinfo(jnp.int16).max)  # above any S (< 32000, the right image's padding included)

    def rest(i, carry):
        sm, sp, second = carry
        si, i = row(i), i.astype(itype)
        sm, sp = jnp.where(k == i + 1, si, sm), jnp.where(k == i - 1, si, sp)
        return sm, sp, jnp.where(jnp.abs(k - i) > 1, jnp.minimum(second, si), second)

    # the costs at k -+ 1 where those exist (s0 where not: unused there)
    sm, sp, second = jax.lax.fori_loop(0, n, rest, (s0, s0, jnp.full(s0.shape, none)), unroll=16)
    s0, sm, sp = (a.astype(jnp.float32) for a in (s0, sm, sp))
    den = sm - 2.0 * s0 + sp
    inner = (k > 0) & (k < n - 1) & (den > 0)
    off = jnp.where(inner, (sm - sp) / jnp.where(inner, 2.0 * den, 1.0), 0.0)
    second = jnp.where(second == none, jnp.inf, second.astype(jnp.float32))
    unique = second * (1.0 - uniqueness) > s0  # strict: a tie (a flat, textureless stretch) is no match
    return (dmin + k).astype(jnp.float32) + jnp.clip(off, -0.5, 0.5), unique


@partial(jax.jit, static_argnames=("dmin", "ndisp", "cost", "window", "paths", "whole_range"))
def _sgm(left, right, p1, p2, g, uniqueness, lr_check, *, dmin, ndisp, cost, window, paths, whole_range=False):
    """Disparities ``(h, wl)`` float32 (NaN invalid) of ``left`` against ``right``
    for ``d = dmin + k``, ``k < ndisp``, before speckle removal."""
    c, okl, whole = _cost_volume(left, right, dmin, ndisp, cost, window)
    if whole_range:
        okl = okl & whole
    s = _aggregate(c, left, p1, p2, g, paths)
    h, n, wl = s.shape
    dl, unique = _wta(lambda k: jax.lax.dynamic_index_in_dim(s, k, 1, False), n, dmin, uniqueness)
    wr = right.shape[1]
    # the right image's disparities by the same S: S_R(q, k) = S(q + dmin + k, k), q < wr
    lo = max(-dmin, 0)
    hi = max(wr + dmin + n - 1 - wl, 0)
    sp = jnp.pad(s, [(0, 0), (0, 0), (lo, hi)], constant_values=jnp.int16(32000))
    a = lo + dmin
    dr, _ = _wta(lambda k: jax.lax.dynamic_slice(sp, (0, k, a + k), (h, 1, wr))[:, 0], n, dmin, 0.0)
    x = jnp.arange(wl, dtype=jnp.float32)[None, :]
    q = jnp.round(x - dl).astype(jnp.int32)
    qin = (q >= 0) & (q < wr)
    back = jnp.take_along_axis(dr, jnp.clip(q, 0, wr - 1), 1)
    ok = okl & unique & qin & (jnp.abs(back - dl) <= lr_check)
    return jnp.where(ok, dl, jnp.nan)


def _remove_speckles(d, size: int, rng: float):
    """NaN for 4-connected regions (neighbours within ``rng`` px) of fewer than ``size`` pixels.

    The regions are the connected components of a graph whose edges join
    neighbours closer than ``rng``; :func:`scipy.ndimage.label` finds them on a
    grid of twice the resolution where pixels sit at even positions and the
    edges between them at the odd ones."""
    if size <= 0:
        return d
    from scipy import ndimage

    h, w = d.shape
    ok = np.isfinite(d)
    grid = np.zeros((2 * h - 1, 2 * w - 1), bool)
    grid[::2, ::2] = ok
    with np.errstate(invalid="ignore"):
        grid[::2, 1::2] = ok[:, 1:] & ok[:, :-1] & (np.abs(d[:, 1:] - d[:, :-1]) <= rng)
        grid[1::2, ::2] = ok[1:] & ok[:-1] & (np.abs(d[1:] - d[:-1]) <= rng)
    labels, _ = ndimage.label(grid)
    pix = labels[::2, ::2]
    counts = np.bincount(pix.ravel())
    out = d.copy()
    out[ok & (counts[pix] < size)] = np.nan
    return out


def disparity_range_from_ties(ties, *, percentiles=(1.0, 99.0), margin: float = 0.1) -> tuple[int, int]:
    """Integer disparity range ``(dmin, dmax)`` from tie points.

    Args:
        ties: ``(n, 2)`` left and right columns ``(x_left, x_right)`` of
            corresponding points (px) of the epipolar pair; their disparities
            are ``x_left - x_right``.
        percentiles: the disparities' percentiles that bound the range (the
            1st and 99th by default, so a few blunders do not widen it).
        margin: widening on each side, as a share of that spread, at least 2 px.

    Returns:
        ``(floor(lo - m), ceil(hi + m))`` with ``m = max(2, margin (hi - lo))``.

    Raises:
        ValueError: ``ties`` not ``(n, 2)`` with at least one finite pair.

    Examples:
        Disparities 10 .. 30 px, widened by 2 px on each side (10 % of 20 px is less than 2); a
        blunder of 500 px, beyond the default 99th percentile, leaves the range as it was:

        >>> import numpy as np
        >>> import photax as ptx
        >>> ties = np.column_stack([np.linspace(110.0, 130.0, 101), np.full(101, 100.0)])
        >>> ptx.disparity_range_from_ties(ties, percentiles=(0, 100))
        (8, 32)
        >>> ptx.disparity_range_from_ties(np.vstack([ties, [[600.0, 100.0]]]))
        (8, 32)
    """
    t = np.asarray(ties, dtype=np.float64)

    if t.ndim != 2 or t.shape[1] != 2:
        raise ValueError(f"ties must be an (n, 2) array of (x_left, x_right) columns, got shape {t.shape}")
    d = t[:, 0] - t[:, 1]
    d = d[np.isfinite(d)]
    if d.size == 0:
        raise ValueError("ties has no finite (x_left, x_right) pair to estimate the disparity range from")
    lo, hi = np.percentile(d, percentiles)
    m = max(2.0, margin * (hi - lo))
    return int(np.floor(lo - m)), int(np.ceil(hi + m))


def _reduce(a, f: int) -> np.ndarray:
    """Block means of ``f x f`` pixels (NaN where a block holds no data)."""
    h, w = (a.shape[0] // f) * f, (a.shape[1] // f) * f
    b = a[:h, :w].reshape(h // f, f, w // f, f)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(b, axis=(1, 3)).astype(np.float32)


def _coarse_range(left, right, *, cost: str, factor: int = 4) -> tuple[int, int]:
    """The disparity range of a pair from a match of its ``factor`` x reduced
    images over +-1/4 of their width (the coarse level of a pyramid): the 1st
    and 99th percentiles of the coarse disparities, times ``factor``, widened
    by ``2 factor`` px on each side.

    Raises:
        ValueError: the images are too small to reduce, or the coarse match found nothing.
    """
    lc, rc = _reduce(left, factor), _reduce(right, factor)
    if min(lc.shape) < 8:
        raise ValueError(f"disparity_range='auto' needs images of at least {8 * factor} px a side, got {left.shape}")
    half = max(lc.shape[1] // 4, 2)
    d = disparity(lc, rc, disparity_range=(-half, half), cost=cost, speckle_size=10)
    d = d[np.isfinite(d)]
    if d.size < 10:
        raise ValueError("disparity_range='auto': the coarse match found no reliable disparity; give the range")
    lo, hi = np.percentile(d, (1.0, 99.0))
    return int(np.floor(factor * lo - 2 * factor)), int(np.ceil(factor * hi + 2 * factor))


def _as_image(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D (rows, cols) grey image, got shape {a.shape}"
            + (" (convert colour images to grey first)" if a.ndim == 3 else "")
        )
    if a.dtype.kind not in "uif":
        raise ValueError(f"{name} must hold numbers, got dtype {a.dtype}")
    if min(a.shape) < 1:
        raise ValueError(f"{name} is empty (shape {a.shape})")
    return a.astype(np.float32)


def disparity(
    left,
    right,
    *,
    disparity_range: tuple[int, int] | str | None = None,
    ties=None,
    cost: str = "census",
    window: int | None = None,
    p1: float | None = None,
    p2: float | None = None,
    paths: int = 8,
    subpixel: bool = True,
    uniqueness: float = 0.02,
    lr_check: float | None = 1.0,
    speckle_size: int = 50,
    speckle_range: float = 2.0,
    tile: int | tuple[int, int] | None = None,
    overlap: int = 32,
    whole_range: bool = False,
) -> np.ndarray:
    """Dense disparity map of a rectified (epipolar) pair by semi-global matching.

    Convention: ``d = col_left - col_right`` (px), rows aligned; the left pixel
    ``(col, row)`` is seen in the right image at ``(col - d, row)``
    (docs/conventions.md, "Stereo"; the module docstring has the algorithm).

    Args:
        left, right: ``(rows, cols)`` grey images (any real dtype), the same
            number of rows; NaN marks pixels without data (no match there).
        disparity_range: ``(dmin, dmax)`` integer disparities searched, both
            included (``dmax - dmin + 1`` candidates); ``"auto"``: coarse to
            fine, the range of a match of both images reduced 4 x over
            +-1/4 of their width (:func:`_coarse_range`).
        ties: instead of a range, ``(n, 2)`` tie points ``(x_left, x_right)``:
            the range is :func:`disparity_range_from_ties` of them.
        cost: ``"census"`` (Hamming distance of ``window`` x ``window`` census
            strings) or ``"zncc"`` (``(1 - rho) (window^2 - 1) / 2``).
        window: cost window (odd, default 5).
        p1: penalty of a 1 px disparity change along a path, in cost units
            (census bits); default ``2 (window^2 - 1) / 3`` (16 for 5 x 5).
        p2: penalty of a larger jump on a flat image, divided by
            ``1 + |dI| / g`` at an intensity step ``dI`` along the path (never
            below ``p1``); default ``20 (window^2 - 1) / 3`` (160 for 5 x 5).
            The defaults were chosen on Middlebury's Motorcycle pair
            (benchmarks/bench_stereo.py).
        paths: 4 (horizontal and vertical) or 8 (and the diagonals).
        subpixel: parabola fit through the aggregated costs; else integers.
        uniqueness: reject when a disparity more than 1 px from the winner
            costs at most ``winner / (1 - uniqueness)``; with 0 only ties
            are rejected (a textureless stretch gets NaN, not ``dmin``).
        lr_check: keep a disparity when the right image's own disparity at
            ``col - d`` agrees to this many px; None turns it off.
        speckle_size: regions of similar disparity smaller than this many
            pixels become NaN; 0 turns it off.
        speckle_range: the largest disparity step (px) inside one region.
        tile: ``(rows, cols)`` (or one int for both) of the tiles' cores;
            None: one tile when the cost volume holds at most 2^25 entries
            (64 MiB of int16; the whole call then peaks near 0.5 GiB), else square tiles of about that volume.
        overlap: pixels of context on every side of a tile (the aggregation
            paths cross it; only the core is kept).
        whole_range: keep a disparity only where every candidate of the range
            was compared, i.e. the right image has data at ``col - d`` for
            every ``d`` (OpenCV's SGBM leaves the same band invalid).  At the
            right image's edge (a stereo pair's overlap ends there) or a hole,
            the true match may be among the candidates not compared, and the
            winner of the others is then a wrong disparity that the left-right
            check does not always catch: a wrong height in a surface model,
            not a missing one.  ``photax.stereo.pair_points`` turns it on for
            frame pairs (an RPC tile's right array is cut to hold the whole
            range); off, the band is matched as well as it can be
            (Middlebury's scores count it).

    Returns:
        ``(rows, cols)`` float32 disparities of the left image, NaN where
        invalid (occluded, not unique, failed the left-right check, speckle,
        outside the right image, NaN input).

    Raises:
        ValueError: images not 2-D or of different rows, no range (neither
            ``disparity_range`` nor ``ties``), an empty range
            (``dmax < dmin``), an unknown ``cost`` or ``paths``, a bad ``window``.

    Examples:
        >>> import numpy as np, photax
        >>> rng = np.random.default_rng(0)
        >>> right = rng.random((40, 80))
        >>> left = np.roll(right, 5, axis=1)  # left col = right col + 5
        >>> d = photax.disparity(left, right, disparity_range=(0, 10), speckle_size=0)
        >>> float(np.nanmedian(d[:, 20:]).round(2))
        5.0
    """
    left = _as_image(left, "left")
    right = _as_image(right, "right")
    if left.shape[0] != right.shape[0]:
        raise ValueError(
            f"left and right must have the same number of rows (rectified pair), got {left.shape} and {right.shape}"
        )
    if cost not in ("census", "zncc"):
        raise ValueError(f"cost must be 'census' or 'zncc', got {cost!r}")
    if paths not in (4, 8):
        raise ValueError(f"paths must be 4 or 8, got {paths!r}")
    if window is None:
        window = 5
    if int(window) != window or window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd integer >= 3, got {window!r}")
    window = int(window)
    if disparity_range is None:
        if ties is None:
            raise ValueError("give disparity_range=(dmin, dmax) or ties=(n, 2) (x_left, x_right) to bound the search")
        disparity_range = disparity_range_from_ties(ties)
    elif ties is not None:
        raise ValueError("give disparity_range or ties, not both")
    elif isinstance(disparity_range, str):
        if disparity_range != "auto":
            raise ValueError(f"disparity_range must be (dmin, dmax), 'auto' or None, got {disparity_range!r}")
        disparity_range = _coarse_range(left, right, cost=cost)
    try:
        dmin, dmax = (int(v) for v in disparity_range)
    except (TypeError, ValueError):
        raise ValueError(f"disparity_range must be two integers (dmin, dmax), got {disparity_range!r}") from None
    if dmax < dmin:
        raise ValueError(f"disparity_range is empty: dmax {dmax} < dmin {dmin}")
    nbits = window * window - 1
    p1 = float(2 * nbits / 3 if p1 is None else p1)
    p2 = float(20 * nbits / 3 if p2 is None else p2)
    if not (p1 >= 0 and p2 >= 0):
        raise ValueError(f"p1 and p2 must be >= 0, got {p1}, {p2}")
    if 8 * (window * window - 1 + max(p1, p2)) >= 32000:
        raise ValueError(f"window {window} with p2 {p2} would overflow the int16 aggregation (module docstring)")
    if overlap < 0:
        raise ValueError(f"overlap must be >= 0, got {overlap}")
    ndisp = dmax - dmin + 1
    h, w = left.shape
    gx = np.abs(np.diff(left[:, :: max(1, w // 2048)], axis=1)) if w > 1 else np.zeros(1, np.float32)
    gx = gx[np.isfinite(gx)]
    g = float(max(np.median(gx), 1e-3 * (np.nanmax(np.abs(left)) or 1.0))) if gx.size else 1.0
    lr = np.inf if lr_check is None else float(lr_check)
    kw = dict(ndisp=ndisp, cost=cost, window=window, paths=paths, whole_range=bool(whole_range))
    args = (p1, p2, g, float(uniqueness), lr)

    if tile is None:
        if h * w * ndisp <= _TILE_BUDGET:
            th, tw = h, w
        else:
            side = int(np.sqrt(_TILE_BUDGET / ndisp)) - 2 * overlap
            th = tw = max(side, 64)
    else:
        th, tw = (tile, tile) if np.ndim(tile) == 0 else tile
        th, tw = int(th), int(tw)
        if th < 1 or tw < 1:
            raise ValueError(f"tile must be positive, got {tile!r}")

    def finish(d):
        d = d if subpixel else np.round(d)
        return _remove_speckles(d, int(speckle_size), float(speckle_range))

    if th >= h and tw >= w:
        return finish(np.asarray(_sgm(left, right, *args, dmin=dmin, **kw))).astype(np.float32)
    return _tiled(left, right, dmin, dmax, args, kw, min(th, h), min(tw, w), int(overlap), finish)


def _tiled(left, right, dmin, dmax, args, kw, th, tw, ov, finish):
    """Tiles of ``th x tw`` cores with ``ov`` px context, each one :func:`_sgm`
    call of one shape (NaN padding), finished (rounding, speckles) on the
    whole tile so that memory stays a tile's, stitched from their cores."""
    h, w = left.shape
    wr = right.shape[1]
    span = dmax - dmin
    out = np.full((h, w), np.nan, np.float32)
    lh, lw = th + 2 * ov, tw + 2 * ov
    for r0 in range(0, h, th):
        for c0 in range(0, w, tw):
            lt = np.full((lh, lw), np.nan, np.float32)
            rt = np.full((lh, lw + span), np.nan, np.float32)
            ra, rb = max(r0 - ov, 0), min(r0 + th + ov, h)
            la, lb = max(c0 - ov, 0), min(c0 + tw + ov, w)
            lt[ra - (r0 - ov) : rb - (r0 - ov), la - (c0 - ov) : lb - (c0 - ov)] = left[ra:rb, la:lb]
            # right columns seen by the tile: left col - dmax ... left col - dmin
            x0 = c0 - ov - dmax
            qa, qb = max(x0, 0), min(x0 + lw + span, wr)
            if qb > qa:
                rt[ra - (r0 - ov) : rb - (r0 - ov), qa - x0 : qb - x0] = right[ra:rb, qa:qb]
            # local disparity: (col - (c0 - ov)) - (col_r - x0) = d - dmax
            d = finish(np.asarray(_sgm(lt, rt, *args, dmin=dmin - dmax, **kw)) + np.float32(dmax))
            rows, cols = min(th, h - r0), min(tw, w - c0)
            out[r0 : r0 + rows, c0 : c0 + cols] = d[ov : ov + rows, ov : ov + cols]
    return out
