"""Design sweeps from a sweep file (TOML): sample named design values of a base finger,
solve every design with `solve_batch`, and write one CSV row per design, chunk by chunk.

Format reference: docs/sweep-format.md. The CSV is written append-only with a flush and
an fsync after every chunk, next to a manifest holding the sweep's hash: running the same
sweep into the same directory again continues after the last complete row (an interrupt
loses at most the chunk being solved); a different sweep there is refused. Every row
carries a `reason`: empty when the design converged, else the validation error of an
invalid design or the solver's result and message.

This module runs a sweep into its results directory; the sweep file is read by
`_sweep_file` and the figure drawn by `_sweep_plot`.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
from collections.abc import Callable

import numpy as np
import tqdm

from . import io as fio
from ._solution import RESULTS
from ._sweep_file import SAMPLINGS as SAMPLINGS
from ._sweep_file import STATUS_COLUMNS as STATUS_COLUMNS
from ._sweep_file import Axis as Axis
from ._sweep_file import Sweep, SweepError, load_sweep, loads_sweep
from ._sweep_plot import plot_sweep
from ._version import __version__
from .batch import INVALID, Diagnosis, iter_batch, iter_grasps, one_line

__all__ = ["Sweep", "SweepError", "load_sweep", "loads_sweep", "run_sweep"]

RESULTS_CSV, MANIFEST, FIGURE = "results.csv", "manifest.json", "sweep.png"
GRASP_CHUNK = 16  # designs grasped between two writes of results.csv (one after another)


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
    for the progress bar, and a line saying where a resumed sweep continues, e.g.
    sys.stderr (None: quiet). after_chunk(rows_done) runs after every chunk has been
    written (a hook for tests and callers). The figure is drawn when all rows exist.
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
    if progress is not None and 0 < done < sweep.size:
        print(f"  ... resuming: {done} of {sweep.size} designs are in {csv_path}", file=progress)
    bar = _progress_bar(sweep.size, done, progress)
    failed = 0
    with bar:
        if done < sweep.size:
            with open(csv_path, "a", encoding="utf-8", newline="") as fh:
                for chunks, (first, res) in enumerate(_batches(sweep, designs, done), start=1):
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


def _batches(sweep: Sweep, designs, done: int):
    """The sweep's results from design `done` on, chunk by chunk: grasps when the finger
    file has a [grasp] table, else solves."""
    if sweep.settings.grasp is not None:
        return iter_grasps(
            sweep.finger,
            designs,
            sweep.outputs,
            grasp_kwargs=sweep.settings.grasp.grasp_kwargs(),
            release_kwargs={"step": sweep.settings.grasp.pull_step},
            mode=sweep.mode,
            chunk_size=sweep.chunk_size or GRASP_CHUNK,
            start=done,
        )
    return iter_batch(
        sweep.finger,
        designs,
        sweep.outputs,
        mode=sweep.mode,
        chunk_size=sweep.chunk_size,
        integrator=sweep.settings.integrator,
        options=sweep.settings.options,
        start=done,
    )


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
