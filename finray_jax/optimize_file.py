"""Optimisation files (TOML, docs/optimize-format.md): the problem they describe and
how they are read. `load_optimize(path)` raises OptimizeError naming the key and value."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re

import equinox as eqx
import numpy as np

from . import io as fio
from ._finger import Finger, FingerError, beam_lengths, validate_finger
from ._geometry import main_beam_samples
from ._grasp import check_objects, unit_direction
from .design import DesignError, check_design_names, get_design
from .design import set_design as _set_design
from .studies import with_object

__all__ = ["DesignVar", "OptimizeError", "OptimizeProblem", "load_optimize", "loads_optimize"]

from ._objective import AGGREGATES, CONSTRAINTS, OBJECTIVES

OPTIMIZERS = ("adam", "sgd")
FORMAT = 1  # bump when the meaning of an optimisation file or its CSV changes


class OptimizeError(fio.FingerFileError):
    """An invalid optimisation file, or an output directory that holds another run."""


# --------------------------------------------------------------------------------------
# The problem
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DesignVar:
    """One optimised design value, kept in [lo, hi] (initial: the finger's value)."""

    name: str
    lo: float
    hi: float
    initial: float


@dataclasses.dataclass(frozen=True)
class OptimizeProblem:
    """A parsed optimisation file (see docs/optimize-format.md)."""

    source: str
    finger_path: str
    finger: Finger
    settings: fio.SolveSettings
    objective: str = "contact_force"
    friction: float = 0.0
    closing: float = 6.0
    direction: tuple = (-1.0, 0.0)
    pull_direction: tuple = (0.0, 1.0)
    symmetric: bool = True
    pull_step: float = 2.0
    diameters: tuple | None = None
    object_height: float = 60.0
    clearance: float = 0.5
    aggregate: str = "mean"
    temperature: float = 0.02
    design: tuple = ()
    constraints: dict = dataclasses.field(default_factory=dict)
    optimizer: str = "adam"
    learning_rate: float = 0.1
    iterations: int = 30
    tolerance: float = 1e-4
    patience: int = 3
    penalty_weight: float = 100.0
    penalty_shift: float = 0.01
    digest: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.design)

    @property
    def lo(self) -> np.ndarray:
        return np.asarray([d.lo for d in self.design], float)

    @property
    def hi(self) -> np.ndarray:
        return np.asarray([d.hi for d in self.design], float)

    @property
    def x0(self) -> np.ndarray:
        return np.asarray([d.initial for d in self.design], float)

    def object_fingers(self) -> list[Finger]:
        """The base finger of every object (its design values at the initial design)."""
        base = _set_design(self.finger, dict(zip(self.names, self.x0.tolist())))
        if self.diameters is None:
            return [base]
        return [
            with_object(base, d, height=self.object_height, clearance=self.clearance)
            for d in self.diameters
        ]

    def active_constraints(self) -> tuple[str, ...]:
        n_cb = self.finger.n_crossbeams
        out = [c for c in CONSTRAINTS if c in self.constraints]
        if n_cb >= 2 and any(n.startswith("crossbeams.") for n in self.names):
            out.append("crossing")  # always, when the layout moves
        return tuple(c for c in CONSTRAINTS if c in out)

    def designed(self, x) -> Finger:
        """The base finger with design values x (one per [[design]] entry)."""
        return _set_design(self.finger, dict(zip(self.names, np.asarray(x, float).tolist())))


# --------------------------------------------------------------------------------------
# Reading optimisation files
# --------------------------------------------------------------------------------------

_TOP = (
    "finger",
    "objective",
    "friction",
    "closing",
    "objects",
    "design",
    "constraints",
    "optimizer",
    "penalty",
)
_HELP = {
    "finger": " (path of the base finger file with [[objects]], relative to this file)",
    "design": " (one [[design]] table per optimised value, with name and bounds)",
    "name": " (a design value, e.g. adaptor.back_clamp_length or crossbeams.front_s[2])",
    "bounds": " ([lo, hi])",
}


def loads_optimize(text: str, *, source: str = "<string>", base_dir: str = ".") -> OptimizeProblem:
    """Read an optimisation from TOML text; the finger path is relative to `base_dir`."""
    return fio.loads_study(text, _parse, OptimizeError, source, base_dir)


def load_optimize(path) -> OptimizeProblem:
    """Read an optimisation file. Raises OptimizeError naming the key and the value."""
    return fio.load_study(path, loads_optimize, "optimisation", OptimizeError)


