"""The closing search: the closing displacement at which the actuator pushes with a given
force, found along the closing path (regula falsi on the step that passes the force, or
the peak where the finger gives way first), and the longest step a closing path may take.
"""

import numpy as np

from ._contact_result import contact_result
from ._finger import Finger
from ._geometry import main_beam_samples
from ._objects import HalfPlane
from ._solution import RESULTS


def closing_step_cap(finger: Finger) -> float:
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


def find_closing(stepper, at, w, target, max_step=np.inf, start=None):
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
    if start is None:
        first = FIRST_CLOSING_STEP
    else:  # (as if the force were proportional to the closing)
        first = 1.5 * t0 * abs(target - f0) / max(f0, 1e-300) + 1e-4
    seen, u, sol, ok = _follow_until_passed(
        stepper, at, force, target, closing, (t0, f0, sol0), first, max_step
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
    return _regula_falsi(
        stepper, at, force, target, tol, (lo, f_lo, sol_lo), (hi, f_hi, sol_hi), max_step
    )


def _follow_until_passed(stepper, at, force, target, closing, first_point, first, max_step):
    """The closing path, closing(u) for u from 0 (first step `first`), followed from
    `first_point` = (closing, force, solution) until its actuator force passes `target`
    (from below when it starts below, else from above). Returns (seen, u, solution, ok):
    seen, the (closing, force, solution) of the path's accepted points, `first_point`
    first; then what `Stepper.follow` returns."""
    t0, f0, sol0 = first_point
    up = f0 < target
    seen = [first_point]

    def passed(u, sol):
        t = closing(u)
        seen.append((t, force(t, sol), sol))
        return (seen[-1][1] >= target) == up

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
    return seen, u, sol, ok


def _regula_falsi(stepper, at, force, target, tol, low, high, max_step):
    """The closing between the solved points `low` and `high` (closing, force, solution;
    the force below the target at the smaller closing, at or above it at the larger) where
    the force is `target` (within tol): regula falsi with the Illinois rule (an end kept
    twice in a row has its excess force halved), each trial followed from the nearer end
    along the chord to the other. Returns (t, solution, ok); not ok when a trial fails or
    the bracket does not close on the target."""
    (lo, f_lo, sol_lo), (hi, f_hi, sol_hi) = low, high
    # g = force - target, g_lo < 0 <= g_hi.
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
