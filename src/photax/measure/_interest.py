"""Interest (point) operators: Moravec, Förstner, Harris; non-maximum
suppression and :func:`interest_points`.

Seed 004 (点特征提取算法):

* Moravec (1977): at each pixel the sums of squared grey differences along
  the four directions of a ``k x k`` window (row, column, both diagonals);
  the interest value is their minimum; candidates above a threshold, then
  the local maxima.
* Förstner (Förstner & Gülch 1987): Roberts gradients
  ``gu = g[i+1, j+1] - g[i, j]``, ``gv = g[i, j+1] - g[i+1, j]``, summed
  over a window into ``N = [[sum gu^2, sum gu gv], [sum gu gv, sum gv^2]]``;
  ``w = det N / tr N`` (inverse size of the error ellipse) and
  ``q = 4 det N / tr(N)^2`` (its roundness, 0..1).  Candidates:
  ``q > T_q`` (0.5..0.75) and ``w > T_w = f * mean(w)`` (f = 0.5..1.5) or
  ``T_w = c * median(w)`` (c = 5); then the local maxima of w.
* Harris (Harris & Stephens 1988): ``det A - k tr(A)^2`` from the
  Gaussian-weighted structure tensor of Sobel gradients.
"""

from __future__ import annotations

from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._common import as_image, batched, check_odd_window, inner_mask
from ._filters import Mode, box_sum, gaussian, max_filter, sobel_pair

# ----------------------------------------------------------------- Moravec


@partial(jax.jit, static_argnames=("window",))
def _moravec_seed(img, window):
    k = window // 2
    h, w = img.shape
    p = jnp.pad(img, k + 1)

    def s(dr, dc):
        return p[k + 1 + dr : k + 1 + dr + h, k + 1 + dc : k + 1 + dc + w]

    vs = []
    for dr, dc in ((0, 1), (1, 1), (1, 0), (1, -1)):  # row, diagonal, column, anti-diagonal
        v = jnp.zeros_like(img)
        for i in range(-k, k):
            d = s(i * dr, i * dc) - s((i + 1) * dr, (i + 1) * dc)
            v = v + d * d
        vs.append(v)
    iv = jnp.minimum(jnp.minimum(vs[0], vs[1]), jnp.minimum(vs[2], vs[3]))
    inside = inner_mask((h, w), k)  # full window only
    return jnp.where(inside, iv, 0.0)


@partial(jax.jit, static_argnames=("window",))
def _moravec_shift(img, window):
    k = window // 2
    h, w = img.shape
    p = jnp.pad(img, k)
    best = jnp.full_like(img, jnp.inf)
    for br in range(-k, k + 1):
        for bc in range(-k, k + 1):
            if br == 0 or bc == 0:  # scikit-image's loop keeps only shifts off both axes
                continue
            d = img - p[k + br : k + br + h, k + bc : k + bc + w]
            best = jnp.minimum(best, box_sum(d * d, window))
    inside = inner_mask((h, w), 2 * k)
    return jnp.where(inside, best, 0.0)


def moravec(image, window: int = 5, *, method: Literal["seed", "shift"] = "seed"):
    """Moravec interest value.

    ``"seed"`` (seed 004, Moravec 1977): with ``k = window // 2``,

        V1 = sum_{i=-k}^{k-1} (g[r, c+i] - g[r, c+i+1])^2     (along the row)
        V2 = sum (g[r+i, c+i] - g[r+i+1, c+i+1])^2            (diagonal)
        V3 = sum (g[r+i, c] - g[r+i+1, c])^2                  (along the column)
        V4 = sum (g[r+i, c-i] - g[r+i+1, c-i-1])^2            (anti-diagonal)
        IV = min(V1, V2, V3, V4)

    ``"shift"``: the windowed form of ``skimage.feature.corner_moravec``
    (``window_size = window // 2``): the minimum over shifts
    ``(dr, dc)``, both non-zero and at most k, of the sum over the
    ``window x window`` box of ``(g[p] - g[p + (dr, dc)])^2``; zero within
    ``2 k`` of the border, as there.

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype.
        window: odd window side, pixels.

    Returns:
        float64 interest values (grey^2) of the shape of ``image``; zero
        where the window does not fit.

    Examples:
        Moravec's interest value (the smallest directional variance): 0 in flat areas and along a
        straight edge, large at a corner:

        >>> import numpy as np
        >>> from photax.measure import moravec
        >>> image = np.zeros((30, 30)); image[15:, 15:] = 100.0
        >>> v = np.asarray(moravec(image, 5))
        >>> float(v[5, 5]), float(v[22, 15]), bool(v[15, 15] > 0)
        (0.0, 0.0, True)
    """
    window = check_odd_window(window)
    img, b = as_image(image)
    if method == "seed":
        fn = _moravec_seed
    elif method == "shift":
        fn = _moravec_shift
    else:
        raise ValueError(f"method: expected 'seed' or 'shift', got {method!r}")
    return batched(lambda im: fn(im, window), img, b)


