"""The paper's studies on the `finray` command line: `compare` (original vs modified
adaptor, the paper's Fig. 4 and Table 2) and `clamp-study` (the best back-beam clamp
length against object size, Fig. 5)."""

import os
import time

import numpy as np

from . import io as fio
from . import studies
from ._cli_args import STUDY_CLOSING, STUDY_SUPPORT
from ._cli_common import (
    DEMO_FINGER,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    UserError,
    compiling,
    engine_from_args,
    engine_notice,
    num,
    percent,
    progress,
    say_interrupted,
    table,
)
from .plot import clamp_study_figure, grasp_figure, release_comparison_figure, save_figure
from .report import comparison_to_dict


def _study_finger(path):
    if path is None:
        finger, _ = fio.load_packaged_finger(DEMO_FINGER)
    else:
        finger, _ = fio.load_finger(path)
    return finger


# --------------------------------------------------------------------------------------
# compare
# --------------------------------------------------------------------------------------


def _placed_rows(cmp, paper_gain) -> list[list[str]]:
    if cmp.placed is None:
        return []
    height, o, m = cmp.placed
    return [
        [
            f"  object at {height:g} mm (N)",
            num(o.contact.normal_force),
            num(m.contact.normal_force),
            percent(cmp.placed_gain),
            f"+{paper_gain:.0f} % (simulated)",
        ]
    ]


def _placed_note(cmp) -> list[str]:
    if cmp.placed is None:
        return []
    return [
        f"  The paper's gain is what this model gives with the object {studies.ABOVE_SUPPORT:g} mm "
        "above the end of the",
        f"  support (here at {cmp.placed[0]:g} mm). At 60 mm the object presses on crossbeams "
        "the support backs.",
    ]


def comparison_lines(cmp) -> list[str]:
    """An adaptor comparison (`studies.Comparison`) as a table beside the paper's figures."""
    o, m = cmp.original.contact, cmp.modified.contact
    rows = [
        [
            "contact force (N)",
            num(o.normal_force),
            num(m.normal_force),
            percent(cmp.contact_force_gain),
            f"+{studies.PAPER_CONTACT_FORCE_GAIN:.0f} % (simulated)",
        ],
        *_placed_rows(cmp, studies.PAPER_CONTACT_FORCE_GAIN),
        ["contact length (mm)", num(o.contact_length), num(m.contact_length), "", ""],
        ["crossbeam force x (N)", num(o.crossbeam_force[0]), num(m.crossbeam_force[0]), "", ""],
        ["crossbeam force z (N)", num(o.crossbeam_force[2]), num(m.crossbeam_force[2]), "", ""],
    ]
    lo, hi = studies.PAPER_RELEASE_RANGE
    for d, (a, b) in cmp.release.items():
        rows.append(
            [
                f"holding force, {d:g} mm (N)",
                num(a.peak),
                num(b.peak),
                percent(cmp.release_gain(d)),
                f"+{lo:.0f} to +{hi:.0f} % (measured)",
            ]
        )
    head = [
        "18 mm object, closing " + f"{cmp.closing:g} mm",
        "original",
        "modified",
        "change",
        "paper",
    ]
    return table(head, rows) + _placed_note(cmp)


