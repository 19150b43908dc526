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
import json
import math
import os
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import io as fio
from ._contact import friction_may_act, with_friction
from ._finger import Finger
from ._grasp import (
    GraspSolution,
    Stepper,
    grasp,
    release_force,
    with_contact,
    with_objects_moved,
    with_stiffness,
)
from ._solution import RESULTS
from ._solve import SolverOptions
from ._version import __version__
from .design import design_valid_jit
from .design import set_design as _set_design
from .plot import plot_grasp, save_figure

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
from ._objective import (
    CONSTRAINTS,
    OBJECTIVES,
    Anchors,
    Data,
    Static,
    design_of,
    loss_and_grad,
    pull_slope,
    z_of,
)
from .optimize_file import (
    FORMAT,
    OptimizeError,
    OptimizeProblem,
    load_optimize,
    loads_optimize,
)

PROGRESS_CSV, CHECKPOINT, BEST_TOML, RESULT_JSON = (
    "progress.csv",
    "checkpoint.json",
    "best.toml",
    "result.json",
)
DESIGN_PNG, CONVERGENCE_PNG = "design.png", "convergence.png"
MAX_HALVINGS = 6


@dataclasses.dataclass
class _Setup:
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
    finger = _pull_finger(problem, g.finger)
    e = np.asarray(problem.pull_direction, float)
    st = Stepper(finger, "planar", g.integrator, SolverOptions(), False)
    at = lambda t: with_objects_moved(finger, t * e)
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
    return _Setup(static, data, anchors, gs)


# --------------------------------------------------------------------------------------
# Steps: anchors, the peak pull, re-grasping after a failed warm start
# --------------------------------------------------------------------------------------


def _refine_pull(setup: _Setup, z, anchors: Anchors, step: float, max_iter: int = 6):
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


def _reanchor(problem: OptimizeProblem, setup: _Setup, x, anchors: Anchors, say):
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


def _evaluate(problem, setup: _Setup, z, anchors: Anchors, say):
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
            refined = _refine_pull(setup, z, anchors, problem.pull_step)
            ok = refined is not None
            anchors = refined if ok else anchors
        if ok:
            (loss, aux), grad = loss_and_grad(z, st, data, anchors)
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
    failed: bool = False  # stopped because an iteration could not be solved


def _load_checkpoint(problem: OptimizeProblem, out_dir: str):
    path = os.path.join(out_dir, CHECKPOINT)
    csv_path = os.path.join(out_dir, PROGRESS_CSV)
    if not os.path.exists(path):
        if _data_rows(csv_path) > 0:
            raise OptimizeError(
                f"{out_dir} holds a {PROGRESS_CSV} without a {CHECKPOINT}: cannot continue it; "
                "use another --out"
            )
        return None
    return fio.read_run_record(
        path,
        out_dir,
        OptimizeError,
        what="checkpoint",
        run="optimisation",
        digest=problem.digest,
        hash_key="hash",
        source_key="source",
    )


def _data_rows(csv_path: str) -> int:
    """Complete rows after the header of a progress file (0 when it is missing). A run
    stopped between writing the header and its first checkpoint left no row: it starts
    afresh."""
    if not os.path.exists(csv_path):
        return 0
    with open(csv_path, "rb") as fh:
        lines = [ln for ln in fh.read().splitlines(keepends=True) if ln.endswith(b"\n")]
    return max(len(lines) - 1, 0)


def _stall(problem: OptimizeProblem, rows) -> int:
    """Iterations in a row, up to the last, whose objective changed by at most
    `tolerance` (relative) from the one before while feasible: `patience` of them stop the
    run. rows: (objective, feasible) per iteration."""
    stall, last = 0, None
    for objective, feasible in rows:
        stall = stall + 1 if (feasible and _unchanged(problem, objective, last)) else 0
        last = objective
    return stall


def _unchanged(problem: OptimizeProblem, objective: float, last) -> bool:
    return last is not None and abs(objective - last) <= problem.tolerance * abs(objective)


def _progress_rows(csv_path: str, rows: int):
    """(objective, feasible) of the first `rows` rows of a progress file."""
    with open(csv_path, encoding="utf-8") as fh:
        lines = fh.read().splitlines()[1 : rows + 1]
    return [(float(c[1]), c[4] == "1") for c in (ln.split(",") for ln in lines)]


def _stop_reason(problem: OptimizeProblem, state: dict) -> str:
    """Why the run stops before its next iteration ("": it goes on), by the problem's
    own iterations, tolerance and patience (they may change between runs)."""
    if state["stall"] >= problem.patience:
        return (
            f"converged: objective changed by <= tolerance = {problem.tolerance} (relative) "
            f"for {problem.patience} iterations"
        )
    if state["rows"] >= problem.iterations:
        return f"reached iterations = {problem.iterations}"
    return ""


def _save_checkpoint(problem: OptimizeProblem, out_dir: str, state: dict) -> None:
    record = {
        "format": FORMAT,
        "hash": problem.digest,
        "source": os.path.abspath(problem.source),
        "state": state,
    }
    fio.write_atomic(os.path.join(out_dir, CHECKPOINT), json.dumps(record) + "\n")


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


