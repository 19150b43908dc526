"""Result codes and the solution of a finger solve."""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx


class RESULTS(optx.RESULTS):  # pyright: ignore
    beyond_limit_load = (
        "No equilibrium on the loading branch: the load is beyond the finger's limit (fold) "
        "load. Reduce the load, or find the limit with `limit_load`."
    )
    continuation_failed = (
        "Load continuation could not reach the full load: the arc-length step fell below "
        "SolverOptions.min_arc_step without a fold being found. Try a smaller "
        "SolverOptions.initial_arc_step or more SolverOptions.max_continuation_steps."
    )


def status_name(result) -> str:
    """'converged' | 'beyond_limit_load' | 'failed' for a concrete result."""
    if result == RESULTS.successful:
        return "converged"
    if result == RESULTS.beyond_limit_load:
        return "beyond_limit_load"
    return "failed"


class BeamSolution(eqx.Module):
    """One beam along its arc length s (base to tip; crossbeams front to back).

    position (N, 3), frame (N, 3, 3) with columns d1 d2 d3, force n (N, 3) and moment m
    (N, 3): the internal wrench the material at s+ exerts on s- (world frame; m about p(s)).
    Segment boundaries appear twice (before and after the junction's jump): the arrays are
    blocks of steps + 2 points per segment (its start, then the steps + 1 points of its
    flexible part).
    """

    s: jax.Array
    position: jax.Array
    frame: jax.Array
    force: jax.Array
    moment: jax.Array


class Reaction(eqx.Module):
    """Wrench the adaptor applies to a beam at its base; moment about the base point."""

    force: jax.Array
    moment: jax.Array


class Tip(eqx.Module):
    position: jax.Array
    displacement: jax.Array
    rotation: jax.Array  # rotation vector (rad), world frame


class CrossbeamWrenches(eqx.Module):
    """Wrench each crossbeam applies to the front beam and to the back beam (C, 3)."""

    front_force: jax.Array
    front_moment: jax.Array
    back_force: jax.Array
    back_moment: jax.Array


class Solution(eqx.Module):
    """The equilibrium of a finger.

    `result` is a RESULTS member; `status` its name. `load_factor` is the factor on the
    finger's loads at which this equilibrium holds (1 when converged; the fold factor when
    the loads lie beyond the limit load). `max_residual` is the largest scaled residual
    (positions over the front-beam length, forces over EI_front / L^2).
    """

    result: RESULTS
    load_factor: jax.Array
    iterations: jax.Array
    max_residual: jax.Array
    front: BeamSolution
    back: BeamSolution
    crossbeams: BeamSolution  # stacked over crossbeams: s (C, N), position (C, N, 3) ...
    reactions_front: Reaction
    reactions_back: Reaction
    tip: Tip
    crossbeam_wrenches: CrossbeamWrenches
    unknowns: jax.Array  # scaled shooting unknowns, usable as a warm start
    mode: str = eqx.field(static=True)
    steps: int = eqx.field(static=True, default=0)  # integration steps per segment

    @property
    def status(self) -> str:
        return status_name(self.result)

    @property
    def converged(self):
        return self.result == RESULTS.successful

    def crossbeam(self, i: int) -> BeamSolution:
        return jax.tree_util.tree_map(lambda x: x[i], self.crossbeams)


def stack_beams(beams):
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *beams)
