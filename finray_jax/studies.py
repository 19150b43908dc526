"""The paper's comparisons on the public API: original vs modified adaptor, and the
back-beam clamp length against object size (Sheikh Sofla et al. 2025, Figs. 4-5, Table 2).

Nothing here is tuned to the paper's numbers: the fingers are our assumed Finger-1
(examples/finger1.toml) and the paper's figures are printed beside ours for context.
The record that lets an interrupted study go on is `_study_record`.
"""

import contextlib
import dataclasses
import os

import equinox as eqx
import numpy as np

from ._bases import PinnedBase
from ._finger import Adaptor, Finger
from ._grasp import grasp
from ._grasp_solution import GraspSolution
from ._objects import Circle
from ._release import release_force
from ._solution import RESULTS
from ._study_record import StudyRecordError as StudyRecordError
from ._study_record import (
    finger_digest,
    read_record,
    study_hash,
    trace_from_record,
    trace_record,
    write_record,
)
from .engines import LocalEngine

# The paper's figures (quoted for comparison only).
PAPER_CONTACT_FORCE_GAIN = 260.0  # %, simulated, 18 mm object (Fig. 4)
PAPER_RELEASE_GAIN = {35.0: 122.0, 50.0: None, 65.0: 205.0}  # %, measured (Table 2 range)
PAPER_RELEASE_RANGE = (122.0, 205.0)

# Where this model reproduces the paper's contact-force gain on Finger-1: the object
# pressing this far (mm) above the end of the modified adaptor's support (docs/grasping.md,
# "What sets the gain"). At the default height the object presses on the crossbeams that
# the support backs, and the gain is several times larger.
ABOVE_SUPPORT = 18.0

ORIGINAL = Adaptor()
MODIFIED = Adaptor(front_base=PinnedBase(), back_clamp_length=20.0, support_length=60.0)


def with_object(finger: Finger, diameter: float, height: float = 60.0, clearance: float = 0.5):
    """The finger (its loads removed) with a cylinder of that diameter in front of the
    front beam, its centre at `height`, `clearance` mm from the beam's surface."""
    r = 0.5 * diameter
    x = float(finger.front_base[0]) - 0.5 * float(finger.front.thickness) - clearance - r
    obj = Circle((x, height), r)
    return eqx.tree_at(lambda f: (f.loads, f.objects), finger, ((), (obj,)))


def with_adaptor(finger: Finger, adaptor: Adaptor) -> Finger:
    return eqx.tree_at(lambda f: f.adaptor, finger, adaptor)


def _gain(original: GraspSolution, modified: GraspSolution) -> float:
    """The modified adaptor's contact (normal) force over the original's, in % more."""
    a = float(original.contact.normal_force)
    b = float(modified.contact.normal_force)
    return 100.0 * (b / a - 1.0)


@dataclasses.dataclass
class Comparison:
    closing: float
    original: GraspSolution
    modified: GraspSolution
    release: dict  # diameter -> (original ReleaseTrace, modified ReleaseTrace)
    # the same object ABOVE_SUPPORT mm above the support's end: (height, original, modified)
    placed: tuple | None = None

    @property
    def contact_force_gain(self) -> float:
        return _gain(self.original, self.modified)

    @property
    def placed_gain(self) -> float:
        return np.nan if self.placed is None else _gain(*self.placed[1:])

    def release_gain(self, diameter) -> float:
        a, b = self.release[diameter]
        return 100.0 * (b.peak / a.peak - 1.0)