# ----------------------------------------------------- structure tensor


def _structure_roberts_box(img, window):
    # Roberts gradients at the half-pixel points (i + 1/2, j + 1/2); the
    # window of pixel (r, c) holds those with i in r-k..r+k-1 (and j alike),
    # i.e. it covers the pixels r-k..r+k exactly (seed 004, step 2).
    k = window // 2
    gu = img[1:, 1:] - img[:-1, :-1]
    gv = img[:-1, 1:] - img[1:, :-1]
    h, w = img.shape

    def wsum(a):
        # box of 2k half-pixel samples ending at index r + k - 1
        p = jnp.pad(a, [(k, k), (k, k)])  # (h-1, w-1) -> (h-1+2k, w-1+2k)
        c = jnp.cumsum(jnp.cumsum(p, 0), 1)
        c = jnp.pad(c, [(1, 0), (1, 0)])
        # sum over p[r .. r+2k-1, c .. c+2k-1] for r in 0..h-1
        return c[2 * k : 2 * k + h, 2 * k : 2 * k + w] - c[:h, 2 * k : 2 * k + w] - c[2 * k : 2 * k + h, :w] + c[:h, :w]

    return wsum(gu * gu), wsum(gu * gv), wsum(gv * gv)


def _structure_sobel_gauss(img, sigma, mode="constant"):
    # skimage.feature.structure_tensor: unnormalised Sobel (mode constant),
    # products smoothed by a Gaussian (mode constant, truncate 4)
    gr, gc = sobel_pair(img, mode)
    return (gaussian(gr * gr, sigma, mode), gaussian(gr * gc, sigma, mode), gaussian(gc * gc, sigma, mode))


def _safe_div(num, den):
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


@partial(jax.jit, static_argnames=("window", "sigma"))
def _foerstner(img, window, sigma):
    if sigma is None:
        a, b, c = _structure_roberts_box(img, window)
        k = window // 2
        h, w = img.shape
        inside = inner_mask((h, w), k)
    else:
        a, b, c = _structure_sobel_gauss(img, sigma)
        inside = jnp.ones(img.shape, bool)
    det = a * c - b * b
    tr = a + c
    # det can come out a rounding error below zero on an edge: clip
    det = jnp.maximum(det, 0.0)
    wv = jnp.where(inside, _safe_div(det, tr), 0.0)
    qv = jnp.where(inside, _safe_div(4.0 * det, tr * tr), 0.0)
    return wv, qv


def foerstner(image, window: int = 5, *, sigma: float | None = None):
    """Förstner interest measures ``(w, q)``.

    ``w = det N / tr N`` and ``q = 4 det N / tr(N)^2`` (docs/maths.md; seed 004;
    Förstner & Gülch 1987) with ``N`` the sum of ``[gu, gv]^T [gu, gv]``:

    * ``sigma=None`` (the seed): Roberts gradients summed over the
      ``window x window`` box of each pixel; zero where the box does not fit.
    * ``sigma`` given: Sobel gradients (unnormalised, border zero) weighted
      by a Gaussian of that sigma, which is ``skimage.feature.corner_foerstner``.

    Where ``tr N = 0`` (no texture) both measures are 0, never NaN.

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype.
        window: odd box side, pixels (seed form only).
        sigma: Gaussian window, pixels.

    Returns:
        ``(w, q)``, float64 of the shape of ``image``; ``w`` in grey^2,
        ``q`` in [0, 1].

    Examples:
        Förstner's roundness ``q`` is near 1 at a corner and near 0 along a straight edge:

        >>> import numpy as np
        >>> from photax.measure import foerstner
        >>> image = np.zeros((40, 40)); image[20:, 20:] = 1.0
        >>> w, q = foerstner(image, 5)
        >>> q = np.asarray(q)
        >>> bool(q[19, 19] > 0.5), bool(q[30, 19] < 0.1)
        (True, True)
    """
    window = check_odd_window(window)
    img, b = as_image(image)
    sig = None if sigma is None else float(sigma)
    if sig is not None and not sig > 0:
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    return batched(lambda im: _foerstner(im, window, sig), img, b)


