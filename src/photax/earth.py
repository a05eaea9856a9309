"""The earth under an image: geodetic coordinates, a local Cartesian frame, earth curvature and
atmospheric refraction.

**Geodetic <-> earth-centred (ECEF)** (:func:`geodetic_to_ecef`, :func:`ecef_to_geodetic`), in JAX on
the WGS84 ellipsoid (``a = 6378137 m``, ``1/f = 298.257223563``)::

    N = a / sqrt(1 - e^2 sin^2 lat)
    X = (N + h) cos lat cos lon,  Y = (N + h) cos lat sin lon,  Z = (N (1 - e^2) + h) sin lat

and back by Bowring's iteration (Bowring 1976).

**Local Cartesian frame** (:class:`LocalFrame`): east, north, up (ENU) about a point of the ellipsoid,
through pyproj (``+proj=cart`` then ``+proj=topocentric``).  Working there puts the curvature of the
earth into the geometry: the collinearity equations hold as they are, nothing is corrected.

**Image-space corrections** (:class:`ImageCorrections`, :func:`correct_image`), for users who work in a
map projection (X, Y projected, Z a height) where a straight ray would need a flat earth and a
vacuum.  Both displace an image point radially from the nadir point, along the vertical plane of its
ray, which keeps its azimuth; with ``alpha`` the ray's nadir angle:

* *atmospheric refraction* bends the ray towards the vertical: the point appears farther out,
  ``d alpha = K tan alpha``, i.e. ``dr = K (r + r^3 / f^2)`` in a vertical image (Wolf & DeWitt,
  *Elements of Photogrammetry*; Kraus, *Photogrammetry*), with
  ``K = (1/(H - h)) int_h^H (n(z) - n(H)) dz``, the mean refractivity of the air between ground
  height ``h`` and camera height ``H`` above that at the camera (from Snell's law in flat layers, to
  first order in ``n - 1``).  :func:`refraction_coefficient` gives it for Bertram's formula (the ARDC model atmosphere, 1966, as in Wolf & DeWitt) or integrates
  the ICAO standard atmosphere (ISO 2533; dry air, ``n - 1 = 77.6e-6 P / T``, P in hPa, T in K);
* *earth curvature*: a map puts a point at ground distance ``S`` from the nadir, at its height, as if
  on a plane; on the sphere of radius ``R`` it lies ``theta = S / R`` around the earth, below the
  tangent plane.  For a camera at height ``Zs`` and a point at height ``h`` (law of sines in the
  triangle earth centre -- camera -- point)::

      theta = asin((R + Zs) / (R + h) sin alpha) - alpha,     tan alpha_map = R theta / (Zs - h)

  whose first term is the textbook's ``dr = H r^3 / (2 R f^2)`` (``H = Zs - h``).  ``R`` is the
  radius of curvature of the ellipsoid in the ray's azimuth (Euler: ``1/R = cos^2 az / M +
  sin^2 az / N``) when the latitude is given, else a fixed radius; a raised point's ray also turns in
  azimuth by ``h sin az cos az (1/N - 1/M)``, as the ellipsoid's normals tilt unequally north and
  east.  The map distance is taken as the distance on the ellipsoid, which an azimuthal equidistant
  projection about the nadir keeps exactly and a transverse Mercator with scale 1 on a central meridian
  through the scene to ``1 + S^2 / (6 R^2)`` (4 mm at 10 km).

:func:`correct_image` removes both from observed image coordinates: the result is where the
collinearity equations in the map frame put the point.  It needs the exterior orientation (the nadir
and the camera height), so :func:`photax.resect` with ``corrections=`` iterates: resect, correct,
resect again.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
MEAN_RADIUS = 6371008.8  # IUGG mean earth radius (m)

Refraction = Literal["bertram", "icao"]


# --- geodetic <-> ECEF ---------------------------------------------------------------------------


@jax.jit
def geodetic_to_ecef(lonlath: Array) -> Array:
    """``(..., 3)`` lon (deg), lat (deg), ellipsoidal height (m) -> ``(..., 3)`` ECEF X, Y, Z (m), WGS84."""
    g = jnp.asarray(lonlath, dtype=jnp.float64)
    lon, lat, h = jnp.deg2rad(g[..., 0]), jnp.deg2rad(g[..., 1]), g[..., 2]
    sl, cl = jnp.sin(lat), jnp.cos(lat)
    n = WGS84_A / jnp.sqrt(1.0 - WGS84_E2 * sl * sl)
    return jnp.stack([(n + h) * cl * jnp.cos(lon), (n + h) * cl * jnp.sin(lon), (n * (1.0 - WGS84_E2) + h) * sl], -1)


@jax.jit
def ecef_to_geodetic(xyz: Array) -> Array:
    """``(..., 3)`` ECEF (m) -> ``(..., 3)`` lon (deg), lat (deg), ellipsoidal height (m), WGS84.

    Bowring's iteration, five steps from ``lat = atan(Z / (p (1 - e^2)))``: below a micrometre for
    points within a few thousand km of the surface.  The height as ``p cos lat + Z sin lat - a^2 / N``,
    which stays finite at the poles."""
    x = jnp.asarray(xyz, dtype=jnp.float64)
    p = jnp.hypot(x[..., 0], x[..., 1])
    z = x[..., 2]
    lat = jnp.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(5):
        sl = jnp.sin(lat)
        n = WGS84_A / jnp.sqrt(1.0 - WGS84_E2 * sl * sl)
        h = p * jnp.cos(lat) + z * sl - WGS84_A**2 / n
        lat = jnp.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    sl = jnp.sin(lat)
    n = WGS84_A / jnp.sqrt(1.0 - WGS84_E2 * sl * sl)
    h = p * jnp.cos(lat) + z * sl - WGS84_A**2 / n
    return jnp.stack([jnp.rad2deg(jnp.arctan2(x[..., 1], x[..., 0])), jnp.rad2deg(lat), h], -1)


def radii_of_curvature(lat_deg) -> tuple[np.ndarray, np.ndarray]:
    """Meridian ``M`` and prime-vertical ``N`` radii of curvature of WGS84 at ``lat_deg`` (m)."""
    s2 = np.sin(np.deg2rad(np.asarray(lat_deg, float))) ** 2
    w = np.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A * (1.0 - WGS84_E2) / w**3, WGS84_A / w


# --- local Cartesian frame ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LocalFrame:
    """A local east-north-up (ENU) Cartesian frame about ``(lon0, lat0, h0)`` on WGS84, through pyproj.

    ``E, N, U`` in metres: ``U`` along the ellipsoid normal at the origin, ``N`` towards the north
    pole in the tangent plane.  Ground coordinates there are the ``X, Y, Z`` of photax's collinearity
    equations with the earth's curvature in the geometry (module docstring).

    Example: ``frame = LocalFrame(10.0, 45.0); enu = frame.from_geographic(lon, lat, h)``;
    ``frame.from_crs("EPSG:32632", x, y, h)`` from a projected CRS (heights ellipsoidal, as given).

    Examples:
        A local east-north-up frame at a point: that point is the origin, and a point 1 km north is
        1 km along +y (to the metre; the earth's curvature lowers it by about 0.08 m):

        >>> import numpy as np
        >>> import photax as ptx
        >>> frame = ptx.LocalFrame(15.0, 45.0, 100.0)
        >>> print(np.round(np.asarray(frame.from_geographic(15.0, 45.0, 100.0)), 6) + 0.0)
        [0. 0. 0.]
        >>> e, n, u = np.asarray(frame.from_geographic(15.0, 45.0 + 1000.0 / 111132.0, 100.0))
        >>> print(f"{e:.3f} {n:.0f} {u:.2f}")
        0.000 1000 -0.08
    """

    lon0: float
    lat0: float
    h0: float = 0.0

    def _pipeline(self):
        import pyproj

        return pyproj.Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lon_0={self.lon0!r} +lat_0={self.lat0!r} +h_0={self.h0!r}"
        )

    def from_geographic(self, lon, lat, h) -> np.ndarray:
        """lon, lat (deg), ellipsoidal h (m), any matching shapes -> ``(..., 3)`` E, N, U (m)."""
        e, n, u = self._pipeline().transform(*np.broadcast_arrays(*(np.asarray(a, float) for a in (lon, lat, h))))
        return np.stack([e, n, u], -1)

    def to_geographic(self, enu) -> np.ndarray:
        """``(..., 3)`` E, N, U (m) -> ``(..., 3)`` lon, lat (deg), ellipsoidal h (m)."""
        from pyproj.enums import TransformDirection

        enu = np.asarray(enu, float)
        lon, lat, h = self._pipeline().transform(
            enu[..., 0], enu[..., 1], enu[..., 2], direction=TransformDirection.INVERSE
        )
        return np.stack([lon, lat, h], -1)

    def from_crs(self, crs, x, y, z) -> np.ndarray:
        """Coordinates in ``crs`` (anything pyproj takes; ``z`` the ellipsoidal height) -> ``(..., 3)`` ENU."""
        import pyproj

        lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)
        return self.from_geographic(lon, lat, z)

    def to_crs(self, crs, enu) -> np.ndarray:
        """``(..., 3)`` ENU -> ``(..., 3)`` x, y in ``crs`` and the ellipsoidal height."""
        import pyproj

        g = self.to_geographic(enu)
        x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(g[..., 0], g[..., 1])
        return np.stack([x, y, g[..., 2]], -1)

    @property
    def ecef_from_enu(self) -> np.ndarray:
        """``(3, 3)`` rotation whose columns are the E, N, U axes in ECEF."""
        lon, lat = math.radians(self.lon0), math.radians(self.lat0)
        sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
        return np.array([[-sl, -sp * cl, cp * cl], [cl, -sp * sl, cp * sl], [0.0, cp, sp]])


# --- refraction ---------------------------------------------------------------------------------

# ICAO standard atmosphere (ISO 2533), geopotential and geometric height taken as equal (< 0.2 % at 11 km).
_T0, _P0, _LAPSE = 288.15, 1013.25, 0.0065  # K, hPa, K/m
_G0, _M_AIR, _R_GAS = 9.80665, 0.0289644, 8.31446
_BETA = _G0 * _M_AIR / (_R_GAS * _LAPSE)  # 5.256: P = P0 (T / T0)^beta in the troposphere
_Z11 = 11000.0
_T11 = _T0 - _LAPSE * _Z11
_P11 = _P0 * (_T11 / _T0) ** _BETA
_SCALE11 = _R_GAS * _T11 / (_G0 * _M_AIR)  # scale height of the isothermal layer above 11 km (m)
_REFRACTIVITY = 77.6e-6  # n - 1 = 77.6e-6 P / T (dry air; P hPa, T K)


def icao_refractivity(z) -> np.ndarray:
    """``n - 1`` of the ICAO standard atmosphere (dry) at height ``z`` (m above sea level, to 20 km)."""
    z = np.asarray(z, float)
    t = np.where(z < _Z11, _T0 - _LAPSE * z, _T11)
    p = np.where(z < _Z11, _P0 * (np.minimum(t, _T0 * 10) / _T0) ** _BETA, _P11 * np.exp(-(z - _Z11) / _SCALE11))
    return _REFRACTIVITY * p / t


def _icao_integral(z) -> np.ndarray:
    """``int_0^z (n - 1) dz`` (m) of :func:`icao_refractivity`, in closed form."""
    z = np.asarray(z, float)
    c = _REFRACTIVITY * _P0 / _T0

    def tropo(zz):  # int_0^zz (T/T0)^(beta - 1) dz
        return _T0 / (_LAPSE * _BETA) * (1.0 - ((_T0 - _LAPSE * zz) / _T0) ** _BETA)

    low = c * tropo(np.minimum(z, _Z11))
    high = _REFRACTIVITY * _P11 / _T11 * _SCALE11 * (1.0 - np.exp(-np.maximum(z - _Z11, 0.0) / _SCALE11))
    return low + high


def refraction_coefficient(camera_height, ground_height, model: Refraction = "bertram") -> np.ndarray:
    """The refraction constant ``K`` (radians): ``d alpha = K tan alpha`` (module docstring).

    Args:
        camera_height, ground_height: metres above sea level (broadcast together); the camera above
            the ground.
        model: ``"bertram"``: ``K = 2410 H / (H^2 - 6 H + 250) - 2410 h^2 / ((h^2 - 6 h + 250) H)``
            micro-radians with H, h in km (Bertram 1966, as Wolf & DeWitt give it), valid to
            about 9 km; ``"icao"``: the mean refractivity of the ICAO standard atmosphere between the two
            heights above its value at the camera, integrated in closed form (to 20 km).

    Examples:
        Bertram's formula by hand for a camera at 3 km over ground at sea level:
        ``K = 2410 H / (H^2 - 6 H + 250)`` micro-radians (H in km), 2410 * 3 / 241 = 30 urad:

        >>> import numpy as np
        >>> import photax as ptx
        >>> print(f"{float(np.squeeze(ptx.refraction_coefficient(3000.0, 0.0))) * 1e6:.3f} urad")
        30.000 urad
    """
    big_h = np.asarray(camera_height, float)
    h = np.asarray(ground_height, float)
    if np.any(big_h <= h):
        raise ValueError("refraction_coefficient: the camera must be above the ground (camera_height > ground_height)")
    if model == "bertram":
        hk, gk = big_h / 1000.0, h / 1000.0
        return 1e-6 * (
            2410.0 * hk / (hk * hk - 6.0 * hk + 250.0) - 2410.0 * gk * gk / ((gk * gk - 6.0 * gk + 250.0) * hk)
        )
    if model == "icao":
        if np.any(big_h > 20000.0):
            raise ValueError("refraction_coefficient: the ICAO model here reaches 20 km; camera_height is above")
        return (_icao_integral(big_h) - _icao_integral(h)) / (big_h - h) - icao_refractivity(big_h)
    raise ValueError(f"model: expected 'bertram' or 'icao', got {model!r}")


# --- image-space corrections --------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ImageCorrections:
    """Which image-space corrections to apply for a ground frame that is a map projection.

    Attributes:
        earth_curvature: remove the earth's curvature (module docstring).  Off in a local Cartesian
            frame (:class:`LocalFrame`), where it is in the geometry.
        refraction: ``None`` (off), ``"bertram"`` or ``"icao"`` (:func:`refraction_coefficient`); wanted
            in any frame.
        latitude: the scene's latitude (deg): the radius of curvature in each ray's azimuth
            (Euler's formula on WGS84); None: ``earth_radius``.
        earth_radius: the sphere's radius when ``latitude`` is None (m; the IUGG mean radius).
        height_origin: height above sea level of ``Z = 0`` of the ground frame (m): 0 for heights
            above sea level, the origin's height for a local frame (refraction only).

    Examples:
        Earth curvature and refraction as corrections of the image coordinates (off by default):

        >>> import photax as ptx
        >>> corr = ptx.ImageCorrections(earth_curvature=True, refraction="icao", latitude=45.0)
        >>> corr.earth_curvature, corr.refraction
        (True, 'icao')
    """

    earth_curvature: bool = False
    refraction: Refraction | None = None
    latitude: float | None = None
    earth_radius: float = MEAN_RADIUS
    height_origin: float = 0.0

    def __post_init__(self):
        if self.refraction not in (None, "bertram", "icao"):
            raise ValueError(f"refraction: expected None, 'bertram' or 'icao', got {self.refraction!r}")
        if not self.earth_radius > 0:
            raise ValueError(f"earth_radius: must be positive, got {self.earth_radius}")

    @property
    def active(self) -> bool:
        return bool(self.earth_curvature or self.refraction)

    @property
    def names(self) -> tuple[str, ...]:
        """What is corrected, in words (``("earth curvature", "refraction (icao)")``; empty when nothing)."""
        out = ("earth curvature",) if self.earth_curvature else ()
        return out + ((f"refraction ({self.refraction})",) if self.refraction else ())


@jax.jit
def _rotate_rays(d: Array, k: Array, zs: Array, h: Array, m_radius: Array, n_radius: Array, curvature: Array):
    """World rays ``(n, 3)`` (down: ``d_z < 0``) -> the map-frame rays: refraction ``k`` ``(n,)`` removed,
    then the earth's curvature (when ``curvature``), in each ray's vertical plane."""
    rho = jnp.hypot(d[:, 0], d[:, 1])
    tan_a = rho / -d[:, 2]
    a = jnp.arctan(tan_a) - k * tan_a  # the straight chord's nadir angle
    sin2_az = jnp.where(rho > 0, (d[:, 0] / jnp.where(rho > 0, rho, 1.0)) ** 2, 1.0)  # azimuth from north
    radius = 1.0 / ((1.0 - sin2_az) / m_radius + sin2_az / n_radius)  # Euler: cos^2 az / M + sin^2 az / N
    theta = jnp.arcsin((radius + zs) / (radius + h) * jnp.sin(a)) - a
    a_map = jnp.where(curvature, jnp.arctan(radius * theta / (zs - h)), a)
    # the vertical component scaled so that rho / -d_z = tan(a_map); at the nadir nothing changes
    t_new = jnp.tan(a_map)
    scale = jnp.where(rho > 0, tan_a / jnp.where(t_new > 0, t_new, 1.0), 1.0)
    # An ellipsoid's normals tilt by S sin(az) / N eastwards and S cos(az) / M northwards: a point raised h
    # along its own normal lies h S sin cos (1/N - 1/M) to the side of its vertical plane, which turns its
    # ray's azimuth by delta = h sin(az) cos(az) (1/N - 1/M) (whatever S); the map has it in the plane.
    sin_az = d[:, 0] / jnp.where(rho > 0, rho, 1.0)
    cos_az = d[:, 1] / jnp.where(rho > 0, rho, 1.0)
    delta = jnp.where(curvature, h * sin_az * cos_az * (1.0 / n_radius - 1.0 / m_radius), 0.0)
    cd, sd = jnp.cos(delta), jnp.sin(delta)
    return jnp.stack([d[:, 0] * cd - d[:, 1] * sd, d[:, 1] * cd + d[:, 0] * sd, d[:, 2] * scale], -1)


def correct_image(image_xy, exterior, camera, ground_height, corrections: ImageCorrections) -> np.ndarray:
    """Observed image coordinates -> where the collinearity equations in a map frame put them.

    Args:
        image_xy: ``(n, 2)`` image-plane coordinates as observed (the camera's unit, y up).
        exterior: the image's :class:`photax.ExteriorOrientation` in the map frame (its ``Z`` the
            camera's height on the same datum as ``ground_height``).
        camera: the :class:`photax.FrameCamera` (distortion is taken off first and put back after).
        ground_height: ``(n,)`` or scalar height of each point's ground (map ``Z``).
        corrections: what to remove (:class:`ImageCorrections`); nothing active returns a copy.

    Returns:
        ``(n, 2)`` corrected image coordinates; NaN where a ray misses the earth.

    Examples:
        The earth's curvature moves an image point outward: from 5 km over flat ground, 4 km off
        nadir, about ``dr = r^3 H / (2 R f^2)`` (the textbooks' first-order formula, Wolf & DeWitt):

        >>> import numpy as np
        >>> import photax as ptx
        >>> f, H, R = 0.15, 5000.0, 6371008.8
        >>> camera = ptx.FrameCamera(focal_length=f)
        >>> exterior = ptx.ExteriorOrientation(position=[0.0, 0.0, H], angles=[0.0, 0.0, 0.0])
        >>> xy = np.array([[f * 4000.0 / H, 0.0]])  # 0.12 m from the principal point
        >>> corrected = ptx.correct_image(xy, exterior, camera, 0.0, ptx.ImageCorrections(earth_curvature=True))
        >>> r = xy[0, 0]
        >>> print(f"{abs(corrected[0, 0] - r) * 1e6:.1f} um; the first-order formula {r**3 * H / (2 * R * f**2) * 1e6:.1f} um")
        30.2 um; the first-order formula 30.1 um
    """
    xy = np.asarray(image_xy, float)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"image_xy: expected shape (n, 2), got {xy.shape}")
    if not corrections.active:
        return xy.copy()
    h = np.broadcast_to(np.asarray(ground_height, float), (len(xy),))
    if np.shape(exterior.position) != (3,):
        raise ValueError(
            f"exterior: one image's orientation expected, got positions of shape {np.shape(exterior.position)}"
        )
    zs = float(np.asarray(exterior.position)[2])
    if np.any(zs <= h):
        raise ValueError("correct_image: the camera is not above every ground height")
    k = np.zeros(len(xy))
    if corrections.refraction:
        k = refraction_coefficient(
            zs + corrections.height_origin, h + corrections.height_origin, corrections.refraction
        )
    if corrections.latitude is None:
        m_r = n_r = corrections.earth_radius
    else:
        m_r, n_r = (float(r) for r in radii_of_curvature(corrections.latitude))
    f = float(camera.focal_length)
    pp = np.asarray(camera.principal_point)
    xn = np.asarray(camera.undistort_normalised(jnp.asarray((xy - pp) / f)))
    r = np.asarray(exterior.rotation)
    d = np.concatenate([xn, -np.ones((len(xy), 1))], 1) @ r.T
    d2 = np.asarray(
        _rotate_rays(jnp.asarray(d), jnp.asarray(k), jnp.asarray(zs), jnp.asarray(h), jnp.asarray(m_r), jnp.asarray(n_r),
                     jnp.asarray(bool(corrections.earth_curvature)))
    )  # fmt: skip
    q = d2 @ r
    xn2 = -q[:, :2] / q[:, 2:3]
    return pp + f * np.asarray(camera.distort_normalised(jnp.asarray(xn2)))
