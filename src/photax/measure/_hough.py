"""Hough transform for straight lines and for circles of given radii.

Seed 004 (Hough 变换): every edge point (x, y) = (column, row) votes for
all lines ``rho = x cos(theta) + y sin(theta)`` through it; peaks of the
accumulator are the lines.  Votes are split linearly between the two
nearest rho bins (and, for circles, bilinearly between the four nearest
centre pixels), so the accumulator is a smooth function of the parameters
and its peaks can be refined below the bin size.  The accumulator is built
in JAX from the list of edge points; finding a variable number of peaks is
done on the host (numpy/scipy).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.ndimage as ndi

from ._common import as_image


class HoughLines(NamedTuple):
    """Lines ``rho = x cos(theta) + y sin(theta)`` in pixel coordinates
    (x = column, y = row, origin at the centre of the top-left pixel;
    theta in [0, pi) radians from the column axis towards the row axis,
    rho in pixels, signed).

    Examples:
        What :func:`hough_lines` returns: each line's normal angle ``theta`` and distance ``rho``
        (``col cos(theta) + row sin(theta) = rho``), its strength, and the accumulator:

        >>> import numpy as np
        >>> from photax.measure import hough_lines
        >>> edges = np.zeros((40, 40), bool); edges[:, 12] = True  # the column 12
        >>> lines = hough_lines(edges, max_lines=1)
        >>> print(f"{np.degrees(lines.theta[0]):.1f} {lines.rho[0]:.2f}")
        0.0 12.00
    """

    theta: np.ndarray  #: (n,) radians, refined
    rho: np.ndarray  #: (n,) pixels, refined
    strength: np.ndarray  #: (n,) accumulator value at the peak (sum of edge weights)
    accumulator: np.ndarray  #: (n_theta, n_rho)
    thetas: np.ndarray  #: (n_theta,) bin centres, radians
    rhos: np.ndarray  #: (n_rho,) bin centres, pixels


class HoughCircles(NamedTuple):
    """Circles of the given radii; centres in pixel coordinates (column, row).

    Examples:
        What :func:`hough_circles` returns: centres ``xy`` (column, row), radii and strengths:

        >>> import numpy as np
        >>> from photax.measure import hough_circles
        >>> t = np.linspace(0, 2 * np.pi, 300)
        >>> edges = np.zeros((40, 40), bool)
        >>> edges[np.round(20 + 7 * np.sin(t)).astype(int), np.round(18 + 7 * np.cos(t)).astype(int)] = True
        >>> found = hough_circles(edges, [6, 7, 8], max_circles=1)
        >>> found.xy.shape, np.round(found.xy[0]).tolist(), float(np.round(found.radius[0]))
        ((1, 2), [18.0, 20.0], 7.0)
    """

    xy: np.ndarray  #: (n, 2) centres, refined
    radius: np.ndarray  #: (n,) radius (one of ``radii``)
    strength: np.ndarray  #: (n,) accumulator value at the centre (edge weight on the circle / samples)
    accumulator: np.ndarray  #: (n_radii, h, w)
    radii: np.ndarray  #: (n_radii,)


def _edge_points(edges, name="edges"):
    img, is_batch = as_image(edges, name)
    if is_batch:
        raise ValueError(f"{name}: Hough takes one image (h, w); loop over a batch (the peak count varies)")
    e = np.asarray(img)
    if not np.all(np.isfinite(e)):
        raise ValueError(f"{name}: contains NaN or inf")
    rows, cols = np.nonzero(e)
    wts = e[rows, cols]
    # Pad to a power of two so repeated calls reuse the compiled accumulator.
    n = len(rows)
    size = max(64, 1 << max(n - 1, 1).bit_length())
    pad = size - n
    xy = np.stack([np.pad(cols, (0, pad)), np.pad(rows, (0, pad))], 1).astype(np.float64)
    return e.shape, xy, np.pad(wts, (0, pad)), (cols.astype(np.float64), rows.astype(np.float64), wts)


@partial(jax.jit, static_argnames=("n_rho",))
def _line_accumulator(xy, wts, thetas, rho0, drho, n_rho):
    def one(theta):
        rho = xy[:, 0] * jnp.cos(theta) + xy[:, 1] * jnp.sin(theta)
        t = (rho - rho0) / drho
        i0 = jnp.floor(t)
        f = t - i0
        i0 = i0.astype(jnp.int32)
        acc = jnp.zeros(n_rho + 1).at[i0].add(wts * (1.0 - f), mode="drop")
        return acc.at[i0 + 1].add(wts * f, mode="drop")[:n_rho]

    return jax.lax.map(one, thetas)


def _quadratic_offset(m, z, p):
    """Vertex of the parabola through (-1, m), (0, z), (1, p), clipped to +-0.5."""
    den = m - 2.0 * z + p
    return np.clip(np.where(den < 0, 0.5 * (m - p) / np.where(den < 0, den, -1.0), 0.0), -0.5, 0.5)


def _peaks(acc, size, threshold, max_peaks):
    """Local maxima of ``acc`` (``size`` window, ``> threshold``), strongest first."""
    local = ndi.maximum_filter(acc, size=size, mode="constant", cval=-np.inf)
    idx = np.argwhere((acc == local) & (acc > threshold))
    order = np.argsort(-acc[tuple(idx.T)], kind="stable")
    idx = idx[order]
    # plateaus give several equal maxima next to each other: keep the first
    keep = []
    for p in idx:
        if all(np.max(np.abs(p - q)) >= size // 2 + 1 for q in keep):
            keep.append(p)
        if len(keep) == max_peaks:
            break
    return np.array(keep, dtype=int).reshape(-1, acc.ndim)


def _same_line(t1, r1, t2, r2, dt, dr):
    d = abs(t1 - t2)
    if d <= dt + 1e-12:
        return abs(r1 - r2) <= dr
    if math.pi - d <= dt + 1e-12:
        return abs(r1 + r2) <= dr
    return False


def hough_lines(
    edges,
    *,
    theta_step: float = math.radians(0.5),
    rho_step: float = 1.0,
    threshold: float = 0.5,
    max_lines: int = 10,
    min_distance: int = 5,
    refine: bool = True,
):
    """Straight lines by the Hough transform, refined below the bin size.

    Each edge pixel (x, y) with weight ``e[y, x]`` (a boolean map counts 1)
    adds its weight along ``rho = x cos(theta) + y sin(theta)`` for each
    theta bin, split linearly between the two nearest rho bins.  Peaks are
    the local maxima above ``threshold`` x the highest bin; each is refined
    by a parabola through its neighbours in theta and in rho, then (with
    ``refine``) by a total-least-squares line fitted to the edge points
    within ``2 rho_step`` (at least 1.5 px) of it, twice.

    Args:
        edges: ``(h, w)`` edge map (bool, or non-negative weights).
        theta_step: bin width in theta, radians (default 0.5 degrees).
        rho_step: bin width in rho, pixels.
        threshold: peaks below ``threshold * max(accumulator)`` are ignored.
        max_lines: at most this many lines, strongest first.
        min_distance: minimal separation of two peaks, in bins.
        refine: fit each line to its edge points.

    Returns:
        :class:`HoughLines` (numpy arrays).  No edge pixel: no line.

    Examples:
        A straight line of edge pixels, column = row + 5 (normal at -45 degrees), found back:

        >>> import numpy as np
        >>> from photax.measure import hough_lines
        >>> edges = np.zeros((60, 60), bool)
        >>> edges[np.arange(50), np.arange(50) + 5] = True
        >>> lines = hough_lines(edges, max_lines=1)
        >>> print(f"{np.degrees(lines.theta[0]) % 180:.1f} deg, |rho| {abs(lines.rho[0]):.2f} px")  # 5 / sqrt(2) = 3.54
        135.0 deg, |rho| 3.54 px
    """
    shape, xy, wts, (xs, ys, ws) = _edge_points(edges)
    if not (theta_step > 0 and rho_step > 0):
        raise ValueError("theta_step and rho_step must be positive")
    h, w = shape
    n_theta = int(round(math.pi / theta_step))
    thetas = np.arange(n_theta) * (math.pi / n_theta)
    dmax = math.hypot(h - 1, w - 1)
    n_rho = 2 * int(math.ceil(dmax / rho_step)) + 3
    rho0 = -(n_rho // 2) * rho_step
    rhos = rho0 + np.arange(n_rho) * rho_step
    acc = np.asarray(
        _line_accumulator(jnp.asarray(xy), jnp.asarray(wts), jnp.asarray(thetas), rho0, float(rho_step), n_rho)
    )
    empty = HoughLines(np.zeros(0), np.zeros(0), np.zeros(0), acc, thetas, rhos)
    if len(xs) == 0 or acc.max() <= 0:
        return empty
    pk = _peaks(acc, 2 * min_distance + 1, threshold * acc.max(), 2 * max_lines + 2)
    out_t, out_r, out_s = [], [], []
    for i, j in pk:
        if len(out_t) == max_lines:
            break
        # theta = 0 and theta = pi are the same line with rho negated: a line
        # near theta = 0 may peak at both ends of the accumulator; keep one
        if any(
            _same_line(thetas[i], rhos[j], t, r, min_distance * (math.pi / n_theta), min_distance * rho_step)
            for t, r in zip(out_t, out_r)
        ):
            continue
        z = acc[i, j]
        # neighbours in theta: across 0/pi the line is (theta -+ pi, -rho)
        im = acc[i - 1, j] if i > 0 else acc[n_theta - 1, n_rho - 1 - j]
        ip = acc[i + 1, j] if i < n_theta - 1 else acc[0, n_rho - 1 - j]
        jm = acc[i, j - 1] if j > 0 else 0.0
        jp = acc[i, j + 1] if j < n_rho - 1 else 0.0
        theta = thetas[i] + float(_quadratic_offset(im, z, ip)) * (math.pi / n_theta)
        rho = rhos[j] + float(_quadratic_offset(jm, z, jp)) * rho_step
        if refine:
            theta, rho = _refine_line(xs, ys, ws, theta, rho, max(1.5, 2.0 * rho_step))
        theta, rho = theta % (2 * math.pi), rho
        if theta >= math.pi:
            theta, rho = theta - math.pi, -rho
        out_t.append(theta)
        out_r.append(rho)
        out_s.append(z)
    return HoughLines(np.array(out_t), np.array(out_r), np.array(out_s), acc, thetas, rhos)


def _refine_line(xs, ys, ws, theta: float, rho: float, band: float) -> tuple[float, float]:
    """Two weighted total-least-squares fits of the edge pixels within
    ``band`` of the line ``x cos(theta) + y sin(theta) = rho``: the normal is
    the direction of least spread of their weighted scatter matrix."""
    for _ in range(2):
        d = xs * math.cos(theta) + ys * math.sin(theta) - rho
        sel = np.abs(d) <= band
        if sel.sum() < 2:
            break
        wsel = ws[sel]
        mx, my = np.average(xs[sel], weights=wsel), np.average(ys[sel], weights=wsel)
        dx, dy = xs[sel] - mx, ys[sel] - my
        cov = np.array(
            [[np.sum(wsel * dx * dx), np.sum(wsel * dx * dy)], [np.sum(wsel * dx * dy), np.sum(wsel * dy * dy)]]
        )
        _, evecs = np.linalg.eigh(cov)
        nrm = evecs[:, 0]  # normal = direction of least spread
        if nrm @ np.array([math.cos(theta), math.sin(theta)]) < 0:
            nrm = -nrm
        theta = math.atan2(nrm[1], nrm[0])
        rho = mx * nrm[0] + my * nrm[1]
    return theta, rho


@partial(jax.jit, static_argnames=("shape", "n_phi"))
def _circle_accumulator(xy, wts, radius, shape, n_phi):
    h, w = shape
    phi = jnp.arange(n_phi, dtype=jnp.float64) * (2 * jnp.pi / n_phi)
    cx = (xy[:, 0:1] + radius * jnp.cos(phi)[None, :]).reshape(-1)
    cy = (xy[:, 1:2] + radius * jnp.sin(phi)[None, :]).reshape(-1)
    v = jnp.repeat(wts / n_phi, n_phi)
    x0, y0 = jnp.floor(cx), jnp.floor(cy)
    fx, fy = cx - x0, cy - y0
    x0, y0 = x0.astype(jnp.int32), y0.astype(jnp.int32)
    acc = jnp.zeros((h + 2, w + 2))
    # one pixel of margin so bilinear splats just outside are dropped, not wrapped
    for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        acc = acc.at[y0 + dy + 1, x0 + dx + 1].add(v * wt, mode="drop")
    return acc[1:-1, 1:-1]


def hough_circles(
    edges, radii, *, threshold: float = 0.3, max_circles: int = 10, min_distance: int = 3, refine: bool = True
):
    """Circles of known radii by the Hough transform.

    Each edge pixel votes, for each radius r, for the centres on the circle
    of radius r around it (``max(32, 4 r)`` samples, each splatted
    bilinearly, weight ``e / n``), so the value at a centre is the summed
    weight of the edge pixels on its circle divided by ``n`` (about 1 to 1.5
    for a complete one-pixel-wide circle).  Peaks above ``threshold`` x the
    highest vote are refined by a parabola per axis and then (``refine``) by
    Gauss-Newton on ``sum (|p - c| - r)^2`` over the edge points within
    2 px of the circle.

    Args:
        edges: ``(h, w)`` edge map (bool or non-negative weights).
        radii: radii to look for, pixels (scalar or sequence).
        threshold: relative to the highest accumulator value.
        max_circles: at most this many circles, strongest first.
        min_distance: minimal separation of two centres, pixels (and one
            radius step).

    Returns:
        :class:`HoughCircles` (numpy arrays).

    Examples:
        A circle of radius 8 drawn around (30, 25), found back among radii 6-10:

        >>> import numpy as np
        >>> from photax.measure import hough_circles
        >>> t = np.linspace(0, 2 * np.pi, 400)
        >>> edges = np.zeros((60, 60), bool)
        >>> edges[np.round(25 + 8 * np.sin(t)).astype(int), np.round(30 + 8 * np.cos(t)).astype(int)] = True
        >>> circles = hough_circles(edges, np.arange(6, 11), max_circles=1)
        >>> print(np.round(circles.xy, 0) + 0.0, np.round(circles.radius, 0))
        [[30. 25.]] [8.]
    """
    shape, xy, wts, (xs, ys, ws) = _edge_points(edges)
    radii = np.atleast_1d(np.asarray(radii, dtype=np.float64))
    if radii.ndim != 1 or not np.all(radii > 0):
        raise ValueError("radii: expected positive radii in pixels")
    accs = []
    for r in radii:
        n_phi = int(max(32, 4 * math.ceil(r)))
        n_phi = 1 << (n_phi - 1).bit_length()  # few distinct compiled shapes
        accs.append(np.asarray(_circle_accumulator(jnp.asarray(xy), jnp.asarray(wts), float(r), shape, n_phi)))
    acc = np.stack(accs)
    empty = HoughCircles(np.zeros((0, 2)), np.zeros(0), np.zeros(0), acc, radii)
    if len(xs) == 0 or acc.max() <= 0:
        return empty
    size = (3, 2 * min_distance + 1, 2 * min_distance + 1)
    local = ndi.maximum_filter(acc, size=size, mode="constant", cval=-np.inf)
    idx = np.argwhere((acc == local) & (acc > threshold * acc.max()))
    idx = idx[np.argsort(-acc[tuple(idx.T)], kind="stable")]
    keep = []
    for p in idx:
        if all(np.hypot(*(p[1:] - q[1:])) > min_distance for q in keep):
            keep.append(p)
        if len(keep) == max_circles:
            break
    out_xy, out_r, out_s = [], [], []
    H, W = shape
    for k, r0, c0 in keep:
        a = acc[k]
        z = a[r0, c0]
        dy = _quadratic_offset(a[r0 - 1, c0] if r0 > 0 else 0.0, z, a[r0 + 1, c0] if r0 < H - 1 else 0.0)
        dx = _quadratic_offset(a[r0, c0 - 1] if c0 > 0 else 0.0, z, a[r0, c0 + 1] if c0 < W - 1 else 0.0)
        c = np.array([c0 + float(dx), r0 + float(dy)])
        rad = radii[k]
        if refine:
            for _ in range(5):
                d = np.hypot(xs - c[0], ys - c[1])
                sel = (np.abs(d - rad) <= 2.0) & (d > 0)
                if sel.sum() < 3:
                    break
                u = np.stack([(c[0] - xs[sel]) / d[sel], (c[1] - ys[sel]) / d[sel]], 1)  # d(d)/dc
                res = d[sel] - rad
                wsel = ws[sel]
                N = (u * wsel[:, None]).T @ u
                if np.linalg.cond(N) > 1e8:
                    break
                c = c - np.linalg.solve(N, (u * wsel[:, None]).T @ res)
        out_xy.append(c)
        out_r.append(rad)
        out_s.append(z)
    return HoughCircles(np.array(out_xy).reshape(-1, 2), np.array(out_r), np.array(out_s), acc, radii)
