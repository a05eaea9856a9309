"""Output raster grids: :class:`Grid` (what rectification, the mosaic and the
uncertainty rasters are computed on) and :func:`ortho_grid`, the grid of an
image's footprint on a DEM.

Raster georeference at pixel *corners*, pixel centres at ``+0.5``
(``docs/conventions.md``).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from rasterio import Affine

from .errors import DegenerateGeometryError, OutsideValidityError
from .geo import check_dem, describe, require_same

if TYPE_CHECKING:  # the sensor models (JAX) are imported where used: a Grid alone needs no JAX
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
            raise DegenerateGeometryError(f"transform is singular: {t}")
        shape = tuple(int(n) for n in self.shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be (rows, cols) with both >= 1, got {self.shape!r}")
        object.__setattr__(self, "transform", Affine(*t))
        object.__setattr__(self, "shape", shape)

    @classmethod
    def from_bounds(cls, bounds, resolution=None, crs=None, *, size=None, target_aligned: bool = False) -> Grid:
        """A north-up grid over ``bounds``, as ``gdalwarp -te`` makes it with ``-tr``, ``-ts`` and ``-tap``.

        Args:
            bounds: ``(xmin, ymin, xmax, ymax)`` in map units (``-te``).
            resolution: pixel size, a scalar or ``(x_size, y_size)``, > 0 (``-tr``).
            size: ``(width, height)`` in pixels (``-ts``); one of them 0: from the other, square
                pixels.  Not with ``resolution``.
            crs: the map CRS (the third argument, where it was before ``size`` came).
            target_aligned: snap the edges outwards to whole multiples of the resolution
                (``-tap``), so that grids of one resolution line up pixel for pixel; needs
                ``resolution``.

        The rules are gdalwarp's (``GDALWarpCreateOutput``), to the bit:

        * ``resolution``: the origin is ``(xmin, ymax)`` (after ``-tap``'s snapping) and the
          size ``int((xmax - xmin + rx / 2) / rx)`` by ``int((ymax - ymin + ry / 2) / ry)``:
          the far edges move to the nearest whole pixel;
        * ``size``: the resolution is ``(xmax - xmin) / width`` by ``(ymax - ymin) / height``,
          the bounds kept exactly;
        * neither: refused (:class:`GridSpec` takes a default resolution from the image).

        Raises:
            ValueError: bounds not ``max > min``, a resolution not positive, a size not
                whole and positive, ``size`` with ``resolution``, ``target_aligned`` without
                ``resolution``, or a grid of no pixel.
        """
        xmin, ymin, xmax, ymax = _bounds(bounds, "bounds")
        if size is not None and resolution is not None:
            raise ValueError("give a resolution or a size, not both (gdalwarp: -tr and -ts exclude each other)")
        if target_aligned and resolution is None:
            raise ValueError("target_aligned needs a resolution (gdalwarp: -tap needs -tr)")
        if size is not None:
            w, h = _size(size)
            rx = (xmax - xmin) / w if w else None
            ry = (ymax - ymin) / h if h else None
            rx, ry = (rx if rx is not None else ry), (ry if ry is not None else rx)
            if not w:
                w = int((xmax - xmin + rx / 2.0) / rx)
            if not h:
                h = int((ymax - ymin + ry / 2.0) / ry)
            return cls(Affine(rx, 0.0, xmin, 0.0, -ry, ymax), (h, w), crs)
        if resolution is None:
            raise ValueError("give a resolution or a size for the grid over the bounds")
        rx, ry = _resolution(resolution)
        if target_aligned:
            xmin, xmax = math.floor(xmin / rx) * rx, math.ceil(xmax / rx) * rx
            ymin, ymax = math.floor(ymin / ry) * ry, math.ceil(ymax / ry) * ry
        cols = int((xmax - xmin + rx / 2.0) / rx)
        rows = int((ymax - ymin + ry / 2.0) / ry)
        if min(rows, cols) < 1:
            raise ValueError(
                f"bounds {_text(bounds)} at resolution {_text(resolution)}: no whole pixel "
                f"({cols} x {rows}); give a finer resolution or wider bounds"
            )
        return cls(Affine(rx, 0.0, xmin, 0.0, -ry, ymax), (rows, cols), crs)

    @classmethod
    def like(cls, path) -> Grid:
        """The grid of a raster file: its CRS, transform and shape (``gdalwarp`` given the
        raster's ``-t_srs``, ``-te`` and ``-ts``).

        Raises:
            ValueError: the file is not a raster, or has no georeference.
        """
        import rasterio

        from ._rasterio import open_quietly
        from .errors import UnreadableFileError

        try:  # not photax.io: the grid is a lower stage than the readers
            with open_quietly(path) as src:
                transform, shape, crs = src.transform, (src.height, src.width), src.crs
        except rasterio.errors.RasterioIOError as exc:
            raise UnreadableFileError(f"{path}: not a raster GDAL can read ({exc})") from None
        if transform == Affine.identity():
            raise ValueError(f"{path}: has no georeference (no geotransform); cannot take its grid")
        return cls(transform, shape, crs.to_wkt() if crs is not None else None)

    def crop(self, bounds) -> Grid:
        """The part of this grid over ``bounds`` ``(xmin, ymin, xmax, ymax)``: on its pixel
        lattice (whole pixels, the edges moved outwards), within its extent.

        Raises:
            ValueError: the grid is rotated, or ``bounds`` do not overlap it.
        """
        a, b, xoff, d, e, yoff = tuple(self.transform)[:6]
        if b != 0 or d != 0 or a <= 0 or e >= 0:
            raise ValueError("crop: only a north-up grid (no rotation) can be cropped to bounds")
        xmin, ymin, xmax, ymax = _bounds(bounds, "bounds")
        rows, cols = self.shape
        c0 = max(math.floor((xmin - xoff) / a), 0)
        c1 = min(math.ceil((xmax - xoff) / a), cols)
        r0 = max(math.floor((yoff - ymax) / -e), 0)
        r1 = min(math.ceil((yoff - ymin) / -e), rows)
        if c1 <= c0 or r1 <= r0:
            raise ValueError(f"bounds {_text(bounds)} do not overlap the grid ({_text(self.bounds)})")
        return Grid(self.transform * Affine.translation(c0, r0), (r1 - r0, c1 - c0), self.crs)

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


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """What was asked of an output grid, gdalwarp's way: checked when made, a :class:`Grid` once
    the image's footprint and sampling distance are known (:meth:`grid`).

    Attributes:
        bounds: ``(xmin, ymin, xmax, ymax)`` (``-te``), or None: the footprint's.
        resolution: pixel size, scalar or ``(x, y)`` (``-tr``), or None: the image's sampling
            distance (with ``bounds``: rounded to whole pixels over them, as gdalwarp does).
        size: ``(width, height)`` (``-ts``), or None.
        target_aligned: snap ``bounds`` outwards to multiples of ``resolution`` (``-tap``).
        crs: the output CRS, or None: the command's default.
        like: a :class:`Grid` to take as it is (its CRS, transform and shape); excludes the others.

    A grid made from the footprint (no ``bounds``) is always target aligned, so that orthos of
    one resolution share one pixel lattice (what :func:`photax.mosaic` needs).

    Examples:
        ``-tr 10 -tap`` over an image's footprint snaps it outwards to whole 10 m pixels; ``-ts``
        divides given bounds into a size:

        >>> import photax as ptx
        >>> footprint = (1003.0, 2001.0, 1096.0, 2047.0)
        >>> g = ptx.GridSpec(resolution=10.0).grid(footprint)
        >>> g.shape, g.transform[2], g.transform[5]  # rows, cols; the top-left corner
        ((5, 10), 1000.0, 2050.0)
        >>> ptx.GridSpec(bounds=(0.0, 0.0, 100.0, 50.0), size=(4, 2)).grid().transform[0]  # 100 m / 4
        25.0
        >>> ptx.GridSpec(bounds=(0.0, 0.0, 100.0, 50.0)).fixed  # without a resolution: it waits for the image's
        False
    """

    bounds: tuple | None = None
    resolution: Any = None
    size: tuple | None = None
    target_aligned: bool = False
    crs: Any = None
    like: Grid | None = None

    def __post_init__(self):
        if self.like is not None:
            given = [n for n in ("bounds", "resolution", "size", "crs") if getattr(self, n) is not None]
            given += ["target_aligned"] if self.target_aligned else []
            if given:
                raise ValueError(f"like: takes the raster's CRS, transform and shape; leave out {', '.join(given)}")
            if not isinstance(self.like, Grid):
                object.__setattr__(self, "like", Grid.like(self.like))
            return
        if self.size is not None and self.resolution is not None:
            raise ValueError("give a resolution or a size, not both (gdalwarp: -tr and -ts exclude each other)")
        if self.target_aligned and self.resolution is None:
            raise ValueError("target_aligned needs a resolution (gdalwarp: -tap needs -tr)")
        if self.bounds is not None:
            object.__setattr__(self, "bounds", _bounds(self.bounds, "bounds"))
        if self.resolution is not None:
            r = _resolution(self.resolution)
            object.__setattr__(self, "resolution", r[0] if r[0] == r[1] else r)
        if self.size is not None:
            object.__setattr__(self, "size", _size(self.size))

    @property
    def fixed(self) -> bool:
        """Whether the grid is known without the image: ``like``, or ``bounds`` with a resolution
        or a size."""
        return self.like is not None or (self.bounds is not None and (self.resolution, self.size) != (None, None))

    def grid(self, footprint=None, default_resolution=None, crs=None) -> Grid:
        """The grid: ``like``'s; or over ``bounds`` (default ``footprint``, the image's
        ``(xmin, ymin, xmax, ymax)``) at ``resolution`` (default ``default_resolution``) or of
        ``size``, in ``self.crs`` (default ``crs``), by :meth:`Grid.from_bounds`."""
        if self.like is not None:
            return self.like
        crs = self.crs if self.crs is not None else crs
        if self.bounds is None:
            if footprint is None:
                raise ValueError("the grid needs bounds (none given, and no footprint)")
            if self.size is not None:
                return Grid.from_bounds(footprint, size=self.size, crs=crs)
            res = self.resolution if self.resolution is not None else default_resolution
            return Grid.from_bounds(footprint, res, crs=crs, target_aligned=True)
        if self.size is not None or self.resolution is not None:
            return Grid.from_bounds(
                self.bounds, self.resolution, crs, size=self.size, target_aligned=self.target_aligned
            )
        if default_resolution is None:
            raise ValueError("the grid over the bounds needs a resolution or a size")
        # gdalwarp -te alone: its suggested resolution rounded to whole pixels over the bounds
        rx, ry = _resolution(default_resolution)
        xmin, ymin, xmax, ymax = self.bounds
        cols = max(int((xmax - xmin + rx / 2.0) / rx), 1)
        rows = max(int((ymax - ymin + ry / 2.0) / ry), 1)
        return Grid.from_bounds(self.bounds, size=(cols, rows), crs=crs)


def _text(v) -> str:
    v = np.asarray(v, dtype=float)
    return f"{float(v):g}" if v.ndim == 0 else "(" + ", ".join(f"{x:.10g}" for x in v.ravel()) + ")"


def _bounds(bounds, what: str) -> tuple[float, float, float, float]:
    try:
        b = tuple(float(v) for v in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be (xmin, ymin, xmax, ymax) numbers, got {bounds!r}") from None
    if len(b) != 4 or not all(math.isfinite(v) for v in b) or not (b[2] > b[0] and b[3] > b[1]):
        raise ValueError(f"{what} must be finite (xmin, ymin, xmax, ymax) with max > min, got {bounds!r}")
    return b


def _resolution(resolution) -> tuple[float, float]:
    try:
        r = np.broadcast_to(np.asarray(resolution, dtype=float), (2,))
    except (TypeError, ValueError):
        raise ValueError(f"resolution must be a number or (x_size, y_size), got {resolution!r}") from None
    rx, ry = float(r[0]), float(r[1])
    if not (rx > 0 and ry > 0 and math.isfinite(rx) and math.isfinite(ry)):
        raise ValueError(f"resolution must be positive and finite, got {resolution!r}")
    return rx, ry


def _size(size) -> tuple[int, int]:
    try:
        w, h = (float(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be (width, height) in pixels, got {size!r}") from None
    if not (w == int(w) and h == int(h) and w >= 0 and h >= 0 and w + h > 0):
        raise ValueError(f"size must be whole (width, height) >= 0, not both 0, got {size!r}")
    return int(w), int(h)


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
        shape = Grid.from_bounds(bounds, resolution, target_aligned=True).shape
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
    if sensor.image_size is None:
        raise ValueError("camera must have an image_size to find the image footprint")
    if sensor.kind == "frame":
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


PARTIAL_DEM = 0.95  # a DEM covering less of an image than this share: a PartialDEMWarning


def dem_coverage(exterior, camera, dem: DEM, *, samples: int = 8, crs=None) -> float:
    """The share of an image whose ground lies on the DEM (0 .. 1): of a ``samples x samples`` lattice
    of pixels spread evenly over the image (cell centres; the default 8 x 8 = 64 points reuse the
    compiled program of :func:`ortho_grid`'s outline, 16 points a side, and give the share to 1/64),
    those whose ray (frame camera: :func:`photax.image_to_ground`) or RPC / push-broom line of sight (the fixed-point iteration of
    :meth:`photax.rpc.RPCCamera.to_ground_dem`) meets a height of the DEM; NaN heights (nodata, holes)
    and ground beyond the DEM's raster count as not covered. ``exterior, camera`` as in
    :func:`ortho_grid` (``exterior=None`` with a ground camera, or a sensor of :mod:`photax.sensor`).

    :func:`photax.orthorectify` warns (:class:`photax.errors.PartialDEMWarning`) below
    :data:`PARTIAL_DEM` and refuses an image the DEM does not cover at all.

    Examples:
        A nadir image 100 m on a side (100 px, f = 100 px, 100 m up) over a DEM of its western half:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (100, 100))
        >>> exterior = ptx.ExteriorOrientation([0.0, 0.0, 100.0], [0.0, 0.0, 0.0])
        >>> west = ptx.DEM(np.zeros((101, 51)), (1.0, 0.0, -50.0, 0.0, -1.0, 50.0))  # x from -50 to 1 m
        >>> ptx.dem_coverage(exterior, camera, west)
        0.5
    """

    if int(samples) < 2:
        raise ValueError(f"samples: expected at least 2, got {samples}")
    sensor, _ = _sensor(exterior, camera, dem, crs)
    if sensor.image_size is None:
        raise ValueError("camera must have an image_size to find the covered share of the image")
    w, h = sensor.image_size
    t = (np.arange(samples) + 0.5) / samples
    px = np.stack(np.meshgrid(t * w - 0.5, t * h - 0.5), -1).reshape(-1, 2)
    ground = sensor.on_dem(px, dem)
    return float(np.mean(np.all(np.isfinite(ground), axis=1)))


def check_coverage(sensor, dem: DEM, *, stacklevel: int = 3) -> float:
    """:func:`dem_coverage` of ``sensor``: a :class:`photax.errors.PartialDEMWarning` with the share
    below :data:`PARTIAL_DEM`, a ValueError when it is nothing. Returns the share."""
    share = dem_coverage(None, sensor, dem)
    if share == 0:
        raise OutsideValidityError(
            "the DEM covers none of the image (no height under any of its pixels: nodata there, or the DEM "
            f"lies elsewhere; DEM bounds {tuple(round(v, 1) for v in dem.bounds)}, {describe(dem.crs)})"
        )
    if share < PARTIAL_DEM:
        from .errors import PartialDEMWarning

        warnings.warn(
            PartialDEMWarning(
                f"the DEM covers {share:.1%} of the image's footprint: the ortho is nodata where it has no height",
                share,
            ),
            stacklevel=stacklevel,
        )
    return share


def _sensor(exterior, camera, dem: DEM, crs):
    """The sensor (:func:`photax.sensor.sensor_of`) and the grid's CRS: for a frame the DEM's (or
    ``crs``), for an RPC ``crs`` or else the UTM zone of the scene's centre."""
    from .geo import utm_crs
    from .sensor import camera_kind, is_sensor, sensor_of

    if is_sensor(camera) and camera.kind != "frame":
        return camera, camera.crs
    if is_sensor(camera):  # a frame sensor: the asked CRS, else its own, else the DEM's
        return camera, crs if crs is not None else (camera.crs if camera.crs is not None else dem.crs)
    if exterior is None and crs is None and camera_kind(camera) != "frame":  # a ground camera
        crs = utm_crs(*camera.ground_box()[0])
    sensor = sensor_of(exterior, camera, crs)
    return sensor, (crs if crs is not None else dem.crs)


def ground_sampling_distance(exterior, camera=None, dem: DEM | None = None, *, per_side: int = 16, crs=None) -> float:
    """The image's mean ground sampling distance on ``dem``: ``sqrt(footprint area / image area in pixels)``;
    ``ground_sampling_distance(sensor, dem)`` for any :class:`photax.sensor.Sensor`, or ``(exterior, camera, dem)``
    (ground units per pixel; ``exterior=None`` and an :class:`photax.rpc.RPCCamera`: in ``crs``, as in
    :func:`ortho_grid`)."""
    exterior, camera, dem, crs = _from_sensor(exterior, camera, dem, crs)
    sensor, _ = _sensor(exterior, camera, dem, crs)
    ground, px = _footprint_outline(sensor, dem, per_side)
    return math.sqrt(_shoelace(ground) / _shoelace(px))


def _from_sensor(exterior, camera, dem, crs, resolution=None):
    """``(exterior, camera, dem, crs)`` of the older signature for the sensor form ``(sensor, dem, ...)``
    (:func:`photax.sensor.sensor_arguments`; the grid's CRS the sensor's where not given), or as given;
    with ``resolution`` the slot a shifted call left it in is returned after them."""
    from .sensor import is_sensor, sensor_arguments

    if not is_sensor(exterior):
        return (exterior, camera, dem, crs) if resolution is None else (exterior, camera, dem, crs, resolution[0])
    sensor = exterior
    exterior, camera, dem, _, rest = sensor_arguments(sensor, (camera, dem, *(resolution or ())))
    crs = crs if crs is not None else sensor.crs
    if crs is not None:
        from .sensor import check_sensor_crs

        check_sensor_crs(sensor, crs)
    if resolution is None:
        return exterior, camera, dem, crs
    return exterior, camera, dem, crs, (rest[0] if rest else None)


def gsd_hint(exterior, camera, dem, grid) -> str:
    """The resolution the image supports, for an output that does not fit."""
    gsd = ground_sampling_distance(exterior, camera, dem, crs=grid.crs)
    return f"the image's ground sampling distance is {gsd:.4g} (this grid: {abs(grid.transform.a):.4g})"


def ortho_grid(
    exterior,
    camera=None,
    dem: DEM | None = None,
    resolution=None,
    *,
    crs=None,
    per_side: int = 16,
    bounds=None,
    size=None,
    target_aligned: bool = False,
    like=None,
    spec: GridSpec | None = None,
) -> Grid:
    """The grid covering an image's footprint on a DEM: ``ortho_grid(sensor, dem, resolution=None, ...)``
    for any :class:`photax.sensor.Sensor` (its CRS the grid's), or ``(exterior, camera, dem, ...)``.

    The image outline (``per_side`` points per edge, on the outer pixel
    edges) is cut with the DEM by :func:`photax.image_to_ground`; rays that
    miss the DEM are cut with the plane at the DEM's mean height.  The
    bounds are clipped to the DEM and snapped to the resolution (``gdalwarp -tap``).

    Args:
        resolution: ground pixel size; default the mean ground sampling
            distance ``sqrt(footprint area / image area in pixels)``
            (:func:`ground_sampling_distance`).  A resolution more than 100
            times finer or coarser than it, or one giving fewer than 16 x 16
            pixels, is refused with the supported range (:func:`check_resolution`).
        crs: the grid's CRS (e.g. the one an orientation file names) where the DEM has none;
            default the DEM's.  Coordinates are not transformed: a DEM labelled with another
            CRS is refused (:func:`photax.io.crs.check_dem`), never relabelled.
        bounds, size, target_aligned: the grid as ``gdalwarp -te``, ``-ts``, ``-tap`` make it
            (:meth:`Grid.from_bounds`; with ``resolution`` for ``-tr``): over ``bounds`` whole,
            not cut to the footprint; without ``bounds`` over the footprint.
        like: a raster (path) or :class:`Grid` whose CRS, transform and shape the grid takes.
        spec: all of these as one :class:`GridSpec` (instead of them).

    A frame image's grid is in its orientation's CRS: another one asked for (a ``like`` raster's
    CRS included) raises :class:`photax.errors.OutputCRSError` (reproject the ortho afterwards,
    e.g. with ``gdalwarp -t_srs``).  Grids given by ``bounds``/``like`` must overlap the image's
    footprint, and a resolution is checked against the ground sampling distance (100 times
    finer or coarser is refused).

    An RPC camera (``exterior=None``, ``camera`` an :class:`photax.rpc.RPCCamera`): the outline is
    cut with the DEM by :meth:`~photax.rpc.RPCCamera.to_ground_dem`, in any ``crs`` (default the
    UTM zone of the scene's centre); the DEM may be in another CRS (its bounds are transformed).
    Likewise a :class:`photax.PushbroomCamera` (any :class:`photax.sensor.GroundCamera`).
    """
    exterior, camera, dem, crs, resolution = _from_sensor(exterior, camera, dem, crs, (resolution,))
    if spec is None:
        spec = GridSpec(bounds, resolution, size, target_aligned, None, like)
    elif (resolution, bounds, size, like) != (None, None, None, None) or target_aligned:
        raise ValueError("ortho_grid: give spec or resolution/bounds/size/target_aligned/like, not both")
    rpc = exterior is None
    if rpc:
        asked = spec.like.crs if spec.like is not None else spec.crs
        crs = asked if asked is not None else crs
    sensor, crs = _sensor(exterior, camera, dem, crs)
    if not rpc:
        check_frame_crs(spec, crs if crs is not None else dem.crs)
    ground, px = _footprint_outline(sensor, dem, per_side)
    gsd = math.sqrt(_shoelace(ground) / _shoelace(px))
    dxmin, dymin, dxmax, dymax = dem.bounds
    if rpc and dem.crs is not None:
        from rasterio.warp import transform_bounds

        dxmin, dymin, dxmax, dymax = transform_bounds(dem.crs, crs, *dem.bounds, densify_pts=21)
    footprint = (
        max(ground[:, 0].min(), dxmin),
        max(ground[:, 1].min(), dymin),
        min(ground[:, 0].max(), dxmax),
        min(ground[:, 1].max(), dymax),
    )
    box = lambda b: f"E {b[0]:.1f}..{b[2]:.1f}, N {b[1]:.1f}..{b[3]:.1f}"  # noqa: E731
    if not (footprint[2] > footprint[0] and footprint[3] > footprint[1]):
        f = (ground[:, 0].min(), ground[:, 1].min(), ground[:, 0].max(), ground[:, 1].max())
        raise ValueError(
            f"the image footprint ({box(f)}) does not overlap the DEM ({box((dxmin, dymin, dxmax, dymax))}, "
            f"{describe(dem.crs)}); are the orientation and the DEM in the same CRS?"
        )
    if not rpc:
        require_same(dem.crs, "the DEM", crs, "the grid's crs=")  # names a CRS where the DEM has none
    crs = dem.crs if crs is None else crs
    if spec.bounds is None and spec.like is None:
        if spec.resolution is not None:
            check_resolution(spec.resolution, gsd, footprint)
        return spec.grid(footprint, gsd, crs)
    grid = spec.grid(footprint, gsd, crs)
    res = (abs(grid.transform.a), abs(grid.transform.e))
    if not (gsd / GSD_FACTOR <= min(res) and max(res) <= GSD_FACTOR * gsd):
        raise ValueError(
            f"the grid's resolution {_text(res)} is outside what the image supports: its ground sampling "
            f"distance is {gsd:.4g}; choose from {gsd / GSD_FACTOR:.4g} to {GSD_FACTOR * gsd:.4g}"
        )
    g = grid.bounds
    if not (g[0] < footprint[2] and footprint[0] < g[2] and g[1] < footprint[3] and footprint[1] < g[3]):
        raise ValueError(f"the output grid ({box(g)}) does not overlap the image's footprint ({box(footprint)})")
    return grid


def check_frame_crs(spec: GridSpec, crs) -> None:
    """A frame image's grid is in its orientation's CRS: refuse another one."""
    from .errors import OutputCRSError
    from .geo import same_crs

    asked, what = (spec.like.crs, "the like raster's CRS") if spec.like is not None else (spec.crs, "the output CRS")
    if asked is not None and not same_crs(asked, crs):
        raise OutputCRSError(
            f"{what} ({describe(asked)}) is not the frame orientation's ({describe(crs)}): a frame image is "
            "orthorectified in its orientation's CRS; reproject the ortho afterwards (gdalwarp -t_srs)"
        )
