"""Point clouds to surface models: rasterisation, hole filling, fusion and the Cloud-Optimized GeoTIFF.

* :func:`rasterize_points`: each point falls in the grid cell holding its ``(X, Y)`` (a
  :class:`photax.Grid`, as the ortho's: corner georeference); a cell's height is the ``median``
  (default: robust to stray matches) or the ``max`` (the top surface) of its points; its sigma the
  median ``sigma_z`` of them; its count how many.  Holes (4-connected empty cells) of at most
  ``fill`` cells across that touch no edge of the grid are filled from their rim, ring by ring
  (each cell the mean of its valid 8-neighbours: a discrete harmonic in-painting); larger ones stay
  nodata (NaN).
* :func:`fuse_dsms`: several surface models of one grid, the median height per cell of those that
  have one (s2p's fusion of the pairs of a triplet).
* :meth:`SurfaceModel.write`: a Cloud-Optimized GeoTIFF (GDAL's ``COG`` driver: tiles, overviews,
  deflate), float32, NaN nodata, the grid's CRS.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Literal

import numpy as np

from ..grid import Grid
from ._points import PointCloud

Reducer = Literal["median", "max"]


@dataclasses.dataclass(frozen=True)
class SurfaceModel:
    """A digital surface model on a :class:`photax.Grid`.

    Attributes:
        heights: ``(rows, cols)`` float64, NaN where no height.
        grid: the grid (transform, shape, CRS).
        count: ``(rows, cols)`` the points (or, fused, the models) behind each cell (0 in filled holes).
        sigma: ``(rows, cols)`` the median height sigma of those points (m; NaN where none).
        filled: ``(rows, cols)`` bool, True in the cells filled from their neighbours.
    """

    heights: np.ndarray
    grid: Grid
    count: np.ndarray
    sigma: np.ndarray
    filled: np.ndarray

    @property
    def completeness(self) -> float:
        """The share of the grid's cells with a height."""
        return float(np.isfinite(self.heights).mean())

    def dem(self):
        """The heights as a :class:`photax.DEM` (for an ortho on this surface)."""
        from ..dem import DEM

        crs = None if self.grid.crs is None else str(self.grid.crs)
        return DEM(self.heights, self.grid.transform, crs=crs)

    def write(self, path, *, inputs=(), overviews: bool = True) -> pathlib.Path:
        """Write the heights as a Cloud-Optimized GeoTIFF (:func:`write_cog`)."""
        return write_cog(path, self.heights, self.grid, inputs=inputs, overviews=overviews)


def _cells(points: PointCloud, grid: Grid):
    t = ~grid.transform
    c, r = t * (points.x, points.y)
    ci, ri = np.floor(np.asarray(c)).astype(np.int64), np.floor(np.asarray(r)).astype(np.int64)
    ok = (ci >= 0) & (ci < grid.width) & (ri >= 0) & (ri < grid.height) & np.isfinite(points.z)
    return ri[ok] * grid.width + ci[ok], ok


def _group_median(cell: np.ndarray, value: np.ndarray, n: int):
    """Median of ``value`` per ``cell`` index (``n`` cells; NaN where empty), by one sort."""
    out = np.full(n, np.nan)
    if len(cell) == 0:
        return out
    order = np.lexsort((value, cell))
    cs, vs = cell[order], value[order]
    starts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
    counts = np.diff(np.r_[starts, len(cs)])
    lo = starts + (counts - 1) // 2
    hi = starts + counts // 2
    out[cs[starts]] = 0.5 * (vs[lo] + vs[hi])
    return out


def rasterize_points(
    points: PointCloud,
    grid: Grid,
    *,
    reducer: Reducer = "median",
    fill: int = 3,
) -> SurfaceModel:
    """A surface model of a point cloud on ``grid`` (module docstring).

    Args:
        points: a :class:`PointCloud` in the grid's CRS.
        grid: the output grid (:class:`photax.Grid`; e.g. ``Grid.from_bounds(bounds, resolution, crs)``).
        reducer: ``"median"`` or ``"max"`` of the points in a cell.
        fill: holes at most this many cells across (their bounding box), enclosed by data, are filled
            from their rim; 0 fills none.

    Raises:
        ValueError: an unknown reducer, a negative ``fill``, or points of another CRS than the grid.
    """
    if reducer not in ("median", "max"):
        raise ValueError(f"reducer must be 'median' or 'max', got {reducer!r}")
    if int(fill) < 0:
        raise ValueError(f"fill must be >= 0, got {fill}")
    if not isinstance(points, PointCloud):
        raise ValueError(f"points must be a PointCloud, got {type(points).__name__}")
    if points.crs is not None and grid.crs is not None:
        from ..io.crs import same_crs

        if not same_crs(points.crs, grid.crs):
            raise ValueError("the points and the grid are in different CRSs: transform the points first")
    n = grid.height * grid.width
    cell, ok = _cells(points, grid)
    z = points.z[ok]
    count = np.bincount(cell, minlength=n)
    if reducer == "max":
        h = np.full(n, -np.inf)
        np.maximum.at(h, cell, z)
        h[count == 0] = np.nan
    else:
        h = _group_median(cell, z, n)
    sigma = _group_median(cell, points.sigma_z[ok], n)
    heights = h.reshape(grid.shape)
    filled = np.zeros(grid.shape, bool)
    if fill > 0:
        heights, filled = fill_holes(heights, int(fill))
    return SurfaceModel(heights, grid, count.reshape(grid.shape), sigma.reshape(grid.shape), filled)


