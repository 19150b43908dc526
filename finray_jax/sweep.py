"""Design sweeps from a sweep file (TOML): sample named design values of a base finger,
solve every design (batched solves, or grasps), and write one CSV row per design, chunk
by chunk, on an engine: this process or a Ray cluster (`finray_jax.engines`).

Format reference: docs/sweep-format.md. Each row carries its design's index. This
process alone writes the CSV, append-only with a flush and an fsync after every chunk
as it lands (in any order on a cluster), next to a manifest holding the sweep's hash;
when every design has its row the CSV is rewritten sorted by index. Running the same
sweep into the same directory again solves only the designs without a row (an interrupt
loses at most the chunks being solved); a different sweep there is refused. Every row
carries a `reason`: empty when the design converged, else the validation error of an
invalid design or the solver's result and message.

This module drives a sweep into its results directory; the chunks are solved by
`_sweep_chunks`, the sweep file read by `_sweep_file` and the figure drawn by
`_sweep_plot`.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
from collections.abc import Callable

import numpy as np
import tqdm

from . import io as fio
from ._solution import RESULTS
from ._sweep_chunks import SweepWork, chunk_size, chunks, csv_line, fmt, solve_chunk, solver_reason
from ._sweep_file import SAMPLINGS as SAMPLINGS
from ._sweep_file import STATUS_COLUMNS as STATUS_COLUMNS
from ._sweep_file import Axis as Axis
from ._sweep_file import Sweep, SweepError, load_sweep, loads_sweep
from ._sweep_plot import plot_sweep
from ._version import __version__
from .batch import Diagnosis
from .engines import LocalEngine, RayEngine

__all__ = ["Sweep", "SweepError", "load_sweep", "loads_sweep", "run_sweep"]

RESULTS_CSV = "results.csv"
MANIFEST = "manifest.json"
FIGURE = "sweep.png"
PARQUET = "results.parquet"


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


def _fields(line: str) -> list[str]:
    return next(csv.reader([line.rstrip("\n")]), [])


def _complete_lines(data: bytes) -> list[str]:
    """The lines of a CSV that ended (a torn last line is left out), each with its newline."""
    keep = data[: data.rfind(b"\n") + 1].decode("utf-8")
    return [line + "\n" for line in keep.split("\n")[:-1]]


# The reason of an old row (written before the reason column) whose solver result was
# not recorded.
_UNRECORDED = (
    "not recorded (this row was written by an older finray_jax, before results.csv had a "
    "reason column; run the sweep into a new --out to see the solver's message)"
)


def _resume(sweep: Sweep, csv_path: str, designs, diagnose: Diagnosis) -> np.ndarray:
    """Which designs the CSV holds already (a boolean per design), its rows in any order,
    each checked against this sweep's design of its index; a torn last line is cut off.
    A CSV written before the `reason` column existed is rewritten with it (atomically),
    so the sweep continues."""
    header = csv_line(sweep.columns)
    have = np.zeros(sweep.size, dtype=bool)
    if not os.path.exists(csv_path):
        fio.write_atomic(csv_path, header)
        return have
    with open(csv_path, "rb") as fh:
        data = fh.read()
    try:
        lines = _complete_lines(data)
    except UnicodeDecodeError as e:
        raise SweepError(f"{csv_path}: not UTF-8 text ({e}); use another --out") from None
    legacy = csv_line(sweep.columns[:-1])  # the columns before the reason column existed
    if not lines or lines[0] not in (header, legacy):
        raise SweepError(f"{csv_path}: its header is not this sweep's columns; use another --out")
    old = lines[0] == legacy
    kept = 1
    for line in lines[1:]:
        index = _row_index(line, len(sweep.columns) - old, sweep, csv_path, designs)
        if index is None:  # (a line no complete row: it and what follows are cut off)
            break
        if have[index]:
            raise SweepError(f"{csv_path}: design {index} has two rows; use another --out")
        have[index] = True
        kept += 1
    if old:
        status = sweep.columns.index("status")
        rows = []
        for line in lines[1:kept]:
            fields = _fields(line)
            k = int(fields[0])
            rows.append(csv_line([*fields, _legacy_reason(fields[status], k, designs, diagnose)]))
        fio.write_atomic(csv_path, header + "".join(rows))
        return have
    size = len("".join(lines[:kept]).encode("utf-8"))
    if size != len(data):
        with open(csv_path, "r+b") as fh:
            fh.truncate(size)
            fh.flush()
            os.fsync(fh.fileno())
    return have


def _row_index(line: str, n_cols: int, sweep: Sweep, csv_path: str, designs) -> int | None:
    """The design index of a complete row of this sweep (None: not a complete row); a
    row whose values are not its design's is refused."""
    try:
        fields = _fields(line)
    except csv.Error:
        return None
    if len(fields) != n_cols:
        return None
    try:
        index = int(fields[0])
        inputs = [float(fields[1 + j]) for j in range(len(sweep.names))]
    except ValueError:
        return None
    if not 0 <= index < sweep.size:
        raise SweepError(
            f"{csv_path}: a row has index {index}, outside this sweep's designs 0 to "
            f"{sweep.size - 1}; use another --out"
        )
    for j, name in enumerate(sweep.names):
        if inputs[j] != float(designs[name][index]):
            raise SweepError(
                f"{csv_path}: row {index} has {name} = {fields[1 + j]}, but this sweep's "
                f"design {index} has {fmt(designs[name][index])}; use another --out"
            )
    return index


