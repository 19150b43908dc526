"""Multiple-shooting assembly of a finger: the residual.

Every beam is cut at its junctions and load points into segments (`_cuts`). The start
state of every segment is an unknown; the residual holds, in this order: the two base
conditions, continuity across every internal cut (with the jump of a point load or a
crossbeam end wrench), the kinematic attachment of both ends of every crossbeam, and the
tip junction.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._contact import beam_gaps, member_smoothing, member_stiffness
from ._finger import BACK, FRONT, Finger
from ._flow import segment_flow, segment_trajectories
from ._geometry import Geometry
from ._members import node_jumps, slot_kinematics, undeformed_nodes
from ._rod import rod_model
from ._segment_table import SegmentTable
from ._topology import Topology


class Problem(eqx.Module):
    """Everything the residual needs, at load factor 1. `lam` scales every load.

    order: None, or the segments nearest first (a permutation, argsort of `gaps`): then
    the residual evaluates the contact law on the first `topo.contact.near` of them only
    (the rest integrate without contact terms, exact where they touch nothing)."""

    topo: Topology = eqx.field(static=True)
    integrator: eqx.Module
    finger: Finger
    geo: Geometry
    table: SegmentTable
    order: jax.Array | None = None

    @property
    def model(self):
        return self.topo.model

    def scale(self):
        return self.model.unknown_scale(self.geo.L, self.geo.F)

    def start_states(self, Y):
        """Physical full start states from scaled unknowns Y (S, n_unknown)."""
        y = Y * self.scale()
        return jax.vmap(self.model.full_from_unknown)(y, self.table.theta)

    def params(self, lam):
        t = self.table
        t = eqx.tree_at(lambda x: x.force, t, t.force * lam)
        return self.model.pack(t)

    def undeformed(self):
        y = jax.vmap(self.model.undeformed_unknown)(self.table.point, self.table.theta)
        return y / self.scale()

    def ends(self, Y, lam):
        starts, Q = self.start_states(Y), self.params(lam)
        if self.order is None:
            return starts, segment_flow(self.model, self.integrator, starts, Q)
        k, o = self.topo.contact.near, self.order
        free = rod_model(self.topo.mode, self.topo.tapered, self.topo.contact.free())
        near = segment_flow(self.model, self.integrator, starts[o[:k]], Q[o[:k]])
        rest = segment_flow(free, self.integrator, starts[o[k:]], Q[o[k:]])
        return starts, jnp.concatenate([near, rest])[jnp.argsort(o)]

    def gaps(self, Y, lam, along=True):
        """(S,) every segment's smallest gap to an object or the support at its step
        points (one integration), or with along=False at its start point only (none);
        1e6 where it cannot touch anything. argsort gives `order`."""
        states = self.integrated(Y, lam) if along else self.start_states(Y)[:, None]
        md, spec = self.model, self.topo.contact
        tau = jnp.linspace(0.0, 1.0, states.shape[1])

        def gap(q, points):
            cols = md.split(q)[1]
            at = lambda y, t: beam_gaps(spec, cols, md.position(y)[jnp.array([0, 2])], t)
            return jnp.min(jax.vmap(at)(points, tau))

        return jax.vmap(gap)(self.params(lam), states)

    def residual(self, Y, lam):
        starts, ends = self.ends(Y, lam)
        return self.residual_from_states(starts, ends, lam)

    def residual_from_states(self, starts, ends, lam):
        topo, md, geo = self.topo, self.model, self.geo
        L, F = geo.L, geo.F
        ix = topo.index
        rows = []

        # Base conditions of the two main beams.
        for b in (FRONT, BACK):
            y = starts[topo.first[b]]
            point, theta = geo.base[b], geo.theta[b]
            rows += topo.base_kinds[b].rows(md, y, point, theta, F, L)

        both = jnp.concatenate([starts, ends])  # index i: start of i; S + i: end of i
        # Kinematic pairs: b must equal a turned by their undeformed relative angle
        # (internal cuts, both crossbeam ends, the tip junction).
        t = self.table
        slot_theta = jnp.concatenate([t.theta, t.theta + t.precurvature[:, 1] * t.length])
        dth = slot_theta[ix.kin_b] - slot_theta[ix.kin_a]
        kin = jax.vmap(md.kinematic_error, in_axes=(0, 0, 0, None))(
            both[ix.kin_a], both[ix.kin_b], dth, L
        )
        rows.append(kin.reshape(-1))

        # Wrench balance: across every internal cut n(s+) - n(s-) + jump = 0, and at the
        # tip n_front + n_back = 0 (a zero-jump row with both signs +).
        force = jax.vmap(md.force)(both)
        moment = jax.vmap(md.moment)(both)
        jf, jm = self._jumps(lam, force, moment, starts, ends)
        wf = ix.w_sign_a[:, None] * force[ix.w_a] + force[ix.w_b] + jf
        wm = ix.w_sign_a[:, None] * moment[ix.w_a] + moment[ix.w_b] + jm
        rows.append(jax.vmap(md.force_rows, in_axes=(0, None))(wf, F).reshape(-1))
        rows.append(jax.vmap(md.moment_rows, in_axes=(0, None, None))(wm, F, L).reshape(-1))
        return jnp.concatenate(rows)

    def _jumps(self, lam, force, moment, starts, ends):
        """Per wrench row (F, M) with n(s+) = n(s-) - F at that cut; the tip row gets
        the opposite of a force acting there (member contact only)."""
        ix = self.topo.index
        n_rows = ix.w_a.shape[0]
        jf = jnp.zeros((n_rows, 3))
        jm = jnp.zeros((n_rows, 3))
        if len(ix.point_rows):
            loads = [self.finger.loads[j] for j in ix.point_loads]
            jf = jf.at[ix.point_rows].add(lam * jnp.stack([ld.force for ld in loads]))
            jm = jm.at[ix.point_rows].add(lam * jnp.stack([ld.moment for ld in loads]))
        if len(ix.cb_rows):
            # A crossbeam pulls the front beam with its start wrench and the back beam with
            # minus its end wrench.
            jf = jf.at[ix.cb_rows].add(ix.cb_sign[:, None] * force[ix.cb_src])
            jm = jm.at[ix.cb_rows].add(ix.cb_sign[:, None] * moment[ix.cb_src])
        if self.topo.members is not None:
            mf, mm = node_jumps(self.topo.members, *self.member_args(starts, ends), n_rows)
            jf, jm = jf + mf, jm + mm
        return jf, jm

    def member_args(self, starts, ends):
        """(slot kinematics, half-thicknesses, undeformed nodes, segment lengths, k,
        delta) of member contact (planar states)."""
        t, f = self.table, self.finger
        kin = slot_kinematics(starts, ends)
        k, delta = member_stiffness(f), member_smoothing(f)
        return kin, t.half, undeformed_nodes(t), t.length, k, delta

    def integrated(self, Y, lam):
        """States at every segment's step points: (S, steps + 1, n_full)."""
        starts = self.start_states(Y)
        return segment_trajectories(self.model, self.integrator, starts, self.params(lam))

    def trajectories(self, Y, lam, traj=None):
        """Per-segment states along s: (S, steps + 2, n_full) and matching arc lengths.
        `traj`: `integrated(Y, lam)`, when it is already known."""
        starts = self.start_states(Y)
        if traj is None:
            traj = self.integrated(Y, lam)
        traj = jnp.concatenate([starts[:, None], traj], axis=1)
        t = self.table
        n = traj.shape[1] - 2
        tau = jnp.linspace(0.0, 1.0, n + 1)
        s_flex = t.start_s[:, None] + t.rigid[:, None] + tau[None] * (t.length - t.rigid)[:, None]
        s = jnp.concatenate([t.start_s[:, None], s_flex], axis=1)
        return s, traj
