"""Seamless mosaics of orthophotos: seamlines, gain/offset balancing, feathering.

:func:`mosaic` joins georeferenced orthos (``xarray.DataArray`` with a
rioxarray georeference, e.g. from :func:`photax.orthorectify_dask`, all on
one CRS and one pixel lattice):

1. **Balancing** (optional): a gain and an offset per image,
   ``v' = g_i v + o_i``, by linear least squares over every overlapping pair,
   ``sum_pairs sum_overlap (g_i v_i + o_i - g_j v_j - o_j)^2 +
   lam sum_i ((g_i - 1)^2 + o_i^2)`` (the weak prior fixes the datum: without
   it all gains could shrink to 0).  Only the pairs' first and second moments
   enter the normal equations.
2. **Seamlines**: images are added one at a time in a canonical order (by
   their footprint centre, not the order given, so the result does not
   depend on it).  In each overlap between the mosaic so far and the next
   image the seam is the **minimum s-t cut** (Kwatra et al. 2003,
   "Graphcut textures") of the 4-neighbour graph whose edge costs are the
   grey-value difference of the two (balanced) images at both ends, plus a
   large penalty on raised objects (``dsm - dem`` above ``raised``) so the
   seam goes round buildings and trees; terminals are the overlap pixels
   touching either image's own area.  ``method="voronoi"``: each pixel from
   the image whose nadir is nearest (the simple option).
3. **Feathering**: across each seam the images are blended linearly over
   ``feather`` pixels on either side (weights from distance transforms of
   the labels).

The work is done in memory with numpy/scipy (scipy's maximum flow for the
cuts); the result is returned as a Dask-backed DataArray so that it writes
with :func:`photax.tiled.to_raster` (``cog=True`` for a Cloud-Optimized
GeoTIFF) like the orthos.  A mosaic larger than memory is not handled yet.
"""

from __future__ import annotations

import math

import numpy as np

_SCALE = 1000  # integer edge capacities: cost units per grey-value unit


def _lattice(orthos):
    """The union grid ``(transform, shape, crs)`` and each ortho's
    ``(row, col)`` offset in it; ValueError on different CRSs or lattices."""
    from rasterio import Affine

    crs = orthos[0].rio.crs
    t0 = orthos[0].rio.transform()
    if t0.b != 0 or t0.d != 0:
        raise ValueError("orthos must be north-up (no rotation in the transform)")
    boxes = []
    for k, o in enumerate(orthos):
        if o.rio.crs != crs:
            raise ValueError(f"orthos[{k}] is in {o.rio.crs}, orthos[0] in {crs}: reproject them to one CRS first")
        t = o.rio.transform()
        if not (math.isclose(t.a, t0.a, rel_tol=1e-9) and math.isclose(t.e, t0.e, rel_tol=1e-9) and t.b == t.d == 0):
            raise ValueError(f"orthos[{k}] has pixel size {(t.a, t.e)}, orthos[0] {(t0.a, t0.e)}: one resolution only")
        c, r = (t.c - t0.c) / t0.a, (t.f - t0.f) / t0.e
        if abs(c - round(c)) > 1e-6 or abs(r - round(r)) > 1e-6:
            raise ValueError(f"orthos[{k}] is not on the pixel lattice of orthos[0] (offset {c:.3f}, {r:.3f} px)")
        boxes.append((round(r), round(c), o.shape[-2], o.shape[-1]))
    r0 = min(b[0] for b in boxes)
    c0 = min(b[1] for b in boxes)
    r1 = max(b[0] + b[2] for b in boxes)
    c1 = max(b[1] + b[3] for b in boxes)
    transform = t0 * Affine.translation(c0, r0)
    return transform, (r1 - r0, c1 - c0), crs, [(b[0] - r0, b[1] - c0) for b in boxes]


def _balance(stack, valid):
    """Gains and offsets ``(n,)``, ``(n,)`` by least squares in the overlaps,
    with the datum ``mean(g) = 1``, ``mean(o) = 0`` (Lagrange multipliers:
    without it all gains would shrink to 0)."""
    n = len(stack)
    N = np.zeros((2 * n, 2 * n))
    for i in range(n):
        for j in range(i + 1, n):
            m = valid[i] & valid[j]
            if not m.any():
                continue
            a, b = stack[i][m].astype(float), stack[j][m].astype(float)
            # Residual g_i a + o_i - g_j b - o_j: design row [a, 1, -b, -1] at (gi, oi, gj, oj).
            idx = [2 * i, 2 * i + 1, 2 * j, 2 * j + 1]
            cols = [a, np.ones_like(a), -b, -np.ones_like(b)]
            for p in range(4):
                for q in range(4):
                    N[idx[p], idx[q]] += np.dot(cols[p], cols[q])
    C = np.zeros((2, 2 * n))
    C[0, 0::2], C[1, 1::2] = 1.0, 1.0
    K = np.block([[N, C.T], [C, np.zeros((2, 2))]])
    rhs = np.concatenate([np.zeros(2 * n), [n, 0.0]])
    x = np.linalg.lstsq(K, rhs, rcond=None)[0][: 2 * n]
    return x[0::2], x[1::2]


