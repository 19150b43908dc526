"""The files of an optimisation run: the progress log (progress.csv, one row per
iteration), the checkpoint (checkpoint.json: the optimiser's state after the last row,
from which a re-run continues), when the run stops, and the best design as finger files
(best.toml, one per object)."""

from __future__ import annotations

import dataclasses
import json
import math
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from . import io as fio
from ._grasp_inputs import with_contact
from ._objective import Anchors
from ._optimize_problem import OptimizeProblem
from .optimize_file import FORMAT, OptimizeError

PROGRESS_CSV, CHECKPOINT, BEST_TOML, RESULT_JSON = (
    "progress.csv",
    "checkpoint.json",
    "best.toml",
    "result.json",
)


def columns(problem: OptimizeProblem, constraints, n_obj) -> tuple[str, ...]:
    """The progress file's columns, for these constraints and n_obj objects."""
    cols = ["iteration", "objective", "loss", "penalty", "feasible", "halvings"]
    cols += list(problem.names)
    cols += [f"margin.{c}" for c in constraints]
    cols += [f"value[{i}]" for i in range(n_obj)]
    if problem.objective == "holding_force":
        cols += [f"pull[{i}]" for i in range(n_obj)]
    return tuple(cols + ["wall_time"])


def progress_cells(
    problem: OptimizeProblem,
    k: int,
    objective: float,
    loss,
    aux: dict,
    feasible: bool,
    halvings: int,
    x,
    margins: dict,
    anchors: Anchors,
    elapsed: float,
) -> list[str]:
    """The progress row of iteration k as text cells, in the order of `columns` (margins:
    constraint -> margin, in the order of the run's constraints)."""
    cells = [
        str(k),
        _fmt(objective),
        _fmt(loss),
        _fmt(aux["penalty"]),
        str(int(feasible)),
        str(halvings),
    ]
    cells += [_fmt(v) for v in x] + [_fmt(m) for m in margins.values()]
    cells += [_fmt(v) for v in np.asarray(aux["values"])]
    if problem.objective == "holding_force":
        cells += [_fmt(v) for v in np.asarray(anchors.pull)]
    cells.append(_fmt(elapsed))
    return cells


def append_row(csv_path: str, cells) -> None:
    """Append one row to the progress file, flushed and fsync'ed."""
    with open(csv_path, "a", encoding="utf-8") as fh:
        fh.write(",".join(cells) + "\n")
        fh.flush()
        os.fsync(fh.fileno())


def _fmt(x) -> str:
    x = float(x)
    return repr(x) if math.isfinite(x) else "nan"


def load_checkpoint(problem: OptimizeProblem, out_dir: str):
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


def stall(problem: OptimizeProblem, rows) -> int:
    """Iterations in a row, up to the last, whose objective changed by at most
    `tolerance` (relative) from the one before while feasible: `patience` of them stop the
    run. rows: (objective, feasible) per iteration."""
    count, last = 0, None
    for objective, feasible in rows:
        count = count + 1 if (feasible and unchanged(problem, objective, last)) else 0
        last = objective
    return count


def unchanged(problem: OptimizeProblem, objective: float, last) -> bool:
    return last is not None and abs(objective - last) <= problem.tolerance * abs(objective)


def progress_rows(csv_path: str, rows: int):
    """(objective, feasible) of the first `rows` rows of a progress file."""
    with open(csv_path, encoding="utf-8") as fh:
        lines = fh.read().splitlines()[1 : rows + 1]
    return [(float(c[1]), c[4] == "1") for c in (ln.split(",") for ln in lines)]


def stop_reason(problem: OptimizeProblem, state: dict) -> str:
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


def save_checkpoint(problem: OptimizeProblem, out_dir: str, state: dict) -> None:
    record = {
        "format": FORMAT,
        "hash": problem.digest,
        "source": os.path.abspath(problem.source),
        "state": state,
    }
    fio.write_atomic(os.path.join(out_dir, CHECKPOINT), json.dumps(record) + "\n")


def truncate_rows(csv_path: str, header: str, rows: int) -> None:
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


def anchors_json(a: Anchors) -> dict:
    return {
        k: np.asarray(getattr(a, k)).tolist() for k in ("unknowns", "stiffness", "closing", "pull")
    }


def anchors_from(d: dict) -> Anchors:
    return Anchors(
        **{k: jnp.asarray(d[k], jnp.float64) for k in ("unknowns", "stiffness", "closing", "pull")}
    )


def best_path(path: str, i: int) -> str:
    """best.toml for the first object, best_object<i>.toml for object i of several."""
    stem, ext = os.path.splitext(path)
    return path if i == 0 else f"{stem}_object{i}{ext}"


def best_tomls(problem: OptimizeProblem, x, iteration: int, objective: float, anchors):
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
        others = [best_path(BEST_TOML, j) for j in range(n_obj) if j != i]
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
        # (the [grasp] table is this problem's, below: the settings' own is left out)
        text = fio.finger_to_toml(finger, dataclasses.replace(problem.settings, grasp=None))
        texts.append("\n".join(head) + "\n" + text + "\n".join(grasp_lines) + "\n")
    return texts


def read_progress(csv_path) -> dict[str, np.ndarray]:
    """The progress CSV as float columns."""
    with open(csv_path, encoding="utf-8") as fh:
        head = fh.readline().rstrip("\n").split(",")
        rows = [line.rstrip("\n").split(",") for line in fh if line.endswith("\n")]
    cols = list(zip(*rows)) if rows else [()] * len(head)
    return {name: np.asarray(col, dtype=np.float64) for name, col in zip(head, cols)}
