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

This module runs the loop; the file is read by `optimize_file`, the objective evaluated
by `_optimize_eval`, the run's files kept by `_optimize_record` and its figures drawn by
`_optimize_plot`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import io as fio
from ._objective import CONSTRAINTS, OBJECTIVES, z_of
from ._optimize_eval import MAX_HALVINGS as MAX_HALVINGS
from ._optimize_eval import Setup, evaluate, initial_setup, reanchor, refine_pull
from ._optimize_plot import CONVERGENCE_PNG as CONVERGENCE_PNG
from ._optimize_plot import DESIGN_PNG as DESIGN_PNG
from ._optimize_plot import plot_run
from ._optimize_record import (
    BEST_TOML,
    PROGRESS_CSV,
    RESULT_JSON,
    anchors_from,
    anchors_json,
    append_row,
    best_path,
    best_tomls,
    columns,
    load_checkpoint,
    progress_cells,
    progress_rows,
    save_checkpoint,
    stall,
    stop_reason,
    truncate_rows,
    unchanged,
)
from ._optimize_record import CHECKPOINT as CHECKPOINT
from ._optimize_record import read_progress as read_progress
from ._version import __version__
from .optimize_file import FORMAT as FORMAT
from .optimize_file import (
    OptimizeError,
    OptimizeProblem,
    load_optimize,
    loads_optimize,
)

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

# The run's parts under the names that tests/test_optimizer.py and benchmarks/optimizer.py
# read from this module.
_setup, _refine_pull, _reanchor = initial_setup, refine_pull, reanchor
_load_checkpoint, _truncate_rows, _stall, _stop_reason = (
    load_checkpoint,
    truncate_rows,
    stall,
    stop_reason,
)
_best_path, _best_tomls = best_path, best_tomls


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
    ck = load_checkpoint(problem, out_dir)
    t_start = time.perf_counter()
    setup = initial_setup(problem, say)
    n_obj = int(setup.anchors.stiffness.shape[0])
    cons = setup.static.constraints
    header = ",".join(columns(problem, cons, n_obj)) + "\n"
    csv_path = os.path.join(out_dir, PROGRESS_CSV)
    best_toml = os.path.join(out_dir, BEST_TOML)
    opt = _optimizer(problem)
    if ck is None:
        state = _fresh_state(problem, setup, out_dir, csv_path, header, say)
    else:
        state = _resumed_state(problem, ck, csv_path, header)
    setup.data = eqx.tree_at(
        lambda d: d.objective_scale, setup.data, jnp.asarray(state["scale"], jnp.float64)
    )
    z = jnp.asarray(state["z"], jnp.float64)
    anchors = anchors_from(state["anchors"])
    opt_state = _restored_opt_state(opt, z, state["opt_state"])
    step = jnp.asarray(state.get("step", np.zeros(len(problem.lo)).tolist()), jnp.float64)
    z_prev = jnp.asarray(state.get("z_prev", state["z"]), jnp.float64)
    new_rows = 0
    t0 = t_start - state["elapsed"]  # (every run's setup and compile count)
    while not state["done"]:
        k = state["rows"]
        reason = stop_reason(problem, state)
        if reason:
            state["done"], state["reason"] = True, reason
            break
        if max_iterations is not None and new_rows >= max_iterations:
            break
        result, halvings, z_try = _step(problem, setup, z, z_prev, step, anchors, k, say)
        if result is None:
            state["done"] = state["failed"] = True
            state["reason"] = (
                f"iteration {k}: no step (halved {MAX_HALVINGS} times) could be solved"
            )
            break
        loss, aux, grad, anchors = result
        z = z_try
        objective, feasible, x, margins = _measured(aux, cons)
        elapsed = time.perf_counter() - t0
        cells = progress_cells(
            problem, k, objective, loss, aux, feasible, halvings, x, margins, anchors, elapsed
        )
        _keep_best(problem, state, k, objective, feasible, x, aux, margins, anchors, best_toml)
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 counts and floats
            updates, opt_state = opt.update(grad, opt_state, z)
        step = jnp.asarray(updates)
        z_prev = z
        append_row(csv_path, cells)
        _advance(state, k, z, z_prev, step, anchors, opt_state, elapsed)
        save_checkpoint(problem, out_dir, state)  # (the loop's head decides the stop)
        new_rows += 1
        if progress is not None:
            _report(problem, k, objective, aux, feasible, halvings, x, margins, progress)
        if after_iteration is not None:
            after_iteration(k + 1)
    save_checkpoint(problem, out_dir, state)
    return _finish(problem, setup, state, out_dir, csv_path, best_toml, plot, say, t_start)


def _optimizer(problem: OptimizeProblem):
    import optax

    if problem.optimizer == "adam":
        return optax.adam(problem.learning_rate)
    return optax.sgd(problem.learning_rate)


def _fresh_state(problem: OptimizeProblem, setup: Setup, out_dir, csv_path, header, say):
    """The state of a new run: the initial design, evaluated once for the objective's
    scale (it must be touched); the progress file's header and the first checkpoint are
    written."""
    z = jnp.asarray(z_of(problem.lo, problem.hi, problem.x0), jnp.float64)
    anchors = setup.anchors
    probe = evaluate(problem, setup, z, anchors, say)
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
        "anchors": anchors_json(anchors),
        "opt_state": None,
        "done": False,
        "reason": "",
    }
    fio.write_atomic(csv_path, header)
    save_checkpoint(problem, out_dir, state)
    return state


