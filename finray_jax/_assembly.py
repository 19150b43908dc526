"""Multiple-shooting assembly of a finger.

Every beam is cut at its junctions and load points into segments. The start state of
every segment is an unknown; the residual holds, in this order: the two base conditions,
continuity across every internal cut (with the jump of a point load or a crossbeam end
wrench), the kinematic attachment of both ends of every crossbeam, and the tip junction.

The *topology* (which events lie on which beam, in which order; the boundary-condition
kinds; the rod model) is static and built once, eagerly, from a concrete finger. Design
values (positions, thicknesses, clamp lengths, loads) flow through as arrays, so a new
design with the same topology never recompiles.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._banded import BandPlan, plan_band
from ._bases import AbstractBase
from ._contact import (
    ContactSpec,
    beam_gaps,
    contact_spec,
    global_params,
    member_smoothing,
    member_stiffness,
    members_touch,
)
from ._finger import BACK, FRONT, Finger, PointLoad, beam_lengths
from ._geometry import Geometry, arc_point, geometry, section_stiffness
from ._members import MemberPlan, build_plan, node_jumps, slot_kinematics, undeformed_nodes
from ._rod import TAPER_NODES, rod_model, segment_flow, segment_trajectories

# Event kinds on a beam, in the order used to break ties at equal arc length.
EDGE_PIECE = 1.0 / 16.0  # the support's edge piece, a fraction of the last piece before l_s
_KIND_ORDER = {"support_end": -1, "dist_end": 0, "cb": 1, "point": 2, "dist_start": 3}


@dataclasses.dataclass(frozen=True)
class Topology:
    """Static description of the shooting problem (hashable)."""

    mode: str
    base_kinds: tuple[AbstractBase, AbstractBase]
    n_crossbeams: int
    events: tuple[tuple[tuple[str, int], ...], ...]  # per beam, ordered (kind, index)
    tapered: bool = False  # a main beam's section varies along s
    contact: ContactSpec | None = None  # objects and support, if any
    members: MemberPlan | None = None  # contact between the finger's own members

    @property
    def n_beams(self):
        return 2 + self.n_crossbeams

    @property
    def segments_per_beam(self):
        return tuple(len(e) + 1 for e in self.events)

    @property
    def first(self):
        return tuple(int(x) for x in np.cumsum((0,) + self.segments_per_beam)[:-1])

    @property
    def last(self):
        return tuple(f + k - 1 for f, k in zip(self.first, self.segments_per_beam))

    @property
    def n_segments(self):
        return sum(self.segments_per_beam)

    @property
    def seg_beam(self):
        return tuple(b for b, k in enumerate(self.segments_per_beam) for _ in range(k))

    def cut_of(self, beam, kind, index):
        """Position of an event in the beam's event list (= index of the cut)."""
        return self.events[beam].index((kind, index))

    @property
    def model(self):
        return rod_model(self.mode, self.tapered, self.contact)

    @functools.cached_property
    def index(self) -> "_Index":
        return _build_index(self)

    @property
    def n_loads(self):
        return len({j for evs in self.events for kind, j in evs if kind in ("point", "dist_start")})

    @property
    def distributed(self) -> bool:
        """Whether a distributed load acts: only then does a segment's flow depend on the
        load factor (point loads are jumps between segments)."""
        return any(kind == "dist_start" for evs in self.events for kind, _ in evs)

    @functools.cached_property
    def band(self) -> BandPlan:
        """Banded ordering of the shooting Jacobian (see `_banded`)."""
        md = self.model
        return plan_band(_row_segments(self), md.n_unknown, self.n_segments)

    @functools.cached_property
    def layout(self) -> "_Layout":
        return _build_layout(self, self.n_loads)


@dataclasses.dataclass(frozen=True, eq=False)
class _Index:
    """Static gather/scatter indices of the residual (into concat(starts, ends))."""

    kin_a: np.ndarray
    kin_b: np.ndarray
    w_a: np.ndarray
    w_b: np.ndarray
    w_sign_a: np.ndarray
    point_rows: np.ndarray
    point_loads: tuple
    cb_rows: np.ndarray
    cb_src: np.ndarray
    cb_sign: np.ndarray


