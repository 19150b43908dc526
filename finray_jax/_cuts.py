"""Where a finger's beams are cut into segments: the topology of a concrete finger.

Every beam is cut at its junctions and load points; each beam's events (crossbeam ends,
point loads, the ends of distributed loads, the support's end) are sorted by their arc
length, and with contact the main beams are subdivided further.
"""

import dataclasses

import numpy as np

from ._contact import ContactSpec, contact_spec, members_touch
from ._finger import BACK, FRONT, Finger, PointLoad, beam_lengths
from ._geometry import geometry
from ._members import MemberPlan, build_plan, undeformed_nodes
from ._segment_table import segment_table
from ._topology import Topology

EDGE_PIECE = 1.0 / 16.0  # the support's edge piece, a fraction of the last piece before l_s
# Event kinds on a beam, in the order used to break ties at equal arc length.
_KIND_ORDER = {"support_end": -1, "dist_end": 0, "cb": 1, "point": 2, "dist_start": 3}


def event_s(finger: Finger, beam: int, kind: str, index: int):
    """Arc length on `beam` of the event (kind, index) of a concrete finger."""
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
