"""The figures of an optimisation run: convergence.png (the objective per iteration)
and design.png (the grasps of the initial and of the best design, side by side)."""

from __future__ import annotations

import os

import numpy as np

from ._grasp import grasp
from ._grasp_inputs import with_stiffness
from ._optimize_eval import Setup
from ._optimize_problem import OptimizeProblem
from ._optimize_record import PROGRESS_CSV, read_progress
from .design import set_design as _set_design
from .plot import plot_grasp, save_figure

DESIGN_PNG, CONVERGENCE_PNG = "design.png", "convergence.png"


def _final_grasps(problem: OptimizeProblem, setup: Setup, x):
    """Grasps of every object at design x with the run's penalty stiffness."""
    out = []
    for i, base in enumerate(problem.object_fingers()):
        f = _set_design(base, dict(zip(problem.names, np.asarray(x, float).tolist())))
        f = with_stiffness(f, *setup.anchors.stiffness[i])
        out.append(grasp(f, problem.closing, direction=problem.direction, stiffen=False))
    return out


def plot_run(problem: OptimizeProblem, setup: Setup, state: dict, out_dir: str, say) -> tuple:
    """convergence.png (the objective per iteration) and, when a feasible design was
    found, design.png (the grasps of the initial and the best design); their paths."""
    from matplotlib.figure import Figure

    data = read_progress(os.path.join(out_dir, PROGRESS_CSV))
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.add_subplot()
    it = data["iteration"]
    feas = data["feasible"] > 0
    objective = problem.objective.replace("_", " ")
    ax.plot(it, data["objective"], "-o", ms=3, color="tab:blue", label=f"{objective} of the design")
    ax.plot(
        it[~feas],
        data["objective"][~feas],
        "x",
        ms=8,
        color="tab:red",
        label="infeasible (a constraint violated)",
    )
    if state["best"] is not None:
        b = state["best"]
        ax.plot(
            [b["iteration"]],
            [b["objective"]],
            "*",
            ms=12,
            color="tab:green",
            label="best feasible design",
        )
    ax.set_xlabel("iteration of the optimiser")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_ylabel(f"{objective}, {problem.aggregate} over the objects (N)")
    ax.set_title(
        f"optimisation: {objective} ({problem.aggregate}) per iteration", fontsize="medium"
    )
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
            plot_grasp(g, axs[i, j], title=f"{what} design, object {i}")
    design = os.path.join(out_dir, DESIGN_PNG)
    save_figure(fig, design)
    return (design, conv)