def compare_command(args) -> int:
    """`finray compare`: the two adaptors' grasps and release forces, resumable."""
    finger = _study_finger(args.finger)
    print(
        f"Original vs modified adaptor, Finger-1 on cylinders: both grasps close by the same "
        f"{args.closing:g} mm (the closing is held equal; the actuator force follows); "
        f"holding forces with friction mu = {args.friction:g}"
    )
    t0 = time.perf_counter()
    kept = os.path.join(args.out, "compare_record.json")
    compiling("contact solver", "for the two adaptors' grasps")
    try:
        cmp = studies.compare_adaptors(
            finger, closing=args.closing, friction=args.friction, progress=progress, record=kept
        )
    except KeyboardInterrupt:
        say_interrupted(kept, "grasps and release traces", counted=False)
        return EXIT_INTERRUPTED
    print("\n".join(comparison_lines(cmp)))
    print(
        f"({time.perf_counter() - t0:.1f} s; holding force: the peak of the release trace "
        f"with friction mu = {args.friction:g}, --friction 0 gives the frictionless, geometric "
        "one; see docs/grasping.md for the model and why our figures differ from the paper's)"
    )
    os.makedirs(args.out, exist_ok=True)
    png = os.path.join(args.out, "compare.png")
    save_figure(grasp_figure([cmp.original, cmp.modified], ["original", "modified"]), png)
    wrote = [png]
    if cmp.release:  # (the release traces: holding force against pull distance)
        wrote.append(os.path.join(args.out, "compare_release.png"))
        save_figure(
            release_comparison_figure(cmp.release, friction=args.friction, closing=cmp.closing),
            wrote[-1],
        )
    js = os.path.join(args.out, "compare.json")
    fio.write_json(js, comparison_to_dict(cmp))
    print("\n".join(f"wrote {p}" for p in (*wrote, js, kept)))
    ok = cmp.original.converged and cmp.modified.converged
    return EXIT_OK if ok else EXIT_FAILED


# --------------------------------------------------------------------------------------
# clamp-study
# --------------------------------------------------------------------------------------


def _print_clamp_tables(st, args) -> None:
    """The study's tables, one per measured quantity, each row an object size and each
    column a clamp length; the table the best clamp length is picked by ends in it."""
    held = (
        f"closing {args.closing:g} mm"
        if args.actuator_force is None
        else f"actuator force {args.actuator_force:g} N"
    )
    tables = [("contact force (N)", st.normal_force)]
    if args.actuator_force is not None:
        tables.append(("closing (mm)", st.closing))
    if args.holding:
        tables.append((f"holding force (N, mu = {args.friction:g})", st.holding_force))
    head = ["object (mm)"] + [f"l_c={x:g}" for x in st.clamp_lengths]
    for k, (what, values) in enumerate(tables):
        best = values is st.force  # (the table the best clamp length is picked by)
        rows = [
            [f"{d:g}"] + [num(x) for x in row] + ([num(b)] if best else [])
            for d, row, b in zip(st.diameters, values, st.best, strict=True)
        ]
        print(
            ("\n" if k else "")
            + f"{what} of the modified adaptor, support up to {st.support_length:g} mm, {held}"
        )
        print("\n".join(table(head + (["best l_c"] if best else []), rows)))


def clamp_study_command(args) -> int:
    """`finray clamp-study`: the modified adaptor's grasps over clamp lengths and object
    sizes, resumable."""
    if args.friction and not args.holding:
        raise UserError("--friction applies to the release traces: add --holding")
    if args.actuator_force is not None and args.closing != STUDY_CLOSING:
        raise UserError(
            f"--closing {args.closing:g} and --actuator-force {args.actuator_force:g}: give one "
            "(the actuator force sets each grasp's closing)"
        )
    finger = _study_finger(args.finger)
    grid = {}
    if args.diameters is not None:
        grid["diameters"] = args.diameters
    if args.clamp_lengths is not None:
        grid["clamp_lengths"] = args.clamp_lengths
    engine = engine_from_args(args)
    js = os.path.join(args.out, "clamp_study.json")
    engine_notice(engine, "contact solver")
    if engine.name == "local":
        compiling("contact solver", "for the study's grasps")
    try:
        st = studies.clamp_study(
            finger,
            **grid,
            support_length=STUDY_SUPPORT,
            closing=args.closing,
            actuator_force=args.actuator_force,
            holding=args.holding,
            friction=args.friction,
            progress=progress,
            record=js,
            engine=engine,
        )
    except KeyboardInterrupt:
        say_interrupted(js, "grasps", counted=False)
        return EXIT_INTERRUPTED
    _print_clamp_tables(st, args)
    if not np.all(np.isfinite(st.normal_force)):
        print("(nan: that grasp did not converge; the '...' line of its solve says why)")
    png = os.path.join(args.out, "clamp_study.png")
    save_figure(clamp_study_figure(st), png)
    print(f"wrote {png}\nwrote {js}")
    return EXIT_OK
