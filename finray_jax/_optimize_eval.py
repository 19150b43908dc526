"""The optimiser's evaluations of the objective (see `optimizer`'s docstring for the
method): the set-up at the initial design (the objects' grasps and peak pulls, the
compiled program's static part and numbers, the first anchors), and the loss and
gradient at a design, warm started from the anchors, with the fresh warm starts
(re-grasping, following the pull to its peak) that a failed warm start needs."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._contact import friction_may_act, with_friction
from ._finger import Finger
from ._grasp import grasp
from ._grasp_inputs import with_contact, with_objects_moved, with_stiffness
from ._grasp_solution import GraspSolution
from ._objective import (
    CONSTRAINTS,
    Anchors,
    Data,
    Static,
    design_of,
    loss_and_grad,
    pull_slope,
)
from ._optimize_problem import OptimizeProblem
from ._release import pulled_to, release_force
from ._solution import RESULTS
from ._solve import SolverOptions
from ._stepper import Stepper
from .design import design_valid_jit
from .design import set_design as _set_design
from .optimize_file import OptimizeError

MAX_HALVINGS = 6  # a step (or a move of the pull) is halved at most this often


@dataclasses.dataclass
class Setup:
    """Everything the loop needs: the compiled program's static part, the numbers, and
    the initial grasps (for the 'before' figure)."""

    static: Static
    data: Data
    anchors: Anchors
    grasps: list


def _pull_finger(problem: OptimizeProblem, finger: Finger) -> Finger:
    return with_contact(finger, friction=problem.friction, slip_direction=problem.pull_direction)


def _initial_grasps(problem: OptimizeProblem, fingers, say):
    """Grasp every object at the initial design; (grasps, stiffnesses)."""
    gs = []
    for i, f in enumerate(fingers):
        say(f"grasp of object {i} at the initial design")
        g = grasp(
            f,
            problem.closing,
            direction=problem.direction,
            symmetric=problem.symmetric,
        )
        if not g.converged:
            raise OptimizeError(
                f"{problem.source}: the grasp of object {i} at the initial design did not "
                f"converge (closing = {problem.closing} mm): {RESULTS[g.solution.result]}"
            )
        gs.append(g)
    return gs


def _peak_pull(problem: OptimizeProblem, g: GraspSolution, i: int, say):
    """(t*, unknowns at t*) of a grasp's release trace (holding force)."""
    say(f"release trace of object {i} (finding the peak pull)")
    tr = release_force(
        g,
        pull_direction=problem.pull_direction,
        step=problem.pull_step,
        friction=problem.friction,
    )
    if not tr.peak > 0:  # (NaN: no point of the trace solved)
        raise OptimizeError(
            f"{problem.source}: object {i} is not held at the initial design (release trace "
            f"with friction = {problem.friction:g}: {tr.message}); holding_force needs a "
            "positive peak"
        )
    sol, _, ok = pulled_to(
        g,
        tr.peak_pull,
        pull_direction=problem.pull_direction,
        step=problem.pull_step,
        friction=problem.friction,
    )
    if not ok:
        raise OptimizeError(
            f"{problem.source}: could not follow object {i}'s pull to its peak at {tr.peak_pull} mm"
        )
    return tr.peak_pull, sol.unknowns


def initial_setup(problem: OptimizeProblem, say=lambda m: None) -> Setup:
    """Grasp every object at the initial design (and find its peak pull, for the holding
    force); the compiled program's static part, the numbers and the first anchors."""
    fingers = problem.object_fingers()
    gs = _initial_grasps(problem, fingers, say)
    pulls, unknowns = [], []
    for i, g in enumerate(gs):
        if problem.objective == "holding_force":
            t, u = _peak_pull(problem, g, i, say)
        else:
            t, u = 0.0, g.solution.unknowns
        pulls.append(t)
        unknowns.append(u)
    bases = fingers
    if problem.objective == "holding_force":
        bases = [_pull_finger(problem, f) for f in fingers]
    anchors = Anchors(
        unknowns=jnp.stack(unknowns),
        stiffness=jnp.asarray([[float(g.stiffness), float(g.support_stiffness)] for g in gs]),
        closing=jnp.asarray([float(g.closing) for g in gs], jnp.float64),
        pull=jnp.asarray(pulls, jnp.float64),
    )
    topology = gs[0].topology  # built while closing: frictionless
    if friction_may_act(bases[0].contact):
        topology = with_friction(topology)
    static = Static(
        names=problem.names,
        objective=problem.objective,
        aggregate=problem.aggregate,
        constraints=problem.active_constraints(),
        topology=topology,
        direction=tuple(
            float(v) for v in np.asarray(problem.direction) / np.linalg.norm(problem.direction)
        ),
        pull=tuple(
            float(v)
            for v in np.asarray(problem.pull_direction) / np.linalg.norm(problem.pull_direction)
        ),
        holding_factor=2 if problem.symmetric else 1,
        integrator=gs[0].integrator,
        options=SolverOptions(),
    )
    limits = np.zeros(len(CONSTRAINTS))
    scales = np.ones(len(CONSTRAINTS))
    for j, c in enumerate(CONSTRAINTS):
        if c in problem.constraints:
            limits[j] = problem.constraints[c]
            if limits[j] > 0:
                scales[j] = limits[j]
    data = Data(
        bases=jax.tree_util.tree_map(lambda *a: jnp.stack(a), *bases),  # (objects, ...)
        lo=jnp.asarray(problem.lo, jnp.float64),
        hi=jnp.asarray(problem.hi, jnp.float64),
        limits=jnp.asarray(limits, jnp.float64),
        scales=jnp.asarray(scales, jnp.float64),
        objective_scale=jnp.ones((), jnp.float64),
        temperature=jnp.asarray(problem.temperature, jnp.float64),
        weight=jnp.asarray(problem.penalty_weight, jnp.float64),
        shift=jnp.asarray(problem.penalty_shift, jnp.float64),
    )
    return Setup(static, data, anchors, gs)


