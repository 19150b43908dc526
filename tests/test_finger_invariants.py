"""Assembly invariants of the finger solve on ref-A: zero load, global balance, planar vs
spatial, out-of-plane loads, no recompilation for new design values, warm starts,
adaptors, and the behaviour at and beyond the limit load.

Compiling one (topology, mode) pair costs ~25-40 s on 2 cores, so solutions are shared
through module-scoped fixtures and the default suite compiles only seven of them:
ref-A with the point load at s = 60 (L1, L2 and every design variant) planar, the same
warm-started (init=...), planar with no load, planar with L3, spatial with the point load,
and the pinned and the free front base.
"""

import dataclasses

import equinox as eqx
import jax
import numpy as np
import pytest
from helpers import beam_at, global_balance, without_jacobian

import finray_jax as fr
from finray_jax import _banded, _newton, _solve, _steps
from finray_jax._rotation import planar_frame

LB = float(np.hypot(40.0, 120.0))  # back-beam length of ref-A


def _replace(module, **kw):
    """A copy through the constructor, so converters turn new values into float64 arrays
    (eqx.tree_at with a Python float would make it a static leaf)."""
    return dataclasses.replace(module, **kw)


def _ref(load):
    return fr.ref_finger_a(load)


def _solve_ok(finger, **kw):
    sol = fr.solve_finger(finger, **kw)
    assert sol.status == "converged", sol.status
    return sol


def _beams(sol):
    yield "front", sol.front
    yield "back", sol.back
    for i in range(sol.crossbeams.s.shape[0]):
        yield f"crossbeam {i}", sol.crossbeam(i)


def _finite(sol):
    return all(
        np.all(np.isfinite(np.asarray(x)))
        for x in jax.tree_util.tree_leaves(sol)
        if eqx.is_array(x)
    )


# --------------------------------------------------------------------------------------
# Shared solutions (module scope: each compiles at most once per process)
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sol_none():
    return _solve_ok(_ref("none"), mode="planar")


@pytest.fixture(scope="module")
def sol_l1():
    return _solve_ok(_ref("L1"), mode="planar")


@pytest.fixture(scope="module")
def sol_l2():
    return _solve_ok(_ref("L2"), mode="planar")


@pytest.fixture(scope="module")
def sol_l3():
    return _solve_ok(_ref("L3"), mode="planar")


@pytest.fixture(scope="module")
def sol_l1_spatial():
    return _solve_ok(_ref("L1"), mode="spatial")


CASES = {"L1": "sol_l1", "L2": "sol_l2", "L3": "sol_l3", "L1-spatial": "sol_l1_spatial"}


@pytest.mark.parametrize(
    "entry,mode",
    [("solve_finger", "planar"), ("solve_finger", "spatial"), ("limit_load", "planar")],
)
def test_solve_under_strict_promotion(entry, mode):
    """The whole solve path traces under strict dtype promotion (house style). Tracing
    with eqx.filter_eval_shape checks every jnp operation without compiling anything."""
    finger = _ref("L1")
    topo = fr.topology_of(finger, mode)
    func = getattr(fr, entry)
    with jax.numpy_dtype_promotion("strict"):
        out = eqx.filter_eval_shape(lambda f: func(f, mode=mode, topology=topo), finger)
    sol = out if entry == "solve_finger" else out.solution
    assert sol.front.data.dtype == np.float64  # packed: s, position, frame, force, moment


# --------------------------------------------------------------------------------------
# zero load
# --------------------------------------------------------------------------------------


def _undeformed(finger, name, s):
    """Undeformed position (N, 3) and frame angle of a beam of `finger` at arc lengths s."""
    fb, bb, tip = (
        np.array([p[0], 0.0, p[1]])
        for p in (
            np.asarray(finger.front_base),
            np.asarray(finger.back_base),
            np.asarray(finger.tip),
        )
    )
    tf = (tip - fb) / np.linalg.norm(tip - fb)
    tb = (tip - bb) / np.linalg.norm(tip - bb)
    if name == "front":
        start, t = fb, tf
    elif name == "back":
        start, t = bb, tb
    else:
        i = int(name.split()[-1])
        start = fb + float(finger.crossbeams.front_s[i]) * tf
        end = bb + float(finger.crossbeams.back_s[i]) * tb
        t = (end - start) / np.linalg.norm(end - start)
    return start + np.asarray(s)[:, None] * t, np.arctan2(t[0], t[2])


