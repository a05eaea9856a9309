"""Attitude angles, rotation matrices and axis-angle vectors.

Every matrix here is ``world_from_camera``: it turns a direction given in the
camera (image-space) frame into the ground frame, ``d_world = R @ d_camera``.
Its transpose takes ground offsets into the camera frame, which is what the
collinearity equations use.  The conventions are written out once in
``docs/conventions.md``.

Two angle conventions are supported and always chosen explicitly:

``"phi-omega-kappa"`` (default; primary axis Y, the classic Chinese and German
textbooks)
    ``R = R_phi @ R_omega @ R_kappa`` with the element formulas of docs/maths.md
    (``a3 = -sin(phi)cos(omega)``, ``b3 = -sin(omega)``, ...).  Angles are
    stored in the order (phi, omega, kappa).

``"omega-phi-kappa"`` (primary axis X; Wolf & DeWitt, ISPRS, most
aerial-triangulation exports)
    ``R = Rx(omega) @ Ry(phi) @ Rz(kappa)``, the transpose of Wolf & DeWitt's
    ``M = R_kappa R_phi R_omega``.  Angles are stored in the order
    (omega, phi, kappa).

Angles are radians.  The middle angle lies in [-pi/2, pi/2]; the other two in
(-pi, pi].
"""

from __future__ import annotations

import functools
from typing import Literal, get_args

import jax
import jax.numpy as jnp
from jax import Array

Convention = Literal["phi-omega-kappa", "omega-phi-kappa"]
CONVENTIONS: tuple[str, ...] = get_args(Convention)

# |cos(middle angle)| below this and the outer two angles are not separable.
_GIMBAL_COS = 1e-9


def check_convention(convention: str) -> str:
    """Return ``convention`` or raise a ValueError naming the valid ones."""
    if convention not in CONVENTIONS:
        raise ValueError(
            f"convention must be one of {CONVENTIONS}, got {convention!r}; photax never guesses the angle order."
        )
    return convention


def _stack33(*rows) -> Array:
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


# Jitted: called eagerly (reports, readers, notebooks) these functions dispatched
# 20-40 small XLA programs each, compiled one by one on first use (1.45 s for
# the axis-angle pair, 0.4 s jitted; derivatives 3.4 -> 1.3 s).
@functools.partial(jax.jit, static_argnames="convention")
def rotation_matrix(angles: Array, convention: Convention = "phi-omega-kappa") -> Array:
    """``world_from_camera`` rotation from attitude angles.

    Args:
        angles: ``(..., 3)`` radians, in the order the convention names:
            (phi, omega, kappa) or (omega, phi, kappa).
        convention: ``"phi-omega-kappa"`` or ``"omega-phi-kappa"``.

    Returns:
        ``(..., 3, 3)`` rotation matrices.

    Examples:
        A rotation of 90 degrees in kappa alone turns the image x axis onto the ground's Y axis:

        >>> import numpy as np
        >>> import photax as ptx
        >>> R = ptx.rotation_matrix(np.radians([0.0, 0.0, 90.0]))  # phi, omega, kappa
        >>> print(np.round(np.asarray(R), 6) + 0.0)
        [[ 0. -1.  0.]
         [ 1.  0.  0.]
         [ 0.  0.  1.]]
        >>> bool(np.allclose(np.asarray(R) @ np.asarray(R).T, np.eye(3)))  # orthonormal
        True
    """
    check_convention(convention)
    angles = jnp.asarray(angles)
    if angles.shape[-1:] != (3,):
        raise ValueError(f"angles must have shape (..., 3), got {angles.shape}")
    if convention == "phi-omega-kappa":
        phi, omega, kappa = angles[..., 0], angles[..., 1], angles[..., 2]
        sp, cp = jnp.sin(phi), jnp.cos(phi)
        so, co = jnp.sin(omega), jnp.cos(omega)
        sk, ck = jnp.sin(kappa), jnp.cos(kappa)
        # docs/maths.md, the textbook element formulas.
        return _stack33(
            (cp * ck - sp * so * sk, -cp * sk - sp * so * ck, -sp * co),
            (co * sk, co * ck, -so),
            (sp * ck + cp * so * sk, -sp * sk + cp * so * ck, cp * co),
        )
    omega, phi, kappa = angles[..., 0], angles[..., 1], angles[..., 2]
    so, co = jnp.sin(omega), jnp.cos(omega)
    sp, cp = jnp.sin(phi), jnp.cos(phi)
    sk, ck = jnp.sin(kappa), jnp.cos(kappa)
    # Transpose of Wolf & DeWitt (2014), eq. C-33.
    return _stack33(
        (cp * ck, -cp * sk, sp),
        (co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp),
        (so * sk - co * sp * ck, so * ck + co * sp * sk, co * cp),
    )


