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
   the 6 vertical and diagonal paths share one scan over the rows, the 2
   horizontal ones one scan over the columns;
3. winner-take-all ``d* = argmin_d S(p, d)``; sub-pixel by the parabola
   through ``S(d*-1), S(d*), S(d*+1)``; rejected when another disparity
   ``|d - d*| > 1`` has ``S(d) * (1 - uniqueness) < S(d*)``;
4. left-right check: the right image's disparities come from the same ``S``
   (``S_R(q, d) = S(q + d, d)``), a left disparity is kept when the right
   one at ``col - d`` agrees to ``lr_check`` px;
5. speckle removal: 4-connected regions of valid disparities whose
   neighbours differ by at most ``speckle_range`` px, smaller than
   ``speckle_size`` pixels, are set to NaN (scipy's connected components).

Memory and precision: the cost volume and the aggregated costs are float32
(costs are small integers or bounded by the census' bit count, P1/P2 at most a
few hundred: float32 holds sums of 8 paths exactly to far below a disparity
step); the disparities come back as float32 (sub-pixel values to ~1e-5 px).
A tile of ``h x w`` pixels and ``n`` disparities holds about ``6 h w n``
float32 at once; big images are cut into tiles with ``overlap`` pixels on
every side (the aggregation paths run across the overlap, and only the
tile's core is kept), so memory is bounded whatever the image size.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["disparity", "disparity_range_from_ties"]

_BIG = 1.0e6  # "no such disparity" in the aggregation: above any real cost, far below float32's limit
_TILE_BUDGET = 2**27  # float32 entries of one tile's cost volume (512 MiB) before tiling kicks in


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


def _cost_volume(left, right, dmin, ndisp: int, cost: str, window: int):
    """``(C (h, wl, n) float32, left validity (h, wl), maximum cost)`` for the
    disparities ``dmin + k``, ``k < n`` (right column = left column - d)."""
    h, wl = left.shape
    wr = right.shape[1]
    vl, vr = jnp.isfinite(left), jnp.isfinite(right)
    left, right = jnp.where(vl, left, 0.0), jnp.where(vr, right, 0.0)
    xr = jnp.arange(wl)[:, None] - (dmin + jnp.arange(ndisp))[None, :]  # (wl, n)
    inside = (xr >= 0) & (xr < wr)
    xr = jnp.clip(xr, 0, wr - 1)
    nbits = window * window - 1
    if cost == "census":
        cl, okl = _census(left, vl, window)
        cr, okr = _census(right, vr, window)
        diff = jax.lax.population_count(cl[:, :, None, :] ^ cr[:, xr, :]).astype(jnp.int32).sum(-1)
        c = diff.astype(jnp.float32)
    else:  # zncc on window x window patches, 1 - rho scaled to the census' bit count
        r = window // 2
        n = float(window * window)
        okl = vl & (_box(vl.astype(jnp.float32), r) == n)
        okr = vr & (_box(vr.astype(jnp.float32), r) == n)
        ml, mr = _box(left, r) / n, _box(right, r) / n
        sl = jnp.sqrt(jnp.maximum(_box(left * left, r) / n - ml * ml, 0.0))
        sr = jnp.sqrt(jnp.maximum(_box(right * right, r) / n - mr * mr, 0.0))
        rs = right[:, xr]  # (h, wl, n): the right pixel of each candidate
        cross = _box(left[:, :, None] * rs, r) / n  # window mean of l * r(x - d), per disparity
        # the right window of candidate d is centred at x - d: its moments are those of the right image there
        rho = (cross - ml[:, :, None] * mr[:, xr]) / jnp.maximum(sl[:, :, None] * sr[:, xr], 1e-6)
        c = (jnp.clip(1.0 - rho, 0.0, 2.0) * (nbits / 2.0)).astype(jnp.float32)
        okr = okr & (sr > 0)
    ok = inside & okr[:, xr]
    c = jnp.where(ok & okl[:, :, None], c, nbits / 2.0)
    return c.astype(jnp.float32), okl, float(nbits)


def _aggregate_step(prev, c, p1, p2):
    """One SGM recursion step for a stack of paths: ``prev``, ``c`` ``(..., n)``, ``p2`` ``(..., 1)``."""
    m = prev.min(-1, keepdims=True)
    big = jnp.full(prev.shape[:-1] + (1,), _BIG, prev.dtype)
    lo = jnp.concatenate([big, prev[..., :-1]], -1)
    hi = jnp.concatenate([prev[..., 1:], big], -1)
    best = jnp.minimum(jnp.minimum(prev, jnp.minimum(lo, hi) + p1), m + p2)
    return c + best - m


def _p2(diff, p1, p2, g):
    return jnp.maximum(p2 / (1.0 + jnp.abs(diff) / g), p1)[..., None]


def _shift(a, dx: int):
    """``a[..., x - dx, :]`` along the second-to-last axis, zeros where that falls outside."""
    if dx == 0:
        return a
    z = jnp.zeros_like(a[..., :1, :])
    return jnp.concatenate([z, a[..., :-1, :]], -2) if dx > 0 else jnp.concatenate([a[..., 1:, :], z], -2)


def _aggregate(c, image, p1, p2, g, paths: int):
    """``S = sum_r L_r`` ``(h, w, n)`` over 4 or 8 paths."""
    h, w, n = c.shape
    img = jnp.where(jnp.isfinite(image), image, 0.0).astype(jnp.float32)
    dxs = (0,) if paths == 4 else (0, 1, -1)
    # vertical and diagonal paths: one scan over the rows, top-down and bottom-up together
    cs = jnp.stack([c, c[::-1]], 1)  # (h, 2, w, n)
    ims = jnp.stack([img, img[::-1]], 1)  # (h, 2, w)

    def rows(carry, x):
        prev, prev_img = carry  # (2, k, w, n), (2, w)
        cr, ir = x
        outs = []
        for j, dx in enumerate(dxs):
            pv = _shift(prev[:, j], dx)
            pi = _shift(prev_img[..., None], dx)[..., 0]
            pen = _p2(ir - pi, p1, p2, g)
            outs.append(_aggregate_step(pv, cr, p1, pen))
        new = jnp.stack(outs, 1)
        return (new, ir), new.sum(1)

    init = (jnp.zeros((2, len(dxs), w, n), jnp.float32), ims[0])
    _, ys = jax.lax.scan(rows, init, (cs, ims))  # (h, 2, w, n)
    s = ys[:, 0] + ys[::-1, 1]
    # horizontal paths: one scan over the columns, left-right and right-left together
    ct = jnp.swapaxes(c, 0, 1)
    cs = jnp.stack([ct, ct[::-1]], 1)  # (w, 2, h, n)
    imt = img.T
    ims = jnp.stack([imt, imt[::-1]], 1)

    def cols(carry, x):
        prev, prev_img = carry
        cc, ic = x
        new = _aggregate_step(prev, cc, p1, _p2(ic - prev_img, p1, p2, g))
        return (new, ic), new

    init = (jnp.zeros((2, h, n), jnp.float32), ims[0])
    _, ys = jax.lax.scan(cols, init, (cs, ims))  # (w, 2, h, n)
    return s + jnp.swapaxes(ys[:, 0] + ys[::-1, 1], 0, 1)


def _wta(s, dmin, uniqueness):
    """Sub-pixel winner and its uniqueness flag along the last axis of ``s``."""
    n = s.shape[-1]
    k = jnp.argmin(s, -1)
    take = lambda i: jnp.take_along_axis(s, jnp.clip(i, 0, n - 1)[..., None], -1)[..., 0]  # noqa: E731
    s0, sm, sp = take(k), take(k - 1), take(k + 1)
    den = sm - 2.0 * s0 + sp
    inner = (k > 0) & (k < n - 1) & (den > 0)
    off = jnp.where(inner, (sm - sp) / jnp.where(inner, 2.0 * den, 1.0), 0.0)
    ks = jnp.arange(n)
    far = jnp.abs(ks - k[..., None]) > 1
    second = jnp.where(far, s, jnp.inf).min(-1)
    unique = second * (1.0 - uniqueness) >= s0
    return (dmin + k).astype(jnp.float32) + jnp.clip(off, -0.5, 0.5), unique, s0 < _BIG / 2


@partial(jax.jit, static_argnames=("ndisp", "cost", "window", "paths"))
def _sgm(left, right, dmin, p1, p2, g, uniqueness, lr_check, *, ndisp, cost, window, paths):
    """Disparities ``(h, wl)`` float32 (NaN invalid) of ``left`` against ``right``
    for ``d = dmin + k``, ``k < ndisp``, before speckle removal."""
    c, okl, _ = _cost_volume(left, right, dmin, ndisp, cost, window)
    s = _aggregate(c, left, p1, p2, g, paths)
    dl, unique, _ = _wta(s, dmin, uniqueness)
    h, wl, n = s.shape
    wr = right.shape[1]
    # the right image's disparities by the same S: S_R(q, k) = S(q + dmin + k, k)
    xl = jnp.arange(wr)[:, None] + (dmin + jnp.arange(n))[None, :]
    inside = (xl >= 0) & (xl < wl)
    sr = jnp.where(inside[None], s[:, jnp.clip(xl, 0, wl - 1), jnp.arange(n)[None, :]], _BIG)
    dr, _, _ = _wta(sr, dmin, 0.0)
    x = jnp.arange(wl, dtype=jnp.float32)[None, :]
    q = jnp.round(x - dl).astype(jnp.int32)
    qin = (q >= 0) & (q < wr)
    back = jnp.take_along_axis(dr, jnp.clip(q, 0, wr - 1), 1)
    ok = okl & unique & qin & (jnp.abs(back - dl) <= lr_check)
    return jnp.where(ok, dl, jnp.nan)


def _remove_speckles(d, size: int, rng: float):
    """NaN for 4-connected regions (neighbours within ``rng`` px) of fewer than ``size`` pixels."""
    if size <= 0:
        return d
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    h, w = d.shape
    ok = np.isfinite(d)
    idx = np.arange(h * w).reshape(h, w)
    a, b = [], []
    with np.errstate(invalid="ignore"):
        e = ok[:, 1:] & ok[:, :-1] & (np.abs(d[:, 1:] - d[:, :-1]) <= rng)
        a.append(idx[:, 1:][e])
        b.append(idx[:, :-1][e])
        e = ok[1:] & ok[:-1] & (np.abs(d[1:] - d[:-1]) <= rng)
        a.append(idx[1:][e])
        b.append(idx[:-1][e])
    a, b = np.concatenate(a), np.concatenate(b)
    g = sp.coo_matrix((np.ones(a.size, np.int8), (a, b)), shape=(h * w, h * w)).tocsr()
    _, labels = connected_components(g, directed=False)
    counts = np.bincount(labels, minlength=labels.max() + 1)
    small = (counts[labels] < size).reshape(h, w)
    out = d.copy()
    out[small & ok] = np.nan
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
    disparity_range: tuple[int, int] | None = None,
    ties=None,
    cost: str = "census",
    window: int | None = None,
    p1: float | None = None,
    p2: float | None = None,
    paths: int = 8,
    subpixel: bool = True,
    uniqueness: float = 0.05,
    lr_check: float | None = 1.0,
    speckle_size: int = 100,
    speckle_range: float = 2.0,
    tile: int | tuple[int, int] | None = None,
    overlap: int = 32,
) -> np.ndarray:
    """Dense disparity map of a rectified (epipolar) pair by semi-global matching.

    Convention: ``d = col_left - col_right`` (px), rows aligned; the left pixel
    ``(col, row)`` is seen in the right image at ``(col - d, row)``
    (docs/conventions.md, "Stereo"; the module docstring has the algorithm).

    Args:
        left, right: ``(rows, cols)`` grey images (any real dtype), the same
            number of rows; NaN marks pixels without data (no match there).
        disparity_range: ``(dmin, dmax)`` integer disparities searched, both
            included (``dmax - dmin + 1`` candidates).
        ties: instead of a range, ``(n, 2)`` tie points ``(x_left, x_right)``:
            the range is :func:`disparity_range_from_ties` of them.
        cost: ``"census"`` (Hamming distance of ``window`` x ``window`` census
            strings) or ``"zncc"`` (``(1 - rho) (window^2 - 1) / 2``).
        window: cost window (odd; 7 for census, 5 for zncc by default).
        p1: penalty of a 1 px disparity change along a path, in cost units
            (census bits); default ``window^2 / 6``.
        p2: penalty of a larger jump on a flat image, divided by
            ``1 + |dI| / g`` at an intensity step ``dI`` along the path (never
            below ``p1``); default ``window^2``.
        paths: 4 (horizontal and vertical) or 8 (and the diagonals).
        subpixel: parabola fit through the aggregated costs; else integers.
        uniqueness: reject when a disparity more than 1 px from the winner
            costs less than ``winner / (1 - uniqueness)``; 0 turns it off.
        lr_check: keep a disparity when the right image's own disparity at
            ``col - d`` agrees to this many px; None turns it off.
        speckle_size: regions of similar disparity smaller than this many
            pixels become NaN; 0 turns it off.
        speckle_range: the largest disparity step (px) inside one region.
        tile: ``(rows, cols)`` (or one int for both) of the tiles' cores;
            None: one tile when the cost volume holds at most 2^27 float32
            (512 MiB), else square tiles of about that volume.
        overlap: pixels of context on every side of a tile (the aggregation
            paths cross it; only the core is kept).

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
        window = 7 if cost == "census" else 5
    if int(window) != window or window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd integer >= 3, got {window!r}")
    window = int(window)
    if disparity_range is None:
        if ties is None:
            raise ValueError("give disparity_range=(dmin, dmax) or ties=(n, 2) (x_left, x_right) to bound the search")
        disparity_range = disparity_range_from_ties(ties)
    elif ties is not None:
        raise ValueError("give disparity_range or ties, not both")
    try:
        dmin, dmax = (int(v) for v in disparity_range)
    except (TypeError, ValueError):
        raise ValueError(f"disparity_range must be two integers (dmin, dmax), got {disparity_range!r}") from None
    if dmax < dmin:
        raise ValueError(f"disparity_range is empty: dmax {dmax} < dmin {dmin}")
    p1 = float(window * window / 6.0 if p1 is None else p1)
    p2 = float(window * window if p2 is None else p2)
    if not (p1 >= 0 and p2 >= 0):
        raise ValueError(f"p1 and p2 must be >= 0, got {p1}, {p2}")
    if overlap < 0:
        raise ValueError(f"overlap must be >= 0, got {overlap}")
    ndisp = dmax - dmin + 1
    h, w = left.shape
    gx = np.abs(np.diff(left[:, :: max(1, w // 2048)], axis=1)) if w > 1 else np.zeros(1, np.float32)
    gx = gx[np.isfinite(gx)]
    g = float(max(np.median(gx), 1e-3 * (np.nanmax(np.abs(left)) or 1.0))) if gx.size else 1.0
    lr = np.inf if lr_check is None else float(lr_check)
    kw = dict(ndisp=ndisp, cost=cost, window=window, paths=paths)
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
    if th >= h and tw >= w:
        out = np.asarray(_sgm(left, right, dmin, *args, **kw))
    else:
        out = _tiled(left, right, dmin, dmax, args, kw, min(th, h), min(tw, w), int(overlap))
    if not subpixel:
        out = np.round(out)
    return _remove_speckles(out, int(speckle_size), float(speckle_range)).astype(np.float32)


def _tiled(left, right, dmin, dmax, args, kw, th, tw, ov):
    """Tiles of ``th x tw`` cores with ``ov`` px context, each one :func:`_sgm`
    call of one shape (NaN padding), stitched from their cores."""
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
            d = np.asarray(_sgm(lt, rt, dmin - dmax, *args, **kw)) + np.float32(dmax)
            rows, cols = min(th, h - r0), min(tw, w - c0)
            out[r0 : r0 + rows, c0 : c0 + cols] = d[ov : ov + rows, ov : ov + cols]
    return out
