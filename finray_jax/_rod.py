"""Static Cosserat rods: the planar and the 3-D model, and the segment flow.

A *segment* is a piece of one beam between two junctions or load points. Its start state
is an unknown of the shooting problem; its flow maps that start state to the end state.
Every segment carries a parameter row q (length, rigid length, stiffnesses, distributed
force, precurvature). The first `rigid` millimetres of a segment are held rigid (inside an
adaptor clamp) and are transported in closed form; the rest is integrated at fixed steps
with a diffrax Runge-Kutta solver.

The segment flow has a custom JVP: each segment's own small Jacobian (state and parameter
columns) is computed once per evaluation by forward mode, and tangents are pushed through
it with a matrix product. Newton's Jacobian then costs one batched forward pass instead of
one re-integration per unknown, and reverse mode works because the rule is linear in the
tangents. Only the start state's own directions are integrated: a 3-D frame turns in three
ways (not nine matrix entries), and without contact a translation of the start translates
the end (no integration needed): 4 of 6 directions planar, 9 of 18 in 3-D.
"""

import functools
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._contact import ContactSpec, contact_load
from ._integrator import integrate
from ._objects import rsqrt
from ._rotation import exp_so3, frame_mismatch, hat, planar_frame, vee

# Sample points (in the flexible part of a segment, tau in [0, 1]) of a varying section.
TAPER_NODES = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])


def _lagrange_weights(tau):
    """Cubic Lagrange weights at TAPER_NODES: exact for stiffnesses cubic in tau."""
    x = TAPER_NODES
    w = []
    for i in range(4):
        wi = 1.0
        for j in range(4):
            if j != i:
                wi = wi * (tau - x[j]) / (x[i] - x[j])
        w.append(wi)
    return jnp.stack(w)


# --------------------------------------------------------------------------------------
# The two rod models. Both describe the same physics; the planar one keeps
# (x, z, theta, nx, nz, my) and the spatial one (p, R, n, m).
# --------------------------------------------------------------------------------------


class AbstractRodModel(eqx.Module):
    """Interface of a rod model (a family of interchangeable implementations).

    tapered: the section varies along s; each segment then carries its stiffnesses at the
    four TAPER_NODES and the rhs interpolates them (static: it fixes the parameter size).
    """

    tapered: bool = eqx.field(static=True, default=False)
    contact: ContactSpec | None = eqx.field(static=True, default=None)
    name: ClassVar[str]
    n_unknown: ClassVar[int]  # unknowns per segment start state
    n_full: ClassVar[int]  # integrated state size
    n_stiff: ClassVar[int]  # stiffness entries per sample
    n_head: ClassVar[int]  # parameters before the stiffness samples
    rotation_slice: ClassVar[slice]  # the rotation part of a segment's unknowns
    position_slice: ClassVar[slice]  # the position part of a full state

    def split(self, q):
        """(stiffness samples, contact columns) of a parameter row."""
        k = self.n_stiff * (4 if self.tapered else 1)
        return q[self.n_head : self.n_head + k], q[self.n_head + k :]

    @property
    def has_contact_law(self) -> bool:
        """Whether the rhs evaluates a contact law: a contact layout that is not the
        law-free one of the far segments (`ContactSpec.free`)."""
        return self.contact is not None and not self.contact.empty

    def contact_at(self, q, x, z, tx, tz, tau):
        """Contact force (fx, fz) and moment l_y per length at centreline point (x, z)
        with unit tangent (tx, tz); plain zeros without contact (no ops traced)."""
        if not self.has_contact_law:
            return 0.0, 0.0, 0.0
        return contact_load(self.contact, self.split(q)[1], x, z, tx, tz, tau)

    @staticmethod
    def after_step(y0, y1):
        """The state after a Runge-Kutta step from y0 to y1 (a model may re-project it)."""
        return y1

    # --- directions of a start state that the segment flow must be differentiated in ---
    @property
    def translation_free(self) -> bool:
        """Without contact the flow commutes with translations: d(end)/d(start position)
        is the identity on the position and zero elsewhere, so it needs no integration."""
        return not self.has_contact_law

    def tangent_basis(self, y):
        """(n_full, k) directions spanning every tangent of the start state y (position
        directions left out when translation_free)."""
        raise NotImplementedError

    def tangent_coords(self, y, dy):
        """(k,) coordinates of a tangent dy at y in `tangent_basis(y)`."""
        raise NotImplementedError

    def rigid_start_tangent(self, y0, q):
        """The start-state tangent that moves `rigid_transport`'s output as a longer rigid
        part does: d rigid_transport(y0, q) / d q[1] = D_y0 rigid_transport . this (the
        position along the tangent t, the force by -f, the moment by -t x n0)."""
        raise NotImplementedError


