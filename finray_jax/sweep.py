"""Design sweeps from a sweep file (TOML): sample named design values of a base finger,
solve every design with `solve_batch`, and write one CSV row per design, chunk by chunk.

Format reference: docs/sweep-format.md. The CSV is written append-only with a flush and
an fsync after every chunk, next to a manifest holding the sweep's hash: running the same
sweep into the same directory again continues after the last complete row (an interrupt
loses at most the chunk being solved); a different sweep there is refused. Every row
carries a `reason`: empty when the design converged, else the validation error of an
invalid design or the solver's result and message.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
from collections.abc import Callable

import numpy as np
import tqdm

from . import io as fio
from ._finger import Finger, FingerError
from ._grasp import check_objects, unit_direction
from ._solution import RESULTS
from ._solve import resolve_mode
from ._version import __version__
from .batch import INVALID, Diagnosis, iter_batch, iter_grasps, one_line
from .design import (
    GRASP_OUTPUTS,
    OUTPUTS,
    RELEASE_OUTPUTS,
    DesignError,
    check_design_names,
    get_design,
)

__all__ = ["Sweep", "SweepError", "load_sweep", "loads_sweep", "run_sweep"]

SAMPLINGS = ("grid", "random")
RESULTS_CSV, MANIFEST, FIGURE = "results.csv", "manifest.json", "sweep.png"
GRASP_CHUNK = 16  # designs grasped between two writes of results.csv (one after another)
STATUS_COLUMNS = ("status", "iterations", "max_residual", "reason")
# Bump when the meaning of a sweep file changes (it keys the sweep's hash). A change of
# the CSV's layout alone is handled when a sweep continues (see `_resume`: a CSV written
# before the `reason` column existed is upgraded in place), so the hash stays.
_FORMAT = 1


class SweepError(fio.FingerFileError):
    """An invalid sweep file, or an output directory that holds another sweep."""


@dataclasses.dataclass(frozen=True)
class Axis:
    """One swept design value: uniform in [lo, hi]; `points` grid points (grid only)."""

    name: str
    lo: float
    hi: float
    points: int | None = None


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A parsed sweep file. `designs()` gives the design values, one row per design."""

    source: str
    finger_path: str
    finger: Finger
    settings: fio.SolveSettings
    axes: tuple[Axis, ...]
    sampling: str
    n_random: int
    seed: int
    outputs: tuple[str, ...]
    mode: str
    chunk_size: int | None  # None: solve_batch's default for the platform
    digest: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    @property
    def size(self) -> int:
        if self.sampling == "grid":
            return math.prod(a.points for a in self.axes)
        return self.n_random

    @property
    def columns(self) -> tuple[str, ...]:
        return ("index", *self.names, *self.outputs, *STATUS_COLUMNS)

    def designs(self) -> dict[str, np.ndarray]:
        """Grid: every combination, the last name varying fastest. Random: uniform in
        [lo, hi], drawn by numpy's default_rng(seed), one row per design."""
        if self.sampling == "grid":
            grids = [np.linspace(a.lo, a.hi, a.points) for a in self.axes]
            cols = np.meshgrid(*grids, indexing="ij")
            return {a.name: c.reshape(-1) for a, c in zip(self.axes, cols)}
        rng = np.random.default_rng(self.seed)
        lo = np.asarray([a.lo for a in self.axes])
        hi = np.asarray([a.hi for a in self.axes])
        u = lo + (hi - lo) * rng.random((self.n_random, len(self.axes)))
        return {a.name: u[:, j] for j, a in enumerate(self.axes)}


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------

_TOP = ("finger", "outputs", "mode", "chunk_size", "sampling", "design")
_HELP = {
    "finger": " (path of the base finger file, relative to this sweep file)",
    "outputs": ' (names of the outputs to record, e.g. ["tip.dx", "max_strain"])',
    "sampling": ' (table [sampling] with kind = "grid" or "random")',
    "design": " (one [[design]] table per swept design value, with name and range)",
    "kind": ' ("grid" or "random")',
    "name": " (a design value, e.g. adaptor.back_clamp_length or crossbeams.front_s[2])",
    "range": " ([lo, hi])",
    "points": " (number of grid points, >= 2)",
    "n": " (number of random designs)",
}


def loads_sweep(text: str, *, source: str = "<string>", base_dir: str = ".") -> Sweep:
    """Read a sweep from TOML text; the finger path is relative to `base_dir`."""
    return fio.loads_study(text, _parse, SweepError, source, base_dir)


