"""The `finray` command line's arguments: the parser of each command, the option types
(checked as they are read, before any work), and the options several commands share."""

import argparse
import math
import os
import sys

from . import io as fio
from ._cli_common import UserError
from ._version import __version__

STUDY_CLOSING = 6.0  # mm, the paper studies' closing displacement
STUDY_SUPPORT = 60.0  # mm, the clamp study's rigid support behind the back beam


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are `UserError`s that name the help to read."""

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
# Option types
# --------------------------------------------------------------------------------------


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


def _diameters(text: str) -> list[float]:
    """A comma-separated list of positive sizes (mm)."""
    return [_positive_float(x) for x in text.split(",")]


def _clamp_lengths(text: str) -> list[float]:
    """A comma-separated list of clamp lengths within the study's support (mm)."""
    lengths = [_nonnegative_float(x) for x in text.split(",")]
    if max(lengths) > STUDY_SUPPORT:
        raise argparse.ArgumentTypeError(
            f"clamp lengths lie within the support's {STUDY_SUPPORT:g} mm, got {text!r}"
        )
    return lengths


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text!r}")
    return n


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


# --------------------------------------------------------------------------------------
# Options shared by several commands
# --------------------------------------------------------------------------------------


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


def resolution_rtol(args):
    """The RTOL of --check-resolution (None when not given), checked to lie in (0, 1)."""
    rtol = args.check_resolution
    if rtol is not None and not 0.0 < rtol < 1.0:
        raise UserError(f"--check-resolution: RTOL must lie in (0, 1), got {rtol:g}")
    return rtol


# --------------------------------------------------------------------------------------
# The commands' parsers
# --------------------------------------------------------------------------------------


def _add_solve_parser(sub):
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


def _add_limit_parser(sub):
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


def _add_validate_parser(sub):
    v = sub.add_parser(
        "validate",
        help="check a finger, sweep or optimisation file",
        description="Check a finger file, or a sweep or optimisation file with its base "
        "finger; print OK or the error (exit 1).",
    )
    v.add_argument("finger", metavar="FILE.toml")


def _add_demo_parser(sub):
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


def _add_grasp_parser(sub):
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


# The release traces' friction `finray compare` reports by default: a first result to set
# beside the paper's measured holding forces, which include friction.
COMPARE_FRICTION = 0.3


def _add_compare_parser(sub):
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
        default=COMPARE_FRICTION,
        metavar="MU",
        help=f"friction coefficient of the release traces (default {COMPARE_FRICTION:g}, TPU on a "
        "plastic cylinder; 0: the frictionless, geometric holding force)",
    )


def _add_clamp_study_parser(sub):
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
        "--diameters",
        type=_diameters,
        default=None,
        metavar="MM,MM,...",
        help="the cylinders' diameters (default 18,35,50,65)",
    )
    cs.add_argument(
        "--clamp-lengths",
        type=_clamp_lengths,
        default=None,
        metavar="MM,MM,...",
        help=f"the back beam's clamp lengths, within the support's {STUDY_SUPPORT:g} mm "
        "(default 0,10,20,30,40,50)",
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
    _add_engine_options(cs)


def _add_engine_options(p) -> None:
    """Where the work runs (docs/distributed.md): this process, or a Ray cluster."""
    g = p.add_argument_group("engine (docs/distributed.md)")
    g.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help="where the work runs: this process (default) or a Ray cluster (Ray Core tasks)",
    )
    g.add_argument(
        "--address",
        default=None,
        metavar="auto|HOST:PORT",
        help="the Ray cluster to use (default: $RAY_ADDRESS, else a Ray instance started on "
        "this machine for the run)",
    )
    g.add_argument(
        "--workers", type=_positive_int, default=None, metavar="N", help="Ray tasks running at once"
    )
    g.add_argument(
        "--task-cpus",
        type=_nonnegative_float,
        default=None,
        metavar="N",
        help="CPUs per Ray task (default 1)",
    )
    g.add_argument(
        "--task-gpus",
        type=_nonnegative_float,
        default=None,
        metavar="N",
        help="GPUs per Ray task (default 0)",
    )
    g.add_argument(
        "--cache-dir",
        default=None,
        metavar="DIR",
        help="the Ray workers' compilation cache, e.g. on storage all nodes share",
    )


def _add_sweep_parser(sub):
    sw = sub.add_parser(
        "sweep",
        help="solve a sweep of designs (sweep file: docs/sweep-format.md)",
        description="Sample design values of a finger, solve every design in batches, and "
        "write DIR/results.csv (one row per design, chunk by chunk), DIR/manifest.json and "
        "DIR/sweep.png. Re-running the same sweep into DIR continues where it stopped. "
        "With --engine ray the chunks run on a Ray cluster.",
    )
    sw.add_argument("sweep", metavar="SWEEP.toml")
    sw.add_argument("--out", metavar="DIR", required=True, help="output directory")
    sw.add_argument("--max-chunks", type=int, default=None, metavar="N", help="stop after N chunks")
    sw.add_argument(
        "--parquet",
        action="store_true",
        help="also write DIR/results.parquet when the sweep is finished (needs pyarrow)",
    )
    _add_engine_options(sw)


def _add_optimize_parser(sub):
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


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"a port lies in 0..65535, got {text!r}")
    return port


def _add_explore_parser(sub):
    ex = sub.add_parser(
        "explore",
        help="a design explorer in the browser (needs finray_jax[explore])",
        description="Start a local web app: move a control, see the grasp (or the load "
        "case) change, and the gradient of an objective in every design value. Default "
        "finger: Finger-1 with the modified adaptor on the 18 mm cylinder. Everything is "
        "served locally (no internet). Ctrl-C stops it. See docs/explorer.md.",
    )
    ex.add_argument("finger", metavar="FINGER.toml", nargs="?", default=None)
    ex.add_argument(
        "--port", type=_port, default=5006, help="local port (default 5006; 0: a free one)"
    )
    ex.add_argument("--no-browser", action="store_true", help="print the address, open no browser")


# In the order `finray --help` lists the commands.
_COMMAND_PARSERS = (
    _add_solve_parser,
    _add_limit_parser,
    _add_validate_parser,
    _add_demo_parser,
    _add_grasp_parser,
    _add_compare_parser,
    _add_clamp_study_parser,
    _add_sweep_parser,
    _add_optimize_parser,
    _add_explore_parser,
)


def build_parser() -> Parser:
    """The `finray` parser: one sub-parser per command (the parsed `command` names it)."""
    p = Parser(
        prog="finray",
        description="Cosserat-rod simulator of fin-ray-effect gripper fingers (units: mm, N, "
        "MPa). Finger files are TOML: see docs/finger-format.md.",
    )
    p.add_argument("--version", action="version", version=f"finray_jax {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p._commands = sub.choices
    for add in _COMMAND_PARSERS:
        add(sub)
    for command in sub.choices.values():
        command.add_argument(
            "-q", "--quiet", action="store_true", help="no progress messages on stderr"
        )
    return p
