"""How a finger file asks to be solved: `SolveSettings` ([meta], [solver]) and
`GraspSettings` ([grasp]), the words those tables accept, and the reading of the [solver]
and [grasp] tables into them."""

from __future__ import annotations

import dataclasses

import diffrax as dfx

from ._integrator import BACKENDS, Integrator
from ._options import LINEAR_SOLVERS, SolverOptions
from ._toml_reader import FingerFileError, TomlReader

#: Integrator names accepted in [solver] integrator, and their diffrax classes.
INTEGRATORS = {
    "Tsit5": dfx.Tsit5,
    "Dopri5": dfx.Dopri5,
    "Bosh3": dfx.Bosh3,
    "Heun": dfx.Heun,
}

MODES = ("auto", "planar", "spatial")

MAX_STEPS = 10_000  # solver.steps: more is a typo (memory and compile time grow with it)
MAX_ITERATIONS = 1_000_000  # the solver's integer options (iteration and step counts)


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
    the release-force trace; release: `finray grasp` traces the release and reports the
    holding force without being asked (--release); friction: the release trace's
    Coulomb coefficient (None: the finger's [contact] friction; --friction overrides).
    """

    closing: float | None = None
    actuator_force: float | None = None
    direction: tuple = (-1.0, 0.0)
    symmetric: bool = True
    pull_step: float = 2.0
    release: bool = False
    friction: float | None = None

    def grasp_kwargs(self) -> dict:
        return {
            "closing": self.closing,
            "actuator_force": self.actuator_force,
            "direction": self.direction,
            "symmetric": self.symmetric,
        }


def solver_option_fields():
    """The SolverOptions fields a [solver] table may set (those with a default)."""
    return [f for f in dataclasses.fields(SolverOptions) if f.default is not dataclasses.MISSING]


def read_solver_table(value, r: TomlReader, name: str, description: str) -> SolveSettings:
    """The [solver] table (`value`), with [meta]'s `name` and `description`."""
    fields = solver_option_fields()
    opt_names = tuple(f.name for f in fields)
    tbl = r.table(value, "solver", ("mode", "integrator", "steps", "backend") + opt_names)
    mode = r.string(tbl.get("mode", "auto"), "solver.mode", MODES)
    integ = _read_integrator(tbl, r)
    opts = _read_options(tbl, r, fields)
    try:
        integrator = Integrator(**integ) if integ else Integrator()
        options = SolverOptions(**opts)
    except ValueError as e:
        raise FingerFileError(f"{r.source}: [solver]: {e}") from None
    return SolveSettings(mode, integrator, options, name, description)


def _read_integrator(tbl: dict, r: TomlReader) -> dict:
    """The Integrator arguments the [solver] table sets (integrator, steps, backend)."""
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
        integ["backend"] = r.choice(tbl["backend"], "solver.backend", BACKENDS)
    return integ


def _read_options(tbl: dict, r: TomlReader, fields) -> dict:
    """The SolverOptions arguments the [solver] table sets, read by each field's type."""
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
            opts[f.name] = r.choice(v, path, LINEAR_SOLVERS)
        elif isinstance(f.default, int):
            opts[f.name] = r.integer(v, path, minimum=1, maximum=MAX_ITERATIONS)
        else:
            opts[f.name] = r.number(v, path, positive=True)
    return opts


def read_grasp_table(value, r: TomlReader) -> GraspSettings:
    """The [grasp] table: exactly one of closing and actuator_force, and the options."""
    keys = ("closing", "actuator_force", "direction", "symmetric", "pull_step", "release")
    keys += ("friction",)
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
        release=r.boolean(tbl.get("release", False), "grasp.release"),
        friction=r.number(tbl["friction"], "grasp.friction", nonnegative=True)
        if "friction" in tbl
        else None,
    )
