"""Finger files (TOML) and results (JSON).

This module sits on the public API: it reads a finger file into a `Finger` plus the
numerical settings of the solve, writes a finger back to TOML, and turns a `Solution`
into plain JSON-able data. The physics core never imports it.

Format reference: docs/finger-format.md. Units: mm, N, MPa; points are (x, z).
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import math
import os
import re
import tomllib
from importlib import resources
from typing import Any

import diffrax as dfx
import numpy as np

from ._contact import Contact
from ._errors import FingerError
from ._finger import (
    Adaptor,
    Crossbeams,
    DistributedLoad,
    Finger,
    Material,
    PointLoad,
    Section,
    check_mode_carries_loads,
    validate_finger,
)
from ._objects import OBJECT_KINDS
from ._options import LINEAR_SOLVERS, SolverOptions
from ._rod import Integrator
from ._version import __version__

__all__ = [
    "FingerFileError",
    "SolveSettings",
    "load_finger",
    "loads_finger",
    "finger_to_toml",
    "solution_to_dict",
    "limit_to_dict",
    "write_json",
    "INTEGRATORS",
    "UNITS",
]

UNITS = {
    "length": "mm",
    "force": "N",
    "moment": "N mm",
    "modulus": "MPa",
    "angle": "rad",
}

#: Integrator names accepted in [solver] integrator, and their diffrax classes.
INTEGRATORS = {
    "Tsit5": dfx.Tsit5,
    "Dopri5": dfx.Dopri5,
    "Bosh3": dfx.Bosh3,
    "Heun": dfx.Heun,
}

MODES = ("auto", "planar", "spatial")
BASE_KINDS = ("clamped", "pinned", "free")
TORSION_KINDS = ("paper", "rectangle")
LOAD_KINDS = ("point", "distributed")


class FingerFileError(ValueError):
    """An invalid finger file. The message names the file, the key path and the value."""


@dataclasses.dataclass(frozen=True)
class SolveSettings:
    """How a finger file asks to be solved ([solver] and [meta] tables).

    mode: "auto" | "planar" | "spatial" (see `solve_finger`).
    integrator, options: passed to `solve_finger` / `limit_load` unchanged.
    name, description: free text from [meta].
    """

    mode: str = "auto"
    integrator: Integrator = dataclasses.field(default_factory=Integrator)
    options: SolverOptions = dataclasses.field(default_factory=SolverOptions)
    name: str = ""
    description: str = ""
    grasp: GraspSettings | None = None

    def solve_kwargs(self) -> dict:
        """Keyword arguments for `solve_finger` and `limit_load`."""
        return {"mode": self.mode, "integrator": self.integrator, "options": self.options}


@dataclasses.dataclass(frozen=True)
class GraspSettings:
    """The [grasp] table: how to close the finger on its objects (see `grasp`).

    closing (mm) or actuator_force (N); direction: the closing direction (x, z) of the
    finger's base; symmetric: a two-finger parallel grasp; pull_step: the step (mm) of
    the release-force trace.
    """

    closing: float | None = None
    actuator_force: float | None = None
    direction: tuple = (-1.0, 0.0)
    symmetric: bool = True
    pull_step: float = 2.0

    def grasp_kwargs(self) -> dict:
        return {
            "closing": self.closing,
            "actuator_force": self.actuator_force,
            "direction": self.direction,
            "symmetric": self.symmetric,
        }


# --------------------------------------------------------------------------------------
# Reading: small typed accessors that name the key path in every error.
# --------------------------------------------------------------------------------------


MAX_STEPS = 10_000  # solver.steps: more is a typo (memory and compile time grow with it)
MAX_ITERATIONS = 1_000_000  # the solver's integer options (iteration and step counts)


# Words users write for a choice, by what they mean (a spelling match would send
# "fixed" to "pinned").
_SYNONYMS = {
    "fixed": ("clamped",),
    "clamp": ("clamped",),
    "built-in": ("clamped",),
    "encastre": ("clamped",),
    "hinge": ("pinned",),
    "hinged": ("pinned",),
    "pin": ("pinned",),
    "released": ("free",),
    "none": ("free",),
    "2d": ("planar",),
    "plane": ("planar",),
    "in-plane": ("planar",),
    "3d": ("spatial",),
    "3-d": ("spatial",),
}


def _show(v) -> str:
    """A value as the user wrote it in TOML."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_show(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_show(x)}" for k, x in v.items()) + "}"
    return repr(v)


def _type_name(v) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "a table"
    return type(v).__name__


