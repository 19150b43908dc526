"""Grasping: closing a finger on rigid objects, by a closing displacement or until the
actuator pushes with a given force, with the contact's penalties stiffened until their
penetration limits hold.

The finger stays where it is; closing the gripper by d moves every object by -d w
relative to the finger (w: the closing direction, the unit vector in which the finger's
base moves, default -x: from the back beam toward the front beam). Each equilibrium is a
Newton solve of the full contact problem (`solve_finger` with objects), warm started from
the previous one; the closing displacement is stepped, and a step that fails is halved.
With a two-finger parallel grasp (`symmetric=True`) the second finger is the mirror image
of the first about the object's plane of symmetry, so only one finger is solved and the
holding force is twice that finger's.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._closing import closing_step_cap, find_closing
from ._contact import (
    check_friction,
    member_penetration_limit,
    member_smoothing,
    member_stiffness,
    smoothing,
    stiffness,
    support_penetration_limit,
    support_smoothing,
    support_stiffness,
)
from ._contact_result import contact_result, with_members
from ._errors import FingerError
from ._finger import Finger
from ._grasp_inputs import check_objects, unit_direction, with_objects_moved, with_stiffness
from ._grasp_solution import GRASP_STEPS, GraspSolution
from ._integrator import Integrator
from ._solution import RESULTS
from ._solve import SolverOptions, direct_core
from ._stepper import Stepper

MAX_STIFFENING = 16.0  # the largest factor on a penalty stiffness in one round
MAX_STIFFENING_ROUNDS = 8  # rounds of stiffening in one grasp


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
    w, d, fa = _checked_inputs(finger, closing, actuator_force, direction)
    # (check_objects validated the finger)
    stepper = Stepper(finger, mode, integrator, options, validate=False, topology=topology)
    stepper.direction = w
    path = _ClosingPath(finger, w, stepper, integrator)
    cap = closing_step_cap(path.finger)
    start = None
    while True:
        if closing is not None:
            t, sol, ok = stepper.follow(
                path.at, 0.0, d, None, d / 8.0, 1e-4 * max(d, 1.0), max_step=cap
            )
        else:
            t, sol, ok = find_closing(stepper, path.at, w, fa, cap, start)
        if sol is None:
            sol, _ = stepper.solve(path.at(0.0), None)
        res = path.result(t, sol)
        stiffened = False
        if stiffen:
            sol, res, ok, stiffened = path.stiffen(t, sol, res, ok)
        # A stiffer contact changes the actuator force at that closing: find the closing
        # for the target force again (a prescribed closing stays what it was).
        if closing is not None or not (ok and stiffened):
            break
        start = (t, float(res.actuator_force), sol)  # (the secant starts from there)
    stab = None
    if ok and check_stability and stepper.topo.mode == "planar":
        sol, res, ok, stab = _stable_equilibrium(path, t, sol, res)
    if not ok:  # (the last accepted state, with why the next step failed)
        code = RESULTS.where(jnp.asarray(False), RESULTS.successful, stepper.failure)
        sol = eqx.tree_at(lambda s: s.result, sol, code)
    return GraspSolution(
        sol,
        res,
        path.at(t),
        jnp.asarray(t),
        jnp.asarray(path.ks[0]),
        jnp.asarray(path.ks[1]),
        stepper.calls,
        2 if symmetric else 1,
        stepper.topo,
        tuple(float(x) for x in w),
        integrator,
        stab,
        tuple(stepper.critical),
    )


def _checked_inputs(finger, closing, actuator_force, direction):
    """The grasp's inputs checked: (the unit closing direction, the closing or None, the
    actuator force or None)."""
    if (closing is None) == (actuator_force is None):
        raise FingerError("grasp needs exactly one of closing= and actuator_force=")
    w = unit_direction(direction, "direction")
    check_objects(finger, w)
    d = fa = None
    if closing is not None:
        d = float(np.asarray(closing))
        if not np.isfinite(d) or d < 0:
            raise FingerError(f"closing must be a non-negative displacement (mm), got {d}")
    else:
        fa = float(np.asarray(actuator_force))
        if not np.isfinite(fa) or fa < 0:
            raise FingerError(f"actuator_force must be a non-negative force (N), got {fa}")
    return w, d, fa


def _penetrations(res):
    """The penetrations into the objects, the support and another member (mm)."""
    pens = (res.max_penetration, res.support_penetration, res.member_penetration)
    return [float(x) for x in pens]


class _ClosingPath:
    """One grasp's closing: the finger with its current penalty stiffnesses (objects,
    support, members: `ks`) and its objects moved to a closing t along w, and the
    stiffening of those penalties until each contact's penetration limit holds.

    The penetration above a contact's smoothing onset goes like k^-order: order 1 for a
    distributed contact, about 3/4 for the support's edge and for members meeting at a
    point, re-estimated from every stiffening (the estimates and the count of rounds carry
    over from one closing search to the next)."""

    def __init__(self, finger, w, stepper, integrator):
        self.ks = [float(x(finger)) for x in (stiffness, support_stiffness, member_stiffness)]
        self.finger = with_stiffness(finger, *self.ks)
        self.w = w
        self.stepper = stepper
        self.integrator = integrator
        finger = self.finger
        self.limits = [
            float(finger.contact.max_penetration * finger.front.thickness),
            float(support_penetration_limit(finger)),
            float(member_penetration_limit(finger)),
        ]
        self.onsets = [
            0.5 * float(x(finger)) for x in (smoothing, support_smoothing, member_smoothing)
        ]
        self.orders = [1.0, 0.75, 0.75]
        self.rounds = 0

    def at(self, t):
        """The finger (current stiffnesses) with its objects where closing by t puts them."""
        return with_objects_moved(self.finger, -t * self.w)

    def result(self, t, sol):
        """The contact result of the equilibrium `sol` at closing t, members' included."""
        res = contact_result(self.at(t), sol, self.w)
        return with_members(res, self.stepper.topo, self.integrator, self.at(t), sol)

    def stiffen(self, t, sol, res, ok):
        """Raise the penalty stiffnesses whose penetration exceeds its limit at closing t
        and solve again, in rounds, until every limit holds, a stiffer penalty does not
        converge (the last equilibrium stays: `GraspSolution.penetration_warnings`), or
        MAX_STIFFENING_ROUNDS are spent. Returns (solution, contact result, ok, whether
        the stiffnesses changed)."""
        stiffened = False
        pens = _penetrations(res)
        over = lambda pens: any(p > lim for p, lim in zip(pens, self.limits))
        while ok and over(pens) and self.rounds < MAX_STIFFENING_ROUNDS:
            # penetration = onset + c k^-order: scale each k so that the part above the
            # onset fits in what is left, stepping log k from the old to the new
            # stiffnesses (warm started).
            old = list(self.ks)
            new = [
                _stiffer(kk, p, lim, onset, order)
                for kk, p, lim, onset, order in zip(
                    old, pens, self.limits, self.onsets, self.orders
                )
            ]
            stiffer = lambda u, k0=old, k1=new, t=t: with_stiffness(
                self.at(t), *(a * (b / a) ** u for a, b in zip(k0, k1))
            )
            u, sol, ok = self.stepper.follow(stiffer, 0.0, 1.0, sol, 1.0, 1e-3)
            if not ok and u > 0:  # part of the way: go on from there
                new, ok = [a * (b / a) ** u for a, b in zip(old, new)], True
            elif not ok:  # not a step: keep the last equilibrium (`penetration_warnings`)
                ok = True
                break
            if ok:
                self.ks = new
                self.finger = with_stiffness(self.finger, *new)  # (at() moves the new finger)
                res = self.result(t, sol)
                seen = _penetrations(res)
                for i in range(3):
                    self.orders[i] = _observed_order(
                        old[i], new[i], pens[i], seen[i], self.onsets[i], self.orders[i]
                    )
                pens = seen
                stiffened = True
            self.rounds += 1
        return sol, res, ok, stiffened


def _stable_equilibrium(path: _ClosingPath, t, sol, res):
    """The final equilibrium's stability; an unstable one is replaced by a stable
    equilibrium next to it when Newton finds one, else not ok (the stepper's failure says
    why). Returns (solution, contact result, ok, Stability)."""
    stepper = path.stepper
    stab = stepper.stability(path.at(t), sol)
    ok = True
    if not stab.stable:
        found = stepper.stable_next_to(t, sol, t, path.at(t), sol, stab)
        if found:
            sol, stab = found[0]
            res = path.result(t, sol)
        else:
            ok, stepper.failure = False, RESULTS.unstable_equilibrium
    return sol, res, ok, stab


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