# --------------------------------------------------------------------------------------
# Evaluations: anchors, the peak pull, re-grasping after a failed warm start
# --------------------------------------------------------------------------------------


def refine_pull(setup: Setup, z, anchors: Anchors, step: float, max_iter: int = 6):
    """Move every object's pull t to the peak of F(t) at design z (Newton on dF/dt = 0,
    or t = 0 where F falls from the onset of the pull: there friction holds hardest;
    d2F/dt2 by a difference of dF/dt; a move whose solve fails is halved); returns the
    new anchors, or None if the solves keep failing."""
    st, data = setup.static, setup.data
    v, s, u, ok = pull_slope(z, st, data, anchors)
    if not bool(jnp.all(ok)):
        return None
    anchors = eqx.tree_at(lambda a: a.unknowns, anchors, u)
    dt = 1e-3 * step
    for _ in range(max_iter):
        interior = jnp.abs(s) * step <= 1e-10 * jnp.abs(v)
        at_start = (anchors.pull <= 0.0) & (s < 0)  # F falls from the pull's onset
        if bool(jnp.all(interior | at_start)):
            break
        probe = eqx.tree_at(lambda a: a.pull, anchors, anchors.pull + dt)
        _, s2, _, ok2 = pull_slope(z, st, data, probe)
        if not bool(jnp.all(ok2)):
            return None
        curv = (s2 - s) / dt
        # Newton toward the maximum; uphill by at most one pull step where F is not concave
        move = jnp.where(curv < 0, -s / jnp.where(curv < 0, curv, -1.0), jnp.sign(s) * step)
        move = jnp.clip(move, -step, step)
        for _halving in range(MAX_HALVINGS):  # a sharp peak (friction): shorter moves
            trial = eqx.tree_at(lambda a: a.pull, anchors, jnp.maximum(anchors.pull + move, 0.0))
            v2, s2, u, ok = pull_slope(z, st, data, trial)
            if bool(jnp.all(ok)):
                break
            move = 0.5 * move
        else:
            return None
        v, s = v2, s2
        anchors = eqx.tree_at(lambda a: a.unknowns, trial, u)
    return anchors


def reanchor(problem: OptimizeProblem, setup: Setup, x, anchors: Anchors, say):
    """Fresh warm starts at design x by full grasps (and pull traces) at the anchors'
    penalty stiffness; None if one fails. They are solved on the initial grasps' segment
    table, as the loss is: the design's own cuts can differ (Finger-1's support length near
    48 mm cuts the back beam into one segment more)."""
    fingers = problem.object_fingers()
    topology = setup.grasps[0].topology  # (frictionless: built while closing)
    unknowns, pulls = [], []
    for i, base in enumerate(fingers):
        say(f"re-grasping object {i} (the warm-started Newton solve did not converge)")
        f = _set_design(base, dict(zip(problem.names, np.asarray(x).tolist())))
        f = with_stiffness(f, *anchors.stiffness[i])
        g = grasp(
            f,
            float(anchors.closing[i]),
            direction=problem.direction,
            stiffen=False,
            topology=topology,
        )
        if not g.converged:
            return None
        u, t = g.solution.unknowns, 0.0
        if problem.objective == "holding_force":
            pf = _pull_finger(problem, g.finger)
            e = np.asarray(setup.static.pull)
            stp = Stepper(pf, "planar", g.integrator, SolverOptions(), False, topology=g.topology)
            t, sol, ok = stp.follow(
                lambda t, pf=pf, e=e: with_objects_moved(pf, t * e),
                0.0,
                float(anchors.pull[i]),
                g.solution,
                problem.pull_step,
                1e-4,
            )
            if not ok:
                return None
            u = sol.unknowns
        unknowns.append(u)
        pulls.append(t)
    return eqx.tree_at(
        lambda a: (a.unknowns, a.pull),
        anchors,
        (jnp.stack(unknowns), jnp.asarray(pulls, jnp.float64)),
    )


def evaluate(problem, setup: Setup, z, anchors: Anchors, say):
    """Loss, aux and gradient at z, warm started from `anchors` (re-anchored by full grasps
    if that fails). Returns (loss, aux, grad, anchors) or None if z cannot be solved or
    leaves the topology."""
    st, data = setup.static, setup.data
    x = design_of(data, z)
    if not bool(design_valid_jit(problem.designed(np.asarray(x)), st.topology)):
        return None
    for attempt in range(2):
        ok = True
        if problem.objective == "holding_force":
            refined = refine_pull(setup, z, anchors, problem.pull_step)
            ok = refined is not None
            anchors = refined if ok else anchors
        if ok:
            (loss, aux), grad = loss_and_grad(z, st, data, anchors)
            ok = bool(jnp.all(aux["converged"])) and bool(aux["valid"])
            ok = ok and bool(jnp.isfinite(loss)) and bool(jnp.all(jnp.isfinite(grad)))
            if ok:
                return loss, aux, grad, eqx.tree_at(lambda a: a.unknowns, anchors, aux["unknowns"])
        if attempt == 0:
            anchors = reanchor(problem, setup, np.asarray(x), anchors, say)
            if anchors is None:
                return None
    return None