def test_zero_load_leaves_the_finger_undeformed(sol_none):
    finger = _ref("none")
    # Tolerances: at zero load the undeformed state is the root up to rounding of
    # O(100 mm) coordinates (1e-14 mm); 1e-12 mm / 1e-12 N leaves a margin of 100.
    for name, beam in _beams(sol_none):
        p0, theta = _undeformed(finger, name, beam.s)
        np.testing.assert_allclose(np.asarray(beam.position), p0, rtol=0, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(
            np.asarray(beam.frame),
            np.broadcast_to(np.asarray(planar_frame(theta)), beam.frame.shape),
            rtol=0,
            atol=1e-12,
            err_msg=name,
        )
        np.testing.assert_allclose(np.asarray(beam.force), 0.0, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(np.asarray(beam.moment), 0.0, atol=1e-12, err_msg=name)
    assert float(sol_none.front.s[-1]) == pytest.approx(120.0, abs=1e-12)
    assert float(sol_none.back.s[-1]) == pytest.approx(LB, abs=1e-12)
    np.testing.assert_allclose(np.asarray(sol_none.tip.position), [0.0, 0.0, 120.0], atol=1e-12)
    np.testing.assert_allclose(np.asarray(sol_none.tip.displacement), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(sol_none.tip.rotation), 0.0, atol=1e-12)
    for r in (sol_none.reactions_front, sol_none.reactions_back):
        np.testing.assert_allclose(np.asarray(r.force), 0.0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(r.moment), 0.0, atol=1e-12)
    assert float(sol_none.load_factor) == 1.0


# --------------------------------------------------------------------------------------
# global force and moment balance
# --------------------------------------------------------------------------------------

# Tolerances: with point loads only, n is constant between cuts and m + p x n is a linear
# invariant of the rod ODE, which Runge-Kutta preserves exactly; the assembly enforces
# every jump and the tip junction to the Newton tolerance (scaled residual ~1e-13), so the
# whole finger balances to rounding. Under L3 the moment of the distributed load,
# integral of p(s) x f ds, is a quadratic invariant that Tsit5 keeps only to its
# truncation error, and the test integrates p(s) from the solution's points with the
# 11-point Newton-Cotes rule per 15 mm segment: both errors measure ~1e-10 of the largest
# moment term at the default 10 steps (2e-12 at 20 steps). 1e-9 holds for all cases.
FORCE_TOL = 1e-9  # N
MOMENT_RTOL = 1e-9  # relative to the largest moment term


def _assert_balanced(finger, sol, load_factor=1.0):
    F, M, scale = global_balance(finger, sol, load_factor)
    assert np.max(np.abs(F)) < FORCE_TOL, F
    assert np.max(np.abs(M)) < MOMENT_RTOL * scale, (M, scale)
    return F, M, scale


@pytest.mark.parametrize("case", list(CASES))
def test_global_balance(case, request):
    sol = request.getfixturevalue(CASES[case])
    finger = _ref(case.split("-")[0])
    F, M, scale = _assert_balanced(finger, sol)
    # The reactions really carry the load (the check is not vacuous).
    applied = np.abs(
        np.asarray(finger.loads[0].force if case != "L3" else finger.loads[0].total_force)
    )[0]
    reacted = abs(float(sol.reactions_front.force[0] + sol.reactions_back.force[0]))
    assert reacted == pytest.approx(applied, rel=1e-9)
    assert scale > 1e-3


def test_crossbeam_wrenches_are_the_jumps_in_the_main_beams(sol_l2):
    """At a crossbeam's front attachment n(s+) = n(s-) - W (W the crossbeam's force on the
    front beam), and the moment jumps by minus its moment; likewise on the back beam.
    Tolerances: both sides are read from one solution and differ by the Newton residual
    (~1e-15 N at L2) only."""
    finger = _ref("L2")
    w = sol_l2.crossbeam_wrenches
    load = np.asarray(finger.loads[0].force)  # 1.5 N at s = 60, the cut of crossbeam 3
    for beam, s_att, force, moment in (
        (sol_l2.front, finger.crossbeams.front_s, w.front_force, w.front_moment),
        (sol_l2.back, finger.crossbeams.back_s, w.back_force, w.back_moment),
    ):
        ss = np.asarray(beam.s)
        for i, s in enumerate(np.asarray(s_att)):
            rows = np.flatnonzero(np.abs(ss - s) < 1e-9)
            a, b = rows[0], rows[-1]
            applied = np.asarray(force[i])
            if beam is sol_l2.front and s == 60.0:
                applied = applied + load
            np.testing.assert_allclose(
                np.asarray(beam.force[b] - beam.force[a]), -applied, atol=1e-12
            )
            np.testing.assert_allclose(
                np.asarray(beam.moment[b] - beam.moment[a]), -np.asarray(moment[i]), atol=1e-11
            )
    # No load acts on a crossbeam, so its force on the front beam and its force on the
    # back beam sum to zero, and they are not trivially zero.
    np.testing.assert_allclose(np.asarray(w.front_force + w.back_force), 0.0, atol=1e-12)
    assert np.max(np.abs(np.asarray(w.front_force))) > 1e-2


# --------------------------------------------------------------------------------------
# planar vs spatial, out-of-plane load
# --------------------------------------------------------------------------------------


def test_planar_and_spatial_agree(sol_l1, sol_l1_spatial):
    # Both integrate the same rod with 10 Tsit5 steps per segment; they differ only in how
    # the rotation is integrated (an angle vs a frame), so they differ by no more than the
    # sum of their integration errors. Measured against 80 steps, the L1 tip's integration
    # error is 4.5e-11 mm (planar) and 4.0e-11 mm (3-D); the two solves differ by 1.4e-11
    # mm at the tip, 2.2e-10 mm along the beams and 2e-11 N mm in the reactions. 1e-9 mm
    # (and N, N mm) bounds that with a margin of ~5.
    assert sol_l1.mode == "planar" and sol_l1_spatial.mode == "spatial"
    np.testing.assert_allclose(
        np.asarray(sol_l1_spatial.tip.position), np.asarray(sol_l1.tip.position), rtol=0, atol=1e-9
    )
    for name in ("front", "back"):
        a, b = getattr(sol_l1, name), getattr(sol_l1_spatial, name)
        np.testing.assert_array_equal(np.asarray(a.s), np.asarray(b.s))
        np.testing.assert_allclose(
            np.asarray(b.position), np.asarray(a.position), rtol=0, atol=1e-9, err_msg=name
        )
    for r_p, r_s in (
        (sol_l1.reactions_front, sol_l1_spatial.reactions_front),
        (sol_l1.reactions_back, sol_l1_spatial.reactions_back),
    ):
        np.testing.assert_allclose(np.asarray(r_s.force), np.asarray(r_p.force), atol=1e-9)
        np.testing.assert_allclose(np.asarray(r_s.moment), np.asarray(r_p.moment), atol=1e-9)
    # Nothing leaves the plane, and the integrated frames stay orthonormal (Tsit5 drift of
    # R^T R from I is a truncation effect, measured 1e-12; bound 1e-10).
    assert np.max(np.abs(np.asarray(sol_l1_spatial.front.position[:, 1]))) < 1e-12
    for beam in (sol_l1_spatial.front, sol_l1_spatial.back):
        R = np.asarray(beam.frame)
        np.testing.assert_allclose(
            np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-10
        )


def test_out_of_plane_load_solves_in_3d():
    finger = _ref("L1").with_loads(fr.PointLoad(0, 60.0, (0.02, 0.01, 0.0)))
    sol = _solve_ok(finger)  # mode="auto" must pick the 3-D model for a y force
    assert sol.mode == "spatial"
    # A +y force moves the load point and the tip toward +y (well above rounding).
    i = beam_at(sol.front, 60.0)
    assert float(sol.front.position[i, 1]) > 1e-3
    assert float(sol.tip.displacement[1]) > 1e-3
    assert float(sol.tip.displacement[0]) > 0.0  # the +x part still pushes toward +x
    _assert_balanced(finger, sol)
    # The reactions take the y force.
    ry = float(sol.reactions_front.force[1] + sol.reactions_back.force[1])
    assert ry == pytest.approx(-0.01, abs=1e-12)


# --------------------------------------------------------------------------------------
# new design values never recompile
# --------------------------------------------------------------------------------------


def test_design_values_do_not_recompile(sol_l1, monkeypatch):
    base = _ref("L1")  # compiled by the sol_l1 fixture
    cb = base.crossbeams
    variants = {
        "back_s": _replace(base, crossbeams=_replace(cb, back_s=np.asarray(cb.back_s) + 2.0)),
        "crossbeam thickness": _replace(base, crossbeams=_replace(cb, thickness=np.full(7, 1.2))),
        "front thickness": _replace(base, front=fr.Section(1.6, 20.0)),
        "E": _replace(base, material=fr.Material(15.0, 0.45)),
        "back clamp length": _replace(base, adaptor=fr.Adaptor(back_clamp_length=10.0)),
        "tip": _replace(base, tip=(0.0, 125.0)),
        "load": base.with_loads(fr.PointLoad(0, 65.0, (0.08, 0.0, 0.0))),
    }
    # Two independent counts, each on an internal of finray_jax/_solve.py (the test fails
    # if either disappears):
    # - make_problem runs once per trace of the jitted cores: wrap it with
    #   eqx.debug.assert_max_traces and count (the jit cache ignores the wrapper);
    # - the size of the jax.jit caches of direct_core (the plain Newton solve) and
    #   solve_core (with load continuation).
    counted = eqx.debug.assert_max_traces(_solve.make_problem, max_traces=None)
    monkeypatch.setattr(_solve, "make_problem", counted)
    caches = [core._cache_size for core in (_solve.direct_core, _solve.solve_core)]
    size0 = [c() for c in caches]
    for name, finger in variants.items():
        assert fr.topology_of(finger, "planar") == fr.topology_of(base, "planar"), name
        sol = _solve_ok(finger, mode="planar")
        moved = np.max(np.abs(np.asarray(sol.tip.position - sol_l1.tip.position)))
        assert moved > 1e-6, f"{name} did not change the answer"
        assert eqx.debug.get_num_traces(counted) == 0, f"{name} retraced the solve"
        assert [c() for c in caches] == size0, f"{name} recompiled the solve"


# --------------------------------------------------------------------------------------
# warm start
# --------------------------------------------------------------------------------------


def _same_root(a, b, atol=1e-9):
    # rtol = atol = 1e-10 on unknowns scaled by 120 mm leaves ~1e-12 mm; compare to 1e-9
    for (name, p), (_, q) in zip(_beams(a), _beams(b)):
        np.testing.assert_allclose(
            np.asarray(q.position), np.asarray(p.position), rtol=0, atol=atol, err_msg=name
        )
    np.testing.assert_allclose(
        np.asarray(b.reactions_back.moment), np.asarray(a.reactions_back.moment), atol=atol
    )


def test_warm_start(sol_l1):
    finger = _replace(_ref("L1"), back=fr.Section(1.5 * 1.01, 20.0))
    cold = _solve_ok(finger, mode="planar")
    # from the deformation alone: fewer Newton iterations than from the undeformed shape
    plain = _solve_ok(finger, mode="planar", init=without_jacobian(sol_l1))
    assert int(plain.iterations) < int(cold.iterations), (plain.iterations, cold.iterations)
    # with sol_l1's Jacobian factors too (chord steps from the start): another path
    assert sol_l1.jacobian is not None
    warm = _solve_ok(finger, mode="planar", init=sol_l1)
    assert int(warm.iterations) != int(plain.iterations)
    # all three converge to the same root
    _same_root(cold, plain)
    _same_root(cold, warm)
    # The thicker back beam really changed the answer.
    assert np.max(np.abs(np.asarray(cold.tip.position - sol_l1.tip.position))) > 1e-5


def test_a_warm_start_with_poor_factors_still_reaches_the_root(sol_l1, sol_l2):
    """Chord steps on a warm start's factors fall back to Newton when they do not help:
    factors of the L1 load's Jacobian used for L2 (82 % of its fold), and of -J (every
    chord step goes the wrong way: its trial is linearised at the start instead) reach
    the cold root."""
    finger = _ref("L2")
    topo = fr.topology_of(finger, "planar")
    other = _solve_ok(finger, mode="planar", init=sol_l1)
    _same_root(sol_l2, other)
    problem = _solve.make_problem(topo, fr.Integrator(), finger)
    fn = lambda y: _solve.natural_residual(y, (problem, 1.0))
    _, A = _banded.linearize(topo.band, fn, sol_l2.unknowns)
    flipped = eqx.tree_at(lambda s: s.jacobian, sol_l2, _banded.factor(topo.band, -A))
    changed = _replace(finger, back=fr.Section(1.5 * 1.01, 20.0))
    cold = _solve_ok(changed, mode="planar", init=without_jacobian(sol_l2))
    wrong = _solve_ok(changed, mode="planar", init=flipped)
    _same_root(cold, wrong)
    # a wasted chord step and its rejected trial, then the plain start's path
    assert int(wrong.iterations) == int(cold.iterations) + 2, (wrong.iterations, cold.iterations)


def test_jacobian_factors_are_kept_only_where_asked(sol_l1):
    finger = _replace(_ref("L1"), back=fr.Section(1.5 * 1.01, 20.0))
    assert fr.solve_finger(finger, mode="planar", keep_jacobian=False).jacobian is None
    with pytest.raises(ValueError, match="keep_jacobian must be True or False, got 'no'"):
        fr.solve_finger(finger, mode="planar", keep_jacobian="no")
    dense = fr.SolverOptions(linear_solver=fr.DenseLinearSolver())
    assert fr.solve_finger(finger, mode="planar", options=dense, init=sol_l1).jacobian is None
    # traced (jit): the full core starts from the factors and keeps none
    topo = fr.topology_of(finger, "planar")
    jitted = jax.jit(lambda f, s: fr.solve_finger(f, topology=topo, init=s))(finger, sol_l1)
    assert jitted.jacobian is None
    _same_root(_solve_ok(finger, mode="planar", init=sol_l1), jitted)
    assert int(jitted.iterations) == int(fr.solve_finger(finger, init=sol_l1).iterations)


@pytest.mark.parametrize(
    "change",
    [("front", "thickness", 1.01), ("front", "thickness", 0.97), ("material", "E", 0.97)],
)
def test_a_warm_start_from_another_design_carries_its_deformation(sol_l2, change):
    """init= carries the other design's deformation (displacements, rotations, and forces
    per unit E) onto this design. L2 lies at 82 % of its fold, where Newton's basin is
    small; from the carried deformation a 1 % thicker or 3 % thinner front beam, or a 3 %
    softer material, converges in at most 8 iterations, on the cold solve's root."""
    owner, name, factor = change
    finger = _ref("L2")
    part = getattr(finger, owner)
    changed = _replace(
        finger,
        **{owner: eqx.tree_at(lambda p: getattr(p, name), part, getattr(part, name) * factor)},
    )
    cold = _solve_ok(changed, mode="planar")
    warm = _solve_ok(changed, mode="planar", init=sol_l2)
    assert int(warm.iterations) <= 8, int(warm.iterations)
    assert int(warm.iterations) < int(cold.iterations)
    for (beam, a), (_, b) in zip(_beams(cold), _beams(warm)):
        np.testing.assert_allclose(
            np.asarray(b.position), np.asarray(a.position), rtol=0, atol=1e-9, err_msg=beam
        )
    # the deformation travels back unchanged: the same design starts at its own root
    topo = fr.topology_of(finger, "planar")
    start = _solve.start_from_deformation(topo, finger, sol_l2.deformation)
    np.testing.assert_allclose(start, sol_l2.unknowns, rtol=1e-14, atol=1e-14)
    assert int(fr.solve_finger(finger, mode="planar", init=sol_l2).iterations) == 1


def test_a_warm_start_of_another_topology_is_refused(sol_l2, sol_l1_spatial):
    with pytest.raises(
        ValueError,
        match="init is a spatial solution of 24 segments; this finger's topology is planar with 24",
    ):
        fr.solve_finger(_ref("L2"), mode="planar", init=sol_l1_spatial)


def test_a_start_at_the_root_is_confirmed_when_the_residual_floor_exceeds_atol(sol_l1):
    """Newton started at a root whose residual cannot reach atol (round-off; a stiff
    contact penalty can put this floor above the default 1e-10) converges in one or two
    iterations: its own full step falls far below the tolerance. atol = 1e-17 puts ref-A's
    floor (~1e-15) above it."""
    finger = _ref("L1")
    strict = _solve.SolverOptions(atol=1e-17)
    again = fr.solve_finger(finger, mode="planar", options=strict, init=sol_l1)
    assert again.result == fr.RESULTS.successful, again.status
    assert float(again.max_residual) > 1e-17  # the floor really is above atol
    assert int(again.iterations) <= 2
    # the same root, to sol_l1's own tolerance (1e-10 on the scaled unknowns)
    np.testing.assert_allclose(
        np.asarray(again.unknowns), np.asarray(sol_l1.unknowns), rtol=0, atol=1e-10
    )


# (L3, 34 s of compiling, is slow: L1 and L2 cover the chord steps in the default suite)
@pytest.mark.parametrize("case", ["L1", "L2", pytest.param("L3", marks=pytest.mark.slow)])
def test_chord_steps_reach_the_same_root_as_newton(case):
    """SolverOptions.reuse_jacobian (default): near the root, steps with the last
    factors and a fresh residual. Same roots as Newton alone, cold and after a 1 % change
    (warm), to the tolerance; and the warm re-solve of L1 does take chord steps (it would
    otherwise count exactly Newton's iterations, the code path being the same)."""
    newton = fr.SolverOptions(reuse_jacobian=False)
    finger = _ref(case)
    changed = _replace(finger, back=fr.Section(1.5 * 1.01, 20.0))
    runs = {}
    for name, opts in (("chord", fr.SolverOptions()), ("newton", newton)):
        cold = _solve_ok(finger, mode="planar", options=opts)
        warm = _solve_ok(changed, mode="planar", options=opts, init=cold)
        runs[name] = (cold, warm)
    for a, b in zip(runs["chord"], runs["newton"]):
        # no worse than Newton's (which stops on its predicted next step: on L2 its
        # residual is 1.9e-10 of the scale, above atol)
        assert float(a.max_residual) <= max(1e-10, 2 * float(b.max_residual))
        for (name, p), (_, q) in zip(_beams(a), _beams(b)):
            np.testing.assert_allclose(
                np.asarray(p.position), np.asarray(q.position), rtol=0, atol=1e-9, err_msg=name
            )
        np.testing.assert_allclose(
            np.asarray(a.reactions_front.force), np.asarray(b.reactions_front.force), atol=1e-10
        )
    if case == "L1":
        assert int(runs["chord"][1].iterations) > int(runs["newton"][1].iterations)


# --------------------------------------------------------------------------------------
# adaptors
# --------------------------------------------------------------------------------------


def _load_point_dx(sol):
    """x displacement of the L1 load point (front beam, s = 60): the displacement
    conjugate to the load, so removing a support can only increase it (linear regime)."""
    return float(sol.front.position[beam_at(sol.front, 60.0), 0])


def test_pinned_front_base(sol_l1):
    finger = _replace(_ref("L1"), adaptor=fr.Adaptor(fr.PinnedBase(), fr.ClampedBase()))
    sol = _solve_ok(finger, mode="planar")
    # A hinge carries no moment: the hinge row holds m_y = 0 to the Newton tolerance
    # (scaled by EI/L = 0.56 N mm), i.e. ~1e-15 N mm.
    assert np.max(np.abs(np.asarray(sol.reactions_front.moment))) < 1e-10
    # ... but still holds the base point, and the base turns.
    np.testing.assert_allclose(np.asarray(sol.front.position[0]), 0.0, atol=1e-12)
    d3 = np.asarray(sol.front.frame[0, :, 2])
    assert abs(d3[0]) > 1e-5
    assert abs(float(sol.reactions_front.force[0])) > 1e-4  # it carries load (7.5e-4 N)
    _assert_balanced(finger, sol)
    assert _load_point_dx(sol) > _load_point_dx(sol_l1)


def test_free_front_base(sol_l1):
    finger = _replace(_ref("L1"), adaptor=fr.Adaptor(fr.FreeBase(), fr.ClampedBase()))
    sol = _solve_ok(finger, mode="planar")
    for x in (sol.reactions_front.force, sol.reactions_front.moment):
        assert np.max(np.abs(np.asarray(x))) < 1e-10
    assert np.max(np.abs(np.asarray(sol.front.position[0]))) > 1e-3  # the base moves
    _assert_balanced(finger, sol)  # the back clamp takes everything
    assert _load_point_dx(sol) > _load_point_dx(sol_l1)


def test_back_clamp_length_stiffens(sol_l1):
    base = _ref("L1")
    stiff = _solve_ok(_replace(base, adaptor=fr.Adaptor(back_clamp_length=10.0)), mode="planar")
    assert float(stiff.tip.displacement[0]) < float(sol_l1.tip.displacement[0])
    assert _load_point_dx(stiff) < _load_point_dx(sol_l1)
    # The clamped length is held rigidly on its undeformed line.
    bs = np.asarray(stiff.back.s)
    inside = bs <= 10.0
    p0 = np.array([40.0, 0.0, 0.0]) + bs[inside, None] * np.array([-40.0, 0.0, 120.0]) / LB
    np.testing.assert_allclose(np.asarray(stiff.back.position)[inside], p0, atol=1e-12)


def test_zero_clamp_length_is_the_original(sol_l1):
    base = _ref("L1")
    same = _solve_ok(
        _replace(base, adaptor=fr.Adaptor(fr.ClampedBase(), fr.ClampedBase(), 0.0, 0.0)),
        mode="planar",
    )
    for (name, a), (_, b) in zip(_beams(sol_l1), _beams(same)):
        np.testing.assert_allclose(
            np.asarray(b.position), np.asarray(a.position), rtol=0, atol=1e-12, err_msg=name
        )
    # Continuity at l_c -> 0: a 1e-6 mm clamp moves the tip by ~1e-6 x |d tip / d l_c|,
    # and |d tip / d l_c| ~ 1e-3 (l_c = 10 moves the tip by 0.011 mm): ~1e-9 mm, bound 1e-8.
    tiny = _solve_ok(_replace(base, adaptor=fr.Adaptor(back_clamp_length=1e-6)), mode="planar")
    assert np.max(np.abs(np.asarray(tiny.tip.position - sol_l1.tip.position))) < 1e-8


@pytest.mark.parametrize("front_lc,back_lc", [(0.0, 35.0), (20.0, 0.0), (20.0, 35.0)])
def test_clamp_over_crossbeams_balances(front_lc, back_lc):
    """Clamped lengths covering crossbeams (back: the first two, at back_s 15.8 and 31.6;
    front: the first, at 15): the crossbeams attach to the rigid adaptor there, and the
    base reactions (moment about the base point) still balance the whole finger."""
    finger = _replace(
        _ref("L2"), adaptor=fr.Adaptor(front_clamp_length=front_lc, back_clamp_length=back_lc)
    )
    sol = _solve_ok(finger, mode="planar")
    _assert_balanced(finger, sol)
    # Crossbeam ends inside a clamp do not move.
    for i in range(2):
        cbi = sol.crossbeam(i)
        if back_lc > float(finger.crossbeams.back_s[i]):
            p, _ = _undeformed(finger, f"crossbeam {i}", cbi.s[-1:])
            np.testing.assert_allclose(np.asarray(cbi.position[-1]), p[0], atol=1e-12)
        if front_lc > float(finger.crossbeams.front_s[i]):
            np.testing.assert_allclose(
                np.asarray(cbi.position[0]), [0.0, 0.0, 15.0 * (i + 1)], atol=1e-12
            )


# --------------------------------------------------------------------------------------
# beyond the limit load, the limit load
# --------------------------------------------------------------------------------------

# Sanity bounds on the fold of ref-A (~1.83 N for the point load at s = 60, ~1.3 N for
# L3); the 0.05 % comparison with OpenSees is in test_reference_opensees.py.
FOLD_L2 = (1.7, 1.95)
FOLD_L3 = (1.2, 1.45)


def test_beyond_the_limit_load():
    finger = _ref("L2").scale_loads(2.5 / 1.5)  # 2.5 N at s = 60: past the fold
    sol = fr.solve_finger(finger, mode="planar")
    assert sol.status == "beyond_limit_load"
    assert sol.result == fr.RESULTS.beyond_limit_load
    lam = float(sol.load_factor)
    assert 0.0 < lam < 1.0
    assert _finite(sol)
    # The returned state is an equilibrium at the returned load factor, near the fold.
    _assert_balanced(finger, sol, lam)
    assert FOLD_L2[0] < 2.5 * lam < FOLD_L2[1]


def test_a_continuation_out_of_steps_says_so():
    """Three arc-length steps cannot reach a fold at 73 % of the load: the solve reports
    that the continuation ran out of steps (not that its step collapsed), with the last
    equilibrium on the path it traced."""
    finger = _ref("L2").scale_loads(2.5 / 1.5)
    options = fr.SolverOptions(max_continuation_steps=3)
    sol = fr.solve_finger(finger, mode="planar", options=options)
    assert sol.result == fr.RESULTS.continuation_steps_exhausted
    assert sol.status == "failed"
    assert "max_continuation_steps" in sol.message and "still rising" in sol.message
    lam = float(sol.load_factor)
    assert 0.0 < lam < 0.73
    _assert_balanced(finger, sol, lam)


@pytest.mark.slow  # (47 s: the solve, limit and refined-limit cores of a scaled finger)
def test_the_fold_is_found_at_any_load_magnitude():
    """A million times L1 (50 kN) folds at a load factor of about 3.7e-5. The arc steps
    scale with the load (`FIRST_STEP_CHANGE`), so the solve reports beyond_limit_load,
    and the fold is the same load, to round-off, as for L1 itself."""
    finger = _ref("L1")
    huge = finger.scale_loads(1e6)
    sol = fr.solve_finger(huge, mode="planar")
    assert sol.status == "beyond_limit_load"
    fold = 36.54123  # (ref-A L1's fold load factor, refined: 36.541231847...)
    assert 0.99 * fold < 1e6 * float(sol.load_factor) < fold
    _assert_balanced(huge, sol, float(sol.load_factor))
    lam = fr.limit_load(huge, mode="planar")
    assert bool(lam.found)
    assert 0.999 * fold < 1e6 * float(lam.load_factor) < fold
    refined = [float(fr.limit_load_factor(f, mode="planar")) for f in (finger, huge)]
    np.testing.assert_allclose(1e6 * refined[1], refined[0], rtol=1e-10)


@pytest.mark.parametrize(
    "case,mode",
    # (L3 planar, 62 s, is slow: L2 checks the same tangent in the default suite)
    [
        ("L2", "planar"),
        pytest.param("L2", "spatial", marks=pytest.mark.slow),
        pytest.param("L3", "planar", marks=pytest.mark.slow),
        pytest.param("L3", "spatial", marks=pytest.mark.slow),
    ],
)
def test_bordered_linearisation_gives_the_path_tangent(case, mode):
    """The continuation's corrector and tangent read b = J^-1 dr/dlam from
    `linearise_arc`. With point loads only (L2) its dr/dlam is the residual's derivative
    at fixed end states; with a distributed load (L3, where r is nonlinear in lam through
    the flows) it is one plain forward-mode tangent through the integrator. Checked
    against a dense Jacobian and the segment flow's own JVP rule at a deformed state with
    the loads half on, and the tangent built from it against the null vector of
    [J, dr/dlam]."""
    finger = _ref(case)
    topo = fr.topology_of(finger, mode)
    problem = _solve.nograd(_solve.make_problem(topo, fr.Integrator(), finger))
    half = jax.numpy.asarray(0.5)
    y = _solve.undeformed_unknowns(topo, finger)
    y = _newton.solve_root(problem, y, half, fr.SolverOptions()).y  # an equilibrium
    y = y + 1e-3 * np.cos(np.arange(y.size))  # and a point off it
    solver = _newton.linear_solver_of(problem, fr.BandedLinearSolver())
    r, factors, sign, b = _steps.linearise_arc(problem, half, y, solver, True)
    fn = lambda a, lam: _solve.natural_residual(a, (problem, lam))
    J = jax.jacfwd(fn)(y, half)
    r_lam = jax.jvp(lambda lam: fn(y, lam), (half,), (jax.numpy.ones(()),))[1]
    np.testing.assert_allclose(r, fn(y, half), rtol=0, atol=1e-13)
    np.testing.assert_allclose(J @ b, r_lam, rtol=0, atol=1e-9 * np.max(np.abs(r_lam)))
    assert sign == np.linalg.slogdet(np.asarray(J))[0]
    t = np.concatenate([-np.asarray(b), [1.0]])  # the tangent (-b, 1): [J, r_lam] t = 0
    A = np.concatenate([np.asarray(J), np.asarray(r_lam)[:, None]], axis=1)
    assert np.max(np.abs(A @ t)) < 1e-9 * np.max(np.abs(A)) * np.max(np.abs(t))


@pytest.mark.slow
@pytest.mark.parametrize("case,bounds", [("L2", FOLD_L2), ("L3", FOLD_L3)])
def test_limit_load(case, bounds):
    finger = _ref(case)
    lim = fr.limit_load(finger, mode="planar")
    assert bool(lim.found)
    magnitude = float(
        np.linalg.norm(
            np.asarray(finger.loads[0].force if case == "L2" else finger.loads[0].total_force)
        )
    )
    assert bounds[0] < float(lim.load_factor) * magnitude < bounds[1]
    assert _finite(lim.solution)
    _assert_balanced(finger, lim.solution, float(lim.load_factor))


def test_tapered_main_beams(sol_l1):
    """A taper whose tip equals its base reproduces the constant section (the varying-
    section path interpolates four equal samples: to rounding); a real taper (front 2.0 ->
    1.0 mm) converges, balances, and its tip moves between those of uniform 1.0 mm and
    2.0 mm front beams."""
    base = _ref("L1")
    same = _replace(base, front=fr.Section(1.5, 20.0, tip_thickness=1.5))
    sol_same = _solve_ok(same)
    for (_, a), (_, b) in zip(_beams(sol_l1), _beams(sol_same)):
        np.testing.assert_allclose(np.asarray(b.position), np.asarray(a.position), atol=1e-10)

    tapered = _replace(base, front=fr.Section(2.0, 20.0, tip_thickness=1.0))
    sol_t = _solve_ok(tapered)  # same topology as `same`: no new compile
    _assert_balanced(tapered, sol_t)
    thin = _solve_ok(_replace(base, front=fr.Section(1.0, 20.0)))
    thick = _solve_ok(_replace(base, front=fr.Section(2.0, 20.0)))
    dx = lambda s: float(s.tip.displacement[0])
    assert dx(thick) < dx(sol_t) < dx(thin)


def test_curved_main_beams():
    """Precurved (circular-arc) main beams: unloaded, the finger keeps its arcs exactly and
    carries no internal force (the precurvature, the joint angles taken at each joint and
    the tip junction are consistent); loaded, planar and 3-D agree and it balances."""
    from finray_jax._geometry import arc_point, geometry

    curved = _replace(_ref("none"), front_curvature=0.004, back_curvature=-0.003)
    sol = _solve_ok(curved, mode="planar")
    geo = geometry(curved)
    for b, (_, beam) in enumerate(_beams(sol)):
        arc = arc_point(geo.base[b], geo.theta[b], geo.curvature[b], beam.s)
        np.testing.assert_allclose(np.asarray(beam.position), np.asarray(arc), atol=1e-10)
        assert np.max(np.abs(np.asarray(beam.force))) < 1e-12
        assert np.max(np.abs(np.asarray(beam.moment))) < 1e-10
    loaded = _replace(_ref("L1"), front_curvature=0.004, back_curvature=-0.003)
    planar = _solve_ok(loaded, mode="planar")
    spatial = _solve_ok(loaded, mode="spatial")
    _assert_balanced(loaded, planar)
    np.testing.assert_allclose(
        np.asarray(planar.tip.displacement), np.asarray(spatial.tip.displacement), atol=1e-9
    )


def test_curvature_rules():
    base = _ref("L1")
    with pytest.raises(fr.FingerError, match="front_curvature = 0.5"):
        fr.validate_finger(_replace(base, front_curvature=0.5))
    clamped = _replace(
        base,
        back_curvature=0.001,
        adaptor=fr.Adaptor(fr.ClampedBase(), fr.ClampedBase(), back_clamp_length=10.0),
    )
    with pytest.raises(fr.FingerError, match="back_clamp_length = 10.0"):
        fr.validate_finger(clamped)


@pytest.mark.parametrize("case", ["L2", "L3"])
def test_large_loads_are_solved_by_direct_newton(case, request):
    """With the rotation cap (default 0.2 rad per Newton step), L2 and L3 converge by
    Newton from the undeformed shape (at most max_newton_steps iterations: no continuation
    is needed); that they are the right equilibria is checked against openseespy in
    test_reference_opensees.py."""
    sol = request.getfixturevalue(CASES[case])
    assert sol.result == fr.RESULTS.successful
    assert int(sol.iterations) <= _solve.SolverOptions().max_newton_steps


def test_line_search_solves_spatial_l2_directly(sol_l2):
    """Newton's lazy line search (a trial point whose residual has not decreased is
    dropped and half the step tried) takes 3-D L2 straight from the undeformed shape to
    the loading branch, within max_newton_steps (no continuation). Same topology as
    sol_l1_spatial: no new compile."""
    spatial = _solve_ok(_ref("L2"), mode="spatial")
    assert int(spatial.iterations) <= _solve.SolverOptions().max_newton_steps
    # Same equilibrium as the planar solve, to the sum of the two models' integration
    # errors at 10 steps per segment. Measured against 80 steps on the L2 tip: 1.0e-4 mm
    # (planar) and 2.5e-4 mm (3-D), 3.5e-4 mm together; the two solves differ by 1.7e-4
    # mm (at 20 steps by 3e-6 mm). Bound: 5e-4 mm.
    np.testing.assert_allclose(
        np.asarray(spatial.tip.displacement), np.asarray(sol_l2.tip.displacement), atol=5e-4
    )


@pytest.mark.slow
@pytest.mark.parametrize("case", ["L2", "L3"])
def test_rotation_capped_newton_matches_the_continuation(case):
    """Capped Newton lands on the loading branch: the continuation's equilibrium. On L2
    the cap is needed: without it (line search alone) Newton from the undeformed shape
    does not get there."""
    finger = _ref(case)
    topo = fr.topology_of(finger, "planar")
    direct, ok, _ = _solve.direct_core(topo, fr.Integrator(), _solve.SolverOptions(), finger, None)
    assert bool(ok) and direct.result == fr.RESULTS.successful
    if case == "L2":
        plain = _solve.SolverOptions(max_rotation_step=None)
        _, plain_ok, _ = _solve.direct_core(topo, fr.Integrator(), plain, finger, None)
        assert not bool(plain_ok)
    cont = fr.solve_finger(finger, mode="planar", options=_solve.SolverOptions(direct_first=False))
    assert int(direct.iterations) < int(cont.iterations)
    np.testing.assert_allclose(direct.unknowns, cont.unknowns, rtol=0, atol=1e-8)


def test_rotation_cap_must_be_positive():
    with pytest.raises(ValueError, match="max_rotation_step must be None or a positive"):
        fr.SolverOptions(max_rotation_step=0.0)
