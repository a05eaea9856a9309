"""Epipolar (normalised) image pairs: both images resampled so that corresponding points share a row.

Both images are re-projected onto one common image plane parallel to the
baseline (seed 004; Kraus 2007 sec. 6.7; Fusiello, Trucco & Verri 2000), by
indirect mapping with photax's resampling kernels (:func:`photax.resample`).

The epipolar frame ``R_e`` (world_from_epipolar, columns ``x_e, y_e, z_e``):

* ``x_e = s b / |b|`` with ``b = C_right - C_left``, and ``s = +-1`` chosen so
  that ``x_e`` points along the images' own x axes as far as it can
  (``s x_e . (x_left + x_right) >= 0``).  Without that choice a baseline
  against the images' x (the right image taken "before" the left) turns
  both images upside down (OpenCV issue #10791).
* ``z_e`` (backwards, as every photax camera) is minus the mean viewing
  direction of the two images made perpendicular to ``x_e``; ``y_e = z_e x x_e``.

Both epipolar images are pinhole images with that rotation, the original
principal distance ``f`` in pixels and no distortion; in image-plane pixels
``(x, y)`` (y up) a ground point ``P`` with ``q = R_e^T (P - C_left)`` is seen at::

    left:  x_l = -f q_x / q_z,            y = -f q_y / q_z
    right: x_r = -f (q_x - B) / q_z,      the same y        (B = s |b|)

so the rows are epipolar lines, and the x-parallax ``p = x_l - x_r = -f B / q_z``
gives the point (:meth:`EpipolarPair.ground`).  Epipolar pixels are
``col = x + c_side``, ``row = r0 - y``: one row origin for both sides, a
column origin per side (each image keeps only its own extent).
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..resampling import Resampling, resample

_MAX_AREA = 4.0  # an epipolar image larger than this many times the original: the geometry does not allow it
_MIN_ANGLE = 25.0  # degrees between the baseline and the viewing direction, at least


@partial(jax.jit, static_argnames="forward")
def _map(xy, r_side, r_epi, f_e, offset, camera, *, forward):
    """Original pixels -> epipolar pixels (``forward``) or back; NaN where a ray points backwards."""
    if forward:
        d = camera.ray(camera.pixel_to_image(xy)) @ r_side.T  # world directions
        q = d @ r_epi  # epipolar frame
        ok = q[:, 2] < 0
        qz = jnp.where(ok, q[:, 2], -1.0)
        x, y = -f_e * q[:, 0] / qz, -f_e * q[:, 1] / qz
        out = jnp.stack([x + offset[0], offset[1] - y], axis=-1)
    else:
        x, y = xy[:, 0] - offset[0], offset[1] - xy[:, 1]
        q = jnp.stack([x / f_e, y / f_e, -jnp.ones_like(x)], axis=-1) @ r_epi.T  # world
        d = q @ r_side  # original camera frame
        ok = d[:, 2] < 0
        d = jnp.where(ok[:, None], d, jnp.array([0.0, 0.0, -1.0]))
        out = camera.image_to_pixel(camera.project(d))
    return jnp.where(ok[:, None], out, jnp.nan)


def _run(xy, rotation, r_epi, f_e, offset, camera, forward: bool) -> np.ndarray:
    """:func:`_map` on ``(n, 2)`` points padded to a power of two (a few compilations for all sizes)."""
    n = len(xy)
    m = max(256, 1 << max(n - 1, 1).bit_length())
    pad = np.zeros((m, 2))
    pad[:n] = xy
    out = _map(
        jnp.asarray(pad),
        jnp.asarray(np.asarray(rotation, dtype=float)),
        jnp.asarray(r_epi),
        float(f_e),
        jnp.asarray(np.asarray(offset, dtype=float)),
        camera,
        forward=forward,
    )
    return np.asarray(out)[:n]


@dataclasses.dataclass(frozen=True)
class EpipolarPair:
    """Two images resampled to a common plane parallel to their baseline.

    Attributes:
        left, right: the epipolar images ``(..., h, w_side)`` (NaN, or 0 for
            integer images, outside the original image).
        rotation: ``(3, 3)`` world_from_epipolar ``R_e`` (module docstring).
        focal_px: principal distance of both epipolar images, px.
        baseline: ``B = b . x_e`` (ground units; negative when the right
            image lies against the epipolar x axis).
        offsets: ``{"left": (c, r0), "right": (c, r0)}``: epipolar pixel of
            each side's image-plane origin (``col = x + c``, ``row = r0 - y``).
        camera, exterior_left, exterior_right: the original orientation.

    Examples:
        Two nadir images 20 m apart, 100 m up (f = 100 px): a ground point's parallax in the
        epipolar images is ``f B / depth``, and :meth:`ground` intersects it back:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (80, 60))
        >>> left, right = (ptx.ExteriorOrientation([x, 0.0, 100.0], [0.0, 0.0, 0.0]) for x in (0.0, 20.0))
        >>> pair = ptx.epipolar_pair(np.zeros((60, 80)), np.zeros((60, 80)), camera, left, right)
        >>> point = np.array([[10.0, 5.0, 3.0]])
        >>> xy = [pair.to_epipolar(s, camera.image_to_pixel(ptx.project(point, e, camera)))
        ...       for s, e in (("left", left), ("right", right))]
        >>> print(np.round(xy[0][0] - xy[1][0], 6) + 0.0)  # 100 px * 20 m / 97 m; same row
        [20.618557  0.      ]
        >>> print(np.round(pair.ground(*xy), 6) + 0.0)
        [[10.  5.  3.]]
    """

    left: np.ndarray
    right: np.ndarray
    rotation: np.ndarray
    focal_px: float
    baseline: float
    offsets: dict
    camera: FrameCamera
    exterior_left: ExteriorOrientation
    exterior_right: ExteriorOrientation

    def _side(self, side: str):
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        ext = self.exterior_left if side == "left" else self.exterior_right
        return np.asarray(ext.rotation), self.offsets[side]

    def _apply(self, side, xy, forward):
        xy = np.asarray(xy, dtype=float)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"xy must have shape (n, 2) (column, row), got {xy.shape}")
        r, off = self._side(side)
        return _run(xy, r, self.rotation, self.focal_px, off, self.camera, forward)

    def to_epipolar(self, side: str, xy) -> np.ndarray:
        """``(n, 2)`` original pixels (column, row) of ``side`` -> its epipolar image's pixels."""
        return self._apply(side, xy, True)

    def from_epipolar(self, side: str, xy) -> np.ndarray:
        """``(n, 2)`` epipolar pixels of ``side`` -> the original image's pixels."""
        return self._apply(side, xy, False)

    def ground(self, left_xy, right_xy) -> np.ndarray:
        """``(n, 3)`` ground points from corresponding epipolar pixels (x-parallax).

        ``q_z = -f B / (x_l - x_r)``, ``q_x = -x_l q_z / f``, ``q_y = -y q_z / f``
        (``y`` the mean of both rows), ``P = C_left + R_e q``.  The depth's
        standard deviation is ``q_z^2 / (f |B|)`` times that of the parallax.
        """
        lxy, rxy = np.asarray(left_xy, dtype=float), np.asarray(right_xy, dtype=float)
        if lxy.shape != rxy.shape or lxy.ndim != 2 or lxy.shape[1] != 2:
            raise ValueError(f"left_xy and right_xy must both have shape (n, 2), got {lxy.shape}, {rxy.shape}")
        (cl, r0), (cr, _) = self.offsets["left"], self.offsets["right"]
        xl, xr = lxy[:, 0] - cl, rxy[:, 0] - cr
        y = r0 - 0.5 * (lxy[:, 1] + rxy[:, 1])
        f = self.focal_px
        with np.errstate(divide="ignore", invalid="ignore"):
            qz = -f * self.baseline / (xl - xr)
        q = np.column_stack([-xl * qz / f, -y * qz / f, qz])
        q[~(qz < 0)] = np.nan  # zero or wrong-signed parallax: not in front of the cameras
        return np.asarray(self.exterior_left.position) + q @ self.rotation.T


