"""Rigorous push-broom (linear-array, "multi-centre projection") sensor model, its resection from GCPs,
and an RPC fitted to it.

Every image line is exposed at its own time and has its own exterior orientation; across the line
the geometry is a frame camera's.  With the line time normalised over the scene,
``tau = (row - (L - 1)/2) / ((L - 1)/2)`` in ``[-1, 1]`` (L lines), the projection centre and the
attitude are polynomials of ``tau``::

    C(tau) = sum_k position[k] tau^k                  (ECEF, m)
    R(tau) = reference @ rotation_matrix(sum_k angles[k] tau^k)      (world_from_camera)

(``reference`` a fixed rotation, e.g. the orbital frame at the scene's centre, so that the angles stay
small and clear of gimbal lock).  In the camera frame (x right along the array, y up, z backwards,
``docs/conventions.md``) with ``q = R(tau)^T (X - C(tau))``, ``X`` the ground point in ECEF::

    column = (w - 1)/2 + x0 - f q_x / q_z
    0      = y0 - f q_y / q_z                          (the point lies on the array: defines tau)

``f``, ``x0``, ``y0`` in pixels: the principal point sits ``x0`` right of the array's centre and ``y0``
above the array (a forward- or backward-looking array).  The forward projection finds ``tau`` by
Newton's method on the second equation (its derivative by ``jax.jvp``), then the column;
:meth:`PushbroomCamera.to_ground` intersects a pixel's ray with the surface of a given ellipsoidal
height.  Ground is lon, lat (deg) and ellipsoidal height (m) on WGS84, as for
:class:`photax.RPCCamera`, so either model serves where the other does.

:func:`resect_pushbroom` adjusts low orders of the position and attitude polynomials (bias, drift) on
GCPs by Gauss-Newton, with a-priori standard deviations of the ephemeris and attitude as
pseudo-observations (without them the along-track position and the pitch are nearly the same
unknown), and reports like :func:`photax.resect`: sigma0, covariance, redundancy numbers, Baarda's w
or Pope's tau, data snooping.

:func:`fit_rpc` fits an :class:`photax.RPCCamera` to any such model, terrain-independently (Tao & Hu
2001): a grid of image points is taken to the ground at several heights over the scene's height
range, and the 78 coefficients are adjusted by iteratively reweighted, regularised least squares; the
fit error is reported on those points and on a check grid between them.

References: Poli & Toutin, "Review of developments in geometric modelling for high resolution
satellite pushbroom sensors", Photogramm. Rec. 27 (2012); Tao & Hu, "A comprehensive study of the
rational function model for photogrammetric processing", PE&RS 67 (2001).
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._float64 import as_float64
from .earth import ecef_to_geodetic, geodetic_to_ecef
from .errors import ConvergenceError
from .rotation import Convention, check_convention, rotation_matrix
from .rpc import RPCCamera, rpc_terms

_NEWTON_STEPS = 10  # line search: Newton on tau (quadratic; the first step is already within a line or so)
_HEIGHT_STEPS = 6  # ray - surface intersection


def _poly(coeffs: Array, tau: Array) -> Array:
    """``sum_k coeffs[k] tau^k`` for ``coeffs`` ``(k + 1, 3)`` and a scalar ``tau`` (Horner: ``tau ** 0``
    has a NaN derivative at 0)."""
    out = coeffs[-1]
    for c in coeffs[-2::-1]:
        out = out * tau + c
    return out


class PushbroomCamera(eqx.Module):
    """A push-broom sensor (module docstring: the equations).

    Attributes:
        position: ``(kp + 1, 3)`` polynomial coefficients of the projection centre in ECEF (m), lowest
            order first, in the normalised line time ``tau``.
        angles: ``(ka + 1, 3)`` polynomial coefficients of the attitude angles (rad, in the order the
            convention names) relative to ``reference``.
        reference: ``(3, 3)`` fixed ``world(ECEF)_from_reference`` rotation.
        focal_length: principal distance (px).
        principal_point: ``(2,)`` ``(x0, y0)`` (px): the principal point relative to the array's centre,
            y up (``y0 != 0``: the array looks forward or backward).
        image_size: ``(width, lines)`` in pixels.
        convention: the angle convention (``docs/conventions.md``).

    Examples:
        The camera of a synthetic scene (:func:`photax.pushbroom_scene`): the line time ``tau`` runs
        from -1 at the first line to +1 at the last, and ground -> pixel -> ground at the point's
        height is a round trip:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.pushbroom_scene(image_size=(2000, 2000)).camera
        >>> [float(camera.tau(row)) for row in (0.0, 999.5, 1999.0)]
        [-1.0, 0.0, 1.0]
        >>> lonlath = np.array([[10.0, 45.0, 500.0]])
        >>> back = np.asarray(camera.to_ground(np.asarray(camera(lonlath)), lonlath[:, 2]))
        >>> bool(np.abs(back - lonlath[:, :2]).max() < 1e-9)  # degrees
        True
    """

    position: Array
    angles: Array
    reference: Array
    focal_length: Array
    principal_point: Array
    image_size: tuple[int, int] = eqx.field(static=True)
    convention: str = eqx.field(static=True, default="phi-omega-kappa")

    def __init__(self, position, angles, reference, focal_length, principal_point=(0.0, 0.0), *, image_size,
                 convention: Convention = "phi-omega-kappa"):  # fmt: skip
        self.position = jnp.asarray(as_float64(position, "position"))
        self.angles = jnp.asarray(as_float64(angles, "angles"))
        self.reference = jnp.asarray(as_float64(reference, "reference"))
        self.focal_length = jnp.asarray(as_float64(focal_length, "focal_length"))
        self.principal_point = jnp.asarray(as_float64(principal_point, "principal_point"))
        self.convention = check_convention(convention)
        for name, a in (("position", self.position), ("angles", self.angles)):
            if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 1:
                raise ValueError(f"{name}: expected polynomial coefficients of shape (k + 1, 3), got {a.shape}")
        if self.reference.shape != (3, 3):
            raise ValueError(f"reference: expected a (3, 3) rotation, got {self.reference.shape}")
        if self.focal_length.shape != () or self.principal_point.shape != (2,):
            raise ValueError("focal_length must be a scalar and principal_point (x0, y0)")
        w, lines = (int(v) for v in image_size)
        if w < 1 or lines < 2:
            raise ValueError(f"image_size: expected (width >= 1, lines >= 2), got {image_size}")
        self.image_size = (w, lines)
        if not isinstance(self.focal_length, jax.core.Tracer):
            if not (np.all(np.isfinite(np.asarray(self.position))) and np.all(np.isfinite(np.asarray(self.angles)))):
                raise ValueError("position / angles: non-finite coefficients")
            ref = np.asarray(self.reference)
            if not (np.allclose(ref.T @ ref, np.eye(3), atol=1e-9) and np.linalg.det(ref) > 0):
                raise ValueError("reference: not a rotation matrix (orthonormal, determinant +1)")
            if not float(self.focal_length) > 0:
                raise ValueError(f"focal_length must be positive, got {float(self.focal_length)}")

    # --- line time and orientation --------------------------------------------------------------

    def tau(self, row) -> Array:
        """Normalised line time of ``row`` (``-1`` at the first line, ``1`` at the last)."""
        half = (self.image_size[1] - 1) / 2.0
        return (jnp.asarray(row, dtype=jnp.float64) - half) / half

    def row(self, tau) -> Array:
        half = (self.image_size[1] - 1) / 2.0
        return jnp.asarray(tau, dtype=jnp.float64) * half + half

    def centre(self, tau) -> Array:
        """``(3,)`` projection centre (ECEF) at the scalar line time ``tau``."""
        return _poly(self.position, tau)

    def rotation(self, tau) -> Array:
        """``(3, 3)`` ``world_from_camera`` at the scalar line time ``tau``."""
        return self.reference @ rotation_matrix(_poly(self.angles, tau), self.convention)

    # --- the orbit and attitude as one parameter vector (uncertainty, resection) ------------------

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of :meth:`parameters`: ``"position[k].X"`` (``Y``, ``Z``) for every coefficient of the
        position polynomial, then ``"angles[k].omega"`` (the convention's axes) of the attitude's, as
        :class:`PushbroomResection` names its adjusted ones."""
        axes = {"position": ("X", "Y", "Z"), "angles": tuple(self.convention.split("-"))}
        return tuple(
            f"{field}[{k}].{label}"
            for field in ("position", "angles")
            for k in range(getattr(self, field).shape[0])
            for label in axes[field]
        )

    def parameters(self) -> Array:
        """The position's then the angles' polynomial coefficients, row by row: ``(3 (kp + ka + 2),)``
        (m, rad), the order of :attr:`parameter_names`."""
        return jnp.concatenate([self.position.ravel(), self.angles.ravel()])

    def with_parameters(self, theta: Array) -> PushbroomCamera:
        """This camera with :meth:`parameters` replaced by ``theta`` (jittable, differentiable)."""
        n = self.position.size
        pos = jnp.reshape(theta[:n], self.position.shape)
        ang = jnp.reshape(theta[n:], self.angles.shape)
        return eqx.tree_at(lambda c: (c.position, c.angles), self, (pos, ang))

    # --- projection -----------------------------------------------------------------------------

    def _in_camera(self, xyz: Array, tau) -> Array:
        return self.rotation(tau).T @ (xyz - self.centre(tau))

    def _project_one(self, xyz: Array):
        f, (x0, y0) = self.focal_length, self.principal_point

        def off_line(t):  # y0 - f q_y / q_z: the point's distance from the array (px)
            q = self._in_camera(xyz, t)
            return y0 - f * q[1] / q[2]

        def step(_, t):
            g, dg = jax.jvp(off_line, (t,), (jnp.ones_like(t),))
            return t - g / dg

        t = jax.lax.fori_loop(0, _NEWTON_STEPS, step, jnp.zeros((), jnp.float64))
        q = self._in_camera(xyz, t)
        column = (self.image_size[0] - 1) / 2.0 + x0 - f * q[0] / q[2]
        return jnp.stack([column, self.row(t)]), jnp.abs(off_line(t)), -q[2]

    def project_ecef(self, xyz: Array) -> Array:
        """``(..., 3)`` ECEF (m) -> ``(..., 2)`` column, row (px); NaN where the line search did not settle
        (the point's distance from the array above 1e-6 px) or the point is behind the sensor."""
        xyz = jnp.asarray(xyz, dtype=jnp.float64)
        out = _project(self, xyz.reshape(-1, 3))
        return out.reshape(*xyz.shape[:-1], 2)

    def __call__(self, ground: Array) -> Array:
        """``(..., 3)`` lon (deg), lat (deg), ellipsoidal h (m) -> ``(..., 2)`` column, row (px)."""
        return self.project_ecef(geodetic_to_ecef(ground))

    project = __call__

    # the ground-camera protocol of photax.sensor (shared with photax.RPCCamera)

    #: Heights (m) whose footprints bound :meth:`ground_box`: the earth's surface lies between them.
    BOX_HEIGHTS = (-500.0, 9000.0)

    def ground_box(self):
        """``((lon, lat), (dlon, dlat))``: centre and half-sides (deg) of the box holding the image's
        outline on the ground at every height of :attr:`BOX_HEIGHTS` (the area an ortho can reach)."""
        w, lines = self.image_size
        t = np.linspace(0.0, 1.0, 9)
        x1, y1 = w - 0.5, lines - 0.5
        edge = np.concatenate(
            [np.stack([t * (x1 + 0.5) - 0.5, np.full_like(t, v)], -1) for v in (-0.5, y1)]
            + [np.stack([np.full_like(t, v), t * (y1 + 0.5) - 0.5], -1) for v in (-0.5, x1)]
        )
        ll = np.concatenate([np.asarray(self.to_ground(jnp.asarray(edge), h)) for h in self.BOX_HEIGHTS])
        if not np.all(np.isfinite(ll)):
            raise ValueError("the push-broom image's outline does not reach the ground (looks above the horizon)")
        lo, hi = ll.min(0), ll.max(0)
        return (lo + hi) / 2, (hi - lo) / 2

    height_range = None  # a rigorous model serves any height

    def invert(self, pixel: Array, h: Array):
        """``(n, 2)`` pixels at ``(n,)`` heights -> ``((n, 2)`` lon, lat, ``(n,)`` converged); jittable."""
        ll = _to_ground(self, pixel, h)
        return ll, jnp.all(jnp.isfinite(ll), axis=-1)

    def ray(self, pixel: Array) -> tuple[Array, Array]:
        """``(..., 2)`` column, row -> projection centres ``(..., 3)`` and unit ray directions ``(..., 3)`` (ECEF)."""
        pixel = jnp.asarray(pixel, dtype=jnp.float64)
        c, d = jax.vmap(self._ray_one)(pixel.reshape(-1, 2))
        return c.reshape(pixel.shape[:-1] + (3,)), d.reshape(pixel.shape[:-1] + (3,))

    def _ray_one(self, p: Array):
        t = self.tau(p[1])
        x = p[0] - (self.image_size[0] - 1) / 2.0 - self.principal_point[0]
        d = self.rotation(t) @ jnp.stack([x, -self.principal_point[1], -self.focal_length])
        return self.centre(t), d / jnp.linalg.norm(d)

    def to_ground(self, pixel: Array, height) -> Array:
        """``(..., 2)`` column, row and ellipsoidal height(s) ``(...)`` -> ``(..., 2)`` lon, lat (deg).

        The pixel's ray meets the surface of that height: Newton's method on the distance along the ray
        (the height's derivative by ``jax.jvp``), from the distance to the sphere through the nadir.
        """
        pixel = jnp.asarray(as_float64(pixel, "pixel"))
        if pixel.shape[-1:] != (2,):
            raise ValueError(f"pixel: expected shape (..., 2), got {pixel.shape}")
        h = jnp.broadcast_to(jnp.asarray(as_float64(height, "height")), pixel.shape[:-1])
        out = _to_ground(self, pixel.reshape(-1, 2), h.reshape(-1))
        return out.reshape(pixel.shape)


