"""The shooting solve's root finder: Newton with chord steps, a line search and a rotation
cap, or the continuation's corrector, as an optimistix root finder (`ShootingNewton`).

`solve_root` runs it through `optimistix.root_find` on the natural residual r(y; lam) of a
`Problem` (args = (problem, lam)) and returns its final state (`NewtonState`): the root,
whether it converged, the sign of det J at the first and the last accepted iterate (free
from the LU factors: whether the root lies on the branch of the start), the factors of the
last linearisation and the iteration count.

**Newton.** Each iteration linearises at the trial point y - a dy. If its residual norm has
not decreased enough (Armijo, ||r||^2 <= (1 - 1e-4 a) ||r_y||^2) the linearisation is
dropped and the next iteration tries half the step; otherwise the trial point is accepted
and its factors give the next step. The residual that decides is the one the Jacobian pass
computes anyway, so a run of full steps pays no extra residual. Far from the root this
keeps Newton from wandering: ref-A's L2 (1.5 N, three quarters of the limit load) is solved
directly in 14 linearisations planar and 16 in 3-D. With contact (objects or a support)
every step is instead backtracked on the spot, residuals only (`backtrack`): a penalty
grows so fast with penetration that a full step into an object is rarely any good.

**Chord steps.** Near the root (`SolverOptions.reuse_jacobian`) an iteration may instead
be a chord step: the residual alone at the trial point, solved with the factors of the
last accepted linearisation. That follows a Newton step shorter than
`reuse_jacobian_below` in every scaled unknown, or a chord step that shrank the step
tenfold; a chord trial that does not decrease the residual is linearised again at the same
point. Chord steps converge linearly, so their convergence test is the remaining distance
step ratio / (1 - ratio), ratio the contraction of the last two steps.

**Convergence.** When the step and the residual are below atol + rtol |y| (scaled), or
when Newton is in its quadratic regime and the predicted next step, step_k^3 /
step_(k-1)^2, is below a tenth of that: this saves the iteration that would only confirm
convergence (a 1 % design change is then re-solved in 2 iterations instead of 3). Also
when the full Newton step is below a tenth of the tolerance (norm-wise, atol + rtol
max|y|): with a stiff contact penalty the residual's round-off floor can lie above atol,
and a start at the root would otherwise never be confirmed. The converged iterate is
y - dy, whose residual is not evaluated here (the residual a Solution reports always is).

**Warm starts.** `chord`: the factors of a Jacobian near y0 (`WarmStart`, banded solver
only). Newton then begins with chord steps on them instead of a linearisation at y0; if
the first chord trial does not decrease the residual, the next iteration linearises at
the start.

**The corrector.** `arc`: None, or an `Arc`: where its `on` holds, the solver is instead
the continuation's corrector, Newton on the bordered system r(y, lam) = 0,
t . (w (y - y_prev), lam - lam_prev) = ds from (y0, lam). Each iteration linearises (no
chord steps, cap or line search) and solves with the factors of J alone (bordering): with
a = J^-1 r and b = J^-1 dr/dlam the step is dlam = (g - w t_y . a) / (t_lam - w t_y . b)
and dy = a - b dlam, g the constraint's residual. Converged when the step is below
atol + rtol |z| and both residuals below atol, or when the step alone is below a tenth of
that (a contact penalty's round-off floor in the residual would otherwise keep short,
smooth steps of the path iterating to max_newton_steps). The last linearisation then lies
within that tolerance of the root, so its b and sign serve the path's tangent there. One
solver serves both, so that a core that runs both (the solve's path) holds one Jacobian
pass, which shortens its compilation by a fifth.

**Near contact segments.** With `Contact.near_segments` the contact law is evaluated on
the segments nearest the objects only; `ShootingNewton._near_rounds` checks the choice.
"""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax import lax

from . import _banded
from ._linear import BandedLU
from ._steps import (
    MAX_HALVINGS,
    backtrack,
    branch,
    cap_rotation,
    linearise_arc,
    natural_residual,
)

MAX_ROUNDS = 3  # choices of the near contact segments


def select(pred, a, b):
    """jnp.where, or the one value when pred is a Python bool."""
    if isinstance(pred, bool):
        return a if pred else b
    return jnp.where(pred, a, b)


