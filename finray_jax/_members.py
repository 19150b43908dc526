"""Contact between the finger's own members: crossbeams, the front beam and the back beam.

A member is a band of half-thickness h around its centreline, as for objects. Between two
shooting nodes the centreline is taken as the cubic Hermite curve through the nodes'
positions with their tangents (the rod's own d3), which follows a bent segment to fourth
order in its length. Every segment carries sample points at a quarter of its length
apart (its start node included). A sample p of member A and member B touch where their
bands overlap: the gap is g = |p - c| - h_A - h_B, with c the point of B's centreline
nearest p (over B's nearby segments; a few Newton steps on the Hermite parameter from the
chord's projection). The contact is a penalty energy: each sample stores (l / 4) U(g),
with U the integral of the objects' C1 penalty ramp (`_contact.penalty`, with the
members' stiffness k per unit length and their own smoothing) and l / 4 the sample's share
of its segment. Every member is sampled against every other one, so contact is seen from
both sides.

The residual is solved at the shooting nodes, so the contact acts there: the force and
moment on each node are minus the energy's gradient in the node's position and angle
(they enter its wrench row as a point load would). The contact is therefore conservative
on the nodes, its stiffness (the energy's Hessian) is symmetric, and the stability test
adds it to the condensed stiffness. Between its nodes a segment carries the contact in
its end wrenches only; the finger's equilibrium and every node see it where it acts.

Which samples can touch which members is fixed with the topology, from the undeformed
finger: a member within `Contact.member_reach` of the sample. Where two members are
joined (a crossbeam's ends, the tip) their bands overlap by construction: a sample whose
undeformed gap to a member is not positive is inside the joint and never in contact with
it, and one whose undeformed gap is below half the thinner member's thickness lies on
the joint's fillet, where contact sets in later (`joint_offset`). Both are tested on the
traced design too, so a design that thickens a member cannot press a joint. A main
beam's first segment is left out (its start is held by the base, which
would take a force there). Planar fingers only.
"""

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._contact import penalty
from ._objects import safe_norm

N_SAMPLES = 4  # sample points per segment, at xi = 0, 1/4, 1/2, 3/4
XI = np.arange(N_SAMPLES) / N_SAMPLES
NEAREST_STEPS = 3  # Newton steps on the nearest point's parameter


@dataclasses.dataclass(frozen=True, eq=False)
class MemberPlan:
    """Static layout of member-to-member contact.

    sample_segment, sample_xi: every sample point (P,).
    group_sample: (G,) a group is one sample against one other member;
    group_members: (G, 2) (the sample's member, the other member);
    group_segments: (G, M) the other member's candidate segments (-1: padding).
    node_rows: (S, 2) the wrench row of each segment's start and end node (-1: none);
    node_signs: (S, 2) the sign with which a force at that node enters its row.
    """

    sample_segment: np.ndarray
    sample_xi: np.ndarray
    group_sample: np.ndarray
    group_members: np.ndarray
    group_segments: np.ndarray
    node_rows: np.ndarray
    node_signs: np.ndarray

    @property
    def n_groups(self) -> int:
        return int(self.group_sample.shape[0])

    @functools.cached_property
    def _key(self):
        return tuple(
            (a.shape, a.tobytes())
            for a in (self.sample_segment, self.group_sample, self.group_segments, self.node_rows)
        )

    def __hash__(self):
        return hash(self._key)

    def __eq__(self, other):
        return isinstance(other, MemberPlan) and self._key == other._key

    def row_dependencies(self, n_rows: int):
        """Per wrench row, the segments its member-contact jump reads."""
        deps = [set() for _ in range(n_rows)]
        seg = self.sample_segment[self.group_sample]
        for a, cands in zip(seg, self.group_segments):
            cands = [int(m) for m in cands if m >= 0]
            touched = {int(a)} | set(cands)
            for s in touched:
                for r in self.node_rows[s]:
                    if r >= 0:
                        deps[r] |= touched
        return deps