def epipolar_frame(exterior_left: ExteriorOrientation, exterior_right: ExteriorOrientation) -> tuple[np.ndarray, float]:
    """``(R_e, B)``: the epipolar rotation (world_from_epipolar) and the signed baseline (module docstring).

    Raises:
        ValueError: the projection centres coincide, or the baseline is
            within 25 degrees of the viewing direction (the epipoles lie in
            or near the images: no resampling to rows is sensible).
    """
    cl, cr = np.asarray(exterior_left.position, float), np.asarray(exterior_right.position, float)
    rl, rr = np.asarray(exterior_left.rotation, float), np.asarray(exterior_right.rotation, float)
    b = cr - cl
    length = float(np.linalg.norm(b))
    if not length > 0:
        raise ValueError("exterior_left and exterior_right have the same projection centre: no baseline")
    x = b / length
    view = -(rl[:, 2] + rr[:, 2])
    view /= np.linalg.norm(view)
    angle = np.degrees(np.arccos(min(1.0, abs(float(x @ view)))))
    if angle < _MIN_ANGLE:
        raise ValueError(
            f"the baseline is {angle:.1f} degrees from the viewing direction (less than {_MIN_ANGLE}): "
            "the epipoles lie in or near the images, epipolar images would be absurdly scaled"
        )
    s = 1.0 if float(x @ (rl[:, 0] + rr[:, 0])) >= 0 else -1.0
    x = s * x
    z = -(view - (view @ x) * x)
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    return np.column_stack([x, y, z]), s * length


