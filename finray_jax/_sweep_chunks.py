"""The work of a sweep: its designs cut into chunks by index, and one chunk solved (or
grasped) into its CSV rows, each row carrying its design's index, wherever the chunk
runs (this process, or a worker of a cluster: `solve_chunk` is an engine's work
function)."""

from __future__ import annotations

import csv
import dataclasses
import io
import math

import numpy as np

from ._batch_data import INVALID, BatchResult, Diagnosis, one_line
from ._grasp_batch import iter_grasps
from ._solution import RESULTS
from ._solve import topology_of
from ._sweep_file import Sweep
from .batch import chunk_size_here, iter_batch

GRASP_CHUNK = 16  # designs grasped in one chunk (one after another)


def chunk_size(sweep: Sweep) -> int:
    """Designs per chunk: the sweep file's chunk_size, else 16 grasps or the batch
    solver's default for this process's platform."""
    if sweep.chunk_size is not None:
        return sweep.chunk_size
    if sweep.settings.grasp is not None:
        return GRASP_CHUNK
    return chunk_size_here()


def chunks(size: int, per_chunk: int, have: np.ndarray) -> list[tuple[int, ...]]:
    """The design indices still to do, chunk by chunk: chunk k holds the missing designs
    among k * per_chunk ... (k + 1) * per_chunk - 1 (the same chunks on every engine)."""
    out = []
    for a in range(0, size, per_chunk):
        todo = tuple(int(i) for i in np.flatnonzero(~have[a : a + per_chunk]) + a)
        if todo:
            out.append(todo)
    return out


def fmt(x) -> str:
    return repr(float(x)) if math.isfinite(float(x)) else "nan"


def csv_line(cells) -> str:
    """One CSV line, a cell quoted where it needs it (a reason may hold commas)."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


# --------------------------------------------------------------------------------------
# Why a design did not converge (the `reason` column)
# --------------------------------------------------------------------------------------


_RESULT_NAMES = {int(item._value): name for name, item in RESULTS._name_to_item.items()}


def solver_reason(code: int) -> str:
    """The reason of a solved design: "" when it converged, else the solver's result and
    the first sentence of its message (e.g. "nonlinear_divergence: Nonlinear solve
    diverged.")."""
    code = int(code)
    if code == int(RESULTS.successful._value):
        return ""
    text = one_line(RESULTS._index_to_message[code])
    end = text.find(". ")
    return f"{_RESULT_NAMES.get(code, code)}: {text if end < 0 else text[: end + 1]}"


def _reasons(res: BatchResult, diagnose: Diagnosis) -> list[str]:
    out = []
    for k in range(res.size):
        code = int(res.result[k])
        if code == INVALID:
            out.append(diagnose({n: v[k] for n, v in res.inputs.items()}))
        else:
            out.append(solver_reason(code))
    return out


# --------------------------------------------------------------------------------------
# One chunk
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SweepWork:
    """What every chunk of a sweep shares: the sweep, and the chunk length every chunk is
    padded to (the driver's, so that all workers run one compiled program)."""

    sweep: Sweep
    per_chunk: int


@dataclasses.dataclass(frozen=True)
class ChunkRows:
    """A solved chunk: its design indices, its CSV rows (in that order) and their
    statuses."""

    indices: tuple[int, ...]
    text: str
    status: tuple[str, ...]


class _Prepared:
    """What every chunk of one sweep needs, made once per process: the design values,
    the base topology (so every chunk runs the one compiled program) and the diagnosis."""

    def __init__(self, work: SweepWork):
        sweep = self.sweep = work.sweep
        self.designs = sweep.designs()
        self.topology = topology_of(sweep.finger, sweep.mode)
        self.diagnose = Diagnosis(sweep.finger, self.topology.mode, self.topology)
        self.per_chunk = work.per_chunk

    def results(self, values) -> BatchResult:
        sw = self.sweep
        if sw.settings.grasp is not None:
            batches = iter_grasps(
                sw.finger,
                values,
                sw.outputs,
                grasp_kwargs=sw.settings.grasp.grasp_kwargs(),
                release_kwargs={"step": sw.settings.grasp.pull_step},
                mode=sw.mode,
                chunk_size=self.per_chunk,
                topology=self.topology,
            )
        else:
            batches = iter_batch(
                sw.finger,
                values,
                sw.outputs,
                mode=sw.mode,
                chunk_size=self.per_chunk,
                integrator=sw.settings.integrator,
                options=sw.settings.options,
                topology=self.topology,
            )
        ((_, res),) = list(batches)  # (one chunk: at most per_chunk designs)
        return res


# (sweep digest, chunk length) -> the sweep's prepared state in this process
_PREPARED: dict[tuple[str, int], _Prepared] = {}


def solve_chunk(work: SweepWork, indices) -> ChunkRows:
    """Designs `indices` of the sweep (at most one chunk) solved into CSV rows."""
    sweep = work.sweep
    key = (sweep.digest, work.per_chunk)
    prep = _PREPARED.get(key)
    if prep is None:
        prep = _PREPARED[key] = _Prepared(work)
    idx = np.asarray(indices, dtype=np.int64)
    res = prep.results({name: v[idx] for name, v in prep.designs.items()})
    text = rows_text(sweep, idx.tolist(), res, _reasons(res, prep.diagnose))
    return ChunkRows(tuple(idx.tolist()), text, tuple(str(s) for s in res.status))


def rows_text(sweep: Sweep, indices, res: BatchResult, reasons) -> str:
    """The CSV rows of designs `indices` (their results `res`, their reasons)."""
    status = res.status
    lines = []
    for k, i in enumerate(indices):
        cells = [str(i)]
        cells += [fmt(res.inputs[n][k]) for n in sweep.names]
        cells += [fmt(res.outputs[n][k]) for n in sweep.outputs]
        cells += [status[k], str(int(res.iterations[k])), fmt(res.max_residual[k])]
        lines.append(csv_line([*cells, reasons[k]]))
    return "".join(lines)