def load_sweep(path) -> Sweep:
    """Read a sweep file. Raises SweepError (a FingerFileError) naming the key and value."""
    return fio.load_study(path, loads_sweep, "sweep", SweepError)


def _parse(doc, r, source, base_dir) -> Sweep:
    r.table(doc, "", _TOP)
    fio.require_keys(r, doc, "", ("finger", "outputs", "sampling", "design"), _HELP)
    finger, settings, finger_path, finger_hash = fio.base_finger(doc, r, base_dir)

    mode = r.string(doc.get("mode", settings.mode), "mode", fio.MODES)
    mode = resolve_mode(finger, mode)
    chunk_size = doc.get("chunk_size")
    if chunk_size is not None:
        chunk_size = r.integer(chunk_size, "chunk_size", minimum=1)

    grasping = settings.grasp is not None  # every design is closed on the objects
    if grasping:
        try:
            check_objects(finger, unit_direction(settings.grasp.direction, "grasp.direction"))
        except FingerError as e:
            raise r.error("finger", f"its [grasp] cannot be solved: {e}", doc["finger"]) from None
    of_grasp = (*GRASP_OUTPUTS, *RELEASE_OUTPUTS)
    valid = (*of_grasp, *OUTPUTS) if grasping else tuple(OUTPUTS)
    outputs = doc["outputs"]
    if not isinstance(outputs, list) or not outputs:
        raise r.error("outputs", "expected a non-empty array of output names", outputs)
    for i, name in enumerate(outputs):
        r.string(name, f"outputs[{i}]")
        if name in of_grasp and not grasping:
            raise r.error(
                f"outputs[{i}]",
                "is an output of a grasp: the finger file needs objects and a [grasp] table",
                name,
            )
        if name not in valid:
            raise r.error(
                f"outputs[{i}]", f"unknown output; valid outputs: {', '.join(valid)}", name
            )
        if outputs.index(name) != i:
            raise r.error(f"outputs[{i}]", "listed twice", name)

    smp = r.table(doc["sampling"], "sampling", ("kind", "n", "seed"))
    fio.require_keys(r, smp, "sampling", ("kind",), _HELP)
    kind = r.string(smp["kind"], "sampling.kind", SAMPLINGS)
    n_random, seed = 0, 0
    if kind == "random":
        fio.require_keys(r, smp, "sampling", ("n",), _HELP)
        n_random = r.integer(smp["n"], "sampling.n", minimum=1)
        seed = r.integer(smp.get("seed", 0), "sampling.seed", minimum=0)
    else:
        for key in ("n", "seed"):
            if key in smp:
                raise r.error(f"sampling.{key}", 'is for kind = "random"', smp[key])

    axes = []
    for i, tbl in enumerate(r.array_of_tables(doc["design"], "design")):
        p = f"design[{i}]"
        r.table(tbl, p, ("name", "range", "points"))
        fio.require_keys(
            r, tbl, p, ("name", "range") + (("points",) if kind == "grid" else ()), _HELP
        )
        name = r.string(tbl["name"], f"{p}.name")
        try:
            check_design_names(finger, [name], scalar=True)
            get_design(finger, [name])  # (e.g. a support length needs a support)
        except DesignError as e:
            raise r.error(f"{p}.name", str(e), name) from None
        if name in (a.name for a in axes):
            raise r.error(f"{p}.name", "listed twice", name)
        lo, hi = r.vector(tbl["range"], f"{p}.range", 2, "[lo, hi]")
        if not lo < hi:
            raise r.error(f"{p}.range", "needs lo < hi", tbl["range"])
        points = None
        if kind == "grid":
            points = r.integer(tbl["points"], f"{p}.points", minimum=2)
        elif "points" in tbl:
            raise r.error(
                f"{p}.points",
                'is for kind = "grid" (random sampling takes sampling.n)',
                tbl["points"],
            )
        axes.append(Axis(name, lo, hi, points))
    if not axes:
        raise r.error("design", "needs at least one [[design]] table" + _HELP["design"])

    # chunk_size only groups the rows: changing it continues the same sweep.
    key = {
        "format": _FORMAT,
        "finger_sha256": finger_hash,
        "mode": mode,
        "sampling": kind,
        "n": n_random,
        "seed": seed,
        "design": [[a.name, a.lo, a.hi, a.points] for a in axes],
        "outputs": list(outputs),
    }
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()
    sweep = Sweep(
        source,
        finger_path,
        finger,
        settings,
        tuple(axes),
        kind,
        n_random,
        seed,
        tuple(outputs),
        mode,
        chunk_size,
        digest,
    )
    if sweep.size > 10**8:
        raise r.error("design", f"{sweep.size} designs is too many (at most 10^8)")
    return sweep


