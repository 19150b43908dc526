"""The `finray` commands that run a study file into an output directory, resumably:
`sweep` (many designs, solved in batches) and `optimize` (a design improved by
gradients). Re-running the same command into the same directory continues."""

import collections
import os
import sys

from . import optimizer as fopt
from . import sweep as fsweep
from ._cli_common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    UserError,
    compiling,
    engine_from_args,
    engine_notice,
    finished_rows,
    num,
    progress_stream,
    say_interrupted,
)


def _no_design_converged(run) -> str:
    """The stderr line of a finished sweep in which no design converged: the counts and
    the most frequent reason (the CSV's reason column)."""
    counts = ", ".join(f"{n} {status}" for status, n in sorted(run.counts.items()))
    text = (
        f"no design of the sweep converged ({counts or 'no rows'}); see the reason column "
        f"of {run.csv}"
    )
    reasons = [str(r) for r in fsweep.read_results(run.csv).get("reason", ()) if r]
    if reasons:  # (ties: the reason of the earliest row)
        top, n = collections.Counter(reasons).most_common(1)[0]
        text += f"; most frequent ({n} of {run.done}): {top}"
    return text


def sweep_command(args) -> int:
    """`finray sweep`: solve a sweep file's designs chunk by chunk into DIR."""
    if args.max_chunks is not None and args.max_chunks < 1:
        raise UserError(f"--max-chunks must be a positive integer, got {args.max_chunks}")
    sw = fsweep.load_sweep(args.sweep)
    engine = engine_from_args(args)
    print(
        f"sweep {args.sweep}: {sw.size} designs ({sw.sampling}) of {sw.finger_path}, "
        f"values {', '.join(sw.names)}; outputs {', '.join(sw.outputs)}; mode {sw.mode}"
    )
    csv_path = os.path.join(args.out, fsweep.RESULTS_CSV)
    program = "contact solver" if sw.settings.grasp is not None else "batch solver"
    if finished_rows(csv_path) < sw.size:
        engine_notice(engine, program)
        if engine.name == "local":
            compiling(program, "for this sweep's finger")
    try:
        run = fsweep.run_sweep(
            sw,
            args.out,
            engine=engine,
            max_chunks=args.max_chunks,
            progress=progress_stream(),
            parquet=args.parquet,
        )
    except KeyboardInterrupt:
        print(file=sys.stderr)  # (ends the progress bar's line)
        say_interrupted(csv_path, "designs")
        return EXIT_INTERRUPTED
    counts = ", ".join(f"{n} {status}" for status, n in sorted(run.counts.items()))
    print(f"wrote {run.csv} ({run.done} of {run.total} designs: {counts or 'none yet'})")
    for path in (run.figure, run.parquet):
        if path:
            print(f"wrote {path}")
    _print_workers(run)
    for chunk in run.failed_chunks:
        print(f"finray: {chunk.describe()}", file=sys.stderr)
    if not run.finished:
        print("not finished: run the same command to continue")
    if run.failed_chunks:
        return EXIT_FAILED
    if run.finished and run.converged == 0:
        print(f"finray: {_no_design_converged(run)}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _print_workers(run) -> None:
    """Each worker's chunks and seconds, when more than one process solved them."""
    if len(run.workers) < 2:
        return
    for name, t in sorted(run.workers.items()):
        print(
            f"  worker {name}: {t.chunks} chunks in {t.seconds:.1f} s (first chunk, with its "
            f"compile: {t.first_seconds:.1f} s)"
        )


def _print_best(pr, run) -> None:
    """The best feasible design so far: its objective, the gain on the initial design, its
    values and constraint margins."""
    b = run.best
    gain = 100.0 * (b["objective"] / run.initial_objective - 1.0)
    print(
        f"best (iteration {b['iteration']}): {pr.objective} {num(b['objective'], 6)} N "
        f"({gain:+.1f} % on the initial {num(run.initial_objective, 6)} N)"
    )
    for name, v in b["design"].items():
        print(f"  {name} = {num(v, 6)}")
    for name, m in b["margins"].items():
        print(f"  margin {name}: {num(m, 4)}")
    print(f"wrote {run.best_toml}")


def optimize_command(args) -> int:
    """`finray optimize`: improve an optimisation file's design values into DIR."""
    if args.max_iterations is not None and args.max_iterations < 1:
        raise UserError(f"--max-iterations must be a positive integer, got {args.max_iterations}")
    pr = fopt.load_optimize(args.optimize)
    cons = ", ".join(f"{k} = {v:g}" for k, v in pr.constraints.items()) or "none"
    objects = (
        "its object"
        if pr.diameters is None
        else (f"cylinders of {', '.join(f'{d:g}' for d in pr.diameters)} mm ({pr.aggregate})")
    )
    print(
        f"optimize {args.optimize}: maximise {pr.objective} of {pr.finger_path} on {objects} "
        f"at closing {pr.closing:g} mm over {', '.join(pr.names)}; constraints: {cons}; "
        f"{pr.optimizer}, learning rate {pr.learning_rate:g}, {pr.iterations} iterations"
    )
    try:
        compiling("objective and its gradient", "for this problem")
        run = fopt.run_optimize(
            pr, args.out, max_iterations=args.max_iterations, progress=progress_stream()
        )
    except KeyboardInterrupt:
        say_interrupted(os.path.join(args.out, fopt.PROGRESS_CSV), "iterations")
        return EXIT_INTERRUPTED
    print(f"{run.reason}; {run.rows} iterations in {run.csv}")
    if run.best is None:
        print("no feasible design yet")
    else:
        _print_best(pr, run)
    for path in run.figures:
        print(f"wrote {path}")
    if not run.finished:
        print("not finished: run the same command to continue")
    return EXIT_FAILED if run.failed else EXIT_OK
