"""Output raster grids: :class:`Grid` (what rectification, the mosaic and the
uncertainty rasters are computed on) and :func:`ortho_grid`, the grid of an
image's footprint on a DEM.

Raster georeference at pixel *corners*, pixel centres at ``+0.5``
(``docs/conventions.md``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from rasterio import Affine

from .io.crs import check_dem, describe, require_same

if TYPE_CHECKING:  # the sensor models (JAX) are imported where used: a Grid alone needs no JAX
    from .collinearity import ExteriorOrientation
    from .dem import DEM


@dataclasses.dataclass(frozen=True)
class Grid:
    """An output raster grid: georeference, size and CRS.

    Attributes:
        transform: GDAL/rasterio affine ``(a, b, xoff, d, e, yoff)``
            (``rasterio.Affine``) from raster coordinates to map coordinates,
            georeferenced at pixel *corners*: the centre of pixel
            ``[row, col]`` is at ``transform * (col + 0.5, row + 0.5)``.
        shape: ``(rows, cols)``.
        crs: the map CRS (anything rasterio accepts), or ``None``.

    Examples:
        An output raster: its affine transform, shape and CRS; ``xy`` gives the pixel centres:

        >>> import photax as ptx
        >>> grid = ptx.Grid.from_bounds((1000.0, 2000.0, 1100.0, 2050.0), resolution=10.0, crs="EPSG:32633")
        >>> grid.shape
        (5, 10)
        >>> grid.xy()[0, 0].tolist()  # the centre of the top-left pixel
        [1005.0, 2045.0]
    """

    transform: Affine
    shape: tuple[int, int]
    crs: Any = None

    def __post_init__(self):
        t = tuple(float(v) for v in tuple(self.transform)[:6])
        if len(t) != 6 or not all(math.isfinite(v) for v in t):
            raise ValueError(f"transform must hold 6 finite affine coefficients, got {self.transform!r}")
        if t[0] * t[4] - t[1] * t[3] == 0:
            raise ValueError(f"transform is singular: {t}")
        shape = tuple(int(n) for n in self.shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be (rows, cols) with both >= 1, got {self.shape!r}")
        object.__setattr__(self, "transform", Affine(*t))
        object.__setattr__(self, "shape", shape)

    @classmethod
    def from_bounds(cls, bounds, resolution, crs=None) -> Grid:
        """A north-up grid covering ``bounds``, snapped to the resolution.

        Args:
            bounds: ``(xmin, ymin, xmax, ymax)`` in map units.
            resolution: pixel size, a scalar or ``(x_size, y_size)``, > 0.
            crs: the map CRS.

        The edges are moved outwards to whole multiples of the resolution,
        so grids of the same resolution line up pixel for pixel.
        """
        xmin, ymin, xmax, ymax = (float(v) for v in bounds)
        rx, ry = (float(v) for v in np.broadcast_to(np.asarray(resolution, dtype=float), (2,)))
        if not (rx > 0 and ry > 0):
            raise ValueError(f"resolution must be positive, got {resolution!r}")
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"bounds must be (xmin, ymin, xmax, ymax) with max > min, got {bounds!r}")
        x0, x1 = math.floor(xmin / rx) * rx, math.ceil(xmax / rx) * rx
        y0, y1 = math.floor(ymin / ry) * ry, math.ceil(ymax / ry) * ry
        shape = (max(round((y1 - y0) / ry), 1), max(round((x1 - x0) / rx), 1))
        return cls(Affine(rx, 0.0, x0, 0.0, -ry, y1), shape, crs)

    @property
    def height(self) -> int:
        return self.shape[0]

    @property
    def width(self) -> int:
        return self.shape[1]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the outer pixel edges."""
        rows, cols = self.shape
        xs, ys = zip(*(self.transform * (c, r) for c in (0, cols) for r in (0, rows)))
        return min(xs), min(ys), max(xs), max(ys)

    def xy(self, rows: slice = slice(None), cols: slice = slice(None)) -> np.ndarray:
        """Map coordinates of the pixel centres of a window.

        Args:
            rows, cols: slices of the grid (default: all of it).

        Returns:
            ``(h, w, 2)`` float64 ``(X, Y)``.
        """
        r = np.arange(self.shape[0], dtype=float)[rows] + 0.5
        c = np.arange(self.shape[1], dtype=float)[cols] + 0.5
        a, b, xoff, d, e, yoff = tuple(self.transform)[:6]
        x = xoff + a * c[None, :] + b * r[:, None]
        y = yoff + d * c[None, :] + e * r[:, None]
        return np.stack([x, y], axis=-1)


