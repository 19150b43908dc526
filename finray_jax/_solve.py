"""Newton shooting with load continuation, fold detection and the limit load."""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax

from . import _banded
from ._assembly import Problem
from ._contact import check_friction
from ._continuation import continuation, path, stopped
from ._cuts import build_topology
from ._finger import (
    BACK,
    FRONT,
    Finger,
    check_mode_carries_loads,
    loads_in_plane,
    validate_finger,
)
from ._geometry import arc_point, geometry
from ._implicit import attach_implicit_gradient
from ._integrator import Integrator
from ._newton import WarmStart, linear_solver_of, on_branch, solve_root
from ._options import MODES, BandedLinearSolver, SolverOptions
from ._rotation import log_so3, planar_frame
from ._segment_table import segment_table
from ._solution import (
    RESULTS,
    BeamSolution,
    Solution,
    Tip,
    stack_beams,
)
from ._steps import natural_residual
from ._types import check_x64


def newton_step(problem, lam, y, linear_solver):
    """The Newton step J^-1 r at y, the residual r and the sign of det J."""
    solver = linear_solver_of(problem, linear_solver)
    r, factors, sign = solver.linearise(lambda y: natural_residual(y, (problem, lam)), y)
    return solver.apply(factors, r), r, sign


# --------------------------------------------------------------------------------------
# The jitted cores
# --------------------------------------------------------------------------------------


def make_problem(topo, integrator, finger) -> Problem:
    geo = geometry(finger)
    return Problem(topo, integrator, finger, geo, segment_table(topo, finger, geo))


