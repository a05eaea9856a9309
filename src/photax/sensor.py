"""Sensors: ground point of a map CRS -> image pixel, the one thing orthorectification asks of a camera.

A *sensor* is an :class:`equinox.Module` with

* ``sensor(ground)``: ``(..., 3)`` ground ``(X, Y, Z)`` in the output grid's CRS -> ``(..., 2)``
  pixel ``(column, row)``, NaN where the point cannot be imaged (behind a frame camera, outside an
  RPC's validity volume); JAX, jittable and differentiable;
* ``image_size``: ``(width, height)`` in pixels;
* ``footprint(pixel, dem)``: ``(n, 2)`` pixels -> ``(n, 2)`` ground ``(X, Y)`` on the DEM (on a
  plane at its mean height where the ray misses it), for the default output grid.

Every sensor implements the one :class:`Sensor` protocol (``project``, ``localize``, ``image_size``,
``crs``, ``footprint``, ``on_dem``, ``validity``, ``kind``), which the products (:func:`photax.orthorectify`,
:func:`photax.ortho_grid`, :func:`photax.ortho_uncertainty`, :func:`photax.match_ties`) take in place of
``(exterior, camera)``.

Two kinds (:func:`sensor_of` picks one from what the user holds):

* :class:`FrameSensor`: an exterior orientation and a :class:`photax.FrameCamera`, the collinearity
  equations in the orientation's (projected) CRS, which is the grid's and the DEM's.
* :class:`GroundSensor`: a *ground camera* and the grid's CRS. A ground camera works in lon, lat (WGS84
  degrees) and ellipsoidal height: a :class:`photax.rpc.RPCCamera` (refined or not) or a
  :class:`photax.PushbroomCamera`; it has ``__call__(lon_lat_h) -> (column, row)``, ``image_size``,
  ``ground_box()`` (its validity box: centre and half-sides in degrees), ``height_range`` (its
  heights, or None for any), ``invert(pixel, h) -> (lon_lat, converged)`` (jittable) and
  ``to_ground(pixel, h)`` (:class:`GroundCamera`). The grid's ``(X, Y)`` are transformed to
  lon, lat by pyproj (through a :class:`LocalTransform`: a degree-5 polynomial fitted over the
  camera's validity box and checked to 1e-9 of its extent), ``Z`` is passed on as the ellipsoidal
  height. A DEM on a geoid (EGM96, EGM2008: most national DEMs, SRTM) must be converted first: taken
  as ellipsoidal, a height error ``dN`` (the geoid undulation, up to +-100 m) moves the imaged point
  by ``dN tan(off-nadir angle)`` on the ground. The DEM may be in another CRS than the grid: it is
  sampled (bilinearly) at the grid point transformed into its CRS, as GDAL's ``RPC_DEM`` samples it
  at the lon, lat.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Literal, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._aot import disk_cached
from ._pytree import Module, field, filter_jit
from .camera import FrameCamera, distort, distortion_jacobian
from .collinearity import ExteriorOrientation, image_to_ground
from .dem import DEM
from .errors import CRSMismatchError, NotConvergedError
from .geo import utm_crs as utm_crs  # noqa: F401 -- its old home, public: photax.sensor.utm_crs
from .rpc import RPC_MARGIN

WGS84 = "EPSG:4326"


def _pyproj(xy: np.ndarray, src: str, dst: str) -> np.ndarray:
    """``(..., 2)`` points of ``src`` -> ``dst`` by pyproj (``always_xy``), NaN where it fails."""
    import pyproj

    xy = np.asarray(xy, dtype=np.float64)
    x, y = pyproj.Transformer.from_crs(src, dst, always_xy=True).transform(xy[..., 0], xy[..., 1], errcheck=False)
    out = np.stack([np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)], axis=-1)
    return np.where(np.isfinite(out), out, np.nan)


_DEGREE = 5  # of the local transformation's polynomial: 21 terms per axis
_FIT_TOL = 1e-9  # its largest error allowed, relative to the box's extent in the target CRS


def _terms(u: Array, xp=jnp) -> Array:
    """``(..., 21)`` monomials ``u^i v^j``, ``i + j <= 5``, of ``(..., 2)`` normalised points (``xp``:
    jax.numpy, or numpy where no JAX is wanted: the fit, eagerly, is 10 x faster in numpy)."""
    x, y = u[..., 0], u[..., 1]
    return xp.stack([x**i * y ** (d - i) for d in range(_DEGREE + 1) for i in range(d + 1)], axis=-1)


class LocalTransform(Module):
    """A CRS transformation (pyproj) over a box, as a polynomial of degree 5 in JAX: jittable,
    differentiable, cached with the compiled code (a pyproj call inside it would be a host callback,
    which JAX neither caches on disk nor runs safely on its threads).

    Map projections are smooth on the scale of the earth's radius ``R``: over a box of side ``d`` the
    polynomial's error is about ``d (d / R)^6``, 1e-6 m for ``d`` = 60 km. :meth:`fit` checks it on
    points between its fitting points and refuses a box where it exceeds 1e-9 of the box's extent
    (0.1 mm over 100 km). Outside the box it is extrapolated (callers stay inside).
    """

    center: Array  # (2,) of the box, source CRS
    half: Array  # (2,) half-sides of the box
    origin: Array  # (2,) the target of the centre
    coefficients: Array  # (21, 2)
    error: float = field(static=True)  # the largest error found by the check, target units

    @classmethod
    def fit(cls, src: str, dst: str, bounds, n: int = 25) -> LocalTransform:
        """Fit over ``bounds`` ``(xmin, ymin, xmax, ymax)`` of ``src`` on an ``n x n`` lattice."""
        x0, y0, x1, y1 = (float(v) for v in bounds)
        center, half = np.array([(x0 + x1) / 2, (y0 + y1) / 2]), np.array([(x1 - x0) / 2, (y1 - y0) / 2])
        if not (np.all(np.isfinite(center)) and np.all(half > 0)):
            raise ValueError(f"LocalTransform: bad bounds {bounds}")
        t = np.cos(np.linspace(np.pi, 0.0, n))  # Chebyshev points: no Runge oscillation at the edges
        u = np.stack(np.meshgrid(t, t), -1).reshape(-1, 2)
        target = _pyproj(center + u * half, src, dst)
        if not np.all(np.isfinite(target)):
            raise ValueError(f"the box {bounds} does not transform from {_short(src)} to {_short(dst)}")
        origin = _pyproj(center, src, dst)
        design = _terms(u, np)
        coef = np.linalg.lstsq(design, target - origin, rcond=None)[0]
        tm = 0.5 * (t[1:] + t[:-1])  # the check: halfway between the fitting points
        uc = np.concatenate([np.stack(np.meshgrid(tm, tm), -1).reshape(-1, 2), u])
        truth = _pyproj(center + uc * half, src, dst)
        err = float(np.max(np.abs(_terms(uc, np) @ coef + origin - truth)))
        extent = float(np.max(np.ptp(target, axis=0)))
        if not err <= _FIT_TOL * extent:
            raise ValueError(
                f"the transformation from {_short(src)} to {_short(dst)} is not smooth enough over "
                f"{bounds} (a degree-{_DEGREE} polynomial is off by {err:.3g}, {err / extent:.2g} of the "
                "extent): is the area too large, or does it cross a zone edge or a pole?"
            )
        f64 = lambda a: jnp.asarray(a, dtype=float)  # noqa: E731 - with a dtype: a transfer, not an eager program
        return cls(f64(center), f64(half), f64(origin), f64(coef), err)

    def __call__(self, xy: Array) -> Array:
        xy = jnp.asarray(xy, dtype=jnp.float64)
        lead = (1,) * (xy.ndim - 1)
        u = (xy - self.center.reshape(*lead, 2)) / self.half.reshape(*lead, 2)
        return _terms(u) @ self.coefficients + self.origin.reshape(*lead, 2)


def _short(crs) -> str:
    from .geo import describe

    return describe(crs)


def _crs_text(crs) -> str:
    """A CRS as WKT text (static, hashable: part of the compiled function's key)."""
    from rasterio.crs import CRS

    return CRS.from_user_input(crs).to_wkt()


@filter_jit
def _footprint(px: Array, exterior: ExteriorOrientation, camera: FrameCamera, dem: DEM) -> tuple[Array, Array]:
    """``(n, 3)`` ground points of the ``(n, 2)`` pixels ``px`` on the DEM,
    and on the plane at the DEM's mean height: one compiled call (kept on
    disk by photax._aot) instead of a dozen small eager operations."""
    img = camera.pixel_to_image(px)
    return (
        image_to_ground(img, exterior, camera, dem=dem),
        image_to_ground(img, exterior, camera, height=jnp.nanmean(dem.heights)),
    )


_footprint_cached = disk_cached(_footprint, "ortho_footprint")


@dataclasses.dataclass(frozen=True)
class Validity:
    """Where a sensor's model holds.

    Attributes:
        height_range: ``(h_min, h_max)`` of the ground heights it serves (an RPC's offset +- scale, m), or
            None for any height (a rigorous model: a frame, a push-broom camera).
        ground_box: ``(xmin, ymin, xmax, ymax)`` in the sensor's ``crs`` outside which it gives NaN (an
            RPC's or a push-broom model's lon, lat box widened by :data:`RPC_MARGIN`), or None (a frame:
            everything in front of the camera).

    Examples:
        A frame holds everywhere in front of it; a push-broom model within a lon, lat box around
        its scene (here in the scene's UTM zone), at any height:

        >>> import numpy as np
        >>> import photax as ptx
        >>> frame = ptx.FrameSensor(ptx.ExteriorOrientation([0.0, 0.0, 100.0], [0.0, 0.0, 0.0]),
        ...                         ptx.FrameCamera.from_pixels(100.0, (100, 100)))
        >>> frame.validity
        Validity(height_range=None, ground_box=None)
        >>> v = ptx.GroundSensor(ptx.pushbroom_scene(image_size=(2000, 2000)).camera, ptx.utm_crs(10.0, 45.0)).validity
        >>> v.height_range, len(v.ground_box), bool(v.ground_box[0] < 578000 < v.ground_box[2])  # E of 10 E, 45 N
        (None, 4, True)
    """

    height_range: tuple[float, float] | None
    ground_box: tuple[float, float, float, float] | None


@runtime_checkable
class Sensor(Protocol):
    """One image's sensor: what every product asks of a frame, an RPC or a push-broom image.

    Ground is ``(X, Y, Z)`` in :attr:`crs` (a frame: its orientation's CRS; an RPC or a push-broom
    model: the map CRS it was built for, ``Z`` ellipsoidal); pixels are ``(column, row)``
    (``docs/conventions.md``).  Implemented by :class:`FrameSensor` and :class:`GroundSensor`;
    :func:`sensor_of` builds one from ``(exterior, camera, crs)``.

    Examples:
        A protocol, checked at run time: a frame sensor is one, a bare camera is not until
        :func:`sensor_of` gives it its orientation:

        >>> import photax as ptx
        >>> from photax.sensor import sensor_of
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (100, 100))
        >>> exterior = ptx.ExteriorOrientation([0.0, 0.0, 100.0], [0.0, 0.0, 0.0])
        >>> isinstance(camera, ptx.Sensor), isinstance(sensor_of(exterior, camera), ptx.Sensor)
        (False, True)
        >>> sensor_of(exterior, camera).kind
        'frame'
    """

    @property
    def kind(self) -> Literal["frame", "rpc", "pushbroom"]: ...

    @property
    def image_size(self) -> tuple[int, int] | None: ...

    @property
    def crs(self) -> str | None: ...

    @property
    def validity(self) -> Validity: ...

    def project(self, ground: Array) -> Array: ...  # (..., 3) -> (..., 2), NaN where not imaged

    def localize(self, pixel: Array, height) -> tuple[Array, Array]: ...  # (n, 2), h -> (n, 3), (n,) converged

    def footprint(self, pixel, dem: DEM) -> np.ndarray: ...  # (n, 2) pixels -> (n, 2) ground (X, Y) on the DEM

    def on_dem(self, pixel, dem: DEM) -> np.ndarray: ...  # (n, 2) pixels -> (n, 3) ground on the DEM, NaN off it


class FrameSensor(Module):
    """A frame camera: the collinearity equations (``docs/conventions.md``); NaN behind the camera and
    past the fold of its lens distortion.  ``crs``: the orientation's CRS, where known (the products
    then check the DEM's and the grid's against it).

    Examples:
        A nadir camera 100 m up (f = 100 px): the nadir images at the centre pixel, a point 10 m east
        and 20 m north 10 columns right and 20 rows up, a point above the camera nowhere; and back:

        >>> import numpy as np
        >>> import photax as ptx
        >>> sensor = ptx.FrameSensor(ptx.ExteriorOrientation([0.0, 0.0, 100.0], [0.0, 0.0, 0.0]),
        ...                          ptx.FrameCamera.from_pixels(100.0, (100, 100)), crs="EPSG:32633")
        >>> print(np.asarray(sensor.project(np.array([[0.0, 0.0, 0.0], [10.0, 20.0, 0.0], [0.0, 0.0, 200.0]]))))
        [[49.5 49.5]
         [59.5 29.5]
         [ nan  nan]]
        >>> ground, ok = sensor.localize(np.array([[59.5, 29.5]]), 0.0)
        >>> print(np.asarray(ground), np.asarray(ok))
        [[10. 20.  0.]] [ True]
    """

    exterior: ExteriorOrientation
    camera: FrameCamera
    crs: str | None = field(static=True, default=None)

    kind = "frame"

    @property
    def image_size(self):
        return self.camera.image_size

    @property
    def validity(self) -> Validity:
        return Validity(None, None)

    def project(self, ground: Array) -> Array:
        """``(..., 3)`` ground -> ``(..., 2)`` pixels, NaN behind the camera (the collinearity equations)."""
        return self(ground)

    def localize(self, pixel: Array, height) -> tuple[Array, Array]:
        """``(n, 2)`` pixels -> ``(n, 3)`` ground on the plane ``Z = height`` (:func:`photax.image_to_ground`,
        jittable) and ``(n,)`` converged: False where the ray misses the plane (NaN)."""
        img = self.camera.pixel_to_image(jnp.asarray(pixel, dtype=jnp.float64))
        ground = image_to_ground(img, self.exterior, self.camera, height=height)
        return ground, jnp.all(jnp.isfinite(ground), axis=-1)

    def __call__(self, ground: Array) -> Array:
        ground = jnp.asarray(ground, dtype=jnp.float64)
        flat = ground.reshape(-1, 3)
        q = self.exterior.points_in_camera(flat)
        xn = -q[:, :2] / q[:, 2:3]
        pix = self.camera.image_to_pixel(
            self.camera.principal_point[None] + self.camera.focal_length * distort(xn, self.camera.distortion)
        )
        # Past the fold of the lens distortion (its Jacobian determinant not positive) a strong barrel or
        # rational model bends rays from outside the field of view back into the image: another place's grey.
        j = distortion_jacobian(xn, self.camera.distortion)
        unfolded = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0] > 0
        ok = (q[:, 2] < 0) & unfolded
        return jnp.where(ok[:, None], pix, jnp.nan).reshape(*ground.shape[:-1], 2)

    def footprint(self, pixel, dem: DEM) -> np.ndarray:
        ground, flat = (
            np.asarray(g) for g in _footprint_cached(jnp.asarray(pixel, dtype=float), self.exterior, self.camera, dem)
        )
        return np.where(np.isfinite(ground), ground, flat)[:, :2]

    def on_dem(self, pixel, dem: DEM) -> np.ndarray:
        """``(n, 2)`` pixels -> ``(n, 3)`` ground points on the DEM, NaN where the ray misses it (the
        covered share of an image: :func:`photax.grid.dem_coverage`)."""
        return np.asarray(_footprint_cached(jnp.asarray(pixel, dtype=float), self.exterior, self.camera, dem)[0])


