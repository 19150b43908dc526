"""The static description of a finger's shooting problem.

The *topology* (which events lie on which beam, in which order; the boundary-condition
kinds; the rod model) is static and built once, eagerly, from a concrete finger
(`_cuts.build_topology`). Design values (positions, thicknesses, clamp lengths, loads)
flow through as arrays, so a new design with the same topology never recompiles. From the
topology follow, once, the residual's gather/scatter indices, the band of its Jacobian,
and every segment's position as a combination of the design's arc lengths.
"""

import dataclasses
import functools

import numpy as np

from ._banded import BandPlan, plan_band
from ._bases import AbstractBase
from ._contact import ContactSpec
from ._finger import BACK, FRONT
from ._members import MemberPlan
from ._rod import rod_model


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
