"""Grasping: closing a finger on rigid objects, contact outputs and the holding force.

The finger stays where it is; closing the gripper by d moves every object by -d w
relative to the finger (w: the closing direction, the unit vector in which the finger's
base moves, default -x: from the back beam toward the front beam). Each equilibrium is a
Newton solve of the full contact problem (`solve_finger` with objects), warm started from
the previous one; the closing displacement is stepped, and a step that fails is halved.
With a two-finger parallel grasp (`symmetric=True`) the second finger is the mirror image
of the first about the object's plane of symmetry, so only one finger is solved and the
holding force is twice that finger's.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._assembly import build_topology
from ._contact import (
    check_friction,
    member_penetration_limit,
    member_smoothing,
    member_stiffness,
    penalty,
    smoothing,
    stiffness,
    support_penetration_limit,
    support_smoothing,
    support_stiffness,
    with_friction,
)
from ._finger import BACK, FRONT, DistributedLoad, Finger, FingerError, validate_finger
from ._geometry import geometry, main_beam_samples, thickness_at
from ._members import group_forces
from ._objects import HalfPlane, safe_norm
from ._rod import Integrator
from ._solution import RESULTS, Solution
from ._solve import (
    SolverOptions,
    direct_core,
    make_problem,
    prepare,
    resolve_mode,
    topology_of,
    undeformed_unknowns,
)
from ._stability import CriticalPoint, Stability, stability_of, stable_neighbours
from ._types import as_float, check_x64

GRASP_STEPS = 16  # default integration steps per segment for contact problems
MAX_STIFFENING = 16.0  # the largest factor on a penalty stiffness in one round


class ContactResult(eqx.Module):
    """Contact outputs of one equilibrium (one finger).

    force: total force (x, y, z) the objects exert on the finger (N).
    normal_force: integral of the normal contact pressure over the beams (N).
    pressure_front, pressure_back: normal contact force per unit length (N/mm) at the
        points of the front and back beams' solutions (`Solution.front.s`, `.back.s`).
    contact_length: arc length in contact (penetration > 0), both beams (mm).
    max_penetration: largest penetration of a beam's surface into an object (mm).
    support_penetration: largest penetration of the back beam into the support (mm).
    support_force: total force of the adaptor's support on the back beam (N).
    crossbeam_force: mean force the crossbeams apply to the front beam (x, y, z) (N): the
        paper's Fig. 4 metric.
    actuator_force: force along the closing direction the actuator applies to the
        finger's adaptor (N): everything the adaptor applies to the finger (base reactions
        and the support) projected on the closing direction.
    member_penetration: largest penetration of one member of the finger into another
        (mm; 0 where member contact is off, `Contact.member_contact`).
    member_force: (members, members) the contact force member j presses on member i
        with (N; members are front, back, then the crossbeams); internal, so it is in no
        balance of the finger as a whole.
    """

    force: jax.Array
    normal_force: jax.Array
    pressure_front: jax.Array
    pressure_back: jax.Array
    contact_length: jax.Array
    max_penetration: jax.Array
    support_penetration: jax.Array
    support_force: jax.Array
    crossbeam_force: jax.Array
    actuator_force: jax.Array
    member_penetration: jax.Array = eqx.field(converter=as_float, default=0.0)
    member_force: jax.Array = eqx.field(converter=as_float, default=((0.0,),))


@functools.partial(jax.jit, static_argnums=(0, 1))
def _member_outputs(topo, integrator, finger, Y, lam):
    """(largest penetration, (B, B) contact forces) between the finger's members."""
    problem = make_problem(topo, integrator, finger)
    starts, ends = problem.ends(jnp.reshape(Y, (topo.n_segments, -1)), lam)
    plan = topo.members
    size, gap = group_forces(plan, *problem.member_args(starts, ends))
    pen = jnp.max(jnp.maximum(-gap, 0.0), initial=0.0)
    a, b = plan.group_members[:, 0], plan.group_members[:, 1]
    B = topo.n_beams
    # every group's force acts on its sample's member (a) and back on the other (b)
    forces = jnp.zeros((B, B)).at[a, b].add(size).at[b, a].add(size)
    return pen, 0.5 * forces


def with_members(res: ContactResult, topo, integrator, finger, sol) -> ContactResult:
    """The contact result with the members' contact filled in (from the topology)."""
    if topo.members is None or not topo.members.n_groups:
        return res
    pen, forces = _member_outputs(topo, integrator, finger, sol.unknowns, sol.load_factor)
    return dataclasses.replace(res, member_penetration=pen, member_force=forces)


def _blocks(x, steps):
    return x.reshape((-1, steps + 2) + x.shape[1:])