@runtime_checkable
class GroundCamera(Protocol):
    """What :class:`GroundSensor` asks of a camera whose ground is lon, lat (deg) and ellipsoidal height
    (m): :class:`photax.rpc.RPCCamera`, :class:`photax.PushbroomCamera`.

    Examples:
        A push-broom camera is one (its ground is lon, lat, h), a frame camera is not:

        >>> import photax as ptx
        >>> pushbroom = ptx.pushbroom_scene(image_size=(2000, 2000)).camera
        >>> isinstance(pushbroom, ptx.GroundCamera), isinstance(ptx.FrameCamera(0.1), ptx.GroundCamera)
        (True, False)
    """

    image_size: tuple[int, int] | None

    def __call__(self, ground: Array) -> Array: ...  # (..., 3) lon, lat, h -> (..., 2) column, row

    def ground_box(self) -> tuple[np.ndarray, np.ndarray]: ...  # (lon, lat) centre, half-sides (deg)

    def invert(self, pixel: Array, h: Array) -> tuple[Array, Array]: ...  # jittable, (n, 2), (n,)

    def to_ground(self, pixel: Array, height) -> Array: ...  # (..., 2) -> (..., 2) lon, lat, NaN if not found


class GroundSensor(Module):
    """A ground camera (:class:`GroundCamera`: an RPC, a push-broom model) seen from a map CRS (module
    docstring): ground ``(X, Y)`` of ``crs`` -> lon, lat (a :class:`LocalTransform` fitted over the
    camera's validity box), ``Z`` the ellipsoidal height; NaN outside the lon, lat validity box widened
    by :data:`RPC_MARGIN` (an RPC's heights beyond its range are extrapolated: :func:`check_rpc_dem` warns).

    Examples:
        A toy RPC (column ``500 + 500 L``, row ``500 - 500 P``) seen from UTM zone 32: the point at
        10.005 E, 45.005 N goes to pixel (750, 250) from its UTM coordinates, and back:

        >>> import numpy as np
        >>> from pyproj import Transformer
        >>> import photax as ptx
        >>> t = np.eye(20)
        >>> rpc = ptx.RPCCamera([-t[2], t[0], t[1], t[0]], [10.0, 45.0, 0.0, 500.0, 500.0],
        ...                     [0.01, 0.01, 500.0, 500.0, 500.0], image_size=(1000, 1000))
        >>> sensor = ptx.GroundSensor(rpc, "EPSG:32632")
        >>> e, n = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(10.005, 45.005)
        >>> print(np.round(np.asarray(sensor.project(np.array([[e, n, 100.0]]))), 6), sensor.kind)
        [[750. 250.]] rpc
        >>> ground, ok = sensor.localize(np.array([[750.0, 250.0]]), 100.0)
        >>> bool(np.allclose(ground, [[e, n, 100.0]], rtol=0, atol=1e-6)), sensor.validity.height_range
        (True, (-500.0, 500.0))
    """

    camera: GroundCamera
    to_lonlat: LocalTransform
    from_lonlat: LocalTransform  # lon, lat -> (X, Y) of crs over the same box: localize's last step, in JAX
    centre: Array  # (2,) lon, lat of the camera's validity box (GroundCamera.ground_box)
    half: Array  # (2,) its half-sides (deg)
    crs: str = field(static=True)

    def __init__(self, camera: GroundCamera, crs):
        if crs is None:
            raise CRSMismatchError(f"an {type(camera).__name__} needs the output grid's CRS (its ground is lon, lat)")
        self.camera = camera
        self.crs = _crs_text(crs)
        self.centre, self.half = (jnp.asarray(v, dtype=jnp.float64) for v in camera.ground_box())
        self.to_lonlat = LocalTransform.fit(self.crs, WGS84, self.box())
        (lon, lat), (dl, dp) = np.asarray(self.centre), 1.2 * np.asarray(self.half)
        self.from_lonlat = LocalTransform.fit(WGS84, self.crs, (lon - dl, lat - dp, lon + dl, lat + dp))

    def box(self, margin: float = 1.2):
        """The camera's lon, lat validity box (an RPC's offsets +- ``margin`` scales) as bounds of ``crs``."""
        from rasterio.warp import transform_bounds

        (lon, lat), (dl, dp) = np.asarray(self.centre), margin * np.asarray(self.half)
        return transform_bounds(WGS84, self.crs, lon - dl, lat - dp, lon + dl, lat + dp, densify_pts=21)

    @property
    def image_size(self):
        return self.camera.image_size

    @property
    def kind(self) -> str:
        """``"pushbroom"`` for a :class:`photax.PushbroomCamera`, else ``"rpc"``."""
        from .pushbroom import PushbroomCamera

        return "pushbroom" if isinstance(self.camera, PushbroomCamera) else "rpc"

    @property
    def validity(self) -> Validity:
        hr = getattr(self.camera, "height_range", None)
        box = tuple(float(v) for v in self.box(RPC_MARGIN))
        return Validity(None if hr is None else tuple(float(v) for v in hr), box)

    def project(self, ground: Array) -> Array:
        """``(..., 3)`` ground of :attr:`crs` (``Z`` ellipsoidal) -> ``(..., 2)`` pixels, NaN outside the box."""
        return self(ground)

    def localize(self, pixel: Array, height) -> tuple[Array, Array]:
        """``(n, 2)`` pixels -> ``(n, 3)`` ground of :attr:`crs` at the ellipsoidal ``height`` and ``(n,)``
        converged (the camera's ``invert`` and the lon, lat -> map :class:`LocalTransform` fitted over the
        validity box: jittable; NaN where it did not converge)."""
        pixel = jnp.asarray(pixel, dtype=jnp.float64)
        h = jnp.broadcast_to(jnp.asarray(height, dtype=jnp.float64), pixel.shape[:1])
        lonlat, ok = self.camera.invert(pixel, h)
        ground = jnp.concatenate([self.from_lonlat(lonlat), h[:, None]], axis=-1)
        return jnp.where(ok[:, None], ground, jnp.nan), ok

    def __call__(self, ground: Array) -> Array:
        ground = jnp.asarray(ground, dtype=jnp.float64)
        llh = jnp.concatenate([self.to_lonlat(ground[..., :2]), ground[..., 2:3]], axis=-1)
        lead = (1,) * (ground.ndim - 1)
        off = jnp.abs(llh[..., :2] - self.centre.reshape(*lead, 2)) / self.half.reshape(*lead, 2)
        ok = jnp.all(off <= RPC_MARGIN, axis=-1)  # heights beyond: extrapolated
        return jnp.where(ok[..., None], self.camera(llh), jnp.nan)

    def footprint(self, pixel, dem: DEM) -> np.ndarray:
        """Pixels -> map ``(X, Y)`` on the DEM: :meth:`RPCCamera.to_ground_dem`'s fixed-point iteration
        (with the camera's ``invert``) in one compiled loop (the DEM's CRS reached by a :class:`LocalTransform`), to 1 mm (the
        outline only bounds the grid); at the DEM's mean height where it fails (off the DEM, or no
        convergence: counted in a warning)."""
        pixel = np.asarray(pixel, dtype=float)
        llh, status = self._on_dem_status(pixel, dem)
        llh = np.array(llh)  # a writable copy (np.asarray of a JAX array is read-only): filled below
        failed = status >= 2
        if failed.any():
            warnings.warn(
                f"the RPC's inverse onto the DEM did not converge at {failed.sum()} of {len(pixel)} points of the "
                "image outline (taken at the DEM's mean height for the output grid)",
                stacklevel=4,
            )
        miss = status != 0
        if miss.any():
            h = np.asarray(dem.heights)
            mean = float(np.nanmean(h)) if np.isfinite(h).any() else _start_height(self.camera, dem)
            llh[miss, :2] = np.asarray(self.camera.to_ground(pixel[miss], mean))
        if not np.isfinite(llh[:, :2]).all():
            raise NotConvergedError("the RPC's inverse does not converge on the image outline: is the RPC valid?")
        return _pyproj(llh[:, :2], WGS84, self.crs)

    def _on_dem_status(self, pixel: np.ndarray, dem: DEM):
        """``(n, 3)`` lon, lat, h on the DEM and ``(n,)`` status of :func:`_on_dem`."""
        to_dem = None
        if dem.crs is not None and not _same(dem.crs, WGS84):
            (lon, lat), (dl, dp) = np.asarray(self.centre), 1.2 * np.asarray(self.half)
            to_dem = LocalTransform.fit(WGS84, _crs_text(dem.crs), (lon - dl, lat - dp, lon + dl, lat + dp))
        h0 = np.full(len(pixel), _start_height(self.camera, dem))
        return (np.asarray(v) for v in _on_dem_cached(self.camera, to_dem, dem, pixel, h0))

    def on_dem(self, pixel, dem: DEM) -> np.ndarray:
        """``(n, 2)`` pixels -> ``(n, 3)`` map ``(X, Y)`` and height on the DEM, NaN where the point is off
        it or the iteration did not converge (the covered share of an image: :func:`photax.grid.dem_coverage`)."""
        llh, status = self._on_dem_status(np.asarray(pixel, dtype=float), dem)
        on = status == 0
        out = np.full((len(llh), 3), np.nan)
        if on.any():
            out[on, :2] = _pyproj(llh[on, :2], WGS84, self.crs)
            out[on, 2] = llh[on, 2]
        return out


