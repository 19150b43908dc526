"""`finray grasp`: close a finger file's finger on its objects, print the contact outputs,
and optionally trace the release, estimate the rigid-contact limit and check the
resolution."""

import time

import finray_jax as fr

from . import io as fio
from ._cli_args import resolution_rtol
from ._cli_common import EXIT_FAILED, EXIT_OK, UserError, compiling, num, progress
from ._cli_finger import check_grasp_objects, report_resolution
from .plot import grasp_figure, save_figure
from .report import grasp_to_dict, rigid_estimate_to_dict

# --------------------------------------------------------------------------------------
# Printing a grasp
# --------------------------------------------------------------------------------------


def _stability_lines(g) -> list[str]:
    s = g.stability
    lines = []
    if s is not None:
        state = "stable" if s.stable else s.message
        lines.append(
            f"  stability         {state} (smallest eigenvalues of the tangent stiffness "
            + ", ".join(f"{v:.3g}" for v in s.eigenvalues[:3])
            + ")"
        )
    return lines + [f"  path              {c.describe()}" for c in g.critical_points]


def _support_lines(g) -> list[str]:
    if g.finger.adaptor.support_length is None:
        return []
    c = g.contact
    return [
        f"  support force     x {num(c.support_force[0])}, z {num(c.support_force[2])} N, "
        f"max penetration {num(c.support_penetration)} mm "
        f"(penalty stiffness {float(g.support_stiffness):.4g} N/mm^2)"
    ]


def _grasp_lines(g, name="") -> list[str]:
    """A grasp's status and contact outputs, one line each (headed by `name` if given)."""
    c = g.contact
    head = f"{name}: " if name else ""
    return (
        [
            f"{head}{g.status} at closing {float(g.closing):.4g} mm "
            f"(penalty stiffness {float(g.stiffness):.4g} N/mm^2)",
            f"  contact force     {num(c.normal_force)} N normal resultant; total force x "
            f"{num(c.force[0])}, z {num(c.force[2])} N",
            f"  contact length    {num(c.contact_length)} mm, max penetration "
            f"{num(c.max_penetration)} mm",
            f"  crossbeam force   x {num(c.crossbeam_force[0])}, z {num(c.crossbeam_force[2])} N "
            "(mean on the front beam)",
            f"  actuator force    {num(c.actuator_force)} N",
        ]
        + _support_lines(g)
        + _stability_lines(g)
        + [f"  warning: {w}" for w in g.penetration_warnings()]
        + ([f"  {fr.RESULTS[g.solution.result]}"] if g.status in ("failed", "unstable") else [])
    )


def _print_short_of_force(g, gs) -> None:
    """Where the closing stopped when a failed grasp fell short of the actuator force asked
    (nothing when it was met, or when the grasp holds the closing instead)."""
    short = gs.actuator_force is not None and (
        float(g.contact.actuator_force) < (1.0 - 1e-6) * gs.actuator_force
    )
    if short and not g.converged:  # (not a failure after the force was met)
        where = f"{num(g.contact.actuator_force)} N at closing {num(g.closing)} mm"
        asked = f"short of the {num(gs.actuator_force)} N asked"
        if g.solution.result == fr.RESULTS.actuator_force_not_reached:
            print(f"  peak actuator force {where}, {asked}")
        else:
            print(f"  the closing path stopped at {where}, {asked}")


# --------------------------------------------------------------------------------------
# The optional analyses of a converged grasp
# --------------------------------------------------------------------------------------


def _release(g, gs, friction):
    """The release trace, printed as the holding force."""
    progress(f"release trace, pull steps of {num(gs.pull_step)} mm")
    trace = fr.release_force(g, step=gs.pull_step, friction=friction)
    mu = float(g.finger.contact.friction) if friction is None else friction
    print(
        f"  holding force     {num(trace.peak)} N at pull {num(trace.peak_pull)} mm, "
        f"friction mu = {mu:g} ({trace.message})"
    )
    return trace


def _rigid_estimate(g):
    """The rigid-contact estimate, printed as its table (None, and the reason printed,
    when it could not be made)."""
    progress("rigid-contact estimate: the grasp at 4 and 16 x its penalty stiffnesses")
    try:
        rigid = fr.rigid_contact_estimate(g)
    except RuntimeError as error:
        print(f"  rigid-contact estimate: {error}")
        return None
    print("  rigid-contact estimate (extrapolated in the penalty stiffness):")
    print("\n".join("    " + line for line in rigid.lines()))
    return rigid


# --------------------------------------------------------------------------------------
# grasp
# --------------------------------------------------------------------------------------


def grasp_command(args) -> int:
    """`finray grasp`: solve the grasp of a finger file with [[objects]] and [grasp]."""
    rtol = resolution_rtol(args)
    finger, settings = fio.load_finger(args.finger)
    if settings.grasp is None:
        raise UserError(f"{args.finger} has no [grasp] table (closing or actuator_force)")
    check_grasp_objects(args.finger, finger, settings)  # (naming the file and the key)
    gs = settings.grasp
    how = (
        f"closing {num(gs.closing)} mm"
        if gs.actuator_force is None
        else f"actuator force {num(gs.actuator_force)} N"
    )
    compiling("contact solver", "for this grasp")
    follows = "actuator force" if gs.actuator_force is None else "closing"
    print(f"grasp: {how} held, the {follows} follows")
    progress(f"grasp, {how}")
    t0 = time.perf_counter()
    g = fr.grasp(finger, **gs.grasp_kwargs())
    print("\n".join(_grasp_lines(g, settings.name or args.finger)))
    _print_short_of_force(g, gs)
    print(f"  solved in {time.perf_counter() - t0:.2f} s")
    friction = args.friction if args.friction is not None else gs.friction
    release = (args.release or gs.release) and g.converged
    trace = _release(g, gs, friction) if release else None
    rigid = _rigid_estimate(g) if args.rigid_estimate and g.converged else None
    check = None
    if rtol is not None and g.converged:
        run = lambda: fr.check_grasp_resolution(g, rtol=rtol)
        check = report_resolution(g.integrator.steps, run)
    if args.out:
        out = grasp_to_dict(g, trace)
        if rigid is not None:
            out["rigid_estimate"] = rigid_estimate_to_dict(rigid)
        if check is not None:
            out["resolution"] = check.to_dict()
        fio.write_json(args.out, out)
        print(f"wrote {args.out}")
    if args.plot:
        save_figure(grasp_figure([g], [settings.name or "grasp"]), args.plot)
        print(f"wrote {args.plot}")
    return EXIT_OK if g.converged else EXIT_FAILED