class PlanarRod(AbstractRodModel):
    """Planar Cosserat rod in the x-z plane: unknowns (x, z, theta, nx, nz, my); the
    integrated state appends (cos theta, sin theta).

    Carrying the frame's two numbers, as the 3-D model carries R, keeps trigonometry out of
    the rhs (cos' = -sin theta', sin' = cos theta'): the Runge-Kutta stages need only
    products (a sine and a cosine per stage were half the cost of a planar step on the
    CPU). After each step (`after_step`) the pair is reset to the cosine and sine of the
    integrated theta, by turning the previous step's pair through the step's angle (a
    short polynomial, `_turn`): it never drifts from theta or off the unit circle, and the
    tip of ref-A is as accurate as with trigonometric stages (relative error at 10 steps
    per segment 5e-6 on L2 and 2.5e-7 on L3, against 6.3e-6 and 8.5e-7).

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
        stiff = _stiffness_rows(self, table, (0, 2, 4))
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
        kga, ea, ei = _stiffness_at(self, self.split(q)[0], tau)
        n1 = c * nx - s * nz
        n3 = s * nx + c * nz
        # Times the compliances: the forward-mode tangents then cost products, not
        # divisions (the segment Jacobians' pass 13 % faster).
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


class SpatialRod(AbstractRodModel):
    """3-D Cosserat rod: state (p, R, n, m) with R stored row-major (18 numbers).

    The start frame is an unknown rotation vector phi relative to the segment's undeformed
    frame: R0 = R_ref exp(hat(phi)). Parameters q = (length, rigid, f (3), u* (3), then
    (kGA1, kGA2, EA, EI1, EI2, GJ) per stiffness sample).
    """

    name: ClassVar[str] = "spatial"
    n_unknown: ClassVar[int] = 12
    n_full: ClassVar[int] = 18
    n_stiff: ClassVar[int] = 6
    n_head: ClassVar[int] = 8
    rotation_slice: ClassVar[slice] = slice(3, 6)
    position_slice: ClassVar[slice] = slice(0, 3)

    def pack(self, table):
        head = [table.length[:, None], table.rigid[:, None], table.force, table.precurvature]
        stiff = _stiffness_rows(self, table, range(6))
        return jnp.concatenate(head + [stiff, table.contact], axis=-1)

    def rhs(self, tau, y, q):
        R = y[3:12].reshape(3, 3)
        n, m = y[12:15], y[15:18]
        ustar = q[5:8]
        k = _stiffness_at(self, self.split(q)[0], tau)
        kse, kbt = k[0:3], k[3:6]
        # Products written out elementwise: XLA's CPU backend runs batched 3x3 matmuls
        # (these states are vmapped over segments and tangents) many times slower.
        v = _dot(R.T, n) / kse + jnp.array([0.0, 0.0, 1.0])
        u = _dot(R.T, m) / kbt + ustar
        dp = _dot(R, v)
        dR = jnp.cross(R, u)  # row i of R hat(u) is (row i of R) x u
        f, mp = q[2:5], -jnp.cross(dp, n)
        if self.has_contact_law:
            fx, fz, ly = self.contact_at(q, y[0], y[2], R[0, 2], R[2, 2], tau)
            zero = jnp.zeros_like(ly)
            f, mp = f + jnp.stack([fx, zero, fz]), mp - jnp.stack([zero, ly, zero])
        return jnp.concatenate([dp, dR.reshape(9), -f, mp])

    @staticmethod
    def after_step(y0, y1):
        """R pulled back toward SO(3) after each step: one Newton-Schulz step of the polar
        factor, R (3 I - R^T R) / 2 (no square root; the drift is squared).

        Runge-Kutta steps R' = R hat(u) as nine numbers and leaves SO(3) by its
        truncation error. On ref-A at 10 steps the re-projection cut the tip's error
        (against a 40-step solve) from 1.6e-4 to 9.6e-6 under L2 and from 1.4e-6 to
        2.4e-7 under L3, as accurate as the planar model's exactly turned frame."""
        del y0
        R = y1[3:12].reshape(3, 3)
        RtR = sum(R[k][:, None] * R[k][None, :] for k in range(3))  # (written out, as
        RRtR = sum(R[:, k : k + 1] * RtR[k][None, :] for k in range(3))  # in `rhs`)
        R = 1.5 * R - 0.5 * RRtR
        return jnp.concatenate([y1[0:3], R.reshape(9), y1[12:]])

    @staticmethod
    def rigid_transport(y, q):
        p, Rf = y[0:3], y[3:12]
        n, m = y[12:15], y[15:18]
        r, f = q[1], q[2:5]
        t = Rf.reshape(3, 3)[:, 2]
        a = n * r - 0.5 * f * r * r
        return jnp.concatenate([p + t * r, Rf, n - f * r, m - jnp.cross(t, a)])

    def tangent_basis(self, y):
        """Frame tangents are R hat(w): three directions instead of nine."""
        R = y[3:12].reshape(3, 3)
        e = jnp.eye(3, dtype=y.dtype)
        turn = jnp.stack([(R @ hat(e[k])).reshape(9) for k in range(3)], axis=1)
        E = jax.scipy.linalg.block_diag(e, turn, jnp.eye(6, dtype=y.dtype))
        return E[:, 3:] if self.translation_free else E

    def tangent_coords(self, y, dy):
        A = y[3:12].reshape(3, 3).T @ dy[3:12].reshape(3, 3)
        w = vee(0.5 * (A - A.T))
        d = jnp.concatenate([dy[0:3], w, dy[12:18]])
        return d[3:] if self.translation_free else d

    def rigid_start_tangent(self, y0, q):
        t, n = y0[3:12].reshape(3, 3)[:, 2], y0[12:15]
        return jnp.concatenate([t, jnp.zeros(9, y0.dtype), -q[2:5], -jnp.cross(t, n)])

    @staticmethod
    def full_from_unknown(y, theta_ref):
        R = planar_frame(theta_ref) @ exp_so3(y[3:6])
        return jnp.concatenate([y[0:3], R.reshape(9), y[6:12]])

    @staticmethod
    def position(y):
        return y[0:3]

    @staticmethod
    def frame(y):
        return y[3:12].reshape(3, 3)

    @staticmethod
    def force(y):
        return y[12:15]

    @staticmethod
    def moment(y):
        return y[15:18]

    @staticmethod
    def kinematic_error(ya, yb, dtheta, L):
        Ra = ya[3:12].reshape(3, 3) @ planar_frame(dtheta)
        Rb = yb[3:12].reshape(3, 3)
        return jnp.concatenate([(yb[0:3] - ya[0:3]) / L, frame_mismatch(Ra, Rb)])

    @staticmethod
    def position_rows(y, point, L):
        return (y[0:3] - point) / L

    @staticmethod
    def orientation_rows(y, theta):
        return frame_mismatch(planar_frame(theta), y[3:12].reshape(3, 3))

    @staticmethod
    def hinge_rows(y, theta, F, L):
        """A hinge about world y: rotations about x and z held, zero moment about y."""
        mis = frame_mismatch(planar_frame(theta), y[3:12].reshape(3, 3))
        return jnp.stack([mis[0], mis[2], y[16] / (F * L)])

    @staticmethod
    def force_rows(force, F):
        return force / F

    @staticmethod
    def moment_rows(moment, F, L):
        return moment / (F * L)

    @staticmethod
    def unknown_scale(L, F):
        o = jnp.ones_like(L)
        return jnp.stack([L, L, L, o, o, o, F, F, F, F * L, F * L, F * L])

    @staticmethod
    def undeformed_unknown(point, theta):
        z = jnp.zeros_like(theta)
        return jnp.concatenate([point, jnp.stack([z, z, z, z, z, z, z, z, z])])


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