def _start_height(camera: GroundCamera, dem: DEM) -> float:
    """Where the height iteration starts: the middle of the camera's height range, else the DEM's mean (or 0)."""
    if getattr(camera, "height_range", None) is not None:
        return float(np.mean(camera.height_range))
    h = np.asarray(dem.heights)
    return float(np.nanmean(h)) if np.isfinite(h).any() else 0.0


def _same(a, b) -> bool:
    from .geo import same_crs

    return same_crs(a, b)


@filter_jit
def _on_dem(camera: GroundCamera, to_dem, dem: DEM, pixel: Array, h: Array, max_steps: int = 50, tol: float = 1e-3):
    """``(n, 3)`` lon, lat, h on the DEM of ``(n, 2)`` pixels and ``(n,)`` status (0 converged, 1 off
    the DEM, 2 inverse not converged, 3 height not settled): the iteration of
    :meth:`RPCCamera.to_ground_dem_status`, compiled."""

    def step(h):
        ll, ok = camera.invert(pixel, h)
        xy = ll if to_dem is None else to_dem(ll)
        new = dem.height(xy[:, 0], xy[:, 1])
        return ll, ok, new

    def body(state):
        h, done, failed, i = state
        _, ok, new = step(h)
        failed = failed | (~ok & jnp.isfinite(h))
        new = jnp.where(ok, new, jnp.nan)
        return new, jnp.abs(new - h) < tol, failed, i + 1

    def cond(state):
        h, done, _, i = state
        return (i < max_steps) & ~jnp.all(done | ~jnp.isfinite(h))

    n = pixel.shape[0]
    h, done, failed, _ = jax.lax.while_loop(cond, body, (h, jnp.zeros(n, bool), jnp.zeros(n, bool), 0))
    ll, ok, _ = step(h)
    failed = failed | (~ok & jnp.isfinite(h))
    status = jnp.where(failed, 2, jnp.where(~jnp.isfinite(h), 1, jnp.where(done & ok, 0, 3)))
    out = jnp.concatenate([ll, h[:, None]], axis=-1)
    return jnp.where((status == 0)[:, None], out, jnp.nan), status