def compare_adaptors(
    finger: Finger,
    *,
    closing: float = 6.0,
    diameter: float = 18.0,
    release_diameters=(35.0, 50.0, 65.0),
    modified: Adaptor = MODIFIED,
    pull_step: float = 2.0,
    friction: float = 0.0,
    progress=None,
    record=None,
) -> Comparison:
    """Original vs modified adaptor: the grasp of a `diameter` cylinder at the same closing
    displacement, and the release (holding) force of larger cylinders.

    record: a JSON file (the CLI's DIR/compare_record.json) rewritten, atomically, after
    every release trace (the long part) with the traces finished so far and the study's
    hash (finger and settings). A run that finds the record of the same study takes its
    traces from it, so an interrupted comparison loses no finished trace (the two grasps
    of the `diameter` cylinder, a few seconds, are solved again); the record of another
    study is replaced."""
    say = progress or (lambda msg: None)
    settings = {
        "closing": float(closing),
        "diameter": float(diameter),
        "release_diameters": [float(d) for d in release_diameters],
        "modified": finger_digest(modified),
        "pull_step": float(pull_step),
        "friction": float(friction),
    }
    digest = study_hash("compare", finger, settings)
    done = {}  # (diameter, adaptor name) -> ReleaseTrace
    if record is not None:
        record = os.fspath(record)
        kept = read_record(record, digest, "compare", say)
        for key, t in (kept or {}).get("release", {}).items():
            d, name = key.split(" ")
            done[float(d), name] = trace_from_record(t)
        if kept is not None:
            n = 2 * len(settings["release_diameters"])
            say(f"continuing {record}: {len(done)} of {n} release traces done")

    def keep():
        n = 2 * len(settings["release_diameters"])
        rec = {"study_hash": digest, "complete": len(done) == n, **settings}
        rec["release"] = {f"{d:g} {name}": trace_record(t) for (d, name), t in done.items()}
        write_record(record, rec)

    base = with_object(finger, diameter)
    say(f"grasp, {diameter:g} mm object, original adaptor")
    g0 = grasp(with_adaptor(base, ORIGINAL), closing)
    say(f"grasp, {diameter:g} mm object, modified adaptor")
    g1 = grasp(with_adaptor(base, modified), closing)
    placed = None
    if modified.support_length is not None:
        height = float(modified.support_length) + ABOVE_SUPPORT
        high = with_object(finger, diameter, height)
        say(f"grasp, {diameter:g} mm object at {height:g} mm, both adaptors")
        placed = (
            height,
            grasp(with_adaptor(high, ORIGINAL), closing),
            grasp(with_adaptor(high, modified), closing),
        )
    release = {}
    for d in release_diameters:
        for name, ad in (("original", ORIGINAL), ("modified", modified)):
            if (float(d), name) in done:
                continue
            say(f"release force, {d:g} mm object, {name} adaptor")
            g = grasp(with_adaptor(with_object(finger, d), ad), closing)
            done[float(d), name] = release_force(g, step=pull_step, friction=friction)
            if record is not None:
                keep()
        release[d] = (done[float(d), "original"], done[float(d), "modified"])
    if record is not None and not os.path.exists(record):
        keep()  # (no trace to run)
    return Comparison(closing, g0, g1, release, placed)


@dataclasses.dataclass
class ClampStudy:
    diameters: np.ndarray
    clamp_lengths: np.ndarray
    support_length: float
    normal_force: np.ndarray  # (diameters, clamp lengths), NaN where a grasp failed
    # What each grasp held equal, and the closing it reached (the set value, or what the
    # actuator force needed).
    closing: np.ndarray | None = None
    actuator_force: float | None = None
    # The holding force (release trace's peak, with `friction`), when the study measures it
    holding_force: np.ndarray | None = None
    friction: float = 0.0

    @property
    def measure(self) -> str:
        """What the best clamp length maximises: "contact force" or "holding force"."""
        return "contact force" if self.holding_force is None else "holding force"

    @property
    def force(self) -> np.ndarray:
        """The measured force, (diameters, clamp lengths): contact or holding."""
        return self.normal_force if self.holding_force is None else self.holding_force

    @property
    def best(self) -> np.ndarray:
        """The clamp length with the largest measured force, per object diameter (NaN
        where no grasp of that diameter gave one)."""
        f = np.where(np.isfinite(self.force), self.force, -np.inf)
        best = self.clamp_lengths[np.argmax(f, axis=1)]
        return np.where(np.isfinite(self.force).any(axis=1), best, np.nan)


