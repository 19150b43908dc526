"""Newton shooting with load continuation, fold detection and the limit load."""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax import lax

from . import _banded
from ._assembly import Problem, build_topology, segment_table
from ._contact import check_friction
from ._finger import (
    BACK,
    FRONT,
    Finger,
    check_mode_carries_loads,
    loads_in_plane,
    validate_finger,
)
from ._geometry import arc_point, geometry
from ._rod import Integrator, apply_flow_jacobians, flow_jacobians
from ._rotation import log_so3, planar_frame
from ._solution import (
    RESULTS,
    BeamSolution,
    Solution,
    Tip,
    stack_beams,
)
from ._types import check_x64

MODES = ("auto", "planar", "spatial")
LINEAR_SOLVERS = ("banded", "dense")


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
    linear_solver: how Newton's linear systems are solved. "banded" (default): the
        Jacobian is assembled from one forward pass per colour of its block pattern (24
        tangents for planar ref-A instead of 144) straight into band order and factored
        by banded LU with partial pivoting (`_banded`); "dense": `jax.jacfwd` with one
        tangent per unknown and a dense LU. Both give the same Newton steps to round-off.
        The implicit gradient and the continuation (its corrector's bordered system, by
        bordering, its tangent and the sign of det J) solve with the same factors.
    reuse_jacobian: near the root, take chord steps: keep the factors of the last
        Jacobian and evaluate only the residual (planar ref-A: 0.10 ms instead of 0.45 ms
        for a Jacobian pass and its factors; with contact 0.5 ms instead of 4 ms) while
        they contract the step at least tenfold; else linearise again. A chord step that
        does not decrease the residual is retried as a Newton step from the same point.
        Chord steps count as iterations. Under `jax.vmap` both branches run (a batched
        `lax.cond` is a select): `solve_batch` turns it off when it vectorises.
    reuse_jacobian_below: the largest change of any scaled unknown in a Newton step
        after which the next iteration reuses its factors. None (default): 1.0 without
        contact, 0.1 with objects or a support, whose penalty laws make the Jacobian
        change faster. (Planar ref-A L1 from the undeformed shape: 2 linearisations and 4
        chord steps instead of 3 and 1, about 10 % faster; with contact 1.0 cost a
        Finger-1 grasp 2 more solves.)
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
    linear_solver: str = eqx.field(static=True, default="banded")
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
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(
                f"SolverOptions.linear_solver must be one of {LINEAR_SOLVERS}, "
                f"got {self.linear_solver!r}"
            )
        for name in ("max_newton_steps", "max_continuation_steps", "max_corrector_steps"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"SolverOptions.{name} must be a positive integer, got {v!r}")


# --------------------------------------------------------------------------------------
# Root solves
# --------------------------------------------------------------------------------------


def _if(pred, true_fn, false_fn, *operands):
    """lax.cond, or the one branch when pred is a Python bool (known when tracing)."""
    if isinstance(pred, bool):
        return (true_fn if pred else false_fn)(*operands)
    return lax.cond(pred, true_fn, false_fn, *operands)


def _where(pred, a, b):
    """jnp.where, or the one value when pred is a Python bool."""
    if isinstance(pred, bool):
        return a if pred else b
    return jnp.where(pred, a, b)


def _natural_fn(y, args):
    problem, lam = args
    return problem.residual(y.reshape(problem.table.length.shape[0], -1), lam).reshape(-1)


class _Newton(eqx.Module):
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


def _linearise(problem, lam, y, linear_solver):
    """The residual at y, the factors of the Jacobian there and the sign of det J."""
    fn = lambda y: _natural_fn(y, (problem, lam))
    if linear_solver == "banded":
        plan = problem.topo.band
        r, A = _banded.linearize(plan, fn, y)
        fac = _banded.factor(plan, A)
        return r, fac, fac.sign
    J, r = jax.jacfwd(lambda y: (lambda o: (o, o))(fn(y)), has_aux=True)(y)
    lu, piv = jax.scipy.linalg.lu_factor(J)
    swaps = jnp.sum(piv != jnp.arange(piv.shape[0], dtype=piv.dtype))
    sign = jnp.prod(jnp.sign(jnp.diagonal(lu))) * jnp.where(swaps % 2 == 0, 1.0, -1.0)
    return r, (lu, piv), sign


def _apply_inverse(problem, factors, r, linear_solver):
    """J^-1 r from the factors of J."""
    if linear_solver == "banded":
        return _banded.solve_factored(problem.topo.band, factors, r)
    return jax.scipy.linalg.lu_solve(factors, r)


def _newton_step(problem, lam, y, linear_solver):
    """The Newton step J^-1 r at y, the residual r and the sign of det J."""
    r, factors, sign = _linearise(problem, lam, y, linear_solver)
    return _apply_inverse(problem, factors, r, linear_solver), r, sign


def _cap_rotation(problem, dy, cap):
    """Scale a Newton step so that no segment's start frame turns by more than `cap` rad.

    Plain Newton from the undeformed shape overshoots large rotations (the residual is
    trigonometric in them) and diverges for loads well below the limit load; limiting the
    rotation part of the step keeps it in the region where the linearisation holds."""
    rot = dy.reshape(problem.table.length.shape[0], -1)[:, problem.model.rotation_slice]
    return dy * jnp.minimum(1.0, cap / jnp.maximum(jnp.max(jnp.abs(rot)), 1e-300))