@eqx.filter_jit
def _project(camera: PushbroomCamera, xyz: Array) -> Array:
    cr, miss, depth = jax.vmap(camera._project_one)(xyz)
    ok = (miss < 1e-6) & (depth > 0)
    return jnp.where(ok[:, None], cr, jnp.nan)


@eqx.filter_jit
def _to_ground(camera: PushbroomCamera, pixel: Array, h: Array) -> Array:
    def one(p, hh):
        c, d = camera._ray_one(p)

        def height(s):
            return ecef_to_geodetic(c + s * d)[2]

        up = c / jnp.linalg.norm(c)
        s = (height(0.0) - hh) / -(up @ d)

        def step(_, s):
            g, dg = jax.jvp(height, (s,), (jnp.ones_like(s),))
            return s - (g - hh) / dg

        s = jax.lax.fori_loop(0, _HEIGHT_STEPS, step, s)
        ok = jnp.abs(height(s) - hh) < 1e-6
        return jnp.where(ok, ecef_to_geodetic(c + s * d)[:2], jnp.nan)

    return jax.vmap(one)(pixel, h)


# --- resection ----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PushbroomResection:
    """Outcome of :func:`resect_pushbroom`.

    Attributes:
        camera: the adjusted :class:`PushbroomCamera`.
        parameters: names of the adjusted corrections (``"position[0].X"``, ``"angles[1].omega"``, ...).
        estimate: ``(u,)`` their adjusted values (m, rad): added to the start's coefficients.
        covariance: ``(u, u)``; ``std`` ``(u,)`` and ``correlation`` ``(u, u)`` from it.
        sigma0: a-posteriori standard deviation of unit weight (dimensionless: the pixels are weighted
            by ``1 / sigma^2``); NaN at zero redundancy.
        redundancy: ``2 n + (priors) - u`` of the final adjustment.
        residuals: ``(n, 2)`` computed - observed (px), every point (outliers, check points included).
        redundancy_numbers: ``(n, 2)`` (0 where a point is not used).
        normalised: ``(n, 2)`` Baarda's w (``sigma`` given) or Pope's tau; for outliers the values with
            which they were excluded; NaN for check points.
        critical: the critical value of the test.
        statistic: ``"w"`` or ``"tau"``.
        outliers: ``(n,)`` control points excluded by data snooping; ``check`` ``(n,)`` check points.
        rmse, check_rmse: RMS of the residuals' lengths (px) of the control inliers / the check points.
        iterations, converged, message: how the last adjustment ended.
        names: ``(n,)`` point names.

    Examples:
        The adjusted camera of :func:`resect_pushbroom`'s example takes the check points from the
        start camera's 11 px to the 0.3 px noise, as the GCPs:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.pushbroom_scene(image_size=(2000, 2000))
        >>> res = ptx.resect_pushbroom(scene.start, scene.gcp_ground, scene.gcp_pixel, position_order=1,
        ...                            position_sigma=10.0, sigma=scene.noise_px)
        >>> rmse = lambda camera: np.sqrt(np.mean(np.sum((camera(scene.check_ground) - scene.check_pixel) ** 2, 1)))
        >>> print(f"{rmse(scene.start):.0f} px -> {rmse(res.camera):.1f} px; GCPs {res.rmse:.1f} px")
        11 px -> 0.4 px; GCPs 0.4 px
        >>> print(res.summary().splitlines()[0])
        push-broom resection: Gauss-Newton converged in 5 steps
    """

    camera: PushbroomCamera
    parameters: tuple[str, ...]
    estimate: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    sigma0: float
    redundancy: int
    residuals: np.ndarray
    redundancy_numbers: np.ndarray
    normalised: np.ndarray
    critical: float
    statistic: str
    outliers: np.ndarray
    check: np.ndarray
    rmse: float
    check_rmse: float
    iterations: int
    converged: bool
    message: str
    names: tuple[str, ...]

    def summary(self) -> str:
        """A short report: parameters with their standard deviations, sigma0, outliers."""
        lines = [f"push-broom resection: {self.message}", f"sigma0 {self.sigma0:.3f}  redundancy {self.redundancy}  "
                 f"rmse {self.rmse:.3f} px  check rmse {self.check_rmse:.3f} px"]  # fmt: skip
        for name, v, s in zip(self.parameters, self.estimate, self.std, strict=True):
            unit = "m" if name.startswith("position") else "urad"
            k = 1.0 if unit == "m" else 1e6
            lines.append(f"  {name:18s} {v * k:12.3f} +- {s * k:.3f} {unit}")
        bad = [self.names[i] for i in np.flatnonzero(self.outliers)]
        lines.append(f"outliers: {', '.join(bad) if bad else 'none'} ({self.statistic} > {self.critical:.2f})")
        return "\n".join(lines)


