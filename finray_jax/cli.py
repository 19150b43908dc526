"""The `finray` command line: solve, limit, validate, demo, grasp, compare, clamp-study,
sweep, optimize and explore. See docs/cli.md.

Exit codes: 0 converged (or limit found, or file valid), 1 user error (bad or missing
file, bad option), 2 the load lies beyond the finger's limit load, 3 the solve failed (a
sweep: it finished and no design converged), 130 interrupted.

This module is the entry point (`main`): it parses the arguments (`_cli_args`), sets up
the run (compilation cache, device), dispatches to the command and turns errors into exit
codes. It holds the commands built on `_solve`, the timed solve of one finger file
(`solve` and `demo`); the others live beside it: `_cli_finger` (limit, validate),
`_cli_grasp` (grasp), `_cli_studies` (compare, clamp-study), `_cli_runs` (sweep,
optimize) and `_cli_explore` (explore). The JSON documents of grasps come from the
library's `finray_jax.report`.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
import warnings

import finray_jax as fr

from . import io as fio
from . import studies
from ._cache import enable_compilation_cache
from ._cli_args import STUDY_CLOSING as STUDY_CLOSING
from ._cli_args import build_parser, resolution_rtol
from ._cli_common import DEMO_FINGER as DEMO_FINGER
from ._cli_common import EXIT_BEYOND as EXIT_BEYOND
from ._cli_common import EXIT_FAILED as EXIT_FAILED
from ._cli_common import EXIT_INTERRUPTED as EXIT_INTERRUPTED
from ._cli_common import EXIT_OK as EXIT_OK
from ._cli_common import EXIT_USER as EXIT_USER
from ._cli_common import STATUS_EXIT as STATUS_EXIT
from ._cli_common import UserError as UserError
from ._cli_common import compiling, progress, set_quiet, solver_name
from ._cli_explore import explore_command
from ._cli_finger import (
    check_resolution,
    crossbeam_table,
    limit_command,
    summary,
    validate_command,
)
from ._cli_grasp import grasp_command
from ._cli_runs import optimize_command, sweep_command
from ._cli_studies import clamp_study_command, compare_command
from ._cli_studies import comparison_lines as _comparison_lines
from ._solve import resolve_mode
from .design import DesignError
from .engines import EngineError
from .plot import grasp_figure, save_figure, save_solution_figure
from .studies import StudyRecordError

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
    cores; 3-D: 16.7 against 23.9 ms; benchmarks/README.md), while a sweep's
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
        _check_writable(option, path, folder)
    if out and args.command in _DIRECTORY_OUTPUTS:
        _check_writable("--out", out, out)


def _check_writable(option: str, path: str, folder: str) -> None:
    """Refuse an output whose folder (or, where it does not exist yet, the nearest folder
    above it, where it would be created) cannot take a new file: a file is made there and
    removed (permission bits alone do not say, e.g. for root or a read-only mount)."""
    where = os.path.abspath(folder)
    while not os.path.exists(where):
        where = os.path.dirname(where)
    if not os.path.isdir(where):
        raise UserError(f"{option} {path}: {where} is a file, not a directory")
    try:
        with tempfile.TemporaryFile(dir=where):
            pass
    except OSError as e:
        raise UserError(f"{option} {path}: cannot write in {where} ({e.strerror or e})") from None


# --------------------------------------------------------------------------------------
# solve and demo
# --------------------------------------------------------------------------------------


def _solve(finger, settings, mode):
    kwargs = settings.solve_kwargs()
    if mode is not None:
        kwargs["mode"] = mode
    compiling(solver_name(resolve_mode(finger, kwargs.get("mode", "auto"))))
    t0 = time.perf_counter()
    sol = fr.solve_finger(finger, **kwargs)
    sol.max_residual.block_until_ready()
    return sol, time.perf_counter() - t0


def _cmd_solve(args) -> int:
    rtol = resolution_rtol(args)
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
    print(summary(sol, finger, settings, args.finger, elapsed))
    check = check_resolution(finger, settings, sol, rtol)
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


def _cmd_demo(args) -> int:
    finger, settings = fio.load_packaged_finger(DEMO_FINGER)
    print(
        "finray demo: Finger-1 under the paper's Fig. 3 load, 4 N in +x spread over the "
        "front beam from l5 = 75 mm to l7 = 105 mm"
    )
    sol, elapsed = _solve(finger, settings, None)
    print(summary(sol, finger, settings, "examples/finger1.toml", elapsed))
    print("\n".join(crossbeam_table(sol, finger)))
    out = args.out
    png, js = os.path.join(out, "demo.png"), os.path.join(out, "demo.json")
    fio.write_json(js, fio.solution_to_dict(sol, finger, settings=settings))
    save_solution_figure(sol, finger, png, title="Finger-1, 4 N over l5..l7")
    print(f"wrote {png}\nwrote {js}")

    print(
        "\nGrasping an 18 mm cylinder: original vs modified adaptor (front base pinned, "
        "back beam clamped over 20 mm, rigid support to 60 mm), same closing of 6 mm"
    )
    compiling("contact solver", "for the two adaptors' grasps")
    cmp = studies.compare_adaptors(finger, closing=6.0, release_diameters=(), progress=progress)
    print("\n".join(_comparison_lines(cmp)))
    grasp_png = os.path.join(out, "demo_grasp.png")
    save_figure(grasp_figure([cmp.original, cmp.modified], ["original", "modified"]), grasp_png)
    print(f"wrote {grasp_png}")
    ok = cmp.original.converged and cmp.modified.converged
    return STATUS_EXIT[sol.status] if ok else EXIT_FAILED


# --------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------


COMMANDS = {
    "grasp": grasp_command,
    "compare": compare_command,
    "clamp-study": clamp_study_command,
    "solve": _cmd_solve,
    "limit": limit_command,
    "validate": validate_command,
    "demo": _cmd_demo,
    "sweep": sweep_command,
    "optimize": optimize_command,
    "explore": explore_command,
}


def _in_file(source: str | None, e: Exception) -> str:
    """A finger error found after reading (e.g. at solve time), prefixed by the finger
    file it came from as the file's own errors are."""
    text = str(e)
    return text if source is None or text.startswith(f"{source}:") else f"{source}: {text}"


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
    parser = build_parser()
    args = None
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as e:  # --help, --version
            return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USER
        set_quiet(args.quiet)
        _check_output_paths(args)
        enable_compilation_cache()
        choose_device(args.command)
        return COMMANDS[args.command](args)
    except fr.FingerError as e:  # (the finger file's, when a command reads one)
        print(f"finray: error: {_in_file(getattr(args, 'finger', None), e)}", file=sys.stderr)
        return EXIT_USER
    except (UserError, fio.FingerFileError, DesignError, StudyRecordError, EngineError) as e:
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
