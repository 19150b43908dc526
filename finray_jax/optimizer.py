"""Gradient-based design optimisation of a grasp, from an optimisation file (TOML).

`finray optimize OPT.toml --out DIR` (or `load_optimize` + `run_optimize`) maximises the
contact force or the holding force of a grasp, for one object or several cylinder sizes
(their mean or a smooth worst case), over named design values of the finger
(`finray_jax.design`: the adaptor's clamp region, the crossbeam layout, thicknesses...).

Method (format reference and discussion: docs/optimize-format.md):

- Bounds by reparameterisation: design value x_j = lo_j + (hi_j - lo_j) sigmoid(z_j); the
  optimiser (optax, Adam by default) works on the unconstrained z.
- Every objective evaluation is ONE Newton solve of the grasp of the current design,
  started from the last accepted design's equilibrium (the anchor), at the anchor's
  penalty stiffness (the stiffness `grasp` chose for the initial design is kept for the
  whole run, so the model does not change under the optimiser), and differentiated by the
  implicit function theorem (`jax.value_and_grad`).
- Holding force: H(x) = max over the pull distance t of F(t, x), the force the fingers
  exert against the pull. Its gradient is, by the envelope theorem, dF/dx at the peak
  pull t*(x); t* is located once by `release_force` and then followed by secant steps on
  dF/dt = 0 (dF/dt by forward-mode implicit differentiation).
- Constraints (minimum thickness, minimum clear spacing between crossbeams, crossbeams
  that do not cross, a strain limit for the material, a maximum contact pressure) enter
  as quadratic exterior penalties on every point that violates them, shifted inward by
  a small relative margin. The best design is the best *feasible* iterate (every
  constraint's margin >= 0 with the true, unshifted limits), so what is saved respects
  every bound and constraint.
- A step that leaves the topology (design_valid false), or whose Newton solve does not
  converge from the anchor even after a fresh `grasp`, is halved (up to 6 times).

Files in DIR: progress.csv (one row per iteration, flushed and fsync'ed),
checkpoint.json (the optimiser's state after the last row: a re-run continues from it),
best.toml (the best feasible design, rewritten whenever it improves), result.json,
design.png (before and after) and convergence.png.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
import tomllib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import io as fio
from ._contact import smoothing
from ._finger import BACK, FRONT, Finger
from ._geometry import geometry
from ._grasp import (
    GraspSolution,
    _half_thickness,
    _moved,
    _Stepper,
    _with_stiffness,
    grasp,
    release_force,
)
from ._objects import _safe_norm
from ._rod import Integrator
from ._solution import RESULTS
from ._solve import SolverOptions, _direct_core
from .design import DesignError, check_design_names, design_valid, get_design, main_beam_strain
from .design import set_design as _set_design

__all__ = [
    "CONSTRAINTS",
    "OBJECTIVES",
    "OptimizeError",
    "OptimizeProblem",
    "OptimizeRun",
    "load_optimize",
    "loads_optimize",
    "run_optimize",
]

OBJECTIVES = ("contact_force", "holding_force")
AGGREGATES = ("mean", "worst")
OPTIMIZERS = ("adam", "sgd")
CONSTRAINTS = ("min_thickness", "min_spacing", "crossing", "max_strain", "max_pressure")
PROGRESS_CSV, CHECKPOINT, BEST_TOML, RESULT_JSON = (
    "progress.csv",
    "checkpoint.json",
    "best.toml",
    "result.json",
)
DESIGN_PNG, CONVERGENCE_PNG = "design.png", "convergence.png"
MAX_HALVINGS = 6
_FORMAT = 1  # bump when the meaning of an optimisation file or its CSV changes


class OptimizeError(fio.FingerFileError):
    """An invalid optimisation file, or an output directory that holds another run."""


# --------------------------------------------------------------------------------------
# Contact totals (differentiable in reverse mode)
# --------------------------------------------------------------------------------------


def _contact_totals(finger: Finger, sol):
    """(normal force, total force (x, y, z), pressure front, pressure back) of a solved
    grasp: the same quantities as `contact_result` (exact totals from the jump of n on
    every segment, split between objects and support by the sampled shares), written with
    divisions that stay finite in the unselected branch of a `where`, so that reverse-mode
    gradients are finite (contact_result's `x / maximum(size, tiny)` is 0 / 0 on segments
    without contact, where tiny underflows to 0, and its reverse pass gives NaN)."""
    from ._contact import penalty
    from ._grasp import _blocks, _blocks_integral, _distributed

    geo = geometry(finger)
    c = finger.contact
    k, delta = c.stiffness, smoothing(finger)
    clamp = (finger.adaptor.front_clamp_length, finger.adaptor.back_clamp_length)
    force = jnp.zeros(3)
    normal = jnp.zeros(())
    pressures = []
    for beam, bs in ((FRONT, sol.front), (BACK, sol.back)):
        p = bs.position[:, ::2]
        h = _half_thickness(finger, beam, bs.s, geo.length[beam])
        free = bs.s > clamp[beam]
        q_obj = jnp.zeros_like(bs.s)
        f_obj = jnp.zeros((bs.s.shape[0], 2))
        for obj in finger.objects:
            q = obj.params()
            d, grad = jax.vmap(jax.value_and_grad(lambda x, q=q, obj=obj: obj.distance(q, x)))(p)
            qn = jnp.where(free, penalty(d - h, k, delta), 0.0)
            t = bs.frame[:, ::2, 2]
            slide = c.friction * jnp.tanh((t @ c.slip_direction) / c.friction_regularisation)
            f_obj = f_obj + qn[:, None] * (grad + slide[:, None] * t)
            q_obj = q_obj + qn
        f_sup = jnp.zeros_like(f_obj)
        if beam == BACK and finger.adaptor.support_length is not None:
            th = geo.theta[BACK]
            nrm = -jnp.stack([jnp.cos(th), -jnp.sin(th)])
            gap = (p - geo.base[BACK, ::2]) @ nrm
            on = free & (bs.s < finger.adaptor.support_length)
            f_sup = jnp.where(on, penalty(gap, k, delta), 0.0)[:, None] * nrm[None]
        s_b = _blocks(bs.s, sol.steps)
        n_b = _blocks(bs.force[:, ::2], sol.steps)
        exact = -(n_b[:, -1] - n_b[:, 0]) - _distributed(finger, beam, s_b[:, 0], s_b[:, -1])
        so, ss, qo = (_blocks_integral(x, s_b, sol.steps) for x in (f_obj, f_sup, q_obj[:, None]))
        sampled = so + ss
        tiny = 1e-24 * jnp.maximum(jnp.sum(exact * exact, axis=1), 1e-280)
        size = jnp.sum(sampled * sampled, axis=1)
        has_o = jnp.sum(so * so, axis=1) > tiny
        has_s = jnp.sum(ss * ss, axis=1) > tiny
        some = size > tiny
        scale = jnp.where(some, jnp.sum(exact * sampled, axis=1) / jnp.where(some, size, 1.0), 1.0)
        obj_part = jnp.where(
            (~has_s)[:, None], exact, jnp.where(has_o[:, None], scale[:, None] * so, 0.0)
        )
        force = force + jnp.insert(jnp.sum(obj_part, axis=0), 1, 0.0)
        q_exact = jnp.where(has_o & some, scale * qo[:, 0], _safe_norm(obj_part))
        normal = normal + jnp.sum(q_exact)
        pressures.append(q_obj)
    return normal, force, pressures[0], pressures[1]


# --------------------------------------------------------------------------------------
# The traced objective
# --------------------------------------------------------------------------------------


class _Static(eqx.Module):
    """What fixes the compiled program: names, kinds, topology, solver settings."""

    names: tuple = eqx.field(static=True)
    objective: str = eqx.field(static=True)
    aggregate: str = eqx.field(static=True)
    constraints: tuple = eqx.field(static=True)  # the active ones, in CONSTRAINTS order
    topology: object = eqx.field(static=True)
    direction: tuple = eqx.field(static=True)  # closing direction w (x, z)
    pull: tuple = eqx.field(static=True)  # pull direction (x, z)
    holding_factor: int = eqx.field(static=True)
    integrator: Integrator
    options: SolverOptions


class _Data(eqx.Module):
    """The problem's numbers (arrays: changing them never recompiles)."""

    bases: Finger  # the base finger of every object, stacked on a leading axis
    lo: jax.Array
    hi: jax.Array
    limits: jax.Array  # (5,) per CONSTRAINTS; unused entries are ignored
    scales: jax.Array  # (5,) what a relative margin of 1 means, per CONSTRAINTS
    objective_scale: jax.Array  # the initial design's objective (normalises the loss)
    temperature: jax.Array  # worst case: smooth-min temperature, relative to objective_scale
    weight: jax.Array  # penalty weight
    shift: jax.Array  # relative inward shift of every constraint in the penalty


