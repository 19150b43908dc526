"""The numerical choices of the equilibrium solve."""

import abc
from typing import ClassVar

import equinox as eqx
import lineax as lx

from ._choices import choice
from ._linear import BandedLU, DenseLU

MODES = ("auto", "planar", "spatial")


class AbstractLinearSolver(eqx.Module):
    """How Newton's linear systems are solved; `name` is its word in solver files."""

    name: ClassVar[str]

    @abc.abstractmethod
    def lineax_solver(self, topo) -> lx.AbstractLinearSolver:
        """The lineax solver for the Jacobians of a problem of this topology."""


class BandedLinearSolver(AbstractLinearSolver):
    """The Jacobian assembled from one forward pass per colour of its block pattern (24
    tangents for planar ref-A instead of 144), straight into band order, and factored by
    banded LU with partial pivoting. The implicit gradient and the continuation (its
    corrector's bordered system, its tangent, the sign of det J) reuse the factors."""

    name: ClassVar[str] = "banded"

    def lineax_solver(self, topo):
        return BandedLU(topo.band)


class DenseLinearSolver(AbstractLinearSolver):
    """`jax.jacfwd` with one tangent per unknown and a dense LU; the gradient
    differentiates through the integrator. Same Newton steps as the banded solver to
    round-off, several times slower: a cross-check."""

    name: ClassVar[str] = "dense"

    def lineax_solver(self, topo):
        return DenseLU()


LINEAR_SOLVERS = {kind.name: kind() for kind in (BandedLinearSolver, DenseLinearSolver)}


def as_linear_solver(value) -> AbstractLinearSolver:
    """`SolverOptions.linear_solver` as its object (a name is deprecated, see `choice`)."""
    return choice(
        value, "SolverOptions.linear_solver", AbstractLinearSolver, LINEAR_SOLVERS, ValueError
    )


class SolverOptions(eqx.Module):
    """Numerical choices of the equilibrium solve (all static).

    rtol, atol: Newton tolerances on the scaled unknowns and residual.
    max_newton_steps: Newton iterations per root solve.
    direct_first: first try Newton at the full load from the initial guess; fall back to
        arc-length continuation when it fails or lands beyond a fold.
    initial_arc_step, min_arc_step, max_arc_step: pseudo-arc-length step sizes, in the
        coordinates where the initial tangent has equal load and shape parts. All three
        shrink by one factor where the first step would otherwise move a scaled unknown
        by more than FIRST_STEP_CHANGE along the initial tangent (loads so large that the
        fold lies at a tiny load factor, e.g. a thousand times the limit load): the
        steps then scale with the load, and the fold is found at any load magnitude.
    max_continuation_steps: bound on continuation steps (vmapped batches run in lock step).
    min_tangent_cosine: a continuation step is retried at half length when the path's
        tangent turns by more than arccos of this (guards against jumping over folds).
    max_corrector_steps: a continuation step whose corrector needs more Newton iterations
        is retried at half length.
    max_rotation_step: the largest rotation (rad) of any segment's start frame in one
        Newton step; longer steps are scaled down (None: no cap). With 0.2 and Newton's
        line search, ref-A's L2 and L3 are solved directly from the undeformed shape in
        14 and 8 linearisations planar (16 and 8 in 3-D) instead of by 35 and 30
        iterations of continuation.
    linear_solver: how Newton's linear systems are solved: BandedLinearSolver()
        (default) or DenseLinearSolver().
    reuse_jacobian: near the root, take chord steps: keep the factors of the last
        Jacobian and evaluate only the residual (a fraction of the cost of a Jacobian
        pass and its factors) while they contract the step at least tenfold; else
        linearise again. A chord step that does not decrease the residual is retried as
        a Newton step from the same point. Chord steps count as iterations. Under
        `jax.vmap` both branches run (a batched `lax.cond` is a select): `solve_batch`
        turns it off when it vectorises.
    reuse_jacobian_below: the largest change of any scaled unknown in a Newton step
        after which the next iteration reuses its factors. None (default): 1.0 without
        contact, 0.1 with objects or a support, whose penalty laws make the Jacobian
        change faster.
    """

    rtol: float = eqx.field(static=True, default=1e-10)
    atol: float = eqx.field(static=True, default=1e-10)
    max_newton_steps: int = eqx.field(static=True, default=20)
    direct_first: bool = eqx.field(static=True, default=True)
    initial_arc_step: float = eqx.field(static=True, default=0.3)
    min_arc_step: float = eqx.field(static=True, default=2e-4)
    max_arc_step: float = eqx.field(static=True, default=0.8)
    max_continuation_steps: int = eqx.field(static=True, default=120)
    min_tangent_cosine: float = eqx.field(static=True, default=0.95)
    max_corrector_steps: int = eqx.field(static=True, default=8)
    max_rotation_step: float | None = eqx.field(static=True, default=0.2)
    linear_solver: AbstractLinearSolver = eqx.field(
        static=True, default=BandedLinearSolver(), converter=as_linear_solver
    )
    reuse_jacobian: bool = eqx.field(static=True, default=True)
    reuse_jacobian_below: float | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        positive = ("rtol", "atol", "initial_arc_step", "min_arc_step", "max_arc_step")
        for name in positive + ("reuse_jacobian_below",):
            v = getattr(self, name)
            if name == "reuse_jacobian_below" and v is None:
                continue
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"SolverOptions.{name} must be a positive number, got {v!r}")
        for name in ("rtol", "atol"):  # (on scaled unknowns and residuals, which are O(1))
            if getattr(self, name) >= 1.0:
                raise ValueError(
                    f"SolverOptions.{name} = {getattr(self, name)!r}: must be below 1 (the "
                    "default is 1e-10; a tolerance of order 1 accepts any iterate)"
                )
        if not self.min_arc_step <= self.initial_arc_step <= self.max_arc_step:
            raise ValueError(
                f"SolverOptions: need min_arc_step <= initial_arc_step <= max_arc_step, got "
                f"{self.min_arc_step!r}, {self.initial_arc_step!r}, {self.max_arc_step!r}"
            )
        cap = self.max_rotation_step
        if cap is not None and not (isinstance(cap, (int, float)) and cap > 0):
            raise ValueError(
                f"SolverOptions.max_rotation_step must be None or a positive angle (rad), "
                f"got {cap!r}"
            )
        if not isinstance(self.reuse_jacobian, bool):
            raise ValueError(
                f"SolverOptions.reuse_jacobian must be True or False, got {self.reuse_jacobian!r}"
            )
        for name in ("max_newton_steps", "max_continuation_steps", "max_corrector_steps"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"SolverOptions.{name} must be a positive integer, got {v!r}")