def _parse(doc, r, source, base_dir) -> OptimizeProblem:
    r.table(doc, "", _TOP)
    fio.require_keys(r, doc, "", ("finger", "design"), _HELP)
    finger, settings, finger_path, finger_hash = fio.base_finger(doc, r, base_dir)
    gs = settings.grasp
    kw = {}
    kw["objective"] = r.string(doc.get("objective", "contact_force"), "objective", OBJECTIVES)
    # The release's friction: this file's, else the finger file's [contact] friction (as
    # `finray grasp --release` and grasp sweeps use it).
    friction = doc.get("friction", None)
    if friction is None:
        friction = float(finger.contact.friction) if kw["objective"] == "holding_force" else 0.0
    kw["friction"] = r.number(friction, "friction", nonnegative=True)
    if kw["friction"] > 0 and kw["objective"] != "holding_force":
        raise r.error(
            "friction",
            'is for objective = "holding_force" (closing is frictionless)',
            doc["friction"],
        )
    closing = doc.get("closing", None if gs is None else gs.closing)
    if closing is None:
        raise r.error(
            "closing",
            "missing: give closing (mm) here or [grasp] closing in the "
            "finger file (an actuator force is not supported by the optimiser)",
        )
    kw["closing"] = r.number(closing, "closing", positive=True)
    if gs is not None:
        kw.update(direction=gs.direction, symmetric=gs.symmetric, pull_step=gs.pull_step)

    obj = r.table(
        doc.get("objects", {}),
        "objects",
        ("diameters", "height", "clearance", "aggregate", "temperature"),
    )
    if "diameters" in obj:
        ds = obj["diameters"]
        if not isinstance(ds, list) or not ds:
            raise r.error("objects.diameters", "expected a non-empty array of diameters (mm)", ds)
        kw["diameters"] = tuple(
            r.number(d, f"objects.diameters[{i}]", positive=True) for i, d in enumerate(ds)
        )
        kw["object_height"] = r.number(obj.get("height", 60.0), "objects.height")
        kw["clearance"] = r.number(obj.get("clearance", 0.5), "objects.clearance", positive=True)
    else:
        for key in ("height", "clearance"):
            if key in obj:
                raise r.error(
                    f"objects.{key}",
                    "is for objects.diameters (cylinders placed by the optimiser)",
                    obj[key],
                )
        if len(finger.objects) != 1:
            raise r.error(
                "finger",
                f"the finger file has {len(finger.objects)} objects; the "
                "optimiser needs exactly one, or objects.diameters",
                doc["finger"],
            )
    kw["aggregate"] = r.string(obj.get("aggregate", "mean"), "objects.aggregate", AGGREGATES)
    kw["temperature"] = r.number(obj.get("temperature", 0.02), "objects.temperature", positive=True)

    design = []
    tables = r.array_of_tables(doc["design"], "design")
    optimised = {t.get("name") for t in tables if isinstance(t.get("name"), str)}
    for i, tbl in enumerate(tables):
        p = f"design[{i}]"
        r.table(tbl, p, ("name", "bounds", "initial"))
        fio.require_keys(r, tbl, p, ("name", "bounds"), _HELP)
        name = r.string(tbl["name"], f"{p}.name")
        try:
            check_design_names(finger, [name], scalar=True)
            current = float(get_design(finger, [name])[name])
        except DesignError as e:
            raise r.error(f"{p}.name", str(e), name) from None
        if name in (d.name for d in design):
            raise r.error(f"{p}.name", "listed twice", name)
        lo, hi = r.vector(tbl["bounds"], f"{p}.bounds", 2, "[lo, hi]")
        if not lo < hi:
            raise r.error(f"{p}.bounds", "needs lo < hi", tbl["bounds"])
        _check_bounds(finger, name, lo, hi, optimised, r.error, f"{p}.bounds", tbl["bounds"])
        x0 = r.number(tbl["initial"], f"{p}.initial") if "initial" in tbl else current
        if not lo < x0 < hi:
            what = f"{p}.initial" if "initial" in tbl else f"{p}.bounds"
            val = tbl["initial"] if "initial" in tbl else tbl["bounds"]
            raise r.error(
                what,
                f"the initial value {x0!r} of {name} must lie strictly inside "
                f"the bounds [{lo!r}, {hi!r}]",
                val,
            )
        design.append(DesignVar(name, lo, hi, x0))
    if not design:
        raise r.error("design", "needs at least one [[design]] table" + _HELP["design"])
    kw["design"] = tuple(design)
    names = [d.name for d in design]
    if "adaptor.support_length" in names or "adaptor.back_clamp_length" in names:
        if finger.adaptor.support_length is not None:
            lc = next((d for d in design if d.name == "adaptor.back_clamp_length"), None)
            ls = next((d for d in design if d.name == "adaptor.support_length"), None)
            lc_hi = float(finger.adaptor.back_clamp_length) if lc is None else lc.hi
            ls_lo = float(finger.adaptor.support_length) if ls is None else ls.lo
            if lc_hi > ls_lo:
                raise r.error(
                    "design",
                    f"the bounds let the clamp (up to {lc_hi!r} mm) pass "
                    f"the support's end (from {ls_lo!r} mm): keep "
                    "adaptor.back_clamp_length <= adaptor.support_length",
                )

    cons = r.table(
        doc.get("constraints", {}),
        "constraints",
        ("min_thickness", "min_spacing", "max_strain", "max_pressure"),
    )
    kw["constraints"] = {
        key: r.number(
            v, f"constraints.{key}", positive=key != "min_spacing", nonnegative=key == "min_spacing"
        )
        for key, v in cons.items()
    }

    o = r.table(
        doc.get("optimizer", {}),
        "optimizer",
        ("kind", "learning_rate", "iterations", "tolerance", "patience"),
    )
    kw["optimizer"] = r.string(o.get("kind", "adam"), "optimizer.kind", OPTIMIZERS)
    kw["learning_rate"] = r.number(
        o.get("learning_rate", 0.1), "optimizer.learning_rate", positive=True
    )
    kw["iterations"] = r.integer(o.get("iterations", 30), "optimizer.iterations", minimum=1)
    kw["tolerance"] = r.number(o.get("tolerance", 1e-4), "optimizer.tolerance", nonnegative=True)
    kw["patience"] = r.integer(o.get("patience", 3), "optimizer.patience", minimum=1)
    pen = r.table(doc.get("penalty", {}), "penalty", ("weight", "shift"))
    kw["penalty_weight"] = r.number(pen.get("weight", 100.0), "penalty.weight", positive=True)
    kw["penalty_shift"] = r.number(pen.get("shift", 0.01), "penalty.shift", nonnegative=True)

    problem = OptimizeProblem(source, finger_path, finger, settings, **kw)
    x0f = problem.designed(problem.x0)
    try:
        validate_finger(x0f)
    except Exception as e:  # noqa: BLE001 - reported with the file's name
        raise r.error("design", f"the initial design is invalid: {e}") from None
    _check_objects_ahead(problem, r, doc, obj)
    if "min_thickness" in kw["constraints"]:
        t = [float(x0f.front.thickness), float(x0f.back.thickness)]
        t += np.asarray(x0f.crossbeams.thickness).tolist()
        if min(t) < kw["constraints"]["min_thickness"]:
            raise r.error(
                "constraints.min_thickness",
                f"the initial design has a beam of thickness {min(t)!r} mm, below the limit",
                cons["min_thickness"],
            )
    key = {
        "format": FORMAT,
        "finger_sha256": finger_hash,
        **{k: (list(v) if isinstance(v, tuple) else v) for k, v in kw.items() if k != "design"},
        "design": [[d.name, d.lo, d.hi, d.initial] for d in design],
    }
    # iterations and tolerance may change between runs: a longer run continues the same one
    for k in ("iterations", "tolerance", "patience"):
        key.pop(k)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
    return dataclasses.replace(problem, digest=digest)