class _Anchors(eqx.Module):
    """Per object (leading axis): the warm start of Newton and the grasp's state."""

    unknowns: jax.Array
    stiffness: jax.Array
    closing: jax.Array
    pull: jax.Array  # the peak pull t* (holding force; 0 for the contact force)


def _design_of(data: _Data, z):
    return data.lo + (data.hi - data.lo) * jax.nn.sigmoid(z)


def _z_of(data_lo, data_hi, x):
    u = (np.asarray(x, float) - data_lo) / (data_hi - data_lo)
    return np.log(u) - np.log1p(-u)


def _values(static: _Static, x) -> dict:
    return {n: x[j] for j, n in enumerate(static.names)}


def _solve_one(static: _Static, base: Finger, x, unknowns, stiffness, closing, pull):
    """The grasp of one object at design x: (objective value, solution, moved finger,
    pressures front/back)."""
    finger = _set_design(base, _values(static, x))
    w, e = jnp.asarray(static.direction), jnp.asarray(static.pull)
    moved = _with_stiffness(_moved(finger, -closing * w + pull * e), stiffness)
    sol, _ = _direct_core(static.topology, static.integrator, static.options, moved, unknowns)
    normal, force, pf, pb = _contact_totals(moved, sol)
    if static.objective == "contact_force":
        value = normal
    else:
        value = static.holding_factor * jnp.dot(force[::2], e)
    return value, sol, moved, pf, pb


def _design_margins(static: _Static, data: _Data, finger: Finger):
    """Relative margins (arrays; >= 0 is feasible) and true margins (physical units) of
    the constraints that depend on the design alone."""
    rel, true = {}, {}
    cb = finger.crossbeams
    C = cb.front_s.shape[0]
    lim = dict(zip(CONSTRAINTS, data.limits))
    sc = dict(zip(CONSTRAINTS, data.scales))
    if "min_thickness" in static.constraints:
        t = [finger.front.thickness, finger.back.thickness]
        t += [s.tip_thickness for s in (finger.front, finger.back) if s.tip_thickness is not None]
        t = jnp.concatenate([jnp.stack(t), cb.thickness])
        m = t - lim["min_thickness"]
        rel["min_thickness"], true["min_thickness"] = m / sc["min_thickness"], jnp.min(m)
    if C >= 2 and "min_spacing" in static.constraints:
        mean_t = 0.5 * (cb.thickness[1:] + cb.thickness[:-1])
        gaps = jnp.concatenate([jnp.diff(cb.front_s), jnp.diff(cb.back_s)])
        m = gaps - jnp.concatenate([mean_t, mean_t]) - lim["min_spacing"]
        rel["min_spacing"], true["min_spacing"] = m / sc["min_spacing"], jnp.min(m)
    if C >= 2 and "crossing" in static.constraints:
        m = jnp.concatenate([jnp.diff(cb.front_s), jnp.diff(cb.back_s)])
        rel["crossing"], true["crossing"] = m / sc["crossing"], jnp.min(m)
    return rel, true


def _state_margins(static: _Static, data: _Data, fingers, sols, pf, pb):
    """Strain and pressure margins over every point of every object's grasp (vmapped
    inputs: leading axis = object)."""
    rel, true = {}, {}
    lim = dict(zip(CONSTRAINTS, data.limits))
    sc = dict(zip(CONSTRAINTS, data.scales))
    if "max_strain" in static.constraints:
        strain = jax.vmap(
            lambda s, f: jnp.concatenate(
                [main_beam_strain(s, f, FRONT), main_beam_strain(s, f, BACK)]
            )
        )(sols, fingers)
        m = lim["max_strain"] - strain
        rel["max_strain"], true["max_strain"] = m / sc["max_strain"], jnp.min(m)
    if "max_pressure" in static.constraints:
        p = jnp.concatenate(
            [pf / fingers.front.depth[:, None], pb / fingers.back.depth[:, None]], axis=1
        )
        m = lim["max_pressure"] - p
        rel["max_pressure"], true["max_pressure"] = m / sc["max_pressure"], jnp.min(m)
    return rel, true


