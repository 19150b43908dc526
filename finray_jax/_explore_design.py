"""The design explorer's controls: what each one sets, its bounds, and the finger a set of
control values describes.

Two kinds of controls. Choices fix the compiled program (the topology): what is solved
(a grasp or the finger's load case), the adaptor (original or modified), the crossbeam
count, the object's kind and how the gripper closes. Values are numbers that never
recompile: `finger_of` builds the finger from them with traceable operations, so the
explorer differentiates every output in every value (`jax.grad`).

Crossbeams are an evenly spaced pattern: `count` crossbeams from `first` to `last` along
the front beam, all at one angle to the horizontal (which places their back ends) and
one thickness.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._bases import ClampedBase, PinnedBase
from ._finger import Adaptor, Crossbeams, DistributedLoad, Finger, PointLoad
from ._geometry import geometry
from ._objects import Circle, RoundedRectangle
from .design import crossbeam_angle, set_design

MODES = ("grasp", "solve")
ADAPTORS = ("modified", "original")
OBJECT_KINDS = ("circle", "square")
CLOSINGS = ("displacement", "force")
MAX_CROSSBEAMS = 12


@dataclasses.dataclass(frozen=True)
class Control:
    """One numeric control: its name on the page (and in the JSON), label, unit, bounds
    and slider step; `modes`: where it acts; `modified`: only with the modified adaptor."""

    name: str
    label: str
    unit: str
    lo: float
    hi: float
    step: float
    modes: tuple = MODES
    modified: bool = False


CONTROLS = (
    Control("back_clamp_length", "back clamp length", "mm", 0.0, 40.0, 0.5, modified=True),
    Control("support_length", "support length", "mm", 0.0, 100.0, 0.5, modified=True),
    Control("crossbeam_first", "first crossbeam (front attachment)", "mm", 5.0, 60.0, 0.5),
    Control("crossbeam_last", "last crossbeam (front attachment)", "mm", 60.0, 115.0, 0.5),
    Control("crossbeam_angle", "crossbeam angle", "deg", -30.0, 30.0, 0.5),
    Control("crossbeam_thickness", "crossbeam thickness", "mm", 0.5, 5.0, 0.05),
    Control("front_thickness", "front beam thickness", "mm", 1.0, 6.0, 0.05),
    Control("back_thickness", "back beam thickness", "mm", 1.0, 6.0, 0.05),
    Control("E", "Young's modulus E", "MPa", 2.0, 60.0, 0.5),
    Control("object_size", "object size (diameter or side)", "mm", 4.0, 40.0, 0.5, ("grasp",)),
    Control("object_x", "object centre x", "mm", -40.0, -2.0, 0.1, ("grasp",)),
    Control("object_z", "object centre z", "mm", 10.0, 115.0, 0.5, ("grasp",)),
    Control("closing", "closing displacement", "mm", 0.0, 15.0, 0.1, ("grasp",)),
    Control("actuator_force", "actuator force", "N", 0.0, 30.0, 0.1, ("grasp",)),
    Control("friction", "friction (holding force)", "", 0.0, 1.0, 0.05, ("grasp",)),
    Control("load_scale", "load scale (load case)", "x", 0.0, 5.0, 0.05, ("solve",)),
)
BY_NAME = {c.name: c for c in CONTROLS}


class ControlError(ValueError):
    """A control value or choice the explorer refuses (names the control and the value)."""


@dataclasses.dataclass(frozen=True)
class Choices:
    """The controls that fix the compiled program."""

    mode: str = "grasp"
    adaptor: str = "modified"
    crossbeam_count: int = 7
    object_kind: str = "circle"
    closing: str = "displacement"

    def checked(self) -> Choices:
        for name, allowed in (
            ("mode", MODES),
            ("adaptor", ADAPTORS),
            ("object_kind", OBJECT_KINDS),
            ("closing", CLOSINGS),
        ):
            if getattr(self, name) not in allowed:
                raise ControlError(f"{name} = {getattr(self, name)!r}: expected one of {allowed}")
        n = self.crossbeam_count
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_CROSSBEAMS:
            raise ControlError(f"crossbeam_count = {n!r}: expected a whole number 1..12")
        return self


def active(choices: Choices) -> list[str]:
    """The names of the values that act on the finger under these choices."""
    out = []
    for c in CONTROLS:
        if choices.mode not in c.modes or (c.modified and choices.adaptor != "modified"):
            continue
        if c.name == "closing" and choices.closing != "displacement":
            continue
        if c.name == "actuator_force" and choices.closing != "force":
            continue
        out.append(c.name)
    return out


def design_values(choices: Choices) -> list[str]:
    """The active values that describe the finger and its object (what a gradient is
    taken in): the active ones but the closing's force and the release's friction."""
    return [n for n in active(choices) if n not in ("actuator_force", "friction")]


def check_value(name: str, value) -> float:
    """The value as a float, or ControlError naming the control and the value."""
    c = BY_NAME.get(name)
    if c is None:
        raise ControlError(f"unknown control {name!r}; controls: {', '.join(BY_NAME)}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ControlError(f"{c.label} ({name}) = {value!r}: expected a number") from None
    if not math.isfinite(x):
        raise ControlError(f"{c.label} ({name}) = {value!r}: expected a finite number")
    if not c.lo <= x <= c.hi:
        raise ControlError(
            f"{c.label} ({name}) = {x:g} {c.unit}: outside its bounds {c.lo:g}..{c.hi:g}"
        )
    return x


# --------------------------------------------------------------------------------------
# From a finger to control values, and back
# --------------------------------------------------------------------------------------


def _pattern_of(finger: Finger) -> tuple[float, float, float, float]:
    """(first, last, angle in degrees, thickness) of a finger's crossbeams: the first and
    last front attachments, the mean angle and the mean thickness."""
    cb = finger.crossbeams
    s = np.asarray(cb.front_s, float)
    angle = float(np.degrees(np.mean(np.asarray(crossbeam_angle(finger)))))
    return float(s.min()), float(s.max()), angle, float(np.mean(np.asarray(cb.thickness)))


def values_of(finger: Finger, closing=None, actuator_force=None, friction=0.3) -> dict:
    """The control values of a finger file's finger (the object's where it has one)."""
    first, last, angle, thickness = _pattern_of(finger)
    ad = finger.adaptor
    v = {
        "back_clamp_length": float(ad.back_clamp_length) or 20.0,
        "support_length": 60.0 if ad.support_length is None else float(ad.support_length),
        "crossbeam_first": first,
        "crossbeam_last": last,
        "crossbeam_angle": round(angle, 9),
        "crossbeam_thickness": thickness,
        "front_thickness": float(finger.front.thickness),
        "back_thickness": float(finger.back.thickness),
        "E": float(finger.material.E),
        "object_size": 18.0,
        "object_x": -11.0,
        "object_z": 60.0,
        "closing": 6.0 if closing is None else float(closing),
        "actuator_force": 5.0 if actuator_force is None else float(actuator_force),
        "friction": 0.3 if friction is None else float(friction),
        "load_scale": 1.0,
    }
    if finger.objects:
        obj = finger.objects[0]
        v["object_x"], v["object_z"] = (float(x) for x in np.asarray(obj.center))
        if isinstance(obj, Circle):
            v["object_size"] = 2.0 * float(obj.radius)
        elif isinstance(obj, RoundedRectangle):
            v["object_size"] = 2.0 * float(np.max(np.asarray(obj.half_size)))
    return v


def choices_of(finger: Finger, closing_by_force: bool = False) -> Choices:
    pinned = isinstance(finger.adaptor.front_base, PinnedBase)
    kind = (
        "square" if finger.objects and isinstance(finger.objects[0], RoundedRectangle) else "circle"
    )
    return Choices(
        mode="grasp",
        adaptor="modified" if pinned or finger.adaptor.support_length is not None else "original",
        crossbeam_count=min(max(finger.n_crossbeams, 1), MAX_CROSSBEAMS),
        object_kind=kind,
        closing="force" if closing_by_force else "displacement",
    )


def base_finger(finger: Finger, loads, choices: Choices) -> Finger:
    """The finger whose program the choices select: its adaptor's kind, `crossbeam_count`
    crossbeams, and an object of the chosen kind (grasp) or the load case (solve). Its
    values are placeholders until `finger_of` sets them."""
    if choices.adaptor == "modified":
        adaptor = Adaptor(
            front_base=PinnedBase(),
            back_base=ClampedBase(),
            back_clamp_length=20.0,
            support_length=60.0,
        )
    else:
        adaptor = Adaptor(front_base=ClampedBase(), back_base=ClampedBase())
    n = choices.crossbeam_count
    cb = finger.crossbeams
    ones = np.ones(n)
    crossbeams = Crossbeams(ones, ones, ones, ones * float(np.asarray(cb.depth).reshape(-1)[0]))
    if choices.mode == "grasp":
        obj = Circle((-11.0, 60.0), 9.0)
        if choices.object_kind == "square":
            obj = RoundedRectangle((-11.0, 60.0), (9.0, 9.0), 1.0)
        objects, loads = (obj,), ()
    else:
        objects = ()
    return eqx.tree_at(
        lambda f: (f.adaptor, f.crossbeams, f.objects, f.loads),
        finger,
        (adaptor, crossbeams, objects, tuple(loads)),
    )


def finger_of(base: Finger, choices: Choices, values: dict, base_loads=()) -> Finger:
    """The finger the values describe on `base` (from `base_finger`); traceable in the
    values. `base_loads`: the load case at scale 1 (solve mode)."""
    v = {k: jnp.asarray(x, jnp.float64) for k, x in values.items()}
    f = base
    if choices.adaptor == "modified":
        f = eqx.tree_at(
            lambda g: (g.adaptor.back_clamp_length, g.adaptor.support_length),
            f,
            (v["back_clamp_length"], v["support_length"]),
        )
    n = choices.crossbeam_count
    frac = jnp.linspace(0.0, 1.0, n) if n > 1 else jnp.zeros(1)
    front_s = v["crossbeam_first"] + (v["crossbeam_last"] - v["crossbeam_first"]) * frac
    geo = geometry(f)
    back_s = front_s * geo.length[1] / geo.length[0]  # (a start for the angle's Newton)
    cb = f.crossbeams
    f = eqx.tree_at(
        lambda g: (g.crossbeams.front_s, g.crossbeams.back_s, g.crossbeams.thickness),
        f,
        (front_s, back_s, jnp.broadcast_to(v["crossbeam_thickness"], cb.thickness.shape)),
    )
    f = set_design(
        f,
        {
            "front.thickness": v["front_thickness"],
            "back.thickness": v["back_thickness"],
            "material.E": v["E"],
            "crossbeams.angle": jnp.broadcast_to(jnp.deg2rad(v["crossbeam_angle"]), (n,)),
        },
    )
    if choices.mode == "grasp":
        center = jnp.stack([v["object_x"], v["object_z"]])
        half = 0.5 * v["object_size"]
        obj = f.objects[0]
        if isinstance(obj, Circle):
            obj = Circle(center, half)
        else:
            obj = RoundedRectangle(center, jnp.stack([half, half]), 0.1 * half)
        return eqx.tree_at(lambda g: g.objects, f, (obj,))
    return eqx.tree_at(lambda g: g.loads, f, scaled_loads(base_loads, v["load_scale"]))


def scaled_loads(loads, scale) -> tuple:
    out = []
    for load in loads:
        if isinstance(load, PointLoad):
            out.append(
                eqx.tree_at(
                    lambda x: (x.force, x.moment), load, (load.force * scale, load.moment * scale)
                )
            )
        elif isinstance(load, DistributedLoad):
            out.append(eqx.tree_at(lambda x: x.total_force, load, load.total_force * scale))
        else:
            out.append(load)
    return tuple(out)
