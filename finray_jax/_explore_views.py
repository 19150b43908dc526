"""What the design explorer draws and reports for a solved state, as plain arrays and
numbers (no plotting library): the deformed finger (and its mirror image, the second
finger of a symmetric grasp) over its undeformed outline, the object, the contact
pressure along the front beam, the crossbeams' axial forces, the numbers, and the
state as a JSON document and a finger file."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ._centrelines import BACK, FRONT
from ._explore_design import Choices
from ._explore_grad import HOLDING, OBJECTIVES
from ._finger_toml import finger_to_toml
from ._geometry import arc_point, geometry
from ._objects import Circle, RoundedRectangle
from ._solution import RESULTS
from ._solve_settings import GraspSettings, SolveSettings
from ._version import __version__
from .design import OUTPUTS

DEFORMED = "#1f77b4"
MIRROR = "#7fa7c9"
OUTLINE_POINTS = 41


@jax.jit
def _outline(finger):
    """The undeformed centrelines: (2, P, 2) main beams and (C, 2, 2) crossbeams (x, z)."""
    geo = geometry(finger)
    mains = []
    for b in (FRONT, BACK):
        s = jnp.linspace(0.0, 1.0, OUTLINE_POINTS) * geo.length[b]
        mains.append(arc_point(geo.base[b], geo.theta[b], geo.curvature[b], s)[:, [0, 2]])
    cb = finger.crossbeams
    f = arc_point(geo.base[FRONT], geo.theta[FRONT], geo.curvature[FRONT], cb.front_s)
    k = arc_point(geo.base[BACK], geo.theta[BACK], geo.curvature[BACK], cb.back_s)
    return jnp.stack(mains), jnp.stack([f[:, [0, 2]], k[:, [0, 2]]], axis=1)


def _object_outline(obj, n: int = 73) -> np.ndarray:
    """(n, 2) points around an object (a circle or a rounded square)."""
    c = np.asarray(obj.center, float)
    if isinstance(obj, Circle):
        a = np.linspace(0.0, 2 * np.pi, n)
        return c + float(obj.radius) * np.stack([np.cos(a), np.sin(a)], axis=1)
    if isinstance(obj, RoundedRectangle):
        h = np.asarray(obj.half_size, float)
        return c + np.array(
            [[-h[0], -h[1]], [h[0], -h[1]], [h[0], h[1]], [-h[0], h[1]], [-h[0], -h[1]]]
        )
    return c[None, :]


@dataclasses.dataclass
class View:
    """The arrays of one state's figures (x, z in mm)."""

    lines: dict  # xs, ys, color: deformed beams (and their mirror image)
    outline: dict  # xs, ys: undeformed beams
    objects: dict  # xs, ys
    pressure: dict  # s (mm along the front beam), q (N/mm)
    crossbeams: dict  # index, force (N, axial, tension > 0)
    numbers: dict  # name -> float


def _mirror(xs, x0):
    return [2.0 * x0 - np.asarray(x) for x in xs]


def view_of(state, symmetric: bool = True) -> View:
    sol = state.solution
    beams = [sol.front.position, sol.back.position]
    beams += [p for p in np.asarray(sol.crossbeams.position)]
    xs = [np.asarray(b)[:, 0] for b in beams]
    ys = [np.asarray(b)[:, 2] for b in beams]
    mains, cbs = (np.asarray(a) for a in _outline(state.moved))
    out_xs = [m[:, 0] for m in mains] + [c[:, 0] for c in cbs]
    out_ys = [m[:, 1] for m in mains] + [c[:, 1] for c in cbs]
    colors = [DEFORMED] * len(xs)
    objects = {"xs": [], "ys": []}
    if state.contact is not None:
        for obj in state.moved.objects:
            p = _object_outline(obj)
            objects["xs"].append(p[:, 0])
            objects["ys"].append(p[:, 1])
        if symmetric and state.moved.objects:
            x0 = float(np.asarray(state.moved.objects[0].center)[0])
            n = len(xs)
            xs, ys = xs + _mirror(xs, x0), ys + ys
            out_xs, out_ys = out_xs + _mirror(out_xs, x0), out_ys + out_ys
            colors = colors + [MIRROR] * n
    s = np.asarray(sol.front.s)
    q = np.zeros_like(s) if state.contact is None else np.asarray(state.contact.pressure_front)
    cb = sol.crossbeams
    axial = np.einsum("ci,ci->c", np.asarray(cb.force)[:, 0], np.asarray(cb.frame)[:, 0, :, 2])
    return View(
        lines={"xs": xs, "ys": ys, "color": colors},
        outline={"xs": out_xs, "ys": out_ys},
        objects=objects,
        pressure={"s": s, "q": q},
        crossbeams={"index": np.arange(len(axial)).astype(float), "force": axial},
        numbers=numbers_of(state),
    )


