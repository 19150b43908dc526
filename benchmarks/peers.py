"""ref-A side by side with the tools a user would pick instead.

Solves the shared ref-A cases L1, L2, L3 with
  * finray_jax, planar and 3-D, cold (from the undeformed guess) and warm (init = the
    previous Solution, after a 1 % thicker back beam): steady-state times after compile,
    medians of repeats, jax.block_until_ready;
  * openseespy: the corotational frame of tests/reference/opensees_ref_a.py (the same
    builder), on the coarsest mesh of h = 5, 2.5, 1.25 mm that agrees with finray_jax to
    0.5 % in tip displacement, with the fewest load steps (1, 2, 5, ...) that converge;
  * PyElastica: benchmarks/elastica_procedure.py (element size 1.25 mm, 343 elements),
    relaxed by damping within a wall-time budget per case (180 s) or until the tip moves
    by less than 1e-5 of itself per 2500 steps; the time at which its tip enters (and
    stays within) 0.5 % of finray_jax's is reported;
  * SciPy: benchmarks/scipy_procedure.py, the paper's single shooting with RK4 and
    scipy.optimize.root (hybr, finite-difference Jacobian) with load stepping.
Agreement is |tip_peer - tip_finray| / |tip_finray| on the tip displacement (dx, dz),
finray_jax planar being the reference.

Prints a table and writes benchmarks/results/peers.json.

Run:  taskset -c 1 .venv/bin/python benchmarks/peers.py [--quick]
      (--quick: fewer repeats, budgets of 60 s per PyElastica case and 30 s per SciPy
      solve; a peer that does not finish in its budget is reported with how far it got)
"""

import argparse
import json
import pathlib
import statistics
import sys
import time

import equinox as eqx
import jax
import numpy as np
from _common import machine, median_time, pin_to_one_core, write

import finray_jax as fr

# Compile times are not reported here (solve.py and scaling.py do that): keep compiled
# solvers between runs of this script.
jax.config.update(
    "jax_compilation_cache_dir", str(pathlib.Path.home() / ".cache" / "finray_jax_bench")
)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "reference"))
CASES = ("L1", "L2", "L3")
TOL = 5e-3  # agreement asked of every peer: 0.5 % in tip displacement


def rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ----------------------------------------------------------------------------- finray_jax
@eqx.filter_jit
def _solve(finger, init, topo, mode):
    return fr.solve_finger(finger, mode=mode, topology=topo, init=init)


def thicker_back(finger):
    return eqx.tree_at(lambda f: f.back.thickness, finger, finger.back.thickness * 1.01)