_on_dem_cached = disk_cached(_on_dem, "rpc_outline_on_dem")


def sensor_of(exterior, camera, crs=None):
    """The sensor of an image: ``(exterior, FrameCamera)``, or ``(None, ground camera)`` (an
    ``RPCCamera``, a ``PushbroomCamera``: :class:`GroundCamera`) with ``crs`` the map CRS of the
    ground points (the output grid's)."""
    if isinstance(camera, (FrameSensor, GroundSensor)):
        return camera
    if not isinstance(camera, FrameCamera) and isinstance(camera, GroundCamera):
        if exterior is not None:
            raise ValueError(f"an {type(camera).__name__} carries its own orientation: pass exterior=None")
        return GroundSensor(camera, crs)
    if not isinstance(camera, FrameCamera):
        raise ValueError(
            f"camera must be a FrameCamera, an RPCCamera or a PushbroomCamera, got {type(camera).__name__}"
        )
    if exterior is None:
        raise ValueError("a frame camera needs its exterior orientation")
    return FrameSensor(exterior, camera)  # no CRS: the products' older path, as before (FrameSensor(..., crs) has one)


def as_exterior_camera(sensor) -> tuple[ExteriorOrientation | None, object]:
    """The ``(exterior, camera)`` pair of the products' older signature for a :class:`Sensor`: a frame's
    orientation and camera, or ``(None, sensor)`` for a ground sensor (which :func:`sensor_of` takes back
    as it is).  ``TypeError`` for anything else."""
    if isinstance(sensor, FrameSensor):
        return sensor.exterior, sensor.camera
    if isinstance(sensor, GroundSensor):
        return None, sensor
    raise TypeError(f"not a photax sensor: {type(sensor).__name__} (photax.sensor_of builds one)")


