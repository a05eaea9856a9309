"""GeoTIFF (and any GDAL raster) reading and writing through rasterio.

Arrays are ``(bands, rows, cols)`` (rasterio layout).  Georeference is the
GDAL affine ``(a, b, xoff, d, e, yoff)`` at pixel corners
(``docs/conventions.md``).  Writing is atomic (:mod:`photax.io.atomic`).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import pathlib
import threading
import warnings
from typing import TYPE_CHECKING

import numpy as np

from .._rasterio import open_quietly
from ..errors import UnreadableFileError, UnsupportedFormatError
from .atomic import atomic_path

if TYPE_CHECKING:
    from ..dem import DEM


def open_raster(path):
    """``rasterio.open(path)`` for reading; an image without georeference
    (a raw photo) is fine, so rasterio's NotGeoreferencedWarning is silenced."""
    import rasterio

    from .files import check_regular, note_input

    path = pathlib.Path(path)
    note_input(path)
    try:
        check_regular(path, "raster file")
    except FileNotFoundError:
        raise FileNotFoundError(f"no such raster file: {path}") from None
    try:
        return open_quietly(path)
    except rasterio.errors.RasterioIOError as exc:
        raise UnsupportedFormatError(f"{path}: not a raster GDAL can read ({exc})") from None


def read_geotiff(path, *, masked: bool = False) -> tuple[np.ndarray, dict]:
    """Read all bands of a raster.

    Args:
        masked: return a ``numpy.ma.MaskedArray`` masked where the file has no data (its nodata value,
            its per-dataset mask band or alpha band: rasterio's ``read(masked=True)``).

    Returns:
        ``(array, profile)``: ``array`` is ``(bands, rows, cols)`` in the
        file's dtype; ``profile`` is rasterio's profile dict (``transform``
        as ``rasterio.Affine``, ``crs``, ``nodata``, ``dtype``, ...).

    Examples:
        ``(bands, rows, cols)`` and rasterio's profile (transform, CRS, dtype...):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "rgb.tif"
        >>> _ = ptx.write_geotiff(path, np.zeros((3, 20, 30), np.uint8), (2.0, 0.0, 0.0, 0.0, -2.0, 40.0), "EPSG:32633")
        >>> bands, profile = ptx.read_geotiff(path)
        >>> bands.shape, profile["count"], profile["transform"].a
        ((3, 20, 30), 3, 2.0)
    """
    with open_raster(path) as src, _damaged(path):
        return src.read(masked=masked), dict(src.profile)


def colormap(src) -> dict | None:
    """The colour map of an open palette raster (its band 1 values index colours), or None."""
    from rasterio.enums import ColorInterp

    if src.count < 1 or src.colorinterp[0] != ColorInterp.palette:
        return None
    try:
        return src.colormap(1)
    except ValueError:  # rasterio: "NULL color table"
        return None


def check_palette(path, src, resampling) -> dict | None:
    """A palette image's colour map, refusing any resampling but nearest neighbour: its values are
    colour indices, which interpolation would turn into other colours (index 2 between 1 and 3)."""
    cmap = colormap(src)
    if cmap is not None and str(getattr(resampling, "value", resampling)) != "nearest":
        raise ValueError(
            f"{path} is a palette image (its values index a colour map): only nearest-neighbour "
            f"resampling keeps them, got {str(getattr(resampling, 'value', resampling))!r}; "
            "use resampling='nearest' (--resampling nearest)"
        )
    return cmap


def read_grey(path, band: int | None = None) -> np.ndarray:
    """One ``(rows, cols)`` grey image from a raster file, in its own grey values: band ``band``
    (1-based), or the only band, or the mean of the first three (RGB).

    Raises:
        ValueError: ``band`` not in the file, naming it.

    Examples:
        One grey image from a raster: its only band, a chosen band, or the mean of RGB:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_grey
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "rgb.tif"
        >>> rgb = np.stack([np.full((4, 5), v, np.uint8) for v in (30, 60, 90)])
        >>> _ = ptx.write_geotiff(path, rgb, None)
        >>> float(read_grey(path)[0, 0]), int(read_grey(path, band=3)[0, 0])
        (60.0, 90)
    """
    data, _ = read_geotiff(path)
    if band is not None:
        if not 1 <= band <= data.shape[0]:
            raise ValueError(f"--band {band}: {path} has {data.shape[0]} band(s)")
        return data[band - 1]
    return data[0] if data.shape[0] == 1 else data[:3].astype(np.float64).mean(axis=0)


@contextlib.contextmanager
def _damaged(path):
    """A file GDAL opens but cannot decode (truncated, corrupt): ValueError naming it."""
    from rasterio._err import CPLE_BaseError
    from rasterio.errors import RasterioError

    try:
        yield
    except (RasterioError, CPLE_BaseError) as exc:
        raise UnreadableFileError(
            f"{path}: a damaged raster, GDAL cannot read it ({' '.join(str(exc).split())})"
        ) from None