# --------------------------------------------------------------------------------------
# Geometry on (x, z) pairs
# --------------------------------------------------------------------------------------


def hermite(p0, t0, p1, t1, xi):
    """Point, first and second derivative in xi of the cubic Hermite curve from p0 to p1
    with unit tangents t0, t1 scaled by the chord length (..., 2)."""
    c = safe_norm(p1 - p0)[..., None]
    m0, m1 = c * t0, c * t1
    x = xi[..., None]
    x2, x3 = x * x, x * x * x
    point = (2 * x3 - 3 * x2 + 1) * p0 + (x3 - 2 * x2 + x) * m0 + (-2 * x3 + 3 * x2) * p1
    point = point + (x3 - x2) * m1
    d1 = (6 * x2 - 6 * x) * (p0 - p1) + (3 * x2 - 4 * x + 1) * m0 + (3 * x2 - 2 * x) * m1
    d2 = (12 * x - 6) * (p0 - p1) + (6 * x - 4) * m0 + (6 * x - 2) * m1
    return point, d1, d2


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _newton(p, p0, t0, p1, t1, xi):
    """One Newton step toward the parameter of the point nearest p, kept in [0, 1]."""
    c, c1, c2 = hermite(p0, t0, p1, t1, xi)
    r = p - c
    slope = -_dot(r, c1)
    curve = jnp.maximum(_dot(c1, c1) - _dot(r, c2), 0.1 * _dot(c1, c1) + 1e-30)
    return jnp.clip(xi - slope / curve, 0.0, 1.0)


def nearest(p, p0, t0, p1, t1):
    """The parameter in [0, 1] of the point of a Hermite segment nearest p, and that point."""
    d = p1 - p0
    xi = jnp.clip(_dot(p - p0, d) / jnp.maximum(_dot(d, d), 1e-30), 0.0, 1.0)
    for _ in range(NEAREST_STEPS):
        xi = _newton(p, p0, t0, p1, t1, xi)
    return xi, hermite(p0, t0, p1, t1, xi)[0]


class Nodes(NamedTuple):
    """Every segment's start and end: positions p0, p1 and unit tangents t0, t1 (S, 2),
    and half-thicknesses h (S, 2) at its two ends."""

    p0: jax.Array
    t0: jax.Array
    p1: jax.Array
    t1: jax.Array
    h: jax.Array

    def at(self, seg, xi):
        return hermite(self.p0[seg], self.t0[seg], self.p1[seg], self.t1[seg], xi)[0]

    def half(self, seg, xi):
        return self.h[seg, 0] + (self.h[seg, 1] - self.h[seg, 0]) * xi

    def ends(self, seg):
        return self.p0[seg], self.t0[seg], self.p1[seg], self.t1[seg]


def _group_contacts(plan: MemberPlan, nodes: Nodes):
    """Per group: the gap, the sample's segment, and half the thinner member's thickness
    there.

    The nearest candidate and its parameter are found without derivatives (a choice,
    and iterations); one Newton step from that parameter, with derivatives, then gives
    the nearest point's exact first derivatives (those of the converged iteration)."""
    seg = jnp.asarray(plan.sample_segment[plan.group_sample])
    xi = jnp.asarray(plan.sample_xi[plan.group_sample])
    p = nodes.at(seg, xi)  # (G, 2)
    h_a = nodes.half(seg, xi)
    cands = jnp.asarray(np.maximum(plan.group_segments, 0))  # (G, M)
    valid = jnp.asarray(plan.group_segments >= 0)
    fixed = jax.lax.stop_gradient((nodes, p, h_a))
    n0, p0, h0 = fixed
    pp = jnp.broadcast_to(p0[:, None], cands.shape + (2,))
    xi_all, c_all = nearest(pp, *n0.ends(cands))
    gap_all = safe_norm(pp - c_all) - h0[:, None] - n0.half(cands, xi_all)
    best = jnp.argmin(jnp.where(valid, gap_all, jnp.inf), axis=1)
    seg_b = jnp.take_along_axis(cands, best[:, None], axis=1)[:, 0]
    xi_b = jnp.take_along_axis(xi_all, best[:, None], axis=1)[:, 0]
    xi_b = _newton(p, *nodes.ends(seg_b), xi_b)
    h_b = nodes.half(seg_b, xi_b)
    gap = safe_norm(p - nodes.at(seg_b, xi_b)) - h_a - h_b
    return gap, seg, jnp.minimum(h_a, h_b)


