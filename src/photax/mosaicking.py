"""Seamless mosaics of orthophotos: seamlines, gain/offset balancing, feathering.

:func:`mosaic` joins georeferenced orthos (``xarray.DataArray`` with a
rioxarray georeference, e.g. from :func:`photax.orthorectify_dask`, or
raster paths; all on one CRS and one pixel lattice) into a lazy, chunked
``xarray.DataArray`` on the union grid:

Orthos may have bands (``band, y, x``, e.g. RGB; all the same number): each
band is balanced on its own, the seams are cut once for all bands (on the
mean of the balanced bands) and every band is blended across the same
seams, so a pixel's colour comes from one image (or a blend of the same
images) in every band.

1. **Balancing** (optional): a gain and an offset per image (and band),
   ``v' = g_i v + o_i``, by linear least squares over every overlapping pair,
   ``sum_pairs sum_overlap (g_i v_i + o_i - g_j v_j - o_j)^2`` with the datum
   ``mean(g) = 1, mean(o) = 0`` (without it all gains could shrink to 0).
   Only the pairs' first and second moments enter the normal equations; they
   are summed chunk by chunk over each overlap window at full resolution, and
   enter as each overlap's means and (co)variances, in grey values centred and
   scaled by the overlaps' pooled mean and spread, weighted by the overlap's
   share of pixels: well-posed at any overlap size.  A gain <= 0 or one the
   overlaps do not determine is an error, not a blank mosaic.
2. **Seamlines**, on the *seam grid*: the union grid coarsened by
   ``seam_scale`` (cells of ``s x s`` pixels, their mean; a cell is an
   image's only where all its pixels are; by default the smallest ``s`` with
   at most 4 Mpx on the seam grid and at most 8192 cells in any two orthos'
   overlap box: the maximum flow's cost grows faster than the overlap).  Images are added one at a time in a
   canonical order (by their footprint centre, not the order given, so the
   result does not depend on it).  In each overlap between the mosaic so far
   and the next image the seam is the **minimum s-t cut** (Kwatra et al.
   2003, "Graphcut textures") of the 4-neighbour graph whose edge costs are
   the grey-value difference of the two (balanced) images at both ends,
   plus a large penalty on raised objects (``dsm - dem`` above ``raised``)
   so the seam goes round buildings and trees; terminals are the overlap
   pixels touching either image's own area.  Each cut works in the next
   image's footprint window only; above 2048 overlap cells it goes coarse
   to fine (the cut of 2 x 2 blocks, refined in a band round it).  ``method="voronoi"``: each pixel from the
   image whose nadir is nearest (the simple option).
3. **Feathering**, per output chunk at full resolution: across each seam
   the images are blended linearly over ``feather`` pixels on either side
   (an image's weight is the share of its label in the ``(2 feather + 1)^2``
   box round the pixel, from the labels in the chunk grown by ``feather + 1``
   pixels: exact, a label farther away gets weight 0).

On request the seamlines are written as GeoJSON (a polygon per ortho) and
the source index as a GeoTIFF (which ortho each pixel comes from).

Memory: the seam grid (``n`` footprints of ``1/s^2`` of their pixels, the
labels) is in memory; the full-resolution orthos are only ever read chunk
by chunk, twice: once for the overlap moments and the seam grid, once for
the output.  Lazy orthos (raster paths, or Dask-backed DataArrays, e.g.
from :func:`photax.orthorectify_dask`, whose chunks cost a kernel call each)
are instead read or computed once and kept when they hold at most
``_PERSIST_BYTES`` (1 GiB) in all: a file in one read, in its own dtype
(float32 with NaN where a mask band, not a nodata value, marks no data), a
Dask array by ``dask.persist``, chunk by chunk; larger ones are read twice.
Both passes are one task per tile (NumPy on the tile's slices of the
orthos): the first sums the overlap moments and the seam grid, the second
blends the output chunk.  Write the result with :func:`photax.to_raster`
(``cog=True``: a tiled, compressed Cloud-Optimized GeoTIFF with overviews).

:func:`mosaic_to_raster` goes from orthos to a file in one call (what ``photax mosaic`` runs): for
raster files or NumPy orthos up to ``_PERSIST_BYTES`` in all it runs the same plan (:func:`_plan`) and
per-tile functions (:func:`_tile_stats`, :func:`_blend_chunk`) on NumPy arrays and a thread per CPU,
writing the chunks as they come (:func:`photax.io.lazy.write_tiles`): no Dask graph, and Dask, xarray,
pandas and rioxarray are not imported (0.8 s of a 1.8 s command-line mosaic of the NGI block).  The file
is the lazy mosaic's written by :func:`photax.to_raster`, byte for byte (tested); larger or Dask-backed
orthos take the lazy way.
"""

from __future__ import annotations

import itertools
import math
from typing import Any, NamedTuple

import numpy as np

from .errors import CRSMismatchError

_SCALE = 1000  # integer edge capacities: cost units per grey-value unit
_SEAM_PIXELS = 1 << 22  # default seam grid: at most 4 Mpx (s = 1 up to that) ...
# ... and at most this many cells in the bounding box of any two orthos' overlap: scipy's maximum flow
# grows faster than linearly (NGI, 5 m: 0.03 s for 8k cells, 0.2 s for 34k, 6 s for 139k).
_SEAM_OVERLAP = 1 << 13
_CUT_CELLS = 2048  # seam cuts of larger overlaps go coarse to fine (_min_cut), ...
_CUT_BAND = 8  # ... the fine cut within this many cells of the coarse one
_PERSIST_BYTES = 1 << 30  # raster files and lazy orthos, up to this in all, are read (computed) once and kept


def _lattice(orthos):
    """The union grid ``(transform, shape, crs)`` and each ortho's
    ``(row, col)`` offset in it; ValueError on different CRSs or lattices."""
    from rasterio import Affine

    crs = orthos[0].crs
    t0 = orthos[0].transform
    if t0.b != 0 or t0.d != 0:
        raise ValueError("orthos must be north-up (no rotation in the transform)")
    boxes = []
    for k, o in enumerate(orthos):
        if o.crs != crs:
            raise CRSMismatchError(f"orthos[{k}] is in {o.crs}, orthos[0] in {crs}: reproject them to one CRS first")
        t = o.transform
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


def mosaic_grid(orthos):
    """The :class:`photax.grid.Grid` :func:`mosaic` puts ``orthos`` on: the union of their
    footprints on their one CRS and pixel lattice.

    Args:
        orthos: raster paths or georeferenced ``xarray.DataArray``\\ s, as for :func:`mosaic`.

    Raises:
        ValueError: orthos in different CRSs, resolutions or lattices, or not north-up.
    """
    from .grid import Grid

    orthos = [_open(o, k) for k, o in enumerate(orthos)]
    if not orthos:
        raise ValueError("orthos must hold at least one ortho")
    transform, shape, crs, _ = _lattice(orthos)
    return Grid(transform, shape, crs)


def heights_on_grid(path, grid) -> np.ndarray:
    """``(rows, cols)`` float64 a single-band height raster (DSM, DEM) of any georeference resampled onto
    ``grid`` (nearest neighbour, by :func:`rasterio.warp.reproject`: what rioxarray's ``reproject_match``
    gives, without importing it; NaN where the raster has no data; in memory: one array of the grid's
    size), as :func:`mosaic`'s ``dsm`` and ``dem`` want it on :func:`mosaic_grid`.

    Raises:
        ValueError: a raster with more than one band, or located by ground control points, naming it.
    """
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    from .io.raster import open_raster

    with open_raster(path) as ds:  # a clear error for a missing or unreadable file
        if ds.count != 1:
            raise ValueError(f"{path}: {ds.count} bands; a height raster has one")
        if ds.gcps[0]:
            raise ValueError(f"{path}: located by ground control points; give a georeferenced height raster")
        heights = np.ma.filled(ds.read(1, masked=True).astype(float), np.nan)
        out = np.full(grid.shape, np.nan)
        reproject(
            heights,
            out,
            src_transform=ds.transform,
            src_crs=ds.crs,
            dst_transform=grid.transform,
            dst_crs=grid.crs,
            src_nodata=np.nan,
            dst_nodata=np.nan,
            resampling=Resampling.nearest,
        )
    return out