NUMBERS = (
    ("contact_force", "contact force (one finger)", "N"),
    ("actuator_force", "actuator force", "N"),
    ("holding_force", "holding force (on request)", "N"),
    ("tip_displacement", "tip displacement", "mm"),
    ("max_strain", "largest strain", ""),
    ("closing", "closing displacement", "mm"),
    ("load_factor", "load factor", ""),
)


_max_strain = jax.jit(OUTPUTS["max_strain"])  # (many small operations: one program)


def numbers_of(state) -> dict:
    sol, finger = state.solution, state.moved
    d = np.asarray(sol.tip.displacement)
    c = state.contact
    nan = float("nan")
    return {
        "contact_force": nan if c is None else float(c.normal_force),
        "actuator_force": nan if c is None else float(c.actuator_force),
        "holding_force": nan if state.holding is None else float(state.holding),
        "tip_displacement": float(np.hypot(d[0], d[2])),
        "max_strain": float(_max_strain(sol, finger)),
        "closing": nan if state.closing is None else float(state.closing),
        "load_factor": float(sol.load_factor),
    }


def status_of(state) -> tuple[str, str]:
    """("ok" | "error", the status line) of a solved state."""
    how = "one Newton solve from the last equilibrium" if state.how == "warm" else "full solve"
    if state.converged:
        return "ok", f"{state.status} ({how}, {1e3 * state.seconds:.0f} ms)"
    keep = " The last good design stays drawn."
    if state.solution.result == RESULTS.beyond_limit_load:
        return "error", f"beyond the limit load: the finger folds under the load case.{keep}"
    if state.solution.result == RESULTS.actuator_force_not_reached:
        c = state.contact
        return "error", (
            "beyond the limit load: the actuator force asked is more than this finger "
            f"presses with (it peaks near {float(c.actuator_force):.3f} N at closing "
            f"{float(state.closing):.3f} mm).{keep}"
        )
    return "error", f"{state.status}: {state.message}{keep}"


# --------------------------------------------------------------------------------------
# Downloads
# --------------------------------------------------------------------------------------


def settings_of(state, explorer) -> SolveSettings:
    """The finger file's settings for the state: [meta] and, for a grasp, [grasp]."""
    choices: Choices = state.choices
    grasp = None
    if choices.mode == "grasp":
        by_force = choices.closing == "force"
        grasp = GraspSettings(
            closing=None if by_force else float(state.values["closing"]),
            actuator_force=float(state.values["actuator_force"]) if by_force else None,
            direction=tuple(float(x) for x in explorer.direction),
            symmetric=explorer.symmetric,
            pull_step=float(explorer.pull_step),
            friction=float(state.values["friction"]),
        )
    what = "grasp" if choices.mode == "grasp" else "load case"
    return SolveSettings(
        mode="planar",
        integrator=explorer.integrator_of(choices),
        name=f"explorer design ({what})",
        description=f"saved by finray explore (finray_jax {__version__})",
        grasp=grasp,
    )


def toml_of(state, explorer) -> str:
    """The state's design as a finger file (a grasp: with the penalty stiffnesses it was
    solved at, so that `finray grasp` solves the same model)."""
    return finger_to_toml(state.finger, settings_of(state, explorer))


def json_of(state, sensitivities=None, objective=None) -> dict:
    """The state's numbers, control values, status and (when known) gradient."""
    out = {
        "status": state.status,
        "message": state.message,
        "choices": dataclasses.asdict(state.choices),
        "values": {k: float(v) for k, v in state.values.items()},
        "numbers": {k: (None if np.isnan(v) else v) for k, v in numbers_of(state).items()},
        "solved_by": state.how,
        "seconds": state.seconds,
    }
    if state.holding is not None:
        out["holding_message"] = state.holding_message
    if sensitivities is not None and objective in OBJECTIVES:
        out["gradient"] = {"objective": objective, "d_objective": sensitivities.gradient(objective)}
    if objective == HOLDING and state.holding_gradient is not None:
        out["gradient"] = {"objective": objective, "d_objective": dict(state.holding_gradient)}
    return out
