"""Pseudo-arc-length continuation of the shooting problem in its load factor, and the
solve's path: direct Newton at full load, else continuation toward it and Newton again.

A path's state (`ArcState`) advances by one corrector solve per step (`arc_advance`):
the corrector is `ShootingNewton` on the bordered system (finray_jax._newton). The path
stops when it crosses its target load factor, or when it folds back (the load factor
stops increasing), refining the fold by step halving down to min_arc_step.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax

from ._newton import Arc, NewtonState, WarmStart, on_branch, solve_root
from ._options import SolverOptions
from ._solution import RESULTS

# The largest change of any scaled unknown that the first continuation step may predict
# (linearly, along the initial tangent). Scaled unknowns measure forces in units of EI/L^2:
# ref-A's point-load paths reach their fold after about 490 of them (L1 at load factor
# 36.5, L2 at 1.22), the distributed L3 after about 590, whatever the load's magnitude.
# So 200 leaves the steps of those cases as they are (their first steps predict 3 to 96)
# and keeps a first step short of the fold when the load is so large that the fold lies
# at a tiny load factor.
FIRST_STEP_CHANGE = 200.0


class ArcState(eqx.Module):
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
    # max_corrector_steps; 0 after any other step. (See `arc_advance`: corners.)
    turned: jax.Array
    # Why the last step was rejected (a RESULTS item): what a continuation whose step
    # collapses reports.
    why: object


def arc_step(s: ArcState, on=True):
    """The next step's constraint from the path's state and its predictor
    (y + ds t_y / w, lam + ds t_lam): (Arc, y, lam). The first step has length zero (at
    the start): it gives the first tangent and the weight w."""
    ds = jnp.where(s.started, s.ds, 0.0)
    return Arc(on, s.y, s.lam, s.t, ds, s.w), s.y + ds * s.t[:-1] / s.w, s.lam + ds * s.t[-1]


def _why_rejected(outside, ok, same, rising):
    """The result a rejected step reports: contact outside the near segments, a corrector
    that did not converge, det J changing sign while the load rose, or the turn tests."""
    return RESULTS.where(
        outside,
        RESULTS.contact_outside_near_segments,
        RESULTS.where(
            ~ok,
            RESULTS.continuation_corrector_failed,
            RESULTS.where(
                ~same & rising, RESULTS.continuation_branch_switch, RESULTS.continuation_failed
            ),
        ),
    )


def _next_step(s: ArcState, accept, first, nit, unit, opts: SolverOptions):
    """The next arc step's length: grown by 1.6 (up to max_arc_step) after an easy step
    away from a fold, kept after a hard one, halved after a rejected one; the first pass
    scales the initial step to the path's unit."""
    grow = accept & (nit <= 4) & ~s.near_fold & ~first
    ds_new = jnp.where(
        accept,
        jnp.where(grow, jnp.minimum(1.6 * s.ds, unit * opts.max_arc_step), s.ds),
        0.5 * s.ds,
    )
    return jnp.where(first, unit * s.ds, ds_new)


