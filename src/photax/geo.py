"""Coordinate reference systems and map zones: the floor every stage stands on (issue 34).

Imports nothing of photax but :mod:`photax.errors` (pyproj and rasterio
inside the functions, so ``import photax.geo`` loads neither), so that the
models, the estimators and the readers (``photax.io``) all take their CRS
rules from one place:

* :func:`utm_crs` -- the WGS84 UTM zone of a point, ``utm_crs(lon, lat)``;
* the CRS checks where two georeferenced inputs meet (issue 27), re-exported
  by :mod:`photax.io.crs` with its vertical datums.  photax computes in the
  ground CRS of the orientation, in metres (or the CRS's linear unit): the
  collinearity equations need a Cartesian frame.  So a **geographic** CRS
  (degrees) where ground coordinates are needed is refused, naming it; two
  inputs in **different** CRSs are refused, naming both (photax does not
  reproject a DEM: ``gdalwarp -t_srs <the orientation's CRS> dem.tif
  dem_utm.tif``); an input without a CRS is not compared.  CRSs are compared
  by :class:`rasterio.crs.CRS` equality (OSR's ``IsSame``), and failing that
  by their horizontal parts (pyproj): a DEM in a compound CRS meets an
  orientation in its horizontal CRS.

Examples
--------
>>> from photax.geo import utm_crs
>>> utm_crs(lon=15.2, lat=45.8), utm_crs(-70.6, -33.4)
('EPSG:32633', 'EPSG:32719')
"""

from __future__ import annotations

import math

from .errors import CRSMismatchError, OutsideValidityError


def utm_crs(lon: float, lat: float) -> str:
    """The WGS84 UTM zone of a point, as ``"EPSG:326zz"`` (north) or ``"EPSG:327zz"`` (south).

    ``lon``, ``lat`` in degrees (keywords welcome: ``utm_crs(lon=..., lat=...)``).
    The zone is ``floor((lon + 180) / 6) + 1`` (60 at ``lon = 180``), without
    the Norway and Svalbard exceptions, as orthority and ODM choose it.
    Raises :class:`photax.errors.OutsideValidityError` outside UTM's latitudes
    (80 S to 84 N) or longitudes, or for a non-finite point.

    Examples:
        Milan (9.19 E, 45.46 N) is in zone 32 north, Santiago de Chile (70.6 W, 33.4 S) in 19 south:

        >>> import photax as ptx
        >>> ptx.utm_crs(lon=9.19, lat=45.46), ptx.utm_crs(lon=-70.6, lat=-33.4)
        ('EPSG:32632', 'EPSG:32719')
    """

    lon, lat = float(lon), float(lat)
    if not (math.isfinite(lon) and math.isfinite(lat) and -180 <= lon <= 180 and -80 <= lat <= 84):
        raise OutsideValidityError(f"no UTM zone at lon {lon}, lat {lat} (UTM covers lat 80 S to 84 N)")
    zone = min(int((lon + 180) // 6) + 1, 60)
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


def _parse(crs):
    from rasterio.crs import CRS
    from rasterio.errors import CRSError

    if crs is None or crs == "":
        return None
    try:
        return CRS.from_user_input(crs)
    except (CRSError, ValueError, TypeError):
        return None


def describe(crs) -> str:
    """A short name of ``crs``: ``EPSG:32633`` when it has a code, else its PROJ string or text."""
    c = _parse(crs)
    if c is None:
        return "no CRS" if crs is None or crs == "" else str(crs)[:80]
    code = c.to_epsg()
    if code is not None:
        return f"EPSG:{code}"
    text = c.to_proj4() or c.to_string()
    return text if len(text) <= 80 else text[:77] + "..."


def require_projected(crs, what: str) -> None:
    """ValueError when ``crs`` (of ``what``, e.g. "the DEM") is geographic."""
    c = _parse(crs)
    if c is not None and c.is_geographic:
        raise CRSMismatchError(
            f"{what} is in a geographic CRS ({describe(crs)}, degrees); photax needs ground "
            "coordinates in metres: reproject it to a projected CRS (e.g. its UTM zone)"
        )


def require_same(a, what_a: str, b, what_b: str) -> None:
    """ValueError naming both when ``a`` and ``b`` are both known and differ."""
    ca, cb = _parse(a), _parse(b)
    if ca is None or cb is None or ca == cb or _same_horizontal(ca, cb):
        return
    raise CRSMismatchError(
        f"{what_a} is in {describe(a)} but {what_b} in {describe(b)}; photax does not reproject "
        f"between them (a DEM: gdalwarp -t_srs {describe(a)} dem.tif dem_reprojected.tif)"
    )


def _horizontal(crs):
    """The horizontal part of a rasterio CRS, as a pyproj CRS (a compound CRS's first component)."""
    import pyproj

    c = pyproj.CRS.from_wkt(crs.to_wkt())
    return c.sub_crs_list[0] if c.is_compound else c


def _same_horizontal(a, b) -> bool:
    try:
        return _horizontal(a).equals(_horizontal(b), ignore_axis_order=True)
    except Exception:  # noqa: BLE001 -- a CRS pyproj cannot read: not the same
        return False


def check_dem(dem, grid=None) -> None:
    """A DEM for the collinearity equations: projected, and in the output grid's CRS when both have one."""
    require_projected(dem.crs, "the DEM")
    if grid is not None:
        require_same(dem.crs, "the DEM", grid.crs, "the output grid")


def same_crs(a, b) -> bool:
    """Whether two CRSs are the same (rasterio equality, or the same horizontal part); an unknown one
    (None, unreadable) is the same as anything, as in :func:`require_same`."""
    ca, cb = _parse(a), _parse(b)
    return ca is None or cb is None or ca == cb or _same_horizontal(ca, cb)
