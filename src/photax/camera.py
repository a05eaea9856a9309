"""Interior orientation: principal distance, principal point, lens distortion,
and the conversion between pixel and image-plane coordinates.

Frames (see ``docs/conventions.md``):

* **camera frame**: x right, y up, z backwards (the camera looks along -z);
  origin at the projection centre.
* **image plane**: x right, y up, origin at the image centre (fiducial
  centre), in the camera's length unit (mm, m or pixels: whatever the focal
  length is given in).  The principal point ``(x0, y0)`` is given in it.
* **pixels**: (column, row), origin at the *centre* of the top-left pixel,
  row down (the OpenCV / scikit-image / ``map_coordinates`` convention).  The
  image centre is at ``((width - 1) / 2, (height - 1) / 2)``.

Distortion is Brown–Conrady on *normalised* coordinates ``(x - x0)/f``, as in
OpenCV and in the BAL camera, so the coefficients do not depend on the unit::

    r^2 = xn^2 + yn^2
    xd  = xn (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 xn yn + p2 (r^2 + 2 xn^2)
    yd  = yn (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 yn^2) + 2 p2 xn yn

with ``y`` up.  OpenCV's ``y`` points down, so its ``p1`` is minus ours
(radial terms and ``p2`` are the same).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array


def _f64(x) -> Array:
    return jnp.asarray(x, dtype=float)


def _like(v: Array, x: Array) -> Array:
    """``v`` (shape ``(k,)``) with leading axes so it broadcasts against ``x``."""
    return jnp.reshape(v, (1,) * (x.ndim - 1) + v.shape)


def _concrete(x) -> bool:
    """True when ``x`` has a value now (not a tracer inside jit/vmap/grad)."""
    return not isinstance(x, jax.core.Tracer)


# The functions and methods that users and photax call eagerly (outside jit) on
# arrays of varying shapes are jitted: eagerly each of their 10-40 operations
# was compiled separately for every new shape (the test suite compiled ~1300
# such one-operation programs from camera.py, dem.py and collinearity.py).
# Inside a traced function the inner jit is inlined, so nothing changes there.
@jax.jit
def distort(xn: Array, distortion: Array) -> Array:
    """Brown–Conrady distortion of ``(..., 2)`` normalised coordinates (the
    formula in this module's docstring); ``distortion`` is ``(..., 5)``
    ``(k1, k2, k3, p1, p2)``, one set for all points or one per point."""
    k1, k2, k3, p1, p2 = (distortion[..., i] for i in range(5))
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return jnp.stack([xd, yd], axis=-1)


@jax.jit
def distortion_jacobian(xn: Array, distortion: Array) -> Array:
    """``(..., 2, 2)`` derivative of :func:`distort` at ``xn``: rows
    ``(xd, yd)``, columns ``(xn, yn)``.

    With ``rho = 1 + k1 r^2 + k2 r^4 + k3 r^6`` and
    ``rho' = d rho / d r^2 = k1 + 2 k2 r^2 + 3 k3 r^4``::

        dxd/dx = rho + 2 x^2 rho' + 2 p1 y + 6 p2 x
        dxd/dy = dyd/dx = 2 x y rho' + 2 p1 x + 2 p2 y
        dyd/dy = rho + 2 y^2 rho' + 6 p1 y + 2 p2 x
    """
    k1, k2, k3, p1, p2 = (distortion[..., i] for i in range(5))
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    slope = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    xy = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y
    xx = radial + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x
    yy = radial + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x
    return jnp.stack([jnp.stack([xx, xy], axis=-1), jnp.stack([xy, yy], axis=-1)], axis=-2)


@jax.jit
def intrinsics_jacobian(xn: Array, focal_length: Array, distortion: Array) -> Array:
    """``(..., 2, 8)`` derivative of the image-plane point ``x = x0 + f D(xn)``
    (:meth:`FrameCamera.project` for a fixed normalised point ``xn``) with
    respect to the interior orientation ``(f, x0, y0, k1, k2, k3, p1, p2)``
    (bundle adjustment's ``INTRINSICS``); ``focal_length`` ``(...)`` and
    ``distortion`` ``(..., 5)`` broadcast against the points::

        dx/df = D(xn),   dx/d(x0, y0) = I,
        dx/dk_j = f xn r^(2j), dy/dk_j = f yn r^(2j)      (j = 1, 2, 3)
        dx/dp1 = 2 f xn yn,        dy/dp1 = f (r^2 + 2 yn^2)
        dx/dp2 = f (r^2 + 2 xn^2), dy/dp2 = 2 f xn yn
    """
    f = focal_length
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    d = distort(xn, distortion)
    one, zero = jnp.ones_like(x), jnp.zeros_like(x)
    rows = (
        [d[..., 0], one, zero, f * x * r2, f * x * r4, f * x * r4 * r2, 2.0 * f * x * y, f * (r2 + 2.0 * x * x)],
        [d[..., 1], zero, one, f * y * r2, f * y * r4, f * y * r4 * r2, f * (r2 + 2.0 * y * y), 2.0 * f * x * y],
    )
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


class FrameCamera(eqx.Module):
    """A frame (pinhole) camera with optional Brown–Conrady distortion.

    Attributes:
        focal_length: principal distance ``f`` (scalar), image-plane unit.
        principal_point: ``(2,)`` principal point ``(x0, y0)`` on the image
            plane, same unit, relative to the image centre.
        distortion: ``(5,)`` ``(k1, k2, k3, p1, p2)`` on normalised
            coordinates (dimensionless).  Zeros for an ideal camera.
        pixel_size: ``(2,)`` image-plane units per pixel along columns and
            rows, or ``None`` if the camera is not tied to a pixel grid.
        image_size: ``(width, height)`` in pixels, or ``None``.
    """

    focal_length: Array
    principal_point: Array
    distortion: Array
    pixel_size: Array | None
    image_size: tuple[int, int] | None = eqx.field(static=True)

    def __init__(
        self,
        focal_length,
        principal_point=(0.0, 0.0),
        distortion=None,
        *,
        pixel_size=None,
        image_size: tuple[int, int] | None = None,
    ):
        self.focal_length = _f64(focal_length)
        self.principal_point = _f64(principal_point)
        self.distortion = _f64(np.zeros(5) if distortion is None else distortion)
        if pixel_size is not None:
            pixel_size = jnp.broadcast_to(_f64(pixel_size), (2,))
        self.pixel_size = pixel_size
        self.image_size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        if self.focal_length.shape != ():
            raise ValueError(f"focal_length must be a scalar, got shape {self.focal_length.shape}")
        if self.principal_point.shape != (2,):
            raise ValueError(f"principal_point must be (x0, y0), got shape {self.principal_point.shape}")
        if self.distortion.shape != (5,):
            raise ValueError(f"distortion must be (k1, k2, k3, p1, p2), got shape {self.distortion.shape}")
        if _concrete(self.focal_length) and not float(self.focal_length) > 0:
            raise ValueError(f"focal_length must be positive, got {float(self.focal_length)}")

    @classmethod
    def from_pixels(
        cls,
        focal_length_px: float,
        image_size: tuple[int, int],
        principal_point_px: tuple[float, float] | None = None,
        distortion=None,
    ) -> FrameCamera:
        """A camera whose image-plane unit is the pixel.

        Args:
            focal_length_px: principal distance in pixels.
            image_size: ``(width, height)`` in pixels.
            principal_point_px: ``(column, row)`` of the principal point;
                default the image centre ``((w - 1)/2, (h - 1)/2)``.
            distortion: ``(k1, k2, k3, p1, p2)`` with p1 in photax's y-up
                sense (minus OpenCV's p1).
        """
        w, h = image_size
        if principal_point_px is None:
            x0 = y0 = 0.0
        else:
            x0 = principal_point_px[0] - (w - 1) / 2.0
            y0 = -(principal_point_px[1] - (h - 1) / 2.0)
        return cls(focal_length_px, (x0, y0), distortion, pixel_size=1.0, image_size=(w, h))

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(np.asarray(self.distortion) != 0))

    # --- pixel <-> image plane -------------------------------------------------

    def _pixel_grid(self) -> tuple[Array, Array]:
        if self.pixel_size is None or self.image_size is None:
            raise ValueError(
                "this camera has no pixel grid: give pixel_size and image_size "
                "(or build it with FrameCamera.from_pixels)"
            )
        w, h = self.image_size
        centre = jnp.array([(w - 1) / 2.0, (h - 1) / 2.0])
        return centre, self.pixel_size

    @jax.jit
    def pixel_to_image(self, colrow: Array) -> Array:
        """``(..., 2)`` pixel (column, row) -> image-plane (x right, y up)."""
        centre, size = self._pixel_grid()
        colrow = jnp.asarray(colrow, dtype=float)
        d = (colrow - _like(centre, colrow)) * _like(size, colrow)
        return jnp.stack([d[..., 0], -d[..., 1]], axis=-1)

    @jax.jit
    def image_to_pixel(self, xy: Array) -> Array:
        """``(..., 2)`` image-plane (x right, y up) -> pixel (column, row)."""
        centre, size = self._pixel_grid()
        xy = jnp.asarray(xy, dtype=float)
        d = jnp.stack([xy[..., 0], -xy[..., 1]], axis=-1) / _like(size, xy)
        return d + _like(centre, xy)

    # --- distortion ------------------------------------------------------------

    def distort_normalised(self, xn: Array) -> Array:
        """Apply Brown–Conrady distortion to ``(..., 2)`` normalised coords
        (:func:`distort`)."""
        return distort(xn, self.distortion)

    def distortion_jacobian(self, xn: Array) -> Array:
        """``(..., 2, 2)`` derivative of :meth:`distort_normalised` at ``xn``
        (:func:`distortion_jacobian`)."""
        return distortion_jacobian(xn, self.distortion)

    def intrinsics_jacobian(self, xn: Array) -> Array:
        """``(..., 2, 8)`` derivative of the image-plane point with respect to
        ``(f, x0, y0, k1, k2, k3, p1, p2)`` (:func:`intrinsics_jacobian`)."""
        return intrinsics_jacobian(xn, self.focal_length, self.distortion)

    @functools.partial(jax.jit, static_argnames="iterations")
    def undistort_normalised(self, xd: Array, iterations: int = 20) -> Array:
        """Invert :meth:`distort_normalised` by fixed-point iteration.

        ``xn <- xd - (distort(xn) - xn)``; converges for the moderate
        distortion of metric and consumer cameras (as OpenCV's
        ``undistortPoints``).
        """

        def body(_, xn):
            return xd - (self.distort_normalised(xn) - xn)

        return jax.lax.fori_loop(0, iterations, body, xd)

    # --- camera frame <-> image plane ---------------------------------------

    @jax.jit
    def project(self, points_in_camera: Array) -> Array:
        """Camera-frame points ``(..., 3)`` -> image-plane ``(..., 2)``.

        ``x = x0 - f Xc/Zc`` (and likewise y), then distortion.  Points must
        lie in front of the camera (``Zc < 0``); behind it the formula still
        gives numbers, so callers check the depth (see
        :func:`photax.collinearity.depth`).
        """
        p = jnp.asarray(points_in_camera)
        xn = -p[..., :2] / p[..., 2:3]
        xd = self.distort_normalised(xn)
        return _like(self.principal_point, xd) + self.focal_length * xd

    @jax.jit
    def normalised(self, xy: Array) -> Array:
        """Image-plane ``(..., 2)`` -> undistorted normalised coordinates."""
        xy = jnp.asarray(xy, dtype=float)
        xd = (xy - _like(self.principal_point, xy)) / self.focal_length
        return self.undistort_normalised(xd)

    @jax.jit
    def ray(self, xy: Array) -> Array:
        """Image-plane ``(..., 2)`` -> camera-frame ray directions ``(..., 3)``.

        The direction ``(xn, yn, -1)`` of the undistorted normalised point,
        not unit length.
        """
        xn = self.normalised(xy)
        return jnp.concatenate([xn, -jnp.ones_like(xn[..., :1])], axis=-1)


# --- OpenCV's camera frame ---------------------------------------------------

#: ``(3, 3)`` rotation from the photax camera frame (x right, y up, z
#: backwards) to OpenCV's and COLMAP's (x right, y **down**, z **forward**):
#: a half turn about x, ``diag(1, -1, -1)``; it is its own inverse, so it also
#: maps OpenCV's frame to photax's.  Read-only.
OPENCV_FROM_PHOTAX = np.diag([1.0, -1.0, -1.0])
OPENCV_FROM_PHOTAX.setflags(write=False)


def opencv_extrinsics(r_world_from_camera, position) -> tuple[np.ndarray, np.ndarray]:
    """A photax orientation as OpenCV's extrinsics ``(R, t)``.

    ``x_cv = R X + t`` maps ground points into OpenCV's camera frame::

        R = F @ r_world_from_camera^T,   t = -R C,   F = OPENCV_FROM_PHOTAX

    (``cv2.Rodrigues(R)`` gives the ``rvec`` of ``cv2.projectPoints`` /
    ``cv2.solvePnP``; ``docs/conventions.md``).

    Args:
        r_world_from_camera: ``(..., 3, 3)`` rotation (``ExteriorOrientation.rotation``).
        position: ``(..., 3)`` projection centre ``C``.

    Returns:
        ``(R, t)``: ``(..., 3, 3)`` camera_from_world in OpenCV's frame and ``(..., 3)``.
    """
    r = OPENCV_FROM_PHOTAX @ np.swapaxes(np.asarray(r_world_from_camera, dtype=float), -1, -2)
    return r, -np.einsum("...ij,...j->...i", r, np.asarray(position, dtype=float))


def from_opencv_extrinsics(r_cv_from_world, t) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's extrinsics ``(R, t)`` as ``(r_world_from_camera, position)``.

    The inverse of :func:`opencv_extrinsics`: ``r_world_from_camera = R^T F``
    and ``C = -R^T t``.  Pass ``R = cv2.Rodrigues(rvec)[0]``.
    """
    r = np.asarray(r_cv_from_world, dtype=float)
    rt = np.swapaxes(r, -1, -2)
    return rt @ OPENCV_FROM_PHOTAX, -np.einsum(
        "...ij,...j->...i", rt, np.reshape(np.asarray(t, dtype=float), r.shape[:-1])
    )
