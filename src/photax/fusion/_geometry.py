"""Where each PAN pixel falls in the MS image, and back: the two grids of a pan-sharpening pair.

Pixel convention as everywhere in photax (``docs/conventions.md``): ``(col, row)``, the centre of the
top-left pixel at ``(0, 0)``; an affine georeference maps pixel *corners*, so the centre of pixel
``(c, r)`` is at ``transform * (c + 0.5, r + 0.5)``.  Rasters in different CRSs are related point by
point through PROJ (``rasterio.warp.transform``).  An image without georeference (``transform=None``)
is taken to cover the other image's bounds exactly, as orthority does.
"""

from __future__ import annotations

import numpy as np

from ..errors import CRSMismatchError


def _affine(transform):
    from rasterio import Affine

    return Affine(*tuple(transform)[:6])


def _grid(shape, window):
    """``(rows, cols)`` float64 indices of the pixels of ``window`` ``(r0, c0, h, w)`` (None: all of
    ``shape``)."""
    r0, c0, h, w = (0, 0, *shape) if window is None else window
    return np.mgrid[r0 : r0 + h, c0 : c0 + w].astype(np.float64)


def _centres(shape, transform, window=None):
    """Map coordinates ``(x, y)`` of every pixel centre of a ``(rows, cols)`` grid (or of its ``window``)."""
    rows, cols = _grid(shape, window)
    t = _affine(transform)
    x = t.a * (cols + 0.5) + t.b * (rows + 0.5) + t.c
    y = t.d * (cols + 0.5) + t.e * (rows + 0.5) + t.f
    return x, y


def _to_pixels(x, y, transform):
    """Pixel-centre ``(col, row)`` of map coordinates in a grid of affine ``transform``."""
    inv = ~_affine(transform)
    cols = inv.a * x + inv.b * y + inv.c - 0.5
    rows = inv.d * x + inv.e * y + inv.f - 0.5
    return cols, rows


def _reproject_points(x, y, src_crs, dst_crs):
    if src_crs is None or dst_crs is None:
        if (src_crs is None) != (dst_crs is None):
            raise CRSMismatchError("one raster has a CRS and the other none: give both or neither")
        return x, y
    from rasterio.crs import CRS
    from rasterio.warp import transform

    a, b = CRS.from_user_input(src_crs), CRS.from_user_input(dst_crs)
    if a == b:
        return x, y
    xs, ys = transform(a, b, x.ravel(), y.ravel())
    return np.asarray(xs).reshape(x.shape), np.asarray(ys).reshape(y.shape)


def positions(src_shape, src_transform, src_crs, dst_shape, dst_transform, dst_crs, window=None):
    """``(cols, rows)`` in the ``dst`` image of every pixel centre of the ``src`` image, each of
    ``src_shape`` (or of the ``(h, w)`` of ``window`` ``(r0, c0, h, w)``, a part of the ``src`` image: the
    same values as the whole image's, pixel by pixel).  ``None`` transforms: the two images cover the same
    bounds (pixel-size ratio from the shapes)."""
    if src_transform is None or dst_transform is None:
        # Matching bounds: one grid is the other scaled (orthority's assumption for ungeoreferenced pairs).
        sy, sx = dst_shape[0] / src_shape[0], dst_shape[1] / src_shape[1]
        rows, cols = _grid(src_shape, window)
        return (cols + 0.5) * sx - 0.5, (rows + 0.5) * sy - 0.5
    x, y = _centres(src_shape, src_transform, window)
    x, y = _reproject_points(x, y, src_crs, dst_crs)
    return _to_pixels(x, y, dst_transform)


def inside(cols, rows, shape):
    """Positions inside the footprint ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` of a ``(H, W)`` image."""
    return (cols >= -0.5) & (cols <= shape[1] - 0.5) & (rows >= -0.5) & (rows <= shape[0] - 0.5)


_STRIP = 256  # PAN rows at a time: the geometry of a scene larger than memory, strip by strip


def footprint(pan_shape, pan_transform, pan_crs, ms_shape, ms_transform, ms_crs):
    """The PAN window the MS covers, ``(r0, r1, c0, c1)`` (rows ``r0:r1``, columns ``c0:c1``), and the
    PAN/MS pixel-size ratio (> 1: MS pixels are larger) over it: the inverse square root of the mean area
    one PAN step covers in MS pixels.  Strip by strip of the PAN (float64 positions of a strip at a time,
    never of the whole scene); ``None`` window when they do not overlap."""
    H, W = pan_shape

    def pos(r0, c0, h, w):
        return positions(pan_shape, pan_transform, pan_crs, ms_shape, ms_transform, ms_crs, (r0, c0, h, w))

    rows_any, cols_any = np.zeros(H, bool), np.zeros(W, bool)
    for s in range(0, H, _STRIP):
        h = min(_STRIP, H - s)
        covered = inside(*pos(s, 0, h, W), ms_shape)
        rows_any[s : s + h] = covered.any(axis=1)
        cols_any |= covered.any(axis=0)
    if not rows_any.any():
        return None, np.nan
    rr, cc = np.nonzero(rows_any)[0], np.nonzero(cols_any)[0]
    r0, r1, c0, c1 = int(rr[0]), int(rr[-1]) + 1, int(cc[0]), int(cc[-1]) + 1
    if r1 - r0 < 2 or c1 - c0 < 2:
        raise ValueError("the PAN pixels the MS covers must be at least 2 x 2")
    sums, counts = np.zeros(4), np.zeros(4)  # d col / d x, d row / d x, d col / d y, d row / d y
    for s in range(r0, r1, _STRIP):
        h = min(_STRIP, r1 - s)
        cols, rows = pos(s, c0, min(h + 1, r1 - s), c1 - c0)  # one row more: the vertical steps
        for k, d in enumerate(
            (np.diff(cols[:h], axis=1), np.diff(rows[:h], axis=1), np.diff(cols, axis=0), np.diff(rows, axis=0))
        ):
            ok = np.isfinite(d)
            sums[k] += d[ok].sum()
            counts[k] += ok.sum()
    dcx, dcy, drx, dry = sums / np.maximum(counts, 1)
    return (r0, r1, c0, c1), float(1.0 / np.sqrt(abs(dcx * dry - dcy * drx)))