def _min_cut(cost_h, cost_v, region, src, snk):
    """Labels of ``region`` pixels: True on the source side of the minimum
    cut separating ``src`` from ``snk`` pixels (4-neighbour graph, capacities
    ``cost_h`` between (r, c) and (r, c+1), ``cost_v`` between (r, c) and (r+1, c))."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    idx = -np.ones(region.shape, dtype=np.int64)
    n = int(region.sum())
    idx[region] = np.arange(n)
    s, t = n, n + 1
    rows, cols, caps = [], [], []
    for cost, (dr, dc) in ((cost_h, (0, 1)), (cost_v, (1, 0))):
        a = idx[: idx.shape[0] - dr, : idx.shape[1] - dc]
        b = idx[dr:, dc:]
        m = (a >= 0) & (b >= 0)
        w = cost[: idx.shape[0] - dr, : idx.shape[1] - dc][m]
        rows += [a[m], b[m]]
        cols += [b[m], a[m]]
        caps += [w, w]
    big = np.int64(2**30)
    p = idx[src & region]
    rows.append(np.full(p.size, s))
    cols.append(p)
    caps.append(np.full(p.size, big))
    p = idx[snk & region]
    rows.append(p)
    cols.append(np.full(p.size, t))
    caps.append(np.full(p.size, big))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(caps).astype(np.int32)
    graph = coo_matrix((w, (r, c)), shape=(n + 2, n + 2)).tocsr()
    graph.sum_duplicates()
    flow = maximum_flow(graph, s, t).flow
    residual = (graph - flow).tocsr()
    residual.data[residual.data <= 0] = 0
    residual.eliminate_zeros()
    reach = breadth_first_order(residual, s, directed=True, return_predecessors=False)
    side = np.zeros(n + 2, dtype=bool)
    side[reach] = True
    out = np.zeros(region.shape, dtype=bool)
    out[region] = side[:n]
    return out


def _touching(mask, other):
    """Pixels of ``mask`` with a 4-neighbour in ``other``."""
    from scipy import ndimage

    return mask & ndimage.binary_dilation(other, structure=ndimage.generate_binary_structure(2, 1))


def mosaic(
    orthos,
    *,
    method: str = "seamline",
    nadirs=None,
    dsm=None,
    dem=None,
    raised: float = 2.0,
    balance: bool = True,
    feather: int = 8,
    chunks: int = 1024,
    info: dict | None = None,
):
    """Join orthophotos into one mosaic without visible seams.

    Args:
        orthos: a sequence of 2-D ``xarray.DataArray`` (``y, x``) with a
            rioxarray georeference, one CRS and one pixel lattice, NaN (or
            their ``rio.nodata``) outside their footprint.
        method: ``"seamline"`` (minimum-difference cuts, default) or
            ``"voronoi"`` (nearest nadir).
        nadirs: ``(n, 2)`` ground ``(X, Y)`` of each image's nadir (for
            ``"voronoi"`` and the canonical order); default each ortho's
            footprint centre.
        dsm, dem: 2-D arrays on the mosaic's union grid (or DataArrays on
            it): pixels with ``dsm - dem > raised`` (metres) are raised
            objects the seams avoid.  ``dem`` may be omitted if ``dsm`` is
            already a height above ground.
        balance: estimate a gain and offset per image in the overlaps.
        feather: half-width in pixels of the linear blend across seams (0:
            hard seams).
        chunks: Dask chunk edge of the returned array.
        info: a dict to receive ``gains`` and ``offsets`` ``(n,)`` (per
            ortho, in the order given), ``labels`` (``(rows, cols)`` index of
            the ortho each pixel comes from, -1 for no data) and ``order``
            (the canonical order the seams were made in).

    Returns:
        ``xarray.DataArray`` (Dask-backed) on the union grid, NaN for no data.
    """
    import dask.array as da
    from scipy import ndimage

    from .rectification._grid import Grid
    from .tiled import _dataarray

    orthos = list(orthos)
    if not orthos:
        raise ValueError("orthos must hold at least one ortho")
    if method not in ("seamline", "voronoi"):
        raise ValueError(f"method must be 'seamline' or 'voronoi', got {method!r}")
    for k, o in enumerate(orthos):
        if o.ndim != 2:
            raise ValueError(f"orthos[{k}] must be 2-D (y, x), got dims {o.dims}")
    transform, shape, crs, offsets = _lattice(orthos)
    n = len(orthos)
    stack = np.full((n,) + shape, np.nan)
    for k, (o, (r, c)) in enumerate(zip(orthos, offsets)):
        v = np.asarray(o.values, dtype=float)
        nd = o.rio.nodata
        if nd is not None and not np.isnan(nd):
            v = np.where(v == nd, np.nan, v)
        stack[k, r : r + v.shape[0], c : c + v.shape[1]] = v
    valid = np.isfinite(stack)
    if n > 1:
        for k in range(n):
            if not any((valid[k] & valid[j]).any() for j in range(n) if j != k):
                raise ValueError(f"orthos[{k}] overlaps no other ortho: nothing to join it by")
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    X, Y = transform.c + transform.a * cc, transform.f + transform.e * rr
    if nadirs is None:
        nadirs = np.array([[X[valid[k]].mean(), Y[valid[k]].mean()] for k in range(n)])
    nadirs = np.asarray(nadirs, dtype=float)
    if nadirs.shape != (n, 2):
        raise ValueError(f"nadirs must be (n, 2) = ({n}, 2), got {nadirs.shape}")
    # Canonical order: by nadir, then by content -- not the order given.  All
    # the work below runs in it, so even rounding does not depend on the input order.
    order = sorted(range(n), key=lambda k: (nadirs[k, 0], nadirs[k, 1], float(np.nansum(stack[k]))))
    stack, valid, nadirs = stack[order], valid[order], nadirs[order]
    if balance and n > 1:
        gains, offs = _balance(stack, valid)
    else:
        gains, offs = np.ones(n), np.zeros(n)
    bal = stack * gains[:, None, None] + offs[:, None, None]
    raised_mask = np.zeros(shape, dtype=bool)
    if dsm is not None:
        h = np.asarray(getattr(dsm, "values", dsm), dtype=float)
        if dem is not None:
            h = h - np.asarray(getattr(dem, "values", dem), dtype=float)
        if h.shape != shape:
            raise ValueError(f"dsm must be on the mosaic grid, shape {shape}, got {h.shape}")
        raised_mask = np.nan_to_num(h) > raised
        # Keep the seams a blend's width off them too: feathering must not mix a roof in.
        raised_mask = ndimage.binary_dilation(raised_mask, iterations=max(feather, 0) + 1)
    labels = -np.ones(shape, dtype=np.int64)
    dist = np.stack([np.hypot(X - nadirs[k, 0], Y - nadirs[k, 1]) for k in range(n)])
    if method == "voronoi":
        d = np.where(valid, dist, np.inf)
        best = np.argmin(d, axis=0)
        labels = np.where(valid.any(axis=0), best, -1)
    else:
        for k in range(n):
            if (labels < 0).all():
                labels[valid[k]] = k
                continue
            overlap = valid[k] & (labels >= 0)
            labels[valid[k] & (labels < 0)] = k
            if not overlap.any():
                continue
            cur = np.take_along_axis(bal, np.maximum(labels, 0)[None], axis=0)[0]
            diff = np.abs(np.where(overlap, cur - bal[k], 0.0))
            pen = raised_mask.astype(float) * 1e3 * max(np.nanmax(diff), 1e-6)
            node = diff + pen + 1e-3 * max(np.nanmax(diff), 1e-6)  # small length term: short seams on ties
            cost_h = np.rint(_SCALE * (node[:, :-1] + node[:, 1:])).astype(np.int64)
            cost_v = np.rint(_SCALE * (node[:-1, :] + node[1:, :])).astype(np.int64)
            own_k = valid[k] & ~overlap & (labels == k)
            own_m = (labels >= 0) & ~valid[k]
            src, snk = _touching(overlap, own_k), _touching(overlap, own_m)
            src, snk = src & ~snk, snk & ~src  # a pixel touching both is left to the cut
            if not src.any() or not snk.any():  # one image inside the other: nearest nadir in the overlap
                prev = np.where(overlap, labels, -1)
                closer = dist[k] < np.take_along_axis(dist, np.maximum(prev, 0)[None], axis=0)[0]
                labels[overlap & closer] = k
                continue
            side = _min_cut(np.minimum(cost_h, 2**30), np.minimum(cost_v, 2**30), overlap, src, snk)
            labels[overlap & side] = k
    # Feathering: weight of image k falls linearly from 1 (feather px inside its label) to 0 (feather px outside).
    if feather > 0 and n > 1:
        w = np.zeros((n,) + shape)
        for k in range(n):
            own = labels == k
            if not own.any():
                continue
            inside = ndimage.distance_transform_edt(own)
            outside = ndimage.distance_transform_edt(~own)
            signed = np.where(own, inside - 0.5, 0.5 - outside)
            w[k] = np.where(valid[k], np.clip(0.5 + signed / (2 * feather), 0.0, 1.0), 0.0)
        total = w.sum(axis=0)
        out = np.where(total > 0, np.nansum(np.nan_to_num(bal) * w, axis=0) / np.where(total > 0, total, 1), np.nan)
    else:
        out = np.take_along_axis(bal, np.maximum(labels, 0)[None], axis=0)[0]
    out = np.where(labels >= 0, out, np.nan)
    grid = Grid(transform, shape, crs)
    arr = _dataarray(da.from_array(out, chunks=chunks), grid, np.asarray(np.nan), "mosaic")
    if info is not None:
        back = np.argsort(order)  # canonical -> given
        info.update(gains=gains[back], offsets=offs[back], labels=np.where(labels >= 0, np.asarray(order)[labels], -1),
                    order=order)
    return arr