def _check_bounds(finger: Finger, name, lo, hi, optimised, error, path, value) -> None:
    """Every value in a design value's [lo, hi] must give a valid finger (the other
    values as in the finger file): checked at lo and at hi with the finger's validation
    (objects aside: where they sit is the grasp's business). Every rule of the validation
    that one value can break holds on an interval of it (a positive thickness, depth or E;
    a clamp in [0, beam length); an attachment inside its beam; nu in (-1, 0.5); ...), so
    the two ends decide for those. Not for every rule: the beam lengths are not monotone
    in the tip's coordinates (a tip.z range across a base), nor the beams' meeting in a
    curvature, and such ranges can pass with an invalid value inside. Crossbeams out of
    order are left to the `crossing` constraint when the neighbour's attachment on that
    beam is optimised too (`optimised`: the names in the file); past a neighbour that
    stays put, they are refused. Likewise the clamp against the support's end when both
    are optimised."""
    # (the clamp against the support's end, when both move, is checked on their bounds
    # together after every [[design]] table is read: here the other one stands aside)
    if name == "adaptor.back_clamp_length" and "adaptor.support_length" in optimised:
        finger = eqx.tree_at(lambda f: f.adaptor.support_length, finger, None)
    if name == "adaptor.support_length" and "adaptor.back_clamp_length" in optimised:
        finger = eqx.tree_at(lambda f: f.adaptor.back_clamp_length, finger, 0.0)
    for which, x in (("lo", lo), ("hi", hi)):
        designed = dataclasses.replace(_set_design(finger, {name: x}), objects=())
        try:
            validate_finger(designed)
        except FingerError as e:
            if _crossing_left_to_the_constraint(designed, name, optimised):
                continue
            raise error(
                path,
                f"{name} = {x!r} (the bound {which}) makes the finger invalid: "
                f"{fio.toml_paths(str(e))}; every value in [lo, hi] must give a valid finger",
                value,
            ) from None