# --------------------------------------------------------------------------------------
# The results directory
# --------------------------------------------------------------------------------------


def _manifest(sweep: Sweep, finished: bool, source: str) -> dict:
    return {
        "sweep_hash": sweep.digest,
        "sweep_file": source,
        "finger_file": sweep.finger_path,
        "n_designs": sweep.size,
        "columns": list(sweep.columns),
        "finished": finished,
        "finray_jax_version": __version__,
    }


def _check_manifest(sweep: Sweep, out_dir: str) -> str:
    """Check that out_dir holds this sweep or none; the sweep file that started it (kept
    in the manifest when another file with the same hash continues it)."""
    path = os.path.join(out_dir, MANIFEST)
    if os.path.exists(path):
        record = fio.read_run_record(
            path,
            out_dir,
            SweepError,
            what="sweep manifest",
            run="sweep",
            digest=sweep.digest,
            hash_key="sweep_hash",
            source_key="sweep_file",
        )
        return record.get("sweep_file") or os.path.abspath(sweep.source)
    if os.path.exists(os.path.join(out_dir, RESULTS_CSV)):
        raise SweepError(f"{out_dir} holds a {RESULTS_CSV} without a {MANIFEST}: use another --out")
    return os.path.abspath(sweep.source)


def _fmt(x) -> str:
    return repr(float(x)) if math.isfinite(float(x)) else "nan"