def _dot(A, x):
    """A @ x for a 3x3 A, as elementwise products and sums."""
    return A[:, 0] * x[0] + A[:, 1] * x[1] + A[:, 2] * x[2]


def rod_model(mode: str, tapered: bool = False, contact=None) -> AbstractRodModel:
    return {"planar": PlanarRod, "spatial": SpatialRod}[mode](tapered=tapered, contact=contact)


def _stiffness_rows(model, table, columns):
    """(S, samples * n_stiff) stiffness part of the parameter rows."""
    k = table.stiffness[:, :, list(columns)]  # (S, 4, n_stiff): samples at TAPER_NODES
    if not model.tapered:
        k = k[:, :1]
    return k.reshape(k.shape[0], -1)


def _stiffness_at(model, flat, tau):
    if not model.tapered:
        return flat
    samples = flat.reshape(4, model.n_stiff)
    return _lagrange_weights(tau) @ samples


# --------------------------------------------------------------------------------------
# Segment flow
# --------------------------------------------------------------------------------------


def segment_trajectories(model, integrator, Y0, Q):
    """States at the n+1 step points of every segment: (S, steps + 1, n_full).

    The first point is the state after the rigid part (the clamp exit), which equals the
    start for a segment without a rigid part.
    """
    return jax.vmap(lambda y, q: integrate(model, integrator, y, q, True))(Y0, Q)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def segment_flow(model, integrator, Y0, Q):
    """End states of all segments: (S, n_full)."""
    return jax.vmap(lambda y, q: integrate(model, integrator, y, q, False))(Y0, Q)


