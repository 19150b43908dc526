"""Checks of an optimisation problem beyond its file's syntax, made when the file is read:
every value in a design value's bounds gives a valid finger, the clamp cannot pass the
support's end, and the objects lie ahead of the finger at the initial design. Each
raises the file reader's error naming the key and its value (`r.error`)."""

from __future__ import annotations

import dataclasses
import re

import equinox as eqx
import numpy as np

from . import io as fio
from ._finger import Finger, FingerError, beam_lengths, validate_finger
from ._geometry import main_beam_samples
from ._grasp_inputs import check_objects, unit_direction
from ._optimize_problem import DesignVar, OptimizeProblem
from .design import set_design as _set_design


def check_bounds(finger: Finger, name, lo, hi, optimised, error, path, value) -> None:
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


def check_clamp_bounds(finger: Finger, design: tuple[DesignVar, ...], error) -> None:
    """The clamp against the support's end, when the bounds of either move it: the
    clamp's upper bound must not pass the support's lower bound (the finger's own value
    stands in for the one that is not optimised)."""
    names = [d.name for d in design]
    if "adaptor.support_length" in names or "adaptor.back_clamp_length" in names:
        if finger.adaptor.support_length is not None:
            lc = next((d for d in design if d.name == "adaptor.back_clamp_length"), None)
            ls = next((d for d in design if d.name == "adaptor.support_length"), None)
            lc_hi = float(finger.adaptor.back_clamp_length) if lc is None else lc.hi
            ls_lo = float(finger.adaptor.support_length) if ls is None else ls.lo
            if lc_hi > ls_lo:
                raise error(
                    "design",
                    f"the bounds let the clamp (up to {lc_hi!r} mm) pass "
                    f"the support's end (from {ls_lo!r} mm): keep "
                    "adaptor.back_clamp_length <= adaptor.support_length",
                )


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


def check_objects_ahead(problem: OptimizeProblem, r, doc, obj: dict) -> None:
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