def _anchors_json(a: Anchors) -> dict:
    return {
        k: np.asarray(getattr(a, k)).tolist() for k in ("unknowns", "stiffness", "closing", "pull")
    }


def _anchors_from(d: dict) -> Anchors:
    return Anchors(
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
        z = jnp.asarray(z_of(lo, hi, problem.x0), jnp.float64)
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
        fio.write_atomic(csv_path, header)
        _save_checkpoint(problem, out_dir, state)
    else:
        state = ck["state"]
        _truncate_rows(csv_path, header, state["rows"])
        if not state.get("failed", False):
            # iterations, tolerance and patience may have changed since: decide anew.
            state["stall"] = _stall(problem, _progress_rows(csv_path, state["rows"]))
            state["done"], state["reason"] = False, ""
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
    t0 = t_start - state["elapsed"]  # (every run's setup and compile count)
    while not state["done"]:
        k = state["rows"]
        reason = _stop_reason(problem, state)
        if reason:
            state["done"], state["reason"] = True, reason
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
            state["done"] = state["failed"] = True
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
            for i, text in enumerate(_best_tomls(problem, x, k, objective, anchors)):
                fio.write_atomic(_best_path(best_path, i), text)
        still = feasible and _unchanged(problem, objective, state["last"])
        state["stall"] = state["stall"] + 1 if still else 0
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
        _save_checkpoint(problem, out_dir, state)  # (the loop's head decides the stop)
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
    _save_checkpoint(problem, out_dir, state)
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
        failed=bool(state.get("failed", False)),
    )
    if state["done"]:
        _write_result(problem, run, out_dir, time.perf_counter() - t_start)
        if plot:
            figures = _plots(problem, setup, state, out_dir, say)
            run = dataclasses.replace(run, figures=figures)
    return run


def _best_path(best_path: str, i: int) -> str:
    """best.toml for the first object, best_object<i>.toml for object i of several."""
    stem, ext = os.path.splitext(best_path)
    return best_path if i == 0 else f"{stem}_object{i}{ext}"


def _best_tomls(problem: OptimizeProblem, x, iteration: int, objective: float, anchors):
    """The best design as finger files, one per object: each holds that object (placed as
    the optimiser placed it) and, for the holding force, the release's friction."""
    k = ", ".join(f"{float(v)!r}" for v in np.asarray(anchors.stiffness)[:, 0])
    k_s = ", ".join(f"{float(v)!r}" for v in np.asarray(anchors.stiffness)[:, 1])
    n_obj = 1 if problem.diameters is None else len(problem.diameters)
    designed = problem.designed(x)
    if problem.objective == "holding_force":
        designed = with_contact(designed, friction=problem.friction)
    w = problem.direction
    grasp_lines = [
        "",
        "[grasp]",
        f"closing = {problem.closing!r}",
        f"direction = [{float(w[0])!r}, {float(w[1])!r}]",
        f"symmetric = {'true' if problem.symmetric else 'false'}",
        f"pull_step = {problem.pull_step!r}",
    ]
    texts = []
    for i, base in enumerate(problem.object_fingers()):
        finger = eqx.tree_at(lambda f: (f.loads, f.objects), designed, (base.loads, base.objects))
        which = "" if problem.diameters is None else f" (object {i}: {problem.diameters[i]:g} mm)"
        others = [_best_path(BEST_TOML, j) for j in range(n_obj) if j != i]
        head = [
            f"# Best feasible design of {os.path.basename(problem.source)} (finray optimize), "
            f"iteration {iteration}{which}:",
            f"# {problem.objective} = {objective!r} N "
            f"({problem.aggregate} over {n_obj} object(s)).",
            "# " + ", ".join(f"{n} = {v!r}" for n, v in zip(problem.names, np.asarray(x).tolist())),
            f"# That figure holds the contact penalty stiffness of the initial design fixed (k = "
            f"{k} N/mm^2, per object;",
            f"# the support's {k_s} N/mm^2); `finray grasp` chooses them for this design anew, "
            "so its force can",
            "# differ slightly ([contact] stiffness = k and support_stiffness reproduce the "
            "figure).",
        ]
        if others:
            head.append(f"# The other objects' files: {', '.join(others)}.")
        text = fio.finger_to_toml(finger, problem.settings)
        texts.append("\n".join(head) + "\n" + text + "\n".join(grasp_lines) + "\n")
    return texts


def _write_result(problem: OptimizeProblem, run: OptimizeRun, out_dir: str, wall: float):
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
    fio.write_atomic(os.path.join(out_dir, RESULT_JSON), json.dumps(payload, indent=2) + "\n")


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
        f = with_stiffness(f, *setup.anchors.stiffness[i])
        out.append(grasp(f, problem.closing, direction=problem.direction, stiffen=False))
    return out


def _plots(problem: OptimizeProblem, setup: _Setup, state: dict, out_dir: str, say) -> tuple:
    from matplotlib.figure import Figure

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
