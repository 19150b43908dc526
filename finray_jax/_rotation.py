"""Rotation maths: hat/vee, Rodrigues' exponential, frame mismatch, planar frames."""

import jax.numpy as jnp
from jaxtyping import Array, Float


def hat(v: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """Skew-symmetric matrix with hat(a) b = a x b."""
    x, y, z = v[0], v[1], v[2]
    zero = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([zero, -z, y]), jnp.stack([z, zero, -x]), jnp.stack([-y, x, zero])])


def vee(S: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """Inverse of `hat` applied to the skew part of S."""
    return 0.5 * jnp.stack([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])


def _safe_sq(phi):
    return jnp.sum(phi * phi)


def exp_so3(phi: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """Rodrigues' formula, smooth (and differentiable) through phi = 0."""
    th2 = _safe_sq(phi)
    small = th2 < 1e-8
    th2_safe = jnp.where(small, 1.0, th2)
    th = jnp.sqrt(th2_safe)
    a = jnp.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, jnp.sin(th) / th)
    b = jnp.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - jnp.cos(th)) / th2_safe)
    K = hat(phi)
    return jnp.eye(3, dtype=phi.dtype) + a * K + b * (K @ K)


def log_so3(R: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """Rotation vector of R (angle below pi)."""
    c = jnp.clip(0.5 * (jnp.trace(R) - 1.0), -1.0, 1.0)
    th = jnp.arccos(c)
    s = jnp.sin(th)
    small = s < 1e-8
    factor = jnp.where(small, 1.0 + th * th / 6.0, th / jnp.where(small, 1.0, s))
    return factor * vee(R)


def frame_mismatch(Ra: Float[Array, "3 3"], Rb: Float[Array, "3 3"]) -> Float[Array, "3"]:
    """A smooth 3-vector that vanishes when Ra == Rb (sine of the relative rotation)."""
    return vee(Ra.T @ Rb)


def planar_frame(theta) -> Float[Array, "3 3"]:
    """Frame rotated about +y by theta: columns d1, d2, d3."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.stack([jnp.stack([c, z, s]), jnp.stack([z, o, z]), jnp.stack([-s, z, c])])


def planar_angle(d3_xz: Float[Array, "2"]):
    """theta of an in-plane tangent given as (x, z)."""
    return jnp.arctan2(d3_xz[0], d3_xz[1])
