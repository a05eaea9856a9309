"""CRS checks where two georeferenced inputs meet (issue 27).

photax computes in the ground CRS of the orientation, in metres (or the
CRS's linear unit): the collinearity equations need a Cartesian frame.  So

* a **geographic** CRS (degrees) where ground coordinates are needed is
  refused, naming it: an orientation or a DEM in EPSG:4326 made a one-pixel
  "ortho" of 5.8 degrees, with exit 0;
* two inputs in **different** CRSs (the orientation's and the DEM's, the
  DEM's and an output grid's) are refused, naming both: photax does not
  reproject a DEM (resampling heights, and their vertical datum, is the
  user's choice: ``gdalwarp -t_srs <the orientation's CRS> dem.tif
  dem_utm.tif``).  A DEM labelled EPSG:32735 under an orientation in
  EPSG:32633 was used as if the numbers matched;
* an input without a CRS is not compared (nothing to compare with).

CRSs are compared by :class:`rasterio.crs.CRS` equality (OSR's ``IsSame``:
``EPSG:32633``, its WKT and its PROJ string are the same CRS), and failing that
by their horizontal parts (pyproj): a DEM in a compound CRS (the NGI DEM:
transverse Mercator + a vertical CRS) meets an orientation in its horizontal
CRS.  Vertical datums are not compared here: heights are taken as they are.

Heights between the WGS84 ellipsoid and a vertical datum (the vertical part of a
compound CRS such as ``EPSG:32735+5773``): :func:`heights_from_ellipsoid` and
:func:`heights_to_ellipsoid`, through pyproj and the geoid grid; the readers of
ellipsoidal heights (OpenSfM/ODM shots, latitude/longitude CSVs) use the first when
the CRS asked of them (a DEM's) has a vertical part.  Without the grid (pyproj's
network is off here) a :class:`VerticalDatumWarning` names it and the error it
leaves (tens of metres): PROJ itself would fall back to a zero shift, silently.
"""

from __future__ import annotations

import numpy as np

from ..errors import OutsideValidityError

# The comparisons live in photax.geo (the models' and estimators' floor, which imports no io); re-exported
# here, where the readers and the CLI have always found them.
from ..geo import check_dem, describe, require_projected, require_same, same_crs  # noqa: F401

# --- vertical datums -------------------------------------------------------------------------

#: The geoid's undulation over the globe (EGM2008: -106.9 m to +85.8 m): the error of a
#: height left on the WGS84 ellipsoid where a geoid (gravity-related) height is meant.
GEOID_UNDULATION_RANGE_M = (-107.0, 86.0)


class VerticalDatumWarning(UserWarning):
    """Heights could not be moved between the ellipsoid and a vertical datum (a missing grid)."""


def vertical_crs(crs):
    """The vertical part of ``crs`` (a compound CRS such as ``EPSG:32735+5773``, or a
    vertical CRS) as a ``pyproj.CRS``; None for a CRS without one (heights then stay
    as they are)."""
    import pyproj

    if crs is None or crs == "":
        return None
    c = pyproj.CRS.from_user_input(crs.to_wkt() if hasattr(crs, "to_wkt") and not isinstance(crs, pyproj.CRS) else crs)
    if c.is_compound:
        return c.sub_crs_list[-1]
    return c if c.is_vertical else None


def _height_transformer(crs, inverse: bool):
    """A pyproj transformer between WGS84 ellipsoidal heights (EPSG:4979) and the
    vertical datum of ``crs``, or None (with a :class:`VerticalDatumWarning` naming the
    missing grid) when the grid it needs is not available here."""
    import warnings

    import pyproj
    from pyproj.transformer import TransformerGroup

    vertical = vertical_crs(crs)
    if vertical is None:
        return None, None
    c = pyproj.CRS.from_user_input(crs.to_wkt() if hasattr(crs, "to_wkt") and not isinstance(crs, pyproj.CRS) else crs)
    if not c.is_compound and vertical.to_epsg() is None:
        raise ValueError(f"{vertical.name!r}: give a compound CRS (horizontal + vertical), not a vertical CRS alone")
    target = c if c.is_compound else pyproj.CRS.from_user_input(f"EPSG:4326+{vertical.to_epsg()}")
    source = pyproj.CRS.from_epsg(4979)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # pyproj's own note; ours names the grid and the error
        group = (
            TransformerGroup(target, source, always_xy=True)
            if inverse
            else TransformerGroup(source, target, always_xy=True)
        )
    if group.best_available and group.transformers:
        return group.transformers[0], vertical
    grids = sorted(
        {g.short_name or g.full_name for op in group.unavailable_operations for g in op.grids if not g.available}
    )
    lo, hi = GEOID_UNDULATION_RANGE_M
    warnings.warn(
        f"heights between the WGS84 ellipsoid and {vertical.name!r}: the grid "
        f"{', '.join(grids) or '(none known)'} is not available (pyproj.network is off: put the file in "
        f"{pyproj.datadir.get_user_data_dir()} or a folder of PROJ_DATA); the heights are left as they are, "
        f"in error by the geoid undulation there ({lo:g} m to +{hi:g} m over the globe, tens of metres in most "
        "places): a DEM and the cameras disagree by that much",
        VerticalDatumWarning,
        stacklevel=3,
    )
    return None, vertical


def _move_heights(lat, lon, h, crs, inverse: bool) -> np.ndarray:

    lat, lon, h = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (lat, lon, h)))
    transformer, vertical = _height_transformer(crs, inverse)
    if transformer is None:
        return h.copy()
    if inverse:  # the compound CRS's horizontal part: project the points there first
        import pyproj

        to_target = pyproj.Transformer.from_crs("EPSG:4326", transformer.source_crs.sub_crs_list[0], always_xy=True)
        x, y = to_target.transform(lon, lat)
        out = transformer.transform(x, y, h)[2]
    else:
        out = transformer.transform(lon, lat, h)[2]
    out = np.asarray(out, dtype=float)
    if not np.all(np.isfinite(out)):
        raise OutsideValidityError(f"heights outside the area of the grid of {vertical.name!r}")
    return out


def heights_from_ellipsoid(lat, lon, h, crs) -> np.ndarray:
    """WGS84 ellipsoidal heights ``h`` (GNSS, OpenSfM, a drone's RTK) at ``lat``, ``lon``
    (degrees) -> heights in the vertical datum of ``crs`` (a compound CRS such as
    ``EPSG:32735+5773``, or a vertical CRS), through pyproj and its geoid grid.
    ``h`` unchanged for a CRS without a vertical part.  When the grid is not
    available here (``pyproj.network`` is off), a :class:`VerticalDatumWarning` names
    it and the size of the error, and ``h`` is returned unchanged: never a silent
    zero shift (PROJ's "ballpark" transformation)."""
    return _move_heights(lat, lon, h, crs, inverse=False)


def heights_to_ellipsoid(lat, lon, height, crs) -> np.ndarray:
    """The inverse of :func:`heights_from_ellipsoid`: heights in ``crs``'s vertical
    datum -> WGS84 ellipsoidal heights (same warning when the grid is missing)."""
    return _move_heights(lat, lon, height, crs, inverse=True)
