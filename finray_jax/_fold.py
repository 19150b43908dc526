"""The limit (fold) load factor as a differentiable function of the design.

`limit_load` traces the loading branch by arc-length continuation and stops within a small
arc step of the fold; neither its stopping point nor its load factor is a smooth function
of the design. Here that point is refined to the fold itself and the load factor gets
tangents from the fold's implicit function theorem.

At a fold the residual R(y, lam; theta) = 0 holds and J = dR/dy is singular, with left
and right null vectors w and v. Differentiating R = 0 along a design change,
J dy + R_lam dlam + R_theta dtheta = 0; multiplied by w (w J = 0):

    dlam* / dtheta = -(w . R_theta) / (w . R_lam)

which needs no derivative of y*. (w . R_lam != 0 is the condition for a simple fold.)

Refinement: with v fixed (the near-null right singular vector at the starting point) the
branch near the fold is parametrised by eta = v . (y - y0): R(y, lam) = 0,
v . (y - y0) = eta is regular there (bordered Jacobian [[J, R_lam], [v, 0]]). On it
lam(eta) has its maximum at the fold, where dlam/deta (from the same bordered matrix)
vanishes; eta* is found by the secant method on dlam/deta, which is nearly linear in eta.
The error of lam* is quadratic in that of eta*, so a few secant steps give lam* to
rounding. Everything uses first derivatives of the residual only.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax

from . import _solve
from ._finger import Finger
from ._integrator import Integrator
from ._solution import RESULTS, Solution
from ._solve import LimitLoad, SolverOptions

__all__ = ["Fold", "FoldOptions", "fold_point", "limit_load_factor"]


class FoldOptions(eqx.Module):
    """Numerical choices of the fold refinement (all static).

    max_secant_steps: secant iterations on dlam/deta.
    max_newton_steps: Newton iterations of each corrector (R = 0 at fixed eta).
    first_step: the secant's first step in eta (scaled unknowns, which are of order 1).
    step_tol: a corrector has converged when its Newton step (scaled, max norm) is below
        this, or when the step stops shrinking (rounding) below stall_tol; the secant has
        converged when its step in eta is below step_tol, or when that step is below
        stall_tol and dlam/deta is below slope_tol (zero to rounding: the secant's steps
        are then noise).
    slope_tol: see step_tol. On ref-A L3 with the back clamp at 8 mm, refined folds have
        |dlam/deta| of 1e-17 to 7e-16, and rounding can keep the secant stepping at that
        level without its step in eta falling below step_tol.
    residual_tol: the refined fold is accepted when its largest scaled residual is below.
    """

    max_secant_steps: int = eqx.field(static=True, default=20)
    max_newton_steps: int = eqx.field(static=True, default=12)
    first_step: float = eqx.field(static=True, default=1e-3)
    step_tol: float = eqx.field(static=True, default=1e-11)
    stall_tol: float = eqx.field(static=True, default=1e-9)
    slope_tol: float = eqx.field(static=True, default=1e-14)
    residual_tol: float = eqx.field(static=True, default=1e-10)

    def __check_init__(self):
        for name in ("first_step", "step_tol", "stall_tol", "slope_tol", "residual_tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"FoldOptions.{name} must be a positive number, got {v!r}")
        for name in ("max_secant_steps", "max_newton_steps"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"FoldOptions.{name} must be a positive integer, got {v!r}")


class Fold(eqx.Module):
    """The fold of a finger's loading branch.

    load_factor: lam* (differentiable with respect to the finger's design values).
    unknowns: the scaled unknowns y* there (as `Solution.unknowns`; no tangents).
    left_null, right_null: unit w and v with w J ~ 0, J v ~ 0 at the fold.
    singular_ratio: smallest over largest singular value of J at the fold (~0).
    dlam_deta: dlam/deta at the returned point (0 at the exact fold).
    max_residual: largest scaled residual there.
    converged: the continuation found a fold (when not warm started), every corrector
        converged, the secant converged and the residual is below residual_tol.
    iterations: Newton iterations of the refinement.
    """

    load_factor: jax.Array
    unknowns: jax.Array
    left_null: jax.Array
    right_null: jax.Array
    singular_ratio: jax.Array
    dlam_deta: jax.Array
    max_residual: jax.Array
    converged: jax.Array
    iterations: jax.Array


# --------------------------------------------------------------------------------------
# Refinement (no tangents: the problem is built from a stop_gradient'ed finger)
# --------------------------------------------------------------------------------------


def _jacobians(problem, y, lam):
    """J = dR/dy, R_lam = dR/dlam and R at (y, lam)."""

    def fn(a, b):
        r = _solve.natural_residual(a, (problem, b))
        return r, r

    (J, Jl), r = jax.jacfwd(fn, argnums=(0, 1), has_aux=True)(y, lam)
    return J, Jl, r


def _bordered(J, Jl, v):
    top = jnp.concatenate([J, Jl[:, None]], axis=1)
    bottom = jnp.concatenate([v, jnp.zeros(1)])[None]
    return jnp.concatenate([top, bottom], axis=0)


class _Corr(eqx.Module):
    y: jax.Array
    lam: jax.Array
    t: jax.Array  # (dy/deta, dlam/deta), from the Jacobian of the last iteration
    J: jax.Array
    rlam: jax.Array
    step: jax.Array
    k: jax.Array
    stalled: jax.Array  # the step stopped shrinking at rounding level


def _corrector(problem, y0, v, y, lam, eta, opts: FoldOptions):
    """Newton on R(y, lam) = 0, v . (y - y0) = eta from (y, lam).

    Each iteration factors the bordered Jacobian once and solves for both the Newton step
    and the branch tangent (dy/deta, dlam/deta); at convergence the tangent is that of a
    point within step_tol of the returned one."""

    def body(c: _Corr):
        J, Jl, r = _jacobians(problem, c.y, c.lam)
        g = jnp.dot(v, c.y - y0) - eta
        rhs = jnp.stack(
            [jnp.concatenate([r, g[None]]), jnp.zeros(r.shape[0] + 1).at[-1].set(1.0)], axis=1
        )
        d = jnp.linalg.solve(_bordered(J, Jl, v), rhs)
        step = jnp.max(jnp.abs(d[:, 0]))
        step = jnp.where(jnp.isfinite(step), step, jnp.inf)
        # Near the fold the bordered system is less well conditioned and the Newton step
        # can stall at rounding level (~1e-12) above step_tol: stop there too.
        stalled = (step >= 0.5 * c.step) & (step < opts.stall_tol)
        return _Corr(c.y - d[:-1, 0], c.lam - d[-1, 0], d[:, 1], J, Jl, step, c.k + 1, stalled)

    n = y.shape[0]
    cond = lambda c: (c.step >= opts.step_tol) & ~c.stalled & (c.k < opts.max_newton_steps)
    init = _Corr(
        y, lam, jnp.zeros(n + 1), jnp.zeros((n, n)), jnp.zeros(n), jnp.asarray(jnp.inf),
        jnp.asarray(0), jnp.asarray(False),
    )  # fmt: skip
    c = lax.while_loop(cond, body, init)
    return c, (c.step < opts.step_tol) | c.stalled


class _Secant(eqx.Module):
    c: _Corr  # the last corrected point
    eta: jax.Array
    eta_prev: jax.Array
    phi_prev: jax.Array
    ok: jax.Array
    k: jax.Array
    iterations: jax.Array
    step: jax.Array  # |eta - eta_prev|


def _refine(problem, y0, lam0, opts: FoldOptions):
    """Refine (y0, lam0), a point on the branch near its fold, to the fold.

    Secant iteration k = 0 corrects the start at eta = 0, k = 1 steps first_step toward
    increasing lam, later ones are secant steps on phi = dlam/deta."""
    J, _, _ = _jacobians(problem, y0, lam0)
    v = jnp.linalg.svd(J)[2][-1]

    def body(s: _Secant):
        phi = s.c.t[-1]
        slope = (phi - s.phi_prev) / jnp.where(s.eta == s.eta_prev, 1.0, s.eta - s.eta_prev)
        secant = s.eta - phi / jnp.where(slope == 0.0, 1.0, slope)
        first = jnp.where(phi >= 0.0, 1.0, -1.0) * opts.first_step
        eta = jnp.where(s.k == 0, 0.0, jnp.where(s.k == 1, first, secant))
        de = eta - s.eta
        c, ok = _corrector(problem, y0, v, s.c.y + de * s.c.t[:-1], s.c.lam + de * phi, eta, opts)
        return _Secant(
            c, eta, s.eta, phi, s.ok & ok, s.k + 1, s.iterations + c.k,
            jnp.where(s.k < 2, jnp.inf, jnp.abs(de)),
        )  # fmt: skip

    def settled(s: _Secant):
        flat = (s.step < opts.stall_tol) & (jnp.abs(s.c.t[-1]) < opts.slope_tol)
        return (s.step < opts.step_tol) | flat

    def cond(s: _Secant):
        return (s.k < opts.max_secant_steps) & ~settled(s) & s.ok

    n, zero = y0.shape[0], jnp.zeros(())
    c0 = _Corr(
        y0, lam0, jnp.zeros(n + 1), J, jnp.zeros(n), jnp.asarray(jnp.inf), jnp.asarray(0),
        jnp.asarray(False),
    )  # fmt: skip
    init = _Secant(
        c0, zero, zero, zero, jnp.asarray(True), jnp.asarray(0), jnp.asarray(0),
        jnp.asarray(jnp.inf),
    )  # fmt: skip
    s = lax.while_loop(cond, body, init)
    r = _solve.natural_residual(s.c.y, (problem, s.c.lam))
    U, sv, Vh = jnp.linalg.svd(s.c.J)
    max_res = jnp.max(jnp.abs(r))
    converged = s.ok & settled(s) & (max_res < opts.residual_tol)
    fold = Fold(
        load_factor=s.c.lam,
        unknowns=s.c.y,
        left_null=U[:, -1],
        right_null=Vh[-1],
        singular_ratio=sv[-1] / sv[0],
        dlam_deta=s.c.t[-1],
        max_residual=max_res,
        converged=converged,
        iterations=s.iterations,
    )
    return fold, s.c.rlam


# --------------------------------------------------------------------------------------
# Tangents of the fold load factor
# --------------------------------------------------------------------------------------


def _residual_of(topo, integrator, finger, y, lam):
    return _solve.natural_residual(y, (_solve.make_problem(topo, integrator, finger), lam))


@eqx.filter_custom_jvp
def _attach(finger, y, lam, w, w_rlam, *, topo, integrator):
    """lam, with tangents -(w . R_theta dtheta) / (w . R_lam) along the finger's tangent."""
    del finger, y, w, w_rlam, topo, integrator
    return lam


@_attach.def_jvp
def _attach_jvp(primals, tangents, *, topo, integrator):
    finger, y, lam, w, w_rlam = primals
    t_finger = tangents[0]
    if t_finger is None:
        return lam, None
    # Symbolic zeros (None) of undifferentiated leaves become zeros.
    t_finger = jax.tree_util.tree_map(
        lambda t, p: jnp.zeros_like(p) if t is None and eqx.is_inexact_array(p) else t,
        t_finger,
        finger,
        is_leaf=lambda x: x is None,
    )
    _, r_dot = eqx.filter_jvp(
        lambda f: _residual_of(topo, integrator, f, y, lam), (finger,), (t_finger,)
    )
    return lam, -jnp.dot(w, r_dot) / w_rlam


@eqx.filter_jit
def _fold_core(topo, integrator, options, fold_options, finger: Finger, y0, lam0):
    problem = _solve.nograd(_solve.make_problem(topo, integrator, finger))
    found = jnp.asarray(True)
    if y0 is None:
        lam0, sol = _solve.limit_core(topo, integrator, options, finger)
        y0, found = sol.unknowns, sol.result == RESULTS.successful
        lam0, y0 = lax.stop_gradient(lam0), lax.stop_gradient(y0)
    fold, rlam = _refine(problem, y0, lam0, fold_options)
    fold = eqx.tree_at(lambda f: f.converged, fold, fold.converged & found)
    w = fold.left_null
    lam = _attach(
        finger,
        fold.unknowns,
        fold.load_factor,
        w,
        jnp.dot(w, rlam),
        topo=topo,
        integrator=integrator,
    )
    return eqx.tree_at(lambda f: f.load_factor, fold, lam)


def _start(init):
    if init is None:
        return None, None
    if isinstance(init, LimitLoad):
        init = init.solution
    if isinstance(init, (Fold, Solution)):
        return lax.stop_gradient(init.unknowns), lax.stop_gradient(init.load_factor)
    raise TypeError(f"init must be a LimitLoad, Fold or Solution, got {type(init).__name__}")


def fold_point(
    finger: Finger,
    *,
    init: LimitLoad | Fold | Solution | None = None,
    mode: str = "auto",
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    fold_options: FoldOptions = FoldOptions(),
    topology=None,
) -> Fold:
    """The fold of the finger's loading branch, refined to rounding, with a load factor
    that `jax.grad` and `jax.jacfwd` differentiate with respect to the design.

    init: a nearby point on the branch close to its fold, e.g. the `limit_load` (or
        `fold_point`) result of the same or a slightly different design of the same
        topology; the continuation is then skipped. None: `limit_load`'s continuation
        finds the fold first.
    """
    topo = _solve.prepare(finger, mode, topology)
    y0, lam0 = _start(init)
    return _fold_core(topo, integrator, options, fold_options, finger, y0, lam0)


def limit_load_factor(
    finger: Finger,
    *,
    init: LimitLoad | Fold | Solution | None = None,
    mode: str = "auto",
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    fold_options: FoldOptions = FoldOptions(),
    topology=None,
    throw: bool = True,
) -> jax.Array:
    """The limit (fold) load factor lam* on the finger's loads, differentiable with respect
    to every design value (see `fold_point`). throw: raise when the fold was not found or
    not refined; otherwise the factor is NaN then."""
    fold = fold_point(
        finger,
        init=init,
        mode=mode,
        integrator=integrator,
        options=options,
        fold_options=fold_options,
        topology=topology,
    )
    lam = jnp.where(fold.converged, fold.load_factor, jnp.nan)
    if throw:
        lam = eqx.error_if(
            lam,
            ~fold.converged,
            "limit_load_factor: the fold was not found or not refined (the continuation "
            "failed, or the refinement's Newton did not converge: start it closer with "
            "init=, or raise FoldOptions.max_newton_steps / max_secant_steps)",
        )
    return lam