class _Ortho(NamedTuple):
    """An input of :func:`mosaic`: ``data`` ``(bands, h, w)``, NumPy or Dask (None: a raster file not
    read yet), its ``shape``, ``dtype`` and georeference, ``nodata`` (a value, NaN or None), ``source``
    (its file, or None) and whether the file's no-data is its ``nodata`` value alone (else a mask band)."""

    data: Any
    shape: tuple
    dtype: Any
    transform: Any
    crs: Any
    nodata: Any
    source: str | None = None
    by_value: bool = True


def _open(o, k: int) -> _Ortho:
    """Ortho ``k``: a DataArray (``(y, x)`` or ``(band, y, x)``) as it is, a raster path by its
    metadata only (read by :func:`_load`)."""
    import os

    if isinstance(o, (str, bytes)) or hasattr(o, "__fspath__"):
        from rasterio.enums import MaskFlags

        from .io.raster import open_raster

        try:
            with open_raster(o) as ds:  # a clear error for a missing or unreadable file
                flags = {f for band in ds.mask_flag_enums for f in band}
                return _Ortho(
                    None,
                    (ds.count, ds.height, ds.width),
                    np.dtype(ds.dtypes[0]),
                    ds.transform,
                    ds.crs,
                    ds.nodata,
                    os.fspath(o),
                    flags <= {MaskFlags.all_valid, MaskFlags.nodata},
                )
        except FileNotFoundError:
            raise ValueError(f"orthos[{k}]: no such raster file: {o}") from None
    if not hasattr(o, "rio"):
        raise ValueError(
            f"orthos[{k}] must be a georeferenced xarray.DataArray or a raster path, got {type(o).__name__}"
        )
    if o.ndim == 2:
        o = o.expand_dims("band")
    if o.ndim != 3 or o.dims[1:] != ("y", "x"):
        raise ValueError(f"orthos[{k}] must be (y, x) or (band, y, x), got dims {o.dims}")
    return _Ortho(o.data, o.shape, o.dtype, o.rio.transform(), o.rio.crs, o.rio.nodata)


def _load(o: _Ortho, keep: bool, off, chunks: int) -> _Ortho:
    """A raster file's ortho with its data: read whole when ``keep`` (in its own dtype where its
    no-data is a value; else float32, NaN where its mask says), else opened lazily in chunks on
    the union grid's (float32, NaN for no data)."""
    if not keep:
        import rioxarray

        ys, xs = _edges(off[0], o.shape[1], chunks), _edges(off[1], o.shape[2], chunks)
        arr = rioxarray.open_rasterio(o.source, masked=True, chunks={"band": -1, "y": ys, "x": xs})
        return o._replace(data=arr.data, dtype=arr.dtype, nodata=np.nan)
    from .io.raster import open_raster

    with open_raster(o.source) as ds:
        if o.by_value:
            return o._replace(data=ds.read())
        data = np.ma.filled(ds.read(masked=True).astype(np.float32), np.nan)
    return o._replace(data=data, dtype=data.dtype, nodata=np.nan)


def _nbytes(o: _Ortho) -> int:
    """Bytes of the ortho's values in memory (as :func:`_load` keeps them)."""
    return math.prod(o.shape) * (o.dtype.itemsize if o.by_value else 4)


def _name(o: _Ortho) -> str:
    """`` (PATH)`` for an ortho opened from a raster file, else ''."""
    return f" ({o.source})" if o.source else ""


def _components(n: int, edges) -> list[list[int]]:
    """The connected components (sorted lists of nodes) of the graph on ``range(n)`` with ``edges``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = np.asarray(list(edges), dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    return [np.flatnonzero(comp == c).tolist() for c in np.unique(comp)]


def _edges(off: int, size: int, chunks: int) -> tuple:
    """Chunk sizes of an axis of ``size`` at ``off`` on the union grid, cut where the union grid's
    ``chunks`` are."""
    cuts = [0, *range(-off % chunks or chunks, size, chunks), size]
    return tuple(b - a for a, b in itertools.pairwise(cuts) if b > a)


def _align(v, off, chunks: int):
    """Dask array ``v`` ``(bands, h, w)`` at ``off`` rechunked on the union grid's ``chunks``."""
    import dask

    ys, xs = _edges(off[0], v.shape[1], chunks), _edges(off[1], v.shape[2], chunks)
    with dask.config.set({"array.rechunk.method": "tasks"}):  # dask would import distributed (0.3 s) to choose
        return v.rechunk((-1, ys, xs))


def _values(v, chunks: int, off=(0, 0)):
    """The ortho's values ``v`` as a ``(bands, h, w)`` Dask array in their own dtype (a NumPy one in
    chunks on the union grid's)."""
    import dask.array as da

    if not isinstance(v, da.Array):
        edges = (-1, _edges(off[0], v.shape[1], chunks), _edges(off[1], v.shape[2], chunks))
        v = da.from_array(np.asarray(v), chunks=edges, name=False)  # a random name: no hash of the whole ortho
    return v


def _grey(v, nodata):
    """Ortho values ``v`` ``(bands, h, w)`` as float32 (a copy), 0 in every band of a pixel with no
    data (NaN or ``nodata``) in any band, and where there is data ``(h, w)``."""
    v = np.asarray(v)
    f = v.astype(np.float32)
    valid = np.isfinite(f).all(axis=0) if v.dtype.kind == "f" else np.ones(v.shape[1:], bool)
    if nodata is not None and not np.isnan(nodata):
        valid &= (v != nodata).all(axis=0)
    np.copyto(f, 0.0, where=~valid)
    return f, valid


