"""Contact: objects' signed distances, the penalty law, closed forms, equilibrium,
symmetry, the unilateral support, bad input and the holding force."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import contact_wrench, global_balance, without_jacobian

import finray_jax as fr
import finray_jax.io
from finray_jax._closing import closing_step_cap as _closing_step_cap
from finray_jax._contact import penalty
from finray_jax._grasp_inputs import with_stiffness
from finray_jax._solve import direct_core
from finray_jax._stepper import Stepper

# ---------------------------------------------------------------------------------------
# Objects and the penalty law
# ---------------------------------------------------------------------------------------

OBJECTS = [
    fr.Circle((1.0, 2.0), 3.0),
    fr.Ellipse((0.5, -1.0), (4.0, 1.5), 0.4),
    fr.RoundedRectangle((2.0, 1.0), (3.0, 1.5), 0.5, -0.3),
    fr.Polygon([[0.0, 0.0], [4.0, 0.0], [1.0, 3.0]], (1.0, 1.0), 0.25, 0.7),
]


def _polyline_distance(points, p):
    a, b = points[:-1], points[1:]
    e = b - a
    t = np.clip(np.sum((p - a) * e, axis=1) / np.maximum(np.sum(e * e, axis=1), 1e-300), 0, 1)
    return float(np.min(np.linalg.norm(a + t[:, None] * e - p, axis=1)))


@pytest.mark.parametrize("obj", OBJECTS, ids=lambda o: o.kind)
def test_distance_is_zero_on_the_outline_and_exact_outside(obj):
    outline = obj.outline(400)
    assert np.max(np.abs(np.asarray(obj.signed_distance(outline)))) < 1e-9
    # Outside points: the distance equals the distance to a dense outline.
    rng = np.random.default_rng(0)
    dense = obj.outline(4000)
    center = dense.mean(axis=0)
    for _ in range(5):
        direction = rng.normal(size=2)
        p = center + 8.0 * direction / np.linalg.norm(direction)
        d = float(obj.signed_distance(p))
        assert d > 0
        assert abs(d - _polyline_distance(dense, p)) < 1e-5
    # Inside the centre the distance is negative; its gradient outside is a unit vector.
    assert float(obj.signed_distance(center)) < 0
    q = obj.params()
    g = jax.grad(lambda x: obj.distance(q, x))(jnp.asarray(center + 8.0 * np.array([0.6, 0.8])))
    assert abs(float(jnp.linalg.norm(g)) - 1.0) < 1e-9


@pytest.mark.parametrize(
    "obj", OBJECTS + [fr.HalfPlane((1.0, 0.5), (0.6, -0.8))], ids=lambda o: o.kind
)
def test_closed_form_normal_is_the_distance_gradient(obj):
    """`distance_and_normal`'s closed-form normal (what the contact rhs evaluates) is the
    autodiff gradient of its distance, at points inside, near and far outside (random, so
    almost surely off the kinks of the distance field)."""
    q = obj.params()
    center = obj.outline(400).mean(axis=0)
    rng = np.random.default_rng(3)
    pts = center + rng.normal(size=(60, 2)) * np.array([[0.5], [2.0], [6.0]]).repeat(20, 0)
    d_ref, g_ref = jax.vmap(jax.value_and_grad(lambda x: obj.distance(q, x)))(jnp.asarray(pts))
    d, nx, nz = jax.vmap(obj.distance_and_normal, in_axes=(None, 0, 0))(q, pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.stack([nx, nz], -1), g_ref, rtol=0, atol=1e-9)
    assert np.any(np.asarray(d_ref) < 0) and np.any(np.asarray(d_ref) > 0)


ELLIPSES = [  # (centre, semi-axes, angle): a circle, both orientations, a/b = 10, turned
    ((0.0, 0.0), (3.0, 3.0), 0.0),
    ((0.0, 0.0), (3.0, 1.0), 0.0),
    ((0.0, 0.0), (1.0, 3.0), 0.0),
    ((0.0, 0.0), (10.0, 1.0), 0.0),
    ((2.0, -1.0), (1.0, 10.0), 0.7),
    ((0.5, -1.0), (4.0, 1.5), 0.4),
]


def _ellipse_test_points(a, b, rng):
    """Local points: the centre, both axes (inside and out), random inside and out."""
    s = np.linspace(-1.6, 1.6, 33)
    r, phi = np.sqrt(rng.uniform(0.0, 1.0, 120)), rng.uniform(0.0, 2.0 * np.pi, 120)
    return np.concatenate(
        [
            [[0.0, 0.0]],
            np.stack([s * a, 0.0 * s], -1),
            np.stack([0.0 * s, s * b], -1),
            np.stack([a * r * np.cos(phi), b * r * np.sin(phi)], -1),  # inside
            rng.uniform(-2.0, 2.0, (120, 2)) * max(a, b),
        ]
    )


@pytest.mark.parametrize("center, axes, angle", ELLIPSES)
def test_ellipse_distance_is_exact_inside_and_out(center, axes, angle):
    """Against the nearest of 100k points on the boundary (the sign from the implicit
    equation), at points inside (the centre and the axes included), on the axes and
    outside; the centre (where the distance is -b) and the points deep inside near the
    major axis are the hard cases."""
    a, b = axes
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    local = _ellipse_test_points(a, b, np.random.default_rng(7))
    pts = np.asarray(center) + local @ rot.T
    t = np.linspace(0.0, 2.0 * np.pi, 100_000, endpoint=False)
    boundary = np.stack([a * np.cos(t), b * np.sin(t)], -1)
    spacing = np.max(np.linalg.norm(np.diff(boundary, axis=0, append=boundary[:1]), axis=1))
    nearest = np.array(
        [np.min(np.linalg.norm(boundary - p, axis=1)) for p in local]  # (local frame)
    )
    ref = np.sign((local[:, 0] / a) ** 2 + (local[:, 1] / b) ** 2 - 1.0) * nearest
    d = np.asarray(fr.Ellipse(center, axes, angle).signed_distance(pts))
    # the nearest sample is at most half a spacing farther than the nearest point
    assert np.all(np.abs(d) <= nearest + 1e-9)
    assert np.max(np.abs(d - ref)) <= 0.5 * spacing
    assert d[0] == pytest.approx(-min(a, b), abs=1e-12)
    assert np.all(np.sign(d[nearest > spacing]) == np.sign(ref[nearest > spacing]))


@jax.jit
@jax.vmap
def _ellipse_grads_one(q, p):
    d, g_p = jax.value_and_grad(fr.Ellipse.distance, argnums=1)(q, p)
    return d, g_p, jax.grad(fr.Ellipse.distance)(q, p)


def _ellipse_grads(q, p):
    """Distances at points p (n, 2), their gradients in p and in the parameters q."""
    return _ellipse_grads_one(jnp.broadcast_to(q, (p.shape[0],) + q.shape), p)


@pytest.mark.parametrize("center, axes, angle", ELLIPSES)
def test_ellipse_distance_gradient_is_the_normal_and_finite(center, axes, angle):
    """Near the surface the gradient is the outward normal (and the closed-form normal);
    everywhere, the centre and the axes included, the gradients in the point and in the
    parameters are finite and the closed-form normal is a unit vector."""
    a, b = axes
    ell = fr.Ellipse(center, axes, angle)
    q = ell.params()
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    t = np.linspace(0.0, 2.0 * np.pi, 73)
    normal = np.stack([b * np.cos(t), a * np.sin(t)], -1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    depth = 0.02 * min(a, b) ** 2 / max(a, b)  # within the smallest radius of curvature
    for off in (-depth, 0.0, depth):
        local = np.stack([a * np.cos(t), b * np.sin(t)], -1) + off * normal
        d, g, _ = _ellipse_grads(q, jnp.asarray(np.asarray(center) + local @ rot.T))
        np.testing.assert_allclose(d, off, rtol=0, atol=1e-12)
        np.testing.assert_allclose(g, normal @ rot.T, rtol=0, atol=1e-9)
    local = _ellipse_test_points(a, b, np.random.default_rng(8))
    p = jnp.asarray(np.asarray(center) + local @ rot.T)
    _, g_p, g_q = _ellipse_grads(q, p)
    _, nx, nz = jax.vmap(ell.distance_and_normal, in_axes=(None, 0, 0))(q, p[:, 0], p[:, 1])
    assert np.all(np.isfinite(g_p)) and np.all(np.isfinite(g_q))
    np.testing.assert_allclose(np.hypot(nx, nz), 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(g_p, axis=1), 1.0, rtol=0, atol=1e-9)


def test_half_plane_distance():
    h = fr.HalfPlane((1.0, 0.0), (2.0, 0.0))
    assert float(h.signed_distance(np.array([3.0, 5.0]))) == pytest.approx(2.0)
    assert float(h.signed_distance(np.array([0.0, -5.0]))) == pytest.approx(-1.0)


def test_penalty_is_zero_before_contact_and_continuously_differentiable():
    k, delta = 100.0, 0.01
    assert float(penalty(0.0, k, delta)) == 0.0
    assert float(penalty(0.5, k, delta)) == 0.0
    dq = jax.grad(penalty)
    for x in (0.0, -delta):  # the joints of the ramp: value and slope continuous
        for f in (penalty, dq):
            assert abs(float(f(x + 1e-12, k, delta)) - float(f(x - 1e-12, k, delta))) < 1e-6
    # linear beyond delta: q = k (x - delta / 2)
    assert float(penalty(-0.1, k, delta)) == pytest.approx(k * (0.1 - delta / 2))


# ---------------------------------------------------------------------------------------
# Closed forms: the front beam as a cantilever (back beam free at its base, no
# crossbeams: it carries no load and the front beam is a plain cantilever).
# ---------------------------------------------------------------------------------------

E, T, DEPTH, L = 12.0, 1.5, 20.0, 120.0


def _cantilever_finger(objects, stiffness, loads=()):
    return fr.Finger(
        material=fr.Material(E, 0.45),
        front_base=(0.0, 0.0),
        back_base=(40.0, 0.0),
        tip=(0.0, L),
        front=fr.Section(T, DEPTH),
        back=fr.Section(T, DEPTH),
        crossbeams=fr.Crossbeams([], [], [], []),
        adaptor=fr.Adaptor(back_base=fr.FreeBase()),
        loads=tuple(loads),
        objects=tuple(objects),
        contact=fr.Contact(stiffness=stiffness, max_penetration=0.002),
    )


def _flexibility(a):
    """Deflection per unit force at s = a of a Timoshenko cantilever loaded at a."""
    EI = E * DEPTH * T**3 / 12.0
    kGA = (5.0 / 6.0) * E / (2 * 1.45) * DEPTH * T
    return a**3 / (3 * EI) + a / kGA


def test_cylinder_pressed_into_a_cantilever_converges_to_rigid_contact():
    """A thin cylinder (radius 1) pushed d = 1 mm past first touch at s = a = 60: in the
    rigid-contact limit the beam deflects by d there, so the force is d / flexibility(a)
    (linear theory; the nonlinear terms and the shift of the contact point around the
    cylinder are ~1e-3 here). The penalty force approaches it as the penalty stiffens
    (the penetration, which the beam does not feel, shrinks)."""
    a, radius, d, clear = 60.0, 1.0, 1.0, 0.05
    rigid = d / _flexibility(a)
    errors = []
    for k in (0.1, 1.0, 10.0):
        obj = fr.Circle((-(radius + T / 2) - clear, a), radius)
        finger = _cantilever_finger([obj], k)
        g = fr.grasp(finger, d + clear, stiffen=False)
        assert g.converged
        assert abs(float(g.contact.force[2])) < 0.05 * rigid
        errors.append(abs(float(g.contact.force[0]) - rigid) / rigid)
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] > 3.0 * errors[2]
    assert errors[2] < 5e-3


def test_tip_pressed_onto_a_wall_converges_to_rigid_contact():
    """A tip force P pushes the cantilever's tip onto a flat wall a = 0.5 mm away (the free
    deflection would be 1.5 mm): the wall carries P - a / flexibility(L)."""
    gap = 0.5
    P = 3.0 * gap / _flexibility(L)
    wall = fr.HalfPlane((-(T / 2 + gap), 0.0), (1.0, 0.0))
    load = fr.PointLoad(0, L, (-P, 0.0, 0.0))
    rigid = P - gap / _flexibility(L)
    errors = []
    for k in (0.01, 0.1, 1.0):
        finger = _cantilever_finger([wall], k, [load])
        stepper = Stepper(finger, "planar", fr.Integrator(steps=16), fr.SolverOptions())
        t, sol, ok = stepper.follow(finger.scale_loads, 0.0, 1.0, None, 0.25, 1e-4)
        assert ok and t == 1.0
        res = fr.contact_result(finger, sol, (-1.0, 0.0))
        errors.append(abs(float(res.force[0]) - rigid) / rigid)
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] > 3.0 * errors[2]
    assert errors[2] < 5e-3


def _with_near(finger, near):
    return eqx.tree_at(
        lambda f: f.contact,
        finger,
        fr.Contact(
            stiffness=finger.contact.stiffness,
            max_penetration=finger.contact.max_penetration,
            near_segments=near,
        ),
    )


def _pressed_onto_a_wall():
    """A distributed load presses the cantilever's outer half onto a parallel wall: 14 of
    its 24 segments touch."""
    wall = fr.HalfPlane((-(T / 2 + 0.3), 0.0), (1.0, 0.0))
    load = fr.DistributedLoad(0, (60.0, 120.0), (-0.3, 0.0, 0.0))
    return _cantilever_finger([wall], 0.1, [load])


def test_too_few_near_segments_is_reported():
    """The default suite's share of the slow test below (one compile): with contact on 8
    segments only, the direct solve stops with the result that names the setting."""
    finger = _with_near(_pressed_onto_a_wall(), 8)
    topo = fr.topology_of(finger, "planar")
    sol, _, _ = direct_core(
        topo, fr.Integrator(steps=16), fr.SolverOptions(), finger, None, np.float64(0.0)
    )
    assert not sol.converged
    assert sol.result == fr.RESULTS.contact_outside_near_segments
    assert "Contact.near_segments" in f"{fr.RESULTS[sol.result]}"


@pytest.mark.slow  # (97-106 s: three contact solves of their own compile)
def test_a_warm_start_with_contact_begins_on_the_factors():
    """A warm start from a solution's Jacobian factors, with contact on the near segments:
    its first chord step reads the residual at the start (later ones read the residual
    that the backtracking of the step before left where it ends, which does not exist
    yet; zeros there would stop Newton at the start). It reaches the root of a start
    without the factors."""
    finger = _with_near(_pressed_onto_a_wall(), 16)
    integrator = fr.Integrator(steps=16)
    base = fr.solve_finger(finger, mode="planar", integrator=integrator)
    assert base.converged and base.jacobian is not None
    plain_init = without_jacobian(base)
    for factor in (1.05, 1.2):
        pressed = finger.scale_loads(factor)
        plain = fr.solve_finger(pressed, mode="planar", integrator=integrator, init=plain_init)
        warm = fr.solve_finger(pressed, mode="planar", integrator=integrator, init=base)
        assert plain.converged and warm.converged
        gap = np.abs(np.asarray(warm.front.position) - np.asarray(plain.front.position))
        assert np.max(gap) < 1e-9
        assert np.max(np.abs(np.asarray(warm.tip.position - base.tip.position))) > 1e-3
    assert int(warm.iterations) != int(plain.iterations)  # (the factors were used)


@pytest.mark.slow  # (139 s: three contact topologies and a path solver compile)
def test_contact_beyond_the_near_segments_is_found():
    """The cantilever pressed onto a wall (`_pressed_onto_a_wall`). A Newton solve that
    evaluates contact on fewer segments than touch must say so (it chooses the near
    segments three times, each time finding contact outside); with enough of them it finds
    the whole finger's root, which every segment gives."""
    base = _pressed_onto_a_wall()
    solutions = {}
    for near in (None, 8, 16):
        finger = _with_near(base, near)
        topo = fr.topology_of(finger, "planar")
        assert topo.contact.near == near
        sol, _, _ = direct_core(
            topo, fr.Integrator(steps=16), fr.SolverOptions(), finger, None, np.float64(0.0)
        )
        solutions[near] = sol
    full = solutions[None]
    assert full.converged
    touching = np.asarray(fr.contact_result(base, full, (-1.0, 0.0)).max_penetration) > 0
    assert touching
    assert solutions[8].result == fr.RESULTS.contact_outside_near_segments
    assert "Contact.near_segments" in f"{fr.RESULTS[solutions[8].result]}"
    assert solutions[16].converged
    np.testing.assert_allclose(solutions[16].unknowns, full.unknowns, rtol=0, atol=1e-9)
    # The path solver of grasp and release_force goes on with every segment instead.
    finger = _with_near(base, 8)
    stepper = Stepper(finger, "planar", fr.Integrator(steps=16), fr.SolverOptions())
    _, sol, ok = stepper.follow(finger.scale_loads, 0.0, 1.0, None, 1.0, 1.0)
    assert ok and stepper.topo.contact.near is None
    np.testing.assert_allclose(sol.unknowns, full.unknowns, rtol=0, atol=1e-9)