@partial(jax.jit, static_argnames=("sigma", "method", "mode"))
def _harris(img, k, eps, sigma, method, mode):
    arr, arc, acc = _structure_sobel_gauss(img, sigma, mode)
    det = arr * acc - arc * arc
    tr = arr + acc
    if method == "k":
        return det - k * tr * tr
    return 2.0 * det / (tr + eps)


def harris(
    image,
    *,
    k: float = 0.05,
    sigma: float = 1.0,
    method: Literal["k", "eps"] = "k",
    eps: float = 1e-6,
    mode: Mode = "constant",
):
    """Harris corner response (Harris & Stephens 1988).

    ``det A - k tr(A)^2`` (``method="k"``) or Noble's ``2 det A / (tr A +
    eps)`` (``"eps"``), with ``A`` the structure tensor of unnormalised
    Sobel gradients (border zero) weighted by a Gaussian of ``sigma``: the
    definition of ``skimage.feature.corner_harris``.

    Args:
        image: ``(h, w)`` or ``(b, h, w)``, any integer or float dtype.
        mode: border mode of the gradients and the window.  scikit-image's
            ``"constant"`` (zero outside) makes the image frame itself an
            edge; :func:`interest_points` uses ``"reflect"``.

    Returns:
        float64 response (grey^4 for ``"k"``) of the shape of ``image``.

    Examples:
        The Harris response of a bright square is largest at its corners, negative on its edges:

        >>> import numpy as np
        >>> from photax.measure import harris
        >>> image = np.zeros((40, 40)); image[10:30, 10:30] = 1.0
        >>> response = np.asarray(harris(image, sigma=1.5))
        >>> r, c = np.unravel_index(np.argmax(response), response.shape)
        >>> bool(min(abs(r - 10), abs(r - 29)) <= 1 and min(abs(c - 10), abs(c - 29)) <= 1), bool(response[20, 10] < 0)
        (True, True)
    """
    img, b = as_image(image)
    if method not in ("k", "eps"):
        raise ValueError(f"method: expected 'k' or 'eps', got {method!r}")
    if not sigma > 0:
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    kk, ee = jnp.asarray(k, jnp.float64), jnp.asarray(eps, jnp.float64)
    return batched(lambda im: _harris(im, kk, ee, float(sigma), method, mode), img, b)


# ------------------------------------------------ non-maximum suppression


@partial(jax.jit, static_argnames=("size",))
def _nms(resp, threshold, size):
    return (resp >= max_filter(resp, size)) & (resp > threshold)


def non_maximum_suppression(response, size: int = 3, threshold: float = 0.0):
    """Local maxima: pixels equal to the maximum of their ``size x size``
    window and above ``threshold``.  (Equal neighbours on a plateau are all
    kept here; :func:`interest_points` thins them by ``min_distance``.)

    Args:
        response: ``(h, w)`` or ``(b, h, w)``.
        size: odd window side, pixels.

    Returns:
        Boolean map of the shape of ``response``.

    Examples:
        The local maxima of a response above a threshold, as a mask:

        >>> import numpy as np
        >>> from photax.measure import non_maximum_suppression
        >>> response = np.zeros((9, 9)); response[2, 3] = 5.0; response[2, 4] = 4.0; response[6, 6] = 1.0
        >>> keep = np.asarray(non_maximum_suppression(response, 3, threshold=2.0))
        >>> np.argwhere(keep).tolist()
        [[2, 3]]
    """
    size = check_odd_window(size, "size")
    resp, b = as_image(response, "response")
    thr = jnp.asarray(threshold, jnp.float64)
    return batched(lambda r: _nms(r, thr, size), resp, b)


class InterestPoints(NamedTuple):
    """Interest points, strongest first.

    Examples:
        What :func:`interest_points` returns: ``xy`` (column, row) and each point's strength:

        >>> import numpy as np
        >>> from photax.measure import interest_points
        >>> image = np.zeros((40, 40)); image[10:30, 10:30] = 1.0
        >>> pts = interest_points(image, "harris", min_distance=5)
        >>> pts.xy.shape[1], len(pts.xy) == len(pts.strength), len(pts.xy) >= 4  # at least the square's corners
        (2, True, True)
    """

    xy: np.ndarray  #: (n, 2) pixel positions (column, row)
    strength: np.ndarray  #: (n,) the operator's value at each point