def _line(cells) -> str:
    """One CSV line, a cell quoted where it needs it (a reason may hold commas)."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


def _fields(line: str) -> list[str]:
    return next(csv.reader([line.rstrip("\n")]), [])


def _complete_lines(data: bytes) -> list[str]:
    """The lines of a CSV that ended (a torn last line is left out), each with its newline."""
    keep = data[: data.rfind(b"\n") + 1].decode("utf-8")
    return [line + "\n" for line in keep.split("\n")[:-1]]


# --------------------------------------------------------------------------------------
# Why a design did not converge (the `reason` column)
# --------------------------------------------------------------------------------------


_RESULT_NAMES = {int(item._value): name for name, item in RESULTS._name_to_item.items()}


def _solver_reason(code: int) -> str:
    """The reason of a solved design: "" when it converged, else the solver's result and
    the first sentence of its message (e.g. "nonlinear_divergence: Nonlinear solve
    diverged.")."""
    code = int(code)
    if code == int(RESULTS.successful._value):
        return ""
    text = one_line(RESULTS._index_to_message[code])
    end = text.find(". ")
    return f"{_RESULT_NAMES.get(code, code)}: {text if end < 0 else text[: end + 1]}"


# The reason of an old row (written before the reason column) whose solver result was
# not recorded.
_UNRECORDED = (
    "not recorded (this row was written by an older finray_jax, before results.csv had a "
    "reason column; run the sweep into a new --out to see the solver's message)"
)


def _reasons(res, diagnose: Diagnosis) -> list[str]:
    out = []
    for k in range(res.size):
        code = int(res.result[k])
        if code == INVALID:
            out.append(diagnose({n: v[k] for n, v in res.inputs.items()}))
        else:
            out.append(_solver_reason(code))
    return out


def _resume(sweep: Sweep, csv_path: str, designs, diagnose: Diagnosis) -> int:
    """Number of complete rows already in the CSV (truncating a torn last line); checks
    that they are the first designs of this sweep. A CSV written before the `reason`
    column existed is rewritten with it (atomically), so the sweep continues."""
    header = _line(sweep.columns)
    if not os.path.exists(csv_path):
        fio.write_atomic(csv_path, header)
        return 0
    with open(csv_path, "rb") as fh:
        data = fh.read()
    try:
        lines = _complete_lines(data)
    except UnicodeDecodeError as e:
        raise SweepError(f"{csv_path}: not UTF-8 text ({e}); use another --out") from None
    legacy = _line(sweep.columns[:-1])  # the columns before the reason column existed
    if not lines or lines[0] not in (header, legacy):
        raise SweepError(f"{csv_path}: its header is not this sweep's columns; use another --out")
    old = lines[0] == legacy
    n_cols = len(sweep.columns) - old
    done = 0
    for line in lines[1:]:
        try:
            fields = _fields(line)
        except csv.Error:
            break
        if len(fields) != n_cols or fields[0] != str(done):
            break
        try:
            inputs = [float(fields[1 + j]) for j in range(len(sweep.names))]
        except ValueError:
            break
        for j, name in enumerate(sweep.names):
            if inputs[j] != float(designs[name][done]):
                raise SweepError(
                    f"{csv_path}: row {done} has {name} = {fields[1 + j]}, but this sweep's "
                    f"design {done} has {_fmt(designs[name][done])}; use another --out"
                )
        done += 1
    if old:
        status = sweep.columns.index("status")
        rows = []
        for k, line in enumerate(lines[1 : done + 1]):
            fields = _fields(line)
            rows.append(_line([*fields, _legacy_reason(fields[status], k, designs, diagnose)]))
        fio.write_atomic(csv_path, header + "".join(rows))
        return done
    size = len("".join(lines[: done + 1]).encode("utf-8"))
    if size != len(data):
        with open(csv_path, "r+b") as fh:
            fh.truncate(size)
            fh.flush()
            os.fsync(fh.fileno())
    return done


def _legacy_reason(status: str, k: int, designs, diagnose: Diagnosis) -> str:
    """The reason of row k of a CSV written before the reason column."""
    if status == "converged":
        return ""
    if status == "invalid":  # (the validation is cheap: done again)
        return diagnose({n: v[k] for n, v in designs.items()})
    if status == "beyond_limit_load":
        return _solver_reason(int(RESULTS.beyond_limit_load._value))
    return _UNRECORDED


def _rows(sweep: Sweep, first: int, res, reasons) -> str:
    lines = []
    status = res.status
    for k in range(res.size):
        cells = [str(first + k)]
        cells += [_fmt(res.inputs[n][k]) for n in sweep.names]
        cells += [_fmt(res.outputs[n][k]) for n in sweep.outputs]
        cells += [status[k], str(int(res.iterations[k])), _fmt(res.max_residual[k])]
        lines.append(_line([*cells, reasons[k]]))
    return "".join(lines)


def _progress_bar(total: int, done: int, stream):
    """A tqdm bar on `stream` (None: none): designs done of the sweep, designs/s, the time
    left, and how many designs did not converge."""
    bar = tqdm.tqdm(
        total=total,
        initial=done,
        file=stream,
        disable=stream is None,
        unit=" designs",
        desc="sweep",
        dynamic_ncols=True,
        mininterval=0.5,
    )
    bar.set_postfix_str("0 not converged", refresh=False)
    return bar


@dataclasses.dataclass(frozen=True)
class SweepRun:
    """What `run_sweep` did: designs in the CSV (done of total), and the files written."""

    done: int
    total: int
    csv: str
    figure: str | None
    counts: dict[str, int]  # rows per status

    @property
    def finished(self) -> bool:
        return self.done == self.total

    @property
    def converged(self) -> int:
        """Rows whose design converged."""
        return self.counts.get("converged", 0)


def run_sweep(
    sweep: Sweep,
    out_dir,
    *,
    max_chunks: int | None = None,
    progress=None,
    plot: bool = True,
    after_chunk: Callable[[int], None] | None = None,
) -> SweepRun:
    """Run (or continue) a sweep into `out_dir`: results.csv, manifest.json, sweep.png
    (not drawn when no design converged or went beyond its limit load: nothing to plot).

    max_chunks: stop after this many chunks (re-run to continue). progress: a text stream
    for the progress line, e.g. sys.stderr (None: quiet). after_chunk(rows_done) runs
    after every chunk has been written (a hook for tests and callers). The figure is drawn
    when all rows exist.
    """
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    source = _check_manifest(sweep, out_dir)
    fio.write_atomic(
        os.path.join(out_dir, MANIFEST),
        json.dumps(_manifest(sweep, False, source), indent=2) + "\n",
    )
    csv_path = os.path.join(out_dir, RESULTS_CSV)
    designs = sweep.designs()
    diagnose = Diagnosis(sweep.finger, sweep.mode)
    done = _resume(sweep, csv_path, designs, diagnose)
    bar = _progress_bar(sweep.size, done, progress)
    failed = 0
    with bar:
        if done < sweep.size:
            if sweep.settings.grasp is not None:
                batches = iter_grasps(
                    sweep.finger,
                    designs,
                    sweep.outputs,
                    grasp_kwargs=sweep.settings.grasp.grasp_kwargs(),
                    release_kwargs={"step": sweep.settings.grasp.pull_step},
                    mode=sweep.mode,
                    chunk_size=sweep.chunk_size or GRASP_CHUNK,
                    start=done,
                )
            else:
                batches = iter_batch(
                    sweep.finger,
                    designs,
                    sweep.outputs,
                    mode=sweep.mode,
                    chunk_size=sweep.chunk_size,
                    integrator=sweep.settings.integrator,
                    options=sweep.settings.options,
                    start=done,
                )
            with open(csv_path, "a", encoding="utf-8", newline="") as fh:
                for chunks, (first, res) in enumerate(batches, start=1):
                    fh.write(_rows(sweep, first, res, _reasons(res, diagnose)))
                    fh.flush()
                    os.fsync(fh.fileno())
                    bar.update(first + res.size - done)
                    done = first + res.size
                    failed += int(np.sum(res.status != "converged"))
                    bar.set_postfix_str(f"{failed} not converged")
                    if after_chunk is not None:
                        after_chunk(done)
                    if max_chunks is not None and chunks >= max_chunks:
                        break
    figure = None
    data = read_results(csv_path)
    if done == sweep.size:
        fio.write_atomic(
            os.path.join(out_dir, MANIFEST),
            json.dumps(_manifest(sweep, True, source), indent=2) + "\n",
        )
        drawn = np.isin(data["status"].astype(str), ("converged", "beyond_limit_load"))
        if plot and np.any(drawn):  # (else the figure would be empty axes)
            figure = os.path.join(out_dir, FIGURE)
            plot_sweep(sweep, data, figure)
    names, counts = np.unique(data["status"].astype(str), return_counts=True)
    return SweepRun(done, sweep.size, csv_path, figure, dict(zip(names.tolist(), counts.tolist())))


TEXT_COLUMNS = ("status", "reason")


def read_results(csv_path) -> dict[str, np.ndarray]:
    """The results CSV as columns: floats, and strings for `status` and `reason` (a CSV
    written before the reason column has none)."""
    with open(csv_path, "rb") as fh:
        lines = _complete_lines(fh.read())
    rows = list(csv.reader(line.rstrip("\n") for line in lines))
    head, rows = (rows[0], rows[1:]) if rows else ([], [])
    cols = list(zip(*rows)) if rows else [()] * len(head)
    return {
        name: np.asarray(col, dtype=object if name in TEXT_COLUMNS else np.float64)
        for name, col in zip(head, cols)
    }


# --------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------


def plot_sweep(sweep: Sweep, data: dict[str, np.ndarray], path: str) -> None:
    """Line plots for a 1-D sweep, heat maps for a 2-D grid, scatter plots otherwise.
    Only converged designs are drawn (beyond-limit ones as orange crosses on line and
    scatter plots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, outs = sweep.names, sweep.outputs
    ok = data["status"] == "converged"
    beyond = data["status"] == "beyond_limit_load"
    heat = sweep.sampling == "grid" and len(names) == 2
    cols = 1 if heat or len(names) == 1 else len(names)
    fig, axs = plt.subplots(
        len(outs), cols, figsize=(4.8 * cols, 3.2 * len(outs)), squeeze=False, layout="constrained"
    )
    for i, out in enumerate(outs):
        y = data[out]
        if heat:
            a, b = sweep.axes
            z = np.where(ok, y, np.nan).reshape(a.points, b.points)
            ax = axs[i, 0]
            mesh = ax.pcolormesh(
                np.linspace(b.lo, b.hi, b.points),
                np.linspace(a.lo, a.hi, a.points),
                z,
                shading="nearest",
            )
            fig.colorbar(mesh, ax=ax, label=out)
            ax.set_xlabel(b.name)
            ax.set_ylabel(a.name)
            continue
        for j, name in enumerate(names):
            ax, x = axs[i, j], data[name]
            if sweep.sampling == "grid" and len(names) == 1:
                ax.plot(x[ok], y[ok], "-o", ms=3)
            else:
                ax.scatter(x[ok], y[ok], s=8)
            if np.any(beyond):
                ax.plot(x[beyond], y[beyond], "x", color="tab:orange", label="beyond limit load")
                ax.legend(fontsize=7)
            ax.set_xlabel(name)
            ax.set_ylabel(out)
    fig.suptitle(f"{os.path.basename(sweep.source)}: {sweep.size} designs ({sweep.sampling})")
    fig.savefig(path, dpi=120)
    plt.close(fig)
