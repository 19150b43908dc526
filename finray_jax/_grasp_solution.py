"""What a grasp returns: the finger's equilibrium at a closing with its contact outputs,
the penalty stiffnesses it was solved with and its stability; and the stability of any
computed equilibrium."""

import equinox as eqx
import jax

from ._contact import member_penetration_limit, member_stiffness, support_penetration_limit
from ._contact_result import ContactResult
from ._errors import FingerError
from ._finger import Finger
from ._integrator import Integrator
from ._solution import RESULTS, Solution
from ._solve import topology_of
from ._stability import CriticalPoint, Stability, stability_of

GRASP_STEPS = 16  # default integration steps per segment for contact problems


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