def interest_points(
    image,
    method: Literal["foerstner", "harris", "moravec"] = "foerstner",
    *,
    window: int = 5,
    min_distance: int = 3,
    max_points: int | None = None,
    q_threshold: float = 0.75,
    w_factor: float = 1.0,
    w_reference: Literal["mean", "median"] = "mean",
    threshold: float | None = None,
    threshold_rel: float = 0.01,
    sigma: float = 1.0,
    k: float = 0.05,
) -> InterestPoints:
    """Interest points of one image: operator, thresholds, local maxima.

    * ``"foerstner"`` (seed 004): candidates with ``q > q_threshold`` and
      ``w > T_w``, ``T_w = w_factor * mean(w)`` (seed: f = 0.5..1.5) or,
      with ``w_reference="median"``, ``w_factor * median(w)`` (seed: c = 5);
      the mean/median are over the pixels where the window fits.  Strength w.
    * ``"harris"`` (border mode ``"reflect"``, so the frame is no corner):
      response above ``threshold`` (default ``threshold_rel`` x the highest
      positive response).  Strength: the response.
    * ``"moravec"`` (seed form): interest value above ``threshold``
      (default ``threshold_rel`` x the highest).  Strength: the value.

    Then the local maxima within ``min_distance`` (a ``2 min_distance + 1``
    window), strongest first, at most ``max_points``.

    Args:
        image: ``(h, w)``, any integer or float dtype (one image: the count
            varies; for batches use the response functions and
            :func:`non_maximum_suppression` under ``vmap``).

    Returns:
        :class:`InterestPoints` with ``xy`` (n, 2: column, row) and
        ``strength`` (n,).  No texture (a constant image): n = 0.

    Examples:
        Förstner interest points of a chequerboard: its inner crossings:

        >>> import numpy as np
        >>> from photax.measure import interest_points
        >>> r, c = np.mgrid[0:48, 0:48]
        >>> board = 200.0 * (((r // 12) + (c // 12)) % 2) + 20.0
        >>> pts = interest_points(board, "foerstner", min_distance=5)
        >>> found = {tuple(int(v) for v in np.round(p / 12.0) * 12) for p in pts.xy}
        >>> {(12, 12), (24, 24), (36, 12)} <= found
        True
    """
    img, b = as_image(image)
    if b:
        raise ValueError("image: interest_points takes one image (h, w); the point count varies per image")
    if method == "foerstner":
        wv, qv = foerstner(img, window)
        wv_np = np.asarray(wv)
        kk = window // 2
        inner = wv_np[kk : wv_np.shape[0] - kk, kk : wv_np.shape[1] - kk]
        if inner.size == 0:
            return InterestPoints(np.zeros((0, 2)), np.zeros(0))
        ref = float(np.mean(inner) if w_reference == "mean" else np.median(inner))
        tw = max(w_factor * ref, 0.0)
        resp = jnp.where(qv > q_threshold, wv, 0.0)
        thr = tw
    elif method in ("harris", "moravec"):
        resp = harris(img, k=k, sigma=sigma, mode="reflect") if method == "harris" else moravec(img, window)
        top = float(jnp.max(resp))
        thr = threshold if threshold is not None else max(threshold_rel * top, 0.0)
    else:
        raise ValueError(f"method: expected 'foerstner', 'harris' or 'moravec', got {method!r}")
    mask = np.asarray(non_maximum_suppression(resp, 2 * min_distance + 1, thr))
    resp = np.asarray(resp)
    rows, cols = np.nonzero(mask)
    keep = _thin(rows, cols, resp[rows, cols], min_distance, max_points, resp.shape)
    xy = np.stack([cols[keep].astype(float), rows[keep].astype(float)], 1).reshape(-1, 2)
    return InterestPoints(xy, resp[rows[keep], cols[keep]].astype(float))


def _thin(rows, cols, score, d: int, max_points: int | None, shape) -> np.ndarray:
    """Indices of the points kept, strongest first: a point is dropped when
    a stronger kept one is within ``d`` pixels in both row and column (one
    point per plateau).  Each kept point blocks its ``(2d + 1)^2`` square in
    an occupancy image, so a candidate costs one lookup: linear in the
    number of candidates (comparing with every kept point was quadratic:
    minutes for the tens of thousands of maxima of a large image)."""
    blocked = np.zeros(shape, bool)
    keep = []
    for i in np.argsort(-score, kind="stable"):
        r, c = rows[i], cols[i]
        if blocked[r, c]:
            continue
        keep.append(i)
        if max_points is not None and len(keep) >= max_points:
            break
        blocked[max(r - d, 0) : r + d + 1, max(c - d, 0) : c + d + 1] = True
    return np.array(keep, dtype=np.int64)
