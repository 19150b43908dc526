"""Best back-beam clamp length l_c against object size (the paper's clamp question).

Finger-1 (examples/finger1.toml, assumed dimensions) with the modified adaptor (front base
pinned, back beam clamped over l_c, rigid support behind it up to l_s) closes by a fixed
displacement on cylinders of several diameters. For each diameter the clamp length that
maximises the contact force is found by gradient ascent: the derivative dF/dl_c comes
from `finray_jax.regrasp` in forward mode (implicit function theorem), steps are
projected on [0, l_s - margin] with a secant (Newton) step once the slope has turned, and
each diameter starts from the previous diameter's optimum. A coarse scan of l_c, each
point grasped from scratch, checks the result.

    .venv/bin/python optimize/clamp_vs_object_size.py --out clamp_out [--quick]

Writes OUT/clamp_vs_object_size.csv (one row per diameter), OUT/clamp_vs_object_size.json
(the scan, the gradient iterations, settings) and OUT/clamp_vs_object_size.png.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _common as cm  # noqa: E402

import finray_jax as fr  # noqa: E402
from finray_jax import studies  # noqa: E402


def set_clamp(base, lc):
    return fr.set_design(base, {"adaptor.back_clamp_length": lc})


def ascend(ev, base, x0, lo, hi, *, step0=5.0, max_step=20.0, tol=0.05, max_iter=12):
    """Maximise F(x) on [lo, hi] from x0: projected gradient steps of growing length, a
    secant (Newton) step on dF/dx where the slope falls, halving after a step that does not
    increase F. Returns the best point and the iterations."""
    x = float(np.clip(x0, lo, hi))
    f, g, ref, pen = ev(base, x)
    log = [dict(x=x, force=f, slope=g, accepted=True)]
    prev, step = None, step0
    for _ in range(max_iter):
        dx = step if g > 0 else -step
        if prev is not None and x != prev[0]:
            curv = (g - prev[1]) / (x - prev[0])
            if curv < 0:  # concave there: Newton on the slope
                dx = float(np.clip(-g / curv, -step, step))
        x_new = float(np.clip(x + dx, lo, hi))
        if abs(x_new - x) < tol:
            break  # at a bound with the slope pointing out, or converged
        f_new, g_new, ref_new, pen_new = ev(base, x_new, ref)
        ok = f_new >= f
        log.append(dict(x=x_new, force=f_new, slope=g_new, accepted=ok))
        if ok:
            prev = (x, g)
            x, f, g, ref, pen = x_new, f_new, g_new, ref_new, pen_new
            step = min(2.0 * step, max_step)
        else:
            prev = (x_new, g_new)
            step = 0.5 * abs(x_new - x)
            if step < tol:
                break
    return dict(x=x, force=f, slope=g, max_penetration=pen), log


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="clamp_vs_object_size", help="output directory")
    p.add_argument("--quick", action="store_true", help="2 diameters, 3 scan points")
    p.add_argument("--closing", type=float, default=cm.CLOSING, help="mm (default 6)")
    p.add_argument("--support-length", type=float, default=60.0, help="l_s (mm, default 60)")
    args = p.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    ls = args.support_length
    lo, hi = 0.0, ls - 5.0
    if args.quick:
        diameters = [18.0, 35.0]
        scan = np.linspace(lo, hi, 3)
        max_iter = 4
    else:
        diameters = [10.0, 18.0, 26.0, 35.0, 45.0, 60.0]
        scan = np.linspace(lo, hi, 12)
        max_iter = 12
    finger = cm.load_finger1()
    adaptor = fr.Adaptor(front_base=fr.PinnedBase(), back_clamp_length=20.0, support_length=ls)

    def base_for(d, k=None):
        b = studies.with_adaptor(studies.with_object(finger, d), adaptor)
        return b if k is None else cm.with_stiffness(b, *k)

    # One contact law for every design: the stiffness grasp() picks for the first object
    # at l_c = 20 mm, times 1.5 (headroom for the stiffer designs).
    g = fr.grasp(base_for(diameters[0]), args.closing)
    k = (1.5 * float(g.stiffness), 1.5 * float(g.support_stiffness))
    print(
        f"contact penalty stiffness fixed at {k[0]:.1f} N/mm^2 (the support's {k[1]:.1f}); "
        f"closing {args.closing} mm, "
        f"support to l_s = {ls} mm, l_c in [{lo}, {hi}] mm"
    )
    ev = cm.ContactForce(set_clamp, args.closing)

    rows, record = [], []
    x_start = 20.0
    for d in diameters:
        base = base_for(d, k)
        t0 = time.perf_counter()
        best, log = ascend(ev, base, x_start, lo, hi, max_iter=max_iter)
        t_grad = time.perf_counter() - t0
        t0 = time.perf_counter()
        scan_f = np.array([ev(base, x)[0] for x in scan])  # each grasped from scratch
        t_scan = time.perf_counter() - t0
        j = int(np.argmax(scan_f))
        row = dict(
            diameter_mm=d,
            lc_gradient_mm=best["x"],
            force_gradient_N=best["force"],
            slope_at_optimum_N_per_mm=best["slope"],
            evaluations=len(log),
            lc_scan_mm=float(scan[j]),
            force_scan_N=float(scan_f[j]),
            gain_over_scan_N=best["force"] - float(scan_f[j]),
            max_penetration_mm=best["max_penetration"],
            seconds_gradient=t_grad,
            seconds_scan=t_scan,
        )
        rows.append(row)
        record.append(dict(diameter_mm=d, iterations=log, scan_force_N=scan_f.tolist()))
        print(
            f"{d:g} mm: gradient l_c = {best['x']:.2f} mm, F = {best['force']:.4f} N "
            f"({len(log)} evaluations, {t_grad:.0f} s); scan best l_c = {scan[j]:.2f} mm, "
            f"F = {scan_f[j]:.4f} N ({t_scan:.0f} s)",
            flush=True,
        )
        x_start = best["x"]

    print()
    cm.print_table(
        rows,
        {
            "diameter_mm": "{:.0f}",
            "lc_gradient_mm": "{:.2f}",
            "force_gradient_N": "{:.4f}",
            "slope_at_optimum_N_per_mm": "{:+.4f}",
            "evaluations": "{:d}",
            "lc_scan_mm": "{:.2f}",
            "force_scan_N": "{:.4f}",
            "gain_over_scan_N": "{:+.2e}",
            "max_penetration_mm": "{:.4f}",
        },
    )
    cm.write_csv(out / "clamp_vs_object_size.csv", rows)
    cm.write_json(
        out / "clamp_vs_object_size.json",
        dict(
            finger="examples/finger1.toml",
            closing_mm=args.closing,
            support_length_mm=ls,
            clamp_bounds_mm=[lo, hi],
            penalty_stiffness=k[0],
            support_penalty_stiffness=k[1],
            quick=args.quick,
            scan_clamp_lengths_mm=scan.tolist(),
            diameters=record,
            rows=rows,
            grasps_from_scratch=ev.grasps,
            regrasp_solves=ev.solves,
            seconds=time.perf_counter() - t_start,
        ),
    )
    _plot(out / "clamp_vs_object_size.png", scan, record, rows)
    print(
        f"\nwrote {out}/clamp_vs_object_size.csv, .json, .png "
        f"({time.perf_counter() - t_start:.0f} s)"
    )
    return 0


def _plot(path, scan, record, rows):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2), layout="constrained")
    ax, ax2 = fig.subplots(1, 2)
    for rec, row in zip(record, rows):
        line = ax.plot(
            scan, rec["scan_force_N"], marker="o", ms=3, label=f"{rec['diameter_mm']:g} mm"
        )[0]
        ax.plot(
            [row["lc_gradient_mm"]],
            [row["force_gradient_N"]],
            marker="*",
            ms=13,
            color=line.get_color(),
            mec="k",
        )
    ax.set_xlabel("back-beam clamp length l_c (mm)")
    ax.set_ylabel("contact force (N)")
    ax.set_title("scan (lines) and gradient optimum (stars)")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize="small", title="object")
    d = [r["diameter_mm"] for r in rows]
    ax2.plot(d, [r["lc_scan_mm"] for r in rows], marker="s", label="coarse scan")
    ax2.plot(
        d, [r["lc_gradient_mm"] for r in rows], marker="*", ms=10, ls="--", label="gradient ascent"
    )
    ax2.set_xlabel("object diameter (mm)")
    ax2.set_ylabel("best l_c (mm)")
    ax2.grid(True, lw=0.4, alpha=0.5)
    ax2.legend(fontsize="small")
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
