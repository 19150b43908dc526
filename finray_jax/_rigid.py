"""How far a penalty grasp is from rigid contact: the grasp re-solved with stiffer
penalties, and its outputs extrapolated to infinite stiffness.

A penalty contact lets a beam sink into what it touches, and the grasp's answers differ
from rigid contact's by a power of 1/k: about 1/k where the contact is spread along a
beam (the penetration is q / k), more slowly where it concentrates (the back beam on the
support's end is an edge contact, near k^-3/4), and about k^-1/2 while the penetration
stays within the penalty's quadratic onset. `rigid_contact_estimate` re-solves a grasp
at its penalty stiffnesses times 4 and 16 (both the objects' and the support's, warm
started along the way, on the grasp's segment cuts), observes the order p of each output
from the three values, and extrapolates (Aitken's delta-squared, exact for
v(k) = v_rigid + c k^-p). It reports how far the grasp's own value lies from that estimate.
Where the three values do not yet converge like a power (they change sign, or do not
shrink by at least 4^0.2 per step), no order is claimed and the stiffest value stands
for the estimate: the distance is then a lower bound.
"""

import dataclasses

import numpy as np

from ._contact_result import contact_result
from ._grasp_inputs import with_stiffness
from ._grasp_solution import GraspSolution
from ._solve import SolverOptions
from ._stepper import Stepper

OUTPUTS = {
    "normal_force": lambda sol, c: float(c.normal_force),
    "contact_force_x": lambda sol, c: float(c.force[0]),
    "contact_force_z": lambda sol, c: float(c.force[2]),
    "support_force_x": lambda sol, c: float(c.support_force[0]),
    "support_force_z": lambda sol, c: float(c.support_force[2]),
    "actuator_force": lambda sol, c: float(c.actuator_force),
    "tip_x": lambda sol, c: float(sol.front.position[-1, 0]),
    "tip_z": lambda sol, c: float(sol.front.position[-1, 2]),
}


@dataclasses.dataclass(frozen=True)
class RigidEstimate:
    """Outputs of a grasp at its penalty stiffnesses times `factors`, and the rigid limit.

    values: name -> the output at each factor (N or mm). order: name -> the observed p of
    v(k) - v_rigid ~ k^-p (NaN where the three values do not converge like a power: the
    estimate is then the stiffest value, and the distance a lower bound). rigid: name ->
    the extrapolated value.
    distance: name -> (value at factor 1 - rigid) / scale, the grasp's own error, with
    scale the largest |value| of its kind (forces: the largest force; tip: the tip's
    displacement from the undeformed finger's).
    """

    factors: tuple
    stiffness: tuple  # the objects' k at each factor
    support_stiffness: tuple
    values: dict
    order: dict
    rigid: dict
    distance: dict

    def lines(self) -> list[str]:
        head = "  ".join(f"k x{f:g}".rjust(12) for f in self.factors)
        out = [f"{'output':18s}{head}  {'rigid est.':>12s}  {'order':>6s}  {'default off':>11s}"]
        for name, vals in self.values.items():
            cols = "  ".join(f"{v:12.6g}" for v in vals)
            p = self.order[name]
            bound = ">=" if np.isnan(p) else "  "
            out.append(
                f"{name:18s}{cols}  {self.rigid[name]:12.6g}  "
                f"{'   n/a' if np.isnan(p) else f'{p:6.2f}'}  "
                f"{bound}{100 * abs(self.distance[name]):8.3f}%"
            )
        out.append("(order n/a: not yet converging like a power of 1/k; >=: at least this far)")
        return out


RATIO = 4.0  # between consecutive stiffnesses
MIN_ORDER = 0.2  # slower than k^-0.2 is not taken for convergence


def _aitken(v):
    """(rigid estimate, order) from values at k, RATIO k, RATIO^2 k."""
    d1, d2 = v[1] - v[0], v[2] - v[1]
    if d1 * d2 <= 0 or abs(d1) < RATIO**MIN_ORDER * abs(d2):
        return v[2], np.nan
    return v[2] + d2 * d2 / (d1 - d2), float(np.log(d1 / d2) / np.log(RATIO))


def rigid_contact_estimate(
    g: GraspSolution, *, options: SolverOptions = SolverOptions()
) -> RigidEstimate:
    """Re-solve the grasp g with its penalty stiffnesses times 4 and 16 and extrapolate
    every contact output and the tip to rigid contact (see the module's docstring).

    Raises RuntimeError when a stiffer grasp does not converge (the message says at which
    stiffness)."""
    factors = (1.0, RATIO, RATIO**2)
    k, k_s = float(g.stiffness), float(g.support_stiffness)
    stepper = Stepper(
        g.finger, "planar", g.integrator, options, validate=False, topology=g.topology
    )
    w = g.direction
    sol = g.solution
    results = [(sol, g.contact)]
    for lo, hi in zip(factors[:-1], factors[1:]):
        path = lambda u, lo=lo, hi=hi: with_stiffness(
            g.finger, k * lo * (hi / lo) ** u, k_s * lo * (hi / lo) ** u
        )
        t, sol, ok = stepper.follow(path, 0.0, 1.0, sol, 1.0, 1e-3)
        if not ok:
            raise RuntimeError(
                f"the grasp with {hi:g} x its penalty stiffness did not converge (reached "
                f"{lo * (hi / lo) ** t:.3g} x): no rigid-contact estimate"
            )
        results.append((sol, contact_result(path(1.0), sol, w)))
    values, order, rigid, distance = {}, {}, {}, {}
    undeformed = np.asarray(g.finger.tip)
    for name, fn in OUTPUTS.items():
        if name.startswith("support") and g.finger.adaptor.support_length is None:
            continue
        v = [fn(s, c) for s, c in results]
        values[name] = tuple(v)
        rigid[name], order[name] = _aitken(v)
    forces = [name for name in values if not name.startswith("tip")]
    f_scale = max(max(abs(x) for x in values[n]) for n in forces)
    t_scale = float(
        np.hypot(values["tip_x"][0] - undeformed[0], values["tip_z"][0] - undeformed[-1])
    )
    for name, v in values.items():
        scale = t_scale if name.startswith("tip") else f_scale
        distance[name] = (v[0] - rigid[name]) / max(scale, 1e-300)
    return RigidEstimate(
        factors,
        tuple(k * f for f in factors),
        tuple(k_s * f for f in factors),
        values,
        order,
        rigid,
        distance,
    )
