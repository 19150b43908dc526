"""The design explorer's solves: the state of the finger on the page, re-solved from the
previous equilibrium when a control moves.

A grasp is solved at the penalty stiffnesses the explorer holds (those `grasp` chose for
the first design of a program, raised by `grasp` again whenever a penetration limit stops
holding), on the segment table of the program's first grasp, so that a moved control
never recompiles: the state shown is `grasp(finger, closing, topology=...)` of the design
with those stiffnesses written into its [contact] table (the TOML download carries them).
A moved value is re-solved by one Newton solve started from the previous equilibrium
moved along its tangent (`_explore_grad`), or else from its deformation; when that
fails, or a penetration limit no longer holds, the whole closing path is solved again
(`grasp`). A closing by actuator force always follows the closing
path. The finger's load case is solved the same way; where Newton fails, `limit_load`
says whether the load lies beyond the limit, and `solve_finger` solves it otherwise.

Choices (what is solved, the adaptor, the crossbeam count, the object's kind) select a
program; a new one compiles on its first solve.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._contact import (
    member_penetration_limit,
    penalty_stiffnesses,
    stiffness,
    support_penetration_limit,
    support_stiffness,
)
from ._contact_result import ContactResult, contact_result, with_members
from ._errors import FingerError
from ._explore_design import Choices, ControlError, active, base_finger, check_value, finger_of
from ._finger import Finger, validate_finger
from ._finger_file import load_packaged_finger
from ._grasp import grasp
from ._grasp_inputs import with_objects_moved, with_stiffness
from ._grasp_solution import GRASP_STEPS, GraspSolution
from ._integrator import Integrator
from ._release import release_force
from ._solution import RESULTS, Solution
from ._solve import (
    SolverOptions,
    direct_core,
    limit_load,
    solve_finger,
    start_from_deformation,
    topology_of,
    undeformed_unknowns,
)

_carry = jax.jit(start_from_deformation, static_argnums=0)
_members = jax.jit(with_members, static_argnums=(1, 2))
_finger_of = eqx.filter_jit(finger_of)  # (one program per choices: the values are arrays)


@dataclasses.dataclass
class Program:
    """What one set of choices compiles: its base finger, and once solved, its topology
    (segment table) and the penalty stiffnesses its grasps are solved at."""

    choices: Choices
    base: Finger
    topology: object = None
    stiffness: tuple | None = None  # (objects, support, members), N/mm^2


@dataclasses.dataclass
class State:
    """One solved design as the page shows it.

    finger: the design (objects where they stand before closing; in a grasp, with the
    penalty stiffnesses it was solved at); moved: the finger with its objects where the
    closing put them (the load case: the finger); how: "warm" (one Newton solve from the
    previous equilibrium) or "path" (the closing path, or a plain `solve_finger`)."""

    choices: Choices
    values: dict
    finger: Finger
    moved: Finger
    solution: Solution
    contact: ContactResult | None
    closing: float | None
    how: str
    seconds: float
    topology: object
    holding: float | None = None
    holding_message: str = ""
    holding_pull: float | None = None  # where the release trace's peak acts (mm)
    holding_gradient: dict | None = None  # (`_explore_grad.holding_gradient`)

    @property
    def status(self) -> str:
        return self.solution.status

    @property
    def converged(self) -> bool:
        return bool(self.solution.result == RESULTS.successful)

    @property
    def message(self) -> str:
        return "" if self.converged else RESULTS[self.solution.result]


class Explorer:
    """The explorer's session: the programs compiled so far and the last solved state.

    finger, grasp_settings: a finger file's finger and [grasp] table (None: close by 6 mm
    along -x, two fingers). loads: the load case for a plain solve (default: the
    finger's own loads, else Finger-1's, 4 N over the front beam's l5..l7)."""

    def __init__(self, finger: Finger, grasp_settings=None, loads=None):
        self.finger = finger
        self.grasp_settings = grasp_settings
        self.direction = (-1.0, 0.0) if grasp_settings is None else grasp_settings.direction
        self.symmetric = True if grasp_settings is None else grasp_settings.symmetric
        self.pull_step = 2.0 if grasp_settings is None else grasp_settings.pull_step
        if loads is None:
            loads = finger.loads or load_packaged_finger("finger1.toml")[0].loads
        self.loads = tuple(loads)
        self.integrator = Integrator(steps=GRASP_STEPS)  # a grasp's, as `grasp`'s default
        self.load_integrator = Integrator()  # the load case's, as `solve_finger`'s default
        self.options = SolverOptions()
        self.programs: dict[Choices, Program] = {}
        self.state: State | None = None  # the last converged state
        self.sensitivities = None  # (`_explore_grad.Sensitivities`) at a recent state

    # ----------------------------------------------------------------------------------

    def program(self, choices: Choices) -> Program:
        key = dataclasses.replace(choices, closing="displacement")
        if key not in self.programs:
            self.programs[key] = Program(key, base_finger(self.finger, self.loads, key))
        return self.programs[key]

    def compiled(self, choices: Choices) -> bool:
        """Whether these choices' program has been solved once (no compile to come)."""
        p = self.programs.get(dataclasses.replace(choices, closing="displacement"))
        return p is not None and p.topology is not None

    def design(self, choices: Choices, values: dict) -> Finger:
        """The checked finger the choices and values describe (ControlError or
        FingerError naming what is wrong)."""
        choices = choices.checked()
        checked = dict(values)
        for name in active(choices):
            if name not in values:
                raise ControlError(f"missing control {name!r}")
            checked[name] = check_value(name, values[name])
        prog = self.program(choices)
        arrays = {k: jnp.asarray(float(v), jnp.float64) for k, v in checked.items()}
        finger = _finger_of(prog.base, choices, arrays, self.loads)
        validate_finger(finger)
        return finger

    def solve(self, choices: Choices, values: dict) -> State:
        """Solve the design; the new state (kept as `state` when it converged). Raises
        ControlError or FingerError for a refused design."""
        t0 = time.perf_counter()
        finger = self.design(choices, values)
        prog = self.program(choices)
        prev = self.state if self.state is not None and self.state.choices == choices else None
        if choices.mode == "solve":
            state = self._solve_loads(prog, choices, values, finger, prev)
        else:
            state = self._grasp(prog, choices, values, finger, prev)
        state.seconds = time.perf_counter() - t0
        if state.converged:
            self.state = state
        return state

    def solve_aside(self, choices: Choices, values: dict) -> State:
        """Solve a design from scratch (the closing path) without making it the state."""
        kept = self.state, self.sensitivities
        self.state = self.sensitivities = None
        try:
            return self.solve(choices, values)
        finally:
            self.state, self.sensitivities = kept

    # ----------------------------------------------------------------------------------

    def _solve_loads(self, prog, choices, values, finger, prev) -> State:
        """Newton from the previous equilibrium's deformation (or the undeformed shape);
        when it fails, the limit load says whether the load case lies beyond it, and if
        not, `solve_finger`'s continuation solves it."""
        if prog.topology is None:
            prog.topology = topology_of(finger, "planar")
        topo, how = prog.topology, "warm"
        if prev is not None:
            y0 = self._start(topo, finger, values, prev)
        else:
            y0, how = undeformed_unknowns(topo, finger), "path"
        sol, ok, _ = direct_core(
            topo, self.load_integrator, self.options, finger, y0, np.float64(0.0)
        )
        if not bool(ok):
            how = "path"
            limit = limit_load(finger, integrator=self.load_integrator, topology=topo)
            if limit.found and float(limit.load_factor) < 1.0:
                sol = eqx.tree_at(lambda s: s.result, limit.solution, RESULTS.beyond_limit_load)
            else:
                sol = solve_finger(finger, integrator=self.load_integrator, topology=topo)
        sol.max_residual.block_until_ready()
        return State(choices, dict(values), finger, finger, sol, None, None, how, 0.0, topo)

    def _grasp(self, prog, choices, values, finger, prev) -> State:
        # (explicit from the first grasp on: one compiled program for every grasp)
        ks = prog.stiffness
        if ks is None:
            ks = penalty_stiffnesses(finger)
        finger = with_stiffness(finger, *ks)
        w = jnp.asarray(self.direction, jnp.float64)
        closing = float(values["closing"])
        if choices.closing == "displacement" and prev is not None and prog.topology is not None:
            found = self._warm(prog, finger, values, w, prev)
            if found is not None:
                moved, sol, res = found
                return State(
                    choices,
                    dict(values),
                    finger,
                    moved,
                    sol,
                    res,
                    closing,
                    "warm",
                    0.0,
                    prog.topology,
                )
        how = {"closing": closing}
        if choices.closing == "force":
            how = {"actuator_force": float(values["actuator_force"])}
        g = grasp(
            finger,
            **how,
            direction=self.direction,
            symmetric=self.symmetric,
            integrator=self.integrator,
            options=self.options,
            topology=prog.topology,
        )
        if prog.topology is None:
            prog.topology = g.topology
        ks = (float(g.stiffness), float(g.support_stiffness), float(g.member_stiffness))
        finger = with_stiffness(finger, *ks)
        if g.converged:
            prog.stiffness = ks
        return State(
            choices,
            dict(values),
            finger,
            g.finger,
            g.solution,
            g.contact,
            float(g.closing),
            "path",
            0.0,
            g.topology,
        )

    def integrator_of(self, choices: Choices) -> Integrator:
        return self.integrator if choices.mode == "grasp" else self.load_integrator

    def _start(self, topo, finger, values, prev):
        """Newton's start for new values: the tangent's prediction from the sensitivities
        at a recent state of the same program, else prev's deformation carried over."""
        sens = self.sensitivities
        if sens is not None and sens.choices == prev.choices:
            return jnp.asarray(sens.predict(values))
        return _carry(topo, finger, prev.solution.deformation)

    def _warm(self, prog, finger, values, w, prev):
        """One Newton solve from the tangent's prediction (the sensitivities at the
        previous state, when known) or else from prev's deformation: (moved, solution,
        contact), or None when it fails or a penetration limit does not hold."""
        moved = with_objects_moved(finger, -float(values["closing"]) * w)
        y0 = self._start(prog.topology, moved, values, prev)
        sol, ok, _ = direct_core(
            prog.topology, self.integrator, self.options, moved, y0, np.float64(0.0)
        )
        if not bool(ok):
            return None
        res = contact_result(moved, sol, w)
        res = _members(res, prog.topology, self.integrator, moved, sol)
        limits = (
            float(moved.contact.max_penetration * moved.front.thickness),
            float(support_penetration_limit(moved)),
            float(member_penetration_limit(moved)),
        )
        pens = (res.max_penetration, res.support_penetration, res.member_penetration)
        if any(float(p) > lim for p, lim in zip(pens, limits)):
            return None
        return moved, sol, res

    # ----------------------------------------------------------------------------------

    def grasp_solution(self, state: State) -> GraspSolution:
        """The state as a `GraspSolution` (a grasp's state)."""
        if state.contact is None:
            raise FingerError("the load case has no grasp: switch to the grasp")
        f = state.moved
        return GraspSolution(
            state.solution,
            state.contact,
            f,
            jnp.asarray(state.closing),
            jnp.asarray(stiffness(f)),
            jnp.asarray(support_stiffness(f)),
            self.integrator.steps,
            2 if self.symmetric else 1,
            state.topology,
            tuple(float(x) for x in np.asarray(self.direction) / np.linalg.norm(self.direction)),
            self.integrator,
        )

    def holding(self, state: State) -> State:
        """The state with its holding force (the release trace's peak, friction as the
        page says); slower: it follows the pull until the contact is lost. The trace is
        solved on the state's segment table, as the grasp is."""
        g = self.grasp_solution(state)
        trace = release_force(
            g,
            step=self.pull_step,
            friction=float(state.values["friction"]),
            integrator=self.integrator,
            topology=state.topology,
        )
        return dataclasses.replace(
            state,
            holding=float(trace.peak),
            holding_message=str(trace.message),
            holding_pull=float(trace.peak_pull),
        )
