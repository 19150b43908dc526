"""Contact between the finger's own members (`Contact.member_contact`, finray_jax._members).

The finger: Finger-1 with the modified adaptor (examples/grasp_finger1_modified.toml) but
crossbeams inclined down toward the back beam (back-beam joints from s = 5 to 95 mm
instead of horizontal), closed 9 mm on the 18 mm cylinder. Closing folds crossbeams 3 and
4 onto the back beam: without member contact the solution passes them through it by
more than half a millimetre.
"""

import dataclasses
import pathlib

import equinox as eqx
import numpy as np
import pytest

import finray_jax as fr
from finray_jax.io import loads_finger

ROOT = pathlib.Path(__file__).resolve().parents[1]
TEXT = (ROOT / "examples" / "grasp_finger1_modified.toml").read_text()
CLOSING = 9.0


def _finger(text=TEXT, **contact):
    finger = loads_finger(text)[0]
    return eqx.tree_at(lambda f: f.contact, finger, dataclasses.replace(finger.contact, **contact))


INCLINED = TEXT.replace("horizontal = true", "back_s = [5.0, 95.0]")


def _segment_distance(points, a, b):
    """Distance of every point (n, 2) to every segment a -> b (m, 2): (n, m)."""
    ab = b - a
    t = np.einsum("nmk,mk->nm", points[:, None] - a[None], ab) / np.maximum(
        np.einsum("mk,mk->m", ab, ab), 1e-30
    )
    c = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - c, axis=-1)


def _members(finger, sol, at=None):
    """(points (n, 2), half-thickness, arc lengths) of every member; at: arc lengths to
    interpolate the points at (the undeformed finger read where the deformed one is)."""
    beams = [sol.front, sol.back] + [sol.crossbeam(j) for j in range(finger.n_crossbeams)]
    half = [float(finger.front.thickness) / 2, float(finger.back.thickness) / 2]
    half += [float(t) / 2 for t in finger.crossbeams.thickness]
    out = []
    for i, b in enumerate(beams):
        s, p = np.asarray(b.s), np.asarray(b.position)[:, ::2]
        if at is not None:
            p = np.stack([np.interp(at[i], s, p[:, k]) for k in (0, 1)], axis=-1)
            s = at[i]
        out.append((p, half[i], s))
    return out


def smallest_clearance(finger, sol):
    """The smallest gap between two members' surfaces at every solution point (step
    points 0.3 mm apart or less), against the other member's polyline, less the joints'
    share (finray_jax._members.joint_offset): a point whose undeformed gap g0 to that
    member is below half the thinner one's thickness h lies on a joint's fillet, and its
    gap counts from h - g0 (points with g0 <= 0 are inside the joint)."""
    undeformed = fr.solve_finger(dataclasses.replace(finger, objects=()))
    now = _members(finger, sol)
    before = _members(finger, undeformed, at=[s for _, _, s in now])
    worst = np.inf
    for i, (p, h, _) in enumerate(now):
        for j, (q, hq, _) in enumerate(now):
            if i == j:
                continue
            gap = _segment_distance(p, q[:-1], q[1:]).min(axis=1) - h - hq
            q0 = before[j][0]
            gap0 = _segment_distance(before[i][0], q0[:-1], q0[1:]).min(axis=1) - h - hq
            outside = gap0 > 0
            if np.any(outside):
                fillet = np.maximum(min(h, hq) - gap0, 0.0)
                worst = min(worst, float(np.min((gap + fillet)[outside])))
    return worst


@pytest.fixture(scope="module")
def folded():
    return fr.grasp(_finger(INCLINED), closing=CLOSING)


def test_members_pressed_together_stay_apart(folded):
    """The grasp converges on a stable equilibrium; crossbeams press on the back beam
    (members 1 and 3, 4) with internal forces of newtons; the largest penetration
    between members where the contact reads them (its samples on the Hermite centrelines)
    is within its limit, 2 % of the thinnest member (the crossbeams' 2 mm); and on the
    dense solution (every integration step, against the other member's polyline) the
    deepest overlap is within the same limit, where the same grasp without member contact
    passes a crossbeam more than half a millimetre through the back beam. The dense read
    differs from the samples by the Hermite curve's departure from the integrated
    centreline between a piece's ends (a few micrometres on these pieces of under 10 mm)
    and by the penetration between samples."""
    g = folded
    assert g.converged, g.solution.message
    assert g.stability is not None and g.stability.stable
    forces = np.asarray(g.contact.member_force)
    assert forces.shape == (2 + 7, 2 + 7)
    np.testing.assert_allclose(forces, forces.T)
    assert forces[1, 2 + 3] > 0.5 or forces[1, 2 + 4] > 0.5, forces[1]
    limit = 0.02 * 2.0
    assert 0.0 < float(g.contact.member_penetration) <= limit
    assert not g.penetration_warnings()
    off = fr.grasp(_finger(INCLINED, member_contact=False), closing=CLOSING)
    assert off.converged
    assert float(np.max(np.asarray(off.contact.member_force))) == 0.0
    without = smallest_clearance(off.finger, off.solution)
    assert without < -0.5
    assert smallest_clearance(g.finger, g.solution) >= -limit


def test_member_contact_is_internal(folded):
    """Member forces are internal: the base reactions, the object and the support still
    balance (to 1e-9 of the forces, Newton's tolerance) while crossbeams press on the
    back beam, and the members' stiffness enters the stability test symmetrically (the
    condensed stiffness's asymmetry is the integration's error, as without it)."""
    g = folded
    sol, c = g.solution, g.contact
    reactions = np.asarray(sol.reactions_front.force) + np.asarray(sol.reactions_back.force)
    total = reactions + np.asarray(c.force) + np.asarray(c.support_force)
    scale = max(np.max(np.abs(x)) for x in (reactions, c.force, c.support_force))
    np.testing.assert_allclose(total, 0.0, atol=1e-9 * scale)
    assert g.stability.asymmetry < 1e-3


@pytest.mark.slow
def test_members_apart_change_nothing():
    """Finger-1's modified grasp at 6 mm, where no members touch: the same normal force
    with member contact on (default) and off, to the integration's error from cutting
    the crossbeams into pieces (16 steps per piece against per crossbeam: 1e-6)."""
    on = fr.grasp(_finger(), closing=6.0)
    off = fr.grasp(_finger(member_contact=False), closing=6.0)
    assert on.converged and off.converged
    assert float(on.contact.member_penetration) == 0.0
    a, b = float(on.contact.normal_force), float(off.contact.normal_force)
    assert abs(a - b) <= 1e-6 * b, (a, b)