def sensor_arguments(sensor, slots, crs_of=None):
    """The products' ``(..., sensor, dem, grid, ...)`` form, read into their older ``(exterior, camera,
    dem, grid)`` slots: ``slots`` the values the caller's parameters after ``exterior`` received (the
    ``camera`` slot first); with a sensor they hold the DEM, the grid and the rest shifted by one, so
    the DEM and the :class:`photax.Grid` are picked by type and the others kept in order.  Returns
    ``(exterior, camera, dem, grid, rest)``, the sensor's CRS checked against the grid's (and a frame's
    against the DEM's): :class:`photax.errors.CRSMismatchError`."""
    dem = next((v for v in slots if isinstance(v, DEM)), None)
    # a photax.Grid (not imported: photax.grid imports this module): a transform and a shape, no heights
    grid = next((v for v in slots if hasattr(v, "transform") and hasattr(v, "shape") and v is not dem), None)
    rest = [v for v in slots if v is not None and v is not dem and v is not grid]
    if dem is None:
        raise TypeError("with a sensor, give the DEM next: (image, sensor, dem, grid=None, ...)")
    if grid is not None:
        check_sensor_crs(sensor, grid.crs)
    if isinstance(sensor, FrameSensor):
        check_sensor_crs(sensor, dem.crs, "the DEM")
    exterior, camera = as_exterior_camera(sensor)
    return exterior, camera, dem, grid, rest


