"""The paper's comparisons on the public API: original vs modified adaptor, and the
back-beam clamp length against object size (Sheikh Sofla et al. 2025, Figs. 4-5, Table 2).

Nothing here is tuned to the paper's numbers: the fingers are our assumed Finger-1
(examples/finger1.toml) and the paper's figures are printed beside ours for context.
"""

import dataclasses
import hashlib
import json
import os

import equinox as eqx
import jax
import numpy as np

from . import io as fio
from ._finger import Adaptor, Finger
from ._grasp import GraspSolution, grasp, release_force
from ._objects import Circle

# The paper's figures (quoted for comparison only).
PAPER_CONTACT_FORCE_GAIN = 260.0  # %, simulated, 18 mm object (Fig. 4)
PAPER_RELEASE_GAIN = {35.0: 122.0, 50.0: None, 65.0: 205.0}  # %, measured (Table 2 range)
PAPER_RELEASE_RANGE = (122.0, 205.0)

ORIGINAL = Adaptor()
MODIFIED = Adaptor(front_base="pinned", back_clamp_length=20.0, support_length=60.0)


def with_object(finger: Finger, diameter: float, height: float = 60.0, clearance: float = 0.5):
    """The finger (its loads removed) with a cylinder of that diameter in front of the
    front beam, its centre at `height`, `clearance` mm from the beam's surface."""
    r = 0.5 * diameter
    x = float(finger.front_base[0]) - 0.5 * float(finger.front.thickness) - clearance - r
    obj = Circle((x, height), r)
    return eqx.tree_at(lambda f: (f.loads, f.objects), finger, ((), (obj,)))


def with_adaptor(finger: Finger, adaptor: Adaptor) -> Finger:
    return eqx.tree_at(lambda f: f.adaptor, finger, adaptor)


@dataclasses.dataclass
class Comparison:
    closing: float
    original: GraspSolution
    modified: GraspSolution
    release: dict  # diameter -> (original ReleaseTrace, modified ReleaseTrace)

    @property
    def contact_force_gain(self) -> float:
        a = float(self.original.contact.normal_force)
        b = float(self.modified.contact.normal_force)
        return 100.0 * (b / a - 1.0)

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
) -> Comparison:
    """Original vs modified adaptor: the grasp of a `diameter` cylinder at the same closing
    displacement, and the release (holding) force of larger cylinders."""
    say = progress or (lambda msg: None)
    base = with_object(finger, diameter)
    say(f"grasp, {diameter:g} mm object, original adaptor")
    g0 = grasp(with_adaptor(base, ORIGINAL), closing)
    say(f"grasp, {diameter:g} mm object, modified adaptor")
    g1 = grasp(with_adaptor(base, modified), closing)
    release = {}
    for d in release_diameters:
        traces = []
        for name, ad in (("original", ORIGINAL), ("modified", modified)):
            say(f"release force, {d:g} mm object, {name} adaptor")
            g = grasp(with_adaptor(with_object(finger, d), ad), closing)
            traces.append(release_force(g, step=pull_step, friction=friction))
        release[d] = tuple(traces)
    return Comparison(closing, g0, g1, release)


@dataclasses.dataclass
class ClampStudy:
    diameters: np.ndarray
    clamp_lengths: np.ndarray
    support_length: float
    normal_force: np.ndarray  # (diameters, clamp lengths), NaN where a grasp failed

    @property
    def best(self) -> np.ndarray:
        """The clamp length with the largest contact force, per object diameter."""
        f = np.where(np.isfinite(self.normal_force), self.normal_force, -np.inf)
        return self.clamp_lengths[np.argmax(f, axis=1)]


class StudyRecordError(ValueError):
    """A study's record file that cannot be read as one (the CLI reports it, no traceback)."""


# Bump when a record's cells would mean something else (it keys the record's hash).
_CLAMP_RECORD_VERSION = 1