def epipolar_pair(
    image_left,
    image_right,
    camera,
    exterior_left: ExteriorOrientation | None = None,
    exterior_right: ExteriorOrientation | None = None,
    *,
    resampling: Resampling | str = "cubic",
    nodata=None,
    camera_right=None,
    bounds=None,
    heights=None,
    max_area: float = _MAX_AREA,
):
    """Resample two images of one camera into an epipolar (normalised) pair.

    Two satellite images (``camera`` and ``camera_right`` ground cameras: :class:`photax.RPCCamera`,
    :class:`photax.PushbroomCamera`; no exterior orientations) are rectified over a tile of the left
    image (``bounds`` ``(col0, row0, col1, row1)``, default all of it) by the local affine
    approximation of s2p, for terrain within ``heights`` ``(h_min, h_max)`` (default the RPCs'
    validity range): :func:`photax.matching.epipolar_affine.affine_epipolar_pair`, which returns an
    :class:`~photax.matching.epipolar_affine.AffineEpipolarPair` reporting the residual vertical
    disparity.  ``camera`` may also be the pair ``(camera_left, camera_right)``.

    Args:
        image_left, image_right: ``(..., H, W)`` images, ``(W, H) ==
            camera.image_size``.
        camera: the interior orientation (with a pixel grid; distortion is
            removed by the resampling).
        exterior_left, exterior_right: the two images' exterior orientations.  Or two
            :class:`photax.Sensor` objects in the ``camera, exterior_left`` places
            (``epipolar_pair(left, right, sensor_left, sensor_right)``): two frames of one camera, or
            two ground sensors (RPC, push-broom).
        resampling: kernel of :func:`photax.resample` (default cubic convolution).
        nodata: value outside the original images (default NaN / 0 for integers).
        max_area: the largest epipolar image allowed, in original image areas (default 4:
            convergent oblique views, whose epipolar images grow large, need more).

    Returns:
        :class:`EpipolarPair`.

    Raises:
        ValueError: images that do not match the camera, no baseline, a
            baseline along the viewing direction, or epipolar images more
            than 4 times the originals' area.

    Examples:
        Two tilted and turned views of a point: in the epipolar pair its rows agree, and the
        epipolar pixels map back to the original ones:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (80, 60))
        >>> left = ptx.ExteriorOrientation([0.0, 0.0, 100.0], np.radians([1.0, -2.0, 0.0]))
        >>> right = ptx.ExteriorOrientation([20.0, 0.0, 100.0], np.radians([1.0, -2.0, 3.0]))
        >>> pair = ptx.epipolar_pair(np.zeros((60, 80)), np.zeros((60, 80)), camera, left, right)
        >>> pair.left.shape, pair.baseline, pair.focal_px
        ((65, 81), 20.0, 100.0)
        >>> point = np.array([[10.0, 5.0, 3.0]])
        >>> views = {"left": left, "right": right}
        >>> px = {s: np.asarray(camera.image_to_pixel(ptx.project(point, e, camera))) for s, e in views.items()}

        >>> epi = {s: pair.to_epipolar(s, px[s]) for s in px}
        >>> bool(abs(epi["left"][0, 1] - epi["right"][0, 1]) < 1e-9)
        True
        >>> bool(np.allclose(pair.from_epipolar("right", epi["right"]), px["right"], atol=1e-9))
        True
    """
    camera, exterior_left, exterior_right, camera_right = sensor_arguments(
        camera, exterior_left, exterior_right, camera_right
    )
    if isinstance(camera, tuple) and len(camera) == 2 and camera_right is None:
        camera, camera_right = camera
    if not isinstance(camera, FrameCamera) or camera_right is not None:
        return _ground_pair(
            image_left, image_right, camera, camera_right, exterior_left, exterior_right,
            resampling=resampling, nodata=nodata, bounds=bounds, heights=heights, max_area=max_area,
        )  # fmt: skip
    if not max_area > 0:
        raise ValueError(f"max_area must be > 0, got {max_area}")
    if bounds is not None or heights is not None:
        raise ValueError("bounds= and heights= are for two ground cameras (RPC, push-broom), not a frame pair")
    if exterior_left is None or exterior_right is None:
        raise ValueError("a frame camera needs exterior_left and exterior_right")
    method = Resampling.check(resampling)
    if camera.image_size is None or camera.pixel_size is None:
        raise ValueError("camera must have a pixel grid (image_size and pixel_size)")
    w, h = camera.image_size
    for name, img in (("image_left", image_left), ("image_right", image_right)):
        if np.shape(img)[-2:] != (h, w):
            raise ValueError(f"{name} has shape {np.shape(img)}, the camera's images are (..., {h}, {w})")
    r_e, base = epipolar_frame(exterior_left, exterior_right)
    f_e = float(np.asarray(camera.focal_length) / np.mean(np.asarray(camera.pixel_size)))
    # the outline of each original image, in epipolar image-plane pixels (origin at the principal point)
    t = np.linspace(0.0, 1.0, 33)
    edge = np.concatenate(
        [
            np.column_stack([t * (w - 1), 0 * t]),
            np.column_stack([t * (w - 1), 0 * t + h - 1]),
            np.column_stack([0 * t, t * (h - 1)]),
            np.column_stack([0 * t + w - 1, t * (h - 1)]),
        ]
    )
    extent = {}
    for side, ext in (("left", exterior_left), ("right", exterior_right)):
        xy = _run(edge, ext.rotation, r_e, f_e, (0.0, 0.0), camera, True)
        if not np.all(np.isfinite(xy)):
            raise ValueError(f"the {side} image reaches behind the epipolar plane: the views are too oblique")
        extent[side] = (xy[:, 0].min(), xy[:, 0].max(), -xy[:, 1].max(), -xy[:, 1].min())  # x range, y range
    y_lo = min(e[2] for e in extent.values())
    y_hi = max(e[3] for e in extent.values())
    rows = int(np.ceil(y_hi - y_lo)) + 1
    offsets, images = {}, {}
    for side, img in (("left", image_left), ("right", image_right)):
        x_lo, x_hi = extent[side][:2]
        cols = int(np.ceil(x_hi - x_lo)) + 1
        if cols * rows > max_area * w * h:
            raise ValueError(
                f"the {side} epipolar image would be {cols} x {rows} px for a {w} x {h} image: "
                "the views are too oblique or convergent for epipolar resampling"
            )
        offsets[side] = (float(-np.floor(x_lo)), float(np.ceil(y_hi)))
        cc, rr = np.meshgrid(np.arange(cols, dtype=float), np.arange(rows, dtype=float))
        ext = exterior_left if side == "left" else exterior_right
        n = rows * cols
        src = np.full((max(256, 1 << (n - 1).bit_length()), 2), np.nan)  # a power of two: few compilations
        src[:n] = _run(np.column_stack([cc.ravel(), rr.ravel()]), ext.rotation, r_e, f_e, offsets[side], camera, False)
        out = np.asarray(resample(img, src[:, 0], src[:, 1], method, nodata=nodata))
        images[side] = out[..., :n].reshape(out.shape[:-1] + (rows, cols))
    return EpipolarPair(
        left=images["left"],
        right=images["right"],
        rotation=r_e,
        focal_px=f_e,
        baseline=base,
        offsets=offsets,
        camera=camera,
        exterior_left=exterior_left,
        exterior_right=exterior_right,
    )


