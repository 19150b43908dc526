"""The root's tangents by the implicit function theorem.

At a root y of r(y; design, lam) = 0, dy = -J^-1 (dr/d(design, lam)) d(design, lam). The
banded solver's rule (`attach_implicit_gradient`) computes it in one forward pass at the
root that integrates every segment with the Jacobians of all its step points
(`flow_jacobians`): the end points' Jacobians give J (from the colour seeds) and
dr/d(design, lam); the banded LU of J solves for dy; all the points' Jacobians then give
the trajectories' tangents, so the outputs never differentiate through the integrator.
The dense option goes through optimistix's implicit JVP with a dense LU instead, and its
outputs differentiate through the integrator.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax import lax

from . import _banded
from ._assembly import Problem
from ._flow import apply_flow_jacobians, flow_jacobians
from ._options import BandedLinearSolver
from ._steps import natural_residual


def _root_primal(inputs):
    _, _, y = inputs
    return y, None


def _root_rewrite(root, residual, inputs):
    del residual
    problem, lam, _ = inputs
    return natural_residual(root, (problem, lam))


def attach_implicit_gradient(problem, lam, y, linear_solver):
    """Return y (a root of the residual) with tangents from the implicit function theorem,
    dy = -J^-1 (dr/d(design, lam)) d(design, lam), and the segments' trajectories at it
    (S, steps + 1, n_full) with their tangents, or None (the dense option: the outputs
    then integrate them, and differentiate through the integrator)."""
    y = lax.stop_gradient(y)
    if isinstance(linear_solver, BandedLinearSolver):
        return _implicit_root(problem, lam, y)
    root, _ = optx.internal.implicit_jvp(
        _root_primal, _root_rewrite, (problem, lam, y), frozenset(), lx.LU()
    )
    return root, None


def _root_trajectories(problem, lam, y):
    return problem.integrated(y.reshape(problem.table.length.shape[0], -1), lam)


@eqx.filter_custom_jvp
def _implicit_root(problem, lam, y):
    return y, _root_trajectories(problem, lam, y)


@_implicit_root.def_jvp
def _implicit_root_jvp(primals, tangents):
    """One forward pass at the root integrates every segment with the Jacobians of all its
    step points (`flow_jacobians`). The end points' Jacobians give J (from the colour
    seeds) and dr/d(design, lam); the banded LU of J solves for dy; all the points'
    Jacobians then give the trajectories' tangents, so the outputs never differentiate
    through the integrator. Everything is linear in the tangents and built of
    transposable operations (gathers, einsums, triangular solves, static loops), so
    reverse mode transposes it."""
    problem, lam, y = primals
    d_problem, d_lam, _ = tangents
    if not _has_tangent((d_problem, d_lam)):
        traj = _root_trajectories(problem, lam, y)
        return (y, traj), (jnp.zeros_like(y), jnp.zeros_like(traj))
    md, S = problem.model, problem.table.length.shape[0]
    dyn, static = eqx.partition((problem, lam), eqx.is_inexact_array)
    d_dyn = jax.tree_util.tree_map(
        lambda x, t: None if x is None else (jnp.zeros_like(x) if t is None else t),
        dyn,
        (d_problem, d_lam),
        is_leaf=lambda x: x is None,
    )
    zero_dyn = jax.tree_util.tree_map(jnp.zeros_like, dyn)

    def setup(a, d):
        p, l = eqx.combine(d, static)
        return p.start_states(a.reshape(S, -1)), p.params(l)

    def residual(starts, ends, d):
        p, l = eqx.combine(d, static)
        return p.residual_from_states(starts, ends, l)

    (starts, Q), setup_jvp = jax.linearize(setup, y, dyn)
    cols = _live_param_columns(problem, d_problem, d_lam)
    traj, jac_y, jac_q = flow_jacobians(
        md, problem.integrator, starts, Q, need_q=cols.size > 0, save_all=True, q_columns=cols
    )
    _, residual_jvp = jax.linearize(residual, starts, traj[:, -1], dyn)

    def flow_dot(d_starts, dQ, at=slice(None)):
        jq = None if jac_q is None else jac_q[:, at]
        dQ = None if jac_q is None else dQ
        return apply_flow_jacobians(md, starts, d_starts, dQ, jac_y[:, at], jq, cols)

    def r_dot(da, dd):
        d_starts, dQ = setup_jvp(da, dd)
        return residual_jvp(d_starts, flow_dot(d_starts, dQ, -1), dd)

    plan = problem.topo.band
    JS = _banded.seeded(plan, lambda c: r_dot(c, zero_dyn), y.dtype)
    fac = lax.stop_gradient(_banded.factor(plan, _banded.band(plan, JS)))
    dy = -_banded.solve_factored(plan, fac, r_dot(jnp.zeros_like(y), d_dyn))
    d_starts, dQ = setup_jvp(dy, d_dyn)
    return (y, traj), (dy, flow_dot(d_starts, dQ))


def _has_tangent(tangents) -> bool:
    """Whether a tree of custom-JVP tangents holds any that is not None or a symbolic zero."""
    zero = jax.custom_derivatives.SymbolicZero
    leaves = jax.tree_util.tree_leaves(tangents, is_leaf=lambda x: x is None)
    return any(not (t is None or isinstance(t, zero)) for t in leaves)


def _live_param_columns(problem: Problem, d_problem, d_lam) -> np.ndarray:
    """The columns of `Problem.params` that the tangents can change (static): those fed by
    a segment-table field that has a tangent (the forces also by a load-factor tangent).
    Found by packing a table of 0/1 flags; the flow is differentiated in these only (a
    design gradient leaves e.g. the loads and precurvatures alone)."""
    table = problem.table
    d_table = getattr(d_problem, "table", None)
    flags = {
        f.name: _has_tangent(getattr(d_table, f.name, None)) for f in dataclasses.fields(table)
    }
    flags["force"] = flags["force"] or _has_tangent(d_lam)
    mask = type(table)(
        **{k: np.full(np.shape(getattr(table, k)), float(on)) for k, on in flags.items()}
    )
    with jax.ensure_compile_time_eval():
        packed = np.asarray(problem.model.pack(mask))
    return np.flatnonzero(np.any(packed != 0.0, axis=0))
