"""A cantilever wrapping a rigid cylinder under a tip force, solved from the undeformed
shape by `solve_finger` (its direct Newton fails: load continuation), against the
closed-form elastica (`helpers.wrapped_cantilever`).

The finger's front beam is the cantilever: clamped at its base, where it touches the
cylinder, with no crossbeams and the back beam a short stub free at its base (it carries
no load). A dead tip force toward the cylinder wraps the beam around it: the contact
begins at once along the beam near the clamp (a corner of the load path: the penalty
switches on within a penetration of a few hundredths of a millimetre) and then spreads
toward the tip.
"""

import numpy as np
import pytest
from helpers import wrapped_cantilever

import finray_jax as fr

E, T, DEPTH, L, CLEAR = 12.0, 1.5, 20.0, 120.0, 0.01
EI = E * DEPTH * T**3 / 12.0
EA = E * DEPTH * T
KGA = (5.0 / 6.0) * E / (2.0 * 1.45) * DEPTH * T
K = E * DEPTH / T  # the default penalty stiffness (N/mm^2)
FOUNDATION = (4.0 * EI / K) ** 0.25  # the penalty's elastic-foundation length (1.14 mm)


def _wrap_finger(P, radius, near=8):
    """The cantilever, the cylinder (centre level with the clamp, CLEAR from the beam's
    face) and the tip force P toward it."""
    return fr.Finger(
        material=fr.Material(E, 0.45),
        front_base=(0.0, 0.0),
        back_base=(-10.0, L - 5.0),
        tip=(0.0, L),
        front=fr.Section(T, DEPTH),
        back=fr.Section(T, DEPTH),
        crossbeams=fr.Crossbeams([], [], [], []),
        adaptor=fr.Adaptor(back_base=fr.FreeBase()),
        loads=(fr.PointLoad(0, L, (P, 0.0, 0.0)),),
        objects=(fr.Circle((radius + T / 2 + CLEAR, 0.0), radius),),
        contact=fr.Contact(near_segments=near),
    )


def _gap(sol, radius):
    """The front beam's gap to the cylinder along it (negative: penetration)."""
    p = np.asarray(sol.front.position)[:, [0, 2]]
    centre = np.array([radius + T / 2 + CLEAR, 0.0])
    return np.linalg.norm(p - centre, axis=1) - radius - T / 2


def test_continuation_wraps_a_cylinder_as_the_elastica():
    """P = 0.5 N wraps 64 degrees of a 25 mm cylinder, solved cold: the continuation
    crosses the corner of its path where contact begins. Against the rigid,
    inextensible closed form:

    * on the wrapped arc the moment is EI / Rc (the curvature 1 / Rc): to 1 %, the
      centreline's radius being Rc plus the penetration (delta / 2 = 0.0075 mm here) and
      the clamp's CLEAR;
    * the contact ends at s = Rc phi to within 2 foundation lengths (2.3 mm) and a
      sampling step (0.5 mm): the penalty spreads rigid contact's point force at the
      lift-off over a few foundation lengths (4 EI / k)^(1/4);
    * the tip lies within P L (1 / EA + 1 / kGA) of the closed form's (0.75 mm), the
      most the rod's extension and shear under forces below P can move it."""
    radius, P = 25.0, 0.5
    rc = radius + T / 2
    phi, _, x_tip, z_tip = wrapped_cantilever(P, EI, L, rc)
    assert np.degrees(phi) > 60.0

    sol = fr.solve_finger(_wrap_finger(P, radius), mode="planar")
    assert sol.converged, sol.message
    assert float(sol.load_factor) == 1.0

    s = np.asarray(sol.front.s)
    a = rc * phi
    wrapped = (s > 0.25 * a) & (s < 0.75 * a)
    moment = np.asarray(sol.front.moment)[:, 1]
    np.testing.assert_allclose(np.abs(moment[wrapped]) * rc / EI, 1.0, atol=0.01)
    end = s[_gap(sol, radius) < 0.0].max()
    assert abs(end - a) < 2.0 * FOUNDATION + 0.5
    tip = np.asarray(sol.tip.position)[[0, 2]]
    assert np.hypot(*(tip - (x_tip, z_tip))) < P * L * (1.0 / EA + 1.0 / KGA)


@pytest.mark.slow  # (~40 s: the warm start's core compiles)
def test_continuation_gives_the_warm_started_load_steps_root():
    """The continuation from the undeformed shape reaches the root that warm-started
    load steps (each solve starting from the one before) reach."""
    radius = 25.0
    cold = fr.solve_finger(_wrap_finger(0.5, radius), mode="planar")
    warm = fr.solve_finger(_wrap_finger(0.25, radius), mode="planar")
    for P in (0.35, 0.5):
        warm = fr.solve_finger(_wrap_finger(P, radius), mode="planar", init=warm)
        assert warm.converged, warm.message
    assert cold.converged, cold.message
    np.testing.assert_allclose(cold.unknowns, warm.unknowns, rtol=0, atol=1e-8)


def test_contact_beyond_the_near_segments_is_named_along_the_continuation():
    """On a 40 mm cylinder P = 0.3 N wraps 69 degrees, 49 mm: more than the 8 near
    segments of 5 mm. The continuation stops there and says so (not that its arc step
    collapsed)."""
    radius, P = 40.0, 0.3
    phi = wrapped_cantilever(P, EI, L, radius + T / 2)[0]
    assert (radius + T / 2) * phi > 8 * 5.0
    sol = fr.solve_finger(_wrap_finger(P, radius), mode="planar")
    assert sol.result == fr.RESULTS.contact_outside_near_segments
    assert "Contact.near_segments" in sol.message and "continuation" in sol.message
    assert 0.0 < float(sol.load_factor) < 1.0
