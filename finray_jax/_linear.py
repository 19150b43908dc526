"""The linear solvers of Newton's steps, the continuation and the implicit gradient.

Both are lineax solvers (`lineax.AbstractLinearSolver`), so optimistix's implicit
adjoint can use them, and both also offer what the shooting solve needs beyond a plain
solve: the residual and the factors from one linearisation, and the sign of det J from
the factors (which tells the branches of a path apart).

- `BandedLU`: the Jacobian's block pattern, coloured, gives it from one forward pass per
  colour (24 tangents for planar ref-A instead of 144), straight into band order, and a
  banded LU with partial pivoting factors it (finray_jax._banded).
- `DenseLU`: `jax.jacfwd` with one tangent per unknown and a dense LU (a check of the
  banded solver; the same Newton steps to round-off).
"""

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import lineax as lx

from . import _banded


class BandedLU(lx.AbstractLinearSolver):
    """Banded LU of a Jacobian assembled from colour-compressed forward passes.

    plan: the `BandPlan` of the Jacobian's pattern (its colours, band order, widths). An
    operator given to `init` must have that pattern: J, not J^T (lineax solves transposed
    systems, as in reverse mode, through `transpose`).
    """

    plan: _banded.BandPlan = eqx.field(static=True)

    def factor_map(self, jvp, dtype) -> _banded.BandLU:
        """The factors of J from the linear map v -> J v (one batched pass over the
        colour seeds)."""
        plan = self.plan
        return _banded.factor(plan, _banded.band(plan, _banded.seeded(plan, jvp, dtype)))

    def linearise(self, fn, y):
        """fn(y), the factors of its Jacobian there and the sign of det J."""
        r, A = _banded.linearize(self.plan, fn, y)
        factors = _banded.factor(self.plan, A)
        return r, factors, factors.sign

    def apply(self, factors, r):
        """J^-1 r from the factors of J."""
        return _banded.solve_factored(self.plan, factors, r)

    def no_factors(self, fn, y):
        """Zero factors of `linearise`'s shapes (a loop's initial carry; no trace of a
        linearisation)."""
        del fn
        return _banded.no_factors(self.plan, y.dtype)

    # lineax's interface (optimistix's implicit adjoint solves through it).

    def init(self, operator, options):
        del options
        if operator.in_size() != self.plan.n or operator.out_size() != self.plan.n:
            raise ValueError(
                f"BandedLU: the operator is {operator.out_size()} x {operator.in_size()}, "
                f"its band plan {self.plan.n} x {self.plan.n}"
            )
        dtype = operator.out_structure().dtype
        return self.factor_map(operator.mv, dtype), eqxi.Static(False)

    def compute(self, state, vector, options):
        del options
        factors, transposed = state
        solve = lambda b: self.apply(factors, b)
        if transposed.value:  # (the solve is gathers and triangular solves: transposable)
            x = jax.linear_transpose(solve, vector)(vector)[0]
        else:
            x = solve(vector)
        return x, lx.RESULTS.successful, {}

    def transpose(self, state, options):
        factors, transposed = state
        return (factors, eqxi.Static(not transposed.value)), options

    def conj(self, state, options):
        return state, options  # (real)

    def assume_full_rank(self):
        return True


class DenseLU(lx.AbstractLinearSolver):
    """Dense LU of the Jacobian from `jax.jacfwd`: `lineax.LU` with the shooting solve's
    extras."""

    def linearise(self, fn, y):
        J, r = jax.jacfwd(lambda y: (lambda o: (o, o))(fn(y)), has_aux=True)(y)
        lu, piv = jax.scipy.linalg.lu_factor(J)
        swaps = jnp.sum(piv != jnp.arange(piv.shape[0], dtype=piv.dtype))
        sign = jnp.prod(jnp.sign(jnp.diagonal(lu))) * jnp.where(swaps % 2 == 0, 1.0, -1.0)
        return r, (lu, piv), sign

    def apply(self, factors, r):
        return jax.scipy.linalg.lu_solve(factors, r)

    def no_factors(self, fn, y):
        shapes = jax.eval_shape(lambda: self.linearise(fn, y))[1]
        return jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), shapes)

    def init(self, operator, options):
        return lx.LU().init(operator, options)

    def compute(self, state, vector, options):
        return lx.LU().compute(state, vector, options)

    def transpose(self, state, options):
        return lx.LU().transpose(state, options)

    def conj(self, state, options):
        return lx.LU().conj(state, options)

    def assume_full_rank(self):
        return True