def _legacy_reason(status: str, k: int, designs, diagnose: Diagnosis) -> str:
    """The reason of row k of a CSV written before the reason column."""
    if status == "converged":
        return ""
    if status == "invalid":  # (the validation is cheap: done again)
        return diagnose({n: v[k] for n, v in designs.items()})
    if status == "beyond_limit_load":
        return solver_reason(int(RESULTS.beyond_limit_load._value))
    return _UNRECORDED


def _sort_rows(csv_path: str) -> None:
    """Rewrite the CSV (atomically) with its rows by design index, if they are not."""
    with open(csv_path, "rb") as fh:
        lines = _complete_lines(fh.read())
    keys = [int(_fields(line)[0]) for line in lines[1:]]
    if keys != sorted(keys):
        order = np.argsort(keys, kind="stable")
        fio.write_atomic(csv_path, lines[0] + "".join(lines[1 + k] for k in order))


def _progress_bar(total: int, done: int, stream):
    """A tqdm bar on `stream` (None: none): designs done of the sweep, designs/s, the time
    left, how many designs did not converge and the workers that delivered."""
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
class FailedChunk:
    """A chunk whose task failed for good: its design indices, and why."""

    indices: tuple[int, ...]
    error: str

    def describe(self) -> str:
        i = self.indices
        span = f"design {i[0]}" if len(i) == 1 else f"designs {i[0]} to {i[-1]}"
        return f"chunk of {span} ({len(i)}) failed: {self.error}"


@dataclasses.dataclass(frozen=True)
class WorkerTime:
    """What one worker process did in a run: chunks, their seconds, and the seconds of
    its first chunk (which compiled the sweep's program, unless a cache held it)."""

    chunks: int = 0
    seconds: float = 0.0
    first_seconds: float = 0.0