def finger_digest(finger: Finger) -> str:
    """A hash of everything a finger holds (structure, settings and values), the same in
    every process: two fingers with the same digest solve alike."""
    leaves, treedef = jax.tree_util.tree_flatten(finger)
    h = hashlib.sha256(str(treedef).encode())
    for leaf in leaves:
        a = np.asarray(leaf)
        h.update(f"{a.dtype}{a.shape}".encode() + a.tobytes())
    return h.hexdigest()


def _read_clamp_record(path, digest):
    """The finished cells (force, solved) of the study `digest` kept in `path`, or None
    when the file is missing or holds another study (another finger or settings)."""
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            rec = json.load(fh)
    except (OSError, ValueError) as exc:
        raise StudyRecordError(
            f"{path}: not a clamp-study record ({exc}); move it away to start afresh"
        ) from None
    if not isinstance(rec, dict) or rec.get("study_hash") != digest:
        return None
    force = np.asarray(rec["normal_force"], dtype=float)  # (null: failed or not solved)
    return force, np.asarray(rec["solved"], dtype=bool)


def clamp_study(
    finger: Finger,
    *,
    diameters=(18.0, 35.0, 50.0, 65.0),
    clamp_lengths=(0.0, 10.0, 20.0, 30.0, 40.0, 50.0),
    support_length: float = 60.0,
    closing: float = 6.0,
    progress=None,
    record=None,
) -> ClampStudy:
    """Contact force of the modified adaptor against the back beam's clamp length l_c
    (support up to `support_length`), for cylinders of several diameters.

    record: a JSON file (the CLI's DIR/clamp_study.json) rewritten, atomically, after
    every grasp with the cells finished so far and the study's hash (finger and
    settings). A run that finds the record of the same study goes on from it, so an
    interrupted study loses no finished grasp; the record of another study is replaced.
    When the study is complete the record also holds `best_clamp_length`."""
    say = progress or (lambda msg: None)
    lc = np.asarray(clamp_lengths, dtype=float)
    dia = np.asarray(diameters, dtype=float)
    if np.any(lc > support_length) or np.any(lc < 0):
        raise ValueError(
            f"clamp_lengths must lie in [0, support_length = {support_length}], got {lc.tolist()}"
        )
    force = np.full((len(dia), len(lc)), np.nan)
    solved = np.zeros(force.shape, bool)
    settings = {
        "version": _CLAMP_RECORD_VERSION,
        "finger": finger_digest(finger),
        "diameters": dia.tolist(),
        "clamp_lengths": lc.tolist(),
        "support_length": float(support_length),
        "closing": float(closing),
    }
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()
    if record is not None:
        record = os.fspath(record)
        kept = _read_clamp_record(record, digest)
        if kept is not None:
            force, solved = kept
            say(f"continuing {record}: {int(solved.sum())} of {solved.size} grasps done")
        elif os.path.exists(record):
            say(f"{record} holds another study (finger or settings differ): starting afresh")

    def study():
        return ClampStudy(dia, lc, float(support_length), force.copy())

    def keep():
        done = bool(solved.all())
        rec = {
            "study_hash": digest,
            "complete": done,
            "diameters": dia,
            "clamp_lengths": lc,
            "support_length": float(support_length),
            "closing": float(closing),
            "normal_force": force,
            "solved": solved,
        }
        if done:
            rec["best_clamp_length"] = study().best
        parent = os.path.dirname(record)
        if parent:
            os.makedirs(parent, exist_ok=True)
        fio._write_atomic(record, fio._json_text(fio._plain(rec)) + "\n")

    for i, d in enumerate(dia):
        base = with_object(finger, d)
        for j, l in enumerate(lc):
            if solved[i, j]:
                continue
            ad = Adaptor(front_base="pinned", back_clamp_length=l, support_length=support_length)
            say(f"{d:g} mm object, l_c = {l:g} mm")
            g = grasp(with_adaptor(base, ad), closing)
            force[i, j] = float(g.contact.normal_force) if g.converged else np.nan
            solved[i, j] = True
            if record is not None:
                keep()
    if record is not None and not os.path.exists(record):
        keep()  # (nothing was left to solve)
    return study()
