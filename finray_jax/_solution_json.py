"""Solutions and limit loads as JSON documents.

`solution_to_dict` and `limit_to_dict` turn results into plain data (lists of floats, NaN
as null) stamped with the package version and the units; `write_json` writes such data
with one array row per line.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from ._finger import Finger, PointLoad
from ._solve_settings import SolveSettings
from ._version import __version__

UNITS = {
    "length": "mm",
    "force": "N",
    "moment": "N mm",
    "modulus": "MPa",
    "angle": "rad",
}


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
    """One beam's solution: arc length, centreline and internal wrench along it."""
    return {
        "s": b.s,
        "position": b.position,
        "force": b.force,
        "moment": b.moment,
    }


def _load_dict(load, factor=1.0) -> dict:
    """A load as in the finger file, its force and moment scaled by `factor`."""
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
    """Plain data as indented JSON text, an array of scalars on one line."""
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