def read_dem(path, band: int = 1) -> DEM:
    """Read a DEM raster as a :class:`photax.DEM` (nodata cells -> NaN).

    The CRS is kept as WKT text.  Only heights and the georeference are
    used: vertical datum conversions (geoid/ellipsoid) are up to the caller.

    Examples:
        A DEM from a GeoTIFF: its heights, transform and CRS, read at ground points:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> heights = np.full((10, 10), 75.0, np.float32)
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "dem.tif"
        >>> _ = ptx.write_geotiff(path, heights, (5.0, 0.0, 1000.0, 0.0, -5.0, 2000.0), "EPSG:32633")
        >>> dem = ptx.read_dem(path)
        >>> print(np.asarray(dem.height(np.array([1020.0]), np.array([1980.0]))), dem.crs.split('"')[1])
        [75.] WGS 84 / UTM zone 33N
    """
    with open_raster(path) as src, _damaged(path):
        if not 1 <= band <= src.count:
            raise ValueError(f"{path}: band {band} does not exist (the file has {src.count})")
        heights = src.read(band).astype(float)
        crs = src.crs.to_wkt() if src.crs else None
        nodata = src.nodata
        transform = tuple(src.transform)[:6]
    if nodata is not None and not np.isnan(nodata):
        heights[heights == nodata] = np.nan
    # Imported here: DEM brings JAX, which the commands that only read rasters never load.
    from ..dem import DEM

    try:
        return DEM(heights, transform, crs)
    except ValueError as exc:  # e.g. a singular georeference
        raise ValueError(f"{path}: {exc}") from None


def write_geotiff(
    path, array, transform, crs=None, nodata=None, *, inputs=(), compress: str | None = "deflate", mask=None
) -> pathlib.Path:
    """Write a ``(bands, rows, cols)`` or ``(rows, cols)`` array as a GeoTIFF, atomically.

    Args:
        path: output file; written to a temporary file beside it and renamed,
            so a failure leaves no partial file.  Refuses to overwrite any
            path in ``inputs``.
        array: the pixels, in the dtype to store.
        transform: affine ``(a, b, xoff, d, e, yoff)`` (or a rasterio.Affine),
            or None for an image without georeference.
        crs: anything rasterio accepts (EPSG code, WKT, PROJ string), or None.
        nodata: the nodata value to record, or None.
        compress: GeoTIFF compression, or None.
        mask: ``(rows, cols)`` bool, True where the pixels hold data: written as GDAL's internal
            per-dataset mask band (rasterio's ``read_masks``, ``read(masked=True)``), which, unlike a
            nodata value, takes no grey value away from the data.

    Examples:
        An array with its affine georeference and CRS, written atomically and read back:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> array = np.arange(12, dtype=np.uint8).reshape(3, 4)
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "a.tif"
        >>> _ = ptx.write_geotiff(path, array, (10.0, 0.0, 500000.0, 0.0, -10.0, 4100000.0), "EPSG:32633")
        >>> bands, profile = ptx.read_geotiff(path)
        >>> bands.shape, bool(np.array_equal(bands[0], array)), profile["crs"].to_epsg()
        ((1, 3, 4), True, 32633)
    """
    import rasterio
    from rasterio import Affine

    a = np.asarray(array)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or min(a.shape) < 1:
        raise ValueError(f"array must be (bands, rows, cols) or (rows, cols), got shape {np.shape(array)}")
    profile = dict(
        driver="GTiff",
        width=a.shape[2],
        height=a.shape[1],
        count=a.shape[0],
        dtype=a.dtype,
        crs=crs,
        nodata=nodata,
        BIGTIFF="IF_SAFER",
    )
    if transform is not None:
        profile["transform"] = Affine(*tuple(transform)[:6])
    if a.shape[1] >= 256 and a.shape[2] >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    if compress:
        profile["compress"] = compress
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != a.shape[1:]:
            raise ValueError(f"mask must be (rows, cols) = {a.shape[1:]}, got shape {mask.shape}")
    # A small block cache: the strips' blocks are written as they come, not all in the close (one
    # C call where a signal waits; photax.rectification's rectify_file, issue 38).
    env = rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True, GDAL_CACHEMAX=64)
    with atomic_path(path, inputs, size=None if compress else a.nbytes) as tmp, warnings.catch_warnings(), env:
        if transform is None:
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with gdal_errors(), rasterio.open(tmp, "w", **profile) as dst:
            write_in_strips(dst, a, mask)
    return pathlib.Path(path)


#: Rows written by one GDAL call in :func:`write_in_strips` (a row of the 256-pixel tiles).
STRIP_ROWS = 256


