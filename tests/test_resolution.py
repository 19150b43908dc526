"""The step-doubling check of the integration error (`finray_jax.check_resolution`).

The default tests check the bookkeeping (which points two solves share, the verdicts and
messages, bad input). The slow ones compile solves at several step counts and check the
estimate against the error measured against an independent fine solve.
"""

import json
import math
import pathlib
import types

import numpy as np
import pytest

import finray_jax as fr
from finray_jax.resolution import (
    ResolutionCheck,
    _shared_points,
    check_grasp_resolution,
    check_resolution,
)


def _check(observed, rel=1e-7, status="converged", suggested=6, solutions=(None, None, None)):
    return ResolutionCheck(
        steps=(10, 20, 40),
        quantity="tip",
        order=5,
        observed_order=observed,
        tip_error=rel * 20.0,
        tip_relative_error=rel,
        shape_error=2.0 * rel * 20.0,
        reaction_error=1e-8,
        normal_force_error=float("nan"),
        normal_force_relative_error=float("nan"),
        suggested_steps=suggested,
        rtol=1e-6,
        status=status,
        solutions=solutions,
    )


def test_shared_points_pick_every_other_step_point():
    # Two segments; a segment's block is its start, then its steps + 1 step points.
    n = 3
    fine = np.concatenate([[0.0], np.linspace(0.0, 1.0, 2 * n + 1)])
    fine = np.concatenate([fine, 1.0 + fine])
    coarse = np.concatenate([[0.0], np.linspace(0.0, 1.0, n + 1)])
    coarse = np.concatenate([coarse, 1.0 + coarse])
    idx = _shared_points(fine.size, n)
    assert idx.shape == coarse.shape
    np.testing.assert_array_equal(fine[idx], coarse)


def test_verdicts_follow_the_observed_order():
    ok = _check(5.2)
    assert ok.asymptotic and ok.reliable and ok.resolved
    assert "tip: observed order 5.2 (expected 5)" in ok.message
    assert "Resolved (tip) to rtol 1e-06" in ok.message
    # Converging faster than the order (before the asymptotic range): an upper bound.
    fast = _check(8.0)
    assert not fast.asymptotic and fast.reliable and fast.resolved
    assert "upper bound" in fast.message
    # Slower: the estimate is too small to trust, however small it is.
    slow = _check(3.5)
    assert not slow.reliable and not slow.resolved
    assert "Use at least 40 steps" in slow.message
    # Agreement to the solver tolerance: no order, the estimate stands.
    flat = _check(float("nan"))
    assert flat.asymptotic and flat.reliable and flat.resolved
    assert "solver tolerance" in flat.message
    big = _check(5.0, rel=1e-4, suggested=25)
    assert big.reliable and not big.resolved and "about 25 steps" in big.message


def test_fewer_suggested_steps_ask_for_a_second_check():
    msg = _check(5.0, rel=1e-9, suggested=3).message
    assert "as few as 3 steps may do (check again at 3" in msg


def test_a_failed_solve_gives_no_estimate():
    sols = tuple(types.SimpleNamespace(status=x) for x in ("converged", "beyond_limit_load", "x"))
    nan = float("nan")
    failed = _check(nan, rel=nan, status="beyond_limit_load", solutions=sols)
    assert not failed.reliable and not failed.resolved
    assert failed.message.startswith("a solve at 20 steps per segment ended beyond_limit_load")


def test_to_dict_is_json_ready():
    d = _check(float("nan")).to_dict()
    assert "solutions" not in d
    text = json.dumps(d, allow_nan=False)  # NaN written as null
    back = json.loads(text)
    assert back["observed_order"] is None and back["steps"] == [10, 20, 40]
    assert back["resolved"] is True and back["message"] == _check(float("nan")).message


@pytest.mark.parametrize("rtol", [0.0, 1.0, -1e-6, float("nan"), "1e-6", True])
def test_bad_rtol_is_named(rtol):
    with pytest.raises(ValueError, match="rtol must be a number in \\(0, 1\\)"):
        check_resolution(fr.ref_finger_a("L1"), rtol=rtol)


def test_a_solution_of_other_settings_is_refused():
    other = types.SimpleNamespace(steps=5, mode="planar")
    with pytest.raises(ValueError, match="solved planar at 5 steps per segment"):
        check_resolution(fr.ref_finger_a("L1"), mode="planar", solution=other)


