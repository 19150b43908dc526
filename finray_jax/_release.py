"""Releasing a grasp: the quasi-static pull-out of the grasped object, step by step, and
the largest force the fingers resist it with (the holding force)."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._contact_result import contact_result
from ._errors import FingerError
from ._finger import Finger
from ._grasp_inputs import unit_direction, with_contact, with_objects_moved
from ._grasp_solution import GRASP_STEPS, GraspSolution
from ._integrator import Integrator
from ._solution import RESULTS, Solution
from ._solve import SolverOptions
from ._stepper import Stepper


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
    finger = _pulled_finger(g.finger, w, friction)
    if max_pull is None:
        max_pull = float(np.ptp(np.asarray(g.solution.front.position[:, 2]))) + 2 * step
    stepper = Stepper(finger, mode, integrator, options, validate=False, topology=topology)
    stepper.direction = w

    def at(t):
        return with_objects_moved(finger, t * w)

    trace = ([], [], [])  # (pull, holding force, normal force) at every solved point
    sol = _pull_onset(stepper, at, g, w, trace)
    complete, message = _pull_out(stepper, at, g, w, sol, step, max_pull, trace)
    pulls, forces, normals = trace
    f = np.asarray(forces)
    peak, peak_pull, message = _peak_holding(f, pulls, message)
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


def pulled_to(
    g: GraspSolution,
    pull: float,
    *,
    pull_direction=(0.0, 1.0),
    step: float = 1.0,
    friction=None,
    topology=None,
):
    """The grasp's equilibrium with its object pulled by `pull` (mm) along
    `pull_direction`, under the pull's friction law (as `release_force` traces it),
    followed from the pull's onset (as the trace starts) a step at a time: (solution,
    pulled finger, ok). It puts the holding force's peak back in hand (`release_force`'s
    `peak_pull`) to differentiate it there."""
    w = unit_direction(pull_direction, "pull_direction")
    finger = _pulled_finger(g.finger, w, friction)
    stepper = Stepper(finger, "planar", g.integrator, SolverOptions(), False, topology=topology)

    def at(t):
        return with_objects_moved(finger, t * w)

    stepper.direction = w
    onset = ([], [], [])
    sol = _pull_onset(stepper, at, g, w, onset)
    if not onset[0]:  # (the pull's onset did not solve)
        return sol, at(0.0), False
    t, sol, ok = stepper.follow(at, 0.0, float(pull), sol, step, 1e-4)
    return sol, at(t), bool(ok)


def _pulled_finger(finger: Finger, w, friction) -> Finger:
    """The grasped finger with the pull's friction law: slip along the pull direction w,
    and the friction coefficient `friction` (None: the finger's own)."""
    finger = with_contact(finger, slip_direction=w)
    if friction is not None:
        mu = float(friction)
        if not np.isfinite(mu) or mu < 0:
            raise FingerError(f"friction must be a non-negative coefficient, got {mu}")
        finger = with_contact(finger, friction=mu)
    return finger


def _record(trace, g: GraspSolution, t, res, w):
    """Append the point at pull t (contact result `res`) to the trace."""
    pulls, forces, normals = trace
    pulls.append(t)
    forces.append(g.holding_factor * float(jnp.dot(res.force[::2], w)))
    normals.append(float(res.normal_force))


def _pull_onset(stepper: Stepper, at, g: GraspSolution, w, trace):
    """The grasp itself, re-solved with the pull's friction: the onset of the pull,
    recorded at pull 0. Returns its solution (the grasp's own when it does not solve, and
    then nothing is recorded)."""
    sol, ok = stepper.solve(at(0.0), g.solution.unknowns)
    mu = float(at(0.0).contact.friction)
    if not ok and mu > 0:
        sol, ok = _with_friction_raised(stepper, at(0.0), mu, g.solution)
    if ok:
        _record(trace, g, 0.0, contact_result(at(0.0), sol, w), w)
        return sol
    return g.solution


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


def _pull_out(stepper: Stepper, at, g: GraspSolution, w, sol, step, max_pull, trace):
    """The pull from the onset's solution `sol`, a step at a time, each point recorded,
    until the contact is lost, the equilibrium is lost or the pull reaches max_pull.
    Returns (complete, message): whether the contact was lost, and how the trace ended."""
    pulls, _, normals = trace
    t = 0.0
    complete, message = False, "reached max_pull"
    peak_normal = max(normals, default=0.0)
    while t < max_pull:
        # stepper.prev continues the pull path's extrapolation across the steps
        t_new, sol_new, ok = stepper.follow(at, t, t + step, sol, step, 1e-3 * step, stepper.prev)
        if t_new > t:
            res = contact_result(at(t_new), sol_new, w)
            t, sol = t_new, sol_new
            _record(trace, g, t, res, w)
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
    return complete, message


def _peak_holding(f, pulls, message):
    """The largest holding force `f` of the trace and the pull where it acts (NaN where
    no point solved; 0 where the fingers never hold the object), and the trace's message
    with what that says. Returns (peak, peak_pull, message)."""
    if not len(f):  # (not even the pull's onset solved: no holding force is known)
        message += ": no point of the trace solved, the holding force is unknown (NaN)"
        return np.nan, np.nan, message
    i = int(np.argmax(f))
    peak, peak_pull = float(f[i]), float(pulls[i])
    if peak <= 1e-9 * float(np.max(np.abs(f))):
        # round-off where the contact fades out is not a holding force
        peak, peak_pull = 0.0, 0.0
        message += "; not held: at every step the fingers push the object along the pull"
    return peak, peak_pull, message