def _aggregate(static: _Static, data: _Data, values):
    """(smooth aggregate for the loss, true aggregate to report)."""
    if static.aggregate == "mean" or values.shape[0] == 1:
        m = jnp.mean(values) if static.aggregate == "mean" else values[0]
        return m, m
    T = data.temperature * data.objective_scale
    smooth = -T * jax.nn.logsumexp(-values / T)  # in [min - T log n, min]
    return smooth, jnp.min(values)


def _loss(z, static: _Static, data: _Data, anchors: _Anchors):
    x = _design_of(data, z)
    solve = lambda b, u, k, d, t: _solve_one(static, b, x, u, k, d, t)
    values, sols, moved, pf, pb = jax.vmap(solve)(
        data.bases, anchors.unknowns, anchors.stiffness, anchors.closing, anchors.pull
    )
    smooth, agg = _aggregate(static, data, values)
    first = jax.tree_util.tree_map(lambda a: a[0], moved)
    rel, true = _design_margins(static, data, first)
    r2, t2 = _state_margins(static, data, moved, sols, pf, pb)
    rel, true = {**rel, **r2}, {**true, **t2}
    penalty = jnp.zeros(())
    for m in rel.values():
        penalty = penalty + jnp.sum(jax.nn.relu(data.shift - m) ** 2)
    loss = -smooth / data.objective_scale + data.weight * penalty
    valid = design_valid(first, static.topology)
    ad = first.adaptor
    if ad.support_length is not None:
        valid = valid & (ad.support_length >= ad.back_clamp_length)
    aux = {
        "x": x,
        "values": values,
        "objective": agg,
        "penalty": penalty,
        "margins": true,
        "valid": valid,
        "converged": sols.result == RESULTS.successful,
        "unknowns": sols.unknowns,
    }
    return loss, aux


_loss_and_grad = eqx.filter_jit(jax.value_and_grad(_loss, has_aux=True))
_loss_only = eqx.filter_jit(_loss)


@eqx.filter_jit
def _pull_slope(z, static: _Static, data: _Data, anchors: _Anchors):
    """Per object: F(t), dF/dt at the anchors' pulls, and the equilibria (holding force)."""
    x = _design_of(data, z)

    def one(b, u, k, d, t):
        def f(t):
            value, sol = _solve_one(static, b, x, u, k, d, t)[:2]
            return value, (sol.unknowns, sol.result == RESULTS.successful)

        value, slope, (unknowns, ok) = jax.jvp(f, (t,), (jnp.ones_like(t),), has_aux=True)
        return value, slope, unknowns, ok

    return jax.vmap(one)(
        data.bases, anchors.unknowns, anchors.stiffness, anchors.closing, anchors.pull
    )


# --------------------------------------------------------------------------------------
# The problem
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DesignVar:
    """One optimised design value, kept in [lo, hi] (initial: the finger's value)."""

    name: str
    lo: float
    hi: float
    initial: float


@dataclasses.dataclass(frozen=True)
class OptimizeProblem:
    """A parsed optimisation file (see docs/optimize-format.md)."""

    source: str
    finger_path: str
    finger: Finger
    settings: fio.SolveSettings
    objective: str = "contact_force"
    friction: float = 0.0
    closing: float = 6.0
    direction: tuple = (-1.0, 0.0)
    pull_direction: tuple = (0.0, 1.0)
    symmetric: bool = True
    pull_step: float = 2.0
    diameters: tuple | None = None
    object_height: float = 60.0
    clearance: float = 0.5
    aggregate: str = "mean"
    temperature: float = 0.02
    design: tuple = ()
    constraints: dict = dataclasses.field(default_factory=dict)
    optimizer: str = "adam"
    learning_rate: float = 0.1
    iterations: int = 30
    tolerance: float = 1e-4
    patience: int = 3
    penalty_weight: float = 100.0
    penalty_shift: float = 0.01
    digest: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.design)

    @property
    def lo(self) -> np.ndarray:
        return np.asarray([d.lo for d in self.design], float)

    @property
    def hi(self) -> np.ndarray:
        return np.asarray([d.hi for d in self.design], float)

    @property
    def x0(self) -> np.ndarray:
        return np.asarray([d.initial for d in self.design], float)

    def object_fingers(self) -> list[Finger]:
        """The base finger of every object (its design values at the initial design)."""
        from .studies import with_object

        base = _set_design(self.finger, dict(zip(self.names, self.x0.tolist())))
        if self.diameters is None:
            return [base]
        return [
            with_object(base, d, height=self.object_height, clearance=self.clearance)
            for d in self.diameters
        ]

    def active_constraints(self) -> tuple[str, ...]:
        n_cb = self.finger.n_crossbeams
        out = [c for c in CONSTRAINTS if c in self.constraints]
        if n_cb >= 2 and any(n.startswith("crossbeams.") for n in self.names):
            out.append("crossing")  # always, when the layout moves
        return tuple(c for c in CONSTRAINTS if c in out)

    def designed(self, x) -> Finger:
        """The base finger with design values x (one per [[design]] entry)."""
        return _set_design(self.finger, dict(zip(self.names, np.asarray(x, float).tolist())))


def _stack(trees):
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *trees)


def _with_contact(finger: Finger, **values) -> Finger:
    c = finger.contact
    for key, v in values.items():
        c = eqx.tree_at(lambda c, key=key: getattr(c, key), c, jnp.asarray(v, jnp.float64))
    return eqx.tree_at(lambda f: f.contact, finger, c)


@dataclasses.dataclass
class _Setup:
    """Everything the loop needs: the compiled program's static part, the numbers, and
    the initial grasps (for the 'before' figure)."""

    static: _Static
    data: _Data
    anchors: _Anchors
    grasps: list