def angles_from_matrix_unchecked(matrix: Array, convention: Convention = "phi-omega-kappa") -> tuple[Array, Array]:
    """Angles from a rotation matrix, plus ``|cos(middle angle)|``.

    No gimbal-lock check: the caller decides what to do where the second
    return value is (near) zero.  See :func:`angles_from_matrix`.
    """
    check_convention(convention)
    m = jnp.asarray(matrix)
    if convention == "phi-omega-kappa":
        middle = jnp.arcsin(jnp.clip(-m[..., 1, 2], -1.0, 1.0))  # omega
        first = jnp.arctan2(-m[..., 0, 2], m[..., 2, 2])  # phi
        last = jnp.arctan2(m[..., 1, 0], m[..., 1, 1])  # kappa
    else:
        middle = jnp.arcsin(jnp.clip(m[..., 0, 2], -1.0, 1.0))  # phi
        first = jnp.arctan2(-m[..., 1, 2], m[..., 2, 2])  # omega
        last = jnp.arctan2(-m[..., 0, 1], m[..., 0, 0])  # kappa
    return jnp.stack([first, middle, last], axis=-1), jnp.abs(jnp.cos(middle))


def angles_from_matrix(matrix: Array, convention: Convention = "phi-omega-kappa") -> Array:
    """Attitude angles of a ``world_from_camera`` matrix.

    The inverse of :func:`rotation_matrix`.  Where the middle angle is +-pi/2
    (gimbal lock) the first and last angles are not defined separately and an
    error is raised (also under ``jit``, through ``eqx.error_if``).

    Args:
        matrix: ``(..., 3, 3)`` rotation matrices.
        convention: ``"phi-omega-kappa"`` or ``"omega-phi-kappa"``.

    Returns:
        ``(..., 3)`` radians in the convention's order.

    Examples:
        The angles back from their matrix, in either convention:

        >>> import numpy as np
        >>> import photax as ptx
        >>> angles = np.radians([2.0, -1.5, 30.0])
        >>> R = ptx.rotation_matrix(angles, "omega-phi-kappa")
        >>> print(np.round(np.degrees(np.asarray(ptx.angles_from_matrix(R, "omega-phi-kappa"))), 6))
        [ 2.  -1.5 30. ]
    """
    matrix = jnp.asarray(matrix)
    if matrix.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {matrix.shape}")
    angles, cos_middle = angles_from_matrix_unchecked(matrix, convention)
    middle = "omega" if convention == "phi-omega-kappa" else "phi"
    import equinox as eqx  # here: not on the import path of photax ortho (photax._pytree)

    return eqx.error_if(
        angles,
        cos_middle < _GIMBAL_COS,
        f"gimbal lock: {middle} is +-90 degrees, so the other two {convention} "
        "angles are not defined separately; use another convention or an "
        "axis-angle vector.",
    )


def convert_angles(angles: Array, source: Convention, target: Convention) -> Array:
    """Re-express attitude angles from one convention in the other.

    Examples:
        The same attitude in the other angle order: both give one rotation matrix.

        >>> import numpy as np
        >>> import photax as ptx
        >>> pok = np.radians([3.0, -2.0, 45.0])
        >>> opk = ptx.convert_angles(pok, "phi-omega-kappa", "omega-phi-kappa")
        >>> bool(np.allclose(ptx.rotation_matrix(pok), ptx.rotation_matrix(opk, "omega-phi-kappa")))
        True
    """
    return angles_from_matrix(rotation_matrix(angles, source), target)