_POSITION = re.compile(r"crossbeams\.(front_s|back_s|angle)\[(\d+)\]")


def _crossing_left_to_the_constraint(finger: Finger, name: str, names) -> bool:
    """True when the only fault of `finger` (made by moving crossbeam value `name`) is
    crossbeams out of order on a beam where the other crossbeam's attachment is
    optimised too: the `crossing` constraint keeps the two apart, the bounds need not."""
    m = _POSITION.fullmatch(name)
    if m is None:
        return False
    c = int(m[2])
    fs = np.asarray(finger.crossbeams.front_s, float)
    bs = np.asarray(finger.crossbeams.back_s, float)
    lf, lb = beam_lengths(finger)
    if not (np.all((fs > 0) & (fs < lf)) and np.all((bs > 0) & (bs < lb))):
        return False  # (an attachment off its beam, or not finite: a fault of its own)
    crossed = False
    for k in range(len(fs) - 1):
        df, db = fs[k + 1] - fs[k], bs[k + 1] - bs[k]
        if df > 0 and db > 0:
            continue
        crossed = True
        if c not in (k, k + 1):
            return False
        other = k + 1 if c == k else k
        if df <= 0 and f"crossbeams.front_s[{other}]" not in names:
            return False
        moved_back = {f"crossbeams.back_s[{other}]", f"crossbeams.angle[{other}]"}
        if db <= 0 and not moved_back & set(names):
            return False
    return crossed


def _check_objects_ahead(problem: OptimizeProblem, r, doc, obj: dict) -> None:
    """The grasp's checks of its objects at the initial design (in reach of the finger,
    ahead of it along the closing direction, clear of the beams), before any solve:
    otherwise the first grasp fails on them, naming a generated objects[0]."""
    try:
        w = unit_direction(problem.direction, "direction")
    except FingerError as e:
        raise r.error("finger", f"{problem.finger_path}: [grasp] {e}", doc["finger"]) from None
    for i, finger in enumerate(problem.object_fingers()):
        try:
            check_objects(finger, w)
        except FingerError as e:
            problem_text = str(e)
            if problem.diameters is None:  # the finger file's own object
                raise r.error(
                    "finger", f"{problem.finger_path}: {problem_text}", doc["finger"]
                ) from None
            what = re.sub(r"^objects\[0\] \(circle\) ", "", problem_text)
            placed = (
                f"the cylinder of objects.diameters[{i}] = {problem.diameters[i]:g} mm "
                f"({problem.clearance:g} mm clear of the front beam)"
            )
            if "lies behind" in what:  # the closing direction's fault, not the height's
                raise r.error(
                    "finger",
                    f"{placed} {what} (the closing direction of the finger file's [grasp])",
                    doc["finger"],
                ) from None
            if "outside the reach" in what:  # in heights too, which the user gave
                z = np.asarray(main_beam_samples(finger, 201)[1])[..., 1]
                rad = 0.5 * problem.diameters[i]
                what += (
                    f" (the cylinder spans z = {problem.object_height - rad:g} to "
                    f"{problem.object_height + rad:g} mm, the beams z = {z.min():.4g} to "
                    f"{z.max():.4g} mm)"
                )
            given = "height" in obj
            raise r.error(
                "objects.height",
                f"{placed}, placed at this height, {what}"
                + ("" if given else "; this is the default height: set objects.height"),
                obj["height"] if given else problem.object_height,
            ) from None