def test_bad_finger_is_refused():
    with pytest.raises(TypeError, match="expected a Finger"):
        check_resolution("finger.toml")
    with pytest.raises(TypeError, match="expected a GraspSolution"):
        check_grasp_resolution(fr.ref_finger_a("L1"))


@pytest.mark.slow
def test_estimate_matches_the_error_against_a_fine_solve():
    """ref-A L2 (82 % of its limit load) at 10 steps: the estimated tip error agrees with
    the error against an 80-step solve, and the suggested steps meet rtol there."""
    finger = fr.ref_finger_a("L2")
    check = check_resolution(finger, mode="planar", rtol=1e-6)
    assert check.status == "converged" and check.steps == (10, 20, 40)
    assert 4.0 <= check.observed_order <= 7.0
    fine = fr.solve_finger(finger, mode="planar", integrator=fr.Integrator(steps=80))
    tip = lambda s: np.asarray(s.tip.displacement)
    size = np.linalg.norm(tip(fine))
    true = np.linalg.norm(tip(check.solutions[0]) - tip(fine)) / size
    assert math.isclose(check.tip_relative_error, true, rel_tol=0.15), (check, true)
    assert true > 1e-6 and not check.resolved  # 10 steps are not enough for 1e-6 here
    m = check.suggested_steps
    assert 10 < m < 20
    at_m = fr.solve_finger(finger, mode="planar", integrator=fr.Integrator(steps=m))
    assert np.linalg.norm(tip(at_m) - tip(fine)) / size <= 1e-6
    # A looser rtol is met at 10 steps.
    loose = check_resolution(finger, mode="planar", rtol=1e-5, solution=check.solutions[0])
    assert loose.resolved and loose.suggested_steps <= 10


@pytest.mark.slow
def test_cli_solve_check_resolution(tmp_path):
    from test_cli import REF_A, run

    path = tmp_path / "r.json"
    code, out, err = run(["solve", REF_A, "--check-resolution", "--out", str(path)])
    assert code == 0, out + err
    assert "resolution: 10 steps per segment: tip error about" in out
    res = json.loads(path.read_text())["resolution"]
    assert res["steps"] == [10, 20, 40] and res["status"] == "converged"
    assert res["resolved"] is True and res["tip_relative_error"] < 1e-6


def test_a_solver_without_a_fixed_order_is_refused():
    class NoOrder:
        def order(self, terms):
            raise NotImplementedError("order depends on the terms")

    integ = types.SimpleNamespace(solver=NoOrder(), steps=10)
    with pytest.raises(ValueError, match="cannot tell the order of NoOrder"):
        check_resolution(fr.ref_finger_a("L1"), integrator=integ)


@pytest.mark.slow
def test_an_unloaded_finger_is_resolved():
    """No load, no displacement: the differences are round-off, measured against the
    front beam's length instead of a zero tip displacement."""
    check = check_resolution(fr.ref_finger_a("L1").scale_loads(0.0), mode="planar")
    assert check.status == "converged"
    assert math.isnan(check.observed_order) and check.resolved
    assert check.tip_relative_error < 1e-6 and check.tip_error < 1e-9


@pytest.mark.slow
def test_grasp_normal_force_estimate_against_a_fine_solve():
    """Finger-1 closed 5 mm on its cylinder, 16 steps: with contact the check assumes
    order 2, and its normal-force estimate agrees with the change to a 128-step solve."""
    import dataclasses

    from finray_jax import io as fio
    from finray_jax._contact_result import contact_result
    from finray_jax._grasp_inputs import with_stiffness
    from finray_jax._solve import direct_core

    root = pathlib.Path(__file__).resolve().parents[1]
    finger, _ = fio.load_finger(str(root / "examples" / "grasp_finger1.toml"))
    g = fr.grasp(finger, 5.0)
    check = check_grasp_resolution(g)
    assert check.status == "converged" and check.quantity == "normal_force"
    assert check.order == 2 and check.steps == (16, 32, 64)
    assert check.reliable
    moved = with_stiffness(g.finger, g.stiffness)
    integ = dataclasses.replace(g.integrator, steps=128)
    fine, _, _ = direct_core(
        g.topology, integ, fr.SolverOptions(), moved, g.solution.unknowns, np.float64(0.0)
    )
    assert fine.status == "converged"
    f128 = float(contact_result(moved, fine, np.asarray(g.direction)).normal_force)
    true = abs(float(g.contact.normal_force) - f128)
    assert 0.5 * true <= check.normal_force_error <= 2.0 * true, (check, true)
    assert check.relative_error == check.normal_force_relative_error
    assert "contact normal force" in check.message