@dataclasses.dataclass(frozen=True)
class SweepRun:
    """What `run_sweep` did: designs in the CSV (done of total), the files written, rows
    per status, the chunks that failed for good (not in the CSV: a re-run tries them
    again) and the workers' times."""

    done: int
    total: int
    csv: str
    figure: str | None
    counts: dict[str, int]  # rows per status
    failed_chunks: tuple[FailedChunk, ...] = ()
    workers: dict[str, WorkerTime] = dataclasses.field(default_factory=dict)
    parquet: str | None = None

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
    engine: LocalEngine | RayEngine | None = None,
    max_chunks: int | None = None,
    progress=None,
    plot: bool = True,
    parquet: bool = False,
    after_chunk: Callable[[int], None] | None = None,
) -> SweepRun:
    """Run (or continue) a sweep into `out_dir`: results.csv, manifest.json, sweep.png
    (not drawn when no design converged or went beyond its limit load: nothing to plot)
    and, with parquet, results.parquet (pyarrow).

    engine: where the chunks are solved: `LocalEngine()` (None: this process) or a
    `RayEngine` (a Ray cluster). Chunks land in any order; this process alone writes
    them, a chunk at a time, each row with its design index; the finished CSV is sorted
    by index, row for row what the local engine writes. A chunk whose task fails for
    good is left out and reported (`SweepRun.failed_chunks`); a re-run solves it.
    max_chunks: stop after this many chunks (re-run to continue). progress: a text stream
    for the progress bar, and a line saying where a resumed sweep continues, e.g.
    sys.stderr (None: quiet). after_chunk(rows_done) runs after every chunk has been
    written (a hook for tests and callers). The figure is drawn when all rows exist.
    """
    engine = LocalEngine() if engine is None else engine
    if parquet:
        _need_pyarrow()
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    source = _check_manifest(sweep, out_dir)
    fio.write_atomic(
        os.path.join(out_dir, MANIFEST),
        json.dumps(_manifest(sweep, False, source), indent=2) + "\n",
    )
    csv_path = os.path.join(out_dir, RESULTS_CSV)
    designs = sweep.designs()
    have = _resume(sweep, csv_path, designs, Diagnosis(sweep.finger, sweep.mode))
    done = int(have.sum())
    if progress is not None and 0 < done < sweep.size:
        print(f"  ... resuming: {done} of {sweep.size} designs are in {csv_path}", file=progress)
    work = SweepWork(sweep, chunk_size(sweep))
    todo = chunks(sweep.size, work.per_chunk, have)[:max_chunks]
    tally = _Tally()
    landing = engine.map_unordered(solve_chunk, work, todo)
    with (
        _progress_bar(sweep.size, done, progress) as bar,
        _appending(csv_path, todo) as fh,
        contextlib.closing(landing),  # (left early, e.g. Ctrl-C: the engine stops its tasks)
    ):
        for landed in landing:
            tally.add(landed)
            if landed.error is None:
                rows = landed.value
                fh.write(rows.text)
                fh.flush()
                os.fsync(fh.fileno())
                have[list(rows.indices)] = True
                bar.update(len(rows.indices))
            bar.set_postfix_str(tally.postfix())
            if landed.error is None and after_chunk is not None:
                after_chunk(int(have.sum()))
    return _finish(sweep, out_dir, source, have, plot, parquet, tally)


class _Tally:
    """A run's chunks as they land: designs not converged, chunks that failed for good,
    and each worker's times (the progress bar's postfix)."""

    def __init__(self):
        self.not_converged = 0
        self.failed: list[FailedChunk] = []
        self.workers: dict[str, WorkerTime] = {}

    def add(self, landed) -> None:
        if landed.error is not None:
            self.failed.append(FailedChunk(tuple(landed.item), landed.error))
            return
        self.not_converged += sum(s != "converged" for s in landed.value.status)
        t = self.workers.get(landed.worker) or WorkerTime()
        first = landed.seconds if landed.first else t.first_seconds
        self.workers[landed.worker] = WorkerTime(t.chunks + 1, t.seconds + landed.seconds, first)

    def postfix(self) -> str:
        text = f"{self.not_converged} not converged"
        if len(self.workers) > 1 or self.failed:
            text += f", {len(self.workers)} workers"
        if self.failed:
            text += f", {len(self.failed)} chunks failed"
        return text


@contextlib.contextmanager
def _appending(csv_path: str, todo):
    """The CSV open for appending rows (nothing opened when there is nothing to do)."""
    if not todo:
        yield None
        return
    with open(csv_path, "a", encoding="utf-8", newline="") as fh:
        yield fh


def _finish(sweep, out_dir, source, have, plot, parquet, tally: _Tally) -> SweepRun:
    """After the chunks: the CSV sorted, the manifest marked finished, the figure and the
    Parquet file, once every design has its row."""
    csv_path = os.path.join(out_dir, RESULTS_CSV)
    figure = table = None
    done = int(have.sum())
    if done == sweep.size:
        _sort_rows(csv_path)
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
        if parquet:
            table = _write_parquet(data, sweep.columns, os.path.join(out_dir, PARQUET))
    names, counts = np.unique(data["status"].astype(str), return_counts=True)
    counts = dict(zip(names.tolist(), counts.tolist()))
    failed = tuple(tally.failed)
    return SweepRun(done, sweep.size, csv_path, figure, counts, failed, tally.workers, table)


PARQUET_HINT = "pip install 'finray_jax[ray]' (or pyarrow alone)"


def _need_pyarrow() -> None:
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        raise SweepError(f"results.parquet needs pyarrow, not installed: {PARQUET_HINT}") from None


def _write_parquet(data, columns, path: str) -> str:
    """The sorted results as a Parquet table (atomically: a temporary file renamed)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {n: data[n].tolist() if n in TEXT_COLUMNS else data[n] for n in columns}
    cols["index"] = data["index"].astype(np.int64)
    table = pa.table(cols)
    tmp = f"{path}.{os.getpid()}.tmp"
    pq.write_table(table, tmp)
    os.replace(tmp, path)
    return path


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