def linear_solver_of(problem, choice):
    """The lineax solver `choice` (a `SolverOptions.linear_solver`) gives this problem."""
    return choice.lineax_solver(problem.topo)


class Arc(eqx.Module):
    """The continuation's arc-length constraint t . (w (y - y_prev), lam - lam_prev) = ds
    for the corrector, and whether it applies (`on`; else Newton runs at fixed lam). `on`
    may be a Python bool (the limit load's corrector): the other mode is then not traced."""

    on: jax.Array
    y: jax.Array  # y_prev
    lam: jax.Array  # lam_prev
    t: jax.Array  # unit tangent in the weighted coordinates (w y, lam)
    ds: jax.Array
    w: jax.Array


class NewtonState(eqx.Module):
    y: jax.Array  # the last accepted iterate (the root once converged)
    norm: jax.Array  # squared residual norm at y
    dy: jax.Array  # Newton step from y (rotation-capped)
    a: jax.Array  # fraction of dy tried next (1, halved on rejection)
    step: jax.Array  # scaled size of the last Newton step
    k: jax.Array  # iterations (linearisations and chord steps, accepted and rejected)
    done: jax.Array
    ok: jax.Array
    sign_first: jax.Array
    sign: jax.Array
    factors: object  # of the Jacobian at the last accepted linearisation
    reuse: jax.Array  # whether the next iteration reuses `factors`
    r_next: jax.Array  # with contact: the residual at the next trial point (backtracking's)
    # With near contact segments (topo.contact.near):
    order: jax.Array | None  # the segments nearest first (`Problem.order`)
    rounds: jax.Array  # choices of the near segments made
    restart: jax.Array  # the next iteration starts a round (a new choice)
    outside: jax.Array  # contact found outside the near segments with no rounds left
    warm: jax.Array  # Newton began with chord steps on a warm start's factors
    # With an arc-length constraint (`Arc`; None without one):
    lam: jax.Array | None = None  # the load factor at y
    dlam: jax.Array | None = None  # its step from y
    b: jax.Array | None = None  # J^-1 dr/dlam at the last linearisation


class _Trial(eqx.Module):
    """One iteration's evaluation at its trial point y_t (and lam_t)."""

    y: jax.Array
    lam: jax.Array
    r: jax.Array
    factors: object
    sign: jax.Array
    b: jax.Array | None
    dy: jax.Array  # J^-1 r with the factors