def camera_kind(camera) -> str | None:
    """``"frame"``, ``"rpc"`` or ``"pushbroom"`` for a camera model (a :class:`photax.FrameCamera`, an
    :class:`photax.rpc.RPCCamera`, a :class:`photax.PushbroomCamera`) or a sensor; None for anything
    else.  The one place that tells the kinds apart by their classes."""
    from .pushbroom import PushbroomCamera
    from .rpc import RPCCamera

    if isinstance(camera, (FrameSensor, GroundSensor)):
        return camera.kind
    if isinstance(camera, FrameCamera):
        return "frame"
    if isinstance(camera, PushbroomCamera):
        return "pushbroom"
    if isinstance(camera, RPCCamera):
        return "rpc"
    return None


def is_sensor(obj) -> bool:
    """Whether ``obj`` is a photax sensor (:class:`FrameSensor`, :class:`GroundSensor`): the products'
    test for their ``(image, sensor, dem, ...)`` form."""
    return isinstance(obj, (FrameSensor, GroundSensor))


def check_sensor_crs(sensor, crs, what: str = "the output grid") -> None:
    """:class:`photax.errors.CRSMismatchError` where ``sensor`` has a CRS and ``crs`` (a grid's, a DEM's)
    is known and another one."""
    from .geo import describe, same_crs

    own = getattr(sensor, "crs", None)
    if own is not None and crs is not None and not same_crs(own, crs):
        raise CRSMismatchError(
            f"the sensor is in {describe(own)} but {what} in {describe(crs)}: build the sensor for that CRS "
            "(photax.sensor_of(exterior, camera, crs))"
        )