def _pull_finger(problem: OptimizeProblem, finger: Finger) -> Finger:
    return _with_contact(finger, friction=problem.friction, slip_direction=problem.pull_direction)


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
    if tr.peak <= 0:
        raise OptimizeError(
            f"{problem.source}: object {i} is not held at the initial design (release trace: "
            f"{tr.message}); holding_force needs a positive peak"
        )
    finger = _pull_finger(problem, g.finger)
    e = np.asarray(problem.pull_direction, float)
    st = _Stepper(finger, "planar", g.integrator, SolverOptions(), False)
    at = lambda t: _moved(finger, t * e)
    t, sol, ok = st.follow(at, 0.0, tr.peak_pull, g.solution, problem.pull_step, 1e-4)
    if not ok:
        raise OptimizeError(
            f"{problem.source}: could not follow object {i}'s pull to its peak at {tr.peak_pull} mm"
        )
    return tr.peak_pull, sol.unknowns


def _setup(problem: OptimizeProblem, say=lambda m: None) -> _Setup:
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
    anchors = _Anchors(
        unknowns=jnp.stack(unknowns),
        stiffness=jnp.stack([jnp.asarray(g.stiffness, jnp.float64) for g in gs]),
        closing=jnp.asarray([float(g.closing) for g in gs], jnp.float64),
        pull=jnp.asarray(pulls, jnp.float64),
    )
    static = _Static(
        names=problem.names,
        objective=problem.objective,
        aggregate=problem.aggregate,
        constraints=problem.active_constraints(),
        topology=gs[0].topology,
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
    data = _Data(
        bases=_stack(bases),
        lo=jnp.asarray(problem.lo, jnp.float64),
        hi=jnp.asarray(problem.hi, jnp.float64),
        limits=jnp.asarray(limits, jnp.float64),
        scales=jnp.asarray(scales, jnp.float64),
        objective_scale=jnp.ones((), jnp.float64),
        temperature=jnp.asarray(problem.temperature, jnp.float64),
        weight=jnp.asarray(problem.penalty_weight, jnp.float64),
        shift=jnp.asarray(problem.penalty_shift, jnp.float64),
    )
    return _Setup(static, data, anchors, gs)


# --------------------------------------------------------------------------------------
# Steps: anchors, the peak pull, re-grasping after a failed warm start
# --------------------------------------------------------------------------------------


def _refine_pull(setup: _Setup, z, anchors: _Anchors, step: float, max_iter: int = 6):
    """Move every object's pull t to the peak of F(t) at design z (Newton on dF/dt = 0,
    d2F/dt2 by a difference of dF/dt); returns the new anchors, or None if a solve
    fails."""
    st, data = setup.static, setup.data
    v, s, u, ok = _pull_slope(z, st, data, anchors)
    if not bool(jnp.all(ok)):
        return None
    anchors = eqx.tree_at(lambda a: a.unknowns, anchors, u)
    dt = 1e-3 * step
    for _ in range(max_iter):
        if float(jnp.max(jnp.abs(s) * step - 1e-10 * jnp.abs(v))) <= 0:
            break
        probe = eqx.tree_at(lambda a: a.pull, anchors, anchors.pull + dt)
        _, s2, _, ok2 = _pull_slope(z, st, data, probe)
        if not bool(jnp.all(ok2)):
            return None
        curv = (s2 - s) / dt
        # Newton toward the maximum; uphill by at most one pull step where F is not concave
        move = jnp.where(curv < 0, -s / jnp.where(curv < 0, curv, -1.0), jnp.sign(s) * step)
        move = jnp.clip(move, -step, step)
        trial = eqx.tree_at(lambda a: a.pull, anchors, jnp.maximum(anchors.pull + move, 0.0))
        v, s, u, ok = _pull_slope(z, st, data, trial)
        if not bool(jnp.all(ok)):
            return None
        anchors = eqx.tree_at(lambda a: a.unknowns, trial, u)
    return anchors


def _reanchor(problem: OptimizeProblem, setup: _Setup, x, anchors: _Anchors, say):
    """Fresh warm starts at design x by full grasps (and pull traces) at the anchors'
    penalty stiffness; None if one fails."""
    fingers = problem.object_fingers()
    unknowns, pulls = [], []
    for i, base in enumerate(fingers):
        say(f"re-grasping object {i} (the warm-started Newton solve did not converge)")
        f = _set_design(base, dict(zip(problem.names, np.asarray(x).tolist())))
        f = _with_contact(f, stiffness=anchors.stiffness[i])
        g = grasp(f, float(anchors.closing[i]), direction=problem.direction, stiffen=False)
        if not g.converged:
            return None
        u, t = g.solution.unknowns, 0.0
        if problem.objective == "holding_force":
            pf = _pull_finger(problem, g.finger)
            e = np.asarray(setup.static.pull)
            stp = _Stepper(pf, "planar", g.integrator, SolverOptions(), False)
            t, sol, ok = stp.follow(
                lambda t, pf=pf, e=e: _moved(pf, t * e),
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


def _evaluate(problem, setup: _Setup, z, anchors: _Anchors, say):
    """Loss, aux and gradient at z, warm started from `anchors` (re-anchored by full grasps
    if that fails). Returns (loss, aux, grad, anchors) or None if z cannot be solved or
    leaves the topology."""
    st, data = setup.static, setup.data
    x = _design_of(data, z)
    if not bool(design_valid(problem.designed(np.asarray(x)), st.topology)):
        return None
    for attempt in range(2):
        ok = True
        if problem.objective == "holding_force":
            refined = _refine_pull(setup, z, anchors, problem.pull_step)
            ok = refined is not None
            anchors = refined if ok else anchors
        if ok:
            (loss, aux), grad = _loss_and_grad(z, st, data, anchors)
            ok = bool(jnp.all(aux["converged"])) and bool(aux["valid"])
            ok = ok and bool(jnp.isfinite(loss)) and bool(jnp.all(jnp.isfinite(grad)))
            if ok:
                return loss, aux, grad, eqx.tree_at(lambda a: a.unknowns, anchors, aux["unknowns"])
        if attempt == 0:
            anchors = _reanchor(problem, setup, np.asarray(x), anchors, say)
            if anchors is None:
                return None
    return None


# --------------------------------------------------------------------------------------
# The run: progress log, checkpoint, best design, resume
# --------------------------------------------------------------------------------------


def _columns(problem: OptimizeProblem, constraints, n_obj) -> tuple[str, ...]:
    cols = ["iteration", "objective", "loss", "penalty", "feasible", "halvings"]
    cols += list(problem.names)
    cols += [f"margin.{c}" for c in constraints]
    cols += [f"value[{i}]" for i in range(n_obj)]
    if problem.objective == "holding_force":
        cols += [f"pull[{i}]" for i in range(n_obj)]
    return tuple(cols + ["wall_time"])


def _fmt(x) -> str:
    x = float(x)
    return repr(x) if math.isfinite(x) else "nan"


def _fsync_write(path, text: str) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _optimizer(problem: OptimizeProblem):
    import optax

    if problem.optimizer == "adam":
        return optax.adam(problem.learning_rate)
    return optax.sgd(problem.learning_rate)


@dataclasses.dataclass(frozen=True)
class OptimizeRun:
    """What `run_optimize` did. best: the best feasible iterate (None if none was):
    iteration, objective, design values, constraint margins."""

    rows: int
    finished: bool
    reason: str
    initial_objective: float
    best: dict | None
    csv: str
    best_toml: str | None
    figures: tuple


def _load_checkpoint(problem: OptimizeProblem, out_dir: str):
    path = os.path.join(out_dir, CHECKPOINT)
    csv_path = os.path.join(out_dir, PROGRESS_CSV)
    if not os.path.exists(path):
        if os.path.exists(csv_path):
            raise OptimizeError(
                f"{out_dir} holds a {PROGRESS_CSV} without a {CHECKPOINT}: cannot continue it; "
                "use another --out"
            )
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            ck = json.load(fh)
    except (OSError, ValueError) as e:
        raise OptimizeError(
            f"{path}: unreadable checkpoint ({e}); remove {out_dir} or use another --out"
        ) from None
    if ck.get("hash") != problem.digest:
        raise OptimizeError(
            f"{out_dir} holds another optimisation (from {ck.get('source', '?')}, hash "
            f"{str(ck.get('hash'))[:12]}; this one's hash is {problem.digest[:12]}): use another "
            "--out directory, or delete that one to start again"
        )
    return ck


def _truncate_rows(csv_path: str, header: str, rows: int) -> None:
    """Keep the header and the first `rows` complete rows (a torn or extra row written
    after the last checkpoint is dropped and recomputed)."""
    if not os.path.exists(csv_path):
        raise OptimizeError(f"{csv_path} is missing but the checkpoint has {rows} rows")
    with open(csv_path, "rb") as fh:
        data = fh.read()
    lines = data.decode("utf-8").splitlines(keepends=True)
    lines = [ln for ln in lines if ln.endswith("\n")]
    if not lines or lines[0] != header:
        raise OptimizeError(f"{csv_path}: its header is not this run's columns; use another --out")
    if len(lines) - 1 < rows:
        raise OptimizeError(
            f"{csv_path} has {len(lines) - 1} rows but the checkpoint has {rows}: cannot "
            "continue; use another --out"
        )
    keep = "".join(lines[: rows + 1]).encode("utf-8")
    if keep != data:
        with open(csv_path, "r+b") as fh:
            fh.truncate(len(keep))
            fh.flush()
            os.fsync(fh.fileno())


def _anchors_json(a: _Anchors) -> dict:
    return {
        k: np.asarray(getattr(a, k)).tolist() for k in ("unknowns", "stiffness", "closing", "pull")
    }


def _anchors_from(d: dict) -> _Anchors:
    return _Anchors(
        **{k: jnp.asarray(d[k], jnp.float64) for k in ("unknowns", "stiffness", "closing", "pull")}
    )


def run_optimize(
    problem: OptimizeProblem,
    out_dir,
    *,
    max_iterations: int | None = None,
    progress=None,
    plot: bool = True,
    after_iteration=None,
) -> OptimizeRun:
    """Run (or continue) an optimisation into `out_dir` (see the module docstring).

    max_iterations: stop after this many new rows (re-run to continue). progress: a text
    stream for one line per iteration (None: quiet). after_iteration(rows) runs after each
    row and checkpoint have been written.
    """

    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    say = (
        (lambda m: print(f"  ... {m}", file=progress, flush=True)) if progress else (lambda m: None)
    )
    ck = _load_checkpoint(problem, out_dir)
    t_start = time.perf_counter()
    setup = _setup(problem, say)
    n_obj = int(setup.anchors.stiffness.shape[0])
    cons = setup.static.constraints
    cols = _columns(problem, cons, n_obj)
    header = ",".join(cols) + "\n"
    csv_path = os.path.join(out_dir, PROGRESS_CSV)
    best_path = os.path.join(out_dir, BEST_TOML)
    opt = _optimizer(problem)
    lo, hi = problem.lo, problem.hi
    if ck is None:
        z = jnp.asarray(_z_of(lo, hi, problem.x0), jnp.float64)
        anchors = setup.anchors
        probe = _evaluate(problem, setup, z, anchors, say)
        if probe is None:
            raise OptimizeError(f"{problem.source}: the initial design could not be evaluated")
        scale = abs(float(probe[1]["objective"]))
        if not scale > 0:
            raise OptimizeError(
                f"{problem.source}: the initial design's {problem.objective} is {scale}; "
                "the objects must be touched (increase the closing)"
            )
        state = {
            "rows": 0,
            "z": np.asarray(z).tolist(),
            "scale": scale,
            "best": None,
            "stall": 0,
            "last": None,
            "elapsed": 0.0,
            "anchors": _anchors_json(anchors),
            "opt_state": None,
            "done": False,
            "reason": "",
        }
        _fsync_write(csv_path, header)
    else:
        state = ck["state"]
        _truncate_rows(csv_path, header, state["rows"])
    setup.data = eqx.tree_at(
        lambda d: d.objective_scale, setup.data, jnp.asarray(state["scale"], jnp.float64)
    )
    z = jnp.asarray(state["z"], jnp.float64)
    anchors = _anchors_from(state["anchors"])
    with jax.numpy_dtype_promotion("standard"):
        opt_state = opt.init(z)
    if state["opt_state"] is not None:
        leaves, tree = jax.tree_util.tree_flatten(opt_state)
        opt_state = jax.tree_util.tree_unflatten(
            tree, [jnp.asarray(v, dtype=l.dtype) for v, l in zip(state["opt_state"], leaves)]
        )
    step = jnp.asarray(state.get("step", np.zeros(len(lo)).tolist()), jnp.float64)
    z_prev = jnp.asarray(state.get("z_prev", state["z"]), jnp.float64)
    new_rows = 0
    t0 = time.perf_counter() - state["elapsed"]
    while not state["done"]:
        k = state["rows"]
        if k >= problem.iterations:
            state["done"], state["reason"] = True, f"reached iterations = {problem.iterations}"
            break
        if max_iterations is not None and new_rows >= max_iterations:
            break
        result, halvings = None, 0
        for halvings in range(MAX_HALVINGS + 1):
            z_try = z_prev + step * 0.5**halvings if k > 0 else z
            result = _evaluate(problem, setup, z_try, anchors, say)
            if result is not None:
                break
        if result is None:
            state["done"] = True
            state["reason"] = (
                f"iteration {k}: no step (halved {MAX_HALVINGS} times) could be solved"
            )
            break
        loss, aux, grad, anchors = result
        z = z_try
        margins = {c: float(aux["margins"][c]) for c in cons}
        feasible = all(m >= 0 for m in margins.values())
        objective = float(aux["objective"])
        x = np.asarray(aux["x"])
        elapsed = time.perf_counter() - t0
        cells = [
            str(k),
            _fmt(objective),
            _fmt(loss),
            _fmt(aux["penalty"]),
            str(int(feasible)),
            str(halvings),
        ]
        cells += [_fmt(v) for v in x] + [_fmt(margins[c]) for c in cons]
        cells += [_fmt(v) for v in np.asarray(aux["values"])]
        if problem.objective == "holding_force":
            cells += [_fmt(v) for v in np.asarray(anchors.pull)]
        cells.append(_fmt(elapsed))
        if feasible and (state["best"] is None or objective > state["best"]["objective"]):
            state["best"] = {
                "iteration": k,
                "objective": objective,
                "design": dict(zip(problem.names, x.tolist())),
                "values": np.asarray(aux["values"]).tolist(),
                "margins": margins,
            }
            _fsync_write(best_path, _best_toml(problem, x, k, objective))
        last = state["last"]
        small = last is not None and abs(objective - last) <= problem.tolerance * abs(objective)
        state["stall"] = state["stall"] + 1 if (small and feasible) else 0
        state["last"] = objective
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 counts and floats
            updates, opt_state = opt.update(grad, opt_state, z)
        step = jnp.asarray(updates)
        z_prev = z
        with open(csv_path, "a", encoding="utf-8") as fh:
            fh.write(",".join(cells) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        state.update(
            rows=k + 1,
            z=np.asarray(z).tolist(),
            z_prev=np.asarray(z_prev).tolist(),
            step=np.asarray(step).tolist(),
            anchors=_anchors_json(anchors),
            opt_state=[np.asarray(v).tolist() for v in jax.tree_util.tree_leaves(opt_state)],
            elapsed=elapsed,
        )
        if state["stall"] >= problem.patience:
            state["done"] = True
            state["reason"] = (
                f"converged: objective changed by <= tolerance = "
                f"{problem.tolerance} (relative) for {problem.patience} iterations"
            )
        _fsync_write(
            os.path.join(out_dir, CHECKPOINT),
            json.dumps(
                {
                    "format": _FORMAT,
                    "hash": problem.digest,
                    "source": os.path.abspath(problem.source),
                    "state": state,
                }
            )
            + "\n",
        )
        new_rows += 1
        if progress is not None:
            m = ", ".join(f"{c} {margins[c]:.3g}" for c in cons)
            print(
                f"iteration {k}: {problem.objective} {objective:.6g} (penalty "
                f"{float(aux['penalty']):.3g}{', infeasible' if not feasible else ''}"
                f"{', halved x' + str(halvings) if halvings else ''}); "
                + ", ".join(f"{n} = {v:.5g}" for n, v in zip(problem.names, x))
                + (f"; margins: {m}" if m else ""),
                file=progress,
                flush=True,
            )
        if after_iteration is not None:
            after_iteration(k + 1)
    _fsync_write(
        os.path.join(out_dir, CHECKPOINT),
        json.dumps(
            {
                "format": _FORMAT,
                "hash": problem.digest,
                "source": os.path.abspath(problem.source),
                "state": state,
            }
        )
        + "\n",
    )
    figures = ()
    run = OptimizeRun(
        rows=state["rows"],
        finished=bool(state["done"]),
        reason=state["reason"] or "stopped (max_iterations): run again to continue",
        initial_objective=float(state["scale"]),
        best=state["best"],
        csv=csv_path,
        best_toml=best_path if state["best"] is not None else None,
        figures=figures,
    )
    if state["done"]:
        _write_result(problem, run, out_dir, time.perf_counter() - t_start)
        if plot:
            figures = _plots(problem, setup, state, out_dir, say)
            run = dataclasses.replace(run, figures=figures)
    return run


def _best_toml(problem: OptimizeProblem, x, iteration: int, objective: float) -> str:
    head = [
        f"# Best feasible design of {os.path.basename(problem.source)} (finray optimize), "
        f"iteration {iteration}:",
        f"# {problem.objective} = {objective!r} N ({problem.aggregate} over "
        f"{1 if problem.diameters is None else len(problem.diameters)} object(s)).",
        "# " + ", ".join(f"{n} = {v!r}" for n, v in zip(problem.names, np.asarray(x).tolist())),
    ]
    text = fio.finger_to_toml(problem.designed(x), problem.settings)
    w = problem.direction
    grasp_lines = [
        "",
        "[grasp]",
        f"closing = {problem.closing!r}",
        f"direction = [{float(w[0])!r}, {float(w[1])!r}]",
        f"symmetric = {'true' if problem.symmetric else 'false'}",
        f"pull_step = {problem.pull_step!r}",
    ]
    return "\n".join(head) + "\n" + text + "\n".join(grasp_lines) + "\n"


def _write_result(problem: OptimizeProblem, run: OptimizeRun, out_dir: str, wall: float):
    from . import __version__

    payload = {
        "source": os.path.abspath(problem.source),
        "objective": problem.objective,
        "aggregate": problem.aggregate,
        "diameters": None if problem.diameters is None else list(problem.diameters),
        "design": {d.name: {"bounds": [d.lo, d.hi], "initial": d.initial} for d in problem.design},
        "constraints": dict(problem.constraints),
        "initial_objective": run.initial_objective,
        "best": run.best,
        "rows": run.rows,
        "reason": run.reason,
        "finray_jax_version": __version__,
    }
    _fsync_write(os.path.join(out_dir, RESULT_JSON), json.dumps(payload, indent=2) + "\n")


def read_progress(csv_path) -> dict[str, np.ndarray]:
    """The progress CSV as float columns."""
    with open(csv_path, encoding="utf-8") as fh:
        head = fh.readline().rstrip("\n").split(",")
        rows = [line.rstrip("\n").split(",") for line in fh if line.endswith("\n")]
    cols = list(zip(*rows)) if rows else [()] * len(head)
    return {name: np.asarray(col, dtype=np.float64) for name, col in zip(head, cols)}


def _final_grasps(problem: OptimizeProblem, setup: _Setup, x):
    """Grasps of every object at design x with the run's penalty stiffness."""
    out = []
    for i, base in enumerate(problem.object_fingers()):
        f = _set_design(base, dict(zip(problem.names, np.asarray(x, float).tolist())))
        f = _with_contact(f, stiffness=setup.anchors.stiffness[i])
        out.append(grasp(f, problem.closing, direction=problem.direction, stiffen=False))
    return out


def _plots(problem: OptimizeProblem, setup: _Setup, state: dict, out_dir: str, say) -> tuple:
    from matplotlib.figure import Figure

    from .plot import plot_grasp, save_figure

    data = read_progress(os.path.join(out_dir, PROGRESS_CSV))
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.add_subplot()
    it = data["iteration"]
    feas = data["feasible"] > 0
    ax.plot(it, data["objective"], "-", color="tab:blue", label=problem.objective)
    ax.plot(it[~feas], data["objective"][~feas], "x", color="tab:red", label="infeasible")
    if state["best"] is not None:
        b = state["best"]
        ax.plot([b["iteration"]], [b["objective"]], "*", ms=12, color="tab:green", label="best")
    ax.set_xlabel("iteration")
    ax.set_ylabel(f"{problem.objective} ({problem.aggregate}) (N)")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize="small")
    conv = os.path.join(out_dir, CONVERGENCE_PNG)
    save_figure(fig, conv)
    if state["best"] is None:
        return (conv,)
    say("grasps of the initial and the best design (figure)")
    after = _final_grasps(problem, setup, [state["best"]["design"][n] for n in problem.names])
    before = setup.grasps
    n = len(before)
    fig = Figure(figsize=(9.0, 6.5 * n), layout="constrained")
    axs = np.asarray(fig.subplots(n, 2, squeeze=False))
    for i in range(n):
        for j, (g, what) in enumerate(((before[i], "initial"), (after[i], "best"))):
            plot_grasp(
                g,
                axs[i, j],
                title=f"{what} design, object {i}\ncontact force "
                f"{float(g.contact.normal_force):.4g} N",
            )
    design = os.path.join(out_dir, DESIGN_PNG)
    save_figure(fig, design)
    return (design, conv)


# --------------------------------------------------------------------------------------
# Reading optimisation files
# --------------------------------------------------------------------------------------

_TOP = (
    "finger",
    "objective",
    "friction",
    "closing",
    "objects",
    "design",
    "constraints",
    "optimizer",
    "penalty",
)
_HELP = {
    "finger": " (path of the base finger file with [[objects]], relative to this file)",
    "design": " (one [[design]] table per optimised value, with name and bounds)",
    "name": " (a design value, e.g. adaptor.back_clamp_length or crossbeams.front_s[2])",
    "bounds": " ([lo, hi])",
}


def _required(r, table, path, keys):
    for key in keys:
        if key not in table:
            full = f"{path}.{key}" if path else key
            raise r.error(full, "missing required key" + _HELP.get(key, ""))


def loads_optimize(text: str, *, source: str = "<string>", base_dir: str = ".") -> OptimizeProblem:
    """Read an optimisation from TOML text; the finger path is relative to `base_dir`."""
    r = fio._Reader(source)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise OptimizeError(f"{source}: not valid TOML: {e}") from None
    try:
        return _parse(doc, r, source, base_dir)
    except OptimizeError:
        raise
    except fio.FingerFileError as e:
        raise OptimizeError(str(e)) from None


def load_optimize(path) -> OptimizeProblem:
    """Read an optimisation file. Raises OptimizeError naming the key and the value."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            text = fh.read().decode("utf-8")
    except OSError as e:
        raise OptimizeError(f"{path}: cannot read the optimisation file: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise OptimizeError(f"{path}: not UTF-8 text: {e}") from None
    return loads_optimize(text, source=path, base_dir=os.path.dirname(os.path.abspath(path)))


def _parse(doc, r, source, base_dir) -> OptimizeProblem:
    r.table(doc, "", _TOP)
    _required(r, doc, "", ("finger", "design"))
    rel = r.string(doc["finger"], "finger")
    finger_path = os.path.normpath(os.path.join(base_dir, rel))
    if not os.path.isfile(finger_path):
        raise r.error("finger", f"no such finger file: {finger_path}", rel)
    finger, settings = fio.load_finger(finger_path)
    with open(finger_path, "rb") as fh:
        finger_hash = hashlib.sha256(fh.read()).hexdigest()
    gs = settings.grasp
    kw = {}
    kw["objective"] = r.string(doc.get("objective", "contact_force"), "objective", OBJECTIVES)
    kw["friction"] = r.number(doc.get("friction", 0.0), "friction", nonnegative=True)
    if kw["friction"] > 0 and kw["objective"] != "holding_force":
        raise r.error(
            "friction",
            'is for objective = "holding_force" (closing is frictionless)',
            doc["friction"],
        )
    closing = doc.get("closing", None if gs is None else gs.closing)
    if closing is None:
        raise r.error(
            "closing",
            "missing: give closing (mm) here or [grasp] closing in the "
            "finger file (an actuator force is not supported by the optimiser)",
        )
    kw["closing"] = r.number(closing, "closing", positive=True)
    if gs is not None:
        kw.update(direction=gs.direction, symmetric=gs.symmetric, pull_step=gs.pull_step)

    obj = r.table(
        doc.get("objects", {}),
        "objects",
        ("diameters", "height", "clearance", "aggregate", "temperature"),
    )
    if "diameters" in obj:
        ds = obj["diameters"]
        if not isinstance(ds, list) or not ds:
            raise r.error("objects.diameters", "expected a non-empty array of diameters (mm)", ds)
        kw["diameters"] = tuple(
            r.number(d, f"objects.diameters[{i}]", positive=True) for i, d in enumerate(ds)
        )
        kw["object_height"] = r.number(obj.get("height", 60.0), "objects.height")
        kw["clearance"] = r.number(obj.get("clearance", 0.5), "objects.clearance", positive=True)
    else:
        for key in ("height", "clearance"):
            if key in obj:
                raise r.error(
                    f"objects.{key}",
                    "is for objects.diameters (cylinders placed by the optimiser)",
                    obj[key],
                )
        if len(finger.objects) != 1:
            raise r.error(
                "finger",
                f"the finger file has {len(finger.objects)} objects; the "
                "optimiser needs exactly one, or objects.diameters",
                rel,
            )
    kw["aggregate"] = r.string(obj.get("aggregate", "mean"), "objects.aggregate", AGGREGATES)
    kw["temperature"] = r.number(obj.get("temperature", 0.02), "objects.temperature", positive=True)

    design = []
    for i, tbl in enumerate(r.array_of_tables(doc["design"], "design")):
        p = f"design[{i}]"
        r.table(tbl, p, ("name", "bounds", "initial"))
        _required(r, tbl, p, ("name", "bounds"))
        name = r.string(tbl["name"], f"{p}.name")
        try:
            check_design_names(finger, [name], scalar=True)
            current = float(get_design(finger, [name])[name])
        except DesignError as e:
            raise r.error(f"{p}.name", str(e), name) from None
        if name in (d.name for d in design):
            raise r.error(f"{p}.name", "listed twice", name)
        lo, hi = r.vector(tbl["bounds"], f"{p}.bounds", 2, "[lo, hi]")
        if not lo < hi:
            raise r.error(f"{p}.bounds", "needs lo < hi", tbl["bounds"])
        x0 = r.number(tbl["initial"], f"{p}.initial") if "initial" in tbl else current
        if not lo < x0 < hi:
            what = f"{p}.initial" if "initial" in tbl else f"{p}.bounds"
            val = tbl["initial"] if "initial" in tbl else tbl["bounds"]
            raise r.error(
                what,
                f"the initial value {x0!r} of {name} must lie strictly inside "
                f"the bounds [{lo!r}, {hi!r}]",
                val,
            )
        design.append(DesignVar(name, lo, hi, x0))
    if not design:
        raise r.error("design", "needs at least one [[design]] table" + _HELP["design"])
    kw["design"] = tuple(design)
    names = [d.name for d in design]
    if "adaptor.support_length" in names or "adaptor.back_clamp_length" in names:
        if finger.adaptor.support_length is not None:
            lc = next((d for d in design if d.name == "adaptor.back_clamp_length"), None)
            ls = next((d for d in design if d.name == "adaptor.support_length"), None)
            lc_hi = float(finger.adaptor.back_clamp_length) if lc is None else lc.hi
            ls_lo = float(finger.adaptor.support_length) if ls is None else ls.lo
            if lc_hi > ls_lo:
                raise r.error(
                    "design",
                    f"the bounds let the clamp (up to {lc_hi!r} mm) pass "
                    f"the support's end (from {ls_lo!r} mm): keep "
                    "adaptor.back_clamp_length <= adaptor.support_length",
                )

    cons = r.table(
        doc.get("constraints", {}),
        "constraints",
        ("min_thickness", "min_spacing", "max_strain", "max_pressure"),
    )
    kw["constraints"] = {
        key: r.number(
            v, f"constraints.{key}", positive=key != "min_spacing", nonnegative=key == "min_spacing"
        )
        for key, v in cons.items()
    }

    o = r.table(
        doc.get("optimizer", {}),
        "optimizer",
        ("kind", "learning_rate", "iterations", "tolerance", "patience"),
    )
    kw["optimizer"] = r.string(o.get("kind", "adam"), "optimizer.kind", OPTIMIZERS)
    kw["learning_rate"] = r.number(
        o.get("learning_rate", 0.1), "optimizer.learning_rate", positive=True
    )
    kw["iterations"] = r.integer(o.get("iterations", 30), "optimizer.iterations", minimum=1)
    kw["tolerance"] = r.number(o.get("tolerance", 1e-4), "optimizer.tolerance", nonnegative=True)
    kw["patience"] = r.integer(o.get("patience", 3), "optimizer.patience", minimum=1)
    pen = r.table(doc.get("penalty", {}), "penalty", ("weight", "shift"))
    kw["penalty_weight"] = r.number(pen.get("weight", 100.0), "penalty.weight", positive=True)
    kw["penalty_shift"] = r.number(pen.get("shift", 0.01), "penalty.shift", nonnegative=True)

    problem = OptimizeProblem(source, finger_path, finger, settings, **kw)
    x0f = problem.designed(problem.x0)
    from ._finger import validate_finger

    try:
        validate_finger(x0f)
    except Exception as e:  # noqa: BLE001 - reported with the file's name
        raise r.error("design", f"the initial design is invalid: {e}") from None
    if "min_thickness" in kw["constraints"]:
        t = [float(x0f.front.thickness), float(x0f.back.thickness)]
        t += np.asarray(x0f.crossbeams.thickness).tolist()
        if min(t) < kw["constraints"]["min_thickness"]:
            raise r.error(
                "constraints.min_thickness",
                f"the initial design has a beam of thickness {min(t)!r} mm, below the limit",
                cons["min_thickness"],
            )
    key = {
        "format": _FORMAT,
        "finger_sha256": finger_hash,
        **{k: (list(v) if isinstance(v, tuple) else v) for k, v in kw.items() if k != "design"},
        "design": [[d.name, d.lo, d.hi, d.initial] for d in design],
    }
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
    # iterations and tolerance may change between runs: a longer run continues the same one
    for k in ("iterations", "tolerance", "patience"):
        key.pop(k)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
    return dataclasses.replace(problem, digest=digest)