def _resumed_state(problem: OptimizeProblem, ck: dict, csv_path, header):
    """The checkpoint's state, its progress file cut to the checkpoint's rows."""
    state = ck["state"]
    truncate_rows(csv_path, header, state["rows"])
    if not state.get("failed", False):
        # iterations, tolerance and patience may have changed since: decide anew.
        state["stall"] = stall(problem, progress_rows(csv_path, state["rows"]))
        state["done"], state["reason"] = False, ""
    return state


def _restored_opt_state(opt, z, leaves):
    """The optimiser's state at z: fresh, or with the checkpoint's leaves (None: none)."""
    with jax.numpy_dtype_promotion("standard"):
        opt_state = opt.init(z)
    if leaves is not None:
        fresh, tree = jax.tree_util.tree_flatten(opt_state)
        opt_state = jax.tree_util.tree_unflatten(
            tree, [jnp.asarray(v, dtype=l.dtype) for v, l in zip(leaves, fresh)]
        )
    return opt_state


def _step(problem: OptimizeProblem, setup: Setup, z, z_prev, step, anchors, k: int, say):
    """Evaluate iteration k's design: the optimiser's step from z_prev, halved until it
    can be solved (the first iteration evaluates z). (result of `evaluate` or None, the
    halvings, the design tried last)."""
    result, halvings = None, 0
    for halvings in range(MAX_HALVINGS + 1):
        z_try = z_prev + step * 0.5**halvings if k > 0 else z
        result = evaluate(problem, setup, z_try, anchors, say)
        if result is not None:
            break
    return result, halvings, z_try


def _measured(aux: dict, cons) -> tuple[float, bool, np.ndarray, dict]:
    """(objective, feasible, design values, constraint -> margin) of an evaluation: feasible
    when every margin of the run's constraints `cons` is >= 0."""
    margins = {c: float(aux["margins"][c]) for c in cons}
    feasible = all(m >= 0 for m in margins.values())
    return float(aux["objective"]), feasible, np.asarray(aux["x"]), margins


def _advance(state: dict, k: int, z, z_prev, step, anchors, opt_state, elapsed) -> None:
    """The state after iteration k's row (what the checkpoint keeps to continue from)."""
    state.update(
        rows=k + 1,
        z=np.asarray(z).tolist(),
        z_prev=np.asarray(z_prev).tolist(),
        step=np.asarray(step).tolist(),
        anchors=anchors_json(anchors),
        opt_state=[np.asarray(v).tolist() for v in jax.tree_util.tree_leaves(opt_state)],
        elapsed=elapsed,
    )


def _keep_best(problem, state, k, objective, feasible, x, aux, margins, anchors, best_toml):
    """Record iteration k in the state: the best feasible design so far (and its finger
    files, rewritten when it improves), and the count of iterations that stalled."""
    if feasible and (state["best"] is None or objective > state["best"]["objective"]):
        state["best"] = {
            "iteration": k,
            "objective": objective,
            "design": dict(zip(problem.names, x.tolist())),
            "values": np.asarray(aux["values"]).tolist(),
            "margins": margins,
        }
        for i, text in enumerate(best_tomls(problem, x, k, objective, anchors)):
            fio.write_atomic(best_path(best_toml, i), text)
    still = feasible and unchanged(problem, objective, state["last"])
    state["stall"] = state["stall"] + 1 if still else 0
    state["last"] = objective


def _report(problem, k, objective, aux, feasible, halvings, x, margins, progress) -> None:
    """One line about iteration k on the progress stream."""
    m = ", ".join(f"{c} {v:.3g}" for c, v in margins.items())
    print(
        f"iteration {k}: {problem.objective} {objective:.6g} (penalty "
        f"{float(aux['penalty']):.3g}{', infeasible' if not feasible else ''}"
        f"{', halved x' + str(halvings) if halvings else ''}); "
        + ", ".join(f"{n} = {v:.5g}" for n, v in zip(problem.names, x))
        + (f"; margins: {m}" if m else ""),
        file=progress,
        flush=True,
    )


def _finish(problem, setup, state, out_dir, csv_path, best_toml, plot, say, t_start):
    """What the run did; when it is done, result.json and (plot) the figures too."""
    figures = ()
    run = OptimizeRun(
        rows=state["rows"],
        finished=bool(state["done"]),
        reason=state["reason"] or "stopped (max_iterations): run again to continue",
        initial_objective=float(state["scale"]),
        best=state["best"],
        csv=csv_path,
        best_toml=best_toml if state["best"] is not None else None,
        figures=figures,
        failed=bool(state.get("failed", False)),
    )
    if state["done"]:
        _write_result(problem, run, out_dir, time.perf_counter() - t_start)
        if plot:
            figures = plot_run(problem, setup, state, out_dir, say)
            run = dataclasses.replace(run, figures=figures)
    return run


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