def joint_offset(plan: MemberPlan, undeformed: Nodes):
    """Per group: how much of the gap the joint's fillet takes (mm; added to the gap).
    A sample whose undeformed gap g0 to the other member is below half the thinner
    member's thickness h lies on a joint's fillet: its contact starts only once it has
    closed by h - g0 more, which goes to 0 where the fillet ends, so the contact sets in
    continuously along the member. A sample with g0 <= 0 is inside the joint: none."""
    gap0, _, h = _group_contacts(plan, undeformed)
    return jnp.where(gap0 > 0, jnp.maximum(h - gap0, 0.0), jnp.inf)


def _energy_density(g, k, delta):
    """The penalty's energy per unit length at gap g: the integral of `penalty`."""
    x = -g
    q = jnp.clip(x, 0.0, delta)
    r = jnp.maximum(x - delta, 0.0)
    return k * (q * q * q / (6.0 * delta) + r * delta / 2.0 + r * r / 2.0)


def _nodes_of(kin, half):
    """Nodes from the slots' kinematics (2 S, 3): x, z, theta of every start, then end."""
    S = half.shape[0]
    p, th = kin[:, :2], kin[:, 2]
    t = jnp.stack([jnp.sin(th), jnp.cos(th)], axis=-1)
    return Nodes(p[:S], t[:S], p[S:], t[S:], half)


def energy(plan: MemberPlan, kin, half, undeformed: Nodes, length, k, delta):
    """The members' contact energy (N mm) as a function of the slots' kinematics."""
    gap, seg, _ = _group_contacts(plan, _nodes_of(kin, half))
    offset = jax.lax.stop_gradient(joint_offset(plan, undeformed))
    share = length[seg] / N_SAMPLES
    return jnp.sum(_energy_density(gap + offset, k, delta) * share)


def group_forces(plan: MemberPlan, kin, half, undeformed: Nodes, length, k, delta):
    """Per group: the size of its contact force (N) and its gap, less the joint's offset
    (`joint_offset`): minus the penetration."""
    gap, seg, _ = _group_contacts(plan, _nodes_of(kin, half))
    gap = gap + joint_offset(plan, undeformed)
    return penalty(gap, k, delta) * length[seg] / N_SAMPLES, gap


def node_jumps(plan: MemberPlan, kin, half, undeformed: Nodes, length, k, delta, n_rows):
    """The member-contact jumps of the wrench rows: forces (n_rows, 3) and moments
    (n_rows, 3), as a point load at each node would enter them. The force and moment on
    a node are minus the energy's gradient in its position and angle (the angle about y:
    its conjugate is the moment about y), so the contact is conservative on the nodes and
    its stiffness is the energy's Hessian."""
    on_slots = -jax.grad(energy, argnums=1)(plan, kin, half, undeformed, length, k, delta)
    rows = jnp.asarray(np.where(plan.node_rows < 0, n_rows, plan.node_rows).T.reshape(-1))
    signs = jnp.asarray(plan.node_signs.T.reshape(-1))[:, None]
    f = signs * on_slots  # (2 S, 3): slots in the order of `kin`
    jf = jnp.zeros((n_rows + 1, 3)).at[rows, 0].add(f[:, 0]).at[rows, 2].add(f[:, 1])
    jm = jnp.zeros((n_rows + 1, 3)).at[rows, 1].add(f[:, 2])
    return jf[:n_rows], jm[:n_rows]