def nograd(tree):
    return jax.tree_util.tree_map(lambda x: lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


def _direct(quiet: Problem, y_start, options, ref_sign=None, chord=None):
    """Newton at full load, and whether it is accepted (`on_branch`)."""
    direct = solve_root(quiet, y_start, jnp.ones(()), options, chord=chord)
    return direct, on_branch(direct, ref_sign)


def _start(problem, init):
    """The undeformed unknowns, Newton's start and its chord factors (`WarmStart`, or
    None) from a core's `init`: None (undeformed), scaled unknowns or a WarmStart."""
    y_und = problem.undeformed().reshape(-1)
    if init is None:
        return y_und, y_und, None
    if isinstance(init, WarmStart):
        return y_und, lax.stop_gradient(init.unknowns), lax.stop_gradient(init)
    return y_und, lax.stop_gradient(init), None


# The cores are jitted with jax.jit, their first three arguments (topology, integrator,
# options) static: its C++ dispatch flattens the finger and builds the Solution several
# times faster than eqx.filter_jit, whose per-call overhead is large for a call this small.
_core_jit = functools.partial(jax.jit, static_argnums=(0, 1, 2))


@functools.partial(_core_jit, static_argnames=("keep_jacobian",))
def direct_core(
    topo,
    integrator,
    options: SolverOptions,
    finger: Finger,
    init,
    ref_sign=None,
    keep_jacobian=False,
):
    """Only the direct Newton solve (compiles in about half the time of `solve_core`);
    `solve_finger` falls back to the continuation when it is not accepted.

    init: None, scaled unknowns or a `WarmStart`. ref_sign: the sign of det J on the
    branch being followed (see `_direct`; 0 or None: the sign at Newton's start).
    keep_jacobian: return the factors of Newton's last linearisation in
    `Solution.jacobian` (banded solver only; what a warm start from this solution
    begins with). Returns (Solution, accepted, sign of det J at the root)."""
    problem = make_problem(topo, integrator, finger)
    quiet = nograd(problem)
    _, y_start, chord = _start(quiet, init)
    direct, ok = _direct(quiet, y_start, options, ref_sign, chord)
    one = jnp.ones(())
    y, traj = attach_implicit_gradient(problem, one, direct.y, options.linear_solver)
    code = RESULTS.where(ok, RESULTS.successful, RESULTS.nonlinear_divergence)
    code = RESULTS.where(direct.ok & ~ok, RESULTS.branch_changed, code)
    code = RESULTS.where(direct.outside, RESULTS.contact_outside_near_segments, code)
    keep = keep_jacobian and isinstance(options.linear_solver, BandedLinearSolver)
    jacobian = lax.stop_gradient(direct.factors) if keep else None
    sol = _outputs(problem, y, one, code, direct.k, traj, jacobian)
    return sol, ok, direct.sign


def _carry_scale(problem: Problem):
    """Physical units of the unknowns, forces and moments per unit of the finger's
    Young's modulus (mm^2, mm^3): what a deformation is carried in."""
    geo = problem.geo
    return problem.model.unknown_scale(geo.L, geo.F / problem.finger.material.E)


def _deformation(problem: Problem, Y):
    return (Y - problem.undeformed()) * _carry_scale(problem)


@functools.partial(jax.jit, static_argnums=(0,))
def deformation_of(topo, finger: Finger, unknowns):
    """The deformation that scaled unknowns carry, (S, n_unknown): each segment's start
    state minus its undeformed one, that is its displacement and rotation (mm, rad) and
    its internal force and moment (zero undeformed) divided by the finger's Young's
    modulus E (mm^2, mm^3)."""
    problem = make_problem(topo, None, finger)
    return _deformation(problem, unknowns.reshape(problem.table.length.shape[0], -1))


def start_from_deformation(topo, finger: Finger, deformation):
    """Scaled unknowns of `finger` deformed as `deformation` says (from `deformation_of`
    on another finger of the same topology): every segment's undeformed start state plus
    the other finger's displacement, rotation and internal wrench per unit E at its own
    segment start. For a changed design this is a better Newton start than the other
    finger's unknowns themselves, which also carry its undeformed geometry (a crossbeam
    moved by 1 mm puts that start 1 mm off).

    Forces travel per unit E: for a change of E alone the start is then the other
    finger's equilibrium at loads scaled by the ratio of the moduli, an equilibrium of
    this design (forces carried in newtons would not be); a change of a thickness keeps
    the forces (carried as scaled unknowns, in units of EI_front / L^2, they would
    change with the front beam's thickness). Iteration counts: benchmarks/README.md."""
    problem = make_problem(topo, None, finger)
    return (problem.undeformed() + deformation / _carry_scale(problem)).reshape(-1)


@functools.partial(jax.jit, static_argnums=(0,))
def undeformed_unknowns(topo, finger: Finger):
    """The scaled unknowns of the undeformed finger (the start `init=None` means): a
    caller that passes them instead of None shares one compiled core for both starts."""
    return make_problem(topo, None, finger).undeformed().reshape(-1)


@_core_jit
def solve_core(topo, integrator, options: SolverOptions, finger: Finger, init):
    """Direct Newton, else arc-length continuation and Newton again from the point it
    reached, all traced (for jit, vmap, grad): one loop, one Newton (`path`)."""
    problem = make_problem(topo, integrator, finger)
    quiet = nograd(problem)
    y_und, y_start, chord = _start(quiet, init)
    st = path(quiet, y_start, y_und, options, chord, 0 if options.direct_first else 1)
    y, traj = attach_implicit_gradient(problem, st.lam, st.y, options.linear_solver)
    return _outputs(problem, y, st.lam, st.code, st.iterations, traj)


@_core_jit
def limit_core(topo, integrator, options: SolverOptions, finger: Finger):
    problem = nograd(make_problem(topo, integrator, finger))
    y_und = problem.undeformed().reshape(-1)
    s = continuation(problem, y_und, jnp.asarray(jnp.inf), options)
    code = RESULTS.where(s.near_fold, RESULTS.successful, stopped(s))
    return s.lam, _outputs(problem, s.y, s.lam, code, s.iterations)


def _outputs(problem: Problem, y, lam, code, iterations, traj=None, jacobian=None) -> Solution:
    """The Solution at y; `traj`: the segments' integrated states, when already known;
    `jacobian`: Newton's last factors, if kept. (The residual is a diagnostic: it is
    evaluated without tangents.)"""
    topo, md, geo = problem.topo, problem.model, problem.geo
    S = problem.table.length.shape[0]
    Y = y.reshape(S, -1)
    s, traj = problem.trajectories(Y, lam, traj)
    # The residual from the trajectories' ends (no second integration).
    q_problem, q_traj, q_lam = nograd((problem, traj, lam))
    r = q_problem.residual_from_states(q_traj[:, 0], q_traj[:, -1], q_lam)

    st = traj.reshape(-1, traj.shape[-1])
    every = BeamSolution.pack(  # every point at once, then the beams are sliced from it
        s.reshape(-1),
        jax.vmap(md.position)(st),
        jax.vmap(md.frame)(st),
        jax.vmap(md.force)(st),
        jax.vmap(md.moment)(st),
    ).data.reshape(*traj.shape[:2], -1)

    def beam(b):
        a, z = topo.first[b], topo.last[b] + 1
        return BeamSolution(every[a:z].reshape(-1, every.shape[-1]))

    front, back = beam(FRONT), beam(BACK)
    cbs = [beam(2 + j) for j in range(topo.n_crossbeams)]
    crossbeams = stack_beams(cbs) if cbs else _empty_beams(front)

    tip0 = arc_point(geo.base[FRONT], geo.theta[FRONT], geo.curvature[FRONT], geo.length[FRONT])
    theta_tip0 = geo.theta[FRONT] + geo.curvature[FRONT] * geo.length[FRONT]
    rot = log_so3(front.frame[-1] @ planar_frame(theta_tip0).T)
    tip = Tip.pack(front.position[-1], front.position[-1] - tip0, rot)
    return Solution(
        result=code,
        load_factor=lam,
        iterations=iterations,
        max_residual=jnp.max(jnp.abs(r)),
        front=front,
        back=back,
        crossbeams=crossbeams,
        tip=tip,
        unknowns=y,
        deformation=_deformation(problem, Y),
        mode=topo.mode,
        steps=problem.integrator.steps,
        jacobian=jacobian,
    )


def _empty_beams(like: BeamSolution):
    return BeamSolution(jnp.zeros((0,) + like.data.shape, like.data.dtype))


# --------------------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------------------


def _is_concrete(finger) -> bool:
    leaves = jax.tree_util.tree_leaves(finger)
    return not any(isinstance(x, jax.core.Tracer) for x in leaves)


def resolve_mode(finger: Finger, mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if mode != "auto":
        return mode
    if not _is_concrete(finger):
        return "spatial"
    return "planar" if loads_in_plane(finger) else "spatial"


def prepare(finger: Finger, mode: str, topology=None):
    """Eager checks and the static topology of a finger."""
    check_x64("finray_jax")
    if not isinstance(finger, Finger):
        raise TypeError(f"expected a Finger, got {type(finger).__name__}")
    if _is_concrete(finger):
        validate_finger(finger)
    if topology is not None:
        check_friction(topology.contact, finger)
        return topology
    if not _is_concrete(finger):
        raise ValueError(
            "cannot build the topology from traced values: pass topology=finray_jax."
            "topology_of(example_finger, mode) when solving under jit or vmap"
        )
    mode = resolve_mode(finger, mode)
    check_mode_carries_loads(finger, mode)
    return build_topology(finger, mode)


def topology_of(finger: Finger, mode: str = "auto"):
    """The static topology (event order, boundary kinds, model) of a concrete finger."""
    return prepare(finger, mode)


_start_from_deformation = jax.jit(start_from_deformation, static_argnums=0)


def _carried(topo, finger: Finger, init: Solution):
    """The Newton start `init` gives this finger (`solve_finger`'s init=), checked."""
    if not isinstance(init, Solution):
        raise TypeError(f"init must be a Solution, got {type(init).__name__}")
    shape = (topo.n_segments, topo.model.n_unknown)
    if init.mode != topo.mode or init.deformation.shape != shape:
        raise ValueError(
            f"init is a {init.mode} solution of {init.deformation.shape[0]} segments; this "
            f"finger's topology is {topo.mode} with {shape[0]}: pass a Solution of the same "
            "topology (topology=, mode=)"
        )
    return _start_from_deformation(topo, finger, init.deformation)


def warm_start(topo, options: SolverOptions, y0, init: Solution | None, concrete: bool):
    """The core's `init` for a start at y0 (None: undeformed): with the banded solver a
    `WarmStart` carrying init's Jacobian factors when it has them (eagerly, zero factors
    unused when it has none, so that both share one compiled program)."""
    if y0 is None or not isinstance(options.linear_solver, BandedLinearSolver):
        return y0
    factors = init.jacobian
    if factors is not None and factors.lu.shape != _banded.lu_shape(topo.band):
        factors = None  # (another model's or resolution's factors: not of this problem)
    if factors is None:
        if not concrete:
            return y0
        return WarmStart(y0, _banded.no_factors(topo.band, y0.dtype), jnp.asarray(False))
    return WarmStart(y0, factors, jnp.asarray(True))


def solve_finger(
    finger: Finger,
    *,
    mode: str = "auto",
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    init: Solution | None = None,
    topology=None,
    keep_jacobian: bool = True,
    throw: bool = False,
) -> Solution:
    """Static equilibrium of a finger under its loads.

    mode: "planar" (x, z, theta), "spatial" (3-D) or "auto" (planar when every load lies
        in the x-z plane).
    init: a previous Solution of the same topology to start Newton from (warm start):
        its deformation (`Solution.deformation`: each segment's displacement, rotation
        and internal wrench) carried onto this finger's undeformed shape, so a start from
        another design keeps its physical forces (the scaled unknowns would rescale them
        with this finger's EI_front / L^2); and, when it has them (`Solution.jacobian`),
        its Jacobian's factors, on which Newton begins with chord steps.
    keep_jacobian: keep the factors of Newton's last linearisation in the returned
        Solution's `jacobian` (eager solves with the banded solver: ref-A planar 0.27 MB,
        3-D 1.1 MB), so that a warm start from it (`init=`) saves a linearisation; False
        for solutions that are kept by the thousand. (A solve that took chord steps only
        passes on the factors it began with: a chain of warm starts linearises again
        when they stop contracting tenfold a step.)
    throw: raise if the solve does not converge (use False in batches and read `result`).
    """
    if not isinstance(keep_jacobian, bool):
        raise ValueError(f"keep_jacobian must be True or False, got {keep_jacobian!r}")
    topo = prepare(finger, mode, topology)
    y0 = None if init is None else _carried(topo, finger, init)
    concrete = _is_concrete((finger, y0))
    y0 = warm_start(topo, options, y0, init, concrete and options.direct_first)
    if options.direct_first and concrete:
        # Called eagerly: compile and run the direct solve alone, and compile the
        # continuation only for fingers that need it.
        sol, ok, _ = direct_core(topo, integrator, options, finger, y0, keep_jacobian=keep_jacobian)
        if not bool(ok):
            cont = dataclasses.replace(options, direct_first=False)
            failed_its = sol.iterations
            sol = solve_core(topo, integrator, cont, finger, None)
            sol = eqx.tree_at(lambda x: x.iterations, sol, sol.iterations + failed_its)
    else:
        sol = solve_core(topo, integrator, options, finger, y0)
    if throw and sol.result != RESULTS.successful:
        raise RuntimeError(f"solve_finger: {sol.status}: {RESULTS[sol.result]}")
    return sol


class LimitLoad(eqx.Module):
    """The limit (fold) load factor on a finger's loads, and the equilibrium there."""

    load_factor: jax.Array
    solution: Solution

    @property
    def found(self) -> bool:
        """True when the branch was traced to its fold (load_factor is the limit)."""
        return bool(self.solution.result == RESULTS.successful)

    @property
    def status(self) -> str:
        """'limit_found', or the failure of the continuation."""
        return "limit_found" if self.found else self.solution.status


def limit_load(
    finger: Finger,
    *,
    mode: str = "auto",
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    topology=None,
) -> LimitLoad:
    """Trace the loading branch by arc-length continuation up to its fold.

    Returns the largest load factor on the finger's loads for which an equilibrium exists
    on the loading branch (refined to about min_arc_step^2 in the scaled arc length).
    """
    topo = prepare(finger, mode, topology)
    lam, sol = limit_core(topo, integrator, options, finger)
    return LimitLoad(lam, sol)
