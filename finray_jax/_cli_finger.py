"""One finger file on the `finray` command line: the printed summary of a solve, the
resolution check, the checks of a grasp file's objects, and the `limit` and `validate`
commands."""

import time

import numpy as np

import finray_jax as fr

from . import io as fio
from . import optimize_file
from . import sweep as fsweep
from ._cli_common import (
    EXIT_FAILED,
    EXIT_OK,
    UserError,
    compiling,
    count,
    num,
    shown_path,
    table,
)
from ._finger import loads_are_zero
from ._grasp_inputs import check_objects, unit_direction
from .plot import save_solution_figure

# --------------------------------------------------------------------------------------
# Printing a solve
# --------------------------------------------------------------------------------------


def summary(sol, finger, settings, source: str, elapsed: float | None = None) -> str:
    """A solve's status, tip displacement and base reactions, as printed by `solve`."""
    lines = []
    name = f"{settings.name} ({source})" if settings.name else source
    lines.append(f"finger: {name}; {finger.n_crossbeams} crossbeams; mode {sol.mode}")
    timing = f", {elapsed:.1f} s" if elapsed is not None else ""
    lines.append(
        f"status: {sol.status} (load factor {num(sol.load_factor, 6)}, {int(sol.iterations)} "
        f"Newton iterations, max residual {num(sol.max_residual, 2)}{timing})"
    )
    if sol.status == "beyond_limit_load":
        lines.append(
            "  the load lies beyond the finger's limit (fold) load; the state below is the "
            f"equilibrium at the fold, load factor {num(sol.load_factor, 6)}"
        )
    elif sol.status == "failed":
        lines.append(f"  {fr.RESULTS[sol.result]}")
    d = np.asarray(sol.tip.displacement, dtype=np.float64)
    rot = np.asarray(sol.tip.rotation, dtype=np.float64)
    lines.append(
        f"tip displacement: dx = {num(d[0])} mm, dy = {num(d[1])} mm, dz = {num(d[2])} mm; "
        f"rotation about y = {num(np.degrees(rot[1]))} deg"
    )
    lines.append("reactions (wrench the adaptor applies at each base; moment about the base):")
    spatial = sol.mode == "spatial"
    head = ["beam", "Fx (N)", "Fz (N)", "My (N mm)"]
    if spatial:
        head = ["beam", "Fx (N)", "Fy (N)", "Fz (N)", "Mx (N mm)", "My (N mm)", "Mz (N mm)"]
    rows = []
    for beam, r in (("front", sol.reactions_front), ("back", sol.reactions_back)):
        F, M = np.asarray(r.force, dtype=np.float64), np.asarray(r.moment, dtype=np.float64)
        vals = [*F, *M] if spatial else [F[0], F[2], M[1]]
        rows.append([beam] + [num(x) for x in vals])
    lines += table(head, rows)
    return "\n".join(lines)


def crossbeam_table(sol, finger) -> list[str]:
    """Per crossbeam: attachment points, axial force (+ tension) and the largest |m_y|."""
    if finger.n_crossbeams == 0:
        return []
    head = ["crossbeam", "front_s (mm)", "back_s (mm)", "axial n.d3 (N)", "max |m_y| (N mm)"]
    rows = []
    cb = finger.crossbeams
    for i in range(finger.n_crossbeams):
        b = sol.crossbeam(i)
        R = np.asarray(b.frame, dtype=np.float64)
        n = np.asarray(b.force, dtype=np.float64)
        axial = np.einsum("ni,ni->n", n, R[:, :, 2])
        mid = len(axial) // 2
        my = np.max(np.abs(np.asarray(b.moment, dtype=np.float64)[:, 1]))
        rows.append([str(i), num(cb.front_s[i]), num(cb.back_s[i]), num(axial[mid]), num(my)])
    return [
        "crossbeams (numbered from 0; axial force at mid-length, + = tension):",
        *table(head, rows),
    ]


# --------------------------------------------------------------------------------------
# Resolution check
# --------------------------------------------------------------------------------------


def check_resolution(finger, settings, sol, rtol):
    """The step-doubling check of a converged solve (None when not asked for)."""
    if rtol is None:
        return None
    if sol.status != "converged":
        print("resolution: not checked (the solve did not converge)")
        return None
    kwargs = settings.solve_kwargs()
    kwargs["mode"] = sol.mode
    run = lambda: fr.check_resolution(finger, rtol=rtol, solution=sol, **kwargs)
    return report_resolution(sol.steps, run)


def report_resolution(n, run):
    """Announce the solves at 2n and 4n steps, run the check, print its verdict."""
    print(f"resolution: solving at {2 * n} and {4 * n} steps per segment ...")
    check = run()
    print(f"resolution: {check.message}")
    return check


# --------------------------------------------------------------------------------------
# A grasp file's objects
# --------------------------------------------------------------------------------------


def check_grasp_objects(path, finger, settings) -> str | None:
    """The checks `fr.grasp` makes of a finger file's objects before it solves (a
    non-zero closing direction; objects within the finger's reach and ahead of it), run
    without solving when the file has a [grasp] table. Errors name the file and the key.
    Returns what was checked, for a summary line (None: no [grasp], nothing to check:
    objects in a file without one are obstacles of a loaded solve, where any side of the
    finger is fine)."""
    gs = settings.grasp
    if gs is None:
        return None
    if not finger.objects:
        raise UserError(
            f"{path}: grasp: a [grasp] table needs at least one [[objects]] entry to close the "
            "finger on"
        )
    try:
        w = unit_direction(gs.direction, "grasp.direction")
        check_objects(finger, w)
    except fr.FingerError as e:
        raise UserError(f"{path}: {e}") from None
    n = len(finger.objects)
    along = f"closing along [{w[0]:g}, {w[1]:g}]"
    return f"{n} object{'s' if n > 1 else ''} ahead and in reach, {along}"