# --------------------------------------------------------------------------------------
# The static plan
# --------------------------------------------------------------------------------------


def build_plan(seg_beam, first_main, nodes_np: Nodes, node_rows, node_signs, reach):
    """The member-contact plan from the undeformed nodes (NumPy arrays).

    seg_beam: (S,) the member of every segment; first_main: segments left out (the main
    beams' first ones); reach: the largest undeformed gap (mm) of a sample to a member it
    may touch."""
    S = len(seg_beam)
    seg_beam = np.asarray(seg_beam)
    allowed = np.ones(S, bool)
    allowed[list(first_main)] = False
    segs = np.flatnonzero(allowed)
    seg_a = np.repeat(segs, N_SAMPLES)
    xi_a = np.tile(XI, segs.size)
    n = nodes_np
    p = np.asarray(n.at(seg_a, xi_a))[:, None]  # (P, 1, 2) against (1, segs, 2)
    xi_b, c = nearest(p, n.p0[segs][None], n.t0[segs][None], n.p1[segs][None], n.t1[segs][None])
    gap = np.linalg.norm(p - np.asarray(c), axis=-1) - np.asarray(n.half(seg_a, xi_a))[:, None]
    h_b = np.asarray(n.half(segs[None], np.asarray(xi_b)))
    gap = gap - h_b
    groups = []  # (sample index, own member, other member, candidates)
    for b in np.unique(seg_beam):
        cols = seg_beam[segs] == b
        g = np.where(cols[None], gap, np.inf)
        best = np.argmin(g, axis=1)
        nearest_gap = g[np.arange(g.shape[0]), best]
        clear = nearest_gap > 0
        other = (seg_beam[seg_a] != b) & clear & (nearest_gap <= reach)
        for i in np.flatnonzero(other):
            # the nearest segment and its neighbours on that member
            k = int(best[i])
            near = [m for m in (k - 1, k, k + 1) if 0 <= m < segs.size and cols[m]]
            groups.append((i, seg_beam[seg_a[i]], b, segs[near]))
    groups.sort(key=lambda x: (x[0], x[2]))
    width = max((g[3].size for g in groups), default=0)
    cand = np.full((len(groups), width), -1, dtype=np.int64)
    for r, g in enumerate(groups):
        cand[r, : g[3].size] = g[3]
    return MemberPlan(
        sample_segment=seg_a.astype(np.int64),
        sample_xi=xi_a.astype(np.float64),
        group_sample=np.asarray([g[0] for g in groups], dtype=np.int64),
        group_members=np.asarray([(g[1], g[2]) for g in groups], dtype=np.int64).reshape(-1, 2),
        group_segments=cand,
        node_rows=np.asarray(node_rows, dtype=np.int64),
        node_signs=np.asarray(node_signs, dtype=np.float64),
    )


def undeformed_nodes(table) -> Nodes:
    """The undeformed segments' ends from a segment table (traced or concrete)."""
    kappa = table.precurvature[:, 1]
    th0, th1 = table.theta, table.theta + kappa * table.length
    p0 = table.point[:, ::2]
    half = 0.5 * th1 - 0.5 * th0
    chord = 2.0 * jnp.where(
        jnp.abs(kappa) > 1e-12,
        jnp.sin(half) / jnp.where(jnp.abs(kappa) > 1e-12, kappa, 1.0),
        0.5 * table.length,
    )
    mid = 0.5 * (th0 + th1)
    p1 = p0 + chord[:, None] * jnp.stack([jnp.sin(mid), jnp.cos(mid)], axis=-1)
    tangent = lambda th: jnp.stack([jnp.sin(th), jnp.cos(th)], axis=-1)
    return Nodes(p0, tangent(th0), p1, tangent(th1), table.half)


def slot_kinematics(starts, ends):
    """(x, z, theta) of every segment's start, then every end (2 S, 3), from planar
    states."""
    return jnp.concatenate([starts[:, :3], ends[:, :3]])
