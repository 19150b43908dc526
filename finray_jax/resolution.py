"""Is a solve resolved? The integration error by step doubling.

A solve integrates every segment at `Integrator.steps` fixed Runge-Kutta steps, and one
solve does not tell how far its answer is from the exact one. Solving again at 2n and 4n
steps does (Richardson): for a method of order p the error of the n-step answer is about
(y_n - y_2n) 2^p / (2^p - 1), and log2(|y_n - y_2n| / |y_2n - y_4n|) is the order the
three solves show. Where that observed order is close to p the estimate can be trusted;
where it is not, n is too coarse for the estimate (or for the answer).

How many steps a finger needs depends on its loads more than on its geometry. On ref-A
with the default Tsit5, the tip at 10 steps is within 6e-10 (L1) and 5e-6 (L2, 82 % of
the limit load) of the 80-step answer; at 4 steps within 1e-7 (L1) and 2e-2 (L2). A batch
of lightly loaded designs can run at fewer steps (cheaper per Newton iteration) when
this check says so.

Only the integration steps are varied. For a grasp (`check_grasp_resolution`) the
segment cuts (`Contact.segment_length`) and the penalty stiffness stay as they were.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._finger import Finger
from ._geometry import geometry
from ._grasp import resolve_near
from ._grasp_solution import GraspSolution
from ._integrator import Integrator
from ._solution import Solution
from ._solve import SolverOptions, prepare, solve_finger
from .io import to_plain  # (NaN -> None, tuples -> lists)

__all__ = ["ResolutionCheck", "check_grasp_resolution", "check_resolution"]

# Differences of the tip below this fraction of its displacement (10x the default Newton
# rtol) are what the Newton tolerance and round-off leave: no order can be read from them.
NOISE = 1e-9
# The order a grasp's check assumes: the C1 penalty law limits it (`check_grasp_resolution`).
CONTACT_ORDER = 2


@dataclasses.dataclass(frozen=True)
class ResolutionCheck:
    """The integration error of an n-step solve, estimated from solves at n, 2n and 4n.

    steps: (n, 2n, 4n). quantity: what decides, "tip" (the tip displacement) or, for a
    grasp, "normal_force" (its contact normal force). order: the order p the estimate
    assumes (the method's; 2 with contact, see `check_grasp_resolution`). observed_order:
    log2 of the ratio of the deciding quantity's differences (NaN where the finer one is
    below the noise level, 1e-9 of the quantity).
    tip_error (mm), tip_relative_error: the estimated error of the n-step tip displacement
    (absolute, and over its size). shape_error (mm): of the n-step main-beam centrelines,
    the largest over their points. reaction_error (N): of the n-step base reaction forces.
    normal_force_error (N), normal_force_relative_error: of a grasp's contact normal force
    (NaN otherwise). suggested_steps: the fewest steps whose estimated relative error of
    the deciding quantity is below rtol (from the order p; 4n when the estimate cannot be
    trusted). status: "converged" when all three solves converged, else the first
    failure's status (the estimates are then NaN). solutions: the three Solutions.
    """

    steps: tuple[int, int, int]
    quantity: str
    order: int
    observed_order: float
    tip_error: float
    tip_relative_error: float
    shape_error: float
    reaction_error: float
    normal_force_error: float
    normal_force_relative_error: float
    suggested_steps: int
    rtol: float
    status: str
    solutions: tuple[Solution, Solution, Solution] = dataclasses.field(repr=False)

    @property
    def relative_error(self) -> float:
        """The deciding quantity's estimated relative error."""
        if self.quantity == "normal_force":
            return self.normal_force_relative_error
        return self.tip_relative_error

    @property
    def asymptotic(self) -> bool:
        """Whether the three solves show the order p (within 1), or differ by no more
        than the noise level."""
        if self.status != "converged":
            return False
        return math.isnan(self.observed_order) or abs(self.observed_order - self.order) <= 1.0

    @property
    def reliable(self) -> bool:
        """Whether the error estimate can be trusted: the solves converge at least about
        as fast as order p (faster, before the asymptotic range, makes the estimate an
        upper bound; slower makes it too small)."""
        if self.status != "converged":
            return False
        return math.isnan(self.observed_order) or self.observed_order >= self.order - 1.0

    @property
    def resolved(self) -> bool:
        """The deciding quantity at n steps is within rtol (relative) of the converged
        answer, by a trustworthy estimate."""
        return self.reliable and self.relative_error <= self.rtol

    @property
    def message(self) -> str:
        n = self.steps[0]
        if self.status != "converged":
            return (
                f"a solve at {self._failed_steps()} steps per segment ended {self.status}: "
                "no estimate"
            )
        head = (
            f"{n} steps per segment: tip error about {self.tip_error:.1e} mm "
            f"({self.tip_relative_error:.1e} of its displacement), centrelines "
            f"{self.shape_error:.1e} mm, reactions {self.reaction_error:.1e} N"
        )
        if self.quantity == "normal_force":
            head += (
                f", contact normal force {self.normal_force_error:.1e} N "
                f"({self.normal_force_relative_error:.1e})"
            )
        what = "tip" if self.quantity == "tip" else "normal force"
        if math.isnan(self.observed_order):
            order = "the finer solves agree to the solver tolerance"
        else:
            order = f"{what}: observed order {self.observed_order:.1f} (expected {self.order})"
        if not self.reliable:
            return (
                f"{head}; {order}: slower than expected, so the estimate is too small to "
                f"trust. Use at least {self.steps[2]} steps and check again."
            )
        if not self.asymptotic:
            order += ", faster than expected: the estimate is an upper bound"
        verdict = "Resolved" if self.resolved else "Not resolved"
        m = self.suggested_steps
        if m < n:  # an extrapolation below the checked range
            advice = f"as few as {m} steps may do (check again at {m} before relying on it)"
        elif m == n:
            advice = f"{n} steps are about what it takes"
        else:
            advice = f"about {m} steps would do"
        return f"{head}; {order}. {verdict} ({what}) to rtol {self.rtol:g}: {advice}."

    def _failed_steps(self) -> int:
        for n, sol in zip(self.steps, self.solutions, strict=True):
            if sol.status != "converged":
                return n
        return self.steps[0]

    def to_dict(self) -> dict:
        """Plain values (JSON-ready), the solutions left out."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        del out["solutions"]
        out["asymptotic"] = self.asymptotic
        out["reliable"] = self.reliable
        out["resolved"] = self.resolved
        out["message"] = self.message
        return to_plain(out)


def _shared_points(fine_len: int, n: int) -> np.ndarray:
    """Indices into a beam of a 2n-step solve of the points an n-step solve has: each
    segment's block is its start, then the step points (n + 1 of them, every other one of
    the 2n + 1)."""
    segments = fine_len // (2 * n + 2)
    inner = np.concatenate([[0], 1 + 2 * np.arange(n + 1)])
    return (np.arange(segments)[:, None] * (2 * n + 2) + inner[None]).reshape(-1)


def _beam_difference(coarse, fine, n: int) -> float:
    """Largest distance between the n-step and 2n-step centreline at the n-step points."""
    idx = _shared_points(fine.s.shape[-1], n)
    s_c, s_f = np.asarray(coarse.s), np.asarray(fine.s)[..., idx]
    if s_c.shape != s_f.shape or not np.allclose(
        s_c, s_f, rtol=0.0, atol=1e-9 * max(1.0, np.max(np.abs(s_c)))
    ):
        raise AssertionError("step-doubled solutions do not share their step points")
    d = np.asarray(coarse.position) - np.asarray(fine.position)[..., idx, :]
    return float(np.max(np.linalg.norm(d, axis=-1)))


def _reaction_difference(coarse: Solution, fine: Solution) -> float:
    """Largest difference of the base reaction forces (N) of the two main beams."""
    return max(
        float(np.linalg.norm(np.asarray(a.force) - np.asarray(b.force)))
        for a, b in (
            (coarse.reactions_front, fine.reactions_front),
            (coarse.reactions_back, fine.reactions_back),
        )
    )


def _order(integrator: Integrator) -> int:
    try:
        p = integrator.solver.order(None)
    except Exception as e:  # a solver whose order depends on its terms
        raise ValueError(
            f"check_resolution: cannot tell the order of {type(integrator.solver).__name__} "
            f"({e}); use an explicit Runge-Kutta solver such as Tsit5"
        ) from None
    if not isinstance(p, (int, np.integer)) or p < 1:
        raise ValueError(
            f"check_resolution: {type(integrator.solver).__name__} has no fixed order ({p!r})"
        )
    return int(p)


def check_resolution(
    finger: Finger,
    *,
    mode: str = "auto",
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    rtol: float = 1e-6,
    solution: Solution | None = None,
) -> ResolutionCheck:
    """Estimate the integration error of solving `finger` at `integrator.steps` steps per
    segment, by solving it at 2 and 4 times as many (each a new compile the first time).

    With objects or a support (contact) the estimate assumes order 2, as
    `check_grasp_resolution` does. rtol: the relative tip error that counts as resolved
    (and that `suggested_steps` aims at). solution: an existing solve of this finger at
    `integrator.steps`, reused as the first of the three.
    """
    _check_rtol(rtol)
    topo = prepare(finger, mode)  # validates the finger; all three share the topology
    p = _order(integrator)
    if topo.contact is not None:  # objects or a support: the C1 penalty limits the order
        p = min(p, CONTACT_ORDER)
    n = integrator.steps
    if solution is not None and (solution.steps != n or solution.mode != topo.mode):
        raise ValueError(
            f"solution was solved {solution.mode} at {solution.steps} steps per segment; "
            f"the check is for {topo.mode} at {n}: pass a solution of those settings or None"
        )
    sols = []
    for k in (1, 2, 4):
        if k == 1 and solution is not None:
            sols.append(solution)
            continue
        integ = dataclasses.replace(integrator, steps=k * n)
        sols.append(solve_finger(finger, integrator=integ, options=options, topology=topo))
    return _estimate(sols, n, p, rtol, float(geometry(finger).L))


def check_grasp_resolution(
    g: GraspSolution, *, rtol: float = 1e-6, options: SolverOptions = SolverOptions()
) -> ResolutionCheck:
    """`check_resolution` for a grasp: its equilibrium solved again at 2 and 4 times its
    steps per segment, at the same closing, penalty stiffness and segment cuts, started
    from its own. The contact normal force decides.

    The estimate assumes order 2, not the method's. The penalty law is C1 (its second
    derivative jumps where contact starts and where the smoothing zone ends), so a step
    across such a point is less accurate, by an amount that depends on where the point
    falls in the step (a C2 law converges no faster: docs/grasping.md). On Finger-1
    (examples/grasp_finger1.toml, closing 5 mm, Tsit5) the normal force changes
    by 3.0e-5, 9.3e-6 and 1.8e-6 N from 16 to 32, 64 and 128 steps (order 1.7, then 2.4),
    while the tip's changes (3.0e-6, 3.7e-6, 4.9e-7 mm) show no steady order."""
    if not isinstance(g, GraspSolution):
        raise TypeError(f"expected a GraspSolution (from finray_jax.grasp), got {type(g).__name__}")
    _check_rtol(rtol)
    if g.status != "converged":
        raise ValueError(f"the grasp did not converge ({g.status}): nothing to check")
    p = min(_order(g.integrator), CONTACT_ORDER)
    n = g.integrator.steps
    sols, normals = [g.solution], [float(g.contact.normal_force)]
    for k in (2, 4):
        integ = dataclasses.replace(g.integrator, steps=k * n)
        sol, contact = resolve_near(g, g.finger, integ, options)
        sols.append(sol)
        normals.append(float(contact.normal_force))
    return _estimate(sols, n, p, rtol, float(geometry(g.finger).L), normals)