# ---------------------------------------------------------------------------------------
# Grasps of the default finger
# ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def finger1():
    finger, _ = fr.io.load_finger("examples/finger1.toml")
    return eqx.tree_at(lambda f: f.objects, finger.with_loads(), (fr.Circle((-11.0, 60.0), 9.0),))


MODIFIED = fr.Adaptor(front_base=fr.PinnedBase(), back_clamp_length=20.0, support_length=60.0)


def test_a_flat_face_pressed_on_the_front_beam(finger1):
    """A box's flat face 0.5 mm in front of the straight front beam first touches it all
    along (14 segments), more than the near ones: the grasp goes on with every segment
    and gives the grasp of a finger that always uses every segment."""
    box = fr.RoundedRectangle((-22.0, 75.0), (20.0, 35.0), corner_radius=2.0)
    finger = eqx.tree_at(lambda f: f.objects, finger1, (box,))
    g = fr.grasp(finger, 3.0)
    assert g.converged and g.topology.contact.near is None
    assert float(g.contact.normal_force) > 0.1
    assert float(g.contact.max_penetration) <= 0.02 * float(finger.front.thickness)
    every = fr.grasp(_with_near(finger, None), 3.0)
    assert float(g.closing) == float(every.closing) == 3.0
    np.testing.assert_allclose(g.solution.unknowns, every.solution.unknowns, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def grasps(finger1):
    original = fr.grasp(finger1, 5.0)
    modified = fr.grasp(eqx.tree_at(lambda f: f.adaptor, finger1, MODIFIED), 5.0)
    return original, modified


@pytest.mark.parametrize("which", [0, 1], ids=["original", "modified"])
def test_grasp_balances_and_respects_the_penetration_limit(grasps, finger1, which):
    """Force and moment balance of the whole finger: the objects' contact force (the
    library's ContactResult.force) and the support's force, with the contact moment from
    the solution (helpers.contact_wrench), plus the base reactions and the loads, sum to
    zero. Moments are about the origin (the front beam's base). Scale: the largest force
    term times the finger's length (front beam length, 120 mm), N mm; forces are compared
    with the largest force term. Every junction and jump is enforced to Newton's tolerance
    (scaled residual ~1e-13) and n and m + p x n are carried through each segment exactly
    by the segment jumps that define the contact wrench, so the sums are zero to rounding:
    1e-9 of the scale."""
    g = grasps[which]
    assert g.converged
    sol, finger = g.solution, g.finger
    assert float(g.contact.normal_force) > 0.1
    force, moment, _ = global_balance(finger, sol)  # reactions and loads
    c_force, c_moment = contact_wrench(finger, sol)
    forces = [
        np.asarray(x)
        for x in (
            sol.reactions_front.force,
            sol.reactions_back.force,
            g.contact.force,
            g.contact.support_force,
        )
    ]
    largest = max(float(np.max(np.abs(f))) for f in forces)
    length = float(np.linalg.norm(np.asarray(finger.tip) - np.asarray(finger.front_base)))
    assert largest > 0.1 and length > 100.0
    # The wrench taken from the solution is the objects' and the support's together.
    np.testing.assert_allclose(c_force, forces[2] + forces[3], rtol=0, atol=1e-9 * largest)
    total_force = force + forces[2] + forces[3]
    total_moment = moment + c_moment
    assert np.max(np.abs(total_force)) < 1e-9 * largest, total_force
    assert np.max(np.abs(total_moment)) < 1e-9 * largest * length, total_moment
    # The contact's moment is not negligible against the scale (the check is not vacuous).
    assert np.max(np.abs(c_moment)) > 1e-2 * largest * length
    assert float(g.contact.max_penetration) <= 0.02 * float(finger1.front.thickness) + 1e-12
    assert float(g.contact.contact_length) > 0
    assert float(g.contact.actuator_force) > 0


def _line_of_action_s(beam, force, moment):
    """Arc length at which the deformed centreline crosses the line of action of a planar
    wrench (force, moment about the origin): (p(s) x F)_y = M_y, with p interpolated
    linearly between solution points (the root moves along the beam, across F, where that
    interpolation is exact to first order)."""
    s, p = np.asarray(beam.s), np.asarray(beam.position)
    gap = np.cross(p, force)[:, 1] - moment[1]
    i = np.flatnonzero(np.diff(np.sign(gap)) != 0)
    assert i.size == 1, i
    i = int(i[0])
    return float(s[i] - gap[i] * (s[i + 1] - s[i]) / (gap[i + 1] - gap[i]))


def test_a_point_like_contact_equals_its_point_load(finger1, grasps):
    """A stiff 1 mm cylinder pressed 1 mm into Finger-1's front beam between crossbeams
    (s = 52.5) touches it over about 0.66 mm. Statically, its pressure is its resultant F
    acting on its line of action, which meets the centreline at s_c; the same finger with
    a point load F at s_c (no objects) must give the same tip, to

    - the smoothing error of spreading F over the patch: with the tip displacement u(s)
      under F at s, and the pressure's variance sigma^2 about s_c (at most a^2 for a patch
      of half-length a), |du| <= a^2 / 2 |u''(s_c)|; u'' is taken from point-load solves
      at s_c +- 1 mm (the same span between crossbeams: same compiled program);
    - the grasp's integration error at its 16 steps per segment (the C1 penalty gives
      second order): its tip moves by 1.1e-5 mm from 16 to 32 steps, so by Richardson the
      16-step tip is off by 1.5e-5 mm; 3e-5 mm is allowed for it.
    The point-load solve's own integration error (10 Tsit5 steps per segment) is below
    1e-9 mm. Both bounds together are ~2e-4 of the 0.107 mm tip displacement; a contact
    force or lever arm off by that much fails. (`grasps` is requested so that the grasp
    program, the same for any one cylinder on Finger-1, is compiled once per module.)"""
    radius, a, depth, clear = 1.0, 52.5, 1.0, 0.05
    t = float(finger1.front.thickness)
    cyl = fr.Circle((-(radius + t / 2) - clear, a), radius)
    g = fr.grasp(eqx.tree_at(lambda f: f.objects, finger1, (cyl,)), depth + clear)
    assert g.converged
    sol = g.solution
    force = np.asarray(g.contact.force)
    c_force, c_moment = contact_wrench(g.finger, sol)
    np.testing.assert_allclose(c_force, force, rtol=0, atol=1e-12)
    assert float(np.linalg.norm(g.contact.support_force)) == 0.0
    s_c = _line_of_action_s(sol.front, force, c_moment)
    half = 0.5 * float(g.contact.contact_length)
    assert abs(s_c - a) < half < 1.0  # point-like, and s_c inside the patch

    bare = eqx.tree_at(lambda f: f.objects, finger1, ())
    topo = fr.topology_of(bare.with_loads(fr.PointLoad(0, s_c, tuple(force))), "planar")

    def tip(s):
        f = bare.with_loads(fr.PointLoad(0, s, tuple(force)))
        point = fr.solve_finger(f, topology=topo)
        assert point.converged
        return np.asarray(point.tip.displacement)

    h = 1.0
    u_minus, u_c, u_plus = tip(s_c - h), tip(s_c), tip(s_c + h)
    curvature = np.abs(u_plus - 2.0 * u_c + u_minus) / h**2  # |u''(s_c)| per component
    tol = 0.5 * half**2 * curvature + 3e-5
    diff = np.abs(np.asarray(sol.tip.displacement) - u_c)
    assert np.all(diff <= tol), (diff, tol)
    assert np.linalg.norm(u_c) > 0.05  # the load really moves the tip


def test_modified_adaptor_grips_harder(grasps):
    original, modified = grasps
    assert float(modified.contact.normal_force) > 2.0 * float(original.contact.normal_force)
    # the support pushes the back beam forward only (toward the front beam: -x here)
    assert float(modified.contact.support_force[0]) < 0
    assert float(jnp.linalg.norm(original.contact.support_force)) == 0.0


def test_mirrored_finger_grasps_symmetrically(finger1, grasps):
    """A finger mirrored about x = 0 with the object mirrored: mirrored forces."""
    mirror = lambda p: (-p[0], p[1])
    m = eqx.tree_at(
        lambda f: (f.front_base, f.back_base, f.tip),
        finger1,
        tuple(jnp.asarray(mirror(p)) for p in (finger1.front_base, finger1.back_base, finger1.tip)),
    )
    m = eqx.tree_at(lambda f: f.objects, m, (fr.Circle((11.0, 60.0), 9.0),))
    g = fr.grasp(m, 5.0, direction=(1.0, 0.0))
    ref = grasps[0].contact
    assert float(g.contact.force[0]) == pytest.approx(-float(ref.force[0]), rel=1e-8)
    assert float(g.contact.force[2]) == pytest.approx(float(ref.force[2]), rel=1e-6, abs=1e-9)
    assert float(g.contact.normal_force) == pytest.approx(float(ref.normal_force), rel=1e-8)


@pytest.mark.slow  # (67 s: two adaptors' topologies, each with its continuation, compile)
def test_unilateral_support_never_pulls(finger1):
    """Pull the back beam forward (away from the support): the support carries nothing and
    the answer equals the finger without a support; push it backward: the support pushes
    forward only."""
    base = eqx.tree_at(lambda f: f.objects, finger1, ())
    with_support = eqx.tree_at(
        lambda f: f.adaptor, base, fr.Adaptor(back_clamp_length=10.0, support_length=60.0)
    )
    without = eqx.tree_at(lambda f: f.adaptor, base, fr.Adaptor(back_clamp_length=10.0))
    for sign in (-1.0, 1.0):
        load = fr.PointLoad(1, 40.0, (sign * 0.5, 0.0, 0.0))
        a = fr.solve_finger(with_support.with_loads(load), mode="planar")
        b = fr.solve_finger(without.with_loads(load), mode="planar")
        assert a.converged and b.converged
        res = fr.contact_result(with_support.with_loads(load), a, (-1.0, 0.0))
        x_a = np.interp(40.0, np.asarray(a.back.s), np.asarray(a.back.position[:, 0]))
        x_b = np.interp(40.0, np.asarray(b.back.s), np.asarray(b.back.position[:, 0]))
        if sign < 0:  # forward: no contact with the support, the same answer (to the
            # integration error: the support cuts the back beam into more segments)
            assert float(jnp.linalg.norm(res.support_force)) == 0.0
            assert float(jnp.max(jnp.abs(a.tip.displacement - b.tip.displacement))) < 1e-6
            assert abs(x_a - x_b) < 1e-6
        else:  # backward: the support pushes toward -x and reduces the motion
            assert float(res.support_force[0]) < -0.1
            assert x_a < x_b
    # balance with the support's force included
    load = fr.PointLoad(1, 40.0, (0.5, 0.0, 0.0))
    a = fr.solve_finger(with_support.with_loads(load), mode="planar")
    res = fr.contact_result(with_support.with_loads(load), a, (-1.0, 0.0))
    total = a.reactions_front.force + a.reactions_back.force + res.support_force
    assert float(jnp.max(jnp.abs(total + jnp.array([0.5, 0.0, 0.0])))) < 1e-6


def test_zero_clamp_length_without_support_is_the_original_adaptor(finger1, grasps):
    g = fr.grasp(eqx.tree_at(lambda f: f.adaptor, finger1, fr.Adaptor(back_clamp_length=0.0)), 5.0)
    assert float(g.contact.normal_force) == pytest.approx(
        float(grasps[0].contact.normal_force), rel=1e-12
    )


def test_balance_helper_agrees_for_loads_only(finger1):
    """The global balance helper of the core tests still holds with a support present and
    no contact (guards the segment table rewrite)."""
    f = eqx.tree_at(lambda f: f.objects, finger1, ())
    f = f.with_loads(fr.PointLoad(0, 60.0, (0.5, 0.0, 0.0)))
    sol = fr.solve_finger(f, mode="planar")
    assert sol.converged
    force, moment, _ = global_balance(f, sol)
    assert max(float(jnp.max(jnp.abs(force))), float(jnp.max(jnp.abs(moment)))) < 1e-8


# ---------------------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------------------


def test_bad_input_is_named(finger1):
    with pytest.raises(fr.FingerError, match=r"objects\[0\] \(circle\) overlaps the front beam"):
        fr.validate_finger(
            eqx.tree_at(lambda f: f.objects, finger1, (fr.Circle((-1.0, 60.0), 9.0),))
        )
    with pytest.raises(fr.FingerError, match=r"objects\[0\] \(circle\) is outside the reach"):
        fr.grasp(eqx.tree_at(lambda f: f.objects, finger1, (fr.Circle((-20.0, 200.0), 9.0),)), 5.0)
    with pytest.raises(fr.FingerError, match=r"objects\[0\] \(circle\) lies behind"):
        fr.grasp(eqx.tree_at(lambda f: f.objects, finger1, (fr.Circle((80.0, 60.0), 9.0),)), 5.0)
    with pytest.raises(fr.FingerError, match=r"contact.friction must be non-negative, got -0.2"):
        fr.validate_finger(eqx.tree_at(lambda f: f.contact, finger1, fr.Contact(friction=-0.2)))
    with pytest.raises(fr.FingerError, match=r"adaptor.support_length = 5.0 must lie in"):
        fr.validate_finger(
            eqx.tree_at(
                lambda f: f.adaptor, finger1, fr.Adaptor(back_clamp_length=20.0, support_length=5.0)
            )
        )
    with pytest.raises(fr.FingerError, match=r"objects\[0\].radius must be positive"):
        fr.validate_finger(
            eqx.tree_at(lambda f: f.objects, finger1, (fr.Circle((-11.0, 60.0), -1.0),))
        )
    with pytest.raises(fr.FingerError, match=r"convex polygon"):
        bad = fr.Polygon([[0.0, 0.0], [0.0, 3.0], [3.0, 0.0]], (-20.0, 60.0))  # clockwise
        fr.validate_finger(eqx.tree_at(lambda f: f.objects, finger1, (bad,)))
    with pytest.raises(fr.FingerError, match=r"closing must be a non-negative"):
        fr.grasp(finger1, -1.0)
    # grasp validates the finger once, itself: an overlap and a non-finger are caught
    with pytest.raises(fr.FingerError, match=r"objects\[0\] \(circle\) overlaps the front beam"):
        fr.grasp(eqx.tree_at(lambda f: f.objects, finger1, (fr.Circle((-1.0, 60.0), 9.0),)), 5.0)
    with pytest.raises(TypeError, match=r"expected a Finger, got dict"):
        fr.grasp({"objects": ()}, 5.0)
    with pytest.raises(fr.FingerError, match=r"friction must be a non-negative"):
        fr.release_force(fr.grasp(finger1, 0.0), friction=-0.1)


# ---------------------------------------------------------------------------------------
# Holding force
# ---------------------------------------------------------------------------------------


def test_holding_force_grows_with_closing_and_with_friction(finger1):
    peaks = []
    for closing in (3.0, 6.0):
        g = fr.grasp(finger1, closing)
        tr = fr.release_force(g, step=3.0)
        assert tr.complete, tr.message
        peaks.append(tr.peak)
    assert peaks[0] > 0 and peaks[1] > peaks[0]
    # mu = 0 is the purely geometric resistance; friction adds to it
    g = fr.grasp(finger1, 6.0)
    rough = fr.release_force(g, step=3.0, friction=0.3)
    assert rough.peak > peaks[1]


def _rough(f, mu=0.3):
    values = (jnp.asarray(mu), jnp.asarray([0.0, 1.0]))
    return eqx.tree_at(lambda f: (f.contact.friction, f.contact.slip_direction), f, values)


def test_a_frictionless_topology_is_refused_where_friction_acts(finger1, grasps):
    """A grasp closes without slip, so its topology leaves the friction law out of the
    rhs; a finger whose friction acts refuses that topology, naming both values."""
    original, _ = grasps
    assert original.topology.contact.friction is False
    with pytest.raises(fr.FingerError, match=r"contact.friction = 0.3 .*slip_direction"):
        fr.solve_finger(_rough(finger1), topology=original.topology)
    with pytest.raises(fr.FingerError, match="frictionless"):
        fr.regrasp(original, _rough(finger1))


@pytest.mark.slow  # (100 s: two frictional topologies compile)
def test_friction_is_left_out_only_where_it_cannot_act(grasps):
    """The grasp's stepper switches the friction law on where friction acts
    (`with_friction`), matching a topology built with friction. A frictionless finger
    gets the same answer with the law in or out."""
    original, _ = grasps

    def solve(finger, topology):
        st = Stepper(finger, "planar", original.integrator, fr.SolverOptions(), False, topology)
        sol, ok = st.solve(finger, original.solution.unknowns)
        assert ok
        return st.topo, sol.unknowns

    topo, a = solve(_rough(original.finger), original.topology)
    assert topo == fr.with_friction(original.topology) and topo.contact.friction
    _, b = solve(_rough(original.finger), None)
    assert float(jnp.max(jnp.abs(a - b))) < 1e-12
    assert float(jnp.max(jnp.abs(a - original.solution.unknowns))) > 1e-6  # friction acts
    smooth = _rough(original.finger, 0.0)
    topo, c = solve(smooth, original.topology)
    assert not topo.contact.friction
    _, d = solve(smooth, fr.with_friction(original.topology))
    assert float(jnp.max(jnp.abs(c - d))) < 1e-12


def test_regrasp_derivative_matches_finite_differences(finger1):
    """d(contact force)/d(closing) by the implicit function theorem (forward mode) against
    central differences of the same discrete model."""
    g = fr.grasp(finger1, 6.0)

    def force(d):
        return fr.regrasp(g, finger1, d)[1].normal_force

    value, slope = jax.jvp(force, (6.0,), (1.0,))
    h = 1e-4
    fd = (float(force(6.0 + h)) - float(force(6.0 - h))) / (2 * h)
    assert float(value) == pytest.approx(float(g.contact.normal_force), rel=1e-8)
    assert float(slope) == pytest.approx(fd, rel=1e-5)


def test_grasp_on_a_given_topology(finger1, grasps):
    """`grasp(..., topology=g.topology)` cuts the beams where g's grasp did: a changed
    design grasped from scratch on those cuts is the equilibrium `regrasp` reaches from g
    (same discrete model, so they agree to the Newton tolerance); a table of another
    finger is refused."""
    original, modified = grasps
    moved = fr.set_design(finger1, {"crossbeams.front_s[1]": 31.0})
    g = fr.grasp(moved, 5.0, stiffen=False, topology=original.topology)
    assert g.converged and g.topology == original.topology
    ref = eqx.tree_at(lambda r: r.stiffness, original, g.stiffness)
    _, contact = fr.regrasp(ref, moved, 5.0)
    assert float(g.contact.normal_force) == pytest.approx(float(contact.normal_force), rel=1e-7)
    with pytest.raises(fr.FingerError, match="segment table of a different finger"):
        fr.grasp(finger1, 5.0, topology=modified.topology)


def test_modified_adaptor_without_friction_pushes_the_object_out(grasps):
    """With the front base pinned and the back beam supported, the front beam leans so
    that its pressure on the 18 mm cylinder has a component toward the tips: without
    friction nothing resists the pull (holding force 0, reported as such, not as the
    round-off left where the contact fades)."""
    _, modified = grasps
    tr = fr.release_force(modified, step=4.0)
    assert tr.force[0] < -0.05 * float(modified.contact.normal_force)
    assert np.all(tr.force <= 1e-9 * np.max(np.abs(tr.force)))
    assert tr.peak == 0.0 and "not held" in tr.message


@pytest.mark.slow  # (58 s: the frictional topology of the modified grasp compiles)
def test_friction_holds_the_object_on_the_modified_adaptor(grasps):
    """The same pull with mu = 0.5 (see the test above): friction holds the cylinder."""
    _, modified = grasps
    rough = fr.release_force(modified, step=4.0, friction=0.5)
    assert rough.complete, rough.message
    assert rough.peak > 0.1 * float(modified.contact.normal_force)


def test_release_trace_without_a_solved_point_reports_no_holding_force(grasps, monkeypatch):
    """When not even the pull's onset solves (Finger-1 on the modified adaptor with
    l_c = 0 and mu = 0.3 does this), the trace has no point: its peak is NaN and its
    message says so, not a holding force of 0 N with "not held"."""
    from finray_jax import _grasp

    original, _ = grasps
    monkeypatch.setattr(_grasp.Stepper, "solve", lambda self, f, i: (None, False))
    monkeypatch.setattr(
        _grasp.Stepper, "follow", lambda self, at, t0, t1, init, *a, **k: (t0, init, False)
    )
    tr = fr.release_force(original, step=4.0, friction=0.3)
    assert tr.pull.size == 0 and not tr.complete
    assert np.isnan(tr.peak) and np.isnan(tr.peak_pull)
    assert "equilibrium lost at pull 0 mm" in tr.message
    assert "holding force is unknown" in tr.message and "not held" not in tr.message


def test_banded_newton_step_on_the_contact_jacobian(grasps):
    """The banded solve's pattern and step on a grasp with objects and the support (many
    short segments, stiff penalties): see test_banded."""
    from test_banded import check_banded_step

    g = grasps[1]
    check_banded_step(g.finger, g.topology, g.solution.unknowns)


def test_chord_steps_with_contact_reach_newtons_root(finger1, grasps):
    """With contact a chord step reuses the residual that the backtracking of the step
    before evaluated where it ends. A stale residual would steer the chord steps to a
    wrong point: the regrasp (a few chord steps from g's root) must reach the root that a
    grasp from scratch on the same cuts and penalty finds (its own path: a closing
    continuation from the undeformed finger), and the residual the outputs re-evaluate
    must be small. (The reference shares the fixture's compiled programs: a solve with
    `reuse_jacobian=False` compiles another 40 s.)"""
    original, _ = grasps
    chord, c_chord = fr.regrasp(original, finger1, 5.1)
    stiff = with_stiffness(finger1, original.stiffness)
    scratch = fr.grasp(stiff, 5.1, stiffen=False, topology=original.topology)
    assert chord.status == scratch.solution.status == "converged"
    assert float(chord.max_residual) < 1e-8 and float(scratch.solution.max_residual) < 1e-8
    assert float(c_chord.normal_force) == pytest.approx(
        float(scratch.contact.normal_force), rel=1e-9
    )
    front = np.asarray(scratch.solution.front.position)
    gap = np.max(np.abs(np.asarray(chord.front.position) - front))
    assert gap < 1e-8


def test_main_beam_samples_follow_the_undeformed_beams():
    """The jitted samples the eager checks use: from base to tip along each beam's arc,
    with the (tapered) half thickness."""
    from finray_jax._geometry import arc_point, geometry, main_beam_samples

    finger = fr.ref_finger_a("L1")
    finger = eqx.tree_at(
        lambda f: (f.front_curvature, f.front.tip_thickness),
        finger,
        (jnp.asarray(0.004), jnp.asarray(1.0)),
        is_leaf=lambda x: x is None,
    )
    s, p, h = (np.asarray(x) for x in main_beam_samples(finger, 11))
    geo = geometry(finger)
    tip = np.asarray(finger.tip)
    for b, base in ((0, finger.front_base), (1, finger.back_base)):
        assert s[b, 0] == 0.0 and s[b, -1] == pytest.approx(float(geo.length[b]), rel=1e-14)
        np.testing.assert_allclose(p[b, 0], np.asarray(base), atol=1e-12)
        np.testing.assert_allclose(p[b, -1], tip, atol=1e-9)
        mid = np.asarray(arc_point(geo.base[b], geo.theta[b], geo.curvature[b], s[b, 5]))[::2]
        np.testing.assert_allclose(p[b, 5], mid, atol=1e-12)
    front, back = float(finger.front.thickness), float(finger.back.thickness)
    np.testing.assert_allclose(h[0], 0.5 * (front + (1.0 - front) * s[0] / s[0, -1]), rtol=1e-14)
    np.testing.assert_allclose(h[1], 0.5 * back, rtol=1e-14)


def test_release_trace_follows_one_branch_whatever_the_step(grasps):
    """Every point of a release trace is the equilibrium with the object at that pull, so
    traces in 4 mm and 2 mm steps must agree where their pulls coincide, unless one of
    them jumped to another equilibrium branch. (The modified adaptor's frictionless pull
    has other branches nearby: a quadratic predictor once landed on one holding 1.25 N.)"""
    _, modified = grasps
    coarse = fr.release_force(modified, step=4.0)
    fine = fr.release_force(modified, step=2.0)
    assert coarse.complete and fine.complete
    common = np.intersect1d(np.round(coarse.pull, 9), np.round(fine.pull, 9))
    assert common.size >= 8
    at = lambda tr: np.asarray([tr.force[np.argmin(np.abs(tr.pull - p))] for p in common])
    scale = float(np.max(np.abs(fine.force)))
    np.testing.assert_allclose(at(coarse), at(fine), rtol=0, atol=1e-6 * scale)


def test_closing_steps_never_carry_an_object_through_a_beam():
    """A closing step is at most half the object's depth below its centre, so a huge
    closing (1000 mm on Finger-1's 18 mm cylinder) cannot jump the object clean through
    the finger into a contact-free 'converged' state."""
    finger = fr.ref_finger_a("L1")
    cyl = dataclasses.replace(finger, objects=(fr.Circle((30.0, 60.0), 9.0),))
    assert _closing_step_cap(cyl) == pytest.approx(4.5)
    ell = dataclasses.replace(finger, objects=(fr.Ellipse((30.0, 60.0), (9.0, 3.0), 0.3),))
    assert _closing_step_cap(ell) == pytest.approx(1.5, rel=1e-3)  # (from 400 outline points)
    wall = dataclasses.replace(finger, objects=(fr.HalfPlane((30.0, 0.0), (-1.0, 0.0)),))
    assert _closing_step_cap(wall) == np.inf

    class Easy:  # a solve that always converges in one iteration
        iterations, unknowns = 1, np.zeros(1)

    ts = []
    stepper = object.__new__(Stepper)
    stepper.solve = lambda at_t, guess: (ts.append(at_t), (Easy(), True))[1]
    t, _, ok = Stepper.follow(stepper, lambda t: t, 0.0, 1000.0, None, 125.0, 0.1, max_step=4.5)
    assert ok and t == 1000.0 and np.max(np.diff([0.0] + ts)) <= 4.5 + 1e-9