def _build_index(topo: Topology) -> _Index:
    S, first, last = topo.n_segments, topo.first, topo.last
    end = lambda i: S + i
    kin = []  # (a, b): b must equal a turned by the undeformed angle between the slots
    wr = []  # (a, b, sign_a)
    point_rows, point_loads, cb_rows, cb_src, cb_sign = [], [], [], [], []
    for b, evs in enumerate(topo.events):
        for k, (kind, j) in enumerate(evs):
            a, c = first[b] + k, first[b] + k + 1
            kin.append((end(a), c))
            row = len(wr)
            wr.append((end(a), c, -1.0))
            if kind == "point":
                point_rows.append(row)
                point_loads.append(j)
            elif kind == "cb":
                cb_rows.append(row)
                if b == FRONT:
                    cb_src.append(first[2 + j])
                    cb_sign.append(1.0)
                else:
                    cb_src.append(end(last[2 + j]))
                    cb_sign.append(-1.0)
    for j in range(topo.n_crossbeams):
        cbeam = 2 + j
        main_f = first[FRONT] + topo.cut_of(FRONT, "cb", j) + 1
        main_b = first[BACK] + topo.cut_of(BACK, "cb", j) + 1
        kin.append((main_f, first[cbeam]))
        kin.append((main_b, end(last[cbeam])))
    kin.append((end(last[FRONT]), end(last[BACK])))
    wr.append((end(last[FRONT]), end(last[BACK]), 1.0))
    kin = np.asarray(kin, dtype=np.int64).reshape(-1, 2)
    i = lambda x: np.asarray(x, dtype=np.int64)
    return _Index(
        kin_a=kin[:, 0],
        kin_b=kin[:, 1],
        w_a=i([w[0] for w in wr]),
        w_b=i([w[1] for w in wr]),
        w_sign_a=np.asarray([w[2] for w in wr]),
        point_rows=i(point_rows),
        point_loads=tuple(point_loads),
        cb_rows=i(cb_rows),
        cb_src=i(cb_src),
        cb_sign=np.asarray(cb_sign),
    )


def _row_segments(topo: Topology):
    """For each residual row (in `Problem.residual_from_states` order), the segments whose
    unknowns it reads. A slot i < S is the start of segment i, S + i its end (a function of
    the same segment's start only: loads and contact act on the segment's own state)."""
    S, ix = topo.n_segments, topo.index
    half = topo.model.n_unknown // 2  # rows per base condition or kinematic pair
    n_force = 2 if topo.mode == "planar" else 3
    n_moment = half - n_force
    rows = []
    for b in (FRONT, BACK):
        rows += [{topo.first[b]}] * half
    for a, b in zip(ix.kin_a, ix.kin_b):
        rows += [{int(a) % S, int(b) % S}] * half
    wrench = [{int(a) % S, int(b) % S} for a, b in zip(ix.w_a, ix.w_b)]
    for row, src in zip(ix.cb_rows, ix.cb_src):
        wrench[int(row)].add(int(src) % S)
    if topo.members is not None:
        for deps, more in zip(wrench, topo.members.row_dependencies(len(wrench))):
            deps |= more
    for per_row in (n_force, n_moment):
        for deps in wrench:
            rows += [deps] * per_row
    return rows


def event_s(finger: Finger, beam: int, kind: str, index: int):
    if kind == "support_end":
        return finger.adaptor.support_length
    if kind == "cb":
        cb = finger.crossbeams
        # (indexing a host copy: indexing the jax array is one dispatch per event)
        return np.asarray(cb.front_s if beam == FRONT else cb.back_s)[index]
    load = finger.loads[index]
    if kind == "point":
        return load.s
    return load.s_range[0] if kind == "dist_start" else load.s_range[1]