def _backtrack(problem, lam, y, dy, r, max_halvings=12):
    """Shorten a Newton step until the residual norm decreases (Armijo, factor 1/2).

    Contact penalties make the residual grow fast with penetration; a full step taken from
    a state without contact can run deep into an object, so the step is cut back. Returns
    the step and the residual at its end (y - step)."""
    norm0 = jnp.sum(r * r)
    fn = lambda a: _natural_fn(y - a * dy, (problem, lam))

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


def _newton_lean(
    problem,
    y0,
    lam,
    options: SolverOptions,
    active=True,
    max_halvings=12,
    max_rounds=3,
    chord=None,
    arc=None,
):
    """Newton's method on the natural residual, with a line search that costs nothing when
    the full step is good; or, where `arc` says so, the continuation's corrector.

    Each iteration linearises at the trial point y - a dy. If its residual norm has not
    decreased enough (Armijo, ||r||^2 <= (1 - 1e-4 a) ||r_y||^2) the linearisation is
    dropped and the next iteration tries half the step; otherwise the trial point is
    accepted and its factors give the next step. The residual that decides is the one the
    Jacobian pass computes anyway, so a run of full steps pays no extra residual. Far from
    the root this keeps Newton from wandering: ref-A's L2 (1.5 N, three quarters of the
    limit load) is solved directly in 14 linearisations planar and 16 in 3-D; without it
    capped Newton wandered (in 3-D past max_newton_steps, so the solve fell back to 55
    continuation iterations). With contact (objects or a support) every step is instead
    backtracked on the spot, residuals only (`_backtrack`): a penalty grows so fast with
    penetration that a full step into an object is rarely any good.

    Near the root (options.reuse_jacobian) an iteration may instead be a chord step: the
    residual alone at the trial point, solved with the factors of the last accepted
    linearisation. That follows a Newton step shorter than options.reuse_jacobian_below
    in every scaled unknown, or a chord step that shrank the step tenfold; a chord trial
    that does not decrease the residual is linearised again at the same point. Chord
    steps converge linearly, so their convergence test is the remaining distance step
    ratio / (1 - ratio), ratio the contraction of the last two steps.

    Besides the root it returns the sign of det(J) at the first and the last accepted
    iterate (free from the LU factors), which tells whether the root lies on the branch of
    the start. Converged when the step and the residual are below atol + rtol |y|
    (scaled), or when Newton is in its quadratic regime and the predicted next step,
    step_k^3 / step_(k-1)^2, is below a tenth of that: this saves the iteration that would
    only confirm convergence (a 1 % design change is then re-solved in 2 iterations
    instead of 3). Also when the full Newton step is below a tenth of the tolerance (norm-
    wise, atol + rtol max|y|): with
    a stiff contact penalty the residual's round-off floor can lie above atol, and a
    start at the root would otherwise never be confirmed. The converged iterate is
    y - dy, whose residual is not evaluated here (the residual reported in the Solution
    always is).

    chord: the factors of a Jacobian near y0 and whether to use them (`WarmStart`: those
    of the solution a warm start comes from, banded solver only). Newton then begins with
    chord steps on them instead of a linearisation at y0 (ref-A L2 after a 1 % change of
    the back beam's thickness: 7 chord steps, 0.90 ms, against two linearisations and a
    chord step, 1.13 ms; benchmarks/README.md, session 25). The chord rules above then
    apply from the first step, with one change: if the first chord trial does not
    decrease the residual, the next iteration linearises at the start, not at the trial
    (so factors that do not fit cost two iterations, and Newton then runs as from a
    plain start).

    arc: None, or an `Arc`: where its `on` holds, this is instead the continuation's
    corrector, Newton on the bordered system r(y, lam) = 0, t . (w (y - y_prev),
    lam - lam_prev) = ds from (y0, lam). Each iteration linearises (no chord steps, cap or
    line search) and solves with the factors of J alone (bordering): with a = J^-1 r and
    b = J^-1 dr/dlam the step is dlam = (g - w t_y . a) / (t_lam - w t_y . b) and
    dy = a - b dlam, g the constraint's residual. Converged when the step is below
    atol + rtol |z| and both residuals below atol, or when the step alone is below a tenth
    of that (as plain Newton's `full` test: a contact penalty's round-off floor in the
    residual, 2-5e-10 on a cantilever wrapping a cylinder under a unit tip force, would
    otherwise keep short, smooth steps of the path iterating to max_newton_steps). The
    last linearisation then lies within that tolerance of the root, so its b and sign
    serve the path's tangent there. One
    function for both, so that a core that runs both (`_path`) holds one Jacobian pass:
    ref-A L1's full core compiled in 7.8-7.9 s instead of 9.8 s planar and in 11.6 s
    instead of 14.7 s in 3-D (L3 planar, 9.1-9.4 s instead of 11.5 s), with the same
    roots, iteration counts and limit loads (session 32).
    """
    contact = problem.topo.contact is not None
    choosing = contact and problem.topo.contact.near is not None
    solver = options.linear_solver
    S = problem.table.length.shape[0]
    at = lambda st: dataclasses.replace(problem, order=st.order) if choosing else problem
    reuse_below = options.reuse_jacobian_below
    if reuse_below is None:
        reuse_below = 0.1 if contact else 1.0

    bordered = arc is not None
    on = arc.on if bordered else False

    def fresh(y_t, lam_t, st):
        if not bordered:
            return _linearise(at(st), lam_t, y_t, solver) + (None,)
        return _linearise_arc(at(st), lam_t, y_t, solver, on)

    def reused(y_t, lam_t, st):
        # With contact the backtracking has evaluated the residual at y_t already.
        r = st.r_next if contact else _natural_fn(y_t, (problem, lam_t))
        return r, st.factors, st.sign, st.b

    def far_touch(gaps, order):
        """Whether a segment outside the near ones of `order` touches (the contact law
        left out there was not zero)."""
        return jnp.min(gaps[order[problem.topo.contact.near :]]) < 0.0

    def choose(y, lam_y, order):
        """The segments nearest first at y (gaps along every segment), and `far_touch`."""
        gaps = problem.gaps(y.reshape(S, -1), lam_y)
        return jnp.argsort(gaps), far_touch(gaps, order)

    def body(st: _Newton):
        y_t = st.y - st.a * st.dy
        lam_t = st.lam - st.a * st.dlam if bordered else lam
        if options.reuse_jacobian:
            r, factors, sign, b = lax.cond(st.reuse, reused, fresh, y_t, lam_t, st)
        else:
            r, factors, sign, b = fresh(y_t, lam_t, st)
        dy = _apply_inverse(problem, factors, r, solver)
        norm = jnp.sum(r * r)
        # Newton's own correction (before any line search or cap) in units of the
        # tolerance, norm-wise: below a tenth, y_t is the root to within round-off, even
        # where the residual sits on a round-off floor above atol (stiff contact
        # penalties), and y_t - dy is closer still (by the step squared). Norm-wise, as
        # the unknowns are scaled to order one: per component, an unknown near zero would
        # need its round-off below atol, which a tight atol (1e-17) never reaches.
        full = jnp.max(jnp.abs(dy)) / (options.atol + options.rtol * jnp.max(jnp.abs(y_t)))
        first = st.k == 0
        start = first | st.restart
        decreased = norm <= (1.0 - 1e-4 * st.a) * st.norm
        # A chord step whose trial point did not decrease the residual is not cut: the
        # next iteration linearises at the same point instead.
        retry = jnp.asarray(False) if contact else st.reuse & ~decreased
        accept = start | contact | decreased
        accept = accept | ((st.a < 0.5**max_halvings) & ~retry)

        def newton_step(dy):
            if options.max_rotation_step is not None:
                dy = _cap_rotation(problem, dy, options.max_rotation_step)
            return dy, jnp.zeros((), dy.dtype), jnp.asarray(False)

        def corrector_step(dy):
            """The bordered step where `on`, and its convergence test."""
            wt = arc.w * arc.t[:-1]
            g = jnp.dot(wt, y_t - arc.y) + arc.t[-1] * (lam_t - arc.lam) - arc.ds
            d_lam = (g - jnp.dot(wt, dy)) / (arc.t[-1] - jnp.dot(wt, b))
            d_y = dy - b * d_lam
            y, lam = y_t - d_y, lam_t - d_lam
            scale = lambda z: options.atol + options.rtol * jnp.abs(z)
            small = jnp.maximum(jnp.max(jnp.abs(d_y) / scale(y)), jnp.abs(d_lam) / scale(lam))
            resid = jnp.maximum(jnp.max(jnp.abs(r)), jnp.abs(g)) < options.atol
            # (or the step alone, below a tenth of the tolerance: see `full` above)
            resid = resid | (small < 0.1)
            finite = jnp.all(jnp.isfinite(y)) & jnp.isfinite(lam)
            return d_y, d_lam, (small < 1.0) & resid & finite

        if bordered:
            dy, dlam, conv_arc = _if(on, corrector_step, newton_step, dy)
            accept = accept | jnp.asarray(on)
        else:
            dy = newton_step(dy)[0]
        r_next = st.r_next
        if contact:  # (after the cap: r_next is the residual where the step ends)
            halvings = _where(on, 0, max_halvings) if bordered else max_halvings
            dy, r_next = _backtrack(at(st), lam_t, y_t, dy, r, halvings)
        y = y_t - dy
        scale = options.atol + options.rtol * jnp.abs(y)
        finite = jnp.all(jnp.isfinite(y))
        step = jnp.max(jnp.abs(dy) / scale)
        biggest = jnp.max(jnp.abs(dy))
        near = biggest < 1e-4
        conv = (step < 1.0) & (jnp.max(jnp.abs(r)) < options.atol)
        ratio = step / jnp.maximum(st.step, 1e-300)
        # Newton's quadratic regime: the next step would be step^3 / previous^2. A chord
        # step contracts linearly (by `ratio`): what is left is step ratio / (1 - ratio).
        quadratic = (~start) & (ratio < 1e-2) & (step * ratio**2 < 0.1) & near & ~st.reuse
        linear = st.reuse & ~start & (ratio < 0.5) & (step * ratio / (1.0 - ratio) < 0.1)
        linear = linear & near
        conv_newton = accept & (conv | (full < 0.1) | quadratic | linear)
        if bordered:
            lam_new = lam_t - dlam
            conv = _where(on, conv_arc, conv_newton)
        else:
            conv = conv_newton
        no = jnp.asarray(False)
        order, again, outside = st.order, no, st.outside
        if choosing:
            # A root of the near problem is a root of the whole one where no segment
            # outside the near ones touches. Checked at a root, and wherever a far
            # segment's start lies inside an object (cheap: no integration); on contact
            # outside, choose again from there and go on while rounds are left.
            lam_y = lam_new if bordered else lam
            inside = far_touch(problem.gaps(y.reshape(S, -1), lam_y, along=False), st.order)
            keep = lambda y, l, o: (o, jnp.asarray(False))
            order, missed = lax.cond(conv | inside, choose, keep, y, lam_y, st.order)
            again = missed & (st.rounds < max_rounds)
            outside = outside | (missed & ~again)  # (and give up)
            conv = conv & ~missed
        # The next iteration reuses these factors while that is cheaper than linearising:
        # after a short Newton step, or a chord step that contracted tenfold. (With a
        # fourfold bound the grasp's release traces stalled at max_newton_steps.)
        short = biggest < reuse_below
        reuse_next = accept & jnp.where(st.reuse, ratio < 0.1, short)
        if bordered:
            reuse_next = reuse_next & ~jnp.asarray(on)
        k = st.k + 1
        # (a warm start's first chord trial that fails is linearised at the start)
        retry_at = jnp.where(st.warm & (k == 2), 0.0, st.a)
        pick = lambda new, old: jnp.where(accept, new, old)
        return _Newton(
            y=jnp.where(conv | again, y, pick(y_t, st.y)),
            norm=pick(norm, st.norm),
            dy=jnp.where(again, 0.0, pick(dy, st.dy)),
            a=jnp.where(accept, 1.0, jnp.where(retry, retry_at, 0.5 * st.a)),
            step=pick(step, st.step),
            k=k,
            done=conv | outside | (accept & ~finite) | (k >= options.max_newton_steps),
            ok=conv & finite,
            sign_first=jnp.where(first, sign, st.sign_first),
            sign=pick(sign, st.sign),
            factors=jax.tree_util.tree_map(pick, factors, st.factors),
            reuse=options.reuse_jacobian & reuse_next & ~again,
            r_next=r_next,
            order=order,
            rounds=jnp.where(again, st.rounds + 1, st.rounds),
            restart=again,
            outside=outside,
            warm=st.warm,
            lam=jnp.where(conv | again, lam_new, pick(lam_t, st.lam)) if bordered else None,
            dlam=jnp.where(again, 0.0, pick(dlam, st.dlam)) if bordered else None,
            b=pick(b, st.b) if bordered else None,
        )

    # (the factors' shapes do not depend on `order`)
    if solver == "banded":  # (no trace of a linearisation: 0.5-0.8 s of tracing)
        factors = _banded.no_factors(problem.topo.band, y0.dtype)
    else:
        factors = jax.eval_shape(lambda: _linearise(problem, lam, y0, solver))[1]
    factors = jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), factors)
    sign, reuse, r_next = jnp.asarray(0.0), jnp.asarray(False), jnp.zeros_like(y0)
    order = jnp.argsort(problem.gaps(y0.reshape(S, -1), lam)) if choosing else None
    if chord is not None and solver == "banded" and options.reuse_jacobian:
        factors, reuse = chord.factors, jnp.asarray(chord.use)
        sign = factors.sign
        if contact:  # (a chord step reads the residual at its trial point from here)
            first_at = dataclasses.replace(problem, order=order) if choosing else problem
            r_next = lax.cond(
                reuse, lambda: _natural_fn(y0, (first_at, lam)), lambda: jnp.zeros_like(y0)
            )
    init = _Newton(
        y=y0,
        norm=jnp.asarray(jnp.inf),
        dy=jnp.zeros_like(y0),
        a=jnp.asarray(0.0),
        step=jnp.asarray(jnp.inf),
        k=jnp.asarray(0),
        done=~jnp.asarray(active),
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
    return lax.while_loop(lambda st: ~st.done, body, init)


def _root_primal(inputs):
    _, _, y = inputs
    return y, None


def _root_rewrite(root, residual, inputs):
    del residual
    problem, lam, _ = inputs
    return _natural_fn(root, (problem, lam))


def _attach_implicit_gradient(problem, lam, y, linear_solver):
    """Return y (a root of the residual) with tangents from the implicit function theorem,
    dy = -J^-1 (dr/d(design, lam)) d(design, lam), and the segments' trajectories at it
    (S, steps + 1, n_full) with their tangents, or None (the dense option: the outputs
    then integrate them, and differentiate through the integrator)."""
    y = lax.stop_gradient(y)
    if linear_solver == "banded":
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


class Arc(eqx.Module):
    """The continuation's arc-length constraint t . (w (y - y_prev), lam - lam_prev) = ds
    for `_newton_lean`, and whether it applies (`on`; else Newton runs at fixed lam). `on`
    may be a Python bool (the limit load's corrector): the other mode is then not traced."""

    on: jax.Array
    y: jax.Array  # y_prev
    lam: jax.Array  # lam_prev
    t: jax.Array  # unit tangent in the weighted coordinates (w y, lam)
    ds: jax.Array
    w: jax.Array


def _linearise_arc(problem, lam, y, linear_solver, on):
    """`_linearise` (r, factors, sign of det J), and b = J^-1 dr/dlam where `on` (zeros
    elsewhere): what a step of the continuation's corrector and the path's tangent need.

    Without distributed loads (the usual case: point loads are jumps between segments)
    the segments' flows do not depend on lam, so dr/dlam is the residual's own derivative
    at the end states of the Jacobian pass, and the pass is J's alone. Paired against a
    pass for dr/dlam (below), ref-A L1's full core compiled in 6.6-6.8 s against 8.1 s
    planar and 10.7-11.1 s against 12.6-12.8 s in 3-D, and `limit_load` ran in 119-121
    against 145-147 ms (planar) and 950-1000 against 1152-1162 ms (3-D), with the same
    limit loads to 12 digits (session 31, when the corrector had a Jacobian pass of its
    own). With distributed loads dr/dlam is a forward-mode pass of its own through the
    integrator (one tangent), where `on` only."""
    S = problem.table.length.shape[0]
    one = jnp.ones_like(lam)
    if linear_solver == "banded" and not problem.topo.distributed:
        # (the flows do not depend on lam: see above)
        def fn(a):
            starts, ends = problem.ends(a.reshape(S, -1), lam)
            return problem.residual_from_states(starts, ends, lam).reshape(-1), (starts, ends)

        plan = problem.topo.band
        r, jvp, (starts, ends) = jax.linearize(fn, y, has_aux=True)
        factors = _banded.factor(plan, _banded.band(plan, _banded.seeded(plan, jvp, y.dtype)))
        sign = factors.sign

        def r_lam():
            at = lambda l: problem.residual_from_states(starts, ends, l).reshape(-1)
            return jax.jvp(at, (lam,), (one,))[1]

    else:
        r, factors, sign = _linearise(problem, lam, y, linear_solver)
        Y = y.reshape(S, -1)

        def r_lam():
            starts = problem.start_states(Y)

            def residual(l):
                return problem.residual_from_states(starts, problem.integrated(Y, l)[:, -1], l)

            return jax.jvp(residual, (lam,), (one,))[1]

    b = _if(
        on,
        lambda: _apply_inverse(problem, factors, r_lam(), linear_solver),
        lambda: jnp.zeros_like(y),
    )
    return r, factors, sign, b


# The largest change of any scaled unknown that the first continuation step may predict
# (linearly, along the initial tangent). Scaled unknowns measure forces in units of EI/L^2:
# ref-A's point-load paths reach their fold after about 490 of them (L1 at load factor
# 36.5, L2 at 1.22), the distributed L3 after about 590, whatever the load's magnitude.
# So 200 leaves the steps of those cases as they are (their first steps predict 3 to 96)
# and keeps a first step short of the fold when the load is so large that the fold lies
# at a tiny load factor.
FIRST_STEP_CHANGE = 200.0


class _Arc(eqx.Module):
    sign: jax.Array  # sign of det(dr/dy) on the branch being traced
    y: jax.Array
    lam: jax.Array
    t: jax.Array  # unit tangent in the weighted coordinates (w y, lam)
    w: jax.Array  # weight of the shape part (set by the first tangent)
    ds: jax.Array
    unit: jax.Array  # factor on the options' arc steps (set by the first tangent, <= 1)
    started: jax.Array  # the tangent at the start is known
    near_fold: jax.Array
    done: jax.Array
    reached: jax.Array
    y_over: jax.Array  # first accepted point beyond the target
    lam_over: jax.Array
    steps: jax.Array
    iterations: jax.Array
    # The turn (rad) of the tangent over the last step rejected from this point although
    # its corrector converged on the branch (same sign of det J, load rising): for turning
    # by more than arccos(min_tangent_cosine) or for needing more than
    # max_corrector_steps; 0 after any other step. (See `_arc_advance`: corners.)
    turned: jax.Array
    # Why the last step was rejected (a RESULTS item): what a continuation whose step
    # collapses reports.
    why: object


def _arc_step(s: _Arc, on=True):
    """The next step's constraint from the path's state and its predictor
    (y + ds t_y / w, lam + ds t_lam): (Arc, y, lam). The first step has length zero (at
    the start): it gives the first tangent and the weight w."""
    ds = jnp.where(s.started, s.ds, 0.0)
    return Arc(on, s.y, s.lam, s.t, ds, s.w), s.y + ds * s.t[:-1] / s.w, s.lam + ds * s.t[-1]


def _arc_advance(s: _Arc, c: _Newton, target, opts: SolverOptions) -> _Arc:
    """The path's state after a corrector `c` (a bordered `_newton_lean` from the
    predictor of `_arc_step(s)`): accept the point, or halve the step.

    The tangent at the new point comes from the corrector's last linearisation: in the
    weighted coordinates (w y, lam) it is (-w J^-1 dr/dlam, 1), normalised and oriented
    along the last one. The first pass (a step of length zero) sets the weight w, which
    makes the tangent's shape and load parts equal, and the arc steps' unit (see
    FIRST_STEP_CHANGE).

    A corner of the path (contact that begins: with a stiff penalty the path's slope
    changes within a penetration of a few hundredths of a millimetre, a tiny part of a
    step) turns the tangent by the same angle however short the step that crosses it,
    where a smooth bend turns it in proportion to the step. So a step whose corrector
    converged on the branch (det J of the same sign, load rising, within
    max_corrector_steps) is accepted although its tangent turns by more than
    arccos(min_tangent_cosine) when the step of twice its length from the same point,
    rejected for its turn or its corrector iterations, turned it by less than 4/3 as
    much. (A cantilever that a tip force wraps on a cylinder, `tests/test_wrap.py`, has
    such a corner where contact begins: a step across it turns the tangent by 40-50
    degrees however short, down to min_arc_step.)

    A rejected step records its cause in `why` (the result a collapsed step reports):
    contact outside the near segments, a corrector that did not converge, det J changing
    sign while the load still rose (another branch), or the turn and corrector tests."""
    first = ~s.started
    y1, lam1, ok, nit, b = c.y, c.lam, c.ok, c.k, c.b
    w = jnp.where(first, 1.0 / jnp.maximum(jnp.linalg.norm(b), 1e-30), s.w)
    # A step ds along the first tangent (-w b, 1) / sqrt(2) predicts a change of
    # ds max|b| / sqrt(2) in the scaled unknowns.
    change = opts.initial_arc_step * jnp.max(jnp.abs(b)) / jnp.sqrt(2.0)
    unit = jnp.where(first, jnp.minimum(1.0, FIRST_STEP_CHANGE / change), s.unit)
    t1 = jnp.concatenate([-w * b, jnp.ones((1,), b.dtype)])
    t1 = t1 / jnp.linalg.norm(t1)
    t1 = jnp.where(jnp.dot(t1, s.t) < 0.0, -t1, t1)
    sign1 = c.sign
    sign = jnp.where(first, sign1, s.sign)
    # A step that turns the tangent sharply, or needs many corrector iterations, may
    # have jumped to another branch: retry shorter. On the traced branch det(dr/dy)
    # keeps its sign until the fold, where the load factor turns back; a sign change
    # while the load still rises (or the reverse) is a jump to another branch.
    cosine = jnp.dot(t1, s.t)
    few = nit <= opts.max_corrector_steps
    smooth = (cosine >= opts.min_tangent_cosine) & few
    same = sign1 == sign
    rising = t1[-1] > 0.0
    folded = ok & smooth & ~same & ~rising & ~first
    on_branch = ok & same & rising & ~first
    turn = jnp.arccos(jnp.clip(cosine, -1.0, 1.0))
    corner = on_branch & few & (s.turned > 0.0) & (turn >= 0.75 * s.turned)
    accept = ok & (first | (smooth & same & rising) | corner)
    turned = jnp.where(on_branch & ~smooth & ~accept, turn, 0.0)
    why = RESULTS.where(
        c.outside,
        RESULTS.contact_outside_near_segments,
        RESULTS.where(
            ~ok,
            RESULTS.continuation_corrector_failed,
            RESULTS.where(
                ~same & rising, RESULTS.continuation_branch_switch, RESULTS.continuation_failed
            ),
        ),
    )
    reached = accept & (lam1 >= target) & ~first
    grow = accept & (nit <= 4) & ~s.near_fold & ~first
    ds_new = jnp.where(
        accept,
        jnp.where(grow, jnp.minimum(1.6 * s.ds, unit * opts.max_arc_step), s.ds),
        0.5 * s.ds,
    )
    ds_new = jnp.where(first, unit * s.ds, ds_new)
    near_fold = s.near_fold | folded
    tiny = ds_new < unit * opts.min_arc_step
    keep = accept & ~reached
    count = jnp.where(first, 0, 1)
    return _Arc(
        sign=sign,
        y=jnp.where(keep, y1, s.y),
        lam=jnp.where(keep, lam1, s.lam),
        t=jnp.where(keep, t1, s.t),
        w=w,
        ds=ds_new,
        unit=unit,
        started=s.started | ok,
        near_fold=near_fold,
        done=reached | (~accept & tiny) | (first & ~ok),
        reached=reached,
        y_over=jnp.where(reached, y1, s.y_over),
        lam_over=jnp.where(reached, lam1, s.lam_over),
        steps=s.steps + count,
        iterations=s.iterations + count * nit,
        turned=turned,
        why=RESULTS.where(accept, s.why, why),
    )


def _arc_over(s: _Arc, options: SolverOptions):
    """Whether the continuation has stopped: done (reached, or the arc step collapsed), or
    out of max_continuation_steps."""
    return s.done | (s.steps >= options.max_continuation_steps)


def _arc_start(y0, options: SolverOptions) -> _Arc:
    """The continuation's state before its first step."""
    false, zero = jnp.asarray(False), jnp.zeros(())
    return _Arc(
        sign=zero,
        y=y0,
        lam=zero,
        t=jnp.zeros(y0.shape[0] + 1).at[-1].set(1.0),
        w=jnp.ones(()),
        ds=jnp.asarray(options.initial_arc_step),
        unit=jnp.ones(()),
        started=false,
        near_fold=false,
        done=false,
        reached=false,
        y_over=y0,
        lam_over=zero,
        steps=jnp.asarray(0),
        iterations=jnp.asarray(0),
        turned=zero,
        why=RESULTS.continuation_failed,
    )


def _stopped(s: _Arc):
    """Why a continuation that neither reached its target nor found a fold stopped: its
    arc step collapsed (done; the cause of the last rejection, `_Arc.why`), or it ran out
    of steps while the load still rose."""
    return RESULTS.where(s.done, s.why, RESULTS.continuation_steps_exhausted)


def _fold_result(s: _Arc):
    failed = RESULTS.where(s.near_fold, RESULTS.beyond_limit_load, _stopped(s))
    return RESULTS.where(s.reached, RESULTS.successful, failed)


# --------------------------------------------------------------------------------------
# The jitted cores
# --------------------------------------------------------------------------------------


def _make_problem(topo, integrator, finger) -> Problem:
    geo = geometry(finger)
    return Problem(topo, integrator, finger, geo, segment_table(topo, finger, geo))


def _nograd(tree):
    return jax.tree_util.tree_map(lambda x: lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


def _on_branch(newton: _Newton, ref_sign=None):
    """Whether a Newton solve at full load converged on the branch it started from: the
    sign of det J at the last iterate is that at the first (no fold crossed), or
    `ref_sign` when given and nonzero (the sign on the branch being followed: a path of
    equilibria compares with its last point, not with the start of Newton, which lies off
    the path and may have either sign)."""
    ref = newton.sign_first
    if ref_sign is not None:
        ref = jnp.where(ref_sign == 0.0, ref, ref_sign)
    return newton.ok & (newton.sign == ref)


def _direct(quiet: Problem, y_start, options, ref_sign=None, chord=None):
    """Newton at full load, and whether it is accepted (`_on_branch`)."""
    direct = _newton_lean(quiet, y_start, jnp.ones(()), options, chord=chord)
    return direct, _on_branch(direct, ref_sign)


class WarmStart(eqx.Module):
    """A Newton start for the cores with the factors of a Jacobian near it: the scaled
    unknowns and the banded LU of the solution a warm start comes from
    (`Solution.jacobian`), and whether to use the factors (False: a plain start at
    `unknowns`, the same compiled program)."""

    unknowns: jax.Array
    factors: _banded.BandLU
    use: jax.Array


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
# times faster than eqx.filter_jit (~0.1 ms against ~0.4 ms per call, measured).
_core_jit = functools.partial(jax.jit, static_argnums=(0, 1, 2))


@functools.partial(_core_jit, static_argnames=("keep_jacobian",))
def _direct_core(
    topo,
    integrator,
    options: SolverOptions,
    finger: Finger,
    init,
    ref_sign=None,
    keep_jacobian=False,
):
    """Only the direct Newton solve (compiles in about half the time of `_solve_core`);
    `solve_finger` falls back to the continuation when it is not accepted.

    init: None, scaled unknowns or a `WarmStart`. ref_sign: the sign of det J on the
    branch being followed (see `_direct`; 0 or None: the sign at Newton's start).
    keep_jacobian: return the factors of Newton's last linearisation in
    `Solution.jacobian` (banded solver only; what a warm start from this solution
    begins with). Returns (Solution, accepted, sign of det J at the root)."""
    problem = _make_problem(topo, integrator, finger)
    quiet = _nograd(problem)
    _, y_start, chord = _start(quiet, init)
    direct, ok = _direct(quiet, y_start, options, ref_sign, chord)
    one = jnp.ones(())
    y, traj = _attach_implicit_gradient(problem, one, direct.y, options.linear_solver)
    code = RESULTS.where(ok, RESULTS.successful, RESULTS.nonlinear_divergence)
    code = RESULTS.where(direct.ok & ~ok, RESULTS.branch_changed, code)
    code = RESULTS.where(direct.outside, RESULTS.contact_outside_near_segments, code)
    keep = keep_jacobian and options.linear_solver == "banded"
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
    problem = _make_problem(topo, None, finger)
    return _deformation(problem, unknowns.reshape(problem.table.length.shape[0], -1))


def start_from_deformation(topo, finger: Finger, deformation):
    """Scaled unknowns of `finger` deformed as `deformation` says (from `deformation_of`
    on another finger of the same topology): every segment's undeformed start state plus
    the other finger's displacement, rotation and internal wrench per unit E at its own
    segment start. For a changed design this is a better Newton start than the other
    finger's unknowns themselves, which also carry its undeformed geometry: on ref-A L1
    with attachments moved by up to 1 mm, 3.25 Newton iterations on average against 4.2
    (and 4.0 from the undeformed shape).

    Forces travel per unit E: for a change of E alone the start is then the old
    equilibrium at loads scaled by the ratio of the moduli, an equilibrium of the new
    design (in physical units L2 at E x 0.97 took 58 iterations, its direct Newton
    failing, against 6); a change of a thickness keeps the forces (in scaled unknowns,
    whose forces are in units of EI_front / L^2, L2 at front thickness x 1.01 took 60
    against 4)."""
    problem = _make_problem(topo, None, finger)
    return (problem.undeformed() + deformation / _carry_scale(problem)).reshape(-1)


@functools.partial(jax.jit, static_argnums=(0,))
def undeformed_unknowns(topo, finger: Finger):
    """The scaled unknowns of the undeformed finger (the start `init=None` means): a
    caller that passes them instead of None shares one compiled core for both starts."""
    return _make_problem(topo, None, finger).undeformed().reshape(-1)


class _Path(eqx.Module):
    phase: jax.Array  # 0: Newton at full load; 1: continuation; 2: Newton after it; 3: finished
    arc: _Arc
    y: jax.Array
    lam: jax.Array
    code: object  # RESULTS item
    iterations: jax.Array


def _continuation(problem, y0, target, options: SolverOptions) -> _Arc:
    """The continuation alone (the limit load): arc steps from (y0, lam = 0) until the
    path stops (`_arc_advance`). Its Newton is the corrector alone: no chord steps, cap
    or plain-Newton branches are compiled."""
    corrector = dataclasses.replace(options, reuse_jacobian=False, max_rotation_step=None)

    def body(s: _Arc):
        arc, y, lam = _arc_step(s)
        return _arc_advance(s, _newton_lean(problem, y, lam, corrector, arc=arc), target, options)

    return lax.while_loop(lambda s: ~_arc_over(s, options), body, _arc_start(y0, options))


def _path(problem, y_start, y_und, options: SolverOptions, chord=None, phase=0):
    """Direct Newton at full load (lam = 1), else pseudo-arc-length continuation from
    (y_und, lam = 0) toward lam = 1 and Newton again at full load from the point it
    reached: one loop whose every pass is one `_newton_lean`, plain (phases 0 and 2) or
    the continuation's corrector (phase 1, one arc step per pass). So the core holds one
    Newton and one Jacobian pass, whatever it runs. phase: where to begin (1: with
    the continuation, as for direct_first=False).

    The continuation stops when the path crosses lam = 1 (reached: Newton at full load
    then starts between the point before and the first point past it) or when it folds
    back (the load factor stops increasing), refining the fold by step halving down to
    min_arc_step; see `_arc_advance`."""
    one = jnp.ones(())

    def body(st: _Path):
        p, s = st.phase, st.arc
        cont = p == 1
        arc, y_pred, lam_pred = _arc_step(s, cont)
        frac = (1.0 - s.lam) / jnp.maximum(s.lam_over - s.lam, 1e-300)
        guess = jnp.where(s.reached, s.y + frac * (s.y_over - s.y), s.y)
        y0 = jnp.where(p == 0, y_start, jnp.where(cont, y_pred, guess))
        lam0 = jnp.where(cont, lam_pred, one)
        # (a warm start's factors serve the direct Newton only)
        warm = None
        if chord is not None:
            warm = WarmStart(chord.unknowns, chord.factors, chord.use & (p == 0))
        newton = _newton_lean(problem, y0, lam0, options, p < 3, chord=warm, arc=arc)
        # Phase 0: accepted, or on to the continuation.
        direct_ok = _on_branch(newton)
        # Phase 1: the next arc step; once it stops, Newton at full load where it reached.
        s1 = lax.cond(cont, lambda: _arc_advance(s, newton, one, options), lambda: s)
        s1 = jax.tree_util.tree_map(
            lambda a, b: jnp.where(p == 0, a, b), _arc_start(y_und, options), s1
        )
        # Phase 2 (and a continuation that stops short): the fold, or Newton's root on the
        # traced branch.
        code = _fold_result(s1)
        off_branch = s.reached & (~newton.ok | (newton.sign != s.sign))
        code = RESULTS.where(off_branch, RESULTS.nonlinear_divergence, code)
        outside = s.reached & newton.outside
        code = RESULTS.where(outside, RESULTS.contact_outside_near_segments, code)
        code = RESULTS.where(p == 0, RESULTS.successful, code)
        over = _arc_over(s1, options)
        stopped = over & ~s1.reached
        after_arc = jnp.where(over, jnp.where(s1.reached, 2, 3), 1)
        phase = jnp.select([p == 0, cont], [jnp.where(direct_ok, 3, 1), after_arc], 3)
        y = jnp.where(cont, s1.y, newton.y)
        lam = jnp.where(cont, s1.lam, one)
        counted = jnp.where(cont, jnp.where(s.started, newton.k, 0), newton.k)
        return _Path(
            phase=jnp.where(p < 3, phase, 3),
            arc=s1,
            y=y,
            lam=lam,
            code=RESULTS.where(cont & ~stopped, st.code, code),
            iterations=st.iterations + counted,
        )

    init = _Path(
        phase=jnp.asarray(phase),
        arc=_arc_start(y_und, options),
        y=y_start,
        lam=one,
        code=RESULTS.successful,
        iterations=jnp.asarray(0),
    )
    return lax.while_loop(lambda st: st.phase < 3, body, init)


@_core_jit
def _solve_core(topo, integrator, options: SolverOptions, finger: Finger, init):
    """Direct Newton, else arc-length continuation and Newton again from the point it
    reached, all traced (for jit, vmap, grad): one loop, one Newton (`_path`)."""
    problem = _make_problem(topo, integrator, finger)
    quiet = _nograd(problem)
    y_und, y_start, chord = _start(quiet, init)
    st = _path(quiet, y_start, y_und, options, chord, 0 if options.direct_first else 1)
    y, traj = _attach_implicit_gradient(problem, st.lam, st.y, options.linear_solver)
    return _outputs(problem, y, st.lam, st.code, st.iterations, traj)


@_core_jit
def _limit_core(topo, integrator, options: SolverOptions, finger: Finger):
    problem = _nograd(_make_problem(topo, integrator, finger))
    y_und = problem.undeformed().reshape(-1)
    s = _continuation(problem, y_und, jnp.asarray(jnp.inf), options)
    code = RESULTS.where(s.near_fold, RESULTS.successful, _stopped(s))
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
    q_problem, q_traj, q_lam = _nograd((problem, traj, lam))
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


def _warm_start(topo, options: SolverOptions, y0, init: Solution | None, concrete: bool):
    """The core's `init` for a start at y0 (None: undeformed): with the banded solver a
    `WarmStart` carrying init's Jacobian factors when it has them (eagerly, zero factors
    unused when it has none, so that both share one compiled program)."""
    if y0 is None or options.linear_solver != "banded":
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
    y0 = _warm_start(topo, options, y0, init, concrete and options.direct_first)
    if options.direct_first and concrete:
        # Called eagerly: compile and run the direct solve alone, and compile the
        # continuation only for fingers that need it.
        sol, ok, _ = _direct_core(
            topo, integrator, options, finger, y0, keep_jacobian=keep_jacobian
        )
        if not bool(ok):
            cont = dataclasses.replace(options, direct_first=False)
            failed_its = sol.iterations
            sol = _solve_core(topo, integrator, cont, finger, None)
            sol = eqx.tree_at(lambda x: x.iterations, sol, sol.iterations + failed_its)
    else:
        sol = _solve_core(topo, integrator, options, finger, y0)
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
    lam, sol = _limit_core(topo, integrator, options, finger)
    return LimitLoad(lam, sol)
