"""Optimisation files (TOML, docs/optimize-format.md): how they are read into the problem
they describe (`OptimizeProblem`, in `_optimize_problem`; the checks beyond the file's
syntax are `_optimize_checks`). `load_optimize(path)` raises OptimizeError naming the key
and value."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

from . import io as fio
from ._finger import validate_finger
from ._objective import AGGREGATES, OBJECTIVES
from ._objective import CONSTRAINTS as CONSTRAINTS
from ._optimize_checks import check_bounds, check_clamp_bounds, check_objects_ahead
from ._optimize_problem import DesignVar, OptimizeProblem
from .design import DesignError, check_design_names, get_design

__all__ = ["DesignVar", "OptimizeError", "OptimizeProblem", "load_optimize", "loads_optimize"]

OPTIMIZERS = ("adam", "sgd")
FORMAT = 1  # bump when the meaning of an optimisation file or its CSV changes


class OptimizeError(fio.FingerFileError):
    """An invalid optimisation file, or an output directory that holds another run."""


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
    kw = _grasp_keys(doc, r, finger, settings.grasp)
    obj = r.table(
        doc.get("objects", {}),
        "objects",
        ("diameters", "height", "clearance", "aggregate", "temperature"),
    )
    kw.update(_object_keys(doc, r, finger, obj))
    kw["design"] = _design(doc, r, finger)
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
    kw.update(_optimizer_keys(doc, r))

    problem = OptimizeProblem(source, finger_path, finger, settings, **kw)
    _check_initial_design(problem, r, doc, obj, cons)
    key = {
        "format": FORMAT,
        "finger_sha256": finger_hash,
        **{k: (list(v) if isinstance(v, tuple) else v) for k, v in kw.items() if k != "design"},
        "design": [[d.name, d.lo, d.hi, d.initial] for d in kw["design"]],
    }
    # iterations and tolerance may change between runs: a longer run continues the same one
    for k in ("iterations", "tolerance", "patience"):
        key.pop(k)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
    return dataclasses.replace(problem, digest=digest)


def _grasp_keys(doc, r, finger, gs) -> dict:
    """objective, friction and closing, and the closing direction, symmetry and pull step
    of the finger file's [grasp] table `gs` (None: the defaults)."""
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
    return kw


def _object_keys(doc, r, finger, obj: dict) -> dict:
    """The [objects] table `obj`: cylinders of several diameters placed by the optimiser
    (else the finger file's one object), and how their forces are aggregated."""
    kw = {}
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
    return kw


def _design(doc, r, finger) -> tuple[DesignVar, ...]:
    """The [[design]] tables: each optimised design value with its bounds and initial
    value (default: the finger's)."""
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
        check_bounds(finger, name, lo, hi, optimised, r.error, f"{p}.bounds", tbl["bounds"])
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
    check_clamp_bounds(finger, tuple(design), r.error)
    return tuple(design)


def _optimizer_keys(doc, r) -> dict:
    """The [optimizer] and [penalty] tables."""
    o = r.table(
        doc.get("optimizer", {}),
        "optimizer",
        ("kind", "learning_rate", "iterations", "tolerance", "patience"),
    )
    kw = {}
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
    return kw


def _check_initial_design(problem: OptimizeProblem, r, doc, obj: dict, cons: dict) -> None:
    """The initial design is a valid finger, its objects lie ahead of it, and its beams
    are no thinner than constraints.min_thickness."""
    x0f = problem.designed(problem.x0)
    try:
        validate_finger(x0f)
    except Exception as e:  # noqa: BLE001 - reported with the file's name
        raise r.error("design", f"the initial design is invalid: {e}") from None
    check_objects_ahead(problem, r, doc, obj)
    if "min_thickness" in problem.constraints:
        t = [float(x0f.front.thickness), float(x0f.back.thickness)]
        t += np.asarray(x0f.crossbeams.thickness).tolist()
        if min(t) < problem.constraints["min_thickness"]:
            raise r.error(
                "constraints.min_thickness",
                f"the initial design has a beam of thickness {min(t)!r} mm, below the limit",
                cons["min_thickness"],
            )