def _shoelace(p: np.ndarray) -> float:
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(np.roll(p[:, 0], -1), p[:, 1])))


MIN_PIXELS = 16  # an output grid has at least 16 x 16 pixels
GSD_FACTOR = 100.0  # and a resolution within GSD / 100 .. 100 GSD


def check_resolution(resolution, gsd: float, bounds, what: str = "the image") -> None:
    """Refuse a pixel size outside what ``what`` supports: between ``gsd / 100`` and ``100 gsd``, and
    giving a grid over ``bounds`` (xmin, ymin, xmax, ymax; :meth:`Grid.from_bounds`) of at least
    ``16 x 16`` pixels. The message names the ground sampling distance ``gsd`` and a supported range
    (up to ``side / 16``, which always gives 16 pixels)."""
    side = min(bounds[2] - bounds[0], bounds[3] - bounds[1])
    lo, hi = gsd / GSD_FACTOR, min(GSD_FACTOR * gsd, side / MIN_PIXELS)
    if hi < lo:
        raise ValueError(
            f"{what}'s footprint ({side:.4g} across) is too small for a {MIN_PIXELS} x "
            f"{MIN_PIXELS} pixel grid at {lo:.4g} (its ground sampling distance {gsd:.4g} / "
            f"{GSD_FACTOR:g})"
        )
    res = np.asarray(resolution, dtype=float)
    ok = lo <= float(np.min(res)) and float(np.max(res)) <= GSD_FACTOR * gsd
    if ok:
        shape = Grid.from_bounds(bounds, resolution).shape
        ok = min(shape) >= MIN_PIXELS
    if not ok:
        text = f"{float(res):g}" if res.ndim == 0 else str(tuple(res.tolist()))
        raise ValueError(
            f"resolution {text} is outside what {what} supports: its ground sampling "
            f"distance is {gsd:.4g}; choose from {lo:.4g} to {hi:.4g} (at most {GSD_FACTOR:g} "
            f"times finer or coarser than the GSD, at least {MIN_PIXELS} x {MIN_PIXELS} pixels)"
        )


def _footprint_outline(sensor, dem: DEM, per_side: int):
    """``(ground (4 per_side, 2), pixel outline (4 per_side, 2))`` of the image's outer pixel edges
    (``sensor``: :mod:`photax.sensor`; ground in its map CRS)."""
    from .sensor import FrameSensor

    if sensor.image_size is None:
        raise ValueError("camera must have an image_size to find the image footprint")
    if isinstance(sensor, FrameSensor):
        check_dem(dem)  # a geographic DEM's degrees are not the orientation's metres
    w, h = sensor.image_size
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    x0, x1, y0, y1 = -0.5, w - 0.5, -0.5, h - 0.5
    px = np.concatenate(
        [
            np.stack([x0 + t * (x1 - x0), np.full_like(t, y0)], -1),
            np.stack([np.full_like(t, x1), y0 + t * (y1 - y0)], -1),
            np.stack([x1 - t * (x1 - x0), np.full_like(t, y1)], -1),
            np.stack([np.full_like(t, x0), y1 - t * (y1 - y0)], -1),
        ]
    )
    ground = sensor.footprint(px, dem)
    if not np.all(np.isfinite(ground)):
        raise ValueError("the image outline does not reach the ground (camera looks above the horizon)")
    return ground, px


def _sensor(exterior, camera, dem: DEM, crs):
    """The sensor (:func:`photax.sensor.sensor_of`) and the grid's CRS: for a frame the DEM's (or
    ``crs``), for an RPC ``crs`` or else the UTM zone of the scene's centre."""
    from .camera import FrameCamera
    from .sensor import GroundSensor, sensor_of, utm_crs

    if isinstance(camera, GroundSensor):
        return camera, camera.crs
    if exterior is None and crs is None and not isinstance(camera, FrameCamera):
        crs = utm_crs(*camera.ground_box()[0])
    sensor = sensor_of(exterior, camera, crs)
    return sensor, (crs if crs is not None else dem.crs)