@eqx.filter_jit
def contact_result(finger: Finger, sol: Solution, direction) -> ContactResult:
    """Contact outputs of a solved finger (objects, support, crossbeams, reactions).

    Totals are exact for the discrete model: on every segment the contact force is the
    change of the internal force n that the distributed loads do not explain (n' = -f).
    Sampled pressures at the solution points split it between objects and support and
    give the normal force.
    """
    geo = geometry(finger)
    c = finger.contact
    k, delta = stiffness(finger), smoothing(finger)
    k_s, delta_s = support_stiffness(finger), support_smoothing(finger)
    clamp = (finger.adaptor.front_clamp_length, finger.adaptor.back_clamp_length)
    force = jnp.zeros(3)
    support = jnp.zeros(3)
    normal = jnp.zeros(())
    length = jnp.zeros(())
    pen = jnp.zeros(())
    sup_pen = jnp.zeros(())
    pressures = []
    w = jnp.insert(as_float(direction), 1, 0.0)
    for beam, bs in ((FRONT, sol.front), (BACK, sol.back)):
        p = bs.position[:, ::2]
        h = 0.5 * thickness_at(
            finger.front if beam == FRONT else finger.back, bs.s, geo.length[beam]
        )
        free = bs.s > clamp[beam]  # no contact inside a clamp
        q_obj = jnp.zeros_like(bs.s)  # normal pressure from objects
        f_obj = jnp.zeros((bs.s.shape[0], 2))  # force per length from objects
        for obj in finger.objects:
            q = obj.params()
            d, nx, nz = jax.vmap(obj.distance_and_normal, in_axes=(None, 0, 0))(q, p[:, 0], p[:, 1])
            grad = jnp.stack([nx, nz], axis=-1)
            gap = d - h
            qn = jnp.where(free, penalty(gap, k, delta), 0.0)
            t = bs.frame[:, ::2, 2]
            slide = c.friction * jnp.tanh((t @ c.slip_direction) / c.friction_regularisation)
            f_obj = f_obj + qn[:, None] * (grad + slide[:, None] * t)
            q_obj = q_obj + qn
            pen = jnp.maximum(pen, jnp.max(jnp.where(free, -gap, 0.0)))
            length = length + _length_inside(jnp.where(free, gap, 1.0), bs.s)
        f_sup = jnp.zeros_like(f_obj)
        backed = jnp.zeros(bs.s.shape[0] // (sol.steps + 2), bool)  # segments the support backs
        if beam == BACK and finger.adaptor.support_length is not None:
            th = geo.theta[BACK]
            nrm = -jnp.stack([jnp.cos(th), -jnp.sin(th)])
            gap = (p - geo.base[BACK, ::2]) @ nrm
            # The support acts on whole segments (those that end at or before l_s), so its
            # force at s = l_s, where a stiff penalty concentrates it, belongs to it too.
            ends = _blocks(bs.s, sol.steps)[:, -1]
            backed = ends <= finger.adaptor.support_length * (1.0 + 1e-12)
            on = free & jnp.repeat(backed, sol.steps + 2)
            f_sup = jnp.where(on, penalty(gap, k_s, delta_s), 0.0)[:, None] * nrm[None]
            sup_pen = jnp.max(jnp.where(on, -gap, 0.0))
        # Per segment: sampled integrals, and the exact total from the jump of n.
        s_b = _blocks(bs.s, sol.steps)
        n_b = _blocks(bs.force[:, ::2], sol.steps)
        dist = _distributed(finger, beam, s_b[:, 0], s_b[:, -1])
        exact = -(n_b[:, -1] - n_b[:, 0]) - dist
        so, ss, qo = (_blocks_integral(x, s_b, sol.steps) for x in (f_obj, f_sup, q_obj[:, None]))
        sampled = so + ss
        # (the floor keeps tiny a normal number, and the division never sees 0 / 0 even
        # in the unselected branch, so reverse-mode gradients stay finite)
        tiny = 1e-24 * jnp.maximum(jnp.sum(exact * exact, axis=1), 1e-280)
        size = jnp.sum(sampled * sampled, axis=1)
        has_o = jnp.sum(so * so, axis=1) > tiny
        has_s = jnp.sum(ss * ss, axis=1) > tiny
        some = size > tiny
        scale = jnp.where(some, jnp.sum(exact * sampled, axis=1) / jnp.where(some, size, 1.0), 1.0)
        # All of the segment's contact force goes to what touches it; if both do, split
        # by the sampled shares. A contact too concentrated for the solution's points
        # (a stiff support's edge force acts between them) is the support's on the
        # segments it backs where no object is seen.
        to_objects = ~has_s & (has_o | ~backed)
        obj_part = jnp.where(
            to_objects[:, None],
            exact,
            jnp.where((has_o & has_s)[:, None], scale[:, None] * so, 0.0),
        )
        force = force + jnp.insert(jnp.sum(obj_part, axis=0), 1, 0.0)
        support = support + jnp.insert(jnp.sum(exact - obj_part, axis=0), 1, 0.0)
        q_exact = jnp.where(has_o & some, scale * qo[:, 0], safe_norm(obj_part))
        normal = normal + jnp.sum(q_exact)
        pressures.append(q_obj)
    reactions = sol.reactions_front.force + sol.reactions_back.force + support
    cb = sol.crossbeam_wrenches.front_force
    return ContactResult(
        force=force,
        normal_force=normal,
        pressure_front=pressures[0],
        pressure_back=pressures[1],
        contact_length=length,
        max_penetration=pen,
        support_penetration=sup_pen,
        support_force=support,
        crossbeam_force=jnp.mean(cb, axis=0) if cb.shape[0] else jnp.zeros(3),
        actuator_force=jnp.dot(reactions, w),
    )


def _length_inside(gap, s):
    """Arc length where gap < 0, with zero crossings interpolated linearly."""
    g0, g1 = gap[:-1], gap[1:]
    ds = s[1:] - s[:-1]
    both = (g0 < 0) & (g1 < 0)
    one = (g0 < 0) != (g1 < 0)
    span = jnp.where(one, jnp.abs(g0 - g1), 1.0)
    frac = jnp.where(one, -jnp.minimum(g0, g1) / span, 0.0)
    return jnp.sum(jnp.where(both, ds, frac * ds))


def _blocks_integral(x, s_b, steps):
    """Trapezoid integral of x over every segment block: (segments, columns)."""
    x_b = _blocks(x, steps)
    ds = (s_b[:, 1:] - s_b[:, :-1])[..., None]
    return jnp.sum(0.5 * (x_b[:, 1:] + x_b[:, :-1]) * ds, axis=1)


def _distributed(finger: Finger, beam: int, s0, s1):
    """Resultant (x, z) of the distributed loads on each segment [s0, s1] of a beam."""
    total = jnp.zeros((s0.shape[0], 2))
    for ld in finger.loads:
        if isinstance(ld, DistributedLoad) and ld.beam == beam:
            a, b = ld.s_range[0], ld.s_range[1]
            overlap = jnp.clip(jnp.minimum(s1, b) - jnp.maximum(s0, a), 0.0, None)
            total = total + overlap[:, None] * ld.force_per_length[::2][None]
    return total


class GraspSolution(eqx.Module):
    """A grasp: the finger's equilibrium at a closing displacement, and its contact.

    closing: the closing displacement d (mm); finger: the finger with its objects where
    they are relative to it at that closing; stiffness, support_stiffness: the objects'
    and the support's penalty stiffness used (after any automatic stiffening; the finger
    holds both); holding_factor: 2 for a symmetric two-finger grasp, else 1.
    stability: whether the equilibrium is stable (`Stability`; None when not tested).
    critical_points: where the closing path (or a stiffening or friction path on the way)
        lost stability and how it went on (`CriticalPoint`).
    """

    solution: Solution
    contact: ContactResult
    finger: Finger
    closing: jax.Array
    stiffness: jax.Array
    support_stiffness: jax.Array
    steps: int = eqx.field(static=True)
    holding_factor: int = eqx.field(static=True, default=2)
    topology: object = eqx.field(static=True, default=None)
    direction: tuple = eqx.field(static=True, default=(-1.0, 0.0))
    integrator: Integrator = Integrator(steps=GRASP_STEPS)
    stability: Stability | None = eqx.field(static=True, default=None)
    critical_points: tuple[CriticalPoint, ...] = eqx.field(static=True, default=())

    @property
    def status(self) -> str:
        return self.solution.status

    @property
    def converged(self) -> bool:
        return bool(self.solution.result == RESULTS.successful)

    @property
    def member_stiffness(self):
        """The members' penalty stiffness used (N/mm^2)."""
        return member_stiffness(self.finger)

    def penetration_warnings(self) -> list[str]:
        """A line for each penetration limit the grasp exceeds (none when both hold).

        `grasp` stiffens a penalty until its limit holds, unless a stiffer penalty stops
        converging: a contact pressed along a long stretch of a shooting segment makes
        the segment's solution grow like exp(L (k / 4 EI)^(1/4)), and past a point Newton
        cannot follow it. A shorter `Contact.segment_length` moves that point;
        `rigid_contact_estimate` tells how far the answer is from rigid contact."""
        c, f = self.contact, self.finger
        out = []
        checks = [
            (
                "an object",
                c.max_penetration,
                f.contact.max_penetration * f.front.thickness,
                "contact.max_penetration",
                self.stiffness,
            ),
        ]
        if f.adaptor.support_length is not None:
            checks.append(
                (
                    "the support",
                    c.support_penetration,
                    support_penetration_limit(f),
                    "contact.max_support_penetration",
                    self.support_stiffness,
                )
            )
        if self.topology is not None and self.topology.members is not None:
            checks.append(
                (
                    "another member",
                    c.member_penetration,
                    member_penetration_limit(f),
                    "contact.max_member_penetration",
                    self.member_stiffness,
                )
            )
        for what, pen, limit, key, k in checks:
            if float(pen) > float(limit) * (1.0 + 1e-9):
                out.append(
                    f"the penetration into {what}, {float(pen):.3g} mm, exceeds its limit "
                    f"{float(limit):.3g} mm ({key}) at penalty stiffness {float(k):.4g} "
                    f"N/mm^2: a stiffer one did not converge on "
                    f"{f.contact.segment_length:g} mm shooting segments "
                    "(contact.segment_length)"
                )
        return out


def stability(result, finger=None, *, integrator=None, topology=None) -> Stability:
    """The stability of a computed equilibrium (eager; planar fingers).

    result: a `GraspSolution` (its own finger, segment table and integrator), or a
        `Solution` or `Fold` of `finger` (pass the integrator and topology it was solved
        with, when not the defaults).
    """
    if isinstance(result, GraspSolution):
        finger, topology, integrator = result.finger, result.topology, result.integrator
        result = result.solution
    if finger is None:
        raise FingerError("stability(solution, finger): pass the finger it was solved for")
    if topology is None:
        topology = topology_of(finger, getattr(result, "mode", "planar"))
    if integrator is None:
        steps = getattr(result, "steps", 0)
        integrator = Integrator(steps=steps) if steps else Integrator()
    return stability_of(topology, integrator, finger, result.unknowns, result.load_factor)


def with_objects_moved(finger: Finger, displacement) -> Finger:
    # (dataclasses.replace: half the cost of eqx.tree_at, which a path pays per step)
    objs = tuple(o.moved(displacement) for o in finger.objects)
    return dataclasses.replace(finger, objects=objs)


def with_contact(finger: Finger, **values) -> Finger:
    """The finger with the given fields of its Contact replaced (as float arrays)."""
    c = finger.contact
    for key, v in values.items():
        c = eqx.tree_at(
            lambda c, key=key: getattr(c, key), c, as_float(v), is_leaf=lambda x: x is None
        )
    return eqx.tree_at(lambda f: f.contact, finger, c)


def with_stiffness(finger: Finger, k, k_support=None, k_members=None) -> Finger:
    """The finger with the objects' penalty stiffness k, the support's and the members'
    (default: the ones it has)."""
    values = {"stiffness": k, "support_stiffness": k_support, "member_stiffness": k_members}
    return with_contact(finger, **{key: v for key, v in values.items() if v is not None})


def unit_direction(direction, name):
    w = np.asarray(direction, dtype=np.float64)
    if w.shape != (2,) or not np.all(np.isfinite(w)) or np.linalg.norm(w) == 0:
        raise FingerError(f"{name} must be a non-zero (x, z) direction, got {w.tolist()}")
    return w / np.linalg.norm(w)


def _shape_key(topo):
    """What two segment tables must share to describe the same finger (the cuts may
    differ: they follow the design values, and so may the count of near segments, which
    follows the supported ones)."""
    contact = topo.contact and dataclasses.replace(topo.contact, friction=True, near=None)
    return (topo.mode, topo.base_kinds, topo.n_crossbeams, topo.tapered, contact)


MAX_CRITICAL = 8  # critical points a stepper goes past (each costs up to 12 solves)


class Stepper:
    """Warm-started equilibria along a path of object displacements, with step halving.

    validate: check the finger (False when the caller has checked it, or for a finger
    whose objects were moved into contact by a previous grasp: its start no longer has the
    objects clear of the beams)."""

    def __init__(self, finger, mode, integrator, options, validate=True, topology=None):
        self.finger = finger
        if validate:
            self.topo = prepare(finger, mode)
        else:
            check_x64("finray_jax")
            self.topo = build_topology(finger, resolve_mode(finger, mode))
        if topology is not None:
            if _shape_key(topology) != _shape_key(self.topo):
                raise FingerError(
                    "topology= is the segment table of a different finger (other beams, "
                    "crossbeams, objects or mode): pass the .topology of a grasp of this finger"
                )
            # (the given one may have been built without friction, and this finger have it)
            own = self.topo.contact
            self.topo = with_friction(topology) if own and own.friction else topology
        self.integrator = integrator
        self.options = options
        self.calls = 0
        # The sign of det J at the accepted equilibria (0: none yet). Every point of a
        # path shares it; a solve that lands on the other sign has crossed a fold or
        # jumped to another branch, and is rejected (whatever the sign where Newton
        # started, off the path).
        self.sign = 0.0
        self.prev = None  # (t, unknowns) of the point before the last one `follow` accepted
        self.failure = RESULTS.nonlinear_divergence  # the result of the last failed solve
        self.critical = []  # CriticalPoints the paths passed
        self.direction = None  # the objects' closing direction, to report normal forces

    def solve(self, finger, init):
        self.calls += 1
        warm = init is not None
        ref = np.float64(self.sign if warm else 0.0)
        if not warm:  # (an array either way: one compiled program for both)
            init = undeformed_unknowns(self.topo, finger)
        solve = lambda: direct_core(self.topo, self.integrator, self.options, finger, init, ref)
        sol, ok, sign = solve()
        ok = bool(ok)
        if not ok and bool(sol.result == RESULTS.contact_outside_near_segments):
            # The contact spans more segments than the near ones (a flat face pressed on a
            # straight beam touches it all along at once): from here on, every segment.
            contact = dataclasses.replace(self.topo.contact, near=None)
            self.topo = dataclasses.replace(self.topo, contact=contact)
            self.calls += 1
            sol, ok, sign = solve()
            ok = bool(ok)
        if not ok and warm:
            sol, ok, sign = self._through_softer_support(finger, init, ref, (sol, ok, sign))
        if ok:
            self.sign = float(sign)
        else:
            self.failure = sol.result
        return sol, ok

    def stability(self, finger, sol):
        return stability_of(self.topo, self.integrator, finger, sol.unknowns)

    def stable_next_to(self, t_last, sol_last, t, finger, seed, stab):
        """Go on past a critical point: the stable equilibria of `finger` (at path
        parameter t) that Newton reaches from the equilibrium `seed` displaced along its
        softest mode (`stab`: the seed's Stability), the one nearest the last stable point
        `sol_last` (at t_last) first. Records a CriticalPoint; returns the
        [(solution, Stability)] found. (Each is accepted with the path's sign of det J,
        which the stepper keeps.)"""
        found = stable_neighbours(
            lambda guess: self.solve(finger, guess),
            lambda s: self.stability(finger, s),
            seed.unknowns,
            stab,
        )
        last = np.asarray(sol_last.unknowns)
        found.sort(key=lambda e: float(np.max(np.abs(np.asarray(e[0].unknowns) - last))))
        forces = tuple(self.normal_force(finger, s) for s, _ in found)
        self.critical.append(CriticalPoint((t_last, t), stab.min_eigenvalue, bool(found), forces))
        return found

    def past_critical(self, at, t, sol, rejected, t_next):
        """The path's branch could not be followed past t (its last equilibrium `sol`).
        When that is a critical point, the stable equilibria just past it: from the
        unstable equilibrium a solve found there (`rejected`: (t_r, solution), rejected
        for its sign of det J), or at a fold (the smallest eigenvalue at `sol` near 0,
        under 5 % of the next) from `sol` itself, at t_next. Returns (found, where) or
        None when it is not a critical point."""
        if self.topo.mode != "planar" or sol is None:
            return None
        if rejected is not None:
            t_r, unstable = rejected
            stab = self.stability(at(t_r), unstable)
            if stab.stable:
                return None
            return self.stable_next_to(t, sol, t_r, at(t_r), unstable, stab), t_r
        stab = self.stability(at(t), sol)
        values = stab.eigenvalues
        if values.size < 2 or not values[0] < 0.05 * values[1]:
            return None
        return self.stable_next_to(t, sol, t_next, at(t_next), sol, stab), t_next

    def normal_force(self, finger, sol):
        if self.direction is None:
            return float("nan")
        return float(contact_result(finger, sol, self.direction).normal_force)

    def _through_softer_support(self, finger, init, ref, failed):
        """A support much stiffer than the objects has a narrow basin of convergence where
        the back beam barely touches it (the penalty's smoothed onset, whose slope rises
        from 0 to k_s within support_smoothing): Newton from a neighbouring equilibrium can
        overshoot it. The same equilibrium is then reached through a ladder of softer
        supports, each solve started from the one before (the penalty enters the compiled
        program as data: no recompilation). The result is that of the finger's own
        stiffness; `failed` is returned when a rung fails."""
        k, k_s = float(stiffness(finger)), float(support_stiffness(finger))
        if not k_s > 4.0 * k:
            return failed
        rungs = int(np.ceil(np.log(k_s / k) / np.log(4.0)))
        guess = init
        for k_rung in [*(k * 4.0 ** np.arange(rungs)), k_s]:
            self.calls += 1
            soft = with_stiffness(finger, k, float(k_rung))
            sol, ok, sign = direct_core(self.topo, self.integrator, self.options, soft, guess, ref)
            if not bool(ok):
                return failed
            guess = sol.unknowns
        return sol, ok, sign

    def follow(self, at, t0, t1, init, first_step, min_step, prev=None, max_step=np.inf, stop=None):
        """Equilibria from parameter t0 to t1 (finger = at(t)), each started from a linear
        extrapolation of the last two; returns (t, solution, ok) of the last accepted
        point. Steps grow after easy solves (up to max_step) and halve after failures.

        prev: (t, unknowns) of the path's point before `init` (continuing a path that an
        earlier call followed: its `self.prev`), so the first step is extrapolated too.
        stop: called as stop(t, solution) at every accepted point; the path ends there
        (ok) when it returns True."""
        t, sol, h = t0, init, min(first_step, max_step)
        rejected = None  # (t, equilibrium) of the nearest solve rejected for det J's sign
        while t < t1 - 1e-12:
            t_try = min(t + h, t1)
            guess = None if sol is None else sol.unknowns
            if prev is not None and guess is not None:
                guess = guess + (guess - prev[1]) * ((t_try - t) / (t - prev[0]))
            trial, ok = self.solve(at(t_try), guess)
            if ok:
                if sol is not None:
                    prev = (t, sol.unknowns)
                h = min(_growth(int(trial.iterations)) * h, t1 - t0, max_step)
                t, sol, rejected = t_try, trial, None
                if stop is not None and stop(t, sol):
                    break
            else:
                if bool(trial.result == RESULTS.branch_changed):
                    rejected = (t_try, trial)
                h = 0.5 * h
                if h < min_step:
                    # The branch ends (a fold) or loses stability (a bifurcation) within
                    # min_step: go on on a stable branch next to it, if there is one.
                    t_next = min(t + 2.0 * min_step, t1)
                    past = None
                    if len(self.critical) < MAX_CRITICAL:
                        past = self.past_critical(at, t, sol, rejected, t_next)
                    if past is None or not past[0]:
                        if past is not None:
                            self.failure = RESULTS.stability_lost
                        self.prev = prev
                        return t, sol, False
                    (found, t), prev, rejected = past, None, None
                    sol = found[0][0]
                    h = min(first_step, max_step, 64.0 * min_step)
        self.prev = prev
        return t, sol, True


def _growth(iterations: int) -> float:
    """Factor on the next path step after a solve that took `iterations` Newton
    iterations: grow after easy solves, shrink after hard ones (the next, equally long
    step would likely fail and cost a full max_newton_steps). On the Finger-1 grasps of
    benchmarks/grasp.py this cut the solves from 11 and 13 (1.5x after <= 6 iterations,
    else 1x) to 7 and 10, with no failed step."""
    if iterations <= 3:
        return 2.0
    if iterations <= 6:
        return 1.5
    return 1.0 if iterations <= 9 else 0.5


def check_objects(finger: Finger, w):
    """The finger is valid (this is the grasp's one validation); its objects lie ahead of
    its front side and within its span."""
    if not isinstance(finger, Finger):
        raise TypeError(f"expected a Finger, got {type(finger).__name__}")
    if not finger.objects:
        raise FingerError("grasp needs at least one object (Finger.objects is empty)")
    validate_finger(finger)
    pts = np.asarray(main_beam_samples(finger, 201)[1]).reshape(-1, 2)
    across = np.array([-w[1], w[0]])
    lo, hi = np.min(pts @ across), np.max(pts @ across)
    for i, obj in enumerate(finger.objects):
        if obj.kind == "half_plane":
            continue
        out = obj.outline(400)
        a, b = np.min(out @ across), np.max(out @ across)
        if b < lo or a > hi:
            raise FingerError(
                f"objects[{i}] ({obj.kind}) is outside the reach of the finger: it spans "
                f"[{a:.4g}, {b:.4g}] mm across the closing direction, the finger [{lo:.4g}, "
                f"{hi:.4g}] mm"
            )
        if np.max(out @ w) < np.min(pts @ w):
            raise FingerError(
                f"objects[{i}] ({obj.kind}) lies behind the finger: closing along "
                f"{w.tolist()} moves the finger away from it"
            )


def grasp(
    finger: Finger,
    closing=None,
    *,
    actuator_force=None,
    direction=(-1.0, 0.0),
    symmetric: bool = True,
    mode: str = "planar",
    integrator: Integrator = Integrator(steps=GRASP_STEPS),
    options: SolverOptions = SolverOptions(),
    stiffen: bool = True,
    topology=None,
    check_stability: bool = True,
) -> GraspSolution:
    """Close the finger on its objects and solve the contact equilibrium.

    closing: displacement (mm) of the finger's base toward the objects along `direction`;
        or actuator_force: the force (N) the actuator applies along `direction` (the
        closing displacement is then found on the closing path, by regula falsi on the
        step that passes the force).
    stiffen: when the largest penetration into an object exceeds `Contact.max_penetration`
        of the front beam's thickness, or the back beam's into the support exceeds its
        limit (`Contact.max_support_penetration`), raise that contact's penalty stiffness
        and solve again (warm started).
    topology: the segment table of an earlier grasp of the same finger (its `.topology`):
        the beams are cut at the same points whatever the design values, so the answer is
        on that grasp's discretisation and nothing recompiles. None: cut for this finger.
    check_stability: test the final equilibrium's stability (`GraspSolution.stability`,
        planar fingers); an unstable one is replaced by a stable equilibrium next to it
        when Newton finds one, else reported with the status "unstable". Along the path a
        solve past a fold or a bifurcation is tested whatever this says
        (`GraspSolution.critical_points`).
    """
    if (closing is None) == (actuator_force is None):
        raise FingerError("grasp needs exactly one of closing= and actuator_force=")
    w = unit_direction(direction, "direction")
    check_objects(finger, w)
    if closing is not None:
        d = float(np.asarray(closing))
        if not np.isfinite(d) or d < 0:
            raise FingerError(f"closing must be a non-negative displacement (mm), got {d}")
    else:
        fa = float(np.asarray(actuator_force))
        if not np.isfinite(fa) or fa < 0:
            raise FingerError(f"actuator_force must be a non-negative force (N), got {fa}")
    # (check_objects validated the finger)
    stepper = Stepper(finger, mode, integrator, options, validate=False, topology=topology)
    stepper.direction = w
    ks = [float(x(finger)) for x in (stiffness, support_stiffness, member_stiffness)]
    finger = with_stiffness(finger, *ks)

    def at(t):
        return with_objects_moved(finger, -t * w)

    def result(t, sol):
        res = contact_result(at(t), sol, w)
        return with_members(res, stepper.topo, integrator, at(t), sol)

    def penetrations(res):
        pens = (res.max_penetration, res.support_penetration, res.member_penetration)
        return [float(x) for x in pens]

    cap = _closing_step_cap(finger)
    limits = [
        float(finger.contact.max_penetration * finger.front.thickness),
        float(support_penetration_limit(finger)),
        float(member_penetration_limit(finger)),
    ]
    onsets = [0.5 * float(x(finger)) for x in (smoothing, support_smoothing, member_smoothing)]
    # penetration - onset ~ k^-order: 1 for a distributed contact, about 3/4 for the
    # support's edge and for members meeting at a point (re-estimated from every
    # stiffening)
    orders = [1.0, 0.75, 0.75]
    rounds, start = 0, None
    while True:
        if closing is not None:
            t, sol, ok = stepper.follow(at, 0.0, d, None, d / 8.0, 1e-4 * max(d, 1.0), max_step=cap)
        else:
            t, sol, ok = _find_closing(stepper, at, w, fa, cap, start)
        if sol is None:
            sol, _ = stepper.solve(at(0.0), None)
        res = result(t, sol)
        stiffened = False
        pens = penetrations(res)
        over = lambda pens: any(p > lim for p, lim in zip(pens, limits))
        while ok and stiffen and over(pens) and rounds < 8:
            # penetration = onset + c k^-order: scale each k so that the part above the
            # onset fits in what is left, stepping log k from the old to the new
            # stiffnesses (warm started).
            old = list(ks)
            new = [
                _stiffer(kk, p, lim, onset, order)
                for kk, p, lim, onset, order in zip(old, pens, limits, onsets, orders)
            ]
            stiffer = lambda u, k0=old, k1=new, t=t: with_stiffness(
                at(t), *(a * (b / a) ** u for a, b in zip(k0, k1))
            )
            u, sol, ok = stepper.follow(stiffer, 0.0, 1.0, sol, 1.0, 1e-3)
            if not ok and u > 0:  # part of the way: go on from there
                new, ok = [a * (b / a) ** u for a, b in zip(old, new)], True
            elif not ok:  # not a step: keep the last equilibrium (`penetration_warnings`)
                ok = True
                break
            if ok:
                ks = new
                finger = with_stiffness(finger, *ks)  # (at() closes over the new finger)
                res = result(t, sol)
                seen = penetrations(res)
                for i in range(3):
                    orders[i] = _observed_order(
                        old[i], new[i], pens[i], seen[i], onsets[i], orders[i]
                    )
                pens = seen
                stiffened = True
            rounds += 1
        # A stiffer contact changes the actuator force at that closing: find the closing
        # for the target force again (a prescribed closing stays what it was).
        if closing is not None or not (ok and stiffened):
            break
        start = (t, float(res.actuator_force), sol)  # (the secant starts from there)
    stab = None
    if ok and check_stability and stepper.topo.mode == "planar":
        stab = stepper.stability(at(t), sol)
        if not stab.stable:
            found = stepper.stable_next_to(t, sol, t, at(t), sol, stab)
            if found:
                sol, stab = found[0]
                res = result(t, sol)
            else:
                ok, stepper.failure = False, RESULTS.unstable_equilibrium
    if not ok:  # (the last accepted state, with why the next step failed)
        code = RESULTS.where(jnp.asarray(False), RESULTS.successful, stepper.failure)
        sol = eqx.tree_at(lambda s: s.result, sol, code)
    return GraspSolution(
        sol,
        res,
        at(t),
        jnp.asarray(t),
        jnp.asarray(ks[0]),
        jnp.asarray(ks[1]),
        stepper.calls,
        2 if symmetric else 1,
        stepper.topo,
        tuple(float(x) for x in w),
        integrator,
        stab,
        tuple(stepper.critical),
    )


def _stiffer(k, pen, limit, onset, order):
    """The stiffness that brings a penetration `pen` at stiffness k below `limit`."""
    if pen <= limit:
        return k
    excess = (pen - onset) / max(limit - onset, 1e-12)
    return k * min((1.3 * excess) ** (1.0 / order), MAX_STIFFENING)


def _observed_order(k0, k1, pen0, pen1, onset, order):
    """The exponent of penetration - onset ~ k^-order seen between two stiffnesses (the
    previous estimate where the step says nothing)."""
    e0, e1 = pen0 - onset, pen1 - onset
    if k1 <= k0 or e0 <= 0 or e1 <= 0 or e1 >= e0:
        return order
    return float(np.clip(np.log(e0 / e1) / np.log(k1 / k0), 0.25, 1.0))


def regrasp(g: GraspSolution, finger: Finger, closing=None, *, options=SolverOptions()):
    """Solve the grasp of `finger` (the design of `g.finger`, objects where they were
    before closing, possibly changed values) at `closing` (default g's), starting Newton
    from g's equilibrium: a single traced solve, differentiable in every design value and
    in the closing by the implicit function theorem (use with jax.grad / jax.jacfwd / vmap
    for designs near g's). Returns (Solution, ContactResult); check `Solution.result`.
    The penalty stiffness is g's."""
    closing = g.closing if closing is None else closing
    moved = with_objects_moved(finger, -closing * jnp.asarray(g.direction))
    return resolve_near(g, moved, g.integrator, options)


def resolve_near(g: GraspSolution, moved: Finger, integrator, options):
    """The equilibrium of `moved` (objects where they are at the closing) with g's penalty
    stiffness, segment cuts and start: (Solution, ContactResult)."""
    moved = with_stiffness(moved, g.stiffness, g.support_stiffness, g.member_stiffness)
    check_friction(g.topology.contact, moved)
    # ref_sign 0 (the sign at g's equilibrium), passed as the stepper passes it: an f64
    # array, so this call reuses the grasp's compiled program
    sol, _, _ = direct_core(
        g.topology, integrator, options, moved, g.solution.unknowns, np.float64(0.0)
    )
    return sol, contact_result(moved, sol, jnp.asarray(g.direction))


def _closing_step_cap(finger: Finger) -> float:
    """The longest closing step (mm): half the depth of the shallowest object below its
    centre (a circle's radius, an ellipse's smaller semi-axis, ...), so that no step
    carries an object through a beam (a half-plane has no such limit)."""
    depths = [  # (from the outline: the signed distance is exact only near the surface)
        np.min(np.linalg.norm(o.outline(400) - np.asarray(o.center), axis=-1))
        for o in finger.objects
        if not isinstance(o, HalfPlane)
    ]
    return 0.5 * min(depths) if depths else np.inf


# The first closing step (mm) of a search for the actuator force, from the closing where
# the open finger first touches an object.
FIRST_CLOSING_STEP = 0.5


def _closing_to_contact(finger: Finger, samples: int = 401) -> float:
    """A closing (mm) at which no object touches the open finger yet: the smallest gap
    between an object and the main beams' surfaces at the start, less the samples'
    spacing (a signed distance changes by at most the distance moved, so the gap between
    samples is no smaller than that). Moving the objects by less than the gap leaves
    them clear of the beams, whatever the direction."""
    s, p, h = (np.asarray(x) for x in main_beam_samples(finger, samples))
    spacing = float(np.max(s[:, -1])) / (samples - 1)
    gap = min(float(np.min(np.asarray(o.signed_distance(p)) - h)) for o in finger.objects)
    return max(gap - spacing, 0.0)


def _solve_between(stepper, at, t, near, far, max_step):
    """The equilibrium at closing t, followed from the solved point `near` = (closing,
    solution), started along the chord to the solved point `far` (the two bracket t, or
    far lies beyond near). Returns (t reached, solution, ok)."""
    (t_n, sol_n), (t_f, sol_f) = near, far
    if t >= t_n:
        return stepper.follow(
            at, t_n, t, sol_n, t - t_n, 1e-4, prev=(t_f, sol_f.unknowns), max_step=max_step
        )
    u, sol, ok = stepper.follow(
        lambda u: at(t_n - u),
        0.0,
        t_n - t,
        sol_n,
        t_n - t,
        1e-4,
        prev=(t_n - t_f, sol_f.unknowns),
        max_step=max_step,
    )
    return t_n - u, sol, ok


# A peak of the actuator force is refined until its bracket is this narrow (mm of closing).
PEAK_WIDTH = 0.02


def _peak_force(stepper, at, force, seen, max_step, rounds=16):
    """The largest actuator force near the highest of the path's points `seen` (closing,
    force, solution), by successive parabolas through the best point and two around it,
    with a golden-section step instead where the parabola's vertex falls outside the
    bracket or too near its best point (each point one solve), until the bracket is
    PEAK_WIDTH wide. Returns (closing, solution) of the best point."""
    k = int(np.argmax([f for _, f, _ in seen]))
    a, b, c = seen[k - 1], seen[k], seen[k + 1]
    golden = 0.5 * (3.0 - np.sqrt(5.0))
    for _ in range(rounds):
        (ta, fa, _), (tb, fb, sb), (tc, fc, _) = a, b, c
        if tc - ta <= PEAK_WIDTH:
            break
        den = (tb - ta) * (fb - fc) - (tb - tc) * (fb - fa)
        num = (tb - ta) ** 2 * (fb - fc) - (tb - tc) ** 2 * (fb - fa)
        t = tb - 0.5 * num / den if den else tb
        if not ta < t < tc or abs(t - tb) < 0.05 * (tc - ta):  # (golden section instead)
            t = tb + golden * ((tc - tb) if tc - tb > tb - ta else (ta - tb))
        side = a if t < tb else c
        if sb is None or side[2] is None:
            break
        t_got, sol, ok = _solve_between(stepper, at, t, (tb, sb), (side[0], side[2]), max_step)
        if not ok:
            break
        point = (t_got, force(t_got, sol), sol)
        if point[1] > fb:  # the new best point, between b and the side it lies on
            a, b, c = (a, point, b) if t_got < tb else (b, point, c)
        else:  # b stays the best; the new point closes the bracket on it
            a, c = (point, c) if t_got < tb else (a, point)
    return b[0], b[2]


def _find_closing(stepper, at, w, target, max_step=np.inf, start=None):
    """Closing displacement at which the actuator force equals `target` (path steps of at
    most max_step). Returns (t, solution, ok): on a failure, the last accepted state, or
    where the force peaked below the target (`RESULTS.actuator_force_not_reached`).

    The force usually grows with the closing. So the path is followed from the open
    finger (or from `start`) as a prescribed closing is, until it passes the target: its
    last two points bracket it. The bracket then closes by regula falsi with the Illinois
    rule (an end kept twice in a row has its excess force halved), each trial started
    from the nearer end's state along the chord to the other's (one solve, the bracket
    being one path step). Where the finger gives way instead (the force rises to a peak
    below the target, then falls), the path goes on until it fails, and the answer is the
    peak, refined by parabolas.

    start: (closing, actuator force, solution) of a solved state of this finger (the
    closing found before the contact was stiffened): the path starts there, toward the
    target (downward when its force is already past it)."""

    def force(t, sol):
        return float(contact_result(at(t), sol, w).actuator_force)

    tol = 1e-8 * max(target, 1e-3)
    if start is None and target <= tol:  # (the open finger: no closing needed)
        return 0.0, None, True
    t0, f0, sol0 = (_closing_to_contact(at(0.0)), 0.0, None) if start is None else start
    if abs(f0 - target) <= tol:
        return t0, sol0, True
    up = f0 < target
    closing = (lambda u: t0 + u) if up else (lambda u: t0 - u)
    seen = [(t0, f0, sol0)]  # (closing, force, solution) of the path's accepted points

    def passed(u, sol):
        t = closing(u)
        seen.append((t, force(t, sol), sol))
        return (seen[-1][1] >= target) == up

    if start is None:
        first = FIRST_CLOSING_STEP
    else:  # (as if the force were proportional to the closing)
        first = 1.5 * t0 * abs(target - f0) / max(f0, 1e-300) + 1e-4
    u, sol, ok = stepper.follow(
        lambda u: at(closing(u)),
        0.0,
        1e3 if up else t0,
        sol0,
        first,
        1e-4,
        max_step=max_step,
        stop=passed,
    )
    if not ok or (seen[-1][1] >= target) != up:  # (a failed step, or the target not passed)
        forces = [f for _, f, _ in seen]
        if up and 0 < int(np.argmax(forces)) < len(seen) - 1:  # the finger gave way
            t, sol = _peak_force(stepper, at, force, seen, max_step)
            stepper.failure = RESULTS.actuator_force_not_reached
            return t, sol, False
        return closing(u), sol, False
    (lo, f_lo, sol_lo), (hi, f_hi, sol_hi) = sorted(seen[-2:], key=lambda e: e[0])
    for t, f, s in ((lo, f_lo, sol_lo), (hi, f_hi, sol_hi)):
        if abs(f - target) <= tol and s is not None:
            return t, s, True
    if sol_lo is None:  # (the open finger)
        sol_lo, _ = stepper.solve(at(lo), None)
    # Regula falsi with the Illinois rule on [lo, hi]: g = force - target, g_lo < 0 <= g_hi.
    g_lo, g_hi, kept = f_lo - target, f_hi - target, 0
    t = hi
    for _ in range(40):
        t = hi - g_hi * (hi - lo) / max(g_hi - g_lo, 1e-300)
        ends = ((lo, sol_lo), (hi, sol_hi))
        near, far = ends if t - lo <= hi - t else ends[::-1]
        t, sol, ok = _solve_between(stepper, at, t, near, far, max_step)
        if not ok:
            return t, sol, False
        g = force(t, sol) - target
        if abs(g) <= tol:
            return t, sol, True
        if g < 0.0:
            lo, sol_lo, g_lo = t, sol, g
            kept = min(kept, 0) - 1  # (hi kept again)
            g_hi *= 0.5 if kept <= -2 else 1.0
        else:
            hi, sol_hi, g_hi = t, sol, g
            kept = max(kept, 0) + 1  # (lo kept again)
            g_lo *= 0.5 if kept >= 2 else 1.0
    return t, sol, False  # (the bracket did not close on the target: not found)


class ReleaseTrace(eqx.Module):
    """The quasi-static pull-out of the object: pull distance, holding force (all fingers),
    and the peak (NaN, with peak_pull, when not even the pull's onset solved)."""

    pull: np.ndarray
    force: np.ndarray
    normal_force: np.ndarray
    peak: float
    peak_pull: float
    complete: bool  # the trace reached the loss of contact (else it stopped early)
    message: str
    # where the pull's path lost stability and how it went on (`CriticalPoint`)
    critical_points: tuple = eqx.field(static=True, default=())


def _with_friction_raised(stepper: Stepper, finger: Finger, mu: float, start: Solution):
    """The equilibrium of `finger` (friction mu) reached from `start`, the frictionless
    one, along a path of growing friction: the onset of a pull, where full friction at once
    moves the equilibrium too far for Newton (the object's contact force turns by
    atan(mu)). Returns (solution, ok)."""

    def at(fraction):
        return with_contact(finger, friction=fraction * mu)

    reached, sol, ok = stepper.follow(at, 0.0, 1.0, start, 0.25, 1.0 / 512)
    stepper.prev = None  # (a point of this path, not of the pull's)
    return sol, ok and reached >= 1.0


def release_force(
    g: GraspSolution,
    *,
    pull_direction=(0.0, 1.0),
    step: float = 1.0,
    max_pull: float | None = None,
    friction=None,
    mode: str = "planar",
    integrator: Integrator = Integrator(steps=GRASP_STEPS),
    options: SolverOptions = SolverOptions(),
    topology=None,
) -> ReleaseTrace:
    """Pull the grasped object along `pull_direction` (default +z: toward the tips) step by
    step, solving the contact at every step, and report the largest resisting force.

    The holding force at a step is the force the fingers exert on the object against the
    pull: holding_factor x (contact force on this finger) . pull_direction. With friction
    the object slides along the pull direction (the slip direction of the friction law).
    The trace starts at pull 0 (the grasp re-solved with the pull's friction law) and
    stops when the contact is lost, or at max_pull (default: the finger's height).
    topology: as for `grasp` (e.g. the grasp's own `.topology`, so that traces of several
    designs share one compiled program); None: cut for the grasped finger.
    """
    w = unit_direction(pull_direction, "pull_direction")
    if not (np.isfinite(step) and step > 0):
        raise FingerError(f"step must be a positive distance (mm), got {step}")
    finger = with_contact(g.finger, slip_direction=w)
    if friction is not None:
        mu = float(friction)
        if not np.isfinite(mu) or mu < 0:
            raise FingerError(f"friction must be a non-negative coefficient, got {mu}")
        finger = with_contact(finger, friction=mu)
    if max_pull is None:
        max_pull = float(np.ptp(np.asarray(g.solution.front.position[:, 2]))) + 2 * step
    stepper = Stepper(finger, mode, integrator, options, validate=False, topology=topology)
    stepper.direction = w

    def at(t):
        return with_objects_moved(finger, t * w)

    pulls, forces, normals = [], [], []
    t = 0.0
    complete, message = False, "reached max_pull"
    # the grasp itself, re-solved with the pull's friction: the onset of the pull
    sol, ok = stepper.solve(at(0.0), g.solution.unknowns)
    mu = float(finger.contact.friction)
    if not ok and mu > 0:
        sol, ok = _with_friction_raised(stepper, at(0.0), mu, g.solution)
    if ok:
        res = contact_result(at(0.0), sol, w)
        pulls.append(0.0)
        forces.append(g.holding_factor * float(jnp.dot(res.force[::2], w)))
        normals.append(float(res.normal_force))
    else:
        sol = g.solution
    peak_normal = max(normals, default=0.0)
    while t < max_pull:
        # stepper.prev continues the pull path's extrapolation across the steps
        t_new, sol_new, ok = stepper.follow(at, t, t + step, sol, step, 1e-3 * step, stepper.prev)
        if t_new > t:
            res = contact_result(at(t_new), sol_new, w)
            t, sol = t_new, sol_new
            pulls.append(t)
            forces.append(g.holding_factor * float(jnp.dot(res.force[::2], w)))
            normals.append(float(res.normal_force))
            peak_normal = max(peak_normal, normals[-1])
            if normals[-1] < 1e-6 * max(peak_normal, 1e-12) or normals[-1] < 1e-9:
                complete, message = True, "contact lost: the object is released"
                break
        if not ok:
            message = f"equilibrium lost at pull {t:.4g} mm (the step could not be refined)"
            if stepper.failure in (
                RESULTS.contact_outside_near_segments,
                RESULTS.stability_lost,
            ):
                message += f": {RESULTS[stepper.failure]}"
            break
    f = np.asarray(forces)
    if not len(f):  # (not even the pull's onset solved: no holding force is known)
        message += ": no point of the trace solved, the holding force is unknown (NaN)"
        peak, peak_pull = np.nan, np.nan
    else:
        i = int(np.argmax(f))
        peak, peak_pull = float(f[i]), float(pulls[i])
        if peak <= 1e-9 * float(np.max(np.abs(f))):
            # round-off where the contact fades out is not a holding force
            peak, peak_pull = 0.0, 0.0
            message += "; not held: at every step the fingers push the object along the pull"
    return ReleaseTrace(
        pull=np.asarray(pulls),
        force=f,
        normal_force=np.asarray(normals),
        peak=peak,
        peak_pull=peak_pull,
        complete=complete,
        message=message,
        critical_points=tuple(stepper.critical),
    )
