"""The design explorer's sensitivities: at a solved state, the derivatives of the
equilibrium's unknowns and of every objective with respect to every design value on the
page, in one compiled program per topology (forward mode through the implicit function
theorem: one factorisation, a back substitution per value).

They serve twice: the objectives' gradients are the page's "which way is better" bars,
and the unknowns' derivatives predict the next equilibrium when a control moves (Newton
then starts from the tangent's prediction, not from the previous equilibrium).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._contact import friction_may_act, penalty_stiffnesses, with_friction
from ._contact_result import contact_result
from ._errors import FingerError
from ._explore_design import Choices, design_values, finger_of
from ._grasp_inputs import with_contact, with_objects_moved, with_stiffness
from ._objective import Static, objective_of
from ._release import pulled_to
from ._solution import RESULTS
from ._solve import direct_core
from .design import OUTPUTS

# The objectives, in the order of the program's outputs.
OBJECTIVES = ("contact force", "tip displacement", "largest strain")
HOLDING = "holding force"  # (on request, value and gradient: `holding_gradient`)


@dataclasses.dataclass
class Sensitivities:
    """At values x (names): the unknowns Y, the objectives, and their derivatives."""

    choices: Choices
    names: tuple
    x: np.ndarray
    unknowns: np.ndarray
    objectives: np.ndarray  # (len(OBJECTIVES),); NaN where it does not apply
    d_unknowns: np.ndarray  # (n_unknowns, len(names))
    d_objectives: np.ndarray  # (len(OBJECTIVES), len(names))

    def gradient(self, objective: str) -> dict:
        i = OBJECTIVES.index(objective)
        return dict(zip(self.names, self.d_objectives[i].tolist()))

    def predict(self, values: dict) -> np.ndarray:
        """The unknowns at other values, to first order."""
        dx = np.asarray([float(values[n]) for n in self.names]) - self.x
        return self.unknowns + self.d_unknowns @ dx


def tip_displacement(sol):
    d = sol.tip.displacement
    return jnp.sqrt(d[0] ** 2 + d[2] ** 2 + 1e-30)


def penalties(state):
    """The penalty stiffnesses (objects, support, members) a grasp's state was solved at:
    its own finger's, which the program's may have left behind since (raised by a later
    grasp whose penetration limit did not hold). Zeros for the load case (unused)."""
    if state.choices.mode != "grasp":
        return jnp.zeros(3, jnp.float64)
    return jnp.asarray(penalty_stiffnesses(state.finger), jnp.float64)


@eqx.filter_jit
def _sensitivities(static, base, loads, fixed, ks, x, y0):
    topo, integrator, options, choices, names, direction = static
    w = jnp.asarray(direction, jnp.float64)

    def outputs(x):
        values = {**fixed, **dict(zip(names, x))}
        finger = finger_of(base, choices, values, loads)
        if choices.mode == "grasp":
            finger = with_stiffness(finger, *ks)
            finger = with_objects_moved(finger, -values["closing"] * w)
        sol, _, _ = direct_core(topo, integrator, options, finger, y0, jnp.zeros(()))
        force = jnp.full((), jnp.nan)
        if choices.mode == "grasp":
            force = contact_result(finger, sol, w).normal_force
        objs = jnp.stack([force, tip_displacement(sol), OUTPUTS["max_strain"](sol, finger)])
        out = (sol.unknowns, objs)
        return out, out

    (d_y, d_obj), (y, obj) = jax.jacfwd(outputs, has_aux=True)(x)
    return y, obj, d_y, d_obj


def sensitivities(explorer, state) -> Sensitivities:
    """The sensitivities at a solved state of `explorer` (`_explore_model.Explorer`)."""
    choices: Choices = state.choices
    names = tuple(design_values(choices))
    fixed = {k: jnp.asarray(float(v), jnp.float64) for k, v in state.values.items()}
    if choices.mode == "grasp":
        fixed["closing"] = jnp.asarray(float(state.closing), jnp.float64)
    prog = explorer.program(choices)
    static = (
        state.topology,
        explorer.integrator_of(choices),
        explorer.options,
        choices,
        names,
        tuple(float(v) for v in explorer.direction),
    )
    x = np.asarray([float(fixed[n]) for n in names])
    y, obj, d_y, d_obj = _sensitivities(
        static,
        prog.base,
        explorer.loads,
        fixed,
        penalties(state),
        jnp.asarray(x),
        state.solution.unknowns,
    )
    return Sensitivities(
        choices, names, x, np.asarray(y), np.asarray(obj), np.asarray(d_y), np.asarray(d_obj)
    )


@eqx.filter_jit
def _holding(static, choices, names, base, fixed, ks, x, y0, friction):
    def value(x):
        values = {**fixed, **dict(zip(names, x))}
        finger = with_stiffness(finger_of(base, choices, values), *ks)
        finger = with_contact(finger, friction=friction, slip_direction=jnp.asarray(static.pull))
        v, sol = objective_of(static, finger, y0, ks, values["closing"], fixed["pull"])[:2]
        return v, sol.result

    (v, result), grad = jax.value_and_grad(value, has_aux=True)(x)
    return v, result, grad


def holding_gradient(explorer, state) -> tuple[float, dict]:
    """The derivatives of a grasp's holding force (`Explorer.holding` computed it: the
    release trace's peak) in every design value: the optimiser's holding-force objective
    (`_objective.objective_of`) at the peak's pull, held, differentiated by one implicit
    solve (reverse mode). Returns (the holding force there, the gradient); FingerError
    when the pull cannot be followed to the peak again."""
    choices: Choices = state.choices
    g = explorer.grasp_solution(state)
    friction = float(state.values["friction"])
    pull_direction = (0.0, 1.0)  # (the release trace's)
    sol, pulled, ok = pulled_to(
        g,
        state.holding_pull,
        pull_direction=pull_direction,
        step=explorer.pull_step,
        friction=friction,
        topology=state.topology,
    )
    if not ok:
        raise FingerError(f"the pull could not be followed to its peak at {state.holding_pull} mm")
    topology = state.topology
    if friction_may_act(pulled.contact):
        topology = with_friction(topology)
    static = Static(
        names=(),
        objective="holding_force",
        aggregate="mean",
        constraints=(),
        topology=topology,
        direction=g.direction,
        pull=pull_direction,
        holding_factor=g.holding_factor,
        integrator=explorer.integrator,
        options=explorer.options,
    )
    names = tuple(design_values(choices))
    fixed = {k: jnp.asarray(float(v), jnp.float64) for k, v in state.values.items()}
    fixed["closing"] = jnp.asarray(float(state.closing), jnp.float64)
    fixed["pull"] = jnp.asarray(float(state.holding_pull), jnp.float64)
    x = jnp.asarray([float(fixed[n]) for n in names])
    base = explorer.program(choices).base
    mu = jnp.asarray(friction, jnp.float64)
    ks = penalties(state)
    v, result, grad = _holding(static, choices, names, base, fixed, ks, x, sol.unknowns, mu)
    if not bool(result == RESULTS.successful):
        raise FingerError(f"the holding force's gradient: {RESULTS[result]}")
    return float(v), dict(zip(names, np.asarray(grad).tolist()))