def ground_sampling_distance(exterior, camera, dem: DEM, *, per_side: int = 16, crs=None) -> float:
    """The image's mean ground sampling distance on ``dem``: ``sqrt(footprint area / image area in pixels)``
    (ground units per pixel; ``exterior=None`` and an :class:`photax.rpc.RPCCamera`: in ``crs``, as in
    :func:`ortho_grid`)."""
    sensor, _ = _sensor(exterior, camera, dem, crs)
    ground, px = _footprint_outline(sensor, dem, per_side)
    return math.sqrt(_shoelace(ground) / _shoelace(px))


def gsd_hint(exterior, camera, dem, grid) -> str:
    """The resolution the image supports, for an output that does not fit."""
    gsd = ground_sampling_distance(exterior, camera, dem, crs=grid.crs)
    return f"the image's ground sampling distance is {gsd:.4g} (this grid: {abs(grid.transform.a):.4g})"


def ortho_grid(
    exterior: ExteriorOrientation | None,
    camera,
    dem: DEM,
    resolution=None,
    *,
    crs=None,
    per_side: int = 16,
) -> Grid:
    """The grid covering an image's footprint on a DEM.

    The image outline (``per_side`` points per edge, on the outer pixel
    edges) is cut with the DEM by :func:`photax.image_to_ground`; rays that
    miss the DEM are cut with the plane at the DEM's mean height.  The
    bounds are clipped to the DEM and snapped to the resolution.

    Args:
        resolution: ground pixel size; default the mean ground sampling
            distance ``sqrt(footprint area / image area in pixels)``
            (:func:`ground_sampling_distance`).  A resolution more than 100
            times finer or coarser than it, or one giving fewer than 16 x 16
            pixels, is refused with the supported range (:func:`check_resolution`).
        crs: the grid's CRS (e.g. the one an orientation file names) where the DEM has none;
            default the DEM's.  Coordinates are not transformed: a DEM labelled with another
            CRS is refused (:func:`photax.io.crs.check_dem`), never relabelled.

    An RPC camera (``exterior=None``, ``camera`` an :class:`photax.rpc.RPCCamera`): the outline is
    cut with the DEM by :meth:`~photax.rpc.RPCCamera.to_ground_dem`, in any ``crs`` (default the
    UTM zone of the scene's centre); the DEM may be in another CRS (its bounds are transformed).
    Likewise a :class:`photax.PushbroomCamera` (any :class:`photax.sensor.GroundCamera`).
    """
    sensor, crs = _sensor(exterior, camera, dem, crs)
    ground, px = _footprint_outline(sensor, dem, per_side)
    gsd = math.sqrt(_shoelace(ground) / _shoelace(px))
    dxmin, dymin, dxmax, dymax = dem.bounds
    rpc = exterior is None
    if rpc and dem.crs is not None:
        from rasterio.warp import transform_bounds

        dxmin, dymin, dxmax, dymax = transform_bounds(dem.crs, crs, *dem.bounds, densify_pts=21)
    bounds = (
        max(ground[:, 0].min(), dxmin),
        max(ground[:, 1].min(), dymin),
        min(ground[:, 0].max(), dxmax),
        min(ground[:, 1].max(), dymax),
    )
    if not (bounds[2] > bounds[0] and bounds[3] > bounds[1]):
        f = (ground[:, 0].min(), ground[:, 1].min(), ground[:, 0].max(), ground[:, 1].max())
        box = lambda b: f"E {b[0]:.1f}..{b[2]:.1f}, N {b[1]:.1f}..{b[3]:.1f}"  # noqa: E731
        raise ValueError(
            f"the image footprint ({box(f)}) does not overlap the DEM ({box((dxmin, dymin, dxmax, dymax))}, "
            f"{describe(dem.crs)}); are the orientation and the DEM in the same CRS?"
        )
    if resolution is None:
        resolution = gsd
    else:
        check_resolution(resolution, gsd, bounds)
    if not rpc:
        require_same(dem.crs, "the DEM", crs, "the grid's crs=")  # names a CRS where the DEM has none
    return Grid.from_bounds(bounds, resolution, crs=dem.crs if crs is None else crs)