def build_topology(finger: Finger, mode: str) -> Topology:
    """Sort each beam's events by their (concrete) arc length."""
    per_beam = [[] for _ in range(finger.n_beams)]
    for j in range(finger.n_crossbeams):
        per_beam[FRONT].append(("cb", j))
        per_beam[BACK].append(("cb", j))
    for j, load in enumerate(finger.loads):
        if isinstance(load, PointLoad):
            per_beam[load.beam].append(("point", j))
        else:
            per_beam[load.beam].append(("dist_start", j))
            per_beam[load.beam].append(("dist_end", j))
    ad = finger.adaptor
    contact = contact_spec(finger)
    if ad.support_length is not None:
        per_beam[BACK].append(("support_end", 0))
    members = members_touch(finger) and mode == "planar"
    if members and contact is None:
        contact = ContactSpec(friction=False)
    events = []
    pieces = _crossbeam_pieces(finger) if members else 1
    for b, evs in enumerate(per_beam):
        key = lambda e, b=b: (float(event_s(finger, b, *e)), _KIND_ORDER[e[0]], e[1])
        evs = sorted(evs, key=key)
        if contact is not None and b in (FRONT, BACK):
            evs = _subdivide(finger, b, evs, finger.contact.segment_length)
        elif b >= 2:
            evs = [("sub", (i, i / pieces)) for i in range(1, pieces)]
        events.append(tuple(evs))
    tapered = finger.front.tip_thickness is not None or finger.back.tip_thickness is not None
    if contact is not None:
        contact = dataclasses.replace(contact, near=_near_count(finger, events))
    topo = Topology(
        mode, (ad.front_base, ad.back_base), finger.n_crossbeams, tuple(events), tapered, contact
    )
    if members:
        topo = dataclasses.replace(topo, members=_member_plan(topo, finger))
    return topo


def _crossbeam_pieces(finger: Finger) -> int:
    """Equal pieces per crossbeam for member contact: none longer than twice the segment
    length (at least 2; equal counts keep the crossbeams' solutions stacked). Contact reads a
    piece as the cubic Hermite curve through its ends, and a buckled crossbeam's S-shape
    needs pieces this short for that curve to follow it (finray_jax._members)."""
    longest = float(np.max(np.asarray(geometry(finger).length[2:]), initial=0.0))
    return max(2, int(np.ceil(longest / (2.0 * finger.contact.segment_length) - 1e-9)))


def _node_rows(topo: Topology):
    """The wrench row of every segment's start and end node, and the sign with which a
    force at that node enters it (-1: none, a main beam's base)."""
    S, first, last = topo.n_segments, topo.first, topo.last
    rows = -np.ones((S, 2), dtype=np.int64)
    signs = np.ones((S, 2))
    row, cb_row = 0, {}
    for b, evs in enumerate(topo.events):
        for k, (kind, j) in enumerate(evs):
            rows[first[b] + k, 1] = rows[first[b] + k + 1, 0] = row
            if kind == "cb":
                cb_row[b, j] = row
            row += 1
    for b in (FRONT, BACK):  # the tip's row: n_front + n_back = a force there
        rows[last[b], 1], signs[last[b], 1] = row, -1.0
    for j in range(topo.n_crossbeams):
        rows[first[2 + j], 0] = cb_row[FRONT, j]
        rows[last[2 + j], 1] = cb_row[BACK, j]
    return rows, signs


def _member_plan(topo: Topology, finger: Finger) -> MemberPlan:
    table = segment_table(topo, finger, geometry(finger))
    nodes = undeformed_nodes(table)
    nodes = type(nodes)(*(np.asarray(x) for x in nodes))
    rows, signs = _node_rows(topo)
    return build_plan(
        np.asarray(topo.seg_beam),
        (topo.first[FRONT], topo.first[BACK]),
        nodes,
        rows,
        signs,
        finger.contact.member_reach,
    )


def _near_count(finger: Finger, events):
    """How many segments a full-load Newton solve evaluates contact on (None: all): the
    supported segments and `Contact.near_segments` more, if fewer than the main beams'."""
    near = finger.contact.near_segments
    main = len(events[FRONT]) + len(events[BACK]) + 2
    supported = (
        events[BACK].index(("support_end", 0)) + 1 if ("support_end", 0) in events[BACK] else 0
    )
    if near is None or supported + near >= main:
        return None
    return supported + near