class ShootingNewton(optx.AbstractRootFinder):
    """Newton for the shooting residual (see the module docstring).

    options: the `SolverOptions`. solver: `BandedLU` or `DenseLU`. active: False gives a
    solve that is done before it starts (a path's finished phase). chord: a warm start's
    factors (`WarmStart`) or None. arc: an `Arc` or None. The problem and the load factor
    come in optimistix's args, (problem, lam).
    """

    options: object = eqx.field(static=True)
    solver: object
    active: object = True
    chord: object = None
    arc: Arc | None = None
    rtol: float = 0.0  # (optimistix's fields; the tolerances are the options')
    atol: float = 0.0
    norm: Callable = optx.max_norm

    # ----------------------------------------------------------------------------------
    # What the problem is

    def _contact(self, problem) -> bool:
        return problem.topo.contact is not None

    def _choosing(self, problem) -> bool:
        return self._contact(problem) and problem.topo.contact.near is not None

    def _at(self, problem, st):
        """The problem with the near segments the state chose."""
        return dataclasses.replace(problem, order=st.order) if self._choosing(problem) else problem

    def _reuse_below(self, problem):
        below = self.options.reuse_jacobian_below
        if below is None:
            below = 0.1 if self._contact(problem) else 1.0
        return below

    def _bordered(self) -> bool:
        return self.arc is not None

    def _on(self):
        return self.arc.on if self._bordered() else False

    # ----------------------------------------------------------------------------------
    # optimistix's interface

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        problem, lam = args
        y0 = y
        S = problem.table.length.shape[0]
        choosing = self._choosing(problem)
        # (the factors' shapes do not depend on `order`; no trace of a linearisation)
        factors = self.solver.no_factors(lambda y: natural_residual(y, args), y0)
        sign, reuse, r_next = jnp.asarray(0.0), jnp.asarray(False), jnp.zeros_like(y0)
        order = jnp.argsort(problem.gaps(y0.reshape(S, -1), lam)) if choosing else None
        chord = self.chord
        if chord is not None and isinstance(self.solver, BandedLU) and self.options.reuse_jacobian:
            factors, reuse = chord.factors, jnp.asarray(chord.use)
            sign = factors.sign
            if self._contact(problem):  # (a chord step reads the residual here first)
                first_at = dataclasses.replace(problem, order=order) if choosing else problem
                r_next = lax.cond(
                    reuse,
                    lambda: natural_residual(y0, (first_at, lam)),
                    lambda: jnp.zeros_like(y0),
                )
        bordered = self._bordered()
        return NewtonState(
            y=y0,
            norm=jnp.asarray(jnp.inf),
            dy=jnp.zeros_like(y0),
            a=jnp.asarray(0.0),
            step=jnp.asarray(jnp.inf),
            k=jnp.asarray(0),
            done=~jnp.asarray(self.active),
            ok=jnp.asarray(False),
            sign_first=jnp.asarray(0.0),
            sign=sign,
            factors=factors,
            reuse=reuse,
            r_next=r_next,
            order=order,
            rounds=jnp.asarray(1),
            restart=jnp.asarray(False),
            outside=jnp.asarray(False),
            warm=reuse,
            lam=jnp.asarray(lam, y0.dtype) if bordered else None,
            dlam=jnp.zeros((), y0.dtype) if bordered else None,
            b=jnp.zeros_like(y0) if bordered else None,
        )

    def step(self, fn, y, args, options, state, tags):
        new = self._iteration(args, state)
        return new.y, new, None

    def terminate(self, fn, y, args, options, state, tags):
        return state.done, optx.RESULTS.successful

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}

    # ----------------------------------------------------------------------------------
    # One iteration

    def _trial(self, problem, lam, st) -> _Trial:
        """Linearise at the trial point, or reuse the last factors (a chord step)."""
        y_t = st.y - st.a * st.dy
        lam_t = st.lam - st.a * st.dlam if self._bordered() else lam
        solver, contact = self.solver, self._contact(problem)

        def fresh(y_t, lam_t, st):
            at = self._at(problem, st)
            if not self._bordered():
                fn = lambda y: natural_residual(y, (at, lam_t))
                return solver.linearise(fn, y_t) + (None,)
            return linearise_arc(at, lam_t, y_t, solver, self._on())

        def reused(y_t, lam_t, st):
            # With contact the backtracking has evaluated the residual at y_t already.
            r = st.r_next if contact else natural_residual(y_t, (problem, lam_t))
            return r, st.factors, st.sign, st.b

        if self.options.reuse_jacobian:
            r, factors, sign, b = lax.cond(st.reuse, reused, fresh, y_t, lam_t, st)
        else:
            r, factors, sign, b = fresh(y_t, lam_t, st)
        return _Trial(y_t, lam_t, r, factors, sign, b, solver.apply(factors, r))

    def _corrector_step(self, tr: _Trial, dy):
        """The bordered step where `on`, and its convergence test."""
        arc, o = self.arc, self.options
        wt = arc.w * arc.t[:-1]
        g = jnp.dot(wt, tr.y - arc.y) + arc.t[-1] * (tr.lam - arc.lam) - arc.ds
        d_lam = (g - jnp.dot(wt, dy)) / (arc.t[-1] - jnp.dot(wt, tr.b))
        d_y = dy - tr.b * d_lam
        y, lam = tr.y - d_y, tr.lam - d_lam
        scale = lambda z: o.atol + o.rtol * jnp.abs(z)
        small = jnp.maximum(jnp.max(jnp.abs(d_y) / scale(y)), jnp.abs(d_lam) / scale(lam))
        resid = jnp.maximum(jnp.max(jnp.abs(tr.r)), jnp.abs(g)) < o.atol
        # (or the step alone, below a tenth of the tolerance: see `full` in `_iteration`)
        resid = resid | (small < 0.1)
        finite = jnp.all(jnp.isfinite(y)) & jnp.isfinite(lam)
        return d_y, d_lam, (small < 1.0) & resid & finite

    def newton_step(self, problem, dy):
        cap = self.options.max_rotation_step
        if cap is not None:
            dy = cap_rotation(problem, dy, cap)
        return dy, jnp.zeros((), dy.dtype), jnp.asarray(False)

    def _near_rounds(self, problem, st, y, lam_y, conv):
        """A root of the near problem is a root of the whole one where no segment outside
        the near ones touches. Checked at a root, and wherever a far segment's start lies
        inside an object (cheap: no integration); on contact outside, choose again from
        there and go on while rounds are left. Returns (order, again, outside, conv)."""
        S = problem.table.length.shape[0]
        near = problem.topo.contact.near

        def far_touch(gaps, order):
            return jnp.min(gaps[order[near:]]) < 0.0

        def choose(y, lam_y, order):
            gaps = problem.gaps(y.reshape(S, -1), lam_y)
            return jnp.argsort(gaps), far_touch(gaps, order)

        inside = far_touch(problem.gaps(y.reshape(S, -1), lam_y, along=False), st.order)
        keep = lambda y, l, o: (o, jnp.asarray(False))
        order, missed = lax.cond(conv | inside, choose, keep, y, lam_y, st.order)
        again = missed & (st.rounds < MAX_ROUNDS)
        outside = st.outside | (missed & ~again)  # (and give up)
        return order, again, outside, conv & ~missed

    def _converged(self, st: NewtonState, tr, dy, y, start):
        """Whether the step dy (taken from the trial point to y) ends the solve; its size
        in units of the tolerance, its ratio to the previous step's, its largest change."""
        o = self.options
        # Newton's own correction (before any line search or cap) in units of the
        # tolerance, norm-wise: below a tenth, y_t is the root to within round-off, even
        # where the residual sits on a round-off floor above atol (stiff contact
        # penalties), and y_t - dy is closer still (by the step squared). Norm-wise, as
        # the unknowns are scaled to order one: per component, an unknown near zero would
        # need its round-off below atol, which a tight atol (1e-17) never reaches.
        full = jnp.max(jnp.abs(tr.dy)) / (o.atol + o.rtol * jnp.max(jnp.abs(tr.y)))
        step = jnp.max(jnp.abs(dy) / (o.atol + o.rtol * jnp.abs(y)))
        biggest = jnp.max(jnp.abs(dy))
        near = biggest < 1e-4
        conv = (step < 1.0) & (jnp.max(jnp.abs(tr.r)) < o.atol)
        ratio = step / jnp.maximum(st.step, 1e-300)
        # Newton's quadratic regime: the next step would be step^3 / previous^2. A chord
        # step contracts linearly (by `ratio`): what is left is step ratio / (1 - ratio).
        quadratic = (~start) & (ratio < 1e-2) & (step * ratio**2 < 0.1) & near & ~st.reuse
        linear = st.reuse & ~start & (ratio < 0.5) & (step * ratio / (1.0 - ratio) < 0.1)
        linear = linear & near
        return conv | (full < 0.1) | quadratic | linear, step, ratio, biggest

    def _iteration(self, args, st: NewtonState) -> NewtonState:
        problem, lam = args
        o, contact, bordered = self.options, self._contact(problem), self._bordered()
        on = self._on()
        tr = self._trial(problem, lam, st)
        r, dy = tr.r, tr.dy
        norm = jnp.sum(r * r)
        first = st.k == 0
        start = first | st.restart
        decreased = norm <= (1.0 - 1e-4 * st.a) * st.norm
        # A chord step whose trial point did not decrease the residual is not cut: the
        # next iteration linearises at the same point instead.
        retry = jnp.asarray(False) if contact else st.reuse & ~decreased
        accept = start | contact | decreased
        accept = accept | ((st.a < 0.5**MAX_HALVINGS) & ~retry)
        if bordered:
            corrector = lambda dy: self._corrector_step(tr, dy)
            dy, dlam, conv_arc = branch(on, corrector, lambda d: self.newton_step(problem, d), dy)
            accept = accept | jnp.asarray(on)
        else:
            dy = self.newton_step(problem, dy)[0]
        r_next = st.r_next
        if contact:  # (after the cap: r_next is the residual where the step ends)
            halvings = select(on, 0, MAX_HALVINGS) if bordered else MAX_HALVINGS
            dy, r_next = backtrack(self._at(problem, st), tr.lam, tr.y, dy, r, halvings)
        y = tr.y - dy
        finite = jnp.all(jnp.isfinite(y))
        conv_newton, step, ratio, biggest = self._converged(st, tr, dy, y, start)
        conv_newton = accept & conv_newton
        if bordered:
            lam_new = tr.lam - dlam
            conv = select(on, conv_arc, conv_newton)
        else:
            conv = conv_newton
        order, again, outside = st.order, jnp.asarray(False), st.outside
        if self._choosing(problem):
            lam_y = lam_new if bordered else lam
            order, again, outside, conv = self._near_rounds(problem, st, y, lam_y, conv)
        # The next iteration reuses these factors while that is cheaper than linearising:
        # after a short Newton step, or a chord step that contracted tenfold. (With a
        # fourfold bound the grasp's release traces stalled at max_newton_steps.)
        short = biggest < self._reuse_below(problem)
        reuse_next = accept & jnp.where(st.reuse, ratio < 0.1, short)
        if bordered:
            reuse_next = reuse_next & ~jnp.asarray(on)
        k = st.k + 1
        # (a warm start's first chord trial that fails is linearised at the start)
        retry_at = jnp.where(st.warm & (k == 2), 0.0, st.a)
        pick = lambda new, old: jnp.where(accept, new, old)
        return NewtonState(
            y=jnp.where(conv | again, y, pick(tr.y, st.y)),
            norm=pick(norm, st.norm),
            dy=jnp.where(again, 0.0, pick(dy, st.dy)),
            a=jnp.where(accept, 1.0, jnp.where(retry, retry_at, 0.5 * st.a)),
            step=pick(step, st.step),
            k=k,
            done=conv | outside | (accept & ~finite) | (k >= o.max_newton_steps),
            ok=conv & finite,
            sign_first=jnp.where(first, tr.sign, st.sign_first),
            sign=pick(tr.sign, st.sign),
            factors=jax.tree_util.tree_map(pick, tr.factors, st.factors),
            reuse=o.reuse_jacobian & reuse_next & ~again,
            r_next=r_next,
            order=order,
            rounds=jnp.where(again, st.rounds + 1, st.rounds),
            restart=again,
            outside=outside,
            warm=st.warm,
            lam=jnp.where(conv | again, lam_new, pick(tr.lam, st.lam)) if bordered else None,
            dlam=jnp.where(again, 0.0, pick(dlam, st.dlam)) if bordered else None,
            b=pick(tr.b, st.b) if bordered else None,
        )


