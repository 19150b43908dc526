"""Grasp forces where they act: the objects', the support's and the reactions' shares of
a grasp against the finger's global balance and against what each contact can exert, and
the support's own penetration limit."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import contact_wrench, global_balance

import finray_jax as fr
import finray_jax.io
from finray_jax._geometry import geometry

EXAMPLES = (
    "examples/grasp_finger1.toml",
    "examples/grasp_finger1_modified.toml",
    "examples/grasp_finger1_modified_50mm.toml",
)
LIMITS = (0.002, 0.005, 0.02, 0.05)  # max_penetration: 0.2 % to 5 % of the thickness


def _example(path, limit):
    finger, settings = fr.io.load_finger(path)
    contact = dataclasses.replace(
        finger.contact, max_penetration=jnp.asarray(limit), friction=jnp.asarray(0.0)
    )
    return dataclasses.replace(finger, contact=contact), settings.grasp


_GRASPS = {}


def _grasp(path, limit):
    if (path, limit) not in _GRASPS:
        finger, grasp = _example(path, limit)
        _GRASPS[path, limit] = fr.grasp(finger, grasp.closing, direction=grasp.direction)
    return _GRASPS[path, limit]


CASES = [
    pytest.param(
        path,
        limit,
        id=f"{path.split('/')[-1][:-5]}-{limit:g}",
        marks=() if (path, limit) == (EXAMPLES[1], 0.002) else pytest.mark.slow,
    )
    for path in EXAMPLES
    for limit in LIMITS
]


@pytest.mark.parametrize("path,limit", CASES)
def test_every_contact_force_is_where_it_acts(path, limit):
    """Each shipped grasp example, frictionless, at penetration limits from 0.2 % to 5 %:

    - the objects, the support, the base reactions and the loads balance (forces and
      moments about the origin, to 1e-9 of the scale: every jump is enforced to Newton's
      tolerance, see test_contact's balance test; plus that tolerance through the
      stiffest penalty, below);
    - the objects touch the front beam only here, so their force is the front beam's
      contact force and the support's the back beam's, both from the solution's jumps of
      n alone (to 1e-9 of the scale);
    - a frictionless support pushes along its normal only (to rounding: n' is a multiple
      of the fixed normal), and a frictionless cylinder along radii: its wrench on the
      finger has no moment about the cylinder's centre. That moment is m + (p - c) x n
      carried through the segments, which the Runge-Kutta steps conserve to their
      truncation error only; with the stiffest penalty the contact patch spans a few of
      the 0.3 mm steps, and it is at most 5e-5 of force x radius. The bound, 1e-3 of it,
      is a line of action 9 um off the centre; the support's force (about 15 N, 40 mm
      away) credited to the cylinder misses it by 600 N mm (4 of force x radius);
    - both penetration limits hold, or the grasp says which does not (the 50 mm
      cylinder at 0.2 %: the back beam lies on the support along a stretch, and a stiffer
      support no longer converges on 5 mm shooting segments).
    """
    g = _grasp(path, limit)
    assert g.converged, g.status
    finger, sol, c = g.finger, g.solution, g.contact
    assert not np.any(np.asarray(c.pressure_back) > 0)  # objects touch the front beam only
    force, moment, _ = global_balance(finger, sol)
    f_obj, f_sup = np.asarray(c.force), np.asarray(c.support_force)
    front_f, front_m = contact_wrench(finger, sol, beams=(0,))
    back_f, back_m = contact_wrench(finger, sol, beams=(1,))
    reactions = np.asarray(sol.reactions_front.force) + np.asarray(sol.reactions_back.force)
    scale = max(np.max(np.abs(x)) for x in (f_obj, f_sup, reactions))
    length = float(np.linalg.norm(np.asarray(finger.tip) - np.asarray(finger.front_base)))
    assert scale > 1.0
    # Newton's position tolerance (1e-13 of the length) seen through the stiffest penalty
    # over one integration step: a stiff support turns it into a force error k eps h
    # (6e-7 N at k = 1.6e5 N/mm^2, the 50 mm cylinder at 0.2 %).
    k = max(float(g.stiffness), float(g.support_stiffness))
    h = finger.contact.segment_length / g.integrator.steps
    tol = 1e-9 * scale + k * 1e-13 * length * h
    np.testing.assert_allclose(force + f_obj + f_sup, 0.0, atol=tol)
    np.testing.assert_allclose(moment + front_m + back_m, 0.0, atol=tol * length)
    np.testing.assert_allclose(f_obj, front_f, atol=tol)
    np.testing.assert_allclose(f_sup, back_f, atol=tol)
    # The normal force is the objects' alone: at least their resultant, and not more than
    # a few percent above it on a convex contact patch of a few degrees.
    assert np.linalg.norm(f_obj) <= float(c.normal_force) <= 1.05 * np.linalg.norm(f_obj)
    (circle,) = finger.objects
    centre = np.insert(np.asarray(circle.center), 1, 0.0)
    radius = float(circle.radius)
    about_centre = front_m - np.cross(centre, front_f)
    assert abs(about_centre[1]) < 1e-3 * np.linalg.norm(f_obj) * radius, about_centre
    if finger.adaptor.support_length is not None:
        th = float(geometry(finger).theta[1])
        normal = -np.array([np.cos(th), 0.0, -np.sin(th)])
        assert np.dot(f_sup, normal) > 0.1 * scale  # it pushes the back beam forward
        assert abs(np.cross(f_sup, normal)[1]) < tol
        over = float(c.support_penetration) > limit * float(finger.back.thickness) * (1 + 1e-9)
        assert over == any("into the support" in w for w in g.penetration_warnings())
        assert not over or path.endswith("50mm.toml") and limit == 0.002
    else:
        np.testing.assert_array_equal(f_sup, 0.0)
    assert float(c.max_penetration) <= limit * float(finger.front.thickness) * (1 + 1e-9)


def test_the_support_obeys_its_own_penetration_limit():
    """Finger-1 on the modified adaptor closed 6 mm: by default the back beam sinks no
    deeper into the support than 2 % of its thickness, and a limit of its own is obeyed
    with a softer support than a tighter one needs."""
    g = _grasp(EXAMPLES[1], 0.02)
    thick = float(g.finger.back.thickness)
    assert 0.5 * 0.02 * thick < float(g.contact.support_penetration) <= 0.02 * thick
    assert g.penetration_warnings() == []
    finger, settings = _example(EXAMPLES[1], 0.02)
    loose = dataclasses.replace(
        finger,
        contact=dataclasses.replace(finger.contact, max_support_penetration=jnp.asarray(0.05)),
    )
    h = fr.grasp(loose, settings.closing, direction=settings.direction)
    assert h.converged
    assert 0.02 * thick < float(h.contact.support_penetration) <= 0.05 * thick
    assert float(h.support_stiffness) < float(g.support_stiffness)
    assert float(h.contact.max_penetration) <= 0.02 * float(finger.front.thickness)


def test_the_rigid_contact_estimate_approaches_the_closed_form():
    """A cylinder pressed into a cantilever (test_contact's closed form, linear theory
    good to ~1e-3): at a soft penalty the grasp is 2.3 % short of rigid contact; the
    estimate extrapolated from k, 4k and 16k is within 5e-3 of it, an order of the
    penalty's quadratic onset (about k^-1/2) is seen, and the distance it reports is the
    grasp's actual error within that margin."""
    from test_contact import T, _cantilever_finger, _flexibility

    a, radius, d, clear = 60.0, 1.0, 1.0, 0.05
    rigid = d / _flexibility(a)
    obj = fr.Circle((-(radius + T / 2) - clear, a), radius)
    g = fr.grasp(_cantilever_finger([obj], 0.1), d + clear, stiffen=False)
    est = fr.rigid_contact_estimate(g)
    own = (float(g.contact.force[0]) - rigid) / rigid
    assert own < -0.01
    assert abs(est.rigid["contact_force_x"] - rigid) < 5e-3 * rigid
    assert 0.3 < est.order["contact_force_x"] < 1.0
    assert abs(est.distance["contact_force_x"] - own) < 5e-3
    assert est.stiffness == (0.1, 0.4, 1.6)