def check_rpc_dem(sensor, dem: DEM, grid) -> None:
    """For an :class:`GroundSensor`: the DEM's heights under the grid against the RPC's height range
    (offset +- scale). All outside: ValueError; some: a warning with how many (extrapolated). A DEM whose CRS has no ellipsoidal height: a warning."""
    if not isinstance(sensor, GroundSensor):
        return
    if sensor.camera.height_range is None:  # a rigorous model (push-broom): any height, ellipsoidal
        _check_ellipsoidal(dem)
        return
    lo, hi = sensor.camera.height_range
    z = _heights_under(dem, grid, sensor.crs)
    z = z[np.isfinite(z)]
    if z.size == 0:
        raise ValueError("the DEM has no height under the output grid")
    out = (z < lo) | (z > hi)
    if out.all():
        raise ValueError(
            f"the DEM's heights under the output grid ({z.min():.1f} .. {z.max():.1f} m) lie outside the "
            f"RPC's validity range {lo:.1f} .. {hi:.1f} m (height offset +- scale): wrong DEM or wrong units?"
        )
    if out.any():
        warnings.warn(
            f"{out.mean():.1%} of the DEM's heights under the output grid ({z.min():.1f} .. {z.max():.1f} m) "
            f"lie outside the RPC's validity range {lo:.1f} .. {hi:.1f} m: the RPC is extrapolated there",
            stacklevel=3,
        )
    _check_ellipsoidal(dem)


