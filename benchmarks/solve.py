"""Solve-time benchmark of ref-A (issue: core performance targets).

Pinned to one core. For L1, L2, L3 in planar and 3-D mode it records:
  compile time (first call, lowering + XLA compile, reported apart),
  cold solve (from the undeformed guess), median of repeats,
  warm re-solve after a 1 % change of the back-beam thickness, starting from the previous
  solution (init=...), median of repeats.
Baselines timed in the same run for L1, so figures from noisy machines can be compared:
the same solve through `diffrax.diffeqsolve` instead of the tableau stepper, and with
the dense LU (`SolverOptions(linear_solver="dense")`) instead of the banded one.

Run:  taskset -c 0 .venv/bin/python benchmarks/solve.py [--quick]
"""

import argparse
import time

import equinox as eqx
import jax
from _common import machine, median_time, pin_to_one_core, write

import finray_jax as fr
from finray_jax import _solve


def bench_case(case, mode, integrator=fr.Integrator(), repeats=15, opts=fr.SolverOptions()):
    finger = fr.ref_finger_a(case)
    topo = fr.topology_of(finger, mode)
    t0 = time.perf_counter()
    sol = jax.block_until_ready(_solve._solve_core(topo, integrator, opts, finger, None))
    compile_s = time.perf_counter() - t0
    cold, n_cold = median_time(
        lambda: jax.block_until_ready(_solve._solve_core(topo, integrator, opts, finger, None)),
        repeats,
    )
    thicker = eqx.tree_at(lambda f: f.back.thickness, finger, finger.back.thickness * 1.01)
    warm_sol = jax.block_until_ready(
        _solve._solve_core(topo, integrator, opts, thicker, sol.unknowns)
    )
    warm, n_warm = median_time(
        lambda: jax.block_until_ready(
            _solve._solve_core(topo, integrator, opts, thicker, sol.unknowns)
        ),
        repeats,
    )
    return {
        "case": case,
        "mode": mode,
        "status": sol.status,
        "iterations_cold": int(sol.iterations),
        "iterations_warm": int(warm_sol.iterations),
        "tip_dx_mm": float(sol.tip.displacement[0]),
        "compile_s": compile_s,
        "cold_ms": 1e3 * cold,
        "warm_ms": 1e3 * warm,
        "repeats": [n_cold, n_warm],
        "steps_per_segment": integrator.steps,
        "backend": integrator.backend,
        "linear_solver": opts.linear_solver,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="L1 only, fewer repeats")
    args = ap.parse_args()
    cores = pin_to_one_core()
    rows = []
    cases = ["L1"] if args.quick else ["L1", "L2", "L3"]
    for mode in ("planar", "spatial"):
        for case in cases:
            row = bench_case(case, mode, repeats=5 if args.quick else 15)
            rows.append(row)
            print(
                f"{case} {mode:8s} {row['status']:10s} compile {row['compile_s']:6.1f} s  "
                f"cold {row['cold_ms']:8.2f} ms ({row['iterations_cold']} it)  "
                f"warm {row['warm_ms']:8.2f} ms ({row['iterations_warm']} it)",
                flush=True,
            )
    base = bench_case("L1", "planar", fr.Integrator(backend="diffeqsolve"), repeats=5)
    print(
        f"baseline diffeqsolve L1 planar: compile {base['compile_s']:.1f} s  cold "
        f"{base['cold_ms']:.2f} ms  warm {base['warm_ms']:.2f} ms"
    )
    dense = []
    for mode in ("planar", "spatial"):
        d = bench_case("L1", mode, repeats=5, opts=fr.SolverOptions(linear_solver="dense"))
        dense.append(d)
        print(
            f"baseline dense LU L1 {mode}: compile {d['compile_s']:.1f} s  cold "
            f"{d['cold_ms']:.2f} ms  warm {d['warm_ms']:.2f} ms"
        )
    path = write(
        "solve",
        {
            "pinned_cores": cores,
            "machine": machine(),
            "rows": rows,
            "baseline_diffeqsolve": base,
            "baseline_dense_lu": dense,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