def _why_not(g: GraspSolution, actuator_force) -> str:
    """Why a grasp of a study did not converge, in a few words."""
    if g.solution.result == RESULTS.actuator_force_not_reached:
        return (
            f"the actuator force peaks at {float(g.contact.actuator_force):.4g} N, at "
            f"closing {float(g.closing):.4g} mm, below {actuator_force:g} N"
        )
    text = " ".join(RESULTS[g.solution.result].split())
    return text[: text.find(". ") + 1] if ". " in text else text


def clamp_study(
    finger: Finger,
    *,
    diameters=(18.0, 35.0, 50.0, 65.0),
    clamp_lengths=(0.0, 10.0, 20.0, 30.0, 40.0, 50.0),
    support_length: float = 60.0,
    closing: float = 6.0,
    actuator_force: float | None = None,
    holding: bool = False,
    friction: float = 0.0,
    pull_step: float = 2.0,
    progress=None,
    record=None,
    engine=None,
) -> ClampStudy:
    """Contact force of the modified adaptor against the back beam's clamp length l_c
    (support up to `support_length`), for cylinders of several diameters.

    Every grasp closes by `closing` (mm), or, with `actuator_force` (N), by what that
    actuator force needs (a stiffer finger then closes less). holding: measure the
    holding force too (the peak of `release_force` with `friction`, in `pull_step` mm
    steps) and pick the best clamp length by it.

    record: a JSON file (the CLI's DIR/clamp_study.json) rewritten, atomically, after
    every grasp with the cells finished so far and the study's hash (finger and
    settings). A run that finds the record of the same study goes on from it, so an
    interrupted study loses no finished grasp; the record of another study is replaced.
    When the study is complete the record also holds `best_clamp_length`.

    engine: where the grasps run (`finray_jax.engines`; None: this process, one after
    another); each grasp is one task on a `RayEngine`, recorded as it lands."""
    say = progress or (lambda msg: None)
    lc = np.asarray(clamp_lengths, dtype=float)
    dia = np.asarray(diameters, dtype=float)
    _check_clamp_study(dia, lc, support_length, actuator_force, friction)
    settings = {
        "diameters": dia.tolist(),
        "clamp_lengths": lc.tolist(),
        "support_length": float(support_length),
        "closing": None if actuator_force is not None else float(closing),
        "actuator_force": None if actuator_force is None else float(actuator_force),
        "holding": bool(holding),
        "friction": float(friction) if holding else None,
        "pull_step": float(pull_step) if holding else None,
    }
    digest = study_hash("clamp-study", finger, settings)
    shape = (len(dia), len(lc))
    cells = {"normal_force": np.full(shape, np.nan), "closing_reached": np.full(shape, np.nan)}
    if holding:
        cells["holding_force"] = np.full(shape, np.nan)
    solved = np.zeros(shape, bool)
    if record is not None:
        record = os.fspath(record)
        cells, solved = _kept_cells(record, digest, cells, solved, say)
    study = lambda: _clamp_result(dia, lc, settings, cells, friction)

    def keep():
        done = bool(solved.all())
        rec = {"study_hash": digest, "complete": done, **settings, **cells, "solved": solved}
        if done:
            rec["best_clamp_length"] = study().best
        write_record(record, rec)

    work = _ClampWork(finger, dia, lc, float(support_length), actuator_force, closing)
    work = dataclasses.replace(work, holding=holding, friction=friction, pull_step=pull_step)

    for (i, j), value in _grasped_cells(work, solved, engine, say):
        for key in cells:
            cells[key][i, j] = value[key]
        solved[i, j] = True
        if record is not None:
            keep()
    if record is not None and not os.path.exists(record):
        keep()  # (nothing was left to solve)
    return study()


def _check_clamp_study(dia, lc, support_length, actuator_force, friction) -> None:
    """The clamp study's arguments, checked before any grasp (a ValueError names one)."""
    if dia.ndim != 1 or dia.size == 0 or not np.all(np.isfinite(dia) & (dia > 0)):
        raise ValueError(f"diameters must be one or more positive sizes (mm), got {dia.tolist()}")
    if lc.ndim != 1 or lc.size == 0 or not np.all(np.isfinite(lc)):
        raise ValueError(f"clamp_lengths must be one or more lengths (mm), got {lc.tolist()}")
    if np.any(lc > support_length) or np.any(lc < 0):
        raise ValueError(
            f"clamp_lengths must lie in [0, support_length = {support_length}], got {lc.tolist()}"
        )
    if actuator_force is not None and not (np.isfinite(actuator_force) and actuator_force > 0):
        raise ValueError(f"actuator_force must be a positive force (N), got {actuator_force}")
    if not (np.isfinite(friction) and friction >= 0):
        raise ValueError(f"friction must be a non-negative coefficient, got {friction}")


