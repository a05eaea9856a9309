"""Rotations: textbook formulas, scipy as the independent reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import photax as ptx
from photax.rotation import angles_from_matrix_unchecked

angle = st.floats(-np.pi + 1e-6, np.pi, allow_nan=False)
middle = st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, allow_nan=False)


def test_phi_omega_kappa_is_y_x_z_composition():
    # DESIGN.md: R = R_phi R_omega R_kappa, R_phi about Y with the textbook's
    # sign (a3 = -sin phi cos omega), i.e. scipy's "YXZ" with phi negated.
    phi, omega, kappa = 0.3, -0.2, 1.1
    ours = ptx.rotation_matrix(jnp.array([phi, omega, kappa]))
    ref = Rotation.from_euler("YXZ", [-phi, omega, kappa]).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-15)


def test_omega_phi_kappa_matches_wolf_m_transposed():
    # Wolf & DeWitt: M = R_kappa R_phi R_omega (world -> image); ours is M^T,
    # scipy's intrinsic "XYZ".
    omega, phi, kappa = 0.1, 0.25, -2.0
    ours = ptx.rotation_matrix(jnp.array([omega, phi, kappa]), "omega-phi-kappa")
    ref = Rotation.from_euler("XYZ", [omega, phi, kappa]).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-15)
    # Wolf's m31 = sin(phi) is our R[0, 2].
    assert ours[0, 2] == pytest.approx(np.sin(phi))


@pytest.mark.parametrize("convention", ["phi-omega-kappa", "omega-phi-kappa"])
@settings(max_examples=200, deadline=None)
@given(a=angle, m=middle, c=angle)
def test_angles_round_trip(convention, a, m, c):
    angles = jnp.array([a, m, c])
    back = ptx.angles_from_matrix(ptx.rotation_matrix(angles, convention), convention)
    # compare modulo 2 pi
    np.testing.assert_allclose(np.angle(np.exp(1j * (np.asarray(back) - np.asarray(angles)))), 0, atol=1e-9)


@pytest.mark.parametrize("convention", ["phi-omega-kappa", "omega-phi-kappa"])
def test_gimbal_lock_raises(convention):
    angles = jnp.array([0.3, np.pi / 2, 0.2])
    with pytest.raises(Exception, match="gimbal lock"):
        ptx.angles_from_matrix(ptx.rotation_matrix(angles, convention), convention)


def test_unknown_convention_is_refused():
    with pytest.raises(ValueError, match="never guesses"):
        ptx.rotation_matrix(jnp.zeros(3), "kappa-phi-omega")


def test_convert_between_conventions_keeps_the_matrix():
    pok = jnp.array([0.2, -0.4, 2.5])
    opk = ptx.convert_angles(pok, "phi-omega-kappa", "omega-phi-kappa")
    np.testing.assert_allclose(ptx.rotation_matrix(opk, "omega-phi-kappa"), ptx.rotation_matrix(pok), atol=1e-14)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3))
def test_axis_angle_matches_scipy(v):
    v = np.asarray(v)
    if np.linalg.norm(v) > np.pi - 1e-6:
        v = v / np.linalg.norm(v) * (np.pi - 1e-3)
    R = ptx.axis_angle_to_matrix(jnp.asarray(v))
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(ptx.matrix_to_axis_angle(R), v, atol=1e-9)


def test_axis_angle_near_pi_and_batched():
    v = np.array([[0.0, 0.0, np.pi - 1e-9], [1e-12, 0, 0], [0.5, -0.3, 0.1]])
    back = ptx.matrix_to_axis_angle(ptx.axis_angle_to_matrix(jnp.asarray(v)))
    np.testing.assert_allclose(back, v, atol=1e-7)


def test_gradients_finite_at_zero_rotation():
    f = lambda v: jnp.sum(ptx.axis_angle_to_matrix(v) @ jnp.array([1.0, 2.0, 3.0]))
    g = jax.grad(f)(jnp.zeros(3))
    assert np.all(np.isfinite(g))
    # d(R p)/dv at identity is -[p]x: sum over rows of [v]x p = v x p ...
    np.testing.assert_allclose(g, np.cross([1.0, 2.0, 3.0], np.ones(3)), atol=1e-12)
    jac = jax.jacobian(ptx.matrix_to_axis_angle)(jnp.eye(3))
    assert np.all(np.isfinite(jac))


def test_unchecked_reports_cos_of_middle_angle():
    _, c = angles_from_matrix_unchecked(ptx.rotation_matrix(jnp.array([0.0, 0.5, 0.0])))
    assert float(c) == pytest.approx(np.cos(0.5))
