"""Rotation maths (finray_jax/_rotation.py): hat/vee, exp/log on SO(3), planar frames."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from finray_jax._rotation import exp_so3, hat, log_so3, planar_angle, planar_frame, vee

# Tolerances: every quantity below is computed by a handful of float64 operations on O(1)
# numbers, so it is exact to a few ulps; 1e-13 leaves a margin of ~100 ulps.
EXACT = 1e-13

RNG = np.random.default_rng(20240611)
VECTORS = [RNG.normal(size=3) for _ in range(5)] + [np.array([1e-3, -2e-3, 5e-4])]


def _unit(v):
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("v", VECTORS)
def test_hat_is_cross_product_and_vee_inverts_it(v):
    w = RNG.normal(size=3)
    K = np.asarray(hat(jnp.asarray(v)))
    np.testing.assert_allclose(K, -K.T, rtol=0, atol=0)  # exactly skew
    np.testing.assert_allclose(K @ w, np.cross(v, w), rtol=0, atol=EXACT)
    np.testing.assert_allclose(np.asarray(vee(jnp.asarray(K))), v, rtol=0, atol=0)


def test_vee_takes_the_skew_part():
    S = RNG.normal(size=(3, 3))
    skew = 0.5 * (S - S.T)
    np.testing.assert_allclose(
        np.asarray(vee(jnp.asarray(S))), np.asarray(vee(jnp.asarray(skew))), atol=EXACT
    )
    np.testing.assert_allclose(np.asarray(hat(vee(jnp.asarray(S)))), skew, atol=EXACT)


@pytest.mark.parametrize("angle", [1e-9, 1e-5, 1e-2, 0.7, 2.0, 3.0])
def test_exp_so3_is_a_rotation_about_the_axis(angle):
    axis = _unit(np.array([0.3, -1.2, 0.8]))
    R = np.asarray(exp_so3(jnp.asarray(angle * axis)))
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=EXACT)
    assert abs(np.linalg.det(R) - 1.0) < EXACT
    # Closed form (Rodrigues): R = cos a I + sin a [k]x + (1 - cos a) k k^T.
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    expected = (
        np.cos(angle) * np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * np.outer(axis, axis)
    )
    np.testing.assert_allclose(R, expected, atol=EXACT)
    np.testing.assert_allclose(R @ axis, axis, atol=EXACT)  # the axis is fixed


@pytest.mark.parametrize("i", [0, 1, 2])
def test_exp_so3_about_a_basis_axis(i):
    a = 0.9
    c, s = np.cos(a), np.sin(a)
    R = np.asarray(exp_so3(jnp.asarray(a * np.eye(3)[i])))
    j, k = (i + 1) % 3, (i + 2) % 3  # right-handed: e_j -> c e_j + s e_k
    np.testing.assert_allclose(R[:, j], c * np.eye(3)[j] + s * np.eye(3)[k], atol=EXACT)
    np.testing.assert_allclose(R[:, k], -s * np.eye(3)[j] + c * np.eye(3)[k], atol=EXACT)


def test_exp_so3_smooth_at_zero():
    J = jax.jacfwd(exp_so3)(jnp.zeros(3))  # (3, 3, 3): d R_ab / d phi_i
    assert np.all(np.isfinite(np.asarray(J)))
    for i in range(3):
        np.testing.assert_allclose(np.asarray(J[..., i]), np.asarray(hat(jnp.eye(3)[i])), atol=0)
    # Second derivatives at 0 are finite too (Newton linearises through the exponential).
    H = jax.jacfwd(jax.jacfwd(exp_so3))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(H)))
    # ... and the switch to the Taylor branch is continuous: at the threshold
    # |phi|^2 = 1e-8 both branches agree to rounding.
    v = np.array([0.6, 0.0, 0.8]) * 1e-4
    for scale in (1 - 1e-9, 1 + 1e-9):
        R = np.asarray(exp_so3(jnp.asarray(scale * v)))
        th = scale * 1e-4
        K = hat(jnp.asarray(scale * v))
        exact = np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * (K @ K)
        np.testing.assert_allclose(R, np.asarray(exact), atol=1e-15)


@pytest.mark.parametrize("angle", [1e-12, 1e-7, 1e-3, 0.5, 1.5, 2.5, 3.0])
def test_log_inverts_exp(angle):
    axis = _unit(np.array([-0.4, 0.9, 0.2]))
    v = angle * axis
    got = np.asarray(log_so3(exp_so3(jnp.asarray(v))))
    # Relative to the angle: log is well conditioned below pi - 0.1 (sin(angle) >= 0.14).
    np.testing.assert_allclose(got, v, rtol=0, atol=1e-12 * max(angle, 1e-3))
    if angle > 1e-3:
        np.testing.assert_allclose(got, v, rtol=1e-12)


def test_exp_of_log_round_trip_on_random_rotations():
    for _ in range(5):
        v = RNG.normal(size=3)
        v *= 2.8 / np.linalg.norm(v) * RNG.uniform(0.05, 1.0)
        R = exp_so3(jnp.asarray(v))
        np.testing.assert_allclose(np.asarray(exp_so3(log_so3(R))), np.asarray(R), atol=EXACT)


@pytest.mark.parametrize("theta", [-2.0, -0.3, 0.0, 0.4, 1.2, 3.0])
def test_planar_frame_convention(theta):
    """_types.py: rotation about +y by theta; d3 = (sin, 0, cos), d1 = (cos, 0, -sin),
    d2 = +y, d1 = d2 x d3."""
    R = np.asarray(planar_frame(jnp.asarray(theta)))
    d1, d2, d3 = R[:, 0], R[:, 1], R[:, 2]
    np.testing.assert_allclose(d3, [np.sin(theta), 0.0, np.cos(theta)], atol=EXACT)
    np.testing.assert_allclose(d1, [np.cos(theta), 0.0, -np.sin(theta)], atol=EXACT)
    np.testing.assert_allclose(d2, [0.0, 1.0, 0.0], atol=0)
    np.testing.assert_allclose(np.cross(d2, d3), d1, atol=EXACT)
    # It is the exponential of theta about +y, and planar_angle recovers theta from d3.
    np.testing.assert_allclose(R, np.asarray(exp_so3(jnp.asarray([0.0, theta, 0.0]))), atol=EXACT)
    assert abs(float(planar_angle(jnp.asarray([d3[0], d3[2]]))) - theta) < EXACT


@pytest.mark.parametrize("v", VECTORS[:3])
def test_spatial_step_pulls_the_frame_back_to_so3(v):
    """SpatialRod.after_step: one Newton-Schulz step of the polar factor squares the drift
    from SO(3), moves R by no more than the drift, and leaves p, n, m alone."""
    from finray_jax._spatial_rod import SpatialRod

    R = np.asarray(exp_so3(jnp.asarray(v)))
    drift = 1e-5 * RNG.normal(size=(3, 3))
    rest = RNG.normal(size=9)
    y = jnp.concatenate(
        [jnp.asarray(rest[:3]), jnp.asarray(R + drift).reshape(9), jnp.asarray(rest[3:])]
    )
    out = np.asarray(SpatialRod.after_step(y, y))
    Rn = out[3:12].reshape(3, 3)
    before = np.abs((R + drift).T @ (R + drift) - np.eye(3)).max()
    after = np.abs(Rn.T @ Rn - np.eye(3)).max()
    assert before > 1e-6 and after < 10 * before**2
    assert np.abs(Rn - (R + drift)).max() < 2 * before
    np.testing.assert_array_equal(out[:3], rest[:3])
    np.testing.assert_array_equal(out[12:], rest[3:])