@dataclasses.dataclass(frozen=True)
class _ClampWork:
    """What every grasp of a clamp study shares (an engine sends it to each worker)."""

    finger: Finger
    diameters: np.ndarray
    clamp_lengths: np.ndarray
    support_length: float
    actuator_force: float | None
    closing: float
    holding: bool = False
    friction: float = 0.0
    pull_step: float = 2.0


def _grasped_cells(work: _ClampWork, solved, engine, say):
    """((i, j), values) of each grasp of the study not yet solved, as it lands on the
    engine (each announced as it is taken; one whose task failed is said and left)."""
    dia, lc = work.diameters, work.clamp_lengths

    def todo():
        for i, j in zip(*np.nonzero(~solved)):
            say(f"{dia[i]:g} mm object, l_c = {lc[j]:g} mm")
            yield int(i), int(j)

    landing = (engine or LocalEngine()).map_unordered(clamp_cell, work, todo())
    with contextlib.closing(landing):  # (left early, e.g. Ctrl-C: the engine stops its tasks)
        for landed in landing:
            i, j = landed.item
            where = f"{dia[i]:g} mm object, l_c = {lc[j]:g} mm"
            if landed.error is not None:
                say(f"{where}: its task failed ({landed.error}); run the study again to retry it")
                continue
            if landed.value["why"]:
                say(f"{where}: no grasp ({landed.value['why']})")
            elif work.holding:
                say(f"{dia[i]:g} mm object: release trace (mu = {work.friction:g}) done")
            yield (i, j), landed.value


def clamp_cell(work: _ClampWork, item) -> dict:
    """Grasp (i, j) of a clamp study: diameter i, clamp length j. Its normal force,
    closing reached and holding force (NaN where not measured), and why it failed ("":
    it converged)."""
    i, j = item
    d = float(work.diameters[i])
    ad = Adaptor(
        front_base=PinnedBase(),
        back_clamp_length=float(work.clamp_lengths[j]),
        support_length=work.support_length,
    )
    design = with_adaptor(with_object(work.finger, d), ad)
    if work.actuator_force is None:
        g = grasp(design, closing=work.closing)
    else:
        g = grasp(design, actuator_force=work.actuator_force)
    out = {"normal_force": np.nan, "closing_reached": np.nan, "holding_force": np.nan}
    if not g.converged:
        return {**out, "why": _why_not(g, work.actuator_force)}
    out["normal_force"] = float(g.contact.normal_force)
    out["closing_reached"] = float(g.closing)
    if work.holding:
        out["holding_force"] = release_force(g, step=work.pull_step, friction=work.friction).peak
    return {**out, "why": ""}


def _kept_cells(record: str, digest: str, cells: dict, solved, say):
    """(cells, solved) of the clamp study `digest` as its record keeps them (null: failed
    or not solved), else those given."""
    kept = read_record(record, digest, "clamp-study", say)
    if kept is None:
        return cells, solved
    cells = {key: np.asarray(kept[key], dtype=float) for key in cells}
    solved = np.asarray(kept["solved"], dtype=bool)
    say(f"continuing {record}: {int(solved.sum())} of {solved.size} grasps done")
    return cells, solved


def _clamp_result(dia, lc, settings: dict, cells: dict, friction) -> ClampStudy:
    """The clamp study as far as its cells go (copies of them)."""
    return ClampStudy(
        dia,
        lc,
        settings["support_length"],
        cells["normal_force"].copy(),
        closing=cells["closing_reached"].copy(),
        actuator_force=settings["actuator_force"],
        holding_force=cells["holding_force"].copy() if settings["holding"] else None,
        friction=float(friction),
    )
