"""The planar Cosserat rod model: unknowns (x, z, theta, nx, nz, my) in the x-z plane."""

import math
from typing import ClassVar

import jax.numpy as jnp

from ._abstract_rod import AbstractRodModel, stiffness_at, stiffness_rows
from ._objects import rsqrt
from ._rotation import planar_frame


class PlanarRod(AbstractRodModel):
    """Planar Cosserat rod in the x-z plane: unknowns (x, z, theta, nx, nz, my); the
    integrated state appends (cos theta, sin theta).

    Carrying the frame's two numbers, as the 3-D model carries R, keeps trigonometry out of
    the rhs (cos' = -sin theta', sin' = cos theta'): the Runge-Kutta stages need only
    products (a sine and a cosine per stage cost as much as the rest of a planar step on
    the CPU). After each step (`after_step`) the pair is reset to the cosine and sine of the
    integrated theta, by turning the previous step's pair through the step's angle (a
    short polynomial, `_turn`): it never drifts from theta or off the unit circle, and the
    tip of ref-A is as accurate as with trigonometric stages (relative error at 10 steps
    per segment 5e-6 on L2 and 2.5e-7 on L3; trigonometric stages give 6.3e-6 and 8.5e-7).

    Parameters q = (length, rigid, fx, fz, u2*, then (kGA, EA, EI) per stiffness sample),
    where EI is the in-plane bending stiffness (about d2 = y) and (fx, fz) the distributed
    force per length.
    """

    name: ClassVar[str] = "planar"
    n_unknown: ClassVar[int] = 6
    n_full: ClassVar[int] = 8
    n_stiff: ClassVar[int] = 3
    n_head: ClassVar[int] = 5
    rotation_slice: ClassVar[slice] = slice(2, 3)
    position_slice: ClassVar[slice] = slice(0, 2)

    def pack(self, table):
        head = jnp.stack(
            [
                table.length,
                table.rigid,
                table.force[:, 0],
                table.force[:, 2],
                table.precurvature[:, 1],
            ],
            axis=-1,
        )
        stiff = stiffness_rows(self, table, (0, 2, 4))
        return jnp.concatenate([head, stiff, table.contact], axis=-1)

    def rhs(self, tau, y, q):
        x, z, th, nx, nz, my, c, s = y
        if self.contact is not None:
            # A stage's (cos, sin) is a linear combination, not a unit vector: far from a
            # root a stiff contact penalty can feed it back until it overflows. Unit length
            # keeps every state finite (so only with contact).
            unit = rsqrt(c * c + s * s)
            c, s = c * unit, s * unit
        u2s = q[4]
        kga, ea, ei = stiffness_at(self, self.split(q)[0], tau)
        n1 = c * nx - s * nz
        n3 = s * nx + c * nz
        # Times the compliances: the forward-mode tangents then cost products, not
        # divisions (a faster pass for the segment Jacobians).
        v1 = n1 * (1.0 / kga)
        v3 = 1.0 + n3 * (1.0 / ea)
        dx = c * v1 + s * v3
        dz = -s * v1 + c * v3
        dth = my * (1.0 / ei) + u2s
        fx, fz, ly = self.contact_at(q, x, z, s, c, tau)
        dmy = -(dz * nx - dx * nz) - ly
        return jnp.stack([dx, dz, dth, -(q[2] + fx), -(q[3] + fz), dmy, -s * dth, c * dth])

    @staticmethod
    def rigid_transport(y, q):
        x, z, th, nx, nz, my, tz, tx = y
        r, fx, fz = q[1], q[2], q[3]
        # n(r) = n0 - f r;  m(r) = m0 - t x (n0 r - f r^2 / 2)  (y-component)
        ax = nx * r - 0.5 * fx * r * r
        az = nz * r - 0.5 * fz * r * r
        return jnp.stack(
            [
                x + tx * r,
                z + tz * r,
                th,
                nx - fx * r,
                nz - fz * r,
                my - (tz * ax - tx * az),
                tz,
                tx,
            ]
        )

    @staticmethod
    def after_step(y0, y1):
        """(cos, sin) of the step's end turned from its start's: exactly theta's again."""
        c, s = _turn((y0[2], y0[6], y0[7]), y1[2])
        return jnp.concatenate([y1[:6], jnp.stack([c, s])])

    def tangent_basis(self, y):
        """A turn d(theta) also moves (cos, sin) by (-sin, cos) d(theta)."""
        E = jnp.eye(8, 6, dtype=y.dtype)
        E = E.at[6, 2].set(-y[7]).at[7, 2].set(y[6])
        return E[:, 2:] if self.translation_free else E

    def tangent_coords(self, y, dy):
        return dy[2:6] if self.translation_free else dy[:6]

    def rigid_start_tangent(self, y0, q):
        _, _, _, nx, nz, _, tz, tx = y0
        zero = jnp.zeros_like(nx)
        return jnp.stack([tx, tz, zero, -q[2], -q[3], -(tz * nx - tx * nz), zero, zero])

    # --- accessors on full states ---
    @staticmethod
    def full_from_unknown(y, theta_ref):
        del theta_ref
        return jnp.concatenate([y, jnp.stack([jnp.cos(y[2]), jnp.sin(y[2])])])

    @staticmethod
    def position(y):
        return jnp.stack([y[0], jnp.zeros_like(y[0]), y[1]])

    @staticmethod
    def frame(y):
        return planar_frame(y[2])

    @staticmethod
    def force(y):
        return jnp.stack([y[3], jnp.zeros_like(y[3]), y[4]])

    @staticmethod
    def moment(y):
        return jnp.stack([jnp.zeros_like(y[5]), y[5], jnp.zeros_like(y[5])])

    # --- residual blocks (scaled by length L and force F) ---
    @staticmethod
    def kinematic_error(ya, yb, dtheta, L):
        """Position and orientation of b minus those of a (a turned by dtheta)."""
        return jnp.stack([(yb[0] - ya[0]) / L, (yb[1] - ya[1]) / L, yb[2] - ya[2] - dtheta])

    @staticmethod
    def position_rows(y, point, L):
        return jnp.stack([(y[0] - point[0]) / L, (y[1] - point[2]) / L])

    @staticmethod
    def orientation_rows(y, theta):
        return jnp.stack([y[2] - theta])

    @staticmethod
    def hinge_rows(y, theta, F, L):
        """A hinge about y: free rotation in the plane, zero moment about y."""
        del theta
        return jnp.stack([y[5]]) / (F * L)

    @staticmethod
    def force_rows(force, F):
        return jnp.stack([force[0], force[2]]) / F

    @staticmethod
    def moment_rows(moment, F, L):
        return jnp.stack([moment[1]]) / (F * L)

    @staticmethod
    def unknown_scale(L, F):
        return jnp.stack([L, L, jnp.ones_like(L), F, F, F * L])

    @staticmethod
    def undeformed_unknown(point, theta):
        z = jnp.zeros_like(theta)
        return jnp.stack([point[0], point[2], theta, z, z, z])


# Taylor coefficients of cos and sin in d^2, to d^14 and d^15: below 5e-14 relative for
# |d| <= 1 rad, and far below round-off for the < 0.1 rad a step turns at a converged state.
_COS = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(8))
_SIN = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(8))


def _horner(coefficients, u):
    acc = coefficients[-1]
    for c in coefficients[-2::-1]:
        acc = c + u * acc
    return acc


def _turn(anchor, theta):
    """(cos theta, sin theta) from anchor = (theta0, cos theta0, sin theta0), theta close
    to theta0: the angle-addition formulas with polynomial cos and sin of the difference.

    A difference beyond 1 rad (a frame turning by more than a radian within one step, which
    only a wild Newton iterate does) is clipped: its cos and sin stay bounded and finite."""
    th0, c0, s0 = anchor
    d = jnp.clip(theta - th0, -1.0, 1.0)
    u = d * d
    cd, sd = _horner(_COS, u), d * _horner(_SIN, u)
    return c0 * cd - s0 * sd, s0 * cd + c0 * sd