def write_in_strips(dst, array, mask=None, rows: int = STRIP_ROWS) -> None:
    """Write ``array`` ``(bands, rows, cols)`` (and ``mask``, ``(rows, cols)`` True where valid,
    to the mask band) into the open rasterio dataset ``dst`` a strip of ``rows`` rows at a time.

    Python runs signal handlers only between its own steps: one GDAL call compressing a
    large array kept a Ctrl-C or SIGTERM waiting until the whole raster was written (issue 38).
    Between strips the handlers run, and a Ctrl-C that was swallowed
    (:data:`photax.io.atomic.interrupted`) stops the write.
    """
    from rasterio.windows import Window

    from .atomic import interrupted

    _, height, width = array.shape
    for r in range(0, height, rows):
        if interrupted.is_set():
            raise KeyboardInterrupt
        h = min(rows, height - r)
        window = Window(0, r, width, h)
        dst.write(array[:, r : r + h], window=window)
        if mask is not None:
            dst.write_mask(np.where(mask[r : r + h], np.uint8(255), np.uint8(0)), window=window)


# rasterio's GDAL error handler (active while a dataset is open) logs each
# failure, at INFO, to these loggers, and raises only for some of them.
_GDAL_LOGGERS = ("rasterio._env", "rasterio._err")
_GDAL_FAILURE = "GDAL signalled an error"
_CAPTURES: list = []  # the live gdal_errors() captures
_CAPTURES_LOCK = threading.Lock()
_LEVELS: dict = {}  # the loggers' own levels, restored when the last capture ends


class _Capture(logging.Filter):
    """A filter on rasterio's loggers keeping the GDAL failures one thread logs;
    the records only let through to make it see them are dropped after."""

    def __init__(self):
        super().__init__()
        self.thread = threading.get_ident()
        self.messages: list[str] = []

    def filter(self, record):
        if record.thread == self.thread and record.getMessage().startswith(_GDAL_FAILURE):
            self.messages.append(" ".join(record.getMessage().split()))
        return record.levelno >= _LEVELS.get(record.name, (None, logging.WARNING))[1]


@contextlib.contextmanager
def gdal_errors():
    """Raise the GDAL failures in this thread during the block, even those
    rasterio lets pass: a GeoTIFF's blocks and directory are written from
    GDAL's cache when the dataset closes, and a write failing there (a full
    disk) only printed ``_tiffWriteProc: No space left on device`` and
    returned, leaving a truncated file.

    Raises:
        OSError: after the block, when GDAL signalled a failure in it (errno
            ``ENOSPC``, ``EFBIG``, ``EDQUOT`` when its message says so, else
            ``EIO``), with GDAL's messages; chained to the exception the
            block raised, if any.
    """
    capture = _Capture()
    with _CAPTURES_LOCK:
        if not _CAPTURES:
            for name in _GDAL_LOGGERS:
                logger = logging.getLogger(name)
                _LEVELS[name] = (logger.level, logger.getEffectiveLevel())
                logger.setLevel(min(logging.INFO, logger.getEffectiveLevel()))
        _CAPTURES.append(capture)
        for name in _GDAL_LOGGERS:
            logging.getLogger(name).addFilter(capture)
    try:
        yield
    except Exception as exc:
        if capture.messages:
            raise _gdal_failure(capture.messages) from exc
        raise
    finally:
        with _CAPTURES_LOCK:
            for name in _GDAL_LOGGERS:
                logging.getLogger(name).removeFilter(capture)
            _CAPTURES.remove(capture)
            if not _CAPTURES:
                for name in _GDAL_LOGGERS:
                    logging.getLogger(name).setLevel(_LEVELS.pop(name)[0])
    if capture.messages:
        raise _gdal_failure(capture.messages)


def _gdal_failure(messages: list[str]) -> OSError:
    text = "; ".join(dict.fromkeys(m.removeprefix(_GDAL_FAILURE + ": ") for m in messages))
    no = next((n for n in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT) if os.strerror(n) in text), errno.EIO)
    return OSError(no, f"GDAL: {text[:300]}")


_UNIT_SYMBOLS = {
    "metre": "m",
    "meter": "m",
    "degree": "°",
    "foot": "ft",
    "US survey foot": "US survey ft",
    "kilometre": "km",
}


def crs_unit(crs) -> str | None:
    """The linear (or angular) unit of a CRS's horizontal axes, as a short
    symbol (``"m"``, ``"ft"``, ``"US survey ft"``, ``"°"``), or None when
    the CRS is absent or unknown to GDAL/PROJ.

    Uses ``rasterio.crs.CRS.units_factor``; a reader of a report should see
    "0.76 m", not "0.76 ground units".
    """
    if crs is None or crs == "":
        return None
    from rasterio.crs import CRS
    from rasterio.errors import CRSError

    try:
        name = CRS.from_user_input(crs).units_factor[0]
    except (CRSError, ValueError, TypeError, IndexError):
        return None
    if not name or name == "unknown":
        return None
    return _UNIT_SYMBOLS.get(name, name)
