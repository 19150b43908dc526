"""The traced objective of the design optimiser (finray_jax.optimizer): one implicit
Newton solve of each object's grasp at design x, the constraint margins, the smooth
aggregate over objects and the exterior penalties. Pure JAX: no files, no logging."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._contact_result import contact_result
from ._finger import BACK, FRONT, Finger
from ._grasp_inputs import with_objects_moved, with_stiffness
from ._integrator import Integrator
from ._solution import RESULTS
from ._solve import SolverOptions, direct_core
from .design import design_valid, main_beam_strain
from .design import set_design as _set_design

OBJECTIVES = ("contact_force", "holding_force")
AGGREGATES = ("mean", "worst")
CONSTRAINTS = ("min_thickness", "min_spacing", "crossing", "max_strain", "max_pressure")


# --------------------------------------------------------------------------------------
# The traced objective
# --------------------------------------------------------------------------------------


class Static(eqx.Module):
    """What fixes the compiled program: names, kinds, topology, solver settings."""

    names: tuple = eqx.field(static=True)
    objective: str = eqx.field(static=True)
    aggregate: str = eqx.field(static=True)
    constraints: tuple = eqx.field(static=True)  # the active ones, in CONSTRAINTS order
    topology: object = eqx.field(static=True)
    direction: tuple = eqx.field(static=True)  # closing direction w (x, z)
    pull: tuple = eqx.field(static=True)  # pull direction (x, z)
    holding_factor: int = eqx.field(static=True)
    integrator: Integrator
    options: SolverOptions


class Data(eqx.Module):
    """The problem's numbers (arrays: changing them never recompiles)."""

    bases: Finger  # the base finger of every object, stacked on a leading axis
    lo: jax.Array
    hi: jax.Array
    limits: jax.Array  # (5,) per CONSTRAINTS; unused entries are ignored
    scales: jax.Array  # (5,) what a relative margin of 1 means, per CONSTRAINTS
    objective_scale: jax.Array  # the initial design's objective (normalises the loss)
    temperature: jax.Array  # worst case: smooth-min temperature, relative to objective_scale
    weight: jax.Array  # penalty weight
    shift: jax.Array  # relative inward shift of every constraint in the penalty


class Anchors(eqx.Module):
    """Per object (leading axis): the warm start of Newton and the grasp's state."""

    unknowns: jax.Array
    stiffness: jax.Array  # (objects, 2): the objects' and the support's k
    closing: jax.Array
    pull: jax.Array  # the peak pull t* (holding force; 0 for the contact force)


def design_of(data: Data, z):
    return data.lo + (data.hi - data.lo) * jax.nn.sigmoid(z)


def z_of(data_lo, data_hi, x):
    u = (np.asarray(x, float) - data_lo) / (data_hi - data_lo)
    return np.log(u) - np.log1p(-u)


def _values(static: Static, x) -> dict:
    return {n: x[j] for j, n in enumerate(static.names)}


def _solve_one(static: Static, base: Finger, x, unknowns, stiffness, closing, pull):
    """The grasp of one object at design x: (objective value, solution, moved finger,
    pressures front/back)."""
    return objective_of(
        static, _set_design(base, _values(static, x)), unknowns, stiffness, closing, pull
    )


def objective_of(static: Static, finger: Finger, unknowns, stiffness, closing, pull):
    """The objective of one designed finger's grasp (its object closed by `closing` along
    static.direction, then pulled by `pull` along static.pull; penalty stiffnesses
    (objects, support)), by one implicit Newton solve from `unknowns`, differentiable in
    the finger: (objective value, solution, moved finger, pressures front/back). The
    holding force is its value at the peak pull, held (the peak's own move does not change
    it to first order)."""
    w, e = jnp.asarray(static.direction), jnp.asarray(static.pull)
    moved = with_stiffness(
        with_objects_moved(finger, -closing * w + pull * e), stiffness[0], stiffness[1]
    )
    sol, _, _ = direct_core(static.topology, static.integrator, static.options, moved, unknowns)
    res = contact_result(moved, sol, w)
    if static.objective == "contact_force":
        value = res.normal_force
    else:
        value = static.holding_factor * jnp.dot(res.force[::2], e)
    return value, sol, moved, res.pressure_front, res.pressure_back


