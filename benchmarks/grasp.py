"""Grasp benchmarks: one full grasp solve (closing onto the object and
beyond), the same grasp by the actuator force it needed, and one release-force trace, on
the default finger (Finger-1) with an 18 mm cylinder, planar, pinned to one core. Compile
time is reported apart; steady times are medians of repeats. As an in-run baseline the
same machine's plain planar ref-A L1 solve (no contact) is timed too, so ratios survive a
noisy machine.

    python benchmarks/grasp.py [--quick]
"""

import argparse
import time

import jax
from _common import machine, median_time, pin_to_one_core, write  # noqa: I001

import finray_jax as fr
from finray_jax import io as fio
from finray_jax.studies import MODIFIED, with_adaptor, with_object

NEWTON = fr.SolverOptions(reuse_jacobian=False)  # the in-run baseline: no chord steps


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    args = ap.parse_args()
    cores = pin_to_one_core()
    repeats = 3 if args.quick else 7

    finger, _ = fio.load_finger("examples/finger1.toml")
    base = with_object(finger, 18.0)
    results = {"machine": machine(), "pinned_cores": cores, "cases": {}}

    # In-run baseline: ref-A L1, planar, no contact.
    ref = fr.ref_finger_a("L1")
    t = time.perf_counter()
    jax.block_until_ready(fr.solve_finger(ref, mode="planar"))
    compile_ref = time.perf_counter() - t
    base_t, n = median_time(lambda: jax.block_until_ready(fr.solve_finger(ref, mode="planar")))
    results["baseline_refA_L1_planar_s"] = base_t
    print(f"baseline: ref-A L1 planar solve {1e3 * base_t:.2f} ms (compile {compile_ref:.1f} s)")

    for name, ad in (("original", fr.Adaptor()), ("modified", MODIFIED)):
        f = with_adaptor(base, ad)
        t = time.perf_counter()
        g = fr.grasp(f, 6.0)
        compile_s = time.perf_counter() - t
        grasp_t, _ = median_time(lambda f=f: fr.grasp(f, 6.0), repeats=repeats, min_total=0)
        t = time.perf_counter()
        tr = fr.release_force(g, step=2.0)
        first_release = time.perf_counter() - t
        release_t, _ = median_time(
            lambda g=g: fr.release_force(g, step=2.0), repeats=max(2, repeats // 2), min_total=0
        )
        case = {
            "first_grasp_s_incl_compile": compile_s,
            "grasp_s": grasp_t,
            "grasp_solves": g.steps,
            "grasp_vs_baseline": grasp_t / base_t,
            "release_trace_s": release_t,
            "first_release_s": first_release,
            "release_steps": int(len(tr.pull)),
            "normal_force_N": float(g.contact.normal_force),
            "max_penetration_mm": float(g.contact.max_penetration),
            "holding_force_N": tr.peak,
            "targets": {"grasp_s": 0.05, "release_trace_s": 1.0},
        }
        # The same grasp by the actuator force it needed: the closing is searched for.
        force = float(g.contact.actuator_force)
        by_force = fr.grasp(f, actuator_force=force)
        case["actuator_grasp"] = {
            "actuator_force_N": force,
            "grasp_s": median_time(
                lambda f=f, F=force: fr.grasp(f, actuator_force=F), repeats=repeats, min_total=0
            )[0],
            "grasp_solves": by_force.steps,
            "closing_mm": float(by_force.closing),
        }
        # The stability test's share: the same grasp without it.
        fr.grasp(f, 6.0, check_stability=False)
        case["without_stability_test"] = {
            "grasp_s": median_time(
                lambda f=f: fr.grasp(f, 6.0, check_stability=False), repeats=repeats, min_total=0
            )[0],
            "stability_s": median_time(lambda g=g: fr.stability(g), repeats=repeats, min_total=0)[
                0
            ],
        }
        # In-run baseline: the same grasp and release trace without chord steps.
        g_n = fr.grasp(f, 6.0, options=NEWTON)
        fr.release_force(g_n, step=2.0, options=NEWTON)
        case["newton_only"] = {
            "grasp_s": median_time(
                lambda f=f: fr.grasp(f, 6.0, options=NEWTON), repeats=repeats, min_total=0
            )[0],
            "grasp_solves": g_n.steps,
            "release_trace_s": median_time(
                lambda g=g_n: fr.release_force(g, step=2.0, options=NEWTON),
                repeats=max(2, repeats // 2),
                min_total=0,
            )[0],
        }
        results["cases"][name] = case
        print(
            f"{name:9s} grasp {1e3 * grasp_t:8.1f} ms ({g.steps} Newton solves; first call "
            f"{compile_s:.1f} s), release trace {release_t:.2f} s ({len(tr.pull)} steps), "
            f"contact force {case['normal_force_N']:.3f} N, holding {tr.peak:.3f} N"
        )
        ag = case["actuator_grasp"]
        print(
            f"{'':9s} by actuator force {ag['actuator_force_N']:.3f} N: grasp "
            f"{1e3 * ag['grasp_s']:8.1f} ms ({ag['grasp_solves']} solves, closing "
            f"{ag['closing_mm']:.4f} mm)"
        )
        ws = case["without_stability_test"]
        print(
            f"{'':9s} without the stability test: grasp {1e3 * ws['grasp_s']:8.1f} ms; "
            f"the test alone {1e3 * ws['stability_s']:.1f} ms"
        )
        nw = case["newton_only"]
        print(
            f"{'':9s} Newton only (no chord steps): grasp {1e3 * nw['grasp_s']:8.1f} ms "
            f"({nw['grasp_solves']} solves), release trace {nw['release_trace_s']:.2f} s"
        )
    path = write("grasp", results)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
