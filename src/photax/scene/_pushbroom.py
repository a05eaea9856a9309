"""A synthetic push-broom satellite scene with known truth (:func:`pushbroom_scene`).

A circular orbit (Kepler, ``GM = 3.986004418e14``; the earth's rotation left out: the truth is the
polynomial model it gives, not an ephemeris) over a scene centre, the sensor pointed off nadir across
the track (roll) and along it (pitch) with the pitch following the orbit's rotation, its attitude
disturbed by a small smooth drift; the position and the attitude are then the polynomials of a
:class:`photax.PushbroomCamera`.  The orbit is turned about the earth's centre until the middle of
the image sees the scene centre.  GCPs and check points: random pixels at random heights taken to
the ground by the true model, the pixels then noised.  ``start`` is the truth with the errors of a
typical ephemeris and attitude (known), for :func:`photax.resect_pushbroom` to remove.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from ..earth import geodetic_to_ecef
from ..pushbroom import PushbroomCamera

_GM = 3.986004418e14  # m^3 / s^2


@dataclasses.dataclass(frozen=True)
class PushbroomScene:
    """Output of :func:`pushbroom_scene` (lon, lat in degrees, heights ellipsoidal in metres).

    Attributes:
        camera: the true :class:`photax.PushbroomCamera`.
        start: the camera with the known ephemeris and attitude errors added (``position_error`` m,
            ``attitude_error`` rad, each ``(2, 3)``: bias and drift of the polynomial coefficients).
        gcp_ground, gcp_pixel: ``(n, 3)`` lon, lat, h and ``(n, 2)`` their measured column, row (noised).
        gcp_true_pixel: ``(n, 2)`` the pixels without noise.
        check_ground, check_pixel: check points, likewise (noised).
        height_range: ``(h_min, h_max)`` of the scene's terrain.
        noise_px: standard deviation of the pixel noise.
        duration: the scan's duration (s); line_period (s).

    Examples:
        The truth and what was measured: the true camera puts the GCPs at their noise-free pixels,
        the start camera (its ephemeris and attitude errors added) some pixels away:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.pushbroom_scene(image_size=(2000, 2000))
        >>> bool(np.abs(np.asarray(scene.camera(scene.gcp_ground)) - scene.gcp_true_pixel).max() < 1e-6)
        True
        >>> bool(np.abs(np.asarray(scene.start(scene.gcp_ground)) - scene.gcp_true_pixel).max() > 1)
        True
        >>> round(scene.duration / scene.line_period), scene.gcp_ground.shape, scene.check_ground.shape
        (1999, (20, 3), (10, 3))
    """

    camera: PushbroomCamera
    start: PushbroomCamera
    position_error: np.ndarray
    attitude_error: np.ndarray
    gcp_ground: np.ndarray
    gcp_pixel: np.ndarray
    gcp_true_pixel: np.ndarray
    check_ground: np.ndarray
    check_pixel: np.ndarray
    height_range: tuple[float, float]
    noise_px: float
    duration: float
    line_period: float


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` onto unit vector ``b`` (Rodrigues)."""
    v, c = np.cross(a, b), float(a @ b)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def pushbroom_scene(
    *,
    centre: tuple[float, float] = (10.0, 45.0),
    altitude: float = 620e3,
    heading: float = 192.0,
    roll: float = 0.0,
    pitch: float = 0.0,
    gsd: float = 2.0,
    image_size: tuple[int, int] = (3000, 3000),
    height_range: tuple[float, float] = (0.0, 1500.0),
    n_gcp: int = 20,
    n_check: int = 10,
    noise_px: float = 0.3,
    position_error: float = 10.0,
    attitude_error: float = 20e-6,
    seed: int = 0,
) -> PushbroomScene:
    """A push-broom scene over ``centre`` (lon, lat) with known truth.

    Args:
        altitude: orbit height above the ellipsoid at the scene (m; 500-700 km for the usual sensors).
        heading: the ground track's azimuth (deg from north; ~192 for a descending sun-synchronous pass).
        roll, pitch: off-nadir angles (deg) across and along the track (pitch > 0 looks backwards).
        gsd: ground sampling distance at nadir (m); sets the focal length and the line period.
        image_size: ``(columns, lines)``.
        height_range: heights of the GCPs and check points (m).
        n_gcp, n_check, noise_px: points and their pixel noise (standard deviation, px).
        position_error, attitude_error: the standard deviations (m, rad) of the bias of ``start``'s
            position and attitude; their drifts are drawn with a third of them.
        seed: the random generator's seed.

    Examples:
        A 2000 x 2000 px scene 20 deg off nadir: its 20 GCPs lie in the image, their measured pixels
        noised by 0.3 px:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.pushbroom_scene(roll=20.0, image_size=(2000, 2000))
        >>> bool(np.all((scene.gcp_true_pixel >= 0) & (scene.gcp_true_pixel <= 1999))), scene.noise_px
        (True, 0.3)
        >>> bool(0.2 < np.std(scene.gcp_pixel - scene.gcp_true_pixel) < 0.4)
        True
    """

    rng = np.random.default_rng(seed)
    lon0, lat0 = centre
    target = np.asarray(geodetic_to_ecef(jnp.array([lon0, lat0, 0.0])))
    up = target / np.linalg.norm(target)
    lo, la = math.radians(lon0), math.radians(lat0)
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    north = np.array([-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)])
    track = math.cos(math.radians(heading)) * north + math.sin(math.radians(heading)) * east
    radius = np.linalg.norm(target) + altitude
    omega = math.sqrt(_GM / radius**3)  # orbit's angular rate (rad/s)
    line_period = gsd / (omega * np.linalg.norm(target))  # ground speed at nadir
    w, lines = image_size
    duration = line_period * (lines - 1)
    # orbit frame at the middle line: s0 radial, v0 along the track; the reference frame x across
    # (to the right of -v0 x up), y = -v0 (rows run along the flight), z up
    s0 = up  # geocentric radial (the orbit's plane holds the earth's centre)
    v0 = track - (track @ s0) * s0  # the geodetic track direction, orthogonal to it
    v0 = v0 / np.linalg.norm(v0)
    reference = np.column_stack([np.cross(-v0, s0), -v0, s0])
    t = np.linspace(-duration / 2, duration / 2, 41)
    orbit = radius * (np.cos(omega * t)[:, None] * s0 + np.sin(omega * t)[:, None] * v0)
    tau = t / (duration / 2)
    vander = tau[:, None] ** np.arange(4)
    position = np.linalg.lstsq(vander, orbit, rcond=None)[0]  # cubic in tau: micrometres off the circle
    # attitude (phi-omega-kappa about the reference): roll = phi (about the along-track y axis), pitch =
    # omega (about the across-track x axis) following the orbit's turn, kappa = 0; plus a small drift
    half = duration / 2
    angles = np.zeros((3, 3))
    angles[0] = [math.radians(roll), math.radians(pitch), 0.0]
    angles[1] = [3e-6, omega * half, -2e-6]
    angles[2] = [1e-6, -1e-6, 0.5e-6]
    focal = altitude / (gsd * math.cos(math.radians(roll)) * math.cos(math.radians(pitch)))

    def camera_of(pos, ref):
        return PushbroomCamera(pos, angles, ref, focal, image_size=image_size)

    cam = camera_of(position, reference)
    middle = jnp.array([(w - 1) / 2.0, (lines - 1) / 2.0])
    for _ in range(4):  # turn the orbit about the earth's centre until the middle pixel sees the centre
        hit = np.asarray(geodetic_to_ecef(jnp.concatenate([cam.to_ground(middle, 0.0), jnp.zeros(1)])))
        q = _rotation_between(hit / np.linalg.norm(hit), up)
        position, reference = position @ q.T, q @ reference
        cam = camera_of(position, reference)

    def points(k):
        pix = rng.uniform([0.0, 0.0], [w - 1.0, lines - 1.0], (k, 2))
        h = rng.uniform(*height_range, k)
        lonlat = np.asarray(cam.to_ground(jnp.asarray(pix), jnp.asarray(h)))
        return np.column_stack([lonlat, h]), pix, pix + rng.normal(0.0, noise_px, (k, 2))

    gcp_ground, gcp_true, gcp_pixel = points(n_gcp)
    check_ground, _, check_pixel = points(n_check)
    pos_err = np.zeros((2, 3))
    pos_err[0] = rng.normal(0.0, position_error, 3)
    pos_err[1] = rng.normal(0.0, position_error / 3, 3)
    att_err = np.zeros((2, 3))
    att_err[0] = rng.normal(0.0, attitude_error, 3)
    att_err[1] = rng.normal(0.0, attitude_error / 3, 3)
    start = PushbroomCamera(
        np.asarray(cam.position).copy() + np.pad(pos_err, ((0, 2), (0, 0))),
        angles + np.pad(att_err, ((0, 1), (0, 0))),
        reference,
        focal,
        image_size=image_size,
    )
    return PushbroomScene(
        camera=cam,
        start=start,
        position_error=pos_err,
        attitude_error=att_err,
        gcp_ground=gcp_ground,
        gcp_pixel=gcp_pixel,
        gcp_true_pixel=gcp_true,
        check_ground=check_ground,
        check_pixel=check_pixel,
        height_range=(float(height_range[0]), float(height_range[1])),
        noise_px=float(noise_px),
        duration=float(duration),
        line_period=float(line_period),
    )