def finray_rows(repeats):
    rows = {}
    for mode in ("planar", "spatial"):
        for case in CASES:
            finger = fr.ref_finger_a(case)
            topo = fr.topology_of(finger, mode)
            t0 = time.perf_counter()
            sol = jax.block_until_ready(_solve(finger, None, topo, mode))
            first = time.perf_counter() - t0
            reps = repeats if mode == "planar" else max(3, repeats // 3)
            cold, n_cold = median_time(
                lambda f=finger, t=topo, m=mode: jax.block_until_ready(_solve(f, None, t, m)),
                reps,
                0.3,
            )
            thick = thicker_back(finger)
            wsol = jax.block_until_ready(_solve(thick, sol, topo, mode))
            warm, n_warm = median_time(
                lambda f=thick, s=sol, t=topo, m=mode: jax.block_until_ready(_solve(f, s, t, m)),
                reps,
                0.3,
            )
            tip = np.asarray(sol.tip.displacement)[[0, 2]]
            rows[(mode, case)] = {
                "case": case,
                "mode": mode,
                "status": sol.status,
                "first_call_s": first,
                "cold_s": cold,
                "warm_s": warm,
                "repeats": [n_cold, n_warm],
                "iterations_cold": int(sol.iterations),
                "iterations_warm": int(wsol.iterations),
                "tip": tip.tolist(),
                "warm_tip": np.asarray(wsol.tip.displacement)[[0, 2]].tolist(),
            }
            print(
                f"finray_jax {mode:8s} {case}: cold {1e3 * cold:9.2f} ms ({int(sol.iterations)} it)"
                f"  warm {1e3 * warm:8.2f} ms  tip {tip}",
                flush=True,
            )
    ref = json.loads((ROOT / "tests" / "data" / "ref_a_opensees.json").read_text())["k_5_6"]
    for case in CASES:
        fine = ref[case]["tip"]
        rows[("planar", case)]["agreement_vs_fine_opensees_2432_el"] = rel(
            rows[("planar", case)]["tip"], (fine["dx"], fine["dz"])
        )
        rows[("spatial", case)]["agreement_vs_planar"] = rel(
            rows[("spatial", case)]["tip"], rows[("planar", case)]["tip"]
        )
    return rows


# ----------------------------------------------------------------------------- openseespy
def opensees_solve(h, case, nsteps, tol=1e-8):
    """Build ref-A on mesh h and solve `case` in nsteps load steps (None if no
    convergence). The builder is tests/reference/opensees_ref_a.py."""
    import opensees_ref_a as osr
    import openseespy.opensees as ops

    fg = osr.Finger(h, 5.0 / 6.0)
    fg.apply_pattern(case)
    osr.static_analysis(("LoadControl", 1.0 / nsteps), tol=tol)
    for _ in range(nsteps):
        if ops.analyze(1) != 0:
            return None, fg
    return np.array([ops.nodeDisp(fg.tip, 1), ops.nodeDisp(fg.tip, 2)]), fg


def opensees_rows(ref_tips, repeats):
    import opensees_ref_a as osr

    def fewest_steps(h, case):
        for n in (1, 2, 5, 10, 20, 50, 100):
            tip, fg = opensees_solve(h, case, n)
            if tip is not None:
                return n, tip, fg
        raise RuntimeError(f"openseespy: {case} h={h} did not converge")

    meshes = {}
    chosen = None
    for h in (5.0, 2.5, 1.25):
        per = {}
        for case in CASES:
            n, tip, fg = fewest_steps(h, case)
            per[case] = {
                "load_steps": n,
                "tip": tip.tolist(),
                "agreement": rel(tip, ref_tips[case]),
                "elements": fg.n_elements,
            }
        meshes[h] = per
        ok = all(p["agreement"] < TOL for p in per.values())
        print(
            f"openseespy h={h}: elements {per['L1']['elements']}, agreement "
            + ", ".join(f"{c} {p['agreement']:.2e}" for c, p in per.items())
            + (" (meets 0.5 %)" if ok else ""),
            flush=True,
        )
        if ok and chosen is None:
            chosen = h
            break
    finer = chosen / 2
    rows = {}
    for h in (chosen, finer):
        for case in CASES:
            n = meshes[chosen][case]["load_steps"] if h == chosen else fewest_steps(h, case)[0]
            t, k = median_time(lambda h=h, c=case, n=n: opensees_solve(h, c, n), repeats, 0.5)
            tip, fg = opensees_solve(h, case, n)
            rows[(h, case)] = {
                "case": case,
                "h_mm": h,
                "elements": fg.n_elements,
                "load_steps": n,
                "solve_s": t,
                "repeats": k,
                "tip": tip.tolist(),
                "agreement": rel(tip, ref_tips[case]),
                "chosen_mesh": h == chosen,
            }
            print(
                f"openseespy h={h} {case}: {1e3 * t:8.1f} ms ({n} load steps, "
                f"{fg.n_elements} el.)  agreement {rows[(h, case)]['agreement']:.2e}",
                flush=True,
            )
    note = (
        "model build + static load-control analysis (Newton, NormDispIncr 1e-8, UmfPack), "
        f"builder {osr.__file__.split('/')[-1]}"
    )
    return rows, chosen, meshes, note


# ----------------------------------------------------------------------------- SciPy
def scipy_rows(ref_tips, budget):
    from scipy_procedure import ShootingModel

    rows = {}
    for case in CASES:
        finger = fr.ref_finger_a(case)
        model = ShootingModel.from_finger(finger)
        runs = [model.solve(budget_s=budget) for _ in range(3 if case == "L1" else 1)]
        sol = runs[-1]
        if not sol.ok:
            rows[case] = {
                "case": case,
                "ok": False,
                "budget_s": budget,
                "load_factor_reached": sol.load_factor,
                "wall_s": sol.seconds,
                "load_levels": sol.load_steps,
                "root_calls": sol.root_calls,
                "residual_evaluations": sol.residual_evaluations,
            }
            print(
                f"SciPy {case}: not finished within {budget:.0f} s (load factor "
                f"{sol.load_factor:.3f} reached, {sol.residual_evaluations} residuals)",
                flush=True,
            )
            continue
        cold = statistics.median(r.seconds for r in runs)
        warm_model = ShootingModel.from_finger(thicker_back(finger))
        wruns = [warm_model.solve(guess=sol.unknowns, budget_s=budget) for _ in range(3)]
        rows[case] = {
            "case": case,
            "ok": sol.ok,
            "budget_s": budget,
            "cold_s": cold,
            "cold_runs": len(runs),
            "load_levels": sol.load_steps,
            "root_calls": sol.root_calls,
            "residual_evaluations": sol.residual_evaluations,
            "seconds_per_residual": sol.seconds / sol.residual_evaluations,
            "warm_s": statistics.median(r.seconds for r in wruns),
            "warm_ok": all(r.ok for r in wruns),
            "warm_root_calls": wruns[-1].root_calls,
            "warm_residual_evaluations": wruns[-1].residual_evaluations,
            "tip": sol.tip_displacement.tolist(),
            "agreement": rel(sol.tip_displacement, ref_tips[case]),
            "unknowns": model.n_unknowns,
            "steps_per_piece": model.steps,
            "method": model.method,
        }
        print(
            f"SciPy {case}: cold {cold:8.2f} s ({sol.load_steps} load levels, "
            f"{sol.residual_evaluations} residuals)  warm {rows[case]['warm_s']:.3f} s  "
            f"agreement {rows[case]['agreement']:.2e}",
            flush=True,
        )
    return rows


# ----------------------------------------------------------------------------- PyElastica
def elastica_rows(ref_tips, budget, dx):
    from elastica_procedure import ElasticaFinger

    # compile PyElastica's numba kernels (cached on disk after the first run) and the
    # joint code paths outside the timed runs
    warm = ElasticaFinger(fr.ref_finger_a("L1"), dx=dx)
    warm.relax(0.0, chunk=20)
    rows = {}
    for case in CASES:
        t0 = time.perf_counter()
        fe = ElasticaFinger(fr.ref_finger_a(case), dx=dx)
        build = time.perf_counter() - t0
        out = fe.relax(budget, reference_tip=ref_tips[case], chunk=2500, tol=TOL, settle=1e-5)
        within = out["within_tol"]
        rows[case] = {
            "case": case,
            "dx_mm": dx,
            "elements": fe.n_elements,
            "build_s": build,
            "budget_s": budget,
            "steps": out["steps"],
            "dt": out["dt"],
            "time_per_step_ms": out["time_per_step_us"] / 1e3,
            "wall_s": out["wall_s"],
            "final_tip": list(out["tip"]),
            "final_agreement": out["rel_diff"],
            "reached_0.5pct_s": None if within is None else within["wall_s"] + build,
            "reached_0.5pct_steps": None if within is None else within["steps"],
            "settled": out["settled"],
            "history": [[round(v, 7) for v in h] for h in out["history"]],
        }
        r = rows[case]
        print(
            f"PyElastica {case}: {fe.n_elements} el., {out['steps']} steps in "
            f"{out['wall_s']:.0f} s ({r['time_per_step_ms']:.2f} ms/step), final agreement "
            f"{out['rel_diff']:.2e}, within 0.5 % after "
            + ("never" if within is None else f"{r['reached_0.5pct_s']:.0f} s"),
            flush=True,
        )
    return rows


# ----------------------------------------------------------------------------- main
def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--elastica-budget",
        type=float,
        default=None,
        help="wall seconds per case (default 240, --quick 60)",
    )
    ap.add_argument("--elastica-dx", type=float, default=1.25)
    ap.add_argument(
        "--scipy-budget",
        type=float,
        default=None,
        help="wall seconds per SciPy cold solve (default 300, --quick 30)",
    )
    ap.add_argument(
        "--skip", default="", help="comma list of peers to skip: opensees,scipy,elastica"
    )
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    cores = pin_to_one_core()
    repeats = 5 if args.quick else 15
    budget = args.elastica_budget or (60.0 if args.quick else 180.0)
    sp_budget = args.scipy_budget or (30.0 if args.quick else 300.0)
    t_start = time.perf_counter()

    fj = finray_rows(repeats)
    ref_tips = {c: fj[("planar", c)]["tip"] for c in CASES}
    base = {c: fj[("planar", c)]["cold_s"] for c in CASES}

    out = {
        "pinned_cores": cores,
        "machine": machine(),
        "quick": args.quick,
        "agreement_metric": "|tip - tip_finray_planar| / |tip_finray_planar| on (dx, dz)",
        "finray_jax": [dict(r) for r in fj.values()],
    }
    if "opensees" not in skip:
        os_rows, chosen, meshes, note = opensees_rows(ref_tips, max(3, repeats // 3))
        out["openseespy"] = {
            "chosen_h_mm": chosen,
            "note": note,
            "mesh_search": {str(h): v for h, v in meshes.items()},
            "rows": list(os_rows.values()),
        }
        for r in os_rows.values():
            r["ratio_to_finray_planar_cold"] = r["solve_s"] / base[r["case"]]
    if "scipy" not in skip:
        sp = scipy_rows(ref_tips, sp_budget)
        for r in sp.values():
            if "cold_s" in r:
                r["ratio_to_finray_planar_cold"] = r["cold_s"] / base[r["case"]]
                r["warm_ratio_to_finray_planar_warm"] = (
                    r["warm_s"] / fj[("planar", r["case"])]["warm_s"]
                )
        out["scipy"] = list(sp.values())
    if "elastica" not in skip:
        el = elastica_rows(ref_tips, budget, args.elastica_dx)
        for r in el.values():
            t = r["reached_0.5pct_s"]
            r["ratio_to_finray_planar_cold"] = None if t is None else t / base[r["case"]]
            r["budget_ratio_to_finray_planar_cold"] = r["wall_s"] / base[r["case"]]
        out["pyelastica"] = list(el.values())
    out["total_seconds"] = time.perf_counter() - t_start

    # ---- table
    print("\nref-A, one core, steady state; ratio = peer / finray_jax planar cold")
    print(f"{'solver':44s} {'case':4s} {'time':>11s} {'ratio':>9s} {'agreement':>10s}")

    def line(name, case, t, ratio, agr):
        ts = "-" if t is None else (f"{1e3 * t:8.2f} ms" if t < 1 else f"{t:8.2f} s ")
        rs = "-" if ratio is None else f"{ratio:8.1f}x"
        ag = "-" if agr is None else f"{agr:.1e}"
        print(f"{name:44s} {case:4s} {ts:>11s} {rs:>9s} {ag:>10s}")

    for case in CASES:
        p, s = fj[("planar", case)], fj[("spatial", case)]
        line(
            "finray_jax planar cold",
            case,
            p["cold_s"],
            1.0,
            p["agreement_vs_fine_opensees_2432_el"],
        )
        line(
            "finray_jax planar warm (1 % design change)",
            case,
            p["warm_s"],
            p["warm_s"] / base[case],
            None,
        )
        line(
            "finray_jax 3-D cold",
            case,
            s["cold_s"],
            s["cold_s"] / base[case],
            s["agreement_vs_planar"],
        )
        line("finray_jax 3-D warm", case, s["warm_s"], s["warm_s"] / base[case], None)
        if "openseespy" in out:
            for r in out["openseespy"]["rows"]:
                if r["case"] == case:
                    line(
                        f"openseespy h={r['h_mm']} ({r['elements']} el., {r['load_steps']} st.)",
                        case,
                        r["solve_s"],
                        r["ratio_to_finray_planar_cold"],
                        r["agreement"],
                    )
        if "scipy" in out:
            for r in out["scipy"]:
                if r["case"] == case and "cold_s" in r:
                    line(
                        "SciPy single shooting cold",
                        case,
                        r["cold_s"],
                        r["ratio_to_finray_planar_cold"],
                        r["agreement"],
                    )
                    line(
                        "SciPy single shooting warm",
                        case,
                        r["warm_s"],
                        r["warm_s"] / base[case],
                        None,
                    )
                elif r["case"] == case:
                    line(
                        f"SciPy: > {r['budget_s']:.0f} s (load {r['load_factor_reached']:.2f})",
                        case,
                        None,
                        None,
                        None,
                    )
        if "pyelastica" in out:
            for r in out["pyelastica"]:
                if r["case"] == case:
                    line(
                        f"PyElastica to 0.5 % ({r['elements']} el.)",
                        case,
                        r["reached_0.5pct_s"],
                        r["ratio_to_finray_planar_cold"],
                        r["final_agreement"],
                    )
    path = write("peers", out)
    print(f"wrote {path} ({out['total_seconds']:.0f} s)")


if __name__ == "__main__":
    main()