def flow_jacobians(
    model,
    integrator,
    Y0,
    Q,
    need_y=True,
    need_q=True,
    save_all=False,
    q_columns=None,
    merge_rigid=True,
):
    """Integrate every segment with the Jacobians of its output (the end state, or with
    `save_all` the states at every step point) with respect to the start state's own
    tangent coordinates (`tangent_coords`) and to the parameters: one forward pass with
    those directions. q_columns: the parameter columns to differentiate in (static; None:
    all of them). Returns (out, jac_y, jac_q); a Jacobian not asked for is None.

    Columns 0 (length) and 1 (rigid) share one integrated direction: the flow reads them
    only as the flexible length, length - rigid, and as the rigid transport at the start,
    whose derivative is the start-state tangent `rigid_start_tangent`. So d/d rigid is
    minus d/d length plus the state Jacobian applied to that tangent. (The pass costs by
    the number of directions, in steps of four: 9 of them cost 0.08-0.12 ms more than 8
    on planar ref-A.) merge_rigid=False integrates both directions (for comparison)."""
    cols = None if q_columns is None else np.asarray(q_columns)
    merge = merge_rigid and need_q and cols is not None and 0 in cols and 1 in cols
    integrated = cols[cols != 1] if merge else cols

    def one(y, q):
        # Differentiate along the start state's own tangent directions only (a frame
        # turns in 3 ways, not 9; translations need no integration without contact).
        E = model.tangent_basis(y)
        if integrated is None:
            b0, full = q, lambda b: b
        else:
            b0, full = q[integrated], lambda b: q.at[integrated].set(b)

        def twice(d, b):
            o = integrate(model, integrator, y + E @ d, full(b), save_all)
            return o, o

        d0 = jnp.zeros(E.shape[1], y.dtype)
        return jax.jacfwd(twice, argnums=argnums, has_aux=True)(d0, b0)

    with_y = need_y or merge
    argnums = tuple(i for i, need in ((0, with_y), (1, need_q)) if need)
    jacs, out = jax.vmap(one)(Y0, Q)
    jac_y = jacs[0] if with_y else None
    jac_q = jacs[-1] if need_q else None
    if merge:
        dY0 = jax.vmap(model.rigid_start_tangent)(Y0, Q)
        rigid = apply_flow_jacobians(model, Y0, dY0, None, jac_y, None)
        length = int(np.flatnonzero(integrated == 0)[0])
        rigid = rigid - jac_q[..., length]
        at = int(np.flatnonzero(cols == 1)[0])
        jac_q = jnp.concatenate([jac_q[..., :at], rigid[..., None], jac_q[..., at:]], axis=-1)
    return out, (jac_y if need_y else None), jac_q


def apply_flow_jacobians(model, Y0, dY0, dQ, jac_y, jac_q, q_columns=None):
    """The tangent of `flow_jacobians`' output for start-state and parameter tangents
    dY0, dQ (either may be None; dQ's columns outside `q_columns`, those `jac_q` was
    taken in, must be zero): linear in them, so reverse mode transposes it."""
    like = jac_y if jac_y is not None else jac_q
    shape = like.shape[:-1]
    dout = jnp.zeros(shape, like.dtype)
    if dY0 is not None:
        d = jax.vmap(model.tangent_coords)(Y0, dY0)
        dout = dout + jnp.einsum("s...j,sj->s...", jac_y, d)
        if model.translation_free:  # a start translation moves every point alike
            pos = model.position_slice
            shift = dY0[:, pos].reshape((shape[0],) + (1,) * (len(shape) - 2) + (-1,))
            dout = dout.at[..., pos].add(shift)
    if dQ is not None:
        dQ = dQ if q_columns is None else dQ[:, np.asarray(q_columns)]
        dout = dout + jnp.einsum("s...j,sj->s...", jac_q, dQ)
    return dout


def _segment_flow_jvp(model, integrator, primals, tangents):
    Y0, Q = primals
    dY0, dQ = tangents
    zero = jax.custom_derivatives.SymbolicZero
    need_y, need_q = not isinstance(dY0, zero), not isinstance(dQ, zero)
    if not (need_y or need_q):
        out = segment_flow(model, integrator, Y0, Q)
        return out, jnp.zeros_like(out)
    out, jac_y, jac_q = flow_jacobians(model, integrator, Y0, Q, need_y, need_q)
    dout = apply_flow_jacobians(
        model, Y0, dY0 if need_y else None, dQ if need_q else None, jac_y, jac_q
    )
    return out, dout


segment_flow.defjvp(_segment_flow_jvp, symbolic_zeros=True)