@pytest.mark.slow
def test_contact_lowers_the_assumed_order():
    """A finger with a support (contact) is checked at order 2, not Tsit5's 5."""
    from finray_jax.studies import MODIFIED, with_adaptor

    finger = with_adaptor(fr.ref_finger_a("L1"), MODIFIED)
    check = check_resolution(finger, mode="planar", integrator=fr.Integrator(steps=8))
    assert check.status == "converged" and check.order == 2 and check.quantity == "tip"
    assert check.steps == (8, 16, 32)


@pytest.mark.slow
def test_spatial_l2_is_as_resolved_as_planar():
    """3-D ref-A L2 at 10 steps: the frame's re-projection after every step keeps the tip
    error near the planar model's (5e-6)."""
    check = check_resolution(fr.ref_finger_a("L2"), mode="spatial")
    assert check.status == "converged" and check.reliable
    assert check.tip_relative_error < 2e-5, check


def _manufactured(n, error, p=5):
    """A stand-in Solution at n steps whose outputs are off by error * n^-p: one segment
    per main beam, its step points where a real solve puts them."""
    from finray_jax._solution import BeamSolution

    e = error * float(n) ** -p
    s = np.concatenate([[0.0], np.linspace(0.0, 50.0, n + 1)])
    pos = np.stack([np.sin(s / 50.0), np.zeros_like(s), s], axis=1) + e
    beam = BeamSolution.pack(
        np.asarray(s), pos, np.broadcast_to(np.eye(3), (s.size, 3, 3)), 0 * pos, 0 * pos
    )
    wrench = types.SimpleNamespace(force=np.array([1.0, 0.0, -2.0]) + e)
    return types.SimpleNamespace(
        status="converged",
        tip=types.SimpleNamespace(displacement=np.array([3.0, 0.0, 4.0]) + e),
        front=beam,
        back=beam,
        reactions_front=wrench,
        reactions_back=wrench,
    )


def test_richardson_recovers_a_manufactured_error():
    """Outputs off by C n^-5: the estimate is exactly C n^-5 (times sqrt 3 for the three
    components), the observed order 5, and the suggested steps meet rtol."""
    from finray_jax.resolution import _estimate

    n, C = 4, 0.5
    sols = [_manufactured(k * n, C) for k in (1, 2, 4)]
    check = _estimate(sols, n, 5, 1e-6, 100.0)
    true = C * n**-5.0 * math.sqrt(3.0)
    size = float(np.linalg.norm(sols[2].tip.displacement))  # the finest tip's size
    assert math.isclose(check.tip_error, true, rel_tol=1e-9)
    assert math.isclose(check.tip_relative_error, true / size, rel_tol=1e-9)
    assert math.isclose(check.shape_error, true, rel_tol=1e-9)
    assert math.isclose(check.reaction_error, true, rel_tol=1e-9)
    assert math.isclose(check.observed_order, 5.0, rel_tol=1e-9)
    assert check.asymptotic and check.reliable and not check.resolved
    m = check.suggested_steps
    rel = lambda k: C * k**-5.0 * math.sqrt(3.0) / size
    assert rel(m) <= 1e-6 < rel(m - 1)
    # A grasp: the normal force decides.
    forces = [2.0 + 0.1 * (k * n) ** -5.0 for k in (1, 2, 4)]
    grasp = _estimate(sols, n, 5, 1e-6, 100.0, forces)
    assert grasp.quantity == "normal_force"
    assert math.isclose(grasp.normal_force_error, 0.1 * n**-5.0, rel_tol=1e-9)
    assert grasp.relative_error == grasp.normal_force_relative_error


def test_a_failed_member_is_reported():
    from finray_jax.resolution import _estimate

    sols = [_manufactured(k * 4, 0.5) for k in (1, 2, 4)]
    sols[2].status = "failed"
    check = _estimate(sols, 4, 5, 1e-6, 100.0)
    assert check.status == "failed" and math.isnan(check.tip_error) and not check.resolved
    assert check.message.startswith("a solve at 16 steps per segment ended failed")