def _check_ellipsoidal(dem: DEM) -> None:
    if not _ellipsoidal(dem.crs):
        warnings.warn(
            "the camera (RPC, push-broom) needs ellipsoidal (WGS84) heights; the DEM's heights are used as they are "
            f"({_vertical_name(dem.crs)}): a geoid undulation N shifts the ortho by N tan(off-nadir angle)",
            stacklevel=4,
        )


def _heights_under(dem: DEM, grid, crs: str, n: int = 64) -> np.ndarray:
    rows = np.linspace(0, grid.shape[0] - 1, min(n, grid.shape[0]))
    cols = np.linspace(0, grid.shape[1] - 1, min(n, grid.shape[1]))
    a, b, xoff, d, e, yoff = tuple(grid.transform)[:6]
    c, r = np.meshgrid(cols + 0.5, rows + 0.5)
    xy = np.stack([xoff + a * c + b * r, yoff + d * c + e * r], -1).reshape(-1, 2)
    if dem.crs is not None:
        xy = _pyproj(xy, crs, _crs_text(dem.crs))
    return np.asarray(dem.height(jnp.asarray(xy[:, 0], dtype=float), jnp.asarray(xy[:, 1], dtype=float)))


def _vertical(crs):
    import pyproj

    if crs is None:
        return None
    c = pyproj.CRS.from_user_input(crs)
    if c.is_compound:
        return c.sub_crs_list[-1]
    return c if c.is_vertical else None


def _ellipsoidal(crs) -> bool:
    """Whether ``crs`` says its heights are ellipsoidal (a geographic 3-D CRS such as EPSG:4979)."""
    import pyproj

    if crs is None:
        return False
    c = pyproj.CRS.from_user_input(crs)
    return not c.is_compound and c.is_geographic and len(c.axis_info) == 3


def _vertical_name(crs) -> str:
    v = _vertical(crs)
    return f"{v.name}" if v is not None else "the DEM's CRS names no vertical datum"