def _subdivide(finger, beam, events, max_length):
    """Insert ("sub", (k, fraction)) cuts so that no segment is longer than max_length: the
    k-th cut after a real event, at that fraction of the way to the next real event. The
    stretch is cut into m equal pieces (m fixed here, from the concrete design; the cut
    positions follow the design values). The last piece before the support's end is cut
    once more, EDGE_PIECE of it from the end: the back beam presses on the support's
    edge over a few hundredths of a millimetre there, and that short piece's steps
    resolve it (docs/grasping.md)."""
    length = beam_lengths(finger)[beam]
    cuts = [0.0] + [float(event_s(finger, beam, *e)) for e in events] + [length]
    out = []
    for k in range(len(events) + 1):
        m = max(1, int(np.ceil((cuts[k + 1] - cuts[k]) / max_length - 1e-9)))
        out += [("sub", (i, i / m)) for i in range(1, m)]
        if k < len(events) and events[k][0] == "support_end" and cuts[k + 1] > cuts[k]:
            out.append(("sub", (m, 1.0 - EDGE_PIECE / m)))
        if k < len(events):
            out.append(events[k])
    return out


# --------------------------------------------------------------------------------------
# Geometry and the segment table (traced)
# --------------------------------------------------------------------------------------


class SegmentTable(eqx.Module):
    start_s: jax.Array  # (S,)
    length: jax.Array  # (S,)
    rigid: jax.Array  # (S,) length held rigidly by an adaptor clamp
    contact: jax.Array  # (S, N_SEGMENT + globals) contact columns, or (S, 0)
    stiffness: jax.Array  # (S, 4, 6): kGA1, kGA2, EA, EI1, EI2, GJ at TAPER_NODES
    force: jax.Array  # (S, 3) distributed force per length (at load factor 1)
    precurvature: jax.Array  # (S, 3)
    theta: jax.Array  # (S,) undeformed frame angle
    point: jax.Array  # (S, 3) undeformed start point
    half: jax.Array | None = None  # (S, 2) half-thickness at the flexible part's ends


@dataclasses.dataclass(frozen=True, eq=False)
class _Layout:
    """Static description of every segment, in terms of a vector of *anchors*: the arc
    lengths the design supplies (0, beam lengths, attachments, load positions, the
    support length). A cut's position is a fixed linear combination of anchors."""

    beam: np.ndarray  # (S,) beam of each segment
    start: np.ndarray  # (S, n_anchor) start position weights
    end: np.ndarray  # (S, n_anchor)
    loads: np.ndarray  # (S, n_loads) 1 where a distributed load covers the segment
    supported: np.ndarray  # (S,) 1 on back-beam segments before the support's end


def _anchor_index(topo: Topology, n_loads: int):
    """Anchor of an event: 0 -> 0, 1 + b -> length of beam b, then crossbeam front_s,
    back_s, the loads' first and second positions, the support length."""
    B, C = topo.n_beams, topo.n_crossbeams
    base = {"length": 1, "front_s": 1 + B, "back_s": 1 + B + C, "load_a": 1 + B + 2 * C}
    base["load_b"] = base["load_a"] + n_loads
    base["support"] = base["load_b"] + n_loads

    def of(beam, kind, j):
        if kind == "cb":
            return base["front_s" if beam == FRONT else "back_s"] + j
        if kind in ("point", "dist_start"):
            return base["load_a"] + j
        if kind == "dist_end":
            return base["load_b"] + j
        return base["support"]  # support_end

    return of, base["support"] + 1


def _build_layout(topo: Topology, n_loads: int) -> _Layout:
    of, n_anchor = _anchor_index(topo, n_loads)
    beam, start, end, loads, supported = [], [], [], [], []
    for b, evs in enumerate(topo.events):
        # Weights of every cut of this beam: 0, each event, the beam's length.
        real = [np.eye(n_anchor)[0]]
        for kind, j in evs:
            real.append(None if kind == "sub" else np.eye(n_anchor)[of(b, kind, j)])
        real.append(np.eye(n_anchor)[1 + b])
        cuts = list(real)
        for i, (kind, j) in enumerate(evs, start=1):
            if kind == "sub":  # the k-th cut after a real cut, a fraction toward the next
                k, fraction = j
                nxt = next(c for c in real[i + 1 :] if c is not None)
                cuts[i] = cuts[i - k] + (nxt - cuts[i - k]) * fraction
        active = np.zeros(n_loads)
        inside = b == BACK
        for k in range(len(evs) + 1):
            if k > 0:
                kind, j = evs[k - 1]
                if kind in ("dist_start", "dist_end"):
                    active[j] = kind == "dist_start"
                elif kind == "support_end":
                    inside = False
            beam.append(b)
            start.append(cuts[k])
            end.append(cuts[k + 1])
            loads.append(active.copy())
            supported.append(float(inside))
    return _Layout(
        np.asarray(beam),
        np.asarray(start),
        np.asarray(end),
        np.asarray(loads).reshape(len(beam), n_loads),
        np.asarray(supported),
    )