# --------------------------------------------------------------------------------------
# limit
# --------------------------------------------------------------------------------------


def _print_limit_loads(finger, factor, where) -> None:
    """Each load of the finger times the limit factor, one line each."""
    for j, load in enumerate(finger.loads):
        if isinstance(load, fr.PointLoad):
            F = np.asarray(load.force) * factor
            what = f"point load at s = {num(load.s)} mm"
        else:
            F = np.asarray(load.total_force) * factor
            s0, s1 = np.asarray(load.s_range)
            what = f"distributed load over s = {num(s0)}..{num(s1)} mm, total"
        beam = {0: "front", 1: "back"}.get(load.beam, f"crossbeam {load.beam - 2}")
        print(
            f"  loads[{j}] ({beam} beam, {what}) {where}: ({num(F[0])}, {num(F[1])}, {num(F[2])}) N"
        )


def limit_command(args) -> int:
    """`finray limit`: the fold load factor on a finger file's loads."""
    finger, settings = fio.load_finger(args.finger)
    if not finger.loads:
        raise UserError(f"{args.finger}: no [[loads]]: the limit load is a factor on the loads")
    if loads_are_zero(finger):
        raise UserError(f"{args.finger}: every load is zero: no factor on them can fold the finger")
    kwargs = settings.solve_kwargs()
    if args.mode is not None:
        kwargs["mode"] = args.mode
    compiling("limit-load search")
    t0 = time.perf_counter()
    lim = fr.limit_load(finger, **kwargs)
    factor = float(lim.load_factor)
    elapsed = time.perf_counter() - t0
    found = bool(lim.found)
    name = f"{settings.name} ({args.finger})" if settings.name else args.finger
    print(f"finger: {name}; mode {lim.solution.mode}")
    if found:
        print(f"limit load factor: {num(factor, 6)} ({elapsed:.1f} s)")
    else:
        steps = ""
        if lim.solution.result == fr.RESULTS.continuation_steps_exhausted:
            steps = f" after {kwargs['options'].max_continuation_steps} arc-length steps"
        print(
            f"no limit load found: continuation stopped at load factor {num(factor, 6)}{steps} "
            f"without a fold ({elapsed:.1f} s). {lim.solution.message}"
        )
    _print_limit_loads(
        finger, factor, "at the limit" if found else "where the continuation stopped"
    )
    sol = lim.solution
    d = np.asarray(sol.tip.displacement, dtype=np.float64)
    print(
        f"equilibrium there: tip dx = {num(d[0])} mm, dz = {num(d[2])} mm, rotation about y = "
        f"{num(np.degrees(float(sol.tip.rotation[1])))} deg"
    )
    if args.out:
        fio.write_json(args.out, fio.limit_to_dict(lim, finger, settings=settings))
        print(f"wrote {args.out}")
    if args.plot:
        save_solution_figure(
            sol,
            finger.scale_loads(factor),
            args.plot,
            title=f"{settings.name or args.finger} at the limit load",
        )
        print(f"wrote {args.plot}")
    return EXIT_OK if found else EXIT_FAILED


# --------------------------------------------------------------------------------------
# validate
# --------------------------------------------------------------------------------------


def _study_kind(path) -> str | None:
    """The kind of a study file ("sweep" or "optimize": a top-level `finger = "base.toml"`), else
    None (a finger file, or a file the finger reader reports on)."""
    import tomllib

    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except (OSError, tomllib.TOMLDecodeError):
        return None
    if not isinstance(doc.get("finger"), str):
        return None
    return "optimize" if "objective" in doc or "optimizer" in doc else "sweep"


def _validate_study(path, kind) -> str:
    """Read a sweep or optimisation file (its base finger too) and say what it holds."""
    if kind == "sweep":
        sw = fsweep.load_sweep(path)
        what = (
            f"sweep of {count(sw.size, 'design')} ({sw.sampling}) over {', '.join(sw.names)}; "
            f"{count(len(sw.outputs), 'output')}, mode {sw.mode}"
        )
        return f"{path}: OK: {what}; base finger {shown_path(sw.finger_path)}"
    pb = optimize_file.load_optimize(path)
    names = ", ".join(d.name for d in pb.design)
    what = (
        f"optimise {pb.objective} over {names}; {pb.optimizer}, {count(pb.iterations, 'iteration')}"
    )
    return f"{path}: OK: {what}; base finger {shown_path(pb.finger_path)}"


def validate_command(args) -> int:
    """`finray validate`: read a finger, sweep or optimisation file and say what it holds."""
    kind = _study_kind(args.finger)
    if kind is not None:
        print(_validate_study(args.finger, kind))
        return EXIT_OK
    finger, settings = fio.load_finger(args.finger)
    grasp = check_grasp_objects(args.finger, finger, settings)
    name = f" ({settings.name})" if settings.name else ""
    print(
        f"{args.finger}{name}: OK: {count(finger.n_crossbeams, 'crossbeam')}, "
        f"{count(len(finger.loads), 'load')}, mode {settings.mode}"
        + (f"; grasp: {grasp}" if grasp else "")
    )
    return EXIT_OK
