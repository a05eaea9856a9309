"""Where each PAN pixel falls in the MS image, and back: the two grids of a pan-sharpening pair.

Pixel convention as everywhere in photax (``docs/conventions.md``): ``(col, row)``, the centre of the
top-left pixel at ``(0, 0)``; an affine georeference maps pixel *corners*, so the centre of pixel
``(c, r)`` is at ``transform * (c + 0.5, r + 0.5)``.  Rasters in different CRSs are related point by
point through PROJ (``rasterio.warp.transform``).  An image without georeference (``transform=None``)
is taken to cover the other image's bounds exactly, as orthority does.
"""

from __future__ import annotations

import numpy as np


def _affine(transform):
    from rasterio import Affine

    return Affine(*tuple(transform)[:6])


def _centres(shape, transform):
    """Map coordinates ``(x, y)`` of every pixel centre of a ``(rows, cols)`` grid."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
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
            raise ValueError("one raster has a CRS and the other none: give both or neither")
        return x, y
    from rasterio.crs import CRS
    from rasterio.warp import transform

    a, b = CRS.from_user_input(src_crs), CRS.from_user_input(dst_crs)
    if a == b:
        return x, y
    xs, ys = transform(a, b, x.ravel(), y.ravel())
    return np.asarray(xs).reshape(x.shape), np.asarray(ys).reshape(y.shape)


def positions(src_shape, src_transform, src_crs, dst_shape, dst_transform, dst_crs):
    """``(cols, rows)`` in the ``dst`` image of every pixel centre of the ``src`` image, each of
    ``src_shape``.  ``None`` transforms: the two images cover the same bounds (pixel-size ratio from the
    shapes)."""
    if src_transform is None or dst_transform is None:
        # Matching bounds: one grid is the other scaled (orthority's assumption for ungeoreferenced pairs).
        sy, sx = dst_shape[0] / src_shape[0], dst_shape[1] / src_shape[1]
        rows, cols = np.mgrid[0 : src_shape[0], 0 : src_shape[1]].astype(np.float64)
        return (cols + 0.5) * sx - 0.5, (rows + 0.5) * sy - 0.5
    x, y = _centres(src_shape, src_transform)
    x, y = _reproject_points(x, y, src_crs, dst_crs)
    return _to_pixels(x, y, dst_transform)


def inside(cols, rows, shape):
    """Positions inside the footprint ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` of a ``(H, W)`` image."""
    return (cols >= -0.5) & (cols <= shape[1] - 0.5) & (rows >= -0.5) & (rows <= shape[0] - 0.5)


def pixel_ratio(cols, rows) -> float:
    """The PAN/MS pixel-size ratio (> 1: MS pixels are larger) from the MS positions of PAN pixels:
    the inverse square root of the mean area one PAN step covers in MS pixels."""
    if cols.shape[0] < 2 or cols.shape[1] < 2:
        raise ValueError("the PAN image must be at least 2 x 2 pixels")
    dcx, dcy = np.nanmean(np.diff(cols, axis=1)), np.nanmean(np.diff(rows, axis=1))
    drx, dry = np.nanmean(np.diff(cols, axis=0)), np.nanmean(np.diff(rows, axis=0))
    return float(1.0 / np.sqrt(abs(dcx * dry - dcy * drx)))