def _check_rtol(rtol):
    if not isinstance(rtol, (int, float)) or not (0.0 < rtol < 1.0):
        raise ValueError(f"rtol must be a number in (0, 1), got {rtol!r}")


def _richardson(values, p: int, scale: float):
    """Estimated absolute and relative error (over `scale`) of values[0], and the observed
    order; values: at n, 2n and 4n steps."""
    d1 = float(np.linalg.norm(np.asarray(values[0]) - np.asarray(values[1])))
    d2 = float(np.linalg.norm(np.asarray(values[1]) - np.asarray(values[2])))
    observed = math.log2(d1 / d2) if d2 > NOISE * scale and d1 > 0.0 else float("nan")
    err = d1 * 2.0**p / (2.0**p - 1.0)  # e(n) = (y_n - y_2n) 2^p / (2^p - 1)
    return err, err / scale, observed


def _estimate(sols, n: int, p: int, rtol: float, length: float, normals=None) -> ResolutionCheck:
    """The check from solves at n, 2n and 4n steps (length: the front beam's; normals:
    a grasp's normal forces, which then decide)."""
    nan = float("nan")
    steps = (n, 2 * n, 4 * n)
    quantity = "tip" if normals is None else "normal_force"
    failed = next((s.status for s in sols if s.status != "converged"), None)
    if failed is not None:
        return ResolutionCheck(
            steps, quantity, p, nan, nan, nan, nan, nan, nan, nan, 4 * n, rtol, failed, tuple(sols)
        )
    tips = [np.asarray(s.tip.displacement) for s in sols]
    # The tip's displacement sets its scale; below 1e-9 of the front beam's length it is
    # none (an unloaded finger), and that length stands in.
    tip_scale = max(float(np.linalg.norm(tips[2])), NOISE * length)
    tip_err, tip_rel, observed = _richardson(tips, p, tip_scale)
    force_err = force_rel = nan
    rel = tip_rel
    if normals is not None:
        force_scale = max(abs(normals[2]), 1e-300)
        force_err, force_rel, observed = _richardson(normals, p, force_scale)
        rel = force_rel
    if observed < p - 1.0:  # (False for NaN) the estimate cannot be trusted
        suggested = 4 * n
    else:  # e(m) = e(n) (n / m)^p; below the noise the estimate is an upper bound
        suggested = max(1, math.ceil(n * (max(rel, NOISE) / rtol) ** (1.0 / p)))
    gain = 2.0**p / (2.0**p - 1.0)
    shape = max(
        _beam_difference(sols[0].front, sols[1].front, n),
        _beam_difference(sols[0].back, sols[1].back, n),
    )
    return ResolutionCheck(
        steps=steps,
        quantity=quantity,
        order=p,
        observed_order=observed,
        tip_error=tip_err,
        tip_relative_error=tip_rel,
        shape_error=gain * shape,
        reaction_error=gain * _reaction_difference(sols[0], sols[1]),
        normal_force_error=force_err,
        normal_force_relative_error=force_rel,
        suggested_steps=suggested,
        rtol=float(rtol),
        status="converged",
        solutions=tuple(sols),
    )