def _anchors(topo: Topology, finger: Finger, geo: Geometry):
    cb, ad = finger.crossbeams, finger.adaptor
    first = [ld.s if isinstance(ld, PointLoad) else ld.s_range[0] for ld in finger.loads]
    second = [ld.s if isinstance(ld, PointLoad) else ld.s_range[1] for ld in finger.loads]
    support = jnp.zeros(()) if ad.support_length is None else ad.support_length
    parts = [jnp.zeros(1), geo.length, cb.front_s, cb.back_s]
    parts += [jnp.stack(first), jnp.stack(second)] if finger.loads else []
    return jnp.concatenate(parts + [support[None]])


def segment_table(topo: Topology, finger: Finger, geo: Geometry) -> SegmentTable:
    lay = topo.layout
    beams = lay.beam
    anchors = _anchors(topo, finger, geo)
    start_s = jnp.asarray(lay.start) @ anchors
    length = jnp.asarray(lay.end) @ anchors - start_s
    ad, cb = finger.adaptor, finger.crossbeams
    zero_c = jnp.zeros(topo.n_crossbeams)
    clamp = jnp.concatenate([jnp.stack([ad.front_clamp_length, ad.back_clamp_length]), zero_c])
    # min(max(clamp - s0, 0), length), ties resolved toward the clamp: a zero-length
    # segment (two events at one arc length) has no rigid part on either side of the tie,
    # where jnp.clip's min would pass half of d(length) into d(rigid).
    reach = jnp.maximum(clamp[beams] - start_s, 0.0)
    rigid = jnp.where(reach <= length, reach, length)

    # Sections: thickness linear from base (t0) to tip (t1) along each beam.
    def ends(sec):
        tip = sec.thickness if sec.tip_thickness is None else sec.tip_thickness
        return sec.thickness, tip

    (f0, f1), (b0, b1) = ends(finger.front), ends(finger.back)
    t0 = jnp.concatenate([jnp.stack([f0, b0]), cb.thickness])[beams]
    t1 = jnp.concatenate([jnp.stack([f1, b1]), cb.thickness])[beams]
    depth = jnp.concatenate([jnp.stack([finger.front.depth, finger.back.depth]), cb.depth])
    nodes = (start_s + rigid)[:, None] + jnp.asarray(TAPER_NODES)[None] * (length - rigid)[:, None]
    thick = t0[:, None] + (t1 - t0)[:, None] * nodes / geo.length[beams][:, None]
    stiffness = section_stiffness(finger.material, thick, depth[beams][:, None], finger.torsion)

    per_length = [
        jnp.zeros(3) if isinstance(ld, PointLoad) else ld.force_per_length for ld in finger.loads
    ]
    force = (
        jnp.asarray(lay.loads) @ jnp.stack(per_length) if per_length else jnp.zeros((len(beams), 3))
    )

    kappa = geo.curvature[beams]
    theta = geo.theta[beams] + kappa * start_s
    point = jax.vmap(arc_point)(geo.base[beams], geo.theta[beams], kappa, start_s)
    zero = jnp.zeros_like(kappa)
    if topo.contact is None:
        contact = jnp.zeros((len(beams), 0))
    else:
        main = jnp.asarray((beams < 2).astype(np.float64))
        support = jnp.asarray(lay.supported) * float(topo.contact.support)
        half = 0.5 * thick[:, jnp.asarray([0, 3])]
        shared = global_params(finger, geo)
        contact = jnp.concatenate(
            [
                main[:, None],
                support[:, None],
                half,
                jnp.broadcast_to(shared, (len(beams), shared.shape[0])),
            ],
            axis=1,
        )
    return SegmentTable(
        start_s=start_s,
        length=length,
        rigid=rigid,
        contact=contact,
        stiffness=stiffness,
        force=force,
        precurvature=jnp.stack([zero, kappa, zero], axis=-1),
        theta=theta,
        point=point,
        half=0.5 * thick[:, jnp.asarray([0, 3])],
    )


# --------------------------------------------------------------------------------------
# Residual
# --------------------------------------------------------------------------------------


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