def _critical(alpha: float, sigma_known: bool, redundancy: float) -> float:
    """Critical value of Baarda's w (normal) or Pope's tau (with ``redundancy`` degrees of freedom)."""
    from scipy import special, stats

    if sigma_known:
        return float(stats.norm.ppf(1.0 - alpha / 2.0))
    if redundancy < 2:
        return math.inf
    t = float(special.stdtrit(redundancy - 1, 1.0 - alpha / 2.0))
    return t * math.sqrt(redundancy) / math.sqrt(redundancy - 1 + t * t)


def _free_slots(camera: PushbroomCamera, position_order, attitude_order):
    """``[(field, k, axis, name)]`` of the adjusted coefficients."""
    axes = camera.convention.split("-")
    slots = []
    for field, order, labels in (("position", position_order, ("X", "Y", "Z")), ("angles", attitude_order, axes)):
        if order is None:
            continue
        have = getattr(camera, field).shape[0] - 1
        if not 0 <= order <= have:
            raise ValueError(f"{field} order: expected 0..{have} (the camera's polynomial), got {order}")
        slots += [(field, k, a, f"{field}[{k}].{labels[a]}") for k in range(order + 1) for a in range(3)]
    return slots


def _with(camera: PushbroomCamera, slots, delta: Array) -> PushbroomCamera:
    pos, ang = camera.position, camera.angles
    for i, (field, k, a, _) in enumerate(slots):
        if field == "position":
            pos = pos.at[k, a].add(delta[i])
        else:
            ang = ang.at[k, a].add(delta[i])
    return eqx.tree_at(lambda c: (c.position, c.angles), camera, (pos, ang))


