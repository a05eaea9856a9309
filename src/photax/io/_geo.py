"""Geodesy shared by the readers of other tools' orientations (OpenSfM's topocentric
frame, drone latitude/longitude/roll/pitch/yaw): WGS84 positions into a projected
CRS, and the rotation from a local east-north-up frame to the projected grid
(meridian convergence, and the tilt between two points' local verticals).

Through pyproj (``import`` inside the functions: ``import photax.io`` loads none).
Heights stay what the input calls them (ellipsoidal for GNSS and OpenSfM): no
vertical datum is converted here.
"""

from __future__ import annotations

import threading

import numpy as np

from ..errors import CRSMismatchError, OutsideValidityError

#: WGS84 ellipsoid (EPSG:7030).
_A, _F = 6378137.0, 1.0 / 298.257223563
_E2 = _F * (2.0 - _F)


def projected_crs(text, what: str = "crs"):
    """A ``pyproj.CRS`` from ``text`` (EPSG code, WKT, PROJ string); it must be projected
    (of a compound CRS, its horizontal part: heights are not converted here)."""
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as exc:
        raise CRSMismatchError(f"{what}: not a CRS ({' '.join(str(exc).split())[:120]})") from None
    if crs.is_compound:  # a DEM's horizontal + vertical CRS: positions go to the horizontal one
        crs = crs.sub_crs_list[0]
    if not crs.is_projected:
        raise CRSMismatchError(f"{what}: {crs.name!r} is not a projected CRS (x, y in metres are needed)")
    return crs


def _check_lla(lat, lon, h, what):
    lat, lon, h = (np.asarray(v, dtype=float) for v in (lat, lon, h))
    if not (np.all(np.abs(lat) <= 90) and np.all(np.abs(lon) <= 360) and np.all(np.isfinite(h))):
        raise ValueError(f"{what}: latitude/longitude out of range or height not finite")
    return lat, lon, h


def ecef_from_enu(lat_deg, lon_deg) -> np.ndarray:
    """``(..., 3, 3)`` rotation from the local east-north-up frame at a geodetic point to ECEF."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    z = np.zeros_like(sl)
    east, north = np.stack([-so, co, z], -1), np.stack([-sl * co, -sl * so, cl], -1)
    cols = [east, north, np.stack([cl * co, cl * so, sl], -1)]
    return np.stack(cols, axis=-1)


def ecef(lat_deg, lon_deg, h) -> np.ndarray:
    """``(..., 3)`` WGS84 geocentric coordinates of geodetic points (closed form)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    n = _A / np.sqrt(1.0 - _E2 * np.sin(la) ** 2)
    return np.stack(
        [(n + h) * np.cos(la) * np.cos(lo), (n + h) * np.cos(la) * np.sin(lo), (n * (1.0 - _E2) + h) * np.sin(la)],
        axis=-1,
    )


_TRANSFORMERS = threading.local()


def transformer(source, target):
    """``pyproj.Transformer.from_crs(source, target, always_xy=True)``, made once per thread
    (making one costs ~40 ms: an OpenSfM reconstruction's reader made 9 a file; a pyproj
    Transformer is not shared between threads)."""
    import pyproj

    cache = getattr(_TRANSFORMERS, "cache", None)
    if cache is None:
        cache = _TRANSFORMERS.cache = {}
    key = (source, target)
    try:
        made = cache.get(key)
    except TypeError:  # an unhashable CRS description
        return pyproj.Transformer.from_crs(source, target, always_xy=True)
    if made is None:
        if len(cache) >= 64:
            cache.clear()
        made = cache[key] = pyproj.Transformer.from_crs(source, target, always_xy=True)
    return made