def _cell_sums(x, place, s: int):
    """Sums of ``x`` ``(..., h, w)`` (at ``place`` ``(row, col)`` in a tile whose origin is a seam cell's)
    over the ``s x s`` seam cells it meets (0 outside it), and the first cell's ``(row, col)`` in the tile."""
    (pr, pc), (hh, ww) = place, x.shape[-2:]
    cr, cc = pr // s, pc // s
    rows, cols = -(-(pr + hh) // s) - cr, -(-(pc + ww) // s) - cc
    pad = np.zeros((*x.shape[:-2], rows * s, cols * s), np.float32)
    pad[..., pr - cr * s : pr - cr * s + hh, pc - cc * s : pc - cc * s + ww] = x
    pad = pad.reshape(*x.shape[:-2], rows, s, cols * s).sum(axis=-2, dtype=np.float64)
    return pad.reshape(*x.shape[:-2], rows, cols, s).sum(axis=-1), (cr, cc)


def _tile_stats(tile, parts, places, idx, nodata, s):
    """Pass 1 on one tile ``(r0, c0, h, w)`` of the union grid (``r0``, ``c0`` multiples of ``s``):
    for the orthos ``idx`` meeting it (``parts`` at ``places`` in the tile, their ``nodata``), each
    one's valid pixel count, its ``s x s`` cell means on the seam grid (NaN unless every pixel of the
    cell has data; with the cells' ``(row, col)`` in the tile) and every pair's overlap moments
    ``(6, bands)``, ``[count, sum a, sum b, sum a^2, sum b^2, sum ab]`` (summed in float64) over the
    pixels where both have data, keyed ``(i, j)`` in the order of ``idx`` (ascending).

    On zero-filled grey values and 0/1 validity: no gathers, only products and sums over the overlap
    boxes (``a vb`` is ``a`` where both have data, 0 elsewhere)."""
    grey = [_grey(v, nd) for v, nd in zip(parts, nodata)]
    counts, cells = {}, {}
    for k, place, (f, valid) in zip(idx, places, grey):
        counts[k] = int(valid.sum())
        if s == 1:
            cells[k] = (place, np.where(valid, f, np.nan))
            continue
        total, at = _cell_sums(f, place, s)
        full = _cell_sums(valid.astype(np.float32), place, s)[0] == s * s
        cells[k] = (at, np.where(full, total / (s * s), np.nan))
    moments = {}
    ax = (1, 2)
    for (i, (ri, ci), (fi, vi)), (j, (rj, cj), (fj, vj)) in itertools.combinations(zip(idx, places, grey), 2):
        r0, c0 = max(ri, rj), max(ci, cj)
        r1, c1 = min(ri + fi.shape[1], rj + fj.shape[1]), min(ci + fi.shape[2], cj + fj.shape[2])
        if r1 <= r0 or c1 <= c0:
            continue
        a, b = fi[:, r0 - ri : r1 - ri, c0 - ci : c1 - ci], fj[:, r0 - rj : r1 - rj, c0 - cj : c1 - cj]
        va = vi[r0 - ri : r1 - ri, c0 - ci : c1 - ci].astype(np.float32)
        vb = vj[r0 - rj : r1 - rj, c0 - cj : c1 - cj].astype(np.float32)
        am, bm = a * vb, b * va
        cnt = np.full(a.shape[0], (va * vb).sum(dtype=np.float64))
        moments[i, j] = np.stack(
            [
                cnt,
                am.sum(ax, dtype=np.float64),
                bm.sum(ax, dtype=np.float64),
                (am * a).sum(ax, dtype=np.float64),
                (bm * b).sum(ax, dtype=np.float64),
                (am * b).sum(ax, dtype=np.float64),
            ]
        )
    return counts, cells, moments


def _tiles(shape, step: int):
    """The tiles ``(r0, c0, h, w)`` of edge ``step`` covering a grid of ``shape``, row by row."""
    for r0 in range(0, shape[0], step):
        for c0 in range(0, shape[1], step):
            yield r0, c0, min(step, shape[0] - r0), min(step, shape[1] - c0)


def _meeting(vals, boxes, tile, ks):
    """The orthos among ``ks`` meeting ``tile`` ``(r0, c0, h, w)``: their slices of ``vals`` (each at its
    box of ``boxes`` on the union grid), places ``(row, col)`` in the tile, and indices."""
    r0, c0, h, w = tile
    parts, places, idx = [], [], []
    for k in ks:
        br, bc, bh, bw = boxes[k]
        a0, a1, b0, b1 = max(r0, br), min(r0 + h, br + bh), max(c0, bc), min(c0 + w, bc + bw)
        if a1 > a0 and b1 > b0:
            parts.append(vals[k][:, a0 - br : a1 - br, b0 - bc : b1 - bc])
            places.append((a0 - r0, b0 - c0))
            idx.append(k)
    return parts, places, idx


def _meet(a, b) -> int:
    """Pixels in the intersection of the boxes ``a`` and ``b`` ``(row, col, h, w)``."""
    h = min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0])
    w = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return max(h, 0) * max(w, 0)


