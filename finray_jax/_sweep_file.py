"""Sweep files (TOML, docs/sweep-format.md): the sweep they describe (`Sweep`, its
`Axis`es) and how they are read. `load_sweep(path)` raises SweepError naming the key and
the value."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math

import numpy as np

from . import io as fio
from ._finger import Finger, FingerError
from ._grasp_inputs import check_objects, unit_direction
from ._solve import resolve_mode
from .design import (
    GRASP_OUTPUTS,
    OUTPUTS,
    RELEASE_OUTPUTS,
    DesignError,
    check_design_names,
    get_design,
)

SAMPLINGS = ("grid", "random")
STATUS_COLUMNS = ("status", "iterations", "max_residual", "reason")
# Bump when the meaning of a sweep file changes (it keys the sweep's hash). A change of
# the CSV's layout alone is handled when a sweep continues (see `sweep._resume`: a CSV
# written before the `reason` column existed is upgraded in place), so the hash stays.
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
    outputs = _outputs(doc, r, finger, settings)
    kind, n_random, seed = _sampling(doc, r)
    axes = _axes(doc, r, finger, kind)

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
        axes,
        kind,
        n_random,
        seed,
        outputs,
        mode,
        chunk_size,
        digest,
    )
    if sweep.size > 10**8:
        raise r.error("design", f"{sweep.size} designs is too many (at most 10^8)")
    return sweep


def _outputs(doc, r, finger: Finger, settings) -> tuple[str, ...]:
    """The `outputs` array: names of outputs of a solve, or, when the finger file has a
    [grasp] table (every design is closed on the objects), of a grasp and its release."""
    grasping = settings.grasp is not None
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
    return tuple(outputs)


def _sampling(doc, r) -> tuple[str, int, int]:
    """The [sampling] table: (kind, number of random designs, seed); 0, 0 for a grid."""
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
    return kind, n_random, seed


def _axes(doc, r, finger: Finger, kind: str) -> tuple[Axis, ...]:
    """The [[design]] tables: one Axis per swept design value of the finger."""
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
    return tuple(axes)