def resect_pushbroom(
    camera: PushbroomCamera,
    ground,
    pixel,
    *,
    attitude_order: int | None = 1,
    position_order: int | None = None,
    attitude_sigma: float | None = None,
    position_sigma: float | None = None,
    sigma=None,
    check=None,
    names=None,
    robust: bool = True,
    alpha: float = 0.001,
    max_steps: int = 20,
    throw: bool = True,
) -> PushbroomResection:
    """Adjust the orbit and attitude of a push-broom image on GCPs.

    The corrections to the polynomial coefficients of orders ``0..attitude_order`` of the angles and
    ``0..position_order`` of the position (None: that one is held) are the unknowns, starting from
    ``camera`` (its ephemeris and attitude as measured).  Gauss-Newton on the pixel residuals, the
    Jacobian by ``jax.jacfwd`` through the line search; columns scaled to unit length for the solve.

    Args:
        camera: the start (e.g. from the image's metadata).
        ground: ``(n, 3)`` lon (deg), lat (deg), ellipsoidal height (m).
        pixel: ``(n, 2)`` measured column, row (px).
        attitude_order, position_order: highest adjusted order (0 bias, 1 drift), or None (held); by
            default the attitude's bias and drift with the ephemeris held, the usual bias compensation.
            Freeing the position too wants ``position_sigma``: without it along-track position and
            pitch (and across-track position and roll) are nearly one unknown, and their standard
            deviations say so.
        attitude_sigma, position_sigma: a-priori standard deviations (rad, m) of the start's
            coefficients: pseudo-observations ``delta = 0`` with those weights; None: free.
        sigma: a-priori standard deviation of the pixel coordinates (px); given, blunders are tested with
            Baarda's w and sigma0 is expected near 1; None: 1 px for the weights and Pope's tau.
        check: ``(n,)`` bool, check points (not in the adjustment, their residuals reported).
        names: ``(n,)`` point names.
        robust: data snooping: exclude the worst control point while its statistic exceeds the critical
            value and the redundancy allows.
        alpha: significance level of each test.
        max_steps: Gauss-Newton steps per adjustment (it stops when the largest scaled step is below 1e-10).
        throw: raise :class:`photax.ConvergenceError` when the adjustment fails; otherwise return the result
            with ``converged=False`` and the reason in ``message``.

    Raises:
        ValueError: bad shapes, non-finite values, GCPs outside the image or where the model cannot
            project them, too few control points for the unknowns (says how many).

    Examples:
        A synthetic scene from a 620 km orbit (:func:`photax.pushbroom_scene`) whose start camera has a
        known ephemeris and attitude error; orbit and attitude bias and drift adjusted on 20 GCPs,
        the ephemeris with a prior of 10 m:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.pushbroom_scene(image_size=(2000, 2000))
        >>> res = ptx.resect_pushbroom(scene.start, scene.gcp_ground, scene.gcp_pixel, position_order=1,
        ...                            position_sigma=10.0, sigma=scene.noise_px)
        >>> res.converged, res.parameters[0], res.parameters[-1]
        (True, 'position[0].X', 'angles[1].kappa')
        >>> truth = -np.concatenate([scene.position_error.ravel(), scene.attitude_error.ravel()])
        >>> bool(np.all(np.abs(res.estimate - truth) < 3 * res.std))  # the truth within 3 sigma
        True
    """
    ground = as_float64(ground, "ground")
    pixel = as_float64(pixel, "pixel")
    if ground.ndim != 2 or ground.shape[1] != 3:
        raise ValueError(f"ground: expected shape (n, 3) lon, lat, h, got {ground.shape}")
    if pixel.shape != (len(ground), 2):
        raise ValueError(f"pixel: expected shape ({len(ground)}, 2) to match ground, got {pixel.shape}")
    n = len(ground)
    names = tuple(str(s) for s in names) if names is not None else tuple(f"P{i}" for i in range(n))
    bad = [names[i] for i in np.flatnonzero(~(np.all(np.isfinite(ground), 1) & np.all(np.isfinite(pixel), 1)))]
    if bad:
        raise ValueError(f"non-finite GCP coordinates: {', '.join(bad)}")
    w, lines = camera.image_size
    outside = (pixel[:, 0] < -0.5) | (pixel[:, 0] > w - 0.5) | (pixel[:, 1] < -0.5) | (pixel[:, 1] > lines - 0.5)
    if np.any(outside):
        raise ValueError(
            f"GCPs outside the image ({w} x {lines}): {', '.join(names[i] for i in np.flatnonzero(outside))}"
        )
    check = np.zeros(n, bool) if check is None else np.asarray(check, bool).reshape(n)
    slots = _free_slots(camera, position_order, attitude_order)
    u = len(slots)
    if u == 0:
        raise ValueError("resect_pushbroom: nothing to adjust (attitude_order and position_order both None)")
    prior = np.array(
        [(attitude_sigma if f == "angles" else position_sigma) or np.nan for f, *_ in slots], float
    )  # NaN: no prior
    n_prior = int(np.sum(np.isfinite(prior)))
    need = math.ceil(max(u - n_prior, 1) / 2)
    if int(np.sum(~check)) < need:
        raise ValueError(f"resect_pushbroom: {u} unknowns ({n_prior} with a prior) need at least {need} control "
                         f"points, got {int(np.sum(~check))}")  # fmt: skip
    sigma_known = sigma is not None
    s_px = np.broadcast_to(np.asarray(1.0 if sigma is None else sigma, float), (n,)).copy()
    if not np.all(s_px > 0):
        raise ValueError("sigma: must be positive")
    xyz = np.asarray(geodetic_to_ecef(ground))
    start = np.asarray(camera(ground))
    with np.errstate(invalid="ignore"):  # a line far beyond the image: the GCP is not in this scene
        lost = np.flatnonzero(~np.all(np.isfinite(start), 1) | (np.abs(start[:, 1] - (lines - 1) / 2) > 2 * lines))
    if lost.size:
        raise ValueError(f"the start camera cannot project {', '.join(names[i] for i in lost)} (behind it, or no line "
                         "of the image sees them): check the GCPs' coordinates (lon, lat order) and the camera")  # fmt: skip

    def model(delta, pts):
        return _project(_with(camera, slots, delta), pts)

    jac = jax.jit(jax.jacfwd(model))
    fun = jax.jit(model)
    pts = jnp.asarray(xyz)
    delta = np.zeros(u)
    used = ~check
    stat_at = np.full((n, 2), np.nan)
    while True:
        delta, info = _adjust(fun, jac, pts, pixel, s_px, prior, used, delta, max_steps)
        r_total = 2 * int(used.sum()) + n_prior - u
        crit = _critical(alpha, sigma_known, r_total)
        stat = info["w"] / (1.0 if sigma_known else info["sigma0"])
        score = np.where(used[:, None] & np.isfinite(stat), np.abs(stat), -np.inf).max(1)
        worst = int(np.argmax(score)) if np.isfinite(score).any() else None
        if not robust or worst is None or not info["converged"] or not np.abs(stat[worst]).max() > crit:
            break
        if r_total - 2 < (1 if sigma_known else 2) or 2 * (used.sum() - 1) + n_prior < u:
            break  # too little redundancy left to exclude another point
        stat_at[worst] = stat[worst]
        used = used.copy()
        used[worst] = False
    res = info["residuals"]
    # as resect: the a-posteriori sigma0 scales the cofactors; without redundancy the a-priori one (if given)
    cov = info["qxx"] * (info["sigma0"] ** 2 if r_total > 0 else (1.0 if sigma_known else math.nan))
    std = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
        normalised = np.where(used[:, None], stat, stat_at)
        normalised[check] = np.nan
        d2 = np.sum(res**2, 1)
        rmse = float(np.sqrt(np.mean(d2[used]))) if used.any() else math.nan
        check_rmse = float(np.sqrt(np.mean(d2[check]))) if check.any() else math.nan
    converged = bool(info["converged"] and np.all(np.isfinite(res[used])))
    message = (f"Gauss-Newton converged in {info['steps']} steps" if converged
               else f"Gauss-Newton did not converge in {info['steps']} steps (or a GCP left the image's lines)")  # fmt: skip
    if r_total <= 0:
        message += "; zero redundancy: sigma0 and blunder tests undefined"
    if throw and not converged:
        raise ConvergenceError(message)
    return PushbroomResection(
        camera=_with(camera, slots, jnp.asarray(delta)),
        parameters=tuple(s[3] for s in slots),
        estimate=delta,
        covariance=cov,
        std=std,
        correlation=corr,
        sigma0=float(info["sigma0"]),
        redundancy=r_total,
        residuals=res,
        redundancy_numbers=info["redundancy"],
        normalised=normalised,
        critical=crit,
        statistic="w" if sigma_known else "tau",
        outliers=~check & ~used,
        check=check,
        rmse=rmse,
        check_rmse=check_rmse,
        iterations=info["steps"],
        converged=converged,
        message=message,
        names=names,
    )


