"""The `finray` command line: solve, limit, validate, demo, sweep and optimize. See docs/cli.md.

Exit codes: 0 converged (or limit found, or file valid), 1 user error (bad or missing
file, bad option), 2 the load lies beyond the finger's limit load, 3 the solve failed (a
sweep: it finished and no design converged), 130 interrupted.
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import sys
import time
import warnings

import numpy as np

import finray_jax as fr

from . import io as fio
from . import optimize_file, studies
from . import optimizer as fopt
from . import sweep as fsweep
from ._cache import enable_compilation_cache
from ._finger import loads_are_zero
from ._grasp import check_objects, unit_direction
from .design import DesignError
from .plot import clamp_study_figure, grasp_figure, save_figure, save_solution_figure
from .studies import StudyRecordError

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


def _say_interrupted(csv_path: str, what: str) -> None:
    """The interrupt's one line: how many finished rows the CSV keeps (none: nothing to
    continue from, a re-run starts afresh)."""
    try:
        with open(csv_path, encoding="utf-8") as fh:
            rows = max(sum(1 for line in fh if line.strip()) - 1, 0)
    except OSError:
        rows = 0
    if rows:
        kept = f"{rows} finished {what} are in {csv_path}: run the same command to continue"
    else:
        kept = f"no {what} had finished (nothing written yet): the same command starts afresh"
    print(f"finray: interrupted; {kept}", file=sys.stderr)


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UserError(f"{message} (see {self.prog} --help)")

    def parse_args(self, args=None, namespace=None):
        # argparse reports a command's unknown option from the top parser ("see finray
        # --help"); the command's own parser names the help that lists its options.
        argv = sys.argv[1:] if args is None else list(args)
        parsed, extra = self.parse_known_args(argv, namespace)
        if extra:
            name = getattr(parsed, "command", None)
            at = argv.index(name) if name in argv else len(argv)
            command = self._commands[name] if extra[0] in argv[at + 1 :] else self
            command.error(f"unrecognized arguments: {' '.join(extra)}")
        return parsed


# --------------------------------------------------------------------------------------
# Set-up
# --------------------------------------------------------------------------------------


# Commands that solve many designs at once (vmapped on an accelerator); the others solve
# one finger, or one grasp, at a time.
_BATCH_COMMANDS = frozenset({"sweep"})
DEVICE_CHOICES = ("auto", "cpu", "default")


def choose_device(command: str) -> str:
    """Where a command runs, from $FINRAY_DEVICE: "default" (jax's default device), "cpu",
    or "auto" (unset): a sweep on jax's default device, every other command on the CPU.

    A single planar solve is a chain of small kernels, which a GPU runs slower than a
    CPU core (ref-A L1 on an H100: 11.3 ms against 5.8 ms on one of that machine's CPU
    cores; 3-D: 16.7 against 23.9 ms; benchmarks/README.md, session 18), while a sweep's
    vmapped chunks run there 60x faster. Returns the platform chosen ("cpu" or jax's
    default backend)."""
    import jax

    want = os.environ.get("FINRAY_DEVICE", "auto").strip().lower() or "auto"
    if want not in DEVICE_CHOICES:
        raise UserError(f"FINRAY_DEVICE = {want!r}: expected one of {', '.join(DEVICE_CHOICES)}")
    if want == "default" or (want == "auto" and command in _BATCH_COMMANDS):
        return jax.default_backend()
    if jax.default_backend() != "cpu":
        jax.config.update("jax_default_device", jax.devices("cpu")[0])
    return "cpu"


def _finite_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return x


def _nonnegative_float(text: str) -> float:
    x = _finite_float(text)
    if x < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return x


def _positive_float(text: str) -> float:
    x = _finite_float(text)
    if not x > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return x


def _figure_path(text: str) -> str:
    """A figure file name whose extension matplotlib can write (checked before solving)."""
    from matplotlib.backend_bases import FigureCanvasBase

    kinds = FigureCanvasBase.get_supported_filetypes()
    ext = os.path.splitext(text)[1].lower().lstrip(".")
    if ext not in kinds:
        raise argparse.ArgumentTypeError(
            f"{text!r}: unknown figure format {ext!r}; use one of {', '.join(sorted(kinds))}"
        )
    return text


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="finray",
        description="Cosserat-rod simulator of fin-ray-effect gripper fingers (units: mm, N, "
        "MPa). Finger files are TOML: see docs/finger-format.md.",
    )
    p.add_argument("--version", action="version", version=f"finray_jax {fr.__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p._commands = sub.choices

    s = sub.add_parser(
        "solve",
        help="solve a finger file for its equilibrium",
        description="Solve a finger file. Exit code 0 converged, 2 beyond the "
        "limit load, 3 failed, 1 user error.",
    )
    s.add_argument("finger", metavar="FINGER.toml")
    s.add_argument("--out", metavar="RESULT.json", help="write the solution as JSON")
    s.add_argument(
        "--plot",
        type=_figure_path,
        metavar="SHAPE.png",
        help="save a figure (shape and n(s), m(s))",
    )
    s.add_argument(
        "--load-scale",
        type=_finite_float,
        default=None,
        metavar="X",
        help="multiply every load by X",
    )
    s.add_argument(
        "--mode",
        choices=fio.MODES,
        default=None,
        help="override [solver] mode (default: the file's, else auto)",
    )
    _add_check_resolution(s, "the tip displacement")

    lim = sub.add_parser(
        "limit",
        help="find the limit (fold) load factor",
        description="Trace the loading branch to its fold: the largest factor "
        "on the file's loads with an equilibrium. Exit 0 found, 3 not found.",
    )
    lim.add_argument("finger", metavar="FINGER.toml")
    lim.add_argument("--out", metavar="LIMIT.json", help="write the result as JSON")
    lim.add_argument(
        "--plot", type=_figure_path, metavar="SHAPE.png", help="save a figure of the limit state"
    )
    lim.add_argument("--mode", choices=fio.MODES, default=None)

    v = sub.add_parser(
        "validate",
        help="check a finger, sweep or optimisation file",
        description="Check a finger file, or a sweep or optimisation file with its base "
        "finger; print OK or the error (exit 1).",
    )
    v.add_argument("finger", metavar="FILE.toml")

    d = sub.add_parser(
        "demo",
        help="solve the default finger under the paper's Fig. 3 load",
        description="Solve Finger-1 (examples/finger1.toml) under 4 N in +x "
        "spread over l5..l7 (DIR/demo.png, DIR/demo.json), then grasp an 18 mm cylinder "
        "with the original and the modified adaptor (DIR/demo_grasp.png).",
    )
    d.add_argument(
        "--out",
        metavar="DIR",
        default=".",
        help="output directory (default: the current directory)",
    )

    gr = sub.add_parser(
        "grasp",
        help="close a finger file's finger on its objects ([[objects]], [grasp])",
        description="Solve the grasp of a finger file with [[objects]] and [grasp]: contact "
        "force, pressure, penetration, actuator force; with --release also trace the "
        "pull-out and report the holding force. Exit 0 converged, 3 failed, 1 user error.",
    )
    gr.add_argument("finger", metavar="FINGER.toml")
    gr.add_argument("--out", metavar="RESULT.json", help="write the grasp as JSON")
    gr.add_argument(
        "--plot", type=_figure_path, metavar="GRASP.png", help="save a figure of the grasp"
    )
    gr.add_argument("--release", action="store_true", help="also trace the release force")
    gr.add_argument(
        "--friction",
        type=_nonnegative_float,
        default=None,
        metavar="MU",
        help="friction coefficient for the release trace (default: [contact])",
    )
    gr.add_argument(
        "--rigid-estimate",
        action="store_true",
        help="also re-solve with the penalty stiffnesses x4 and x16 and extrapolate the "
        "contact outputs and the tip to rigid contact (how far the penalty answer is from it)",
    )
    _add_check_resolution(gr, "the contact normal force")

    cmp_ = sub.add_parser(
        "compare",
        help="original vs modified adaptor (the paper's Fig. 4 and Table 2 settings)",
        description="Grasp an 18 mm cylinder with Finger-1 on the original and the modified "
        "adaptor at the same closing displacement, and trace the release force of 35, 50 and "
        "65 mm cylinders; print our figures beside the paper's. Writes DIR/compare.png, "
        "DIR/compare.json and DIR/compare_record.json, which keeps every finished release "
        "trace, so an interrupted comparison, run again, continues.",
    )
    _add_study_options(cmp_)
    cmp_.add_argument(
        "--friction",
        type=_nonnegative_float,
        default=0.0,
        metavar="MU",
        help="friction coefficient of the release traces (default 0: frictionless)",
    )

    cs = sub.add_parser(
        "clamp-study",
        help="best back-beam clamp length against object size (the paper's Fig. 5)",
        description="Contact force (or, with --holding, holding force) of the modified "
        "adaptor against the back beam's clamp length for cylinders of increasing size, at "
        "equal closing displacement or (--actuator-force) equal actuator force. Writes "
        "DIR/clamp_study.png and .json; the JSON keeps every finished grasp, so an "
        "interrupted study, run again, continues.",
    )
    _add_study_options(cs)
    cs.add_argument(
        "--actuator-force",
        type=_positive_float,
        default=None,
        metavar="N",
        help="hold the actuator force equal instead of the closing (replaces --closing)",
    )
    cs.add_argument(
        "--holding",
        action="store_true",
        help="also trace each release and pick the best l_c by the holding force",
    )
    cs.add_argument(
        "--friction",
        type=_nonnegative_float,
        default=0.0,
        metavar="MU",
        help="friction coefficient of the release traces (with --holding; default 0)",
    )

    sw = sub.add_parser(
        "sweep",
        help="solve a sweep of designs (sweep file: docs/sweep-format.md)",
        description="Sample design values of a finger, solve every design in batches, and "
        "write DIR/results.csv (one row per design, chunk by chunk), DIR/manifest.json and "
        "DIR/sweep.png. Re-running the same sweep into DIR continues where it stopped.",
    )
    sw.add_argument("sweep", metavar="SWEEP.toml")
    sw.add_argument("--out", metavar="DIR", required=True, help="output directory")
    sw.add_argument("--max-chunks", type=int, default=None, metavar="N", help="stop after N chunks")

    op = sub.add_parser(
        "optimize",
        help="optimise design values for the contact or holding force (docs/optimize-format.md)",
        description="Maximise the contact force or the holding force of a grasp over design "
        "values of a finger (gradients by the implicit function theorem, optax), under "
        "bounds and constraints. Writes DIR/progress.csv (one row per iteration), "
        "DIR/best.toml (the best feasible design), DIR/result.json, DIR/design.png and "
        "DIR/convergence.png. Re-running the same file into DIR continues where it stopped.",
    )
    op.add_argument("optimize", metavar="OPT.toml")
    op.add_argument("--out", metavar="DIR", required=True, help="output directory")
    op.add_argument(
        "--max-iterations",
        type=int,
        default=None,
        metavar="N",
        help="stop after N more iterations (run again to continue)",
    )
    return p


# --------------------------------------------------------------------------------------
# Printing
# --------------------------------------------------------------------------------------


def _percent(x) -> str:
    """A change in percent; "n/a" where a force it compares is unknown (NaN)."""
    return f"{x:+.0f} %" if math.isfinite(x) else "n/a"


def _f(x, digits=4) -> str:
    x = float(x)
    if not math.isfinite(x):
        return "nan"
    return f"{x:.{digits}g}"


def _summary(sol, finger, settings, source: str, elapsed: float | None = None) -> str:
    lines = []
    name = f"{settings.name} ({source})" if settings.name else source
    lines.append(f"finger: {name}; {finger.n_crossbeams} crossbeams; mode {sol.mode}")
    timing = f", {elapsed:.1f} s" if elapsed is not None else ""
    lines.append(
        f"status: {sol.status} (load factor {_f(sol.load_factor, 6)}, {int(sol.iterations)} "
        f"Newton iterations, max residual {_f(sol.max_residual, 2)}{timing})"
    )
    if sol.status == "beyond_limit_load":
        lines.append(
            "  the load lies beyond the finger's limit (fold) load; the state below is the "
            f"equilibrium at the fold, load factor {_f(sol.load_factor, 6)}"
        )
    elif sol.status == "failed":
        lines.append(f"  {fr.RESULTS[sol.result]}")
    d = np.asarray(sol.tip.displacement, dtype=np.float64)
    rot = np.asarray(sol.tip.rotation, dtype=np.float64)
    lines.append(
        f"tip displacement: dx = {_f(d[0])} mm, dy = {_f(d[1])} mm, dz = {_f(d[2])} mm; "
        f"rotation about y = {_f(np.degrees(rot[1]))} deg"
    )
    lines.append("reactions (wrench the adaptor applies at each base; moment about the base):")
    spatial = sol.mode == "spatial"
    head = ["beam", "Fx (N)", "Fz (N)", "My (N mm)"]
    if spatial:
        head = ["beam", "Fx (N)", "Fy (N)", "Fz (N)", "Mx (N mm)", "My (N mm)", "Mz (N mm)"]
    rows = []
    for beam, r in (("front", sol.reactions_front), ("back", sol.reactions_back)):
        F, M = np.asarray(r.force, dtype=np.float64), np.asarray(r.moment, dtype=np.float64)
        vals = [*F, *M] if spatial else [F[0], F[2], M[1]]
        rows.append([beam] + [_f(x) for x in vals])
    lines += _table(head, rows)
    return "\n".join(lines)


def _table(head, rows) -> list[str]:
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    fmt = lambda r: (
        "  "
        + "  ".join(
            str(c).ljust(w) if i == 0 else str(c).rjust(w)
            for i, (c, w) in enumerate(zip(r, widths, strict=True))
        )
    )
    return [fmt(head)] + [fmt(r) for r in rows]


def _crossbeam_table(sol, finger) -> list[str]:
    """Per crossbeam: attachment points, axial force (+ tension) and the largest |m_y|."""
    if finger.n_crossbeams == 0:
        return []
    head = ["crossbeam", "front_s (mm)", "back_s (mm)", "axial n.d3 (N)", "max |m_y| (N mm)"]
    rows = []
    cb = finger.crossbeams
    for i in range(finger.n_crossbeams):
        b = sol.crossbeam(i)
        R = np.asarray(b.frame, dtype=np.float64)
        n = np.asarray(b.force, dtype=np.float64)
        axial = np.einsum("ni,ni->n", n, R[:, :, 2])
        mid = len(axial) // 2
        my = np.max(np.abs(np.asarray(b.moment, dtype=np.float64)[:, 1]))
        rows.append([str(i), _f(cb.front_s[i]), _f(cb.back_s[i]), _f(axial[mid]), _f(my)])
    return [
        "crossbeams (numbered from 0; axial force at mid-length, + = tension):",
        *_table(head, rows),
    ]


# --------------------------------------------------------------------------------------
# Commands
# --------------------------------------------------------------------------------------


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _in_file(source: str | None, e: Exception) -> str:
    """A finger error found after reading (e.g. at solve time), prefixed by the finger
    file it came from as the file's own errors are."""
    text = str(e)
    return text if source is None or text.startswith(f"{source}:") else f"{source}: {text}"


def _solve(finger, settings, mode):
    kwargs = settings.solve_kwargs()
    if mode is not None:
        kwargs["mode"] = mode
    t0 = time.perf_counter()
    sol = fr.solve_finger(finger, **kwargs)
    sol.max_residual.block_until_ready()
    return sol, time.perf_counter() - t0


STUDY_CLOSING = 6.0  # mm, the paper studies' closing displacement


def _add_study_options(parser):
    """--out, --closing and --finger of the paper studies (compare, clamp-study)."""
    parser.add_argument("--out", metavar="DIR", default=".", help="output folder (default: .)")
    parser.add_argument(
        "--closing",
        type=_positive_float,
        default=STUDY_CLOSING,
        metavar="MM",
        help=f"closing displacement of every grasp (default {STUDY_CLOSING:g} mm)",
    )
    parser.add_argument(
        "--finger", metavar="FINGER.toml", default=None, help="another finger (default Finger-1)"
    )


def _add_check_resolution(parser, what):
    parser.add_argument(
        "--check-resolution",
        nargs="?",
        const=1e-6,
        default=None,
        type=_finite_float,
        metavar="RTOL",
        help="also solve at 2x and 4x the steps per segment and estimate the integration "
        f"error (the relative error of {what} that counts as resolved: RTOL, default 1e-6)",
    )


def _resolution_rtol(args):
    rtol = args.check_resolution
    if rtol is not None and not 0.0 < rtol < 1.0:
        raise UserError(f"--check-resolution: RTOL must lie in (0, 1), got {rtol:g}")
    return rtol


def _check_resolution(finger, settings, sol, rtol):
    """The step-doubling check of a converged solve (None when not asked for)."""
    if rtol is None:
        return None
    if sol.status != "converged":
        print("resolution: not checked (the solve did not converge)")
        return None
    kwargs = settings.solve_kwargs()
    kwargs["mode"] = sol.mode
    run = lambda: fr.check_resolution(finger, rtol=rtol, solution=sol, **kwargs)
    return _report_resolution(sol.steps, run)


def _report_resolution(n, run):
    """Announce the solves at 2n and 4n steps, run the check, print its verdict."""
    print(f"resolution: solving at {2 * n} and {4 * n} steps per segment ...")
    check = run()
    print(f"resolution: {check.message}")
    return check


def _cmd_solve(args) -> int:
    rtol = _resolution_rtol(args)
    finger, settings = fio.load_finger(args.finger)
    if args.load_scale is not None:
        finger = finger.scale_loads(args.load_scale)
    if settings.grasp is not None and finger.objects and not finger.loads:
        print(
            f"finray: note: {args.finger} describes a grasp; `finray solve` solves its "
            "loads alone (it has none) with the objects where they stand: "
            f"`finray grasp {args.finger}` closes the finger on them",
            file=sys.stderr,
        )
    sol, elapsed = _solve(finger, settings, args.mode)
    print(_summary(sol, finger, settings, args.finger, elapsed))
    check = _check_resolution(finger, settings, sol, rtol)
    if args.out:
        out = fio.solution_to_dict(sol, finger, settings=settings)
        if check is not None:
            out["resolution"] = check.to_dict()
        fio.write_json(args.out, out)
        print(f"wrote {args.out}")
    if args.plot:
        save_solution_figure(sol, finger, args.plot, title=settings.name or args.finger)
        print(f"wrote {args.plot}")
    return STATUS_EXIT[sol.status]


_DIRECTORY_OUTPUTS = ("demo", "compare", "clamp-study", "sweep", "optimize")


def _check_output_paths(args) -> None:
    """Refuse, before any work, an --out directory that is a file, and an output file
    whose folder is a file."""
    out = getattr(args, "out", None)
    if out and args.command in _DIRECTORY_OUTPUTS:
        if os.path.exists(out) and not os.path.isdir(out):
            raise UserError(f"--out {out}: is a file, not a directory")
    files = [("--out", out)] if out and args.command not in _DIRECTORY_OUTPUTS else []
    files += [("--plot", args.plot)] if getattr(args, "plot", None) else []
    for option, path in files:
        folder = os.path.dirname(path) or "."
        if os.path.exists(folder) and not os.path.isdir(folder):
            raise UserError(f"{option} {path}: {folder} is a file, not a directory")
        if os.path.isdir(path):
            raise UserError(f"{option} {path}: is a directory, not a file name")


def _cmd_limit(args) -> int:
    finger, settings = fio.load_finger(args.finger)
    if not finger.loads:
        raise UserError(f"{args.finger}: no [[loads]]: the limit load is a factor on the loads")
    if loads_are_zero(finger):
        raise UserError(f"{args.finger}: every load is zero: no factor on them can fold the finger")
    kwargs = settings.solve_kwargs()
    if args.mode is not None:
        kwargs["mode"] = args.mode
    t0 = time.perf_counter()
    lim = fr.limit_load(finger, **kwargs)
    factor = float(lim.load_factor)
    elapsed = time.perf_counter() - t0
    found = bool(lim.found)
    name = f"{settings.name} ({args.finger})" if settings.name else args.finger
    print(f"finger: {name}; mode {lim.solution.mode}")
    if found:
        print(f"limit load factor: {_f(factor, 6)} ({elapsed:.1f} s)")
    else:
        steps = ""
        if lim.solution.result == fr.RESULTS.continuation_steps_exhausted:
            steps = f" after {kwargs['options'].max_continuation_steps} arc-length steps"
        print(
            f"no limit load found: continuation stopped at load factor {_f(factor, 6)}{steps} "
            f"without a fold ({elapsed:.1f} s). {lim.solution.message}"
        )
    where = "at the limit" if found else "where the continuation stopped"
    for j, load in enumerate(finger.loads):
        if isinstance(load, fr.PointLoad):
            F = np.asarray(load.force) * factor
            what = f"point load at s = {_f(load.s)} mm"
        else:
            F = np.asarray(load.total_force) * factor
            s0, s1 = np.asarray(load.s_range)
            what = f"distributed load over s = {_f(s0)}..{_f(s1)} mm, total"
        beam = {0: "front", 1: "back"}.get(load.beam, f"crossbeam {load.beam - 2}")
        print(f"  loads[{j}] ({beam} beam, {what}) {where}: ({_f(F[0])}, {_f(F[1])}, {_f(F[2])}) N")
    sol = lim.solution
    d = np.asarray(sol.tip.displacement, dtype=np.float64)
    print(
        f"equilibrium there: tip dx = {_f(d[0])} mm, dz = {_f(d[2])} mm, rotation about y = "
        f"{_f(np.degrees(float(sol.tip.rotation[1])))} deg"
    )
    if args.out:
        fio.write_json(args.out, fio.limit_to_dict(lim, finger, settings=settings))
        print(f"wrote {args.out}")
    if args.plot:
        save_solution_figure(
            sol,
            finger.scale_loads(factor),
            args.plot,
            title=f"{settings.name or args.finger} at the limit load",
        )
        print(f"wrote {args.plot}")
    return EXIT_OK if found else EXIT_FAILED


def _check_grasp_objects(path, finger, settings) -> str | None:
    """The checks `fr.grasp` makes of a finger file's objects before it solves (a
    non-zero closing direction; objects within the finger's reach and ahead of it), run
    without solving when the file has a [grasp] table. Errors name the file and the key.
    Returns what was checked, for a summary line (None: no [grasp], nothing to check:
    objects in a file without one are obstacles of a loaded solve, where any side of the
    finger is fine)."""
    gs = settings.grasp
    if gs is None:
        return None
    if not finger.objects:
        raise UserError(
            f"{path}: grasp: a [grasp] table needs at least one [[objects]] entry to close the "
            "finger on"
        )
    try:
        w = unit_direction(gs.direction, "grasp.direction")
        check_objects(finger, w)
    except fr.FingerError as e:
        raise UserError(f"{path}: {e}") from None
    n = len(finger.objects)
    along = f"closing along [{w[0]:g}, {w[1]:g}]"
    return f"{n} object{'s' if n > 1 else ''} ahead and in reach, {along}"


def _study_kind(path) -> str | None:
    """The kind of a study file ("sweep" or "optimize": a top-level `finger = "base.toml"`), else
    None (a finger file, or a file the finger reader reports on)."""
    import tomllib

    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except (OSError, tomllib.TOMLDecodeError):
        return None
    if not isinstance(doc.get("finger"), str):
        return None
    return "optimize" if "objective" in doc or "optimizer" in doc else "sweep"


def _shown_path(path) -> str:
    """A path relative to the working directory when it lies below it."""
    rel = os.path.relpath(path)
    return path if rel.startswith("..") else rel


def _validate_study(path, kind) -> str:
    """Read a sweep or optimisation file (its base finger too) and say what it holds."""
    if kind == "sweep":
        sw = fsweep.load_sweep(path)
        what = (
            f"sweep of {_count(sw.size, 'design')} ({sw.sampling}) over {', '.join(sw.names)}; "
            f"{_count(len(sw.outputs), 'output')}, mode {sw.mode}"
        )
        return f"{path}: OK: {what}; base finger {_shown_path(sw.finger_path)}"
    pb = optimize_file.load_optimize(path)
    names = ", ".join(d.name for d in pb.design)
    what = (
        f"optimise {pb.objective} over {names}; {pb.optimizer}, "
        f"{_count(pb.iterations, 'iteration')}"
    )
    return f"{path}: OK: {what}; base finger {_shown_path(pb.finger_path)}"


def _cmd_validate(args) -> int:
    kind = _study_kind(args.finger)
    if kind is not None:
        print(_validate_study(args.finger, kind))
        return EXIT_OK
    finger, settings = fio.load_finger(args.finger)
    grasp = _check_grasp_objects(args.finger, finger, settings)
    name = f" ({settings.name})" if settings.name else ""
    print(
        f"{args.finger}{name}: OK: {_count(finger.n_crossbeams, 'crossbeam')}, "
        f"{_count(len(finger.loads), 'load')}, mode {settings.mode}"
        + (f"; grasp: {grasp}" if grasp else "")
    )
    return EXIT_OK


def _cmd_demo(args) -> int:
    finger, settings = fio.load_packaged_finger(DEMO_FINGER)
    print(
        "finray demo: Finger-1 under the paper's Fig. 3 load, 4 N in +x spread over the "
        "front beam from l5 = 75 mm to l7 = 105 mm"
    )
    sol, elapsed = _solve(finger, settings, None)
    print(_summary(sol, finger, settings, "examples/finger1.toml", elapsed))
    print("\n".join(_crossbeam_table(sol, finger)))
    out = args.out
    png, js = os.path.join(out, "demo.png"), os.path.join(out, "demo.json")
    fio.write_json(js, fio.solution_to_dict(sol, finger, settings=settings))
    save_solution_figure(sol, finger, png, title="Finger-1, 4 N over l5..l7")
    print(f"wrote {png}\nwrote {js}")

    print(
        "\nGrasping an 18 mm cylinder: original vs modified adaptor (front base pinned, "
        "back beam clamped over 20 mm, rigid support to 60 mm), same closing of 6 mm"
    )
    cmp = studies.compare_adaptors(finger, closing=6.0, release_diameters=(), progress=_progress)
    print("\n".join(_comparison_lines(cmp)))
    grasp_png = os.path.join(out, "demo_grasp.png")
    save_figure(grasp_figure([cmp.original, cmp.modified], ["original", "modified"]), grasp_png)
    print(f"wrote {grasp_png}")
    ok = cmp.original.converged and cmp.modified.converged
    return STATUS_EXIT[sol.status] if ok else EXIT_FAILED


def _cmd_sweep(args) -> int:
    if args.max_chunks is not None and args.max_chunks < 1:
        raise UserError(f"--max-chunks must be a positive integer, got {args.max_chunks}")
    sw = fsweep.load_sweep(args.sweep)
    print(
        f"sweep {args.sweep}: {sw.size} designs ({sw.sampling}) of {sw.finger_path}, "
        f"values {', '.join(sw.names)}; outputs {', '.join(sw.outputs)}; mode {sw.mode}"
    )
    try:
        run = fsweep.run_sweep(sw, args.out, max_chunks=args.max_chunks, progress=sys.stderr)
    except KeyboardInterrupt:
        _say_interrupted(os.path.join(args.out, fsweep.RESULTS_CSV), "designs")
        return EXIT_INTERRUPTED
    counts = ", ".join(f"{n} {status}" for status, n in sorted(run.counts.items()))
    print(f"wrote {run.csv} ({run.done} of {run.total} designs: {counts or 'none yet'})")
    if run.figure:
        print(f"wrote {run.figure}")
    elif not run.finished:
        print("not finished: run the same command to continue")
    if run.finished and run.converged == 0:
        print(f"finray: {_no_design_converged(run)}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


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


def _cmd_optimize(args) -> int:
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
        run = fopt.run_optimize(
            pr, args.out, max_iterations=args.max_iterations, progress=sys.stderr
        )
    except KeyboardInterrupt:
        _say_interrupted(os.path.join(args.out, fopt.PROGRESS_CSV), "iterations")
        return EXIT_INTERRUPTED
    print(f"{run.reason}; {run.rows} iterations in {run.csv}")
    if run.best is None:
        print("no feasible design yet")
    else:
        b = run.best
        gain = 100.0 * (b["objective"] / run.initial_objective - 1.0)
        print(
            f"best (iteration {b['iteration']}): {pr.objective} {_f(b['objective'], 6)} N "
            f"({gain:+.1f} % on the initial {_f(run.initial_objective, 6)} N)"
        )
        for name, v in b["design"].items():
            print(f"  {name} = {_f(v, 6)}")
        for name, m in b["margins"].items():
            print(f"  margin {name}: {_f(m, 4)}")
        print(f"wrote {run.best_toml}")
    for path in run.figures:
        print(f"wrote {path}")
    if not run.finished:
        print("not finished: run the same command to continue")
    return EXIT_FAILED if run.failed else EXIT_OK


def _progress(msg):
    print(f"  ... {msg}", file=sys.stderr, flush=True)


def _grasp_dict(g, release=None) -> dict:
    c = g.contact
    out = {
        "status": g.status,
        "closing": float(g.closing),
        "penalty_stiffness": float(g.stiffness),
        "support_penalty_stiffness": float(g.support_stiffness),
        "max_residual": float(g.solution.max_residual),
        "stability": _stability_dict(g),
        "contact": {
            "force": np.asarray(c.force).tolist(),
            "normal_force": float(c.normal_force),
            "contact_length": float(c.contact_length),
            "max_penetration": float(c.max_penetration),
            "support_force": np.asarray(c.support_force).tolist(),
            "support_penetration": float(c.support_penetration),
            "crossbeam_force_mean": np.asarray(c.crossbeam_force).tolist(),
            "actuator_force": float(c.actuator_force),
            "pressure_front": {
                "s": np.asarray(g.solution.front.s).tolist(),
                "q": np.asarray(c.pressure_front).tolist(),
            },
            "pressure_back": {
                "s": np.asarray(g.solution.back.s).tolist(),
                "q": np.asarray(c.pressure_back).tolist(),
            },
        },
        "reactions": {
            "front": {
                "force": np.asarray(g.solution.reactions_front.force).tolist(),
                "moment": np.asarray(g.solution.reactions_front.moment).tolist(),
            },
            "back": {
                "force": np.asarray(g.solution.reactions_back.force).tolist(),
                "moment": np.asarray(g.solution.reactions_back.moment).tolist(),
            },
        },
    }
    if release is not None:
        out["release"] = {
            "peak": release.peak,
            "peak_pull": release.peak_pull,
            "complete": release.complete,
            "message": release.message,
            "pull": release.pull.tolist(),
            "force": release.force.tolist(),
        }
    return out


def _stability_dict(g):
    s = g.stability
    if s is None:
        return None
    return {
        "stable": s.stable,
        "min_eigenvalue": s.min_eigenvalue,
        "eigenvalues": s.eigenvalues.tolist(),
        "conjugate_segments": list(s.conjugate_segments),
        "critical_points": [c.describe() for c in g.critical_points],
    }


def _stability_lines(g) -> list[str]:
    s = g.stability
    lines = []
    if s is not None:
        state = "stable" if s.stable else s.message
        lines.append(
            f"  stability         {state} (smallest eigenvalues of the tangent stiffness "
            + ", ".join(f"{v:.3g}" for v in s.eigenvalues[:3])
            + ")"
        )
    return lines + [f"  path              {c.describe()}" for c in g.critical_points]


def _support_lines(g) -> list[str]:
    if g.finger.adaptor.support_length is None:
        return []
    c = g.contact
    return [
        f"  support force     x {_f(c.support_force[0])}, z {_f(c.support_force[2])} N, "
        f"max penetration {_f(c.support_penetration)} mm "
        f"(penalty stiffness {float(g.support_stiffness):.4g} N/mm^2)"
    ]


def _grasp_lines(g, name="") -> list[str]:
    c = g.contact
    head = f"{name}: " if name else ""
    return (
        [
            f"{head}{g.status} at closing {float(g.closing):.4g} mm "
            f"(penalty stiffness {float(g.stiffness):.4g} N/mm^2)",
            f"  contact force     {_f(c.normal_force)} N normal resultant; total force x "
            f"{_f(c.force[0])}, z {_f(c.force[2])} N",
            f"  contact length    {_f(c.contact_length)} mm, max penetration "
            f"{_f(c.max_penetration)} mm",
            f"  crossbeam force   x {_f(c.crossbeam_force[0])}, z {_f(c.crossbeam_force[2])} N "
            "(mean on the front beam)",
            f"  actuator force    {_f(c.actuator_force)} N",
        ]
        + _support_lines(g)
        + _stability_lines(g)
        + [f"  warning: {w}" for w in g.penetration_warnings()]
        + ([f"  {fr.RESULTS[g.solution.result]}"] if g.status in ("failed", "unstable") else [])
    )


def _cmd_grasp(args) -> int:
    rtol = _resolution_rtol(args)
    finger, settings = fio.load_finger(args.finger)
    if settings.grasp is None:
        raise UserError(f"{args.finger} has no [grasp] table (closing or actuator_force)")
    _check_grasp_objects(args.finger, finger, settings)  # (naming the file and the key)
    gs = settings.grasp
    how = (
        f"closing {_f(gs.closing)} mm"
        if gs.actuator_force is None
        else f"actuator force {_f(gs.actuator_force)} N"
    )
    _progress(f"grasp, {how}")
    t0 = time.perf_counter()
    g = fr.grasp(finger, **gs.grasp_kwargs())
    print("\n".join(_grasp_lines(g, settings.name or args.finger)))
    short = gs.actuator_force is not None and (
        float(g.contact.actuator_force) < (1.0 - 1e-6) * gs.actuator_force
    )
    if short and not g.converged:  # (not a failure after the force was met)
        where = f"{_f(g.contact.actuator_force)} N at closing {_f(g.closing)} mm"
        asked = f"short of the {_f(gs.actuator_force)} N asked"
        if g.solution.result == fr.RESULTS.actuator_force_not_reached:
            print(f"  peak actuator force {where}, {asked}")
        else:
            print(f"  the closing path stopped at {where}, {asked}")
    print(f"  solved in {time.perf_counter() - t0:.2f} s")
    trace = None
    if args.release and g.converged:
        _progress(f"release trace, pull steps of {_f(gs.pull_step)} mm")
        trace = fr.release_force(g, step=gs.pull_step, friction=args.friction)
        print(
            f"  holding force     {_f(trace.peak)} N at pull {_f(trace.peak_pull)} mm "
            f"({trace.message})"
        )
    rigid = None
    if args.rigid_estimate and g.converged:
        _progress("rigid-contact estimate: the grasp at 4 and 16 x its penalty stiffnesses")
        try:
            rigid = fr.rigid_contact_estimate(g)
        except RuntimeError as error:
            print(f"  rigid-contact estimate: {error}")
        else:
            print("  rigid-contact estimate (extrapolated in the penalty stiffness):")
            print("\n".join("    " + line for line in rigid.lines()))
    check = None
    if rtol is not None and g.converged:
        run = lambda: fr.check_grasp_resolution(g, rtol=rtol)
        check = _report_resolution(g.integrator.steps, run)
    if args.out:
        out = _grasp_dict(g, trace)
        if rigid is not None:
            out["rigid_estimate"] = {
                key: getattr(rigid, key)
                for key in (
                    "factors",
                    "stiffness",
                    "support_stiffness",
                    "values",
                    "order",
                    "rigid",
                    "distance",
                )
            }
        if check is not None:
            out["resolution"] = check.to_dict()
        fio.write_json(args.out, out)
        print(f"wrote {args.out}")
    if args.plot:
        save_figure(grasp_figure([g], [settings.name or "grasp"]), args.plot)
        print(f"wrote {args.plot}")
    return EXIT_OK if g.converged else EXIT_FAILED


def _study_finger(path):
    if path is None:
        finger, _ = fio.load_packaged_finger(DEMO_FINGER)
    else:
        finger, _ = fio.load_finger(path)
    return finger


def _placed_rows(cmp, paper_gain) -> list[list[str]]:
    if cmp.placed is None:
        return []
    height, o, m = cmp.placed
    return [
        [
            f"  object at {height:g} mm (N)",
            _f(o.contact.normal_force),
            _f(m.contact.normal_force),
            _percent(cmp.placed_gain),
            f"+{paper_gain:.0f} % (simulated)",
        ]
    ]


def _placed_note(cmp) -> list[str]:
    if cmp.placed is None:
        return []
    return [
        f"  The paper's gain is what this model gives with the object {studies.ABOVE_SUPPORT:g} mm "
        "above the end of the",
        f"  support (here at {cmp.placed[0]:g} mm). At 60 mm the object presses on crossbeams "
        "the support backs.",
    ]


def _comparison_lines(cmp) -> list[str]:
    o, m = cmp.original.contact, cmp.modified.contact
    rows = [
        [
            "contact force (N)",
            _f(o.normal_force),
            _f(m.normal_force),
            _percent(cmp.contact_force_gain),
            f"+{studies.PAPER_CONTACT_FORCE_GAIN:.0f} % (simulated)",
        ],
        *_placed_rows(cmp, studies.PAPER_CONTACT_FORCE_GAIN),
        ["contact length (mm)", _f(o.contact_length), _f(m.contact_length), "", ""],
        ["crossbeam force x (N)", _f(o.crossbeam_force[0]), _f(m.crossbeam_force[0]), "", ""],
        ["crossbeam force z (N)", _f(o.crossbeam_force[2]), _f(m.crossbeam_force[2]), "", ""],
    ]
    lo, hi = studies.PAPER_RELEASE_RANGE
    for d, (a, b) in cmp.release.items():
        rows.append(
            [
                f"release force, {d:g} mm (N)",
                _f(a.peak),
                _f(b.peak),
                _percent(cmp.release_gain(d)),
                f"+{lo:.0f} to +{hi:.0f} % (measured)",
            ]
        )
    head = [
        "18 mm object, closing " + f"{cmp.closing:g} mm",
        "original",
        "modified",
        "change",
        "paper",
    ]
    return _table(head, rows) + _placed_note(cmp)


def _cmd_compare(args) -> int:
    finger = _study_finger(args.finger)
    t0 = time.perf_counter()
    kept = os.path.join(args.out, "compare_record.json")
    try:
        cmp = studies.compare_adaptors(
            finger, closing=args.closing, friction=args.friction, progress=_progress, record=kept
        )
    except KeyboardInterrupt:
        print(
            f"finray: interrupted; finished release traces are in {kept}: run the same "
            "command to continue",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    print("\n".join(_comparison_lines(cmp)))
    print(
        f"({time.perf_counter() - t0:.1f} s; frictionless release unless --friction; see "
        "docs/grasping.md for the model and why our figures differ from the paper's)"
    )
    os.makedirs(args.out, exist_ok=True)
    png = os.path.join(args.out, "compare.png")
    save_figure(grasp_figure([cmp.original, cmp.modified], ["original", "modified"]), png)
    js = os.path.join(args.out, "compare.json")
    fio.write_json(
        js,
        {
            "closing": cmp.closing,
            "original": _grasp_dict(cmp.original),
            "modified": _grasp_dict(cmp.modified),
            "contact_force_gain_percent": cmp.contact_force_gain,
            "placed": None
            if cmp.placed is None
            else {
                "height": cmp.placed[0],
                "original": _grasp_dict(cmp.placed[1]),
                "modified": _grasp_dict(cmp.placed[2]),
                "contact_force_gain_percent": cmp.placed_gain,
            },
            "release": {
                str(d): {
                    "original": a.peak,
                    "modified": b.peak,
                    "gain_percent": cmp.release_gain(d),
                }
                for d, (a, b) in cmp.release.items()
            },
        },
    )
    print(f"wrote {png}\nwrote {js}\nwrote {kept}")
    ok = cmp.original.converged and cmp.modified.converged
    return EXIT_OK if ok else EXIT_FAILED


def _cmd_clamp_study(args) -> int:
    if args.friction and not args.holding:
        raise UserError("--friction applies to the release traces: add --holding")
    if args.actuator_force is not None and args.closing != STUDY_CLOSING:
        raise UserError(
            f"--closing {args.closing:g} and --actuator-force {args.actuator_force:g}: give one "
            "(the actuator force sets each grasp's closing)"
        )
    finger = _study_finger(args.finger)
    js = os.path.join(args.out, "clamp_study.json")
    try:
        st = studies.clamp_study(
            finger,
            closing=args.closing,
            actuator_force=args.actuator_force,
            holding=args.holding,
            friction=args.friction,
            progress=_progress,
            record=js,
        )
    except KeyboardInterrupt:
        print(
            f"finray: interrupted; finished grasps are in {js}: run the same command to continue",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    held = (
        f"closing {args.closing:g} mm"
        if args.actuator_force is None
        else f"actuator force {args.actuator_force:g} N"
    )
    tables = [("contact force (N)", st.normal_force)]
    if args.actuator_force is not None:
        tables.append(("closing (mm)", st.closing))
    if args.holding:
        tables.append((f"holding force (N, mu = {args.friction:g})", st.holding_force))
    head = ["object (mm)"] + [f"l_c={x:g}" for x in st.clamp_lengths]
    for k, (what, values) in enumerate(tables):
        best = values is st.force  # (the table the best clamp length is picked by)
        rows = [
            [f"{d:g}"] + [_f(x) for x in row] + ([_f(b)] if best else [])
            for d, row, b in zip(st.diameters, values, st.best, strict=True)
        ]
        print(
            ("\n" if k else "")
            + f"{what} of the modified adaptor, support up to {st.support_length:g} mm, {held}"
        )
        print("\n".join(_table(head + (["best l_c"] if best else []), rows)))
    if not np.all(np.isfinite(st.normal_force)):
        print("(nan: that grasp did not converge; the '...' line of its solve says why)")
    png = os.path.join(args.out, "clamp_study.png")
    save_figure(clamp_study_figure(st), png)
    print(f"wrote {png}\nwrote {js}")
    return EXIT_OK


COMMANDS = {
    "grasp": _cmd_grasp,
    "compare": _cmd_compare,
    "clamp-study": _cmd_clamp_study,
    "solve": _cmd_solve,
    "limit": _cmd_limit,
    "validate": _cmd_validate,
    "demo": _cmd_demo,
    "sweep": _cmd_sweep,
    "optimize": _cmd_optimize,
}


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A FingerWarning as one line, `finray: warning: ...` (Python's default names the
    console script's line and echoes it); other warnings as Python shows them."""
    if issubclass(category, fr.FingerWarning):
        print(f"finray: warning: {message}", file=sys.stderr if file is None else file)
    else:
        _python_show_warning(message, category, filename, lineno, file, line)


_python_show_warning = warnings.showwarning


def main(argv=None) -> int:
    """Entry point of the `finray` console script. Returns the exit code."""
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        return _main(argv)


def _main(argv) -> int:
    parser = _parser()
    args = None
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as e:  # --help, --version
            return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USER
        _check_output_paths(args)
        if args.command != "validate":
            enable_compilation_cache()
            choose_device(args.command)
        return COMMANDS[args.command](args)
    except fr.FingerError as e:  # (the finger file's, when a command reads one)
        print(f"finray: error: {_in_file(getattr(args, 'finger', None), e)}", file=sys.stderr)
        return EXIT_USER
    except (UserError, fio.FingerFileError, DesignError, StudyRecordError) as e:
        print(f"finray: error: {e}", file=sys.stderr)
        return EXIT_USER
    except OSError as e:  # e.g. an output path that cannot be written
        where = f": {e.filename}" if getattr(e, "filename", None) else ""
        print(f"finray: error: {e.strerror or e}{where}", file=sys.stderr)
        return EXIT_USER
    except KeyboardInterrupt:  # (sweep, optimize, compare and clamp-study say what they kept)
        print("finray: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
