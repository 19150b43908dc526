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
    contact_outside_near_segments = (
        "The Newton solve (at full load, or a step of the load continuation) evaluates "
        "contact on the segments nearest the objects only (Contact.near_segments and the "
        "supported ones), and after three choices of them some other segment still "
        "touched an object: the contact spans more segments. Raise Contact.near_segments, "
        "or set it to None (every segment)."
    )
    continuation_failed = (
        "Load continuation could not reach the full load: down to SolverOptions.min_arc_step "
        "every arc-length step turned the path's tangent by more than "
        "arccos(SolverOptions.min_tangent_cosine), or needed more than "
        "SolverOptions.max_corrector_steps corrector iterations, and no fold was found. "
        "Try a smaller SolverOptions.min_arc_step, or a lower min_tangent_cosine."
    )
    continuation_corrector_failed = (
        "Load continuation could not reach the full load: down to SolverOptions.min_arc_step "
        "the corrector (Newton on the arc-length system) did not converge within "
        "SolverOptions.max_newton_steps from the predicted point. With contact the "
        "penalty's onset can be too abrupt for the steps: try a larger "
        "Contact.max_penetration (a smoother onset) or a smaller SolverOptions.min_arc_step."
    )
    continuation_branch_switch = (
        "Load continuation could not reach the full load: down to SolverOptions.min_arc_step "
        "every arc-length step landed where det J has the other sign while the load factor "
        "still rose (not a fold: another branch crosses the path there, a bifurcation). "
        "Try a smaller SolverOptions.min_arc_step, or break the symmetry of the loads."
    )
    actuator_force_not_reached = (
        "The actuator force was not reached: along the closing path the force rose to a "
        "peak below it and then fell (the finger gives way). The grasp returned is the one "
        "at that peak (its closing and contact.actuator_force): the most this finger "
        "applies to the object."
    )
    branch_changed = (
        "Newton converged, but to an equilibrium whose sign of det J differs from that of "
        "the path it continues: a fold or a bifurcation lies between them. A path of "
        "equilibria goes on past it only on a stable branch (see `CriticalPoint`)."
    )
    unstable_equilibrium = (
        "The equilibrium found is unstable (its tangent stiffness has a negative "
        "eigenvalue, or a segment buckles with both ends held: see `.stability`), and "
        "Newton started from it displaced along its softest mode found no stable one "
        "next to it. The finger would not stay there."
    )
    stability_lost = (
        "Along the path the equilibrium lost its stability (a fold or a bifurcation: the "
        "tangent stiffness's smallest eigenvalue passed 0) and no stable equilibrium was "
        "found next to the unstable one past it: the finger would snap. The result is the "
        "last stable equilibrium; `critical_points` says where it was lost."
    )
    continuation_steps_exhausted = (
        "Load continuation took SolverOptions.max_continuation_steps arc-length steps "
        "without reaching the full load or a fold, and the load factor was still rising. "
        "Raise SolverOptions.max_continuation_steps (or max_arc_step). Loads that stiffen "
        "the finger (a pull along a beam) may have no fold at any load factor."
    )


def status_name(result) -> str:
    """'converged' | 'beyond_limit_load' | 'unstable' | 'failed' for a concrete result."""
    if result == RESULTS.successful:
        return "converged"
    if result == RESULTS.unstable_equilibrium:
        return "unstable"
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

    Stored packed, one row of 19 values per point (`data`: s, position, frame row by row,
    force, moment; leading axes for stacked crossbeams or a batch), and read through the
    properties. A compiled solve returns each array of its result as its own buffer, and
    each costs dispatch time: a few packed arrays (9) come back several times faster
    than five arrays per beam with the reactions, tip and crossbeam wrenches apart (31)
    would (benchmarks/README.md, "Dispatch").
    """

    data: jax.Array

    @classmethod
    def pack(cls, s, position, frame, force, moment) -> "BeamSolution":
        flat = frame.reshape(*frame.shape[:-2], 9)
        return cls(jnp.concatenate([s[..., None], position, flat, force, moment], axis=-1))

    @property
    def s(self):
        return self.data[..., 0]

    @property
    def position(self):
        return self.data[..., 1:4]

    @property
    def frame(self):
        return self.data[..., 4:13].reshape(*self.data.shape[:-1], 3, 3)

    @property
    def force(self):
        return self.data[..., 13:16]

    @property
    def moment(self):
        return self.data[..., 16:19]


class Reaction(eqx.Module):
    """Wrench the adaptor applies to a beam at its base; moment about the base point."""

    force: jax.Array
    moment: jax.Array


class Tip(eqx.Module):
    """The front beam's tip: position, displacement from the undeformed tip and rotation
    vector (rad, world frame), stored packed as the rows of `data` (..., 3, 3)."""

    data: jax.Array

    @classmethod
    def pack(cls, position, displacement, rotation) -> "Tip":
        return cls(jnp.stack([position, displacement, rotation], axis=-2))

    @property
    def position(self):
        return self.data[..., 0, :]

    @property
    def displacement(self):
        return self.data[..., 1, :]

    @property
    def rotation(self):
        return self.data[..., 2, :]


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
    tip: Tip
    unknowns: jax.Array  # scaled shooting unknowns
    # (S, n_unknown): each segment's start state minus its undeformed one: displacement
    # and rotation (mm, rad), internal force and moment over the finger's E (mm^2, mm^3):
    # what `init=` carries onto another design of the same topology
    deformation: jax.Array
    mode: str = eqx.field(static=True)
    steps: int = eqx.field(static=True, default=0)  # integration steps per segment
    # The banded LU of the shooting Jacobian at Newton's last linearisation (eager
    # `solve_finger` with the banded solver; None otherwise): a warm start from this
    # solution (`init=`) begins with chord steps on it instead of a linearisation.
    jacobian: object = None

    @property
    def status(self) -> str:
        return status_name(self.result)

    @property
    def message(self) -> str:
        """Why the solve did not converge and what to try ("" when it converged)."""
        return RESULTS[self.result]

    @property
    def converged(self):
        return self.result == RESULTS.successful

    @property
    def reactions_front(self) -> Reaction:
        return _reaction(self.front)

    @property
    def reactions_back(self) -> Reaction:
        return _reaction(self.back)

    @property
    def crossbeam_wrenches(self) -> CrossbeamWrenches:
        """(C, 3) arrays; (0, 3) when there are no crossbeams."""
        cb = self.crossbeams
        return CrossbeamWrenches(
            front_force=cb.force[..., 0, :],
            front_moment=cb.moment[..., 0, :],
            back_force=-cb.force[..., -1, :],
            back_moment=-cb.moment[..., -1, :],
        )

    def crossbeam(self, i: int) -> BeamSolution:
        return jax.tree_util.tree_map(lambda x: x[i], self.crossbeams)


def _reaction(beam: BeamSolution) -> Reaction:
    return Reaction(-beam.force[..., 0, :], -beam.moment[..., 0, :])


def stack_beams(beams):
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *beams)