def _adjust(fun, jac, pts, observed, s_px, prior, used, delta, max_steps):
    """Gauss-Newton on the used points (and the priors) from ``delta``; precision at the solution."""
    has_prior = np.isfinite(prior)
    pseudo = np.eye(len(prior))[has_prior] / prior[has_prior, None]  # rows of the priors' pseudo-observations
    wts = np.repeat(used / s_px, 2)
    rows = np.concatenate([np.repeat(used, 2), np.ones(len(pseudo), bool)])

    def system(delta):
        v = np.asarray(fun(jnp.asarray(delta), pts)) - observed  # computed - observed
        a = np.asarray(jac(jnp.asarray(delta), pts))  # (n, 2, u)
        design = np.concatenate([a.reshape(-1, a.shape[-1]) * wts[:, None], pseudo])
        return v, design, np.concatenate([-v.reshape(-1) * wts, -delta[has_prior] / prior[has_prior]])

    converged, steps = False, 0
    for steps in range(1, max_steps + 1):  # noqa: B007 -- the count is reported
        v, design, rhs = system(delta)
        if not (np.all(np.isfinite(design[rows])) and np.all(np.isfinite(rhs[rows]))):
            break  # a used point the model cannot project: not converged
        design, rhs = np.nan_to_num(design), np.nan_to_num(rhs)
        scale = np.linalg.norm(design, axis=0)
        scale[scale == 0] = 1.0
        step = np.linalg.lstsq(design / scale, rhs, rcond=None)[0]
        delta = delta + step / scale
        if np.max(np.abs(step)) < 1e-10 * max(1.0, float(np.max(np.abs(delta * scale)))):
            converged = True
            break
    v, design, rhs = system(delta)
    return delta, dict(
        converged=converged, steps=steps, **_precision(np.nan_to_num(design), np.nan_to_num(rhs), v, used, s_px)
    )


