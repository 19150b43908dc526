"""What the `finray` command line's modules share: exit codes, the user-error type, the
default finger, and the text formatting of numbers, tables and progress lines."""

import math
import os
import sys

from .engines import engine_named, require_ray

EXIT_OK, EXIT_USER, EXIT_BEYOND, EXIT_FAILED = 0, 1, 2, 3
EXIT_INTERRUPTED = 130  # (128 + SIGINT, as a shell reports it)
STATUS_EXIT = {
    "converged": EXIT_OK,
    "beyond_limit_load": EXIT_BEYOND,
    "unstable": EXIT_FAILED,
    "failed": EXIT_FAILED,
}

# The default finger of `finray demo`, `compare` and `clamp-study`: Finger-1, shipped as
# package data (finray_jax/data/finger1.toml, the same file as examples/finger1.toml).
DEMO_FINGER = "finger1.toml"


class UserError(Exception):
    """A mistake in the command line or its inputs: reported in one line, exit code 1."""


def num(x, digits=4) -> str:
    """A number to `digits` significant digits ("nan" where it is not finite)."""
    x = float(x)
    if not math.isfinite(x):
        return "nan"
    return f"{x:.{digits}g}"


def percent(x) -> str:
    """A change in percent; "n/a" where a force it compares is unknown (NaN)."""
    return f"{x:+.0f} %" if math.isfinite(x) else "n/a"


def count(n: int, noun: str) -> str:
    """`n` and the noun, plural unless n is 1."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


def table(head, rows) -> list[str]:
    """Aligned text rows, indented by two spaces: the first column left-aligned, the
    others right-aligned."""
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    fmt = lambda r: (
        "  "
        + "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w)
            for i, (c, w) in enumerate(zip(r, widths, strict=True))
        )
    )
    return [fmt(head)] + [fmt(r) for r in rows]


class _Voice:
    """Whether progress lines are shown (`--quiet` silences them) and which programs
    this process has compiled (XLA compiles each once per process; the persistent
    compilation cache serves later runs)."""

    quiet = False
    compiled: set[str] = set()


def set_quiet(quiet: bool) -> None:
    _Voice.quiet = bool(quiet)


def progress_stream():
    """The stream progress goes to: stderr, or None under --quiet."""
    return None if _Voice.quiet else sys.stderr


def progress(msg):
    """A progress line on stderr (stdout keeps the results), unless --quiet."""
    if not _Voice.quiet:
        print(f"  ... {msg}", file=sys.stderr, flush=True)


# How long the first compile of each program takes on one core of the 2-core reference
# machine (benchmarks/README.md); the persistent cache cuts a later run's to about a tenth.
COMPILE_TIMES = {
    "planar solver": "about 7 s",
    "3-D solver": "about 10 s",
    "limit-load search": "about 8 s",
    "contact solver": "about 20-30 s",
    "batch solver": "about 10-20 s",
    "objective and its gradient": "about 60-80 s",
}


def compiling(program: str, what: str = "for this finger") -> None:
    """Say, before its first compile in this process, that `program` is compiling."""
    if program in _Voice.compiled:
        return
    _Voice.compiled.add(program)
    progress(
        f"compiling the {program} {what}, {COMPILE_TIMES[program]} the first time; "
        "cached afterwards"
    )


def solver_name(mode: str) -> str:
    """The compiled program's name for a solve mode ("planar", "spatial")."""
    return "3-D solver" if mode == "spatial" else "planar solver"


def shown_path(path) -> str:
    """A path relative to the working directory when it lies below it."""
    rel = os.path.relpath(path)
    return path if rel.startswith("..") else rel


def finished_rows(csv_path: str) -> int:
    """Rows after the header of a results CSV (0 when there is none)."""
    try:
        with open(csv_path, encoding="utf-8") as fh:
            return max(sum(1 for line in fh if line.strip()) - 1, 0)
    except OSError:
        return 0


def say_interrupted(path: str, what: str, *, counted: bool = True) -> None:
    """The interrupt's one line: what the command kept in `path`, a results CSV (counted:
    how many rows) or a study's record (named when it exists); or that nothing had
    finished, so that a re-run starts afresh."""
    kept = finished_rows(path) if counted else os.path.exists(path)
    if kept:
        count = f"{kept} " if counted else ""
        text = f"{count}finished {what} are in {path}: run the same command to continue"
    else:
        text = f"no {what} had finished (nothing written yet): the same command starts afresh"
    print(f"finray: interrupted; {text}", file=sys.stderr)


def engine_from_args(args):
    """The engine the --engine options name (an EngineError names a bad setting)."""
    ray_only = ("address", "workers", "task_cpus", "task_gpus", "cache_dir")
    given = [f"--{k.replace('_', '-')}" for k in ray_only if getattr(args, k) is not None]
    if args.engine == "local" and given:
        raise UserError(f"{', '.join(given)}: options of --engine ray (the engine is local)")
    if args.engine == "ray":
        require_ray()
    return engine_named(
        args.engine,
        address=args.address,
        workers=args.workers,
        task_cpus=args.task_cpus,
        task_gpus=args.task_gpus,
        cache_dir=args.cache_dir,
    )


def engine_notice(engine, program: str) -> None:
    """Where the work runs, on stderr (a cluster's workers compile `program` each)."""
    if engine.name != "local":
        progress(f"running on {engine.describe()}; each worker compiles the {program} once")