def _balance(n: int, moments: dict, names=None):
    """Gains and offsets ``(n,)``, ``(n,)`` by least squares in the overlaps
    from the pairs' moments ``{(i, j): [count, Sa, Sb, Saa, Sbb, Sab]}``,
    with the datum ``mean(g) = 1``, ``mean(o) = 0`` (Lagrange multipliers);
    ``names`` of the images for messages.

    Well-posed at any overlap size: the sums become each pair's means and
    (co)variances, grey values are centred on the overlaps' pooled mean and
    scaled by their pooled spread, and each pair is weighted by its share of
    the overlap pixels, so the normal equations hold numbers of order 1 beside
    the datum's (raw sums of 1e5 pixels, ~1e10, drowned it: all gains 0).

    Raises:
        ValueError: the overlaps leave a gain undetermined (an ortho constant
            in its overlaps).  The caller checks the gains' signs.
    """
    stats = {}
    total = sum(float(v[0]) for v in moments.values() if v[0] > 0)
    for p, (cnt, sa, sb, saa, sbb, sab) in moments.items():
        if cnt > 0:
            ma, mb = sa / cnt, sb / cnt
            stats[p] = (
                cnt / total,
                ma,
                mb,
                max(saa / cnt - ma * ma, 0.0),
                max(sbb / cnt - mb * mb, 0.0),
                sab / cnt - ma * mb,
            )
    mu = sum(w * (ma + mb) / 2 for w, ma, mb, *_ in stats.values())
    spread = sum(w * (vaa + vbb + (ma - mu) ** 2 + (mb - mu) ** 2) / 2 for w, ma, mb, vaa, vbb, _ in stats.values())
    sd = math.sqrt(spread) if spread > 0 else 1.0
    N = np.zeros((2 * n, 2 * n))
    for (i, j), (w, ma, mb, vaa, vbb, vab) in stats.items():
        # Residual g_i a + o_i - g_j b - o_j, a and b in units (v - mu) / sd: design row [a, 1, -b, -1].
        a, b = (ma - mu) / sd, (mb - mu) / sd
        eaa, ebb, eab = vaa / sd**2 + a * a, vbb / sd**2 + b * b, vab / sd**2 + a * b
        idx = [2 * i, 2 * i + 1, 2 * j, 2 * j + 1]
        N[np.ix_(idx, idx)] += w * np.array([[eaa, a, -eab, -a], [a, 1, -b, -1], [-eab, -b, ebb, b], [-a, -1, b, 1]])
    # Datum mean(g) = 1, mean(o) = 0; in these units the offsets o' = (o - mu (1 - g)) / sd: mean(o') = 0.
    C = np.zeros((2, 2 * n))
    C[0, 0::2], C[1, 1::2] = 1.0 / n, 1.0 / n
    K = np.block([[N, C.T], [C, np.zeros((2, 2))]])
    for k in range(n):  # an ortho constant in all its overlaps: its gain and offset are one unknown
        gg, go, oo = N[2 * k, 2 * k], N[2 * k, 2 * k + 1], N[2 * k + 1, 2 * k + 1]
        if gg - go**2 / max(oo, 1e-300) <= 1e-12 * N.trace():  # its variance in the overlaps, ~0
            name = names[k] if names else f"ortho {k}"
            raise ValueError(
                f"the overlaps do not determine the gain of {name}: it is constant in them; mosaic without balancing"
            )
    sv = np.linalg.svd(K, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise ValueError("the overlaps do not determine every gain and offset: mosaic without balancing")
    x = np.linalg.solve(K, np.concatenate([np.zeros(2 * n), [1.0, 0.0]]))[: 2 * n]
    g = x[0::2]
    return g, sd * x[1::2] + mu * (1 - g)


def _min_cut(cost_h, cost_v, region, src, snk):
    """Labels of ``region`` pixels: True on the source side of the minimum
    cut separating ``src`` from ``snk`` pixels (4-neighbour graph, capacities
    ``cost_h`` between (r, c) and (r, c+1), ``cost_v`` between (r, c) and (r+1, c)).

    Coarse to fine above ``_CUT_CELLS`` region cells: the cut of the graph of 2 x 2 blocks (an edge
    between blocks carries the capacities of the edges it stands for), then, at full resolution, the
    cut within ``_CUT_BAND`` cells of the coarse seam, the cells beyond it held to their coarse side.
    The maximum flow's cost grows faster than the graph (scipy: 28 ms for the NGI block's largest
    overlap, 8.5k cells; 12 ms so, and the same cut on all three of its overlaps; on overlaps of
    pure texture differences, the worst case, a cut within 6 % of the minimum's cost)."""
    if region.sum() <= _CUT_CELLS:
        return _max_flow_cut(cost_h, cost_v, region, src, snk)

    (h, w), (hc, wc) = region.shape, (-(-region.shape[0] // 2), -(-region.shape[1] // 2))

    def blocks(x, fn):
        pad = np.zeros((2 * hc, 2 * wc), x.dtype)
        pad[: x.shape[0], : x.shape[1]] = x
        return pad, fn(pad.reshape(hc, 2, wc, 2), axis=(1, 3))

    _, reg_c = blocks(region, np.any)
    src_c, snk_c = blocks(src & region, np.any)[1], blocks(snk & region, np.any)[1]
    src_c, snk_c = src_c & ~snk_c, snk_c & ~src_c
    if not src_c.any() or not snk_c.any():
        return _max_flow_cut(cost_h, cost_v, region, src, snk)
    # The fine edges between region cells crossing from one block to the next (odd column / row).
    eh = blocks(np.where(region[:, :-1] & region[:, 1:], cost_h, 0), np.sum)[0][:, 1::2]
    ev = blocks(np.where(region[:-1] & region[1:], cost_v, 0), np.sum)[0][1::2, :]
    ch = np.minimum(eh.reshape(hc, 2, wc).sum(1)[:, : wc - 1], 2**30)
    cv = np.minimum(ev.reshape(hc, wc, 2).sum(2)[: hc - 1], 2**30)
    side = np.repeat(np.repeat(_min_cut(ch, cv, reg_c, src_c, snk_c), 2, 0), 2, 1)[:h, :w] & region
    dh = (side[:, :-1] != side[:, 1:]) & region[:, :-1] & region[:, 1:]
    dv = (side[:-1] != side[1:]) & region[:-1] & region[1:]
    seam = np.zeros((h, w), bool)  # cells on the coarse cut
    seam[:, :-1] |= dh
    seam[:, 1:] |= dh
    seam[:-1] |= dv
    seam[1:] |= dv
    free = _grow(seam, _CUT_BAND) & region
    near = _grow(free) & region
    ring = near & ~free  # held to their coarse side
    src2, snk2 = (src & near) | (ring & side & ~snk), (snk & near) | (ring & ~side & ~src)
    src2, snk2 = src2 & ~snk2, snk2 & ~src2
    if not free.any():
        return side
    side[near] = _max_flow_cut(cost_h, cost_v, near, src2, snk2)[near]
    return side


def _max_flow_cut(cost_h, cost_v, region, src, snk):
    """:func:`_min_cut` at full resolution: scipy's maximum flow, then the cells reachable from the
    source in the residual graph."""
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


def _grow(mask, n: int = 1):
    """``mask`` grown by ``n`` cells through 4-neighbours (``scipy.ndimage.binary_dilation`` with its
    default cross, ``n`` iterations; in NumPy: importing ``scipy.ndimage`` costs ~0.2 s of a CLI run)."""
    out = np.asarray(mask, bool)
    for _ in range(n):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def _box_share(own, f: int) -> np.ndarray:
    """float32 share of True in the ``(2 f + 1)^2`` box round each cell of ``own``, the edges extended
    (``scipy.ndimage.uniform_filter(own, 2 f + 1, mode="nearest")``; counted in integers)."""
    n = 2 * f + 1
    p = np.pad(own, f, mode="edge").astype(np.int32)
    c = np.zeros((p.shape[0] + 1, p.shape[1]), np.int32)
    np.cumsum(p, axis=0, out=c[1:])
    p = c[n:] - c[:-n]  # the column sums of n cells
    c = np.zeros((p.shape[0], p.shape[1] + 1), np.int32)
    np.cumsum(p, axis=1, out=c[:, 1:])
    return ((c[:, n:] - c[:, :-n]) / np.float32(n * n)).astype(np.float32)


def _touching(mask, other):
    """Pixels of ``mask`` with a 4-neighbour in ``other``."""
    return mask & _grow(other)


def _window(off, size, shape, grow: int):
    """Slices of the box ``off, size`` grown by ``grow`` cells, inside ``shape``."""
    (r, c), (h, w) = off, size
    return (slice(max(r - grow, 0), min(r + h + grow, shape[0])), slice(max(c - grow, 0), min(c + w + grow, shape[1])))


def _seamlines(cells, offs, shape, gains, offsets, raised, nadirs, transform, method):
    """Labels ``(rows, cols)`` on the seam grid (canonical image index, -1
    for no data); images in canonical order, each cut made in its window."""
    labels = -np.ones(shape, dtype=np.int64)
    cur = np.full(shape, np.nan)  # balanced value of the image each cell is labelled with
    best = np.full(shape, np.inf)  # voronoi: distance to the nearest nadir so far
    empty = True
    for k, cell in enumerate(cells):
        win = _window(offs[k], cell.shape, shape, 1)
        v = np.full((win[0].stop - win[0].start, win[1].stop - win[1].start), np.nan)
        r, c = offs[k][0] - win[0].start, offs[k][1] - win[1].start
        v[r : r + cell.shape[0], c : c + cell.shape[1]] = cell
        valid = np.isfinite(v)
        bal = v * gains[k] + offsets[k]
        rr, cc = np.mgrid[win[0], win[1]] + 0.5
        X, Y = transform.c + transform.a * cc, transform.f + transform.e * rr
        dist = np.hypot(X - nadirs[k, 0], Y - nadirs[k, 1])
        lab, cu = labels[win], cur[win]  # views
        if method == "voronoi":  # strict <: ties go to the first in canonical order
            d = np.where(valid, dist, np.inf)
            closer = d < best[win]
            best[win][closer] = d[closer]
            lab[closer] = k
            continue
        if empty:
            lab[valid], cu[valid], empty = k, bal[valid], False
            continue
        overlap = valid & (lab >= 0)
        new = valid & (lab < 0)
        lab[new], cu[new] = k, bal[new]
        if not overlap.any():
            continue
        diff = np.abs(np.where(overlap, cu - bal, 0.0))
        top = max(float(diff.max()), 1e-6)
        node = diff + raised[win].astype(float) * 1e3 * top + 1e-3 * top  # small length term: short seams on ties
        cost_h = np.rint(_SCALE * (node[:, :-1] + node[:, 1:])).astype(np.int64)
        cost_v = np.rint(_SCALE * (node[:-1, :] + node[1:, :])).astype(np.int64)
        own_k = valid & ~overlap & (lab == k)
        own_m = (lab >= 0) & ~valid
        src, snk = _touching(overlap, own_k), _touching(overlap, own_m)
        src, snk = src & ~snk, snk & ~src  # a pixel touching both is left to the cut
        if not src.any() or not snk.any():  # one image inside the other: nearest nadir in the overlap
            prev = np.where(overlap, lab, 0)
            dprev = np.hypot(X - nadirs[prev, 0], Y - nadirs[prev, 1])
            side = overlap & (dist < dprev)
        else:
            side = overlap & _min_cut(np.minimum(cost_h, 2**30), np.minimum(cost_v, 2**30), overlap, src, snk)
        lab[side], cu[side] = k, bal[side]
    return labels


def _blend_chunk(tile, parts, places, idx, nodata, gains, offsets, lab, lab_origin, window, s, feather):
    """One output chunk ``(bands, h, w)``, float32: the intersecting orthos ``parts`` (canonical indices
    ``idx``, at ``places`` in the chunk, their ``nodata``), balanced (gains and offsets ``(m, bands)``)
    and feathered across the labels (seam grid ``lab`` at ``lab_origin``, cells of ``s`` px), the same
    weights in every band.

    Each ortho is handled on its own box in the chunk (no ``(m, bands, h, w)`` stack): its weight is
    the share of its label in the ``(2 feather + 1)^2`` box round the pixel, which falls linearly from
    1 (``feather`` px inside its label) to 0 (``feather`` px outside) across a straight seam; 0 where
    it has no data.  An ortho whose label fills the box has weight 1, one whose label is absent
    (and no unlabelled pixel in its box) is skipped: only the pixels near a seam are filtered."""

    r0, c0, h, w = tile
    (wr0, wr1), (wc0, wc1) = window
    nb = gains.shape[1]
    rows = np.arange(wr0, wr1) // s - lab_origin[0]
    full = lab.astype(np.int16)[rows][:, np.arange(wc0, wc1) // s - lab_origin[1]]
    dr, dc = r0 - wr0, c0 - wc0
    inner = full[dr : dr + h, dc : dc + w]
    # In float32 (the orthos' grey values need no more; half the memory traffic of float64).
    num, total = np.zeros((nb, h, w), np.float32), np.zeros((h, w), np.float32)
    unlabelled = inner < 0  # in no labelled cell (a seam cell only partly covered): the mean of what is there
    for (pr, pc), v, k, nd, g, o in zip(places, parts, idx, nodata, gains, offsets):
        hh, ww = v.shape[1:]
        box = (slice(pr, pr + hh), slice(pc, pc + ww))
        f = feather
        a0, a1 = max(dr + pr - f, 0), min(dr + pr + hh + f, full.shape[0])
        b0, b1 = max(dc + pc - f, 0), min(dc + pc + ww + f, full.shape[1])
        own = full[a0:a1, b0:b1] == k
        loose = unlabelled[box]
        if not own.any() and not loose.any():
            continue  # none of its label within reach: weight 0 everywhere
        bal, valid = _grey(v, nd)
        bal *= g.astype(np.float32)[:, None, None]
        bal += o.astype(np.float32)[:, None, None]
        if own.all():
            wt = valid.astype(np.float32)
        else:
            wt = _box_share(own, f) if f > 0 else own.astype(np.float32)
            r, c = dr + pr - a0, dc + pc - b0
            wt = wt[r : r + hh, c : c + ww]
            wt[loose] = 1.0
            wt[~valid] = 0.0
        bal *= wt  # 0 where no data (the offset too)
        num[:, box[0], box[1]] += bal
        total[box] += wt
    out = np.full((nb, h, w), np.nan, np.float32)
    np.divide(num, total, out=out, where=total > 0)
    return out


def _index_tile(labels, s: int, tile) -> np.ndarray:
    """The source index on ``tile`` ``(r0, c0, h, w)`` of the union grid: the ``labels`` of its seam cells
    (``s`` px) at full resolution, int16."""
    r0, c0, h, w = tile
    return labels[np.ix_(np.arange(r0, r0 + h) // s, np.arange(c0, c0 + w) // s)].astype(np.int16)


def _write_source_index(path, labels, s, grid, chunks, inputs):
    """The source-index GeoTIFF: ``labels`` (seam grid, cells of ``s`` px) at full resolution on ``grid``,
    int16, -1 (its nodata) for no image; written chunk by chunk, atomically (from the labels in memory)."""
    from .io.lazy import write_tiles

    if labels.max() >= np.iinfo(np.int16).max:
        raise ValueError(f"a source index holds at most {np.iinfo(np.int16).max} orthos, got {labels.max() + 1}")
    tiles = (((t[0], t[1]), _index_tile(labels, s, t)) for t in _tiles(grid.shape, chunks))
    write_tiles(
        path,
        tiles,
        shape=(1, *grid.shape),
        dtype=np.int16,
        transform=grid.transform,
        crs=grid.crs,
        nodata=-1,
        name="source_index",
        chunks=chunks,
        inputs=inputs,
    )


def _write_seamlines(path, labels, transform, crs, names, inputs):
    """The seamlines as GeoJSON: one (multi)polygon per ortho, the area of the mosaic it is the source of
    (``labels`` vectorised on the seam grid ``transform``; neighbours share the seam as an edge), with
    properties ``index`` (in the order given) and ``source`` (its file, or null); the CRS in a ``crs``
    member (GeoJSON 2008; the coordinates are in the orthos' CRS)."""
    import json

    from rasterio import features

    from .io.atomic import atomic_write

    parts = {}
    for geom, value in features.shapes(labels.astype(np.int32), mask=labels >= 0, connectivity=4, transform=transform):
        parts.setdefault(int(value), []).append(geom["coordinates"])
    feats = [
        {
            "type": "Feature",
            "properties": {"index": k, "source": names[k]},
            "geometry": {"type": "MultiPolygon", "coordinates": parts[k]},
        }
        for k in sorted(parts)
    ]
    epsg = crs.to_epsg() if crs is not None else None
    doc = {"type": "FeatureCollection", "features": feats}
    if crs is not None:
        doc["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}" if epsg else crs.to_wkt()}}
    with atomic_write(path, inputs=inputs) as fh:
        json.dump(doc, fh)


class _Plan(NamedTuple):
    """What :func:`_plan` leaves for the output: its ``grid``, number of bands ``nb``, ``chunks``, whether
    the orthos are NumPy arrays (``eager``) and, per output chunk ``(r0, c0, h, w)``, the arguments of
    :func:`_blend_chunk` (None: no ortho meets it)."""

    grid: Any
    nb: int
    chunks: int
    eager: bool
    blends: list


def _plan(
    orthos,
    *,
    eager,
    method,
    nadirs,
    dsm,
    dem,
    raised,
    balance,
    feather,
    chunks,
    seam_scale,
    info,
    seamlines,
    source_index,
    bar=None,
) -> _Plan:
    """:func:`mosaic` up to the output chunks' tasks: the inputs, one pass for the overlap moments and the
    seam grid, the balance and the seams (written on request).  ``eager``: the orthos (``_Ortho`` tuples, or
    what :func:`mosaic` takes) are read into NumPy arrays and the pass runs on threads (``bar`` counting
    its tiles), no Dask; else, as Dask arrays and tasks."""
    # Over 80 lines: it reads top to bottom: inputs, one pass for moments and the seam grid, seams, the
    # output chunks' arguments.
    from rasterio import Affine

    from .grid import Grid

    orthos = list(orthos)
    if not orthos:
        raise ValueError("orthos must hold at least one ortho")
    if method not in ("seamline", "voronoi"):
        raise ValueError(f"method must be 'seamline' or 'voronoi', got {method!r}")
    if isinstance(chunks, bool) or not isinstance(chunks, (int, np.integer)) or chunks < 1:
        raise ValueError(f"chunks must be a positive number of pixels, got {chunks!r}")
    if isinstance(feather, bool) or not isinstance(feather, (int, np.integer)) or feather < 0:
        raise ValueError(f"feather must be a number of pixels >= 0, got {feather!r}")
    orthos = [o if isinstance(o, _Ortho) else _open(o, k) for k, o in enumerate(orthos)]
    nb = orthos[0].shape[0]
    for k, o in enumerate(orthos):
        if o.shape[0] != nb:
            raise ValueError(f"orthos[{k}] has {o.shape[0]} bands, orthos[0] {nb}: one number of bands only")
    transform, shape, crs, offsets = _lattice(orthos)
    # Raster files and lazy DataArrays, up to _PERSIST_BYTES in all, are read (computed) once here and
    # kept for both passes below (Dask ones chunk by chunk, in chunks on the output's: a chunk of the
    # output then reads whole input chunks, no concatenation); larger ones are read twice.
    lazy = [k for k, o in enumerate(orthos) if o.data is None or not isinstance(o.data, np.ndarray)]
    keep = eager or sum(_nbytes(orthos[k]) for k in lazy) <= _PERSIST_BYTES
    for k in lazy:
        if orthos[k].data is None:
            orthos[k] = _load(orthos[k], keep, offsets[k], chunks)
    if not eager:
        import dask

        computed = [k for k in lazy if keep and not isinstance(orthos[k].data, np.ndarray)]
        for k, v in zip(computed, dask.persist(*(_align(orthos[k].data, offsets[k], chunks) for k in computed))):
            orthos[k] = orthos[k]._replace(data=v)
    n = len(orthos)
    boxes = [(r, c, o.shape[-2], o.shape[-1]) for o, (r, c) in zip(orthos, offsets)]
    if seam_scale is None:
        meet = max((_meet(boxes[i], boxes[j]) for i in range(n) for j in range(i + 1, n)), default=0)
        s = max(1, math.ceil(math.sqrt(shape[0] * shape[1] / _SEAM_PIXELS)), math.ceil(math.sqrt(meet / _SEAM_OVERLAP)))
    elif isinstance(seam_scale, bool) or not isinstance(seam_scale, (int, np.integer)) or seam_scale < 1:
        raise ValueError(f"seam_scale must be a positive number of pixels, got {seam_scale!r}")
    else:
        s = int(seam_scale)
    shape_c = (-(-shape[0] // s), -(-shape[1] // s))
    vals = [np.asarray(o.data) if eager else _values(o.data, chunks, off) for o, off in zip(orthos, offsets)]
    nodata = [o.nodata for o in orthos]
    raised_c = None if dsm is None else _raised_cells(dsm, dem, raised, shape, s, chunks, eager)
    # One pass over the inputs, a task per tile (whole seam cells): the seam grid, the overlap
    # moments, the valid pixel counts; and the raised cells.
    step = max(s, chunks // s * s)
    tiles, tasks = [], []
    for tile in _tiles(shape, step):
        parts, places, idx = _meeting(vals, boxes, tile, range(n))
        if idx:
            tiles.append(tile)
            tasks.append((tile, parts, places, idx, [nodata[k] for k in idx], s))
    if eager:
        results = list(_threads(_tile_stats, tasks, bar))
    else:
        import dask

        stats = dask.delayed(_tile_stats, pure=True)
        results, raised_c = dask.compute([stats(*t) for t in tasks], raised_c)
    seam_off = [(b[0] // s, b[1] // s) for b in boxes]
    cells = [
        np.full((nb, -(-(b[0] + b[2]) // s) - r, -(-(b[1] + b[3]) // s) - c), np.nan)
        for b, (r, c) in zip(boxes, seam_off)
    ]
    counts, moments = np.zeros(n, dtype=np.int64), {}
    for tile, (cnt, cel, mom) in zip(tiles, results):
        for k, v in cnt.items():
            counts[k] += v
        for k, ((cr, cc), cell) in cel.items():
            r, c = tile[0] // s + cr - seam_off[k][0], tile[1] // s + cc - seam_off[k][1]
            cells[k][:, r : r + cell.shape[1], c : c + cell.shape[2]] = cell
        for p, v in mom.items():
            moments[p] = moments[p] + v if p in moments else v
    for k in range(n):
        if counts[k] == 0:
            raise ValueError(f"orthos[{k}]{_name(orthos[k])} has no valid pixel (all no-data)")
    for k in range(n):
        if n > 1 and not any(moments[p][0][0] > 0 for p in moments if k in p):
            raise ValueError(f"orthos[{k}]{_name(orthos[k])} overlaps no other ortho: nothing to join it by")
    groups = _components(n, [p for p in moments if moments[p][0][0] > 0])
    if len(groups) > 1:
        sets = " and ".join("{" + ", ".join(f"orthos[{k}]" for k in g) + "}" for g in groups)
        raise ValueError(f"the orthos do not all overlap: they fall into {sets}, with no overlap between the groups")
    tc = transform * Affine.scale(s)
    if nadirs is None:
        nadirs = []
        for k, (cell, (r, c)) in enumerate(zip(cells, seam_off)):
            rr, cc = np.nonzero(np.all(np.isfinite(cell), axis=0))
            if rr.size == 0:
                raise ValueError(
                    f"orthos[{k}] covers no whole {s} x {s} px cell of the seam grid: give a smaller seam_scale"
                )
            nadirs.append([(tc.c + tc.a * (cc + c + 0.5)).mean(), (tc.f + tc.e * (rr + r + 0.5)).mean()])
    nadirs = np.asarray(nadirs, dtype=float)
    if nadirs.shape != (n, 2):
        raise ValueError(f"nadirs must be (n, 2) = ({n}, 2), got {nadirs.shape}")
    # Canonical order: by nadir, then by content -- not the order given.  All
    # the work below runs in it, so even rounding does not depend on the input order.
    order = sorted(range(n), key=lambda k: (nadirs[k, 0], nadirs[k, 1], float(np.nansum(cells[k]))))
    pos = np.argsort(order)  # given -> canonical
    canon = {}
    for (i, j), (cnt, sa, sb, saa, sbb, sab) in moments.items():
        canon[(pos[i], pos[j]) if pos[i] < pos[j] else (pos[j], pos[i])] = (
            (cnt, sa, sb, saa, sbb, sab) if pos[i] < pos[j] else (cnt, sb, sa, sbb, saa, sab)
        )
    gains, offs = np.ones((n, nb)), np.zeros((n, nb))  # (canonical image, band)
    if balance and n > 1:
        for b in range(nb):
            gains[:, b], offs[:, b] = _balance(
                n,
                {p: tuple(x[b] for x in v) for p, v in canon.items()},
                [f"orthos[{k}]{_name(orthos[k])}" for k in order],
            )
        for k in range(n):
            if np.any(gains[pos[k]] <= 0):
                raise ValueError(
                    f"balancing gives orthos[{k}]{_name(orthos[k])} a gain of "
                    f"{np.min(gains[pos[k]]):.3g} (<= 0): its grey values do not match the "
                    "others' in the overlaps; mosaic without balancing"
                )
    up = np.zeros(shape_c, dtype=bool)
    if raised_c is not None:
        # Keep the seams a blend's width off raised objects too: feathering must not mix a roof in.
        up = _grow(np.asarray(raised_c), -(-(feather + 1) // s))
    # One seam for all bands, cut on the mean of the balanced bands.
    seam_cells = [
        np.mean(cells[k] * gains[c][:, None, None] + offs[c][:, None, None], axis=0) for c, k in enumerate(order)
    ]
    labels = _seamlines(
        seam_cells, [seam_off[k] for k in order], shape_c, np.ones(n), np.zeros(n), up, nadirs[order], tc, method
    )
    # The output chunks: the arguments of _blend_chunk on the slices of the orthos each meets.
    grow = feather + 1
    blends = []
    for tile in _tiles(shape, chunks):
        r0, c0, h, w = tile
        parts, places, idx = _meeting(vals, boxes, tile, order)
        if not idx:
            blends.append((tile, None))
            continue
        wr0, wr1 = max(r0 - grow, 0), min(r0 + h + grow, shape[0])
        wc0, wc1 = max(c0 - grow, 0), min(c0 + w + grow, shape[1])
        lab = labels[wr0 // s : (wr1 - 1) // s + 1, wc0 // s : (wc1 - 1) // s + 1]
        p = pos[idx]  # canonical
        args = (
            tile,
            parts,
            places,
            p,
            [nodata[k] for k in idx],
            gains[p],
            offs[p],
            lab,
            (wr0 // s, wc0 // s),
            ((wr0, wr1), (wc0, wc1)),
            s,
            feather if n > 1 else 0,
        )
        blends.append((tile, args))
    grid = Grid(transform, shape, crs)
    given = np.where(labels >= 0, np.asarray(order)[labels], -1)
    names = [o.source for o in orthos]
    inputs = [x for x in names if x]
    if source_index is not None:
        _write_source_index(source_index, given, s, grid, chunks, inputs)
    if seamlines is not None:
        _write_seamlines(seamlines, given, tc, crs, names, inputs)
    if info is not None:
        g, o = (gains[pos, 0], offs[pos, 0]) if nb == 1 else (gains[pos], offs[pos])
        info.update(gains=g, offsets=o, labels=given, order=order, seam_scale=s)
    return _Plan(grid, nb, chunks, eager, blends)


def _raised_cells(dsm, dem, raised, shape, s, chunks, eager):
    """Seam cells holding a raised object (``dsm - dem > raised``) on the seam grid (bool; Dask unless
    ``eager``)."""
    if eager:
        xp = np
    else:
        import dask.array as xp
    h = xp.asarray(dsm.data if hasattr(dsm, "dims") else dsm).astype(float)
    if dem is not None:
        h = h - xp.asarray(dem.data if hasattr(dem, "dims") else dem).astype(float)
    if h.shape != shape:
        raise ValueError(f"dsm must be on the mosaic grid, shape {shape}, got {h.shape}")
    up = xp.nan_to_num(h) > raised
    if s == 1:
        return up
    rc, cc = -(-shape[0] // s), -(-shape[1] // s)
    up = xp.pad(up, ((0, rc * s - shape[0]), (0, cc * s - shape[1])), constant_values=False)
    if eager:
        return up.reshape(rc, s, cc, s).any(axis=(1, 3))
    return xp.coarsen(np.any, up.rechunk(max(s, chunks // s * s)), {0: s, 1: s})


def _threads(fn, tasks, bar=None):
    """``fn(*task)`` for each of ``tasks``, on a thread per CPU (NumPy releases the GIL), yielded in
    order; at most two per thread ahead of the consumer (bounded memory); ``bar`` counts them."""
    import collections
    import os
    from concurrent.futures import ThreadPoolExecutor

    workers = os.cpu_count() or 1
    if bar is not None:
        bar.total = (bar.total or 0) + len(tasks)
    with ThreadPoolExecutor(workers, thread_name_prefix="photax-mosaic") as pool:
        pending = collections.deque()

        def done():
            result = pending.popleft().result()
            if bar is not None:
                bar.update()  # before the yield: the consumer may not ask again after the last
            return result

        for task in tasks:
            pending.append(pool.submit(fn, *task))
            if len(pending) >= 2 * workers:
                yield done()
        while pending:
            yield done()


def _lazy(plan: _Plan):
    """The mosaic of ``plan`` as a lazy DataArray: a Dask task per output chunk (:func:`_blend_chunk`)."""
    import dask
    import dask.array as da

    from .io.lazy import dataarray

    blend = dask.delayed(_blend_chunk, pure=True)
    rows = {}
    for (r0, _c0, h, w), args in plan.blends:
        if args is None:
            chunk = da.full((plan.nb, h, w), np.nan, dtype=np.float32, chunks=(plan.nb, h, w))
        else:
            chunk = da.from_delayed(blend(*args), (plan.nb, h, w), dtype=np.float32)
        rows.setdefault(r0, []).append(chunk)
    data = da.block(list(rows.values()))
    return dataarray(data[0] if plan.nb == 1 else data, plan.grid, np.asarray(np.nan), "mosaic")


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
    seam_scale: int | None = None,
    info: dict | None = None,
    seamlines=None,
    source_index=None,
):
    """Join orthophotos into one mosaic without visible seams, lazily (:func:`mosaic_to_raster` writes
    it to a file, without Dask where the orthos fit in memory).

    Args:
        orthos: a sequence of ``xarray.DataArray`` (``y, x`` or ``band, y,
            x``; NumPy- or Dask-backed) with a rioxarray georeference, or
            raster paths (all bands, opened lazily in ``chunks``); one CRS,
            one pixel lattice and one number of bands, NaN (or their
            ``rio.nodata``) outside their footprint.
        method: ``"seamline"`` (minimum-difference cuts, default) or
            ``"voronoi"`` (nearest nadir).
        nadirs: ``(n, 2)`` ground ``(X, Y)`` of each image's nadir (for
            ``"voronoi"`` and the canonical order); default each ortho's
            footprint centre.
        dsm, dem: 2-D arrays (NumPy, Dask or DataArray) on the mosaic's
            union grid: pixels with ``dsm - dem > raised`` (metres) are raised
            objects the seams avoid (by ``feather + 1`` px).  ``dem`` may be
            omitted if ``dsm`` is already a height above ground.
        balance: estimate a gain and offset per image in the overlaps.
        feather: half-width in pixels of the linear blend across seams (0:
            hard seams).
        chunks: Dask chunk edge of the returned array (and of path inputs).
        seam_scale: cell edge ``s`` in pixels of the grid the seams are cut
            on (default the smallest with at most 4 Mpx on the union grid and
            8192 cells in any two orthos' overlap box; 1 for full resolution).
        info: a dict to receive ``gains`` and ``offsets`` ``(n,)`` (per
            ortho, in the order given; ``(n, bands)`` with several bands), ``labels`` (the index of the ortho
            each seam-grid cell comes from, -1 for none; at full resolution
            when ``seam_scale == 1``), ``seam_scale`` and ``order`` (the
            canonical order the seams were made in).
        seamlines: a path: write the seamlines there as GeoJSON, one
            (multi)polygon per ortho (the area it is the source of, on the
            seam grid; properties ``index``, in the order given, and
            ``source``, its file), in the orthos' CRS.
        source_index: a path: write a GeoTIFF on the mosaic grid there, int16,
            the index (in the order given) of the ortho each pixel comes from
            (its seam-grid cell's label; within ``feather`` px of a seam the
            pixel blends it with its neighbour), -1 for none.

    Returns:
        Lazy ``xarray.DataArray`` (float32, Dask chunks of ``chunks``) on the
        union grid, ``(y, x)`` for single-band orthos, else ``(band, y,
        x)``; CRS and transform on the rioxarray conventions,
        NaN for no data.

    Raises:
        ValueError: no orthos, orthos in different CRSs, resolutions or pixel
            lattices, an ortho with no valid pixel, an ortho that overlaps no
            other, groups of orthos with no overlap between them, a gain the
            balancing leaves undetermined or makes <= 0, bad arguments.

    Examples:
        Two orthos of one scene overlapping by 20 columns, joined by nearest nadir: the left of the
        mosaic comes from the first, the right from the second, and both agree with the scene
        (the balancing finds gain 1, offset 0):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> yy, xx = np.mgrid[0:40, 0:60]
        >>> scene = (100 + 50 * np.sin(xx / 5.0) * np.cos(yy / 7.0)).astype(np.uint8)
        >>> a = ptx.write_geotiff(folder / "a.tif", scene[:, :40], (1.0, 0.0, 0.0, 0.0, -1.0, 40.0), "EPSG:32633", nodata=0)
        >>> b = ptx.write_geotiff(folder / "b.tif", scene[:, 20:], (1.0, 0.0, 20.0, 0.0, -1.0, 40.0), "EPSG:32633", nodata=0)
        >>> info = {}
        >>> m = ptx.mosaic([a, b], method="voronoi", info=info)  # lazy: computed below
        >>> m.shape, str(m.rio.crs), info["gains"].tolist(), info["offsets"].tolist()
        ((40, 60), 'EPSG:32633', [1.0, 1.0], [0.0, 0.0])
        >>> np.unique(info["labels"][:, :25]).tolist(), np.unique(info["labels"][:, 35:]).tolist()
        ([0], [1])
        >>> bool(np.allclose(m.compute().values, scene, atol=1e-3))
        True
    """
    plan = _plan(
        orthos,
        eager=False,
        method=method,
        nadirs=nadirs,
        dsm=dsm,
        dem=dem,
        raised=raised,
        balance=balance,
        feather=feather,
        chunks=chunks,
        seam_scale=seam_scale,
        info=info,
        seamlines=seamlines,
        source_index=source_index,
    )
    return _lazy(plan)


def _out_type(dtype, nodata):
    """The type ``(dtype, nodata, lo, hi)`` a mosaic of orthos of ``dtype`` (with ``nodata``) is written
    in: integer orthos (e.g. uint8 RGB) give that type, rounded and clipped to ``lo..hi``, with their nodata
    value (the type's minimum if none; kept out of the data); float orthos give float32 with NaN."""
    dtype = np.dtype(dtype)
    if not np.issubdtype(dtype, np.integer):
        return np.dtype(np.float32), np.nan, None, None
    lo, hi = np.iinfo(dtype).min, np.iinfo(dtype).max
    nodata = lo if nodata is None or not lo <= nodata <= hi else int(nodata)
    lo, hi = (lo + 1, hi) if nodata == lo else (lo, hi - 1) if nodata == hi else (lo, hi)
    return dtype, nodata, lo, hi


def _to_type(v, dtype, nodata, lo, hi):
    """A mosaic chunk ``v`` (float32, NaN for no data) in the type of :func:`_out_type`."""
    if lo is None:
        return v.astype(dtype, copy=False)
    r = np.rint(v)
    np.minimum(np.maximum(r, lo, out=r), hi, out=r)
    r[np.isnan(v)] = nodata
    return r.astype(dtype)


def _dask_progress(bar):
    """A Dask callback advancing ``bar`` by one per task (its total grows by each graph's size)."""
    from dask.callbacks import Callback

    def start(dsk):
        bar.total = (bar.total or 0) + len(dsk)

    return Callback(start=start, posttask=lambda *a: bar.update())


def mosaic_to_raster(orthos, path, *, cog: bool = True, inputs=(), progress=None, **options):
    """:func:`mosaic` written to a raster file in the orthos' type, atomically (what ``photax mosaic`` does).

    Orthos that are raster files or NumPy-backed DataArrays, at most ``_PERSIST_BYTES`` (1 GiB) in all,
    with NumPy ``dsm`` and ``dem``, are mosaicked without Dask, xarray or rioxarray (their imports are
    most of a command-line mosaic's time): read whole, each pass and output chunk on a thread per CPU,
    the chunks written as they come (:func:`photax.io.lazy.write_tiles`); the same functions per tile,
    the same file as :func:`mosaic` then :func:`photax.to_raster`.  Others take that lazy way, on
    Dask's threads unless Dask is configured otherwise.

    Args:
        orthos: as for :func:`mosaic`.
        path: the output GeoTIFF: integer orthos (e.g. uint8 RGB) give a mosaic of their type, rounded
            and clipped, with their nodata value (the type's minimum if none, kept out of the data);
            float orthos float32 with NaN.
        cog: a Cloud-Optimized GeoTIFF (with overviews), else a tiled GeoTIFF; deflate-compressed.
        inputs: paths ``path`` must not overwrite (besides the orthos).
        progress: a progress bar (``total`` and ``update()``, e.g. tqdm's) counting the tiles, or None.
        options: :func:`mosaic`'s keyword arguments (``method``, ``dsm``, ``feather``, ``chunks``,
            ``info``, ``seamlines``, ``source_index``, ...), its defaults where not given.

    Returns:
        ``path``.

    Raises:
        ValueError: as :func:`mosaic`.
        TypeError: an option :func:`mosaic` does not take.

    Examples:
        Two overlapping orthos (GeoTIFFs on one 1 m grid) joined into one raster; where only one
        covers, the mosaic is that ortho:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> yy, xx = np.mgrid[0:40, 0:60]
        >>> scene = (100 + 50 * np.sin(xx / 5.0) * np.cos(yy / 7.0)).astype(np.uint8)
        >>> a = ptx.write_geotiff(folder / "a.tif", scene[:, :40], (1.0, 0.0, 0.0, 0.0, -1.0, 40.0), "EPSG:32633", nodata=0)
        >>> b = ptx.write_geotiff(folder / "b.tif", scene[:, 20:], (1.0, 0.0, 20.0, 0.0, -1.0, 40.0), "EPSG:32633", nodata=0)
        >>> out = ptx.mosaic_to_raster([a, b], folder / "m.tif", cog=False)
        >>> bands, profile = ptx.read_geotiff(out)
        >>> bands.shape, bool(np.array_equal(bands[0][:, :15], scene[:, :15]))
        ((1, 40, 60), True)
    """
    if unknown := sorted(set(options) - set(mosaic.__kwdefaults__)):
        raise TypeError(f"mosaic_to_raster() got options mosaic() does not take: {', '.join(unknown)}")
    options = {**mosaic.__kwdefaults__, **options}
    dsm, dem, chunks = options["dsm"], options["dem"], options["chunks"]
    orthos = [_open(o, k) for k, o in enumerate(orthos)]
    if not orthos:
        raise ValueError("orthos must hold at least one ortho")
    dtype, nodata, lo, hi = _out_type(orthos[0].dtype, orthos[0].nodata)
    inputs = [*inputs, *(o.source for o in orthos if o.source)]
    eager = (
        all(o.data is None or isinstance(o.data, np.ndarray) for o in orthos)
        and sum(_nbytes(o) for o in orthos) <= _PERSIST_BYTES
        and all(isinstance(h.data if hasattr(h, "dims") else h, (np.ndarray, type(None))) for h in (dsm, dem))
    )
    if eager:
        from .io.lazy import write_tiles

        plan = _plan(orthos, eager=True, bar=progress, **options)

        def chunk(tile, args):
            if args is None:
                return _to_type(np.full((plan.nb, tile[2], tile[3]), np.nan, np.float32), dtype, nodata, lo, hi)
            return _to_type(_blend_chunk(*args), dtype, nodata, lo, hi)

        blocks = _threads(chunk, plan.blends, progress)
        grid = plan.grid
        tiles = (((t[0], t[1]), b) for b, (t, _) in zip(blocks, plan.blends))  # blocks first: run to its end
        return write_tiles(
            path,
            tiles,
            shape=(plan.nb, *grid.shape),
            dtype=dtype,
            transform=grid.transform,
            crs=grid.crs,
            nodata=nodata,
            name="mosaic",
            chunks=chunks,
            cog=cog,
            inputs=inputs,
        )
    import contextlib

    import dask
    import dask.threaded

    from .io.lazy import to_raster

    # Dask's threads unless configured otherwise: this process may have no dask.distributed client, and
    # asking for one (a scheduler given by name does) imports distributed (0.3-0.9 s of a 1 s mosaic).
    scheduler = dask.config.get("scheduler", None) or dask.threaded.get
    with (
        _dask_progress(progress) if progress is not None else contextlib.nullcontext(),
        dask.config.set(scheduler=scheduler),
    ):
        out = _lazy(_plan(orthos, eager=False, **options))
        if lo is not None:
            data = out.data.map_blocks(_to_type, dtype, nodata, lo, hi, dtype=dtype)
            out = out.copy(data=data).rio.write_nodata(nodata, encoded=False)
        return to_raster(out, path, cog=cog, inputs=inputs)


_GDAL_RESAMPLING = {"nearest": "nearest", "bilinear": "bilinear", "cubic": "cubic", "lanczos": "lanczos",
                    "lanczos4": "lanczos", "bspline": "cubic_spline"}  # fmt: skip


def warp_to_grid(
    src_path, dst_path, grid, *, resampling: str = "bilinear", chunks: int = 1024, inputs=(), name: str = "mosaic"
):
    """A raster (a mosaic on its orthos' union grid) put on another ``grid`` (the one
    ``photax mosaic --bounds/--like/--size`` asks for), tile by tile, as a Cloud-Optimized GeoTIFF,
    atomically; no data (the file's nodata) outside the raster.

    On the same CRS, resolution and pixel lattice (whole-pixel offsets) the pixels are copied as
    they are (nearest neighbour hits every centre); otherwise they are resampled by GDAL
    (:func:`rasterio.warp.reproject`, ``resampling``; photax's ``lanczos4`` and ``bspline`` are
    GDAL's ``lanczos`` and ``cubic_spline``).

    Returns:
        ``dst_path``.
    """
    import rasterio
    from rasterio import Affine
    from rasterio.enums import Resampling as GdalResampling
    from rasterio.warp import reproject

    from .io.crs import same_crs
    from .io.lazy import write_tiles

    with rasterio.open(src_path) as src:
        a, e = src.transform.a, src.transform.e
        ga, ge = grid.transform.a, grid.transform.e
        col = (grid.transform.c - src.transform.c) / a
        row = (grid.transform.f - src.transform.f) / e
        lattice = (
            same_crs(src.crs, grid.crs)
            and (a, e) == (ga, ge)
            and src.transform.b == grid.transform.b == 0
            and src.transform.d == grid.transform.d == 0
            and abs(col - round(col)) < 1e-6
            and abs(row - round(row)) < 1e-6
        )
        method = GdalResampling.nearest if lattice else GdalResampling[_GDAL_RESAMPLING[resampling]]
        nodata = src.nodata
        fill = nodata if nodata is not None else 0
        dtype, bands = src.dtypes[0], src.count

        def tiles():
            for r0, c0, h, w in _tiles(grid.shape, chunks):
                block = np.full((bands, h, w), fill, dtype=dtype)
                reproject(
                    rasterio.band(src, list(range(1, bands + 1))),
                    block,
                    dst_transform=grid.transform * Affine.translation(c0, r0),
                    dst_crs=grid.crs if grid.crs is not None else src.crs,
                    dst_nodata=nodata,
                    src_nodata=nodata,
                    resampling=method,
                )
                yield (r0, c0), block

        return write_tiles(
            dst_path,
            tiles(),
            shape=(bands, *grid.shape),
            dtype=dtype,
            transform=grid.transform,
            crs=grid.crs if grid.crs is not None else src.crs,
            nodata=nodata,
            name=name,
            chunks=chunks,
            cog=True,
            inputs=inputs,
        )