def _precision(design, rhs, v, used, s_px):
    """sigma0, cofactor matrix, redundancy numbers and w of the (weighted, stacked) system."""
    n = len(v)
    scale = np.linalg.norm(design, axis=0)
    scale[scale == 0] = 1.0
    qs = np.linalg.pinv((design / scale).T @ (design / scale))
    qxx = qs / np.outer(scale, scale)
    r_total = design.shape[0] - 2 * n + 2 * int(used.sum()) - design.shape[1]
    vw = -rhs  # weighted residuals at the solution (computed - observed)
    sigma0 = math.sqrt(float(vw @ vw) / r_total) if r_total > 0 else math.nan
    hat = np.einsum("ij,jk,ik->i", design / scale, qs, design / scale)[: 2 * n].reshape(n, 2)
    red = np.where(used[:, None], 1.0 - hat, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = v / s_px[:, None] / np.sqrt(np.where(red > 1e-12, red, np.nan))
    return dict(sigma0=sigma0, qxx=qxx, redundancy=red, w=w, residuals=v)


# --- RPC fitted to a rigorous model -------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RPCFit:
    """Outcome of :func:`fit_rpc`.

    Attributes:
        camera: the fitted :class:`photax.RPCCamera`.
        rmse, max_error: RMS and largest length of the RPC's error (RPC - rigorous, px) on the fit points.
        check_rmse, check_max_error: the same on the check grid (image points between the fit grid's,
            heights between its layers).
        points, check_points: how many of each.
        iterations: reweighting iterations (Tao & Hu's ``W = 1 / den^2``).
        regularisation: the ridge factor used.
        check_ground: ``(m, 3)`` the check points' lon, lat, h; ``check_pixel`` ``(m, 2)`` their rigorous
            column, row; ``check_residuals`` ``(m, 2)`` RPC minus rigorous (px), for maps of the error.

    Examples:
        The fit of :func:`fit_rpc`'s example: 15 x 15 image points on 7 height layers, an RPC within
        a ten-thousandth of a pixel of the rigorous model there:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.pushbroom_scene(roll=20.0, pitch=-15.0, image_size=(2000, 2000))
        >>> fit = ptx.fit_rpc(scene.camera, scene.height_range)
        >>> fit.points, bool(fit.max_error < 1e-4), fit.check_residuals.shape
        (1575, True, (1176, 2))
        >>> gap = np.asarray(fit.camera(fit.check_ground)) - np.asarray(scene.camera(fit.check_ground))
        >>> bool(np.allclose(gap, fit.check_residuals, atol=1e-6))
        True
    """

    camera: RPCCamera
    rmse: float
    max_error: float
    check_rmse: float
    check_max_error: float
    points: int
    check_points: int
    iterations: int
    regularisation: float
    check_ground: np.ndarray
    check_pixel: np.ndarray
    check_residuals: np.ndarray


def _grid_points(model, heights, cols, rows):
    cc, rr, hh = np.meshgrid(cols, rows, heights, indexing="ij")
    pix = np.stack([cc.ravel(), rr.ravel()], -1)
    lonlat = np.asarray(model.to_ground(jnp.asarray(pix), jnp.asarray(hh.ravel())))
    ok = np.all(np.isfinite(lonlat), 1)
    return np.column_stack([lonlat, hh.ravel()])[ok], pix[ok]


def fit_rpc(
    model,
    height_range: tuple[float, float],
    *,
    grid: int = 15,
    layers: int = 7,
    regularisation: float = 1e-8,
    max_iterations: int = 10,
) -> RPCFit:
    """Fit an RPC (cubic / cubic, RPC00B) to a rigorous sensor model, terrain-independently (Tao & Hu 2001).

    A ``grid x grid`` lattice of image points over the whole image, taken to the ground on ``layers``
    heights evenly over ``height_range`` (``model.to_ground``), gives the fit points; offsets and scales
    are their centres and half ranges.  For each image axis ``p = Num(L, P, H) / Den(L, P, H)`` (with
    ``Den``'s constant term 1) is linearised as ``Num - p (Den - 1) = p`` and solved with the weights
    ``1 / Den^2`` of the previous iteration (Tao & Hu's iterative least squares) and a ridge term
    ``regularisation * trace(M^T W M) / 39`` on the normal equations (the 39 unknowns of an axis, on
    normalised coordinates), which keeps the nearly dependent denominator terms in check.

    Args:
        model: anything with ``image_size``, ``to_ground(pixel, height)`` and ``__call__(lonlath)``
            (a :class:`PushbroomCamera`).
        height_range: ``(h_min, h_max)`` ellipsoidal heights the RPC must serve (m); h_max > h_min.
        grid: image points per axis; layers: height layers (at least 3 for the cubic height terms).

    Returns:
        :class:`RPCFit` with the error on the fit points and on a check grid half a cell away.

    Examples:
        The RPC of a push-broom image looking 20 deg across and 15 deg along the track:

        >>> import photax as ptx
        >>> scene = ptx.pushbroom_scene(roll=20.0, pitch=-15.0, image_size=(2000, 2000))
        >>> fit = ptx.fit_rpc(scene.camera, scene.height_range)
        >>> fit.check_points, fit.check_max_error < 0.01  # px, between the grid's points and heights
        (1176, True)
        >>> type(fit.camera).__name__
        'RPCCamera'
    """
    h0, h1 = (float(v) for v in height_range)
    if not h1 > h0:
        raise ValueError(f"height_range: expected (h_min, h_max) with h_max > h_min, got {height_range}")
    if grid < 5 or layers < 3:
        raise ValueError("fit_rpc: grid needs at least 5 points per axis and layers at least 3 (the cubic terms)")
    w, lines = model.image_size
    cols, rows = np.linspace(0.0, w - 1.0, grid), np.linspace(0.0, lines - 1.0, grid)
    ground, pix = _grid_points(model, np.linspace(h0, h1, layers), cols, rows)
    if len(ground) < 0.9 * grid * grid * layers:
        raise ValueError(
            f"fit_rpc: the model took only {len(ground)} of {grid * grid * layers} grid points to the ground"
        )
    lo, hi = ground.min(0), ground.max(0)
    g_off, g_scale = (lo + hi) / 2.0, np.maximum((hi - lo) / 2.0, 1e-12)
    p_off = np.array([(w - 1) / 2.0, (lines - 1) / 2.0])
    p_scale = np.maximum(p_off, 0.5)
    m = np.asarray(rpc_terms(jnp.asarray((ground - g_off) / g_scale)))
    target = (pix - p_off) / p_scale
    coeffs = np.zeros((4, 20))
    iterations = 0
    for axis, (num_row, den_row) in ((1, (0, 1)), (0, (2, 3))):  # line, then sample (RPC00B row order)
        p = target[:, axis]
        design = np.concatenate([m, -p[:, None] * m[:, 1:]], 1)
        wts = np.ones(len(p))
        prev = None
        for it in range(1, max_iterations + 1):
            a = design * wts[:, None]
            normal = a.T @ a
            ridge = regularisation * np.trace(normal) / normal.shape[0]
            x = np.linalg.solve(normal + ridge * np.eye(len(normal)), a.T @ (p * wts))
            den = 1.0 + m[:, 1:] @ x[20:]
            wts = 1.0 / np.abs(den)
            iterations = max(iterations, it)
            if prev is not None and np.max(np.abs(x - prev)) < 1e-12:  # normalised coefficients, ~1
                break
            prev = x
        coeffs[num_row] = x[:20]
        coeffs[den_row] = np.concatenate([[1.0], x[20:]])
    offsets = np.array([g_off[0], g_off[1], g_off[2], p_off[0], p_off[1]])
    scales = np.array([g_scale[0], g_scale[1], g_scale[2], p_scale[0], p_scale[1]])
    rpc = RPCCamera(coeffs, offsets, scales, image_size=(w, lines))
    err = np.linalg.norm(np.asarray(rpc(jnp.asarray(ground))) - pix, axis=1)
    # check grid: half a cell away in the image, between the layers in height
    half_c, half_r = (cols[1] - cols[0]) / 2.0, (rows[1] - rows[0]) / 2.0
    dh = (h1 - h0) / (layers - 1)
    c_ground, c_pix = _grid_points(
        model, np.linspace(h0 + dh / 2, h1 - dh / 2, layers - 1), cols[:-1] + half_c, rows[:-1] + half_r
    )
    c_res = np.asarray(rpc(jnp.asarray(c_ground))) - c_pix
    c_err = np.linalg.norm(c_res, axis=1)
    return RPCFit(
        camera=rpc,
        rmse=float(np.sqrt(np.mean(err**2))),
        max_error=float(err.max()),
        check_rmse=float(np.sqrt(np.mean(c_err**2))),
        check_max_error=float(c_err.max()),
        points=len(ground),
        check_points=len(c_ground),
        iterations=iterations,
        regularisation=regularisation,
        check_ground=c_ground,
        check_pixel=c_pix,
        check_residuals=c_res,
    )
