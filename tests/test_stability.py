"""Elastic stability of equilibria: the condensed tangent stiffness against the closed-form
buckling loads of a column, its zero at a limit load's fold, the stability a grasp reports,
and a path that goes on past a fold on the stable branch next to it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize

import finray_jax as fr
import finray_jax.io
from finray_jax import _fold, design
from finray_jax._flow import flow_jacobians
from finray_jax._grasp_inputs import with_stiffness
from finray_jax._integrator import Integrator
from finray_jax._planar_rod import PlanarRod
from finray_jax._solution import RESULTS, status_name
from finray_jax._solve import SolverOptions, direct_core
from finray_jax._stability import (
    _full_jacobian,
    condensed_stability,
    stability_of,
)
from finray_jax._stepper import Stepper

# --------------------------------------------------------------------------------------
# A clamped column under an axial dead load (closed forms)
# --------------------------------------------------------------------------------------

EI, EA, KGA, LENGTH = 100.0, 1e4, 4e3, 10.0


def _critical(n_half_waves_over_length):
    """The load P at which alpha L = c, alpha^2 = (P / EI)(1 - P/EA + P/kGA): the Jacobi
    equation of the straight extensible, shearable rod under a dead axial load P (the
    lateral force stays 0, the section's shear and stretch follow n)."""
    c = (n_half_waves_over_length / LENGTH) ** 2 * EI  # P (1 - P/EA + P/kGA) = c
    a = 1.0 / KGA - 1.0 / EA
    return (-1.0 + np.sqrt(1.0 + 4.0 * a * c)) / (2.0 * a)


@jax.jit
def _jacobians(starts, Q):
    return flow_jacobians(PlanarRod(), Integrator(steps=16), starts, Q, True, False, True)[1]


def _column(P, segments):
    """Stability of the straight cantilever (clamped at s = 0, free end) under a
    compressive dead load P, cut into equal shooting segments."""
    h = LENGTH / segments
    z0 = np.arange(segments) * h * (1.0 - P / EA)
    starts = np.zeros((segments, 8))
    starts[:, 1], starts[:, 4], starts[:, 6] = z0, -P, 1.0
    Q = np.tile([h, 0.0, 0.0, 0.0, 0.0, KGA, EA, EI], (segments, 1))
    jac = _jacobians(jnp.asarray(starts), jnp.asarray(Q))
    jac = _full_jacobian(np.asarray(jac), translation_free=True)
    fixed = np.zeros((segments + 1, 3), dtype=bool)
    fixed[0] = True
    F = EI / LENGTH**2
    return condensed_stability(
        jac,
        np.arange(segments),
        np.arange(1, segments + 1),
        fixed,
        np.ones(segments, dtype=bool),
        kin_scale=np.array([LENGTH, LENGTH, 1.0]),
        wrench_scale=np.array([F, F, F * LENGTH]),
        y_scale=np.array([LENGTH, LENGTH, 1.0, F, F, F * LENGTH]),
    )


def test_cantilever_column_loses_stability_at_its_closed_form_load():
    """alpha L = pi / 2 (clamped, free end). The integration error of 16 Runge-Kutta
    steps per segment (alpha h ~ 0.04) on the linearised flow is far below 1e-9."""
    p_cr = _critical(np.pi / 2)
    assert _column(0.0, 4).stable
    assert _column(0.99 * p_cr, 4).stable
    above = _column(1.01 * p_cr, 4)
    assert not above.stable and above.min_eigenvalue < 0 and not above.conjugate_segments
    assert "negative eigenvalue" in above.message
    # dead axial load on a straight rod: conservative, K symmetric to rounding
    assert above.asymmetry < 1e-12
    root = optimize.brentq(lambda P: _column(P, 4).min_eigenvalue, 0.5 * p_cr, 1.5 * p_cr)
    assert root == pytest.approx(p_cr, rel=1e-9)
    # the softest mode is the sway of the free end: lateral, not axial
    tip = _column(1.01 * p_cr, 4).modes[0][-1]
    assert abs(tip[0]) > 1e3 * abs(tip[1])


def test_segment_held_at_both_ends_has_a_conjugate_point_at_its_closed_form_load():
    """One segment over the whole column: held at both ends it buckles at alpha L = 2 pi
    (the clamped-clamped load), where det B(s) first vanishes inside it."""
    p_cc = _critical(2.0 * np.pi)
    assert _column(0.99 * p_cc, 1).conjugate_segments == ()
    beyond = _column(1.01 * p_cc, 1)
    assert beyond.conjugate_segments == (0,)
    assert not beyond.stable and "buckle with both ends held" in beyond.message


def test_status_of_an_unstable_equilibrium_is_not_converged():
    assert status_name(RESULTS.unstable_equilibrium) == "unstable"
    assert status_name(RESULTS.stability_lost) == "failed"
    assert status_name(RESULTS.branch_changed) == "failed"


# --------------------------------------------------------------------------------------
# A limit load's fold (ref-A)
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_smallest_eigenvalue_vanishes_at_the_fold_and_not_before():
    """At the fold of ref-A under L2 the tangent stiffness is singular: its smallest
    eigenvalue, of order 10 unloaded, is 0 to the fold's refinement (the refined point
    has det J / its scale below 1e-12); on the loading branch it falls like
    sqrt(lam* - lam), and the other equilibrium next to the fold, on the far side of
    the critical mode, is unstable with the other sign of det J."""
    base = design.set_design(fr.ref_finger_a("L2"), {"adaptor.back_clamp_length": 8.0})
    topo = fr.topology_of(base, "planar")
    integrator = Integrator()
    fold = _fold.fold_point(base, init=fr.limit_load(base, mode="planar"), topology=topo)
    lam = float(fold.load_factor)

    def at(factor):
        sol = fr.solve_finger(base.scale_loads(factor * lam), mode="planar")
        assert sol.converged
        return sol, stability_of(topo, integrator, base, sol.unknowns, factor * lam)

    unloaded = at(0.0)[1].min_eigenvalue
    assert 1.0 < unloaded < 100.0
    values = [at(f)[1].min_eigenvalue for f in (0.5, 0.9, 0.99, 0.999)]
    assert all(v > 0 for v in values) and values[1] > values[2] > values[3]
    assert values[2] / values[3] == pytest.approx(np.sqrt(10.0), rel=0.05)
    at_fold = stability_of(topo, integrator, base, fold.unknowns, lam)
    assert abs(at_fold.min_eigenvalue) < 1e-6 * unloaded
    assert fr.stability(fold, base).min_eigenvalue == pytest.approx(at_fold.min_eigenvalue)

    # The unstable twin at 0.999 lam*: Newton from the fold pushed along the critical
    # mode, away from the loading branch's equilibrium.
    stable_sol, stable = at(0.999)
    mode = at_fold.perturbations[0]
    away = np.sign(np.dot(np.asarray(fold.unknowns - stable_sol.unknowns), mode))
    finger = base.scale_loads(0.999 * lam)
    opts = SolverOptions()
    _, _, sign_stable = direct_core(topo, integrator, opts, finger, stable_sol.unknowns, 0.0)
    twin, ok, sign = direct_core(
        topo, integrator, opts, finger, fold.unknowns + away * 1e-2 * mode, 0.0
    )
    assert bool(ok)
    assert np.max(np.abs(np.asarray(twin.unknowns - stable_sol.unknowns))) > 1e-3
    unstable = stability_of(topo, integrator, finger, twin.unknowns)
    assert not unstable.stable and unstable.min_eigenvalue < 0
    assert float(sign) == -float(sign_stable)


# --------------------------------------------------------------------------------------
# Grasps
# --------------------------------------------------------------------------------------


def _modified(back_clamp_length=None):
    finger, settings = fr.io.load_finger("examples/grasp_finger1_modified.toml")
    if back_clamp_length is not None:
        finger = design.set_design(finger, {"adaptor.back_clamp_length": back_clamp_length})
    return finger, settings.grasp


@pytest.mark.slow
def test_grasp_reports_a_stable_equilibrium():
    """Finger-1 on the modified adaptor closed 6 mm: stable, with the crossbeam under the
    object bowed. Penalty contact is conservative: K is symmetric to the integration's
    error with the C1 penalty (measured 7e-5)."""
    finger, settings = _modified()
    g = fr.grasp(finger, settings.closing, direction=settings.direction)
    assert g.converged and g.critical_points == ()
    s = g.stability
    assert s.stable and s.min_eigenvalue > 0 and s.conjugate_segments == ()
    assert s.asymmetry < 1e-3
    again = fr.stability(g)
    np.testing.assert_allclose(again.eigenvalues, s.eigenvalues, rtol=1e-12)


@pytest.mark.slow
def test_path_in_clamp_length_goes_on_past_its_fold_on_the_other_stable_branch():
    """Finger-1 (modified adaptor, 18 mm cylinder, closed 6 mm) followed from l_c = 2 mm
    down in l_c: its branch ends at a fold near l_c = 1.4 mm (the smallest eigenvalue
    falls toward 0 while the next stays near 4). The path goes on past it on the stable
    branch next to it, and at l_c = 0.5 mm that is the equilibrium a closing path finds
    there (same penalty stiffnesses: equal to the solver's tolerance)."""
    finger, settings = _modified(2.0)
    g = fr.grasp(finger, settings.closing, direction=settings.direction)
    assert g.converged
    stepper = Stepper(g.finger, "planar", g.integrator, SolverOptions(), False, g.topology)
    stepper.direction = np.asarray(g.direction)

    def at(u):  # l_c = 2 - u
        return design.set_design(g.finger, {"adaptor.back_clamp_length": 2.0 - u})

    u, sol, ok = stepper.follow(at, 0.0, 1.5, g.solution, 0.1, 1e-3)
    assert ok and u == pytest.approx(1.5)
    (critical,) = stepper.critical
    assert critical.switched and 0.5 < critical.between[0] < 0.7
    assert 0 <= critical.min_eigenvalue < 0.05 * 4.0
    assert "stability lost" in critical.describe()
    end = stepper.stability(at(u), sol)
    assert end.stable

    direct = fr.grasp(
        with_stiffness(_modified(0.5)[0], float(g.stiffness), float(g.support_stiffness)),
        settings.closing,
        direction=settings.direction,
        stiffen=False,
        topology=g.topology,
    )
    assert direct.converged and direct.stability.stable
    force = fr.contact_result(at(u), sol, np.asarray(g.direction)).normal_force
    assert float(force) == pytest.approx(float(direct.contact.normal_force), rel=1e-7)
    assert float(force) < float(g.contact.normal_force) - 1.0  # another branch: ~1.8 N less