class _Reader:
    def __init__(self, source: str):
        self.source = source
        # The document and its allowed top-level keys, once its top-level table is
        # checked: a top-level key written after a [table] is, in TOML, a key of that
        # table, and the messages about it say so (when the document has no such key at
        # its top level: a crossbeam's `front` is a misspelt front_s, not the [front]).
        self.doc: dict = {}
        self.top_keys: tuple = ()

    def error(self, path: str, problem: str, value=dataclasses.MISSING) -> FingerFileError:
        if value is dataclasses.MISSING:
            return FingerFileError(f"{self.source}: {path}: {problem}")
        return FingerFileError(f"{self.source}: {path} = {_show(value)}: {problem}")

    # -- tables --------------------------------------------------------------------

    def table(self, value, path: str, allowed, required=(), hints=None) -> dict:
        """Check that `value` is a table with only `allowed` keys and all `required` ones."""
        if not isinstance(value, dict):
            raise self.error(path, f"expected a table [{path}], got {_type_name(value)}", value)
        if not path:
            self.doc, self.top_keys = value, tuple(allowed)
        hints = hints or {}
        for key in value:
            if key not in allowed:
                full = f"{path}.{key}" if path else key
                if key in hints:
                    raise self.error(full, hints[key], value[key])
                if path and key in self.top_keys and key not in self.doc:
                    hint = (
                        f" ('{key}' is a top-level key, and {_BEFORE_TABLES}: TOML reads it "
                        f"as {full} here)"
                    )
                else:
                    close = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
                    hint = f" (did you mean '{close[0]}'?)" if close else ""
                where = f"in [{path}]" if path else "at the top level"
                known = ", ".join(allowed)
                raise self.error(
                    full, f"unknown key {where}{hint}; known keys: {known}", value[key]
                )
        for key in required:
            if key not in value:
                full = f"{path}.{key}" if path else key
                more = _KEY_HELP.get(key, "") + self.misplaced(path, key)
                raise self.error(full, "missing required key" + more)
        return value

    def misplaced(self, path: str, key: str) -> str:
        """For a missing top-level key that the document has inside one of its tables
        (written after that table's header), a hint saying so; else ""."""
        if path:
            return ""
        for name, tbl in self.doc.items():
            if isinstance(tbl, list) and tbl and all(isinstance(x, dict) for x in tbl):
                name, tbl = f"{name}[{len(tbl) - 1}]", tbl[-1]
            if isinstance(tbl, dict) and key in tbl:
                return (
                    f" (the file has {name}.{key}: {_BEFORE_TABLES}, or TOML reads it as a "
                    f"key of the table above it)"
                )
        return ""

    def array_of_tables(self, value, path: str) -> list:
        if isinstance(value, dict):
            raise self.error(
                path,
                f"expected an array of tables written [[{path}]] (one per entry), got a "
                f"single table [{path}]",
            )
        if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
            raise self.error(path, f"expected an array of tables [[{path}]]", value)
        return value

    # -- scalars -------------------------------------------------------------------

    def number(self, value, path: str, *, positive=False, nonnegative=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(path, f"expected a number, got {_type_name(value)}", value)
        try:
            x = float(value)
        except OverflowError:  # an integer beyond the float range
            x = math.inf
        if not math.isfinite(x):
            raise self.error(path, "must be a finite number", value)
        if positive and x <= 0:
            raise self.error(path, "must be positive", value)
        if nonnegative and x < 0:
            raise self.error(path, "must not be negative", value)
        return x

    def integer(self, value, path: str, *, minimum=None, maximum=None, why="") -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(path, f"expected an integer, got {_type_name(value)}", value)
        if minimum is not None and value < minimum:
            raise self.error(path, f"must be an integer >= {minimum}", value)
        if maximum is not None and value > maximum:
            raise self.error(path, f"must be an integer <= {maximum}{why}", value)
        return value

    def boolean(self, value, path: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(path, f"expected true or false, got {_type_name(value)}", value)
        return value

    def string(self, value, path: str, choices=None) -> str:
        if not isinstance(value, str):
            raise self.error(path, f"expected a string, got {_type_name(value)}", value)
        if choices is not None and value not in choices:
            close = [c for c in _SYNONYMS.get(value.lower(), ()) if c in choices]
            close = close or difflib.get_close_matches(value, list(choices), n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            options = " | ".join(f'"{c}"' for c in choices)
            raise self.error(path, f"must be one of {options}{hint}", value)
        return value

    def vector(self, value, path: str, n: int, what: str) -> list[float]:
        if not isinstance(value, list):
            raise self.error(path, f"expected {what}, an array of {n} numbers", value)
        if len(value) != n:
            raise self.error(
                path, f"expected {what}, an array of {n} numbers, got {len(value)}", value
            )
        for i, x in enumerate(value):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise self.error(
                    path,
                    f"expected {what}, an array of {n} numbers; element {i} is {_type_name(x)}",
                    value,
                )
            if not math.isfinite(float(x)):
                raise self.error(path, f"element {i} must be a finite number", value)
        return [float(x) for x in value]


_BEFORE_TABLES = "a top-level key must come before the first [table] in the file"


_KEY_HELP = {
    "E": " (Young's modulus, MPa)",
    "nu": " (Poisson's ratio)",
    "base": " (base point [x, z], mm)",
    "tip": " (tip point [x, z], mm, shared by both beams)",
    "thickness": " (in-plane thickness, mm)",
    "depth": " (out-of-plane depth, mm)",
    "front_s": " (arc length on the front beam, mm)",
    "back_s": " (arc length on the back beam, mm)",
    "kind": ' ("point" or "distributed")',
    "beam": ' ("front", "back" or a crossbeam index)',
    "s": " (arc length of a point load, mm)",
    "s_range": " ([s0, s1] of a distributed load, mm)",
    "force": " (point force [Fx, Fy, Fz], N)",
    "total_force": " (resultant [Fx, Fy, Fz] of a distributed load, N)",
    "count": " (number of crossbeams)",
    "material": " (table [material] with E and nu)",
    "front": " (table [front] with base, tip, thickness, depth)",
    "back": " (table [back] with base, thickness, depth)",
}

_TOP_KEYS = (
    "meta",
    "torsion",
    "material",
    "front",
    "back",
    "crossbeams",
    "crossbeam_pattern",
    "adaptor",
    "loads",
    "solver",
    "objects",
    "contact",
    "grasp",
)
_TOP_HINTS = {
    "crossbeam": "unknown key (did you mean 'crossbeams'? write one [[crossbeams]] table per "
    "crossbeam)",
    "load": "unknown key (did you mean 'loads'? write one [[loads]] table per load)",
}


def _solver_option_fields():
    return [f for f in dataclasses.fields(SolverOptions) if f.default is not dataclasses.MISSING]


# --------------------------------------------------------------------------------------
# Building the finger
# --------------------------------------------------------------------------------------


def _parse(doc: dict, r: _Reader) -> tuple[Finger, SolveSettings]:
    r.table(doc, "", _TOP_KEYS, required=("material", "front", "back"), hints=_TOP_HINTS)
    if "crossbeams" in doc and "crossbeam_pattern" in doc:
        raise r.error(
            "crossbeam_pattern",
            "give either [[crossbeams]] tables or one [crossbeam_pattern], not both",
        )

    # [meta]
    meta = r.table(doc.get("meta", {}), "meta", ("name", "description"))
    name = r.string(meta.get("name", ""), "meta.name")
    description = r.string(meta.get("description", ""), "meta.description")

    torsion = r.string(doc.get("torsion", "paper"), "torsion", TORSION_KINDS)

    # [material]
    mat = r.table(
        doc["material"], "material", ("E", "nu", "shear_coefficient"), required=("E", "nu")
    )
    material = Material(
        E=r.number(mat["E"], "material.E", positive=True),
        nu=r.number(mat["nu"], "material.nu"),
        shear_coefficient=r.number(
            mat.get("shear_coefficient", 5.0 / 6.0), "material.shear_coefficient", positive=True
        ),
    )

    # [front], [back]
    front = r.table(
        doc["front"],
        "front",
        ("base", "tip", "thickness", "depth", "tip_thickness", "curvature"),
        required=("base", "tip", "thickness", "depth"),
    )
    back = r.table(
        doc["back"],
        "back",
        ("base", "thickness", "depth", "tip_thickness", "curvature"),
        required=("base", "thickness", "depth"),
        hints={"tip": "the two beams share one tip: give it once, as front.tip"},
    )
    front_base = r.vector(front["base"], "front.base", 2, "a point [x, z]")
    tip = r.vector(front["tip"], "front.tip", 2, "a point [x, z]")
    back_base = r.vector(back["base"], "back.base", 2, "a point [x, z]")
    sections = {}
    curvature = {
        beam: r.number(tbl["curvature"], f"{beam}.curvature") if "curvature" in tbl else 0.0
        for beam, tbl in (("front", front), ("back", back))
    }
    for beam, tbl in (("front", front), ("back", back)):
        tip_t = tbl.get("tip_thickness")
        sections[beam] = Section(
            r.number(tbl["thickness"], f"{beam}.thickness", positive=True),
            r.number(tbl["depth"], f"{beam}.depth", positive=True),
            None if tip_t is None else r.number(tip_t, f"{beam}.tip_thickness", positive=True),
        )

    # crossbeams
    if "crossbeam_pattern" in doc:
        crossbeams = _pattern(doc["crossbeam_pattern"], r, front_base, back_base, tip)
    else:
        rows = []
        for i, cb in enumerate(r.array_of_tables(doc.get("crossbeams", []), "crossbeams")):
            p = f"crossbeams[{i}]"
            keys = ("front_s", "back_s", "thickness", "depth")
            r.table(cb, p, keys, required=keys)
            rows.append(
                (
                    r.number(cb["front_s"], f"{p}.front_s"),
                    r.number(cb["back_s"], f"{p}.back_s"),
                    r.number(cb["thickness"], f"{p}.thickness", positive=True),
                    r.number(cb["depth"], f"{p}.depth", positive=True),
                )
            )
        cols = np.asarray(rows, dtype=np.float64).reshape(-1, 4).T
        crossbeams = Crossbeams(*cols)
    n_cb = int(np.shape(crossbeams.front_s)[0])

    # [adaptor]
    ad = r.table(
        doc.get("adaptor", {}),
        "adaptor",
        ("front_base", "back_base", "front_clamp_length", "back_clamp_length", "support_length"),
    )
    adaptor = Adaptor(
        front_base=r.string(ad.get("front_base", "clamped"), "adaptor.front_base", BASE_KINDS),
        back_base=r.string(ad.get("back_base", "clamped"), "adaptor.back_base", BASE_KINDS),
        front_clamp_length=r.number(
            ad.get("front_clamp_length", 0.0), "adaptor.front_clamp_length", nonnegative=True
        ),
        back_clamp_length=r.number(
            ad.get("back_clamp_length", 0.0), "adaptor.back_clamp_length", nonnegative=True
        ),
        support_length=None
        if "support_length" not in ad
        else r.number(ad["support_length"], "adaptor.support_length", nonnegative=True),
    )
    objects = tuple(
        _object(o, f"objects[{i}]", r)
        for i, o in enumerate(r.array_of_tables(doc.get("objects", []), "objects"))
    )
    contact = _contact(doc.get("contact", {}), r)

    # [[loads]]
    loads = tuple(
        _load(ld, f"loads[{j}]", r, n_cb)
        for j, ld in enumerate(r.array_of_tables(doc.get("loads", []), "loads"))
    )

    settings = _settings(doc.get("solver", {}), r, name, description)
    if "grasp" in doc:
        settings = dataclasses.replace(settings, grasp=_grasp(doc["grasp"], r))

    finger = Finger(
        material=material,
        front_base=front_base,
        back_base=back_base,
        tip=tip,
        front=sections["front"],
        back=sections["back"],
        crossbeams=crossbeams,
        adaptor=adaptor,
        loads=loads,
        front_curvature=curvature["front"],
        back_curvature=curvature["back"],
        torsion=torsion,
        objects=objects,
        contact=contact,
    )
    try:
        validate_finger(finger)
        check_mode_carries_loads(finger, settings.mode)
    except FingerError as e:
        msg = toml_paths(str(e))
        if "crossbeam_pattern" in doc and "crossbeam" in msg:
            msg += " (crossbeams generated by [crossbeam_pattern], numbered from 0)"
        raise FingerFileError(f"{r.source}: {msg}") from None
    return finger, settings


def _pattern(value, r: _Reader, front_base, back_base, tip) -> Crossbeams:
    p = "crossbeam_pattern"
    tbl = r.table(
        value,
        p,
        ("count", "front_s", "horizontal", "back_s", "thickness", "depth"),
        required=("count", "front_s", "thickness", "depth"),
    )
    n = r.integer(tbl["count"], f"{p}.count", minimum=1)
    f0, f1 = r.vector(tbl["front_s"], f"{p}.front_s", 2, "[first, last] front-beam arc lengths")
    if n == 1 and f0 != f1:
        raise r.error(
            f"{p}.front_s", "with count = 1, first and last must be equal", tbl["front_s"]
        )
    horizontal = r.boolean(tbl.get("horizontal", False), f"{p}.horizontal")
    front_s = np.linspace(f0, f1, n)
    if horizontal and "back_s" in tbl:
        raise r.error(
            f"{p}.back_s", "give either horizontal = true or back_s, not both", tbl["back_s"]
        )
    if horizontal:
        fb, bb, tp = (np.asarray(x, dtype=np.float64) for x in (front_base, back_base, tip))
        lf, lb = np.linalg.norm(tp - fb), np.linalg.norm(tp - bb)
        if lf == 0 or abs(tp[1] - bb[1]) < 1e-12 * max(lb, 1.0):
            raise r.error(
                f"{p}.horizontal",
                "needs a back beam that rises in z (back.base and front.tip differ in z)",
                True,
            )
        z = fb[1] + front_s * (tp[1] - fb[1]) / lf
        back_s = (z - bb[1]) * lb / (tp[1] - bb[1])
    elif "back_s" in tbl:
        b0, b1 = r.vector(tbl["back_s"], f"{p}.back_s", 2, "[first, last] back-beam arc lengths")
        back_s = np.linspace(b0, b1, n)
    else:
        raise r.error(f"{p}.back_s", "missing: give back_s = [first, last] or horizontal = true")
    t = r.number(tbl["thickness"], f"{p}.thickness", positive=True)
    d = r.number(tbl["depth"], f"{p}.depth", positive=True)
    return Crossbeams(front_s, back_s, np.full(n, t), np.full(n, d))


def _beam_index(value, path: str, r: _Reader, n_cb: int) -> int:
    if isinstance(value, str):
        if value == "front":
            return 0
        if value == "back":
            return 1
        close = difflib.get_close_matches(value, ["front", "back"], n=1, cutoff=0.5)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise r.error(
            path, f'must be "front", "back" or a crossbeam index 0..{n_cb - 1}{hint}', value
        )
    if isinstance(value, bool) or not isinstance(value, int):
        raise r.error(
            path, f'must be "front", "back" or a crossbeam index, got {_type_name(value)}', value
        )
    if not 0 <= value < n_cb:
        raise r.error(
            path,
            f"no such crossbeam: this finger has {n_cb} crossbeams, indices 0..{n_cb - 1}",
            value,
        )
    return 2 + value


def _load(value, p: str, r: _Reader, n_cb: int):
    if not isinstance(value, dict):
        raise r.error(p, "expected a table", value)
    if "kind" not in value:
        raise r.error(f"{p}.kind", "missing required key" + _KEY_HELP["kind"])
    kind = r.string(value["kind"], f"{p}.kind", LOAD_KINDS)
    if kind == "point":
        allowed, required = ("kind", "beam", "s", "force", "moment"), ("beam", "s", "force")
        hints = {
            "total_force": "a point load takes force = [Fx, Fy, Fz] (N); total_force is for "
            'kind = "distributed"',
            "s_range": "a point load takes s (one arc length, mm); s_range is for kind = "
            '"distributed"',
        }
    else:
        allowed, required = (
            ("kind", "beam", "s_range", "total_force"),
            ("beam", "s_range", "total_force"),
        )
        hints = {
            "force": "a distributed load takes total_force = [Fx, Fy, Fz], its resultant in N "
            '(spread uniformly over s_range); force is for kind = "point"',
            "s": 'a distributed load takes s_range = [s0, s1] (mm); s is for kind = "point"',
            "moment": "a distributed load carries no moment; add a point load for one",
        }
    r.table(value, p, allowed, required=required, hints=hints)
    beam = _beam_index(value["beam"], f"{p}.beam", r, n_cb)
    if kind == "point":
        return PointLoad(
            beam,
            r.number(value["s"], f"{p}.s"),
            r.vector(value["force"], f"{p}.force", 3, "a force [Fx, Fy, Fz] in N"),
            r.vector(
                value.get("moment", [0.0, 0.0, 0.0]),
                f"{p}.moment",
                3,
                "a moment [Mx, My, Mz] in N mm",
            ),
        )
    s_range = r.vector(value["s_range"], f"{p}.s_range", 2, "[s0, s1] in mm")
    if not s_range[0] < s_range[1]:
        raise r.error(f"{p}.s_range", "needs s0 < s1", value["s_range"])
    return DistributedLoad(
        beam,
        s_range,
        r.vector(value["total_force"], f"{p}.total_force", 3, "a force [Fx, Fy, Fz] in N"),
    )


def _settings(value, r: _Reader, name: str, description: str) -> SolveSettings:
    fields = _solver_option_fields()
    opt_names = tuple(f.name for f in fields)
    tbl = r.table(value, "solver", ("mode", "integrator", "steps", "backend") + opt_names)
    mode = r.string(tbl.get("mode", "auto"), "solver.mode", MODES)
    default_integrator = Integrator()
    integ = {}
    if "integrator" in tbl:
        raw = r.string(tbl["integrator"], "solver.integrator")
        by_lower = {k.lower(): k for k in INTEGRATORS}
        if raw.lower() not in by_lower:
            r.string(raw, "solver.integrator", tuple(INTEGRATORS))  # raises with a suggestion
        integ["solver"] = INTEGRATORS[by_lower[raw.lower()]](scan_kind="lax")
    if "steps" in tbl:
        integ["steps"] = r.integer(
            tbl["steps"],
            "solver.steps",
            minimum=1,
            maximum=MAX_STEPS,
            why=" (fixed steps per segment)",
        )
    if "backend" in tbl:
        integ["backend"] = r.string(tbl["backend"], "solver.backend")
    opts = {}
    for f in fields:
        if f.name not in tbl:
            continue
        path, v = f"solver.{f.name}", tbl[f.name]
        if isinstance(f.default, bool):
            opts[f.name] = r.boolean(v, path)
        elif f.name == "max_rotation_step" and v is False:
            opts[f.name] = None  # no cap: plain Newton steps
        elif f.name == "max_rotation_step" and v is True:
            raise r.error(path, "expected an angle in rad, or false for no cap", v)
        elif f.name == "linear_solver":
            opts[f.name] = r.string(v, path, LINEAR_SOLVERS)
        elif isinstance(f.default, int):
            opts[f.name] = r.integer(v, path, minimum=1, maximum=MAX_ITERATIONS)
        else:
            opts[f.name] = r.number(v, path, positive=True)
    try:
        integrator = Integrator(**integ) if integ else default_integrator
        options = SolverOptions(**opts)
    except ValueError as e:
        raise FingerFileError(f"{r.source}: [solver]: {e}") from None
    return SolveSettings(mode, integrator, options, name, description)


_OBJECT_KEYS = {
    "circle": (("center", "radius"), ()),
    "ellipse": (("center", "semi_axes"), ("angle_deg",)),
    "rounded_rectangle": (("center", "half_size"), ("corner_radius", "angle_deg")),
    "polygon": (("vertices",), ("center", "corner_radius", "angle_deg")),
    "half_plane": (("point", "normal"), ()),
}


def _object(value, p: str, r: _Reader):
    """One [[objects]] table: kind, then the kind's keys (points (x, z) in mm, angles in
    degrees)."""
    if not isinstance(value, dict):
        raise r.error(p, f"expected a table [[objects]], got {_type_name(value)}", value)
    if "kind" not in value:
        raise r.error(f"{p}.kind", f"missing required key (one of {', '.join(_OBJECT_KEYS)})")
    kind = r.string(value["kind"], f"{p}.kind", tuple(_OBJECT_KEYS))
    need, optional = _OBJECT_KEYS[kind]
    tbl = r.table(value, p, ("kind",) + need + optional, required=need)
    args = {}
    for key in need + optional:
        if key not in tbl:
            continue
        path = f"{p}.{key}"
        if key in ("center", "point", "normal"):
            args[key] = r.vector(tbl[key], path, 2, "a point [x, z]")
        elif key in ("semi_axes", "half_size"):
            args[key] = r.vector(tbl[key], path, 2, "two lengths [along x, along z]")
        elif key == "vertices":
            pts = tbl[key]
            if not isinstance(pts, list) or len(pts) < 3:
                raise r.error(path, "must be a list of 3 or more points [x, z]", pts)
            args[key] = [
                r.vector(v, f"{path}[{i}]", 2, "a point [x, z]") for i, v in enumerate(pts)
            ]
        elif key == "angle_deg":
            args["angle"] = np.deg2rad(r.number(tbl[key], path))
        else:
            args[key] = r.number(tbl[key], path, positive=key == "radius")
    return OBJECT_KINDS[kind](**args)


def _contact(value, r: _Reader) -> Contact:
    keys = (
        "stiffness",
        "max_penetration",
        "support_stiffness",
        "max_support_penetration",
        "friction",
        "friction_regularisation",
        "segment_length",
        "near_segments",
        "member_contact",
        "member_stiffness",
        "max_member_penetration",
        "member_reach",
    )
    tbl = r.table(value, "contact", keys)
    args = {}
    for key in keys:
        if key == "member_contact" and key in tbl:
            args[key] = r.boolean(tbl[key], "contact.member_contact")
        elif key == "near_segments" and key in tbl:  # a count, or "all" (None)
            v = tbl[key]
            if isinstance(v, str):
                r.string(v, "contact.near_segments", ("all",))
                args[key] = None
            else:
                args[key] = r.integer(v, "contact.near_segments", minimum=1)
        elif key in tbl:
            args[key] = r.number(
                tbl[key],
                f"contact.{key}",
                positive=key != "friction",
                nonnegative=key == "friction",
            )
    return Contact(**args)


def _grasp(value, r: _Reader) -> GraspSettings:
    keys = ("closing", "actuator_force", "direction", "symmetric", "pull_step")
    tbl = r.table(value, "grasp", keys)
    if ("closing" in tbl) == ("actuator_force" in tbl):
        raise r.error("grasp", "give exactly one of closing (mm) and actuator_force (N)")
    return GraspSettings(
        closing=r.number(tbl["closing"], "grasp.closing", nonnegative=True)
        if "closing" in tbl
        else None,
        actuator_force=r.number(tbl["actuator_force"], "grasp.actuator_force", nonnegative=True)
        if "actuator_force" in tbl
        else None,
        direction=tuple(
            r.vector(tbl.get("direction", [-1.0, 0.0]), "grasp.direction", 2, "a direction [x, z]")
        ),
        symmetric=r.boolean(tbl.get("symmetric", True), "grasp.symmetric"),
        pull_step=r.number(tbl.get("pull_step", 2.0), "grasp.pull_step", positive=True),
    )


def toml_paths(msg: str) -> str:
    """Rename validate_finger's field names to the finger file's key paths."""
    msg = re.sub(r"(?<![\w.])front_base\b", "front.base", msg)
    msg = re.sub(r"(?<![\w.])back_base\b", "back.base", msg)
    msg = re.sub(r"^tip\b", "front.tip", msg)
    msg = re.sub(r"(?<![\w.])tip = ", "front.tip = ", msg)
    msg = re.sub(r"(?<![\w.])(front|back)_curvature\b", r"\1.curvature", msg)
    msg = msg.replace("equals tip", "equals front.tip")
    return msg


def loads_finger(text: str, *, source: str = "<string>") -> tuple[Finger, SolveSettings]:
    """Read a finger from TOML text. `source` names it in error messages."""
    r = _Reader(source)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise FingerFileError(f"{source}: not valid TOML: {e}") from None
    return _parse(doc, r)


def load_finger(path) -> tuple[Finger, SolveSettings]:
    """Read a finger file (TOML). Returns the finger and its solve settings.

    Raises FingerFileError (a ValueError) naming the file, the key and the bad value.
    """
    path = os.fspath(path)
    text = _read_text(path, "finger", FingerFileError)
    return loads_finger(text, source=path)


# --------------------------------------------------------------------------------------
# Finger files shipped with the package (finray_jax/data/)
# --------------------------------------------------------------------------------------

# Finger-1 (assumed dimensions; the default finger of `finray demo`, `compare` and
# `clamp-study`) and its grasps of a cylinder. examples/ holds the same files for users to
# copy and edit (a test keeps them identical).
PACKAGED_FINGERS = (
    "finger1.toml",
    "grasp_finger1.toml",
    "grasp_finger1_modified.toml",
    "grasp_finger1_modified_50mm.toml",
)


def packaged_finger_text(name: str = "finger1.toml") -> str:
    """The text of a finger file shipped with finray_jax (one of PACKAGED_FINGERS)."""
    if name not in PACKAGED_FINGERS:
        raise ValueError(f"no packaged finger file {name!r}: one of {PACKAGED_FINGERS}")
    return (resources.files("finray_jax") / "data" / name).read_text(encoding="utf-8")


def load_packaged_finger(name: str = "finger1.toml") -> tuple[Finger, SolveSettings]:
    """Read a finger file shipped with finray_jax (default: Finger-1, finger1.toml)."""
    return loads_finger(packaged_finger_text(name), source=f"<finray_jax data: {name}>")


# --------------------------------------------------------------------------------------
# Study files (sweeps, optimisations) that name a base finger file
# --------------------------------------------------------------------------------------


def _read_text(path, what: str, error: type[FingerFileError]) -> str:
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as e:
        raise error(f"{path}: cannot read the {what} file: {e.strerror}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: not UTF-8 text: {e}") from None


def loads_study(text: str, parse, error: type[FingerFileError], source: str, base_dir: str):
    """Parse a study file's TOML with `parse(doc, reader, source, base_dir)`; every
    FingerFileError (its own or its base finger's) comes out as `error`."""
    r = _Reader(source)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{source}: not valid TOML: {e}") from None
    try:
        return parse(doc, r, source, base_dir)
    except error:
        raise
    except FingerFileError as e:
        raise error(str(e)) from None


def load_study(path, loads, what: str, error: type[FingerFileError]):
    path = os.fspath(path)
    text = _read_text(path, what, error)
    return loads(text, source=path, base_dir=os.path.dirname(os.path.abspath(path)))


def require_keys(r: _Reader, table: dict, path: str, keys, hints: dict) -> None:
    for key in keys:
        if key not in table:
            full = f"{path}.{key}" if path else key
            raise r.error(
                full, "missing required key" + hints.get(key, "") + r.misplaced(path, key)
            )


def write_atomic(path, text: str) -> None:
    """Write a file through a flushed and fsync'ed temporary and a rename, so that an
    interruption leaves the old file or the new one, never a torn one."""
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_run_record(path, out_dir, error, *, what, run, digest, hash_key, source_key) -> dict:
    """The JSON record a resumable run keeps in its output directory (a sweep's manifest,
    an optimisation's checkpoint), checked to belong to this `run` (same hash)."""
    try:
        with open(path, encoding="utf-8") as fh:
            record = json.load(fh)
    except (OSError, ValueError) as e:
        raise error(
            f"{path}: unreadable {what} ({e}); remove {out_dir} or use another --out"
        ) from None
    if record.get(hash_key) != digest:
        raise error(
            f"{out_dir} holds another {run} (from {record.get(source_key, '?')}, hash "
            f"{str(record.get(hash_key))[:12]}; this one's hash is {digest[:12]}; the hash "
            f"covers the {run} file and its finger file, so one of them differs): use another "
            "--out directory, or delete that one to start again"
        )
    return record


def base_finger(doc: dict, r: _Reader, base_dir: str):
    """The finger file a study names (key `finger`, relative to the study file):
    (finger, settings, normalised path, sha256 of its bytes)."""
    rel = r.string(doc["finger"], "finger")
    path = os.path.normpath(os.path.join(base_dir, rel))
    if not os.path.isfile(path):
        raise r.error("finger", f"no such finger file: {path}", rel)
    finger, settings = load_finger(path)
    with open(path, "rb") as fh:
        digest = hashlib.sha256(fh.read()).hexdigest()
    return finger, settings, path, digest


# --------------------------------------------------------------------------------------
# Writing TOML
# --------------------------------------------------------------------------------------


def _tf(x) -> str:
    """A float in TOML, exactly (repr round-trips)."""
    v = float(x)
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(v)


def _tv(xs) -> str:
    return "[" + ", ".join(_tf(x) for x in np.asarray(xs, dtype=np.float64).reshape(-1)) + "]"


def _ts(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def _optional_lines(section, curvature):
    out = []
    if section.tip_thickness is not None:
        out.append(f"tip_thickness = {_tf(section.tip_thickness)}")
    if float(curvature) != 0.0:
        out.append(f"curvature = {_tf(curvature)}")
    return out


def finger_to_toml(finger: Finger, settings: SolveSettings | None = None) -> str:
    """A finger (and optionally its solve settings) as a finger file.

    Values are written exactly (`load_finger` gives back equal arrays). Crossbeams are
    always written as explicit [[crossbeams]] tables.
    """
    validate_finger(finger)
    out = [
        "# finray_jax finger file. Units: mm, N, MPa; points are (x, z).",
        f"torsion = {_ts(finger.torsion)}",
        "",
    ]
    if settings is not None and (settings.name or settings.description):
        out += ["[meta]"]
        if settings.name:
            out.append(f"name = {_ts(settings.name)}")
        if settings.description:
            out.append(f"description = {_ts(settings.description)}")
        out.append("")
    m = finger.material
    out += [
        "[material]",
        f"E = {_tf(m.E)}",
        f"nu = {_tf(m.nu)}",
        f"shear_coefficient = {_tf(m.shear_coefficient)}",
        "",
    ]
    out += [
        "[front]",
        f"base = {_tv(finger.front_base)}",
        f"tip = {_tv(finger.tip)}",
        f"thickness = {_tf(finger.front.thickness)}",
        f"depth = {_tf(finger.front.depth)}",
        *_optional_lines(finger.front, finger.front_curvature),
        "",
    ]
    out += [
        "[back]",
        f"base = {_tv(finger.back_base)}",
        f"thickness = {_tf(finger.back.thickness)}",
        f"depth = {_tf(finger.back.depth)}",
        *_optional_lines(finger.back, finger.back_curvature),
        "",
    ]
    ad = finger.adaptor
    out += [
        "[adaptor]",
        f"front_base = {_ts(ad.front_base)}",
        f"back_base = {_ts(ad.back_base)}",
        f"front_clamp_length = {_tf(ad.front_clamp_length)}",
        f"back_clamp_length = {_tf(ad.back_clamp_length)}",
        *([] if ad.support_length is None else [f"support_length = {_tf(ad.support_length)}"]),
        "",
    ]
    out += _objects_toml(finger)
    cb = finger.crossbeams
    for i in range(finger.n_crossbeams):
        out += [
            f"[[crossbeams]]  # {i}",
            f"front_s = {_tf(cb.front_s[i])}",
            f"back_s = {_tf(cb.back_s[i])}",
            f"thickness = {_tf(cb.thickness[i])}",
            f"depth = {_tf(cb.depth[i])}",
            "",
        ]
    for load in finger.loads:
        beam = {0: '"front"', 1: '"back"'}.get(load.beam, str(load.beam - 2))
        if isinstance(load, PointLoad):
            out += [
                "[[loads]]",
                'kind = "point"',
                f"beam = {beam}",
                f"s = {_tf(load.s)}",
                f"force = {_tv(load.force)}",
                f"moment = {_tv(load.moment)}",
                "",
            ]
        elif isinstance(load, DistributedLoad):
            out += [
                "[[loads]]",
                'kind = "distributed"',
                f"beam = {beam}",
                f"s_range = {_tv(load.s_range)}",
                f"total_force = {_tv(load.total_force)}",
                "",
            ]
        else:
            raise TypeError(f"cannot write a {type(load).__name__} to a finger file")
    if settings is not None:
        out += _settings_toml(settings)
    return "\n".join(out).rstrip("\n") + "\n"


def _objects_toml(finger: Finger) -> list[str]:
    out = []
    for obj in finger.objects:
        out += ["[[objects]]", f"kind = {_ts(obj.kind)}"]
        need, optional = _OBJECT_KEYS[obj.kind]
        for key in need + optional:
            if key == "angle_deg":
                out.append(f"angle_deg = {_tf(np.rad2deg(float(obj.angle)))}")
            elif key == "vertices":
                out.append("vertices = [" + ", ".join(_tv(v) for v in obj.vertices) + "]")
            else:
                v = getattr(obj, key)
                out.append(f"{key} = {_tv(v) if np.ndim(v) else _tf(v)}")
        out.append("")
    c = finger.contact
    out += ["[contact]"]
    if c.stiffness is not None:
        out.append(f"stiffness = {_tf(c.stiffness)}")
    out.append(f"max_penetration = {_tf(c.max_penetration)}")
    if c.support_stiffness is not None:
        out.append(f"support_stiffness = {_tf(c.support_stiffness)}")
    if c.max_support_penetration is not None:
        out.append(f"max_support_penetration = {_tf(c.max_support_penetration)}")
    if c.member_contact is not None:
        out.append(f"member_contact = {'true' if c.member_contact else 'false'}")
    if c.member_stiffness is not None:
        out.append(f"member_stiffness = {_tf(c.member_stiffness)}")
    if c.max_member_penetration is not None:
        out.append(f"max_member_penetration = {_tf(c.max_member_penetration)}")
    out.append(f"member_reach = {_tf(c.member_reach)}")
    out += [
        f"friction = {_tf(c.friction)}",
        f"friction_regularisation = {_tf(c.friction_regularisation)}",
        f"segment_length = {_tf(c.segment_length)}",
        "near_segments = " + ('"all"' if c.near_segments is None else str(c.near_segments)),
        "",
    ]
    return out if finger.objects or finger.adaptor.support_length is not None else []


def _settings_toml(settings: SolveSettings) -> list[str]:
    integ = settings.integrator
    name = type(integ.solver).__name__
    if name not in INTEGRATORS:
        raise ValueError(
            f"cannot write integrator solver {name} to a finger file; use one of "
            f"{tuple(INTEGRATORS)}"
        )
    out = [
        "[solver]",
        f"mode = {_ts(settings.mode)}",
        f"integrator = {_ts(name)}",
        f"steps = {integ.steps}",
    ]
    if getattr(integ, "backend", None) not in (None, Integrator().backend):
        out.append(f"backend = {_ts(integ.backend)}")
    for f in _solver_option_fields():
        v = getattr(settings.options, f.name)
        if v is None and f.name == "max_rotation_step":  # the cap switched off
            out.append(f"{f.name} = false")
            continue
        if v is None:  # an option left to its default rule (reuse_jacobian_below)
            continue
        if isinstance(f.default, bool):
            out.append(f"{f.name} = {'true' if v else 'false'}")
        elif isinstance(f.default, str):
            out.append(f"{f.name} = {_ts(v)}")
        elif isinstance(f.default, int):
            out.append(f"{f.name} = {int(v)}")
        else:
            out.append(f"{f.name} = {_tf(v)}")
    return out + [""]


# --------------------------------------------------------------------------------------
# Solutions as JSON
# --------------------------------------------------------------------------------------


def to_plain(x):
    """numpy/jax arrays and scalars to lists and floats; non-finite floats to None."""
    if isinstance(x, dict):
        return {k: to_plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_plain(v) for v in x]
    if isinstance(x, (str, bool)) or x is None:
        return x
    if isinstance(x, int):
        return x
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    a = np.asarray(x)
    if a.dtype == bool:
        return a.tolist()
    if np.issubdtype(a.dtype, np.integer):
        return a.tolist()
    a = a.astype(np.float64)
    if a.ndim == 0:
        v = float(a)
        return v if math.isfinite(v) else None
    if np.all(np.isfinite(a)):
        return a.tolist()
    return to_plain(a.tolist())


def _beam_dict(b) -> dict:
    return {
        "s": b.s,
        "position": b.position,
        "force": b.force,
        "moment": b.moment,
    }


def _load_dict(load, factor=1.0) -> dict:
    beam = {0: "front", 1: "back"}.get(load.beam, load.beam - 2)
    if isinstance(load, PointLoad):
        return {
            "kind": "point",
            "beam": beam,
            "s": load.s,
            "force": np.asarray(load.force) * factor,
            "moment": np.asarray(load.moment) * factor,
        }
    return {
        "kind": "distributed",
        "beam": beam,
        "s_range": load.s_range,
        "total_force": np.asarray(load.total_force) * factor,
    }


def solution_to_dict(sol, finger: Finger, *, settings: SolveSettings | None = None) -> dict:
    """A Solution as plain JSON-able data (lists of floats; NaN written as null).

    Positions (N, 3) are (x, y, z) in mm; forces n(s) in N and moments m(s) in N mm are the
    internal wrench (material at s+ on s-, world frame); reactions are what the adaptor
    applies to each beam at its base (moment about the base point).
    """
    wr = sol.crossbeam_wrenches
    rot = np.asarray(sol.tip.rotation, dtype=np.float64)
    d = {
        "finray_jax_version": __version__,
        "units": dict(UNITS),
        "name": settings.name if settings is not None else "",
        "mode": sol.mode,
        "status": sol.status,
        "converged": sol.status == "converged",
        "message": sol.message,
        "load_factor": sol.load_factor,
        "iterations": sol.iterations,
        "max_residual": sol.max_residual,
        "tip": {
            "position": sol.tip.position,
            "displacement": sol.tip.displacement,
            "rotation": rot,
            "rotation_y": rot[1],
        },
        "reactions": {
            "front": {"force": sol.reactions_front.force, "moment": sol.reactions_front.moment},
            "back": {"force": sol.reactions_back.force, "moment": sol.reactions_back.moment},
        },
        "beams": {
            "front": _beam_dict(sol.front),
            "back": _beam_dict(sol.back),
            "crossbeams": [_beam_dict(sol.crossbeam(i)) for i in range(finger.n_crossbeams)],
        },
        "crossbeam_wrenches": {
            "front_force": wr.front_force,
            "front_moment": wr.front_moment,
            "back_force": wr.back_force,
            "back_moment": wr.back_moment,
        },
        "loads": [_load_dict(ld) for ld in finger.loads],
    }
    return to_plain(d)


def limit_to_dict(lim, finger: Finger, *, settings: SolveSettings | None = None) -> dict:
    """A LimitLoad as JSON-able data: the factor, the loads at the limit, the equilibrium."""
    factor = float(lim.load_factor)
    sol = solution_to_dict(lim.solution, finger, settings=settings)
    summary = {k: sol[k] for k in ("tip", "reactions", "max_residual", "iterations")}
    return to_plain(
        {
            "finray_jax_version": __version__,
            "units": dict(UNITS),
            "name": settings.name if settings is not None else "",
            "mode": lim.solution.mode,
            "found": bool(lim.found),
            "limit_load_factor": factor,
            "loads": [_load_dict(ld) for ld in finger.loads],
            "limit_loads": [_load_dict(ld, factor) for ld in finger.loads],
            "equilibrium_at_limit": summary,
            "solution": sol,
        }
    )


def json_text(obj, level=0) -> str:
    pad, inner = "  " * level, "  " * (level + 1)
    if isinstance(obj, dict):
        if not obj:
            return "{}"
        items = [f"{inner}{json.dumps(str(k))}: {json_text(v, level + 1)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(obj, (list, tuple)):
        if all(not isinstance(v, (dict, list, tuple)) for v in obj):
            return json.dumps(list(obj), allow_nan=False)
        return "[\n" + ",\n".join(inner + json_text(v, level + 1) for v in obj) + "\n" + pad + "]"
    return json.dumps(obj, allow_nan=False)


def write_json(path, obj: Any) -> None:
    """Write JSON-able data (arrays allowed) to `path`, one array row per line."""
    path = os.fspath(path)
    parent = os.path.dirname(path)
    if parent:
        os.makedirs(parent, exist_ok=True)
    text = json_text(to_plain(obj))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text + "\n")
