"""Exterior orientation and the collinearity equations.

Ground -> image (docs/maths.md, with ``R = world_from_camera``)::

    x - x0 = -f [a1 dX + b1 dY + c1 dZ] / [a3 dX + b3 dY + c3 dZ]
    y - y0 = -f [a2 dX + b2 dY + c2 dZ] / [a3 dX + b3 dY + c3 dZ]

with ``(dX, dY, dZ) = (X - Xs, Y - Ys, Z - Zs)``; the bracketed sums are the
components of ``R^T d``, the ground offset in the camera frame.  Distortion is
applied on top (see :mod:`photax.camera`).

Image -> ground (monoplotting): the ray ``R (xn, yn, -1)`` from the
projection centre, intersected with a horizontal plane or, iteratively, with
a DEM.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from ._float64 import as_float64
from ._pytree import Module, field
from .camera import FrameCamera, distort, distortion_jacobian
from .dem import DEM
from .rotation import (
    Convention,
    angles_from_matrix_unchecked,
    check_convention,
    rotation_matrix,
)


class ExteriorOrientation(Module):
    """Projection centre and attitude of an image.

    Attributes:
        position: ``(..., 3)`` projection centre ``(Xs, Ys, Zs)`` in the
            ground frame (metres, or the ground CRS unit).
        angles: ``(..., 3)`` radians, in the order the convention names:
            (phi, omega, kappa) or (omega, phi, kappa).
        convention: ``"phi-omega-kappa"`` (default) or ``"omega-phi-kappa"``.

    Use :attr:`X` ... :attr:`kappa` for named access whatever the convention.
    A leading batch shape is allowed (e.g. from :func:`photax.resect_batch`).

    Examples:
        Position (X, Y, Z) and angles in radians; the rotation matrix is ``world_from_camera``:

        >>> import numpy as np
        >>> import photax as ptx
        >>> eo = ptx.ExteriorOrientation(position=[512300.0, 4103800.0, 450.0], angles=np.radians([1.2, -0.8, 35.0]))
        >>> eo.convention
        'phi-omega-kappa'
        >>> bool(np.allclose(eo.rotation, ptx.rotation_matrix(eo.angles)))
        True
    """

    position: Array
    angles: Array
    convention: str = field(static=True, default="phi-omega-kappa")

    def __init__(self, position, angles, convention: Convention = "phi-omega-kappa"):
        if not isinstance(position, jax.core.Tracer):  # a float32 position has lost digits: say so
            position = as_float64(position, "position", resolution=1e-3)  # a millimetre (of metres)
        self.position = jnp.asarray(position, dtype=float)
        self.angles = jnp.asarray(angles, dtype=float)
        self.convention = check_convention(convention)
        if self.position.shape[-1:] != (3,) or self.angles.shape[-1:] != (3,):
            raise ValueError(
                f"position and angles must have shape (..., 3), got {self.position.shape} and {self.angles.shape}"
            )

    @classmethod
    def from_rotation(cls, position, matrix, convention: Convention = "phi-omega-kappa"):
        """From a projection centre and a ``world_from_camera`` matrix."""
        from .rotation import angles_from_matrix

        return cls(position, angles_from_matrix(matrix, convention), convention)

    @property
    def rotation(self) -> Array:
        """``(..., 3, 3)`` ``world_from_camera`` matrix."""
        return rotation_matrix(self.angles, self.convention)  # type: ignore[arg-type]

    def _angle(self, name: str) -> Array:
        order = self.convention.split("-")
        return self.angles[..., order.index(name)]

    X = property(lambda self: self.position[..., 0], doc="Projection centre X (easting).")
    Y = property(lambda self: self.position[..., 1], doc="Projection centre Y (northing).")
    Z = property(lambda self: self.position[..., 2], doc="Projection centre Z (height).")
    phi = property(lambda self: self._angle("phi"), doc="phi, radians.")
    omega = property(lambda self: self._angle("omega"), doc="omega, radians.")
    kappa = property(lambda self: self._angle("kappa"), doc="kappa, radians.")

    def to_convention(self, convention: Convention) -> ExteriorOrientation:
        """The same orientation with angles in another convention.

        Raises where the target convention is in gimbal lock.
        """
        if convention == self.convention:
            return self
        return ExteriorOrientation.from_rotation(self.position, self.rotation, convention)

    def to_vector(self) -> Array:
        """``(..., 6)`` ``(X, Y, Z, a1, a2, a3)``, angles in convention order."""
        return jnp.concatenate([self.position, self.angles], axis=-1)

    @classmethod
    def from_vector(cls, vector, convention: Convention = "phi-omega-kappa"):
        vector = jnp.asarray(vector, dtype=float)
        return cls(vector[..., :3], vector[..., 3:], convention)

    @jax.jit
    def points_in_camera(self, ground_xyz: Array) -> Array:
        """``(n, 3)`` ground points -> camera frame (``R^T (X - Xs)``)."""
        d = jnp.asarray(ground_xyz, dtype=float) - self.position[..., None, :]
        return jnp.einsum("...ij,...ni->...nj", self.rotation, d)


def stack_exteriors(exterior) -> ExteriorOrientation:
    """One batched orientation ``(n_images, 3)`` from a batched one or a list.

    A list is converted to the first element's convention (elements whose
    angles are NaN -- unknown, to be initialised -- are taken as they are).

    Raises:
        ValueError: ``exterior`` is neither, or is not one orientation per image.
    """
    import numpy as np  # numpy side: this runs once per problem, never under jit

    if isinstance(exterior, ExteriorOrientation):
        eo = exterior
    else:
        eo_list = list(exterior)
        if not eo_list or not all(isinstance(e, ExteriorOrientation) for e in eo_list):
            raise ValueError("exterior must be an ExteriorOrientation (batched) or a list of them")
        conv = eo_list[0].convention
        eo_list = [e.to_convention(conv) if np.all(np.isfinite(np.asarray(e.angles))) else e for e in eo_list]
        eo = ExteriorOrientation(
            np.stack([np.asarray(e.position) for e in eo_list]), np.stack([np.asarray(e.angles) for e in eo_list]), conv
        )
    if eo.position.ndim != 2:
        raise ValueError(f"exterior must hold one orientation per image, shape (n_images, 3); got {eo.position.shape}")
    return eo


@jax.jit
def project(ground_xyz: Array, exterior: ExteriorOrientation, camera: FrameCamera) -> Array:
    """The collinearity equations: ground points -> image-plane coordinates.

    Vectorised, differentiable, and safe under ``jit`` / ``vmap``.

    Args:
        ground_xyz: ``(n, 3)`` ground coordinates.
        exterior: the image's exterior orientation.
        camera: the interior orientation.

    Returns:
        ``(n, 2)`` image-plane ``(x, y)`` in the camera's unit, y up.
        Points behind the camera give numbers too: check :func:`depth`.

    Examples:
        A vertical photo from 1000 m with f = 0.1 m: a point 100 m east of the nadir images at
        x = f * 100 / 1000 = 0.01 m (the collinearity equations' scale f / H):

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera(focal_length=0.1)
        >>> exterior = ptx.ExteriorOrientation(position=[0.0, 0.0, 1000.0], angles=[0.0, 0.0, 0.0])
        >>> print(np.round(np.asarray(ptx.project(np.array([[100.0, 0.0, 0.0], [0.0, -50.0, 0.0]]), exterior, camera)), 6) + 0.0)
        [[ 0.01  0.  ]
         [ 0.   -0.005]]
    """
    return camera.project(exterior.points_in_camera(ground_xyz))


def angle_axes(angles: Array, convention: Convention = "phi-omega-kappa") -> Array:
    """``(..., 3, 3)`` world-frame axes of the three angles: row ``k`` is
    ``w_k`` with ``dR/da_k = [w_k]x R`` (``R`` = world_from_camera,
    ``[w]x`` the cross-product matrix).

    ``R = A(a1) B(a2) C(a3)`` is a product of rotations about fixed axes
    ``e_k``, and ``d/da A = s [e]x A`` for a rotation about ``e`` by
    ``s a`` (``s = +-1``), so ``w_1 = s1 e1``, ``w_2 = s2 A e2`` and
    ``w_3 = s3 A B e3`` = the third column of ``R`` for both conventions:

    * phi-omega-kappa: ``R = Ry(-phi) Rx(omega) Rz(kappa)`` ->
      ``w = (0, -1, 0), (cos phi, 0, sin phi), R[:, 2]``;
    * omega-phi-kappa: ``R = Rx(omega) Ry(phi) Rz(kappa)`` ->
      ``w = (1, 0, 0), (0, cos omega, sin omega), R[:, 2]``.
    """
    check_convention(convention)
    angles = jnp.asarray(angles)
    return angle_axes_of(angles, rotation_matrix(angles, convention), convention == "phi-omega-kappa")


def angle_axes_of(angles: Array, rotation: Array, pok) -> Array:
    """:func:`angle_axes` with the convention as a (possibly traced) flag
    ``pok`` (True: phi-omega-kappa) and ``R`` given (resection's lanes carry
    the convention as data)."""
    c, s = jnp.cos(angles[..., 0]), jnp.sin(angles[..., 0])
    zero, one = jnp.zeros_like(c), jnp.ones_like(c)
    w1 = jnp.where(pok, jnp.stack([zero, -one, zero], -1), jnp.stack([one, zero, zero], -1))
    w2 = jnp.where(pok, jnp.stack([c, zero, s], -1), jnp.stack([zero, c, s], -1))
    return jnp.stack([w1, w2, rotation[..., :, 2]], axis=-2)


def collinearity_jacobian(
    ground_xyz: Array, position: Array, rotation: Array, axes: Array, camera: FrameCamera, *, wrt_ground: bool = True
) -> tuple[Array, Array, Array]:
    """The collinearity equations and their closed-form Jacobian.

    With ``d = X - C``, ``q = R^T d`` (camera frame), ``xn = -q_xy / q_z``,
    ``x = x0 + f D(xn)`` (``D`` the distortion)::

        dq/dC = -R^T,   dq/dX = R^T,   dq/da_k = R^T (d x w_k)
        dxn/dq = -1/q_z [[1, 0, xn], [0, 1, yn]]
        dx/dp = f D'(xn) dxn/dq dq/dp

    (``w_k`` from :func:`angle_axes`; ``D'`` is
    :meth:`FrameCamera.distortion_jacobian`.)

    Args:
        ground_xyz: ``(n, 3)`` ground points.
        position: ``(3,)`` projection centre.
        rotation: ``(3, 3)`` world_from_camera.
        axes: ``(3, 3)`` angle axes from :func:`angle_axes`.
        camera: the interior orientation.
        wrt_ground: False to leave out the ground point's columns.

    Returns:
        ``xy`` ``(n, 2)`` as :func:`project`; ``jacobian`` ``(n, 2, 9)``,
        columns ``(Xs, Ys, Zs, a1, a2, a3, X, Y, Z)`` (``(n, 2, 6)``
        without the ground point); ``q`` ``(n, 3)``
        the points in the camera frame (``-q_z`` is :func:`depth`).
    """
    return collinearity_rows(ground_xyz, position[None], rotation[None], axes[None], camera.focal_length[None],
                             camera.principal_point[None], camera.distortion[None], wrt_ground=wrt_ground)  # fmt: skip


def collinearity_rows(
    ground_xyz: Array, position: Array, rotation: Array, axes: Array, focal_length: Array, principal_point: Array,
    distortion: Array, *, wrt_ground: bool = True, dots: bool = False,
) -> tuple[Array, Array, Array]:  # fmt: skip
    """:func:`collinearity_jacobian` with the orientation and the camera given
    per point (bundle adjustment: one image and camera per observation) or
    once for all (leading axis of length 1 / no leading axis).

    Args:
        ground_xyz: ``(n, 3)``; position ``(n | 1, 3)``; rotation, axes
            ``(n | 1, 3, 3)``; focal_length ``(n | 1,)``;
            principal_point ``(n | 1, 2)``; distortion ``(n | 1, 5)``
            (:func:`photax.camera.distort`).
        axes: None for rotation increments about the camera's own axes
            (``R <- R Exp(da)``, bundle adjustment): then ``dq/da = [q]_x``.
        dots: how the two small matrix products are contracted, same
            numbers either way.  False (default): element-wise products and
            sums -- under ``vmap`` (resection, one image per batch member) XLA
            turns tiny matrix products into batched dots that run one small
            kernel per point on CPU (measured several times slower).  True:
            batched ``matmul`` -- faster when the rows themselves are the
            batch and there is no ``vmap`` (bundle adjustment: 2.5x faster
            on BAL problem-49-7776's 31,000 observations).
    """
    d = ground_xyz - position
    q = (d[:, None, :] @ rotation)[:, 0] if dots else jnp.sum(d[:, :, None] * rotation, axis=1)  # R^T d per row
    if axes is None:  # rotation increments about the camera's own axes: R^T (d x R e_k) = q x e_k
        dq_da = jnp.stack([jnp.cross(q, e[None, :]) for e in jnp.eye(3)], axis=-1)  # (n, 3, 3)
    else:
        dq_da = jnp.stack(
            [jnp.sum(jnp.cross(d, axes[:, k])[:, :, None] * rotation, axis=1) for k in range(3)], axis=-1
        )  # (n, 3, 3)
    xn = -q[:, :2] / q[:, 2:3]
    # dxn/dq = -1/q_z [[1, 0, xn], [0, 1, yn]] (xn = -q_x / q_z), so with J = f D'(xn):
    # dx/dq = -1/q_z [J[:, 0], J[:, 1], J xn] (columns), written out element-wise.
    f = focal_length
    jd = distortion_jacobian(xn, distortion)  # (n, 2, 2)
    g = -f / q[:, 2]
    dx_dq = jnp.stack([jd[:, :, 0], jd[:, :, 1], jd[:, :, 0] * xn[:, :1] + jd[:, :, 1] * xn[:, 1:]], axis=-1)
    dx_dq = g[:, None, None] * dx_dq  # (n, 2, 3)
    if dots:
        dx_dx, dx_da = dx_dq @ jnp.swapaxes(rotation, -1, -2), dx_dq @ dq_da
    else:
        dx_dx = jnp.sum(dx_dq[:, :, None, :] * rotation[:, None, :, :], axis=-1)
        dx_da = jnp.sum(dx_dq[:, :, :, None] * dq_da[:, None, :, :], axis=2)
    # dx/dX = dx/dq R^T = -dx/dC
    xy = principal_point + f[:, None] * distort(xn, distortion)
    return xy, jnp.concatenate([-dx_dx, dx_da, dx_dx] if wrt_ground else [-dx_dx, dx_da], axis=-1), q


def project_jacobian(ground_xyz: Array, exterior: ExteriorOrientation, camera: FrameCamera) -> tuple[Array, Array]:
    """:func:`project` and its closed-form Jacobian (:func:`collinearity_jacobian`).

    Returns ``xy`` ``(n, 2)`` and ``(n, 2, 9)`` derivatives with respect to
    ``(Xs, Ys, Zs, a1, a2, a3, X, Y, Z)``, angles in the exterior's
    convention order (radians).
    """
    ground = jnp.asarray(ground_xyz, dtype=float)
    rot = exterior.rotation
    axes = angle_axes(exterior.angles, exterior.convention)  # type: ignore[arg-type]
    xy, jac, _ = collinearity_jacobian(ground, exterior.position, rot, axes, camera)
    return xy, jac


def depth(ground_xyz: Array, exterior: ExteriorOrientation) -> Array:
    """``(n,)`` distance of each point in front of the camera along its axis.

    Positive in front of the camera, negative behind it.

    Examples:
        The distance along the optical axis: 1000 m below a vertical camera, whatever the offset:

        >>> import numpy as np
        >>> import photax as ptx
        >>> exterior = ptx.ExteriorOrientation(position=[0.0, 0.0, 1000.0], angles=[0.0, 0.0, 0.0])
        >>> print(np.round(np.asarray(ptx.depth(np.array([[0.0, 0.0, 0.0], [300.0, 400.0, 0.0]]), exterior)), 6))
        [1000. 1000.]
    """
    return -exterior.points_in_camera(ground_xyz)[..., 2]


def image_to_ground(
    image_xy: Array,
    exterior: ExteriorOrientation,
    camera: FrameCamera,
    height: float | Array | None = None,
    dem: DEM | None = None,
    *,
    iterations: int = 30,
    tol: float = 1e-4,
) -> Array:
    """Monoplotting: image points -> ground, on a height or a DEM.

    With ``height`` the ray is cut with the plane ``Z = height``.  With a
    ``dem`` the ray is cut iteratively: start at the DEM's mean height,
    then ``Z <- dem(X, Y)`` until the height changes by less than ``tol``.
    Points that do not converge in ``iterations`` steps, or whose ray leaves
    the DEM, are NaN.

    Args:
        image_xy: ``(n, 2)`` image-plane coordinates.
        exterior, camera: orientation of the image.
        height: scalar or ``(n,)`` ground height(s).
        dem: a :class:`photax.DEM`.

    Returns:
        ``(n, 3)`` ground coordinates.

    Examples:
        Monoplotting: an image point back onto a known height (the inverse of :func:`project`):

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera(focal_length=0.1)
        >>> exterior = ptx.ExteriorOrientation(position=[500.0, 200.0, 1000.0], angles=[0.01, -0.02, 0.3])
        >>> ground = np.array([[620.0, 150.0, 40.0]])
        >>> xy = ptx.project(ground, exterior, camera)
        >>> print(np.round(np.asarray(ptx.image_to_ground(xy, exterior, camera, height=40.0)), 6))
        [[620. 150.  40.]]
    """
    if (height is None) == (dem is None):
        raise ValueError("give exactly one of height= or dem=")
    direction = jnp.einsum("ij,nj->ni", exterior.rotation, camera.ray(image_xy))
    centre = exterior.position

    def on_plane(z):
        lam = (z - centre[2]) / direction[:, 2]
        pts = centre[None, :] + lam[:, None] * direction
        # A plane behind the camera (lam < 0) is not where the ray meets it.
        return jnp.where((lam > 0)[:, None], pts, jnp.nan)

    if dem is not None:
        z0 = jnp.full(direction.shape[0], jnp.nanmean(dem.heights))

        def body(carry):
            z, _, k = carry
            p = on_plane(z)
            z_new = dem.height(p[:, 0], p[:, 1])
            return z_new, jnp.abs(z_new - z), k + 1

        def cond(carry):
            _, step, k = carry
            return (k < iterations) & jnp.any(step > tol)

        z, step, _ = jax.lax.while_loop(cond, body, (z0, jnp.full_like(z0, jnp.inf), 0))
        pts = on_plane(z)
        return jnp.where((step <= tol)[:, None], pts, jnp.nan)
    z = jnp.broadcast_to(jnp.asarray(height, dtype=float), direction.shape[:1])
    return on_plane(z)


def look_at(
    position: Array, target: Array, kappa_up: Array | None = None, convention: Convention = "phi-omega-kappa"
) -> ExteriorOrientation:
    """An orientation at ``position`` whose optical axis points at ``target``.

    Convenient for synthetic scenes.  The camera's y axis is as close to the
    ground +Y as the viewing direction allows (north up), unless
    ``kappa_up`` gives another ground direction for it.

    Examples:
        An orientation that looks from a position at a target: the target images at the principal point.

        >>> import numpy as np
        >>> import photax as ptx
        >>> exterior = ptx.look_at(np.array([0.0, -500.0, 800.0]), np.array([100.0, 0.0, 0.0]))
        >>> camera = ptx.FrameCamera(focal_length=0.05)
        >>> print(np.round(np.asarray(ptx.project(np.array([[100.0, 0.0, 0.0]]), exterior, camera)), 9) + 0.0)
        [[0. 0.]]
    """
    position = jnp.asarray(position, dtype=float)
    back = position - jnp.asarray(target, dtype=float)
    z = back / jnp.linalg.norm(back)  # camera +z points away from the scene
    up = jnp.array([0.0, 1.0, 0.0]) if kappa_up is None else jnp.asarray(kappa_up, dtype=float)
    x = jnp.cross(up, z)
    x = x / jnp.linalg.norm(x)
    y = jnp.cross(z, x)
    matrix = jnp.stack([x, y, z], axis=-1)
    angles, _ = angles_from_matrix_unchecked(matrix, convention)
    return ExteriorOrientation(position, angles, convention)