def _skew(v: Array) -> Array:
    z = jnp.zeros_like(v[..., 0])
    return _stack33(
        (z, -v[..., 2], v[..., 1]),
        (v[..., 2], z, -v[..., 0]),
        (-v[..., 1], v[..., 0], z),
    )


@jax.jit
def axis_angle_to_matrix(rotvec: Array) -> Array:
    """Rodrigues' formula, with finite values and gradients at zero rotation.

    ``R = I + sin(t)/t K + (1 - cos t)/t^2 K^2`` with ``t = |rotvec|`` and
    ``K`` the cross-product matrix of ``rotvec``.  Near ``t = 0`` the two
    coefficients are replaced by their Taylor series; the double ``where``
    keeps NaN out of the unused branch's gradient (as jaxlie does).

    Args:
        rotvec: ``(..., 3)`` axis times angle in radians.

    Returns:
        ``(..., 3, 3)`` rotation matrices.

    Examples:
        A rotation vector of length pi/2 along z (Rodrigues' formula), and the identity at zero:

        >>> import numpy as np
        >>> import photax as ptx
        >>> R = ptx.axis_angle_to_matrix(np.array([0.0, 0.0, np.pi / 2]))
        >>> print(np.round(np.asarray(R), 6) + 0.0)
        [[ 0. -1.  0.]
         [ 1.  0.  0.]
         [ 0.  0.  1.]]
        >>> bool(np.allclose(ptx.axis_angle_to_matrix(np.zeros(3)), np.eye(3)))
        True
    """
    rotvec = jnp.asarray(rotvec)
    theta2 = jnp.sum(rotvec * rotvec, axis=-1)
    small = theta2 < 1e-8
    safe2 = jnp.where(small, 1.0, theta2)
    safe = jnp.sqrt(safe2)
    a = jnp.where(small, 1.0 - theta2 / 6.0, jnp.sin(safe) / safe)
    b = jnp.where(small, 0.5 - theta2 / 24.0, (1.0 - jnp.cos(safe)) / safe2)
    k = _skew(rotvec)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=k.dtype), k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


@jax.jit
def matrix_to_axis_angle(matrix: Array) -> Array:
    """Axis-angle vector of a rotation matrix (angle in [0, pi]).

    Through the unit quaternion (Shepperd's method, which picks the best
    conditioned of four formulas), then ``2 atan2(|v|, w) v/|v|`` with a
    Taylor series for small ``|v|``.

    Examples:
        The inverse of :func:`axis_angle_to_matrix`:

        >>> import numpy as np
        >>> import photax as ptx
        >>> v = np.array([0.1, -0.2, 0.3])
        >>> print(np.round(np.asarray(ptx.matrix_to_axis_angle(ptx.axis_angle_to_matrix(v))), 6))
        [ 0.1 -0.2  0.3]
    """
    m = jnp.asarray(matrix)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {m.shape}")
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    # Four candidate quaternions (w, x, y, z), each well conditioned when its
    # leading diagonal term is the largest.
    cands = jnp.stack(
        [
            jnp.stack(
                [1 + trace, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            jnp.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            jnp.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            jnp.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        axis=-2,
    )
    pick = jnp.argmax(jnp.stack([trace, m00, m11, m22], -1), axis=-1)
    q = jnp.take_along_axis(cands, pick[..., None, None], axis=-2)[..., 0, :]
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    q = jnp.where(q[..., :1] < 0, -q, q)  # w >= 0: angle in [0, pi]
    w, v = q[..., 0], q[..., 1:]
    n2 = jnp.sum(v * v, axis=-1)
    small = n2 < 1e-16
    n_safe = jnp.sqrt(jnp.where(small, 1.0, n2))
    w_safe = jnp.where(small, w, 1.0)
    scale = jnp.where(
        small,
        2.0 / w_safe - 2.0 * n2 / (3.0 * w_safe**3),
        2.0 * jnp.arctan2(n_safe, w) / n_safe,
    )
    return scale[..., None] * v