def arc_advance(s: ArcState, c: NewtonState, target, opts: SolverOptions) -> ArcState:
    """The path's state after a corrector `c` (a bordered `solve_root` from the
    predictor of `arc_step(s)`): accept the point, or halve the step.

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
    why = _why_rejected(c.outside, ok, same, rising)
    reached = accept & (lam1 >= target) & ~first
    ds_new = _next_step(s, accept, first, nit, unit, opts)
    near_fold = s.near_fold | folded
    tiny = ds_new < unit * opts.min_arc_step
    keep = accept & ~reached
    count = jnp.where(first, 0, 1)
    return ArcState(
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


def arc_over(s: ArcState, options: SolverOptions):
    """Whether the continuation has stopped: done (reached, or the arc step collapsed), or
    out of max_continuation_steps."""
    return s.done | (s.steps >= options.max_continuation_steps)


def arc_start(y0, options: SolverOptions) -> ArcState:
    """The continuation's state before its first step."""
    false, zero = jnp.asarray(False), jnp.zeros(())
    return ArcState(
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


def stopped(s: ArcState):
    """Why a continuation that neither reached its target nor found a fold stopped: its
    arc step collapsed (done; the cause of the last rejection, `ArcState.why`), or it ran out
    of steps while the load still rose."""
    return RESULTS.where(s.done, s.why, RESULTS.continuation_steps_exhausted)


def fold_result(s: ArcState):
    failed = RESULTS.where(s.near_fold, RESULTS.beyond_limit_load, stopped(s))
    return RESULTS.where(s.reached, RESULTS.successful, failed)


class PathState(eqx.Module):
    phase: jax.Array  # 0: Newton at full load; 1: continuation; 2: Newton after it; 3: finished
    arc: ArcState
    y: jax.Array
    lam: jax.Array
    code: object  # RESULTS item
    iterations: jax.Array


def continuation(problem, y0, target, options: SolverOptions) -> ArcState:
    """The continuation alone (the limit load): arc steps from (y0, lam = 0) until the
    path stops (`arc_advance`). Its Newton is the corrector alone: no chord steps, cap
    or plain-Newton branches are compiled."""
    corrector = dataclasses.replace(options, reuse_jacobian=False, max_rotation_step=None)

    def body(s: ArcState):
        arc, y, lam = arc_step(s)
        return arc_advance(s, solve_root(problem, y, lam, corrector, arc=arc), target, options)

    return lax.while_loop(lambda s: ~arc_over(s, options), body, arc_start(y0, options))


def path(problem, y_start, y_und, options: SolverOptions, chord=None, phase=0):
    """Direct Newton at full load (lam = 1), else pseudo-arc-length continuation from
    (y_und, lam = 0) toward lam = 1 and Newton again at full load from the point it
    reached: one loop whose every pass is one `solve_root`, plain (phases 0 and 2) or
    the continuation's corrector (phase 1, one arc step per pass). So the core holds one
    Newton and one Jacobian pass, whatever it runs. phase: where to begin (1: with
    the continuation, as for direct_first=False).

    The continuation stops when the path crosses lam = 1 (reached: Newton at full load
    then starts between the point before and the first point past it) or when it folds
    back (the load factor stops increasing), refining the fold by step halving down to
    min_arc_step; see `arc_advance`."""
    one = jnp.ones(())

    def body(st: PathState):
        p, s = st.phase, st.arc
        cont = p == 1
        arc, y_pred, lam_pred = arc_step(s, cont)
        frac = (1.0 - s.lam) / jnp.maximum(s.lam_over - s.lam, 1e-300)
        guess = jnp.where(s.reached, s.y + frac * (s.y_over - s.y), s.y)
        y0 = jnp.where(p == 0, y_start, jnp.where(cont, y_pred, guess))
        lam0 = jnp.where(cont, lam_pred, one)
        # (a warm start's factors serve the direct Newton only)
        warm = None
        if chord is not None:
            warm = WarmStart(chord.unknowns, chord.factors, chord.use & (p == 0))
        newton = solve_root(problem, y0, lam0, options, p < 3, chord=warm, arc=arc)
        # Phase 0: accepted, or on to the continuation.
        direct_ok = on_branch(newton)
        # Phase 1: the next arc step; once it stops, Newton at full load where it reached.
        s1 = lax.cond(cont, lambda: arc_advance(s, newton, one, options), lambda: s)
        s1 = jax.tree_util.tree_map(
            lambda a, b: jnp.where(p == 0, a, b), arc_start(y_und, options), s1
        )
        # Phase 2 (and a continuation that stops short): the fold, or Newton's root on the
        # traced branch.
        code = fold_result(s1)
        off_branch = s.reached & (~newton.ok | (newton.sign != s.sign))
        code = RESULTS.where(off_branch, RESULTS.nonlinear_divergence, code)
        outside = s.reached & newton.outside
        code = RESULTS.where(outside, RESULTS.contact_outside_near_segments, code)
        code = RESULTS.where(p == 0, RESULTS.successful, code)
        over = arc_over(s1, options)
        stopped = over & ~s1.reached
        after_arc = jnp.where(over, jnp.where(s1.reached, 2, 3), 1)
        phase = jnp.select([p == 0, cont], [jnp.where(direct_ok, 3, 1), after_arc], 3)
        y = jnp.where(cont, s1.y, newton.y)
        lam = jnp.where(cont, s1.lam, one)
        counted = jnp.where(cont, jnp.where(s.started, newton.k, 0), newton.k)
        return PathState(
            phase=jnp.where(p < 3, phase, 3),
            arc=s1,
            y=y,
            lam=lam,
            code=RESULTS.where(cont & ~stopped, st.code, code),
            iterations=st.iterations + counted,
        )

    init = PathState(
        phase=jnp.asarray(phase),
        arc=arc_start(y_und, options),
        y=y_start,
        lam=one,
        code=RESULTS.successful,
        iterations=jnp.asarray(0),
    )
    return lax.while_loop(lambda st: st.phase < 3, body, init)
