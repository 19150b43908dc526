"""How the number and the angle of the crossbeams change the grip.

Finger-1 (examples/finger1.toml, assumed dimensions, original adaptor) is rebuilt with N
evenly spaced crossbeams over the same span of the front beam (the file's crossbeam
pattern with another count), and all crossbeams are turned to one angle a to the
horizontal (design value `crossbeams.angle`, positive: back end higher). For every
(N, a):

* the contact force F on an 18 mm cylinder at a fixed closing (a grasp), and dF/da from
  `finray_jax.regrasp` in forward mode (implicit function theorem), checked against a
  central finite difference at a = 0;
* the tip stiffness under the paper's Fig. 3 load (4 N in +x over s = 75..105 mm):
  4 N / tip dx, all angles of a count in one `solve_batch`.

    .venv/bin/python optimize/crossbeam_count_angle.py --out cb_out [--quick]

Writes OUT/crossbeam_count_angle.csv (one row per design), .json and .png.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _common as cm  # noqa: E402

import finray_jax as fr  # noqa: E402
from finray_jax import studies  # noqa: E402

LOAD_N = 4.0  # the Fig. 3 load's resultant in +x


def set_angle(base, a):
    """Every crossbeam at angle a (rad) to the horizontal."""
    return fr.set_design(base, {"crossbeams.angle": jnp.full(base.n_crossbeams, a)})


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="crossbeam_count_angle", help="output directory")
    p.add_argument("--quick", action="store_true", help="2 counts, 2 angles")
    p.add_argument("--closing", type=float, default=cm.CLOSING, help="mm (default 6)")
    args = p.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    if args.quick:
        counts, angles_deg = [5, 7], [0.0, 10.0]
    else:
        counts, angles_deg = [3, 4, 5, 6, 7, 8], [-15.0, -7.5, 0.0, 7.5, 15.0]
    angles = np.radians(angles_deg)

    rows = []
    k = None
    for n in counts:
        t0 = time.perf_counter()
        loaded = cm.load_finger1(n)  # with the Fig. 3 load
        res = fr.solve_batch(
            loaded,
            {"crossbeams.angle": np.repeat(angles[:, None], n, axis=1)},
            outputs=["tip.dx"],
            chunk_size=len(angles),
        )
        base = studies.with_object(loaded, 18.0)  # loads removed, cylinder in front
        if k is None:  # one contact law for all designs (see clamp_vs_object_size.py)
            k = 1.5 * float(fr.grasp(base, args.closing).stiffness)
            print(f"contact penalty stiffness fixed at {k:.1f} N/mm^2", flush=True)
        base = cm.with_stiffness(base, k)
        ev = cm.ContactForce(set_angle, args.closing)
        for a, a_deg, dx, status in zip(angles, angles_deg, res.outputs["tip.dx"], res.status):
            f, df, ref, pen = ev(base, a)  # grasped from scratch at this angle
            fd = float("nan")
            if a_deg == 0.0:
                h = 1e-4  # rad
                fd = (ev(base, a + h, ref)[0] - ev(base, a - h, ref)[0]) / (2 * h)
            rows.append(
                dict(
                    count=n,
                    angle_deg=a_deg,
                    contact_force_N=f,
                    dF_dangle_N_per_rad=df,
                    dF_dangle_fd_N_per_rad=fd,
                    tip_dx_mm=float(dx),
                    tip_stiffness_N_per_mm=LOAD_N / float(dx),
                    fig3_status=str(status),
                    max_penetration_mm=pen,
                )
            )
        print(
            f"{n} crossbeams: {len(angles)} angles in {time.perf_counter() - t0:.0f} s "
            "(compile included)",
            flush=True,
        )

    print()
    cm.print_table(
        rows,
        {
            "count": "{:d}",
            "angle_deg": "{:+.1f}",
            "contact_force_N": "{:.4f}",
            "dF_dangle_N_per_rad": "{:+.4f}",
            "dF_dangle_fd_N_per_rad": "{:+.4f}",
            "tip_dx_mm": "{:.3f}",
            "tip_stiffness_N_per_mm": "{:.4f}",
            "max_penetration_mm": "{:.4f}",
        },
    )
    cm.write_csv(out / "crossbeam_count_angle.csv", rows)
    cm.write_json(
        out / "crossbeam_count_angle.json",
        dict(
            finger="examples/finger1.toml",
            object_diameter_mm=18.0,
            closing_mm=args.closing,
            fig3_load_N=LOAD_N,
            penalty_stiffness=k,
            counts=counts,
            angles_deg=angles_deg,
            quick=args.quick,
            rows=rows,
            seconds=time.perf_counter() - t_start,
        ),
    )
    _plot(out / "crossbeam_count_angle.png", rows, counts, angles_deg)
    print(
        f"\nwrote {out}/crossbeam_count_angle.csv, .json, .png "
        f"({time.perf_counter() - t_start:.0f} s)"
    )
    return 0


def _plot(path, rows, counts, angles_deg):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 4), layout="constrained")
    axes = fig.subplots(1, 3)
    for n in counts:
        r = [x for x in rows if x["count"] == n]
        a = np.array([x["angle_deg"] for x in r])
        f = np.array([x["contact_force_N"] for x in r])
        s = np.array([x["dF_dangle_N_per_rad"] for x in r]) * np.pi / 180.0
        line = axes[0].plot(a, f, marker="o", label=f"{n}")[0]
        for ai, fi, si in zip(a, f, s):  # the gradient as a short tangent
            axes[0].plot(
                [ai - 2, ai + 2],
                [fi - 2 * si, fi + 2 * si],
                color=line.get_color(),
                lw=3,
                alpha=0.4,
            )
        axes[1].plot(a, s, marker="o", color=line.get_color())
        axes[2].plot(
            a, [x["tip_stiffness_N_per_mm"] for x in r], marker="o", color=line.get_color()
        )
    axes[0].set_ylabel("contact force, 18 mm object (N)")
    axes[0].legend(title="crossbeams", fontsize="small")
    axes[1].set_ylabel("dF/d(angle) (N/deg)")
    axes[2].set_ylabel("tip stiffness, Fig. 3 load (N/mm)")
    for ax in axes:
        ax.set_xlabel("crossbeam angle (deg)")
        ax.grid(True, lw=0.4, alpha=0.5)
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