def geodetic_from_ecef(xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lat, lon, h)`` (degrees, metres) of ``(..., 3)`` geocentric points, through PROJ."""

    t = transformer("EPSG:4978", "EPSG:4979")
    xyz = np.asarray(xyz, dtype=float)
    lon, lat, h = t.transform(xyz[..., 0], xyz[..., 1], xyz[..., 2])
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def project_lla(lat, lon, h, crs) -> np.ndarray:
    """``(..., 3)`` positions in the projected ``crs`` of WGS84 (EPSG:4979) points; heights unchanged."""

    lat, lon, h = _check_lla(lat, lon, h, "geographic position")
    t = transformer("EPSG:4979", crs)
    x, y, z = t.transform(lon, lat, h)
    out = np.stack(np.broadcast_arrays(x, y, z), axis=-1).astype(float)
    if not np.all(np.isfinite(out)):
        raise OutsideValidityError(f"positions outside the area of {crs.name!r}")
    return out


def grid_from_enu(lat, lon, crs, delta: float = 1e-6) -> np.ndarray:
    """``(..., 3, 3)`` rotation from the east-north-up frame at WGS84 points to the
    ``(x, y, z)`` frame of the projected ``crs`` there: a turn about the vertical by
    the meridian convergence (grid north from the meridian's direction, by central
    differences along it, as orthority does; the projection is taken as conformal).
    """
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    zero = np.zeros_like(lat)
    north = project_lla(lat + delta, lon, zero, crs) - project_lla(lat - delta, lon, zero, crs)
    n = north[..., :2] / np.linalg.norm(north[..., :2], axis=-1, keepdims=True)
    z = np.zeros_like(n[..., 0])
    east = np.stack([n[..., 1], -n[..., 0], z], axis=-1)
    north = np.stack([n[..., 0], n[..., 1], z], axis=-1)
    up = np.stack([z, z, np.ones_like(z)], axis=-1)
    return np.stack([east, north, up], axis=-1)


def topocentric_to_projected(points, reference_lla, crs) -> tuple[np.ndarray, np.ndarray]:
    """Points of the topocentric (east-north-up) frame at ``reference_lla`` =
    ``(lat, lon, h)`` into the projected ``crs``, exactly (through geocentric and
    geodetic coordinates), with the ``(..., 3, 3)`` rotation from the topocentric
    frame to the grid frame at each point (the local vertical at the point, not at
    the reference, then the meridian convergence there).

    Returns:
        ``(xyz (..., 3), grid_from_topocentric (..., 3, 3))``.
    """
    lat0, lon0, h0 = _check_lla(*reference_lla, "reference_lla")
    points = np.asarray(points, dtype=float)
    r0 = ecef_from_enu(lat0, lon0)
    geocentric = ecef(lat0, lon0, h0) + points @ r0.T
    lat, lon, h = geodetic_from_ecef(geocentric)
    xyz = project_lla(lat, lon, h, crs)
    local_from_topo = np.swapaxes(ecef_from_enu(lat, lon), -1, -2) @ r0
    return xyz, grid_from_enu(lat, lon, crs) @ local_from_topo


def reproject(xyz, source, target) -> tuple[np.ndarray, np.ndarray]:
    """``(..., 3)`` positions in the projected ``source`` CRS -> ``target``, with the
    ``(..., 3, 3)`` rotation from ``source``'s grid frame to ``target``'s at each point
    (the difference of their meridian convergences); heights unchanged."""

    xyz = np.asarray(xyz, dtype=float)
    t = transformer(source, "EPSG:4979")
    lon, lat, h = (np.asarray(v) for v in t.transform(xyz[..., 0], xyz[..., 1], xyz[..., 2]))
    out = project_lla(lat, lon, h, target)
    turn = grid_from_enu(lat, lon, target) @ np.swapaxes(grid_from_enu(lat, lon, source), -1, -2)
    return out, turn


def projected_to_topocentric(xyz, reference_lla, crs) -> np.ndarray:
    """``(..., 3)`` positions in the projected ``crs`` -> the topocentric (east-north-up)
    frame at ``reference_lla`` = ``(lat, lon, h)``, exactly (through geodetic and
    geocentric coordinates): the inverse of :func:`topocentric_to_projected`'s positions."""

    lat0, lon0, h0 = _check_lla(*reference_lla, "reference_lla")
    xyz = np.asarray(xyz, dtype=float)
    t = transformer(crs, "EPSG:4979")
    lon, lat, h = (np.asarray(v) for v in t.transform(xyz[..., 0], xyz[..., 1], xyz[..., 2]))
    if not (np.all(np.isfinite(lat)) and np.all(np.isfinite(lon)) and np.all(np.isfinite(h))):
        raise OutsideValidityError(f"positions outside the area of {crs.name!r}")
    return (ecef(lat, lon, h) - ecef(lat0, lon0, h0)) @ ecef_from_enu(lat0, lon0)