def sensor_arguments(camera, exterior_left=None, exterior_right=None, camera_right=None):
    """``(camera, exterior_left, exterior_right, camera_right)`` of a pair given as two
    :class:`photax.Sensor` objects in the ``camera, exterior_left`` places (``epipolar_pair(a, b,
    sensor_a, sensor_b)``); any other arguments are returned as they came.

    Two frame sensors must share one camera (the frame pair is two images of one camera); a frame
    and a ground sensor (RPC, push-broom) are no pair.

    Raises:
        ValueError: a sensor pair with more arguments, a frame and a ground sensor, two frames of
            different cameras.
    """
    from ..sensor import FrameSensor, GroundSensor

    sensors = (FrameSensor, GroundSensor)
    if not (isinstance(camera, sensors) or isinstance(exterior_left, sensors)):
        return camera, exterior_left, exterior_right, camera_right
    left, right = camera, exterior_left
    if not (isinstance(left, sensors) and isinstance(right, sensors)):
        raise ValueError(
            f"give two sensors (photax.Sensor: FrameSensor, GroundSensor), got {type(left).__name__} "
            f"and {type(right).__name__}"
        )
    if exterior_right is not None or camera_right is not None:
        raise ValueError("two sensors carry their cameras and orientations: pass no exterior or camera_right")
    if type(left) is not type(right):
        raise ValueError(
            f"a {left.kind} sensor and a {right.kind} sensor are no stereo pair (two frames or two ground)"
        )
    if isinstance(left, GroundSensor):
        return left.camera, None, None, right.camera
    import equinox as eqx

    if not eqx.tree_equal(left.camera, right.camera):
        raise ValueError("a frame pair is two images of one camera: the two frame sensors have different cameras")
    return left.camera, left.exterior, right.exterior, None


def _ground_pair(image_left, image_right, camera, camera_right, exterior_left, exterior_right, **options):
    """:func:`epipolar_pair` of two ground cameras, their arguments checked."""
    from ..sensor import GroundCamera
    from .epipolar_affine import affine_epipolar_pair

    for name, cam in (("camera", camera), ("camera_right", camera_right)):
        if cam is None:
            raise ValueError(
                f"an {type(camera).__name__} pair needs camera_right= (each satellite image has its own camera)"
            )
        if isinstance(cam, FrameCamera) or not isinstance(cam, GroundCamera):
            raise ValueError(
                f"{name} must be a FrameCamera (with exteriors), or both RPCCamera / PushbroomCamera, "
                f"got {type(cam).__name__}"
            )
    if exterior_left is not None or exterior_right is not None:
        raise ValueError("RPC and push-broom cameras carry their own orientation: pass no exterior orientations")
    options.pop("max_area", None)
    return affine_epipolar_pair(image_left, image_right, camera, camera_right, **options)