def fill_holes(heights: np.ndarray, size: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """``(filled heights, filled mask)``: NaN holes (4-connected) at most ``size`` cells across that
    touch no edge of the grid, filled ring by ring from their rim (each cell the mean of its valid
    8-neighbours); larger holes and those at the edge stay NaN."""
    from scipy import ndimage

    h = np.array(heights, dtype=float)
    empty = ~np.isfinite(h)
    labels, n = ndimage.label(empty)
    if n == 0:
        return h, np.zeros(h.shape, bool)
    small = np.zeros(n + 1, bool)
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        rs, cs = sl
        across = max(rs.stop - rs.start, cs.stop - cs.start)
        edge = rs.start == 0 or cs.start == 0 or rs.stop == h.shape[0] or cs.stop == h.shape[1]
        small[k] = across <= size and not edge
    todo = small[labels]
    mask = todo.copy()
    kernel = np.ones((3, 3))
    while todo.any():
        valid = np.isfinite(h)
        s = ndimage.convolve(np.where(valid, h, 0.0), kernel, mode="constant")
        c = ndimage.convolve(valid.astype(float), kernel, mode="constant")
        ring = todo & (c > 0)
        if not ring.any():
            break
        h[ring] = s[ring] / c[ring]
        todo &= ~ring
    return h, mask


def fuse_dsms(models, *, min_count: int = 1) -> SurfaceModel:
    """The median height per cell of several :class:`SurfaceModel` of one grid (``min_count``: at least
    that many models with a height there, else NaN); ``count`` is how many had one."""
    models = list(models)
    if not models:
        raise ValueError("fuse_dsms: no surface models")
    grid = models[0].grid
    for k, m in enumerate(models[1:], start=1):
        if not isinstance(m, SurfaceModel):
            raise ValueError(f"models[{k}] is a {type(m).__name__}, not a SurfaceModel")
        if m.grid.shape != grid.shape or not np.allclose(tuple(m.grid.transform), tuple(grid.transform)):
            raise ValueError(f"models[{k}] is on another grid than models[0]: rasterize them on one grid")
    stack = np.stack([m.heights for m in models])
    count = np.isfinite(stack).sum(axis=0)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN cells
            h = np.nanmedian(stack, axis=0)
            sigma = np.nanmedian(np.stack([m.sigma for m in models]), axis=0)
    h[count < max(int(min_count), 1)] = np.nan
    filled = np.logical_and.reduce([m.filled | ~np.isfinite(m.heights) for m in models]) & np.isfinite(h)
    return SurfaceModel(h, grid, count, sigma, filled)


def write_cog(path, heights, grid: Grid, *, inputs=(), overviews: bool = True) -> pathlib.Path:
    """Write ``(rows, cols)`` heights on ``grid`` as a Cloud-Optimized GeoTIFF, atomically: GDAL's
    ``COG`` driver where present (float32, deflate with the floating-point predictor, 256 px
    tiles, overviews), else a tiled GTiff with internal overviews; nodata NaN, the grid's CRS.

    Raises:
        ValueError: heights of another shape than the grid, or no height at all (a blank DSM).
    """
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.shutil import copy as rio_copy

    from ..io.atomic import atomic_path

    h = np.asarray(heights, dtype=np.float32)
    if h.shape != grid.shape:
        raise ValueError(f"heights have shape {h.shape}, the grid {grid.shape}")
    if not np.isfinite(h).any():
        raise ValueError("the surface model has no height at all (blank DSM): nothing to write")
    profile = dict(
        driver="GTiff",
        width=grid.width,
        height=grid.height,
        count=1,
        dtype="float32",
        transform=grid.transform,
        crs=grid.crs,
        nodata=np.nan,
        tiled=True,
        blockxsize=256,
        blockysize=256,
        compress="deflate",
        predictor=3,
    )
    cog = _has_driver("COG")
    path = pathlib.Path(path)
    with atomic_path(path, inputs) as tmp:
        stage = tmp.with_name(tmp.name + ".stage.tif") if cog else tmp
        try:
            with rasterio.open(stage, "w", **profile) as dst:
                dst.write(h, 1)
                if overviews and not cog:
                    factors = [f for f in (2, 4, 8, 16, 32) if min(grid.shape) // f >= 64]
                    if factors:
                        dst.build_overviews(factors, Resampling.average)
            if cog:
                rio_copy(
                    stage,
                    tmp,
                    driver="COG",
                    compress="DEFLATE",
                    predictor="FLOATING_POINT",
                    blocksize=256,
                    overviews="AUTO" if overviews else "NONE",
                    resampling="AVERAGE",
                )
        finally:
            if cog and stage.exists():
                stage.unlink()
    return path


def _has_driver(name: str) -> bool:
    import rasterio

    with rasterio.Env() as env:
        return name in env.drivers()