def _design_margins(static: Static, data: Data, finger: Finger):
    """Relative margins (arrays; >= 0 is feasible) and true margins (physical units) of
    the constraints that depend on the design alone."""
    rel, true = {}, {}
    cb = finger.crossbeams
    C = cb.front_s.shape[0]
    lim = dict(zip(CONSTRAINTS, data.limits))
    sc = dict(zip(CONSTRAINTS, data.scales))
    if "min_thickness" in static.constraints:
        t = [finger.front.thickness, finger.back.thickness]
        t += [s.tip_thickness for s in (finger.front, finger.back) if s.tip_thickness is not None]
        t = jnp.concatenate([jnp.stack(t), cb.thickness])
        m = t - lim["min_thickness"]
        rel["min_thickness"], true["min_thickness"] = m / sc["min_thickness"], jnp.min(m)
    if C >= 2 and "min_spacing" in static.constraints:
        mean_t = 0.5 * (cb.thickness[1:] + cb.thickness[:-1])
        gaps = jnp.concatenate([jnp.diff(cb.front_s), jnp.diff(cb.back_s)])
        m = gaps - jnp.concatenate([mean_t, mean_t]) - lim["min_spacing"]
        rel["min_spacing"], true["min_spacing"] = m / sc["min_spacing"], jnp.min(m)
    if C >= 2 and "crossing" in static.constraints:
        m = jnp.concatenate([jnp.diff(cb.front_s), jnp.diff(cb.back_s)])
        rel["crossing"], true["crossing"] = m / sc["crossing"], jnp.min(m)
    return rel, true


def _state_margins(static: Static, data: Data, fingers, sols, pf, pb):
    """Strain and pressure margins over every point of every object's grasp (vmapped
    inputs: leading axis = object)."""
    rel, true = {}, {}
    lim = dict(zip(CONSTRAINTS, data.limits))
    sc = dict(zip(CONSTRAINTS, data.scales))
    if "max_strain" in static.constraints:
        strain = jax.vmap(
            lambda s, f: jnp.concatenate(
                [main_beam_strain(s, f, FRONT), main_beam_strain(s, f, BACK)]
            )
        )(sols, fingers)
        m = lim["max_strain"] - strain
        rel["max_strain"], true["max_strain"] = m / sc["max_strain"], jnp.min(m)
    if "max_pressure" in static.constraints:
        p = jnp.concatenate(
            [pf / fingers.front.depth[:, None], pb / fingers.back.depth[:, None]], axis=1
        )
        m = lim["max_pressure"] - p
        rel["max_pressure"], true["max_pressure"] = m / sc["max_pressure"], jnp.min(m)
    return rel, true


def _aggregate(static: Static, data: Data, values):
    """(smooth aggregate for the loss, true aggregate to report)."""
    if static.aggregate == "mean" or values.shape[0] == 1:
        m = jnp.mean(values) if static.aggregate == "mean" else values[0]
        return m, m
    T = data.temperature * data.objective_scale
    smooth = -T * jax.nn.logsumexp(-values / T)  # in [min - T log n, min]
    return smooth, jnp.min(values)


def _loss(z, static: Static, data: Data, anchors: Anchors):
    x = design_of(data, z)
    solve = lambda b, u, k, d, t: _solve_one(static, b, x, u, k, d, t)
    values, sols, moved, pf, pb = jax.vmap(solve)(
        data.bases, anchors.unknowns, anchors.stiffness, anchors.closing, anchors.pull
    )
    smooth, agg = _aggregate(static, data, values)
    first = jax.tree_util.tree_map(lambda a: a[0], moved)
    rel, true = _design_margins(static, data, first)
    r2, t2 = _state_margins(static, data, moved, sols, pf, pb)
    rel, true = {**rel, **r2}, {**true, **t2}
    penalty = jnp.zeros(())
    for m in rel.values():
        penalty = penalty + jnp.sum(jax.nn.relu(data.shift - m) ** 2)
    loss = -smooth / data.objective_scale + data.weight * penalty
    valid = design_valid(first, static.topology)
    ad = first.adaptor
    if ad.support_length is not None:
        valid = valid & (ad.support_length >= ad.back_clamp_length)
    aux = {
        "x": x,
        "values": values,
        "objective": agg,
        "penalty": penalty,
        "margins": true,
        "valid": valid,
        "converged": sols.result == RESULTS.successful,
        "unknowns": sols.unknowns,
    }
    return loss, aux


loss_and_grad = eqx.filter_jit(jax.value_and_grad(_loss, has_aux=True))
loss_only = eqx.filter_jit(_loss)


@eqx.filter_jit
def pull_slope(z, static: Static, data: Data, anchors: Anchors):
    """Per object: F(t), dF/dt at the anchors' pulls, and the equilibria (holding force)."""
    x = design_of(data, z)

    def one(b, u, k, d, t):
        def f(t):
            value, sol = _solve_one(static, b, x, u, k, d, t)[:2]
            return value, (sol.unknowns, sol.result == RESULTS.successful)

        value, slope, (unknowns, ok) = jax.jvp(f, (t,), (jnp.ones_like(t),), has_aux=True)
        return value, slope, unknowns, ok

    return jax.vmap(one)(
        data.bases, anchors.unknowns, anchors.stiffness, anchors.closing, anchors.pull
    )
