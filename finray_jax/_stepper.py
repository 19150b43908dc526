"""Equilibria along a path: a stepper that solves the finger as a parameter moves its
objects or its contact values (closing, stiffening, friction, pull), each solve warm
started from an extrapolation of the last two, with steps that grow after easy solves and
halve after failures, and that goes on past a critical point on a stable branch next to
it."""

import dataclasses

import numpy as np

from ._contact import stiffness, support_stiffness, with_friction
from ._contact_result import contact_result
from ._cuts import build_topology
from ._errors import FingerError
from ._grasp_inputs import with_stiffness
from ._solution import RESULTS
from ._solve import direct_core, prepare, resolve_mode, undeformed_unknowns
from ._stability import CriticalPoint, stability_of, stable_neighbours
from ._types import check_x64


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
    benchmarks/grasp.py these factors take 7 and 10 solves, with no failed step."""
    if iterations <= 3:
        return 2.0
    if iterations <= 6:
        return 1.5
    return 1.0 if iterations <= 9 else 0.5