def solve_root(problem, y0, lam, options, active=True, chord=None, arc=None) -> NewtonState:
    """`ShootingNewton` on the problem's residual at load factor lam, from y0, through
    optimistix.root_find; its final state. The problem is stop-gradient'd by the callers
    (the root's tangents come from the implicit function theorem, attached after)."""
    linear = linear_solver_of(problem, options.linear_solver)
    sol = optx.root_find(
        natural_residual,
        ShootingNewton(options, linear, active, chord, arc),
        y0,
        (problem, lam),
        max_steps=None,  # (the options' max_newton_steps bounds it)
        adjoint=optx.ImplicitAdjoint(linear),
        throw=False,
    )
    return sol.state


def on_branch(newton: NewtonState, ref_sign=None):
    """Whether a Newton solve at full load converged on the branch it started from: the
    sign of det J at the last iterate is that at the first (no fold crossed), or
    `ref_sign` when given and nonzero (the sign on the branch being followed: a path of
    equilibria compares with its last point, not with the start of Newton, which lies off
    the path and may have either sign)."""
    ref = newton.sign_first
    if ref_sign is not None:
        ref = jnp.where(ref_sign == 0.0, ref, ref_sign)
    return newton.ok & (newton.sign == ref)


class WarmStart(eqx.Module):
    """A Newton start for the cores with the factors of a Jacobian near it: the scaled
    unknowns and the banded LU of the solution a warm start comes from
    (`Solution.jacobian`), and whether to use the factors (False: a plain start at
    `unknowns`, the same compiled program)."""

    unknowns: jax.Array
    factors: _banded.BandLU
    use: jax.Array
