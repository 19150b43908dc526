"""The pieces of one Newton iteration of the shooting solve: the linearisation with the
load factor's column for the continuation's corrector, the rotation cap and the line
search."""

import jax
import jax.numpy as jnp
from jax import lax

from ._linear import BandedLU

MAX_HALVINGS = 12  # line-search halvings of one step


def natural_residual(y, args):
    """The residual of a Problem at flat scaled unknowns y; args = (problem, lam)."""
    problem, lam = args
    return problem.residual(y.reshape(problem.table.length.shape[0], -1), lam).reshape(-1)


def branch(pred, true_fn, false_fn, *operands):
    """lax.cond, or the one branch when pred is a Python bool (known when tracing)."""
    if isinstance(pred, bool):
        return (true_fn if pred else false_fn)(*operands)
    return lax.cond(pred, true_fn, false_fn, *operands)


def cap_rotation(problem, dy, cap):
    """Scale a Newton step so that no segment's start frame turns by more than `cap` rad.

    Plain Newton from the undeformed shape overshoots large rotations (the residual is
    trigonometric in them) and diverges for loads well below the limit load; limiting the
    rotation part of the step keeps it in the region where the linearisation holds."""
    rot = dy.reshape(problem.table.length.shape[0], -1)[:, problem.model.rotation_slice]
    return dy * jnp.minimum(1.0, cap / jnp.maximum(jnp.max(jnp.abs(rot)), 1e-300))


def backtrack(problem, lam, y, dy, r, max_halvings=MAX_HALVINGS):
    """Shorten a Newton step until the residual norm decreases (Armijo, factor 1/2).

    Contact penalties make the residual grow fast with penetration; a full step taken from
    a state without contact can run deep into an object, so the step is cut back. Returns
    the step and the residual at its end (y - step)."""
    norm0 = jnp.sum(r * r)
    fn = lambda a: natural_residual(y - a * dy, (problem, lam))

    def worse(c):
        a, k, rr = c
        n = jnp.sum(rr * rr)
        return (~(n <= (1.0 - 1e-4 * a) * norm0)) & (k < max_halvings)

    def halve(c):
        a, k, _ = c
        return 0.5 * a, k + 1, fn(0.5 * a)

    one = jnp.ones((), dy.dtype)
    a, _, rr = lax.while_loop(worse, halve, (one, 0, fn(one)))
    return a * dy, rr


def linearise_arc(problem, lam, y, solver, on):
    """The solver's linearisation (r, factors, sign of det J), and b = J^-1 dr/dlam where
    `on` (zeros elsewhere): what a step of the continuation's corrector and the path's
    tangent need.

    Without distributed loads (the usual case: point loads are jumps between segments)
    the segments' flows do not depend on lam, so dr/dlam is the residual's own derivative
    at the end states of the Jacobian pass, and the pass is J's alone (this shortens the
    full core's compilation by a sixth and the limit load's run by a sixth against a
    pass of its own for dr/dlam). With distributed loads dr/dlam is a forward-mode pass
    of its own through the integrator (one tangent), where `on` only."""
    S = problem.table.length.shape[0]
    one = jnp.ones_like(lam)
    if isinstance(solver, BandedLU) and not problem.topo.distributed:
        # (the flows do not depend on lam: see above)
        def fn(a):
            starts, ends = problem.ends(a.reshape(S, -1), lam)
            return problem.residual_from_states(starts, ends, lam).reshape(-1), (starts, ends)

        r, jvp, (starts, ends) = jax.linearize(fn, y, has_aux=True)
        factors = solver.factor_map(jvp, y.dtype)
        sign = factors.sign

        def r_lam():
            at = lambda l: problem.residual_from_states(starts, ends, l).reshape(-1)
            return jax.jvp(at, (lam,), (one,))[1]

    else:
        r, factors, sign = solver.linearise(lambda y: natural_residual(y, (problem, lam)), y)
        Y = y.reshape(S, -1)

        def r_lam():
            starts = problem.start_states(Y)

            def residual(l):
                return problem.residual_from_states(starts, problem.integrated(Y, l)[:, -1], l)

            return jax.jvp(residual, (lam,), (one,))[1]

    b = branch(on, lambda: solver.apply(factors, r_lam()), lambda: jnp.zeros_like(y))
    return r, factors, sign, b
