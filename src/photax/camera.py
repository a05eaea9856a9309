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

Distortion ``D`` maps *normalised* coordinates ``xn = (x - x0)/f`` (as in
OpenCV and in the BAL camera, so the coefficients do not depend on the unit)
to distorted ones, ``x = x0 + f D(xn)``.  Three models, named by
:data:`DISTORTION_MODELS` and told apart by the length of the coefficient
vector (5, 12, 4), so that every function below takes them alike:

* ``"brown"`` (Brown–Conrady, OpenCV's 5 terms), ``(k1, k2, k3, p1, p2)``::

    r^2 = xn^2 + yn^2
    xd  = xn (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 xn yn + p2 (r^2 + 2 xn^2)
    yd  = yn (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 yn^2) + 2 p2 xn yn

* ``"opencv"`` (OpenCV's full model without the tilt), ``(k1, k2, k3, p1,
  p2, k4, k5, k6, s1, s2, s3, s4)``: the radial factor becomes the rational
  ``(1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)`` and the
  thin prism adds ``s1 r^2 + s2 r^4`` to ``xd``, ``s3 r^2 + s4 r^4`` to ``yd``;
  with ``k4 ... s4`` zero it is ``"brown"``.
* ``"fisheye"`` (Kannala–Brandt as OpenCV's ``cv2.fisheye`` and OpenSfM's
  ``fisheye_opencv``; OpenSfM's ``fisheye`` is ``k3 = k4 = 0``),
  ``(k1, k2, k3, k4)``: with ``r = |xn|`` and ``t = atan(r)`` the angle off
  the axis, ``xd = xn t (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8) / r``.

With ``y`` up.  OpenCV's ``y`` points down, so its ``p1``, ``s3`` and ``s4``
are minus ours (the others are the same).
"""

from __future__ import annotations

import functools
import types

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._pytree import Module, field


def _f64(x) -> Array:
    # numpy first: jnp.asarray of a Python number or list is an eager program of its own (lowered and
    # looked up in the compile cache in every process); a float64 numpy array is a plain transfer.
    return jnp.asarray(x if isinstance(x, jax.Array) else np.asarray(x, dtype=float), dtype=float)


def _like(v: Array, x: Array) -> Array:
    """``v`` (shape ``(k,)``) with leading axes so it broadcasts against ``x``."""
    return jnp.reshape(v, (1,) * (x.ndim - 1) + v.shape)


def _concrete(x) -> bool:
    """True when ``x`` has a value now (not a tracer inside jit/vmap/grad)."""
    return not isinstance(x, jax.core.Tracer)


#: Distortion models: name -> the names of its coefficients, in the order of
#: :attr:`FrameCamera.distortion` (module docstring).  Read-only.
DISTORTION_MODELS = types.MappingProxyType(
    {
        "brown": ("k1", "k2", "k3", "p1", "p2"),
        "opencv": ("k1", "k2", "k3", "p1", "p2", "k4", "k5", "k6", "s1", "s2", "s3", "s4"),
        "fisheye": ("k1", "k2", "k3", "k4"),
    }
)
_MODEL_OF_SIZE = {len(v): k for k, v in DISTORTION_MODELS.items()}
#: Below this radius the fisheye's ``t/r`` and its slope are their Taylor series
#: (the closed forms cancel digits); the series' error there is below 1e-12.
_FISHEYE_SMALL = 1e-3


def distortion_model(distortion) -> str:
    """The model (a key of :data:`DISTORTION_MODELS`) of a coefficient vector
    ``(..., n)``, from its length ``n``."""
    n = jnp.shape(distortion)[-1]
    if n not in _MODEL_OF_SIZE:
        raise ValueError(f"no distortion model has {n} coefficients (brown 5, opencv 12, fisheye 4)")
    return _MODEL_OF_SIZE[n]


def _coefficients(distortion: Array, n: int) -> list[Array]:
    return [distortion[..., i] for i in range(n)]


# --- brown and opencv: a rational radial factor, decentring, thin prism ---------


def _rational(x: Array, y: Array, distortion: Array):
    """``r^2``, the radial factor ``rho = N/M`` of ``r^2``, its slope ``d rho / d
    r^2``, the denominator ``M``, ``(p1, p2)`` and the thin prism ``(s1, s2, s3,
    s4)``; for ``"brown"`` ``M = 1`` and no prism (None): its terms are not
    computed at all (bundle adjustment's hot path)."""
    n = distortion.shape[-1]
    k1, k2, k3, p1, p2, *rest = _coefficients(distortion, n)
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    num_slope = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    if n == 5:
        return r2, num, num_slope, 1.0, (p1, p2), None
    k4, k5, k6, *prism = rest
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    den_slope = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    return r2, num / den, (num_slope * den - num * den_slope) / (den * den), den, (p1, p2), prism


def _distort_rational(x, y, distortion):
    r2, rho, _, _, (p1, p2), prism = _rational(x, y, distortion)
    xd = x * rho + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * rho + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    if prism is not None:
        s1, s2, s3, s4 = prism
        xd, yd = xd + r2 * (s1 + s2 * r2), yd + r2 * (s3 + s4 * r2)
    return xd, yd


def _jacobian_rational(x, y, distortion):
    """``rho' = d rho / d r^2``; the prism's ``d/dx (s1 r^2 + s2 r^4) = 2 x (s1 + 2 s2 r^2)``::

    dxd/dx = rho + 2 x^2 rho' + 2 p1 y + 6 p2 x + 2 x (s1 + 2 s2 r^2)
    dxd/dy = 2 x y rho' + 2 p1 x + 2 p2 y + 2 y (s1 + 2 s2 r^2)
    dyd/dx = 2 x y rho' + 2 p1 x + 2 p2 y + 2 x (s3 + 2 s4 r^2)
    dyd/dy = rho + 2 y^2 rho' + 6 p1 y + 2 p2 x + 2 y (s3 + 2 s4 r^2)
    """
    r2, rho, slope, _, (p1, p2), prism = _rational(x, y, distortion)
    cross = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y
    xx = rho + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x
    yy = rho + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x
    if prism is None:
        return xx, cross, cross, yy
    s1, s2, s3, s4 = prism
    px, py = 2.0 * (s1 + 2.0 * s2 * r2), 2.0 * (s3 + 2.0 * s4 * r2)
    return xx + x * px, cross + y * px, cross + x * py, yy + y * py


def _coefficient_jacobian_rational(x, y, distortion):
    """Columns ``d(xd, yd)/d(coefficient)``, in :data:`DISTORTION_MODELS`' order::

    d/dk_j     = (xn, yn) r^(2j) / M                  (j = 1, 2, 3)
    d/dp1 = (2 xn yn, r^2 + 2 yn^2),   d/dp2 = (r^2 + 2 xn^2, 2 xn yn)
    d/dk_(j+3) = -(xn, yn) rho r^(2j) / M             (j = 1, 2, 3)
    d/ds1 = (r^2, 0), d/ds2 = (r^4, 0), d/ds3 = (0, r^2), d/ds4 = (0, r^4)
    """
    r2, rho, _, den, _, prism = _rational(x, y, distortion)
    zero = jnp.zeros_like(x)
    powers = (r2, r2 * r2, r2 * r2 * r2)
    cols = [(x * r / den, y * r / den) for r in powers]
    cols += [(2.0 * x * y, r2 + 2.0 * y * y), (r2 + 2.0 * x * x, 2.0 * x * y)]
    if prism is not None:
        cols += [(-x * rho * r / den, -y * rho * r / den) for r in powers]
        cols += [(r2, zero), (r2 * r2, zero), (zero, r2), (zero, r2 * r2)]
    return cols


# --- fisheye (Kannala-Brandt) ---------------------------------------------------


def _fisheye(x, y, distortion):
    """``r``, ``t = atan r``, ``s = t_d / r`` (``t_d = t (1 + k1 t^2 + ... + k4 t^8)``),
    ``g = (ds/dr) / r`` and ``t / r``; Taylor series below :data:`_FISHEYE_SMALL`::

    s = 1 + (k1 - 1/3) r^2 + (1/5 - k1 + k2) r^4,   g = 2 (k1 - 1/3) + 4 (1/5 - k1 + k2) r^2
    """
    k1, k2, k3, k4 = _coefficients(distortion, 4)
    r2 = x * x + y * y
    small = r2 < _FISHEYE_SMALL**2
    r = jnp.sqrt(jnp.where(small, 1.0, r2))  # the closed forms only where r is not small
    t = jnp.arctan(r)
    t2 = t * t
    poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))  # d t_d / d t
    s_big = t * poly / r
    g_big = (dpoly / (1.0 + r * r) - s_big) / (r * r)  # (t_d' t' r - t_d) / r^3
    a, b = k1 - 1.0 / 3.0, 0.2 - k1 + k2
    s = jnp.where(small, 1.0 + r2 * (a + r2 * b), s_big)
    g = jnp.where(small, 2.0 * a + 4.0 * b * r2, g_big)
    t_over_r = jnp.where(small, 1.0 - r2 / 3.0 + 0.2 * r2 * r2, t / r)
    t2 = jnp.where(small, r2 * (1.0 - 2.0 * r2 / 3.0), t2)
    return s, g, t_over_r, t2


def _distort_fisheye(x, y, distortion):
    s = _fisheye(x, y, distortion)[0]
    return x * s, y * s


def _jacobian_fisheye(x, y, distortion):
    """``xd = s(r) xn``: ``dxd/dx = s + g x^2``, ``dxd/dy = dyd/dx = g x y``, ``dyd/dy = s + g y^2``."""
    s, g, _, _ = _fisheye(x, y, distortion)
    return s + g * x * x, g * x * y, g * x * y, s + g * y * y


def _coefficient_jacobian_fisheye(x, y, distortion):
    """``d(xd, yd)/dk_j = (xn, yn) (t / r) t^(2j)``."""
    _, _, t_over_r, t2 = _fisheye(x, y, distortion)
    out, p = [], t_over_r
    for _ in range(4):
        p = p * t2
        out.append((x * p, y * p))
    return out


def _split(xn: Array):
    return xn[..., 0], xn[..., 1]


# The functions and methods that users and photax call eagerly (outside jit) on
# arrays of varying shapes are jitted: eagerly each of their 10-40 operations
# was compiled separately for every new shape (the test suite compiled ~1300
# such one-operation programs from camera.py, dem.py and collinearity.py).
# Inside a traced function the inner jit is inlined, so nothing changes there.
@jax.jit
def distort(xn: Array, distortion: Array) -> Array:
    """Distortion of ``(..., 2)`` normalised coordinates (the formulas in this
    module's docstring); ``distortion`` is ``(..., n)``, the coefficients of one
    of :data:`DISTORTION_MODELS` (its length names it), one set for all points
    or one per point."""
    fisheye = distortion_model(distortion) == "fisheye"
    xd, yd = (_distort_fisheye if fisheye else _distort_rational)(*_split(xn), distortion)
    return jnp.stack([xd, yd], axis=-1)


@jax.jit
def distortion_jacobian(xn: Array, distortion: Array) -> Array:
    """``(..., 2, 2)`` derivative of :func:`distort` at ``xn``: rows
    ``(xd, yd)``, columns ``(xn, yn)`` (closed forms: ``_jacobian_rational``,
    ``_jacobian_fisheye``).

    With ``rho = 1 + k1 r^2 + k2 r^4 + k3 r^6`` and
    ``rho' = d rho / d r^2 = k1 + 2 k2 r^2 + 3 k3 r^4``, for ``"brown"``::

        dxd/dx = rho + 2 x^2 rho' + 2 p1 y + 6 p2 x
        dxd/dy = dyd/dx = 2 x y rho' + 2 p1 x + 2 p2 y
        dyd/dy = rho + 2 y^2 rho' + 6 p1 y + 2 p2 x
    """
    fisheye = distortion_model(distortion) == "fisheye"
    xx, xy, yx, yy = (_jacobian_fisheye if fisheye else _jacobian_rational)(*_split(xn), distortion)
    return jnp.stack([jnp.stack([xx, xy], axis=-1), jnp.stack([yx, yy], axis=-1)], axis=-2)


@jax.jit
def intrinsics_jacobian(xn: Array, focal_length: Array, distortion: Array) -> Array:
    """``(..., 2, 3 + n)`` derivative of the image-plane point ``x = x0 + f D(xn)``
    (:meth:`FrameCamera.project` for a fixed normalised point ``xn``) with
    respect to the interior orientation ``(f, x0, y0, *coefficients)``
    (:meth:`FrameCamera.intrinsic_names`; bundle adjustment's
    ``INTRINSICS`` for ``"brown"``); ``focal_length`` ``(...)`` and
    ``distortion`` ``(..., n)`` broadcast against the points::

        dx/df = D(xn),   dx/d(x0, y0) = I,   dx/dc = f dD/dc

    with ``dD/dc`` in closed form per model; for ``"brown"``::

        dx/dk_j = f xn r^(2j), dy/dk_j = f yn r^(2j)      (j = 1, 2, 3)
        dx/dp1 = 2 f xn yn,        dy/dp1 = f (r^2 + 2 yn^2)
        dx/dp2 = f (r^2 + 2 xn^2), dy/dp2 = 2 f xn yn
    """
    f = focal_length
    x, y = _split(xn)
    d = distort(xn, distortion)
    one, zero = jnp.ones_like(x), jnp.zeros_like(x)
    fisheye = distortion_model(distortion) == "fisheye"
    cols = (_coefficient_jacobian_fisheye if fisheye else _coefficient_jacobian_rational)(x, y, distortion)
    rows = (
        [d[..., 0], one, zero] + [f * c[0] for c in cols],
        [d[..., 1], zero, one] + [f * c[1] for c in cols],
    )
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


@functools.partial(jax.jit, static_argnames="iterations")
def undistort(xd: Array, distortion: Array, iterations: int = 20, tol: float = 1e-10) -> Array:
    """Invert :func:`distort`: the normalised ``xn`` with ``D(xn) = xd``, NaN
    where the inversion did not converge.

    ``"brown"`` and ``"opencv"``: Newton's method on the two coordinates with
    :func:`distortion_jacobian`, from ``xd``.  ``"fisheye"``: Newton on the
    angle ``t`` with ``t_d(t) = |xd|`` (from ``t = |xd|``, as OpenCV's
    ``cv2.fisheye.undistortPoints``), then ``xn = xd tan(t) / |xd|``.

    Converged means ``|D(xn) - xd| <= tol`` (normalised units: 1e-10 is
    1e-6 pixel for a focal length of 10,000 pixels) on the branch where the
    distortion keeps its orientation (Jacobian determinant > 0; fisheye:
    ``0 <= t < pi/2``): a point past the fold of a strong distortion, where
    no ray maps to it one to one, is NaN, never a wrong ray.
    """
    xd = jnp.asarray(xd, dtype=float)
    if distortion_model(distortion) == "fisheye":
        xn = _undistort_fisheye(xd, distortion, iterations)
    else:

        def step(_, xn):
            j = distortion_jacobian(xn, distortion)
            e = distort(xn, distortion) - xd
            det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
            dx = (j[..., 1, 1] * e[..., 0] - j[..., 0, 1] * e[..., 1]) / det
            dy = (j[..., 0, 0] * e[..., 1] - j[..., 1, 0] * e[..., 0]) / det
            return xn - jnp.stack([dx, dy], axis=-1)

        xn = jax.lax.fori_loop(0, iterations, step, xd)
    j = distortion_jacobian(xn, distortion)
    det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
    err = jnp.max(jnp.abs(distort(xn, distortion) - xd), axis=-1)
    ok = (err <= tol) & (det > 0)
    return jnp.where(ok[..., None], xn, jnp.nan)


def _undistort_fisheye(xd, distortion, iterations):
    k1, k2, k3, k4 = _coefficients(distortion, 4)  # () or one per point, as rho
    rho = jnp.sqrt(jnp.sum(xd * xd, axis=-1))

    def step(_, t):
        t2 = t * t
        td = t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        dtd = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
        return t - (td - rho) / dtd

    t = jax.lax.fori_loop(0, iterations, step, rho)
    inside = (t >= 0) & (t < 0.5 * jnp.pi)
    scale = jnp.where(rho > 0, jnp.tan(jnp.where(inside, t, 0.0)) / jnp.where(rho > 0, rho, 1.0), 1.0)
    return jnp.where(inside[..., None], xd * scale[..., None], jnp.nan)


class FrameCamera(Module):
    """A frame (pinhole) camera with optional lens distortion (Brown–Conrady,
    OpenCV's full model or a Kannala–Brandt fisheye: the module docstring).

    Attributes:
        focal_length: principal distance ``f`` (scalar), image-plane unit.
        principal_point: ``(2,)`` principal point ``(x0, y0)`` on the image
            plane, same unit, relative to the image centre.
        distortion: the coefficients of :attr:`model` on normalised
            coordinates (dimensionless): ``(5,)`` ``(k1, k2, k3, p1, p2)``
            for ``"brown"`` (the default), ``(12,)`` for ``"opencv"``,
            ``(4,)`` for ``"fisheye"`` (:data:`DISTORTION_MODELS`).  Zeros
            for an ideal camera.
        pixel_size: ``(2,)`` image-plane units per pixel along columns and
            rows, or ``None`` if the camera is not tied to a pixel grid.
        image_size: ``(width, height)`` in pixels, or ``None``.

    Examples:
        A camera in millimetres (8.8 mm lens, 17.6 um pixels, 1000 x 750 px): the image centre is
        pixel (499.5, 374.5) (pixel centres at integers, row down), the image-plane origin:

        >>> import numpy as np
        >>> import photax as ptx
        >>> cam = ptx.FrameCamera(focal_length=8.8, pixel_size=0.0176, image_size=(1000, 750))
        >>> print(np.round(np.asarray(cam.image_to_pixel(np.array([[0.0, 0.0], [0.176, 0.176]]))), 6))
        [[499.5 374.5]
         [509.5 364.5]]
        >>> print(f"{float(cam.focal_length) / 0.0176:.1f} px")  # f in pixels
        500.0 px
    """

    focal_length: Array
    principal_point: Array
    distortion: Array
    pixel_size: Array | None
    image_size: tuple[int, int] | None = field(static=True)

    def __init__(
        self,
        focal_length,
        principal_point=(0.0, 0.0),
        distortion=None,
        *,
        pixel_size=None,
        image_size: tuple[int, int] | None = None,
        model: str = "brown",
    ):
        if model not in DISTORTION_MODELS:
            raise ValueError(f"model must be one of {sorted(DISTORTION_MODELS)}, got {model!r}")
        names = DISTORTION_MODELS[model]
        self.focal_length = _f64(focal_length)
        self.principal_point = _f64(principal_point)
        self.distortion = _f64(np.zeros(len(names)) if distortion is None else distortion)
        if pixel_size is not None:
            pixel_size = jnp.broadcast_to(_f64(pixel_size), (2,))
        self.pixel_size = pixel_size
        self.image_size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        if self.focal_length.shape != ():
            raise ValueError(f"focal_length must be a scalar, got shape {self.focal_length.shape}")
        if self.principal_point.shape != (2,):
            raise ValueError(f"principal_point must be (x0, y0), got shape {self.principal_point.shape}")
        if self.distortion.shape != (len(names),):
            raise ValueError(
                f"distortion must be ({', '.join(names)}) for the {model} model, got shape {self.distortion.shape}"
            )
        if _concrete(self.focal_length) and not float(self.focal_length) > 0:
            raise ValueError(f"focal_length must be positive, got {float(self.focal_length)}")

    @classmethod
    def from_pixels(
        cls,
        focal_length_px: float,
        image_size: tuple[int, int],
        principal_point_px: tuple[float, float] | None = None,
        distortion=None,
        *,
        model: str = "brown",
    ) -> FrameCamera:
        """A camera whose image-plane unit is the pixel.

        Args:
            focal_length_px: principal distance in pixels.
            image_size: ``(width, height)`` in pixels.
            principal_point_px: ``(column, row)`` of the principal point;
                default the image centre ``((w - 1)/2, (h - 1)/2)``.
            distortion: ``(k1, k2, k3, p1, p2)`` with p1 in photax's y-up
                sense (minus OpenCV's p1), or the coefficients of ``model``.
            model: a key of :data:`DISTORTION_MODELS`.
        """
        w, h = image_size
        if principal_point_px is None:
            x0 = y0 = 0.0
        else:
            x0 = principal_point_px[0] - (w - 1) / 2.0
            y0 = -(principal_point_px[1] - (h - 1) / 2.0)
        return cls(focal_length_px, (x0, y0), distortion, pixel_size=1.0, image_size=(w, h), model=model)

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(np.asarray(self.distortion) != 0))

    @property
    def model(self) -> str:
        """The distortion model, a key of :data:`DISTORTION_MODELS` (told by the
        length of :attr:`distortion`)."""
        return distortion_model(self.distortion)

    @property
    def intrinsic_names(self) -> tuple[str, ...]:
        """Names of the interior orientation's parameters in the order of
        :meth:`intrinsics_jacobian`: ``("f", "x0", "y0", *coefficients)``."""
        return ("f", "x0", "y0", *DISTORTION_MODELS[self.model])

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
        """Apply the lens distortion to ``(..., 2)`` normalised coords
        (:func:`distort`)."""
        return distort(xn, self.distortion)

    def distortion_jacobian(self, xn: Array) -> Array:
        """``(..., 2, 2)`` derivative of :meth:`distort_normalised` at ``xn``
        (:func:`distortion_jacobian`)."""
        return distortion_jacobian(xn, self.distortion)

    def intrinsics_jacobian(self, xn: Array) -> Array:
        """``(..., 2, 3 + n)`` derivative of the image-plane point with respect to
        :attr:`intrinsic_names` (``(f, x0, y0, k1, k2, k3, p1, p2)`` for
        ``"brown"``; :func:`intrinsics_jacobian`)."""
        return intrinsics_jacobian(xn, self.focal_length, self.distortion)

    @functools.partial(jax.jit, static_argnames="iterations")
    def undistort_normalised(self, xd: Array, iterations: int = 20) -> Array:
        """Invert :meth:`distort_normalised` by Newton's method, NaN where it
        does not converge (:func:`undistort`)."""
        return undistort(xd, self.distortion, iterations)

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
