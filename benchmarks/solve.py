"""Solve-time benchmark of ref-A.

Pinned to one core. For L1, L2, L3 in planar and 3-D mode it records:
  compile time (first call, lowering + XLA compile, reported apart) of the full traced
  core (direct Newton, continuation fallback: what jit/vmap/grad compile) and of the
  direct-Newton core alone (what an eager `solve_finger` compiles first),
  and for L1 the time of a `solve_finger` call from Python (finger checks included),
  cold solve (from the undeformed guess), median of repeats,
  warm re-solve after a 1 % change of the back-beam thickness, starting from the previous
  solution as `solve_finger(init=)` does (its unknowns and the factors of its Jacobian
  that an eager solve keeps), median of repeats, with the start from the unknowns alone
  beside it (a warm start without the factors); and after a 1 % change of the front-beam
  thickness, started from the previous solution's carried deformation as
  `solve_finger(init=)` starts it (the iterations from its scaled unknowns beside it).
Baselines timed in the same run for L1, so figures from noisy machines can be compared:
the same solve through `diffrax.diffeqsolve` instead of the tableau stepper, and with
the dense LU (`SolverOptions(linear_solver=fr.DenseLinearSolver())`) instead of the banded one, and
(every case) Newton without chord steps (`SolverOptions(reuse_jacobian=False)`).

And what a new process pays for its first `solve_finger` (as in a CLI run, which keeps
JAX's compilation cache on disk), with that cache empty and filled (child processes).

Run:  taskset -c 0 .venv/bin/python benchmarks/solve.py [--quick]
"""

import argparse
import os
import subprocess
import sys
import tempfile
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
    sol = jax.block_until_ready(_solve.solve_core(topo, integrator, opts, finger, None))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    _solve.direct_core.lower(topo, integrator, opts, finger, None).compile()
    direct_compile_s = time.perf_counter() - t0
    cold, n_cold = median_time(
        lambda: jax.block_until_ready(_solve.solve_core(topo, integrator, opts, finger, None)),
        repeats,
    )
    thicker = eqx.tree_at(lambda f: f.back.thickness, finger, finger.back.thickness * 1.01)
    # The warm start as `solve_finger(init=sol)` makes it: the unknowns and the factors
    # of Newton's last linearisation, which an eager solve keeps (Solution.jacobian).
    eager = _solve.direct_core(topo, integrator, opts, finger, None, keep_jacobian=True)[0]
    warm_start = _solve.warm_start(topo, opts, sol.unknowns, eager, True)
    warm_sol = jax.block_until_ready(_solve.solve_core(topo, integrator, opts, thicker, warm_start))
    warm, n_warm = median_time(
        lambda: jax.block_until_ready(
            _solve.solve_core(topo, integrator, opts, thicker, warm_start)
        ),
        repeats,
    )
    # Baseline in the same run: the start from the unknowns alone, without the factors.
    plain_sol = _solve.solve_core(topo, integrator, opts, thicker, sol.unknowns)
    plain, _ = median_time(
        lambda: jax.block_until_ready(
            _solve.solve_core(topo, integrator, opts, thicker, sol.unknowns)
        ),
        repeats,
    )
    # A 1 % thicker front beam, started as solve_finger(init=sol) starts it: the carried
    # deformation (Solution.deformation) and the factors; the scaled unknowns' iterations
    # beside it.
    front = eqx.tree_at(lambda f: f.front.thickness, finger, finger.front.thickness * 1.01)
    start = _solve.start_from_deformation(topo, front, sol.deformation)
    start = _solve.warm_start(topo, opts, start, eager, True)
    front_sol = _solve.solve_core(topo, integrator, opts, front, start)
    warm_front, _ = median_time(
        lambda: jax.block_until_ready(_solve.solve_core(topo, integrator, opts, front, start)),
        repeats,
    )
    scaled = _solve.solve_core(topo, integrator, opts, front, sol.unknowns)
    return {
        "case": case,
        "mode": mode,
        "status": sol.status,
        "iterations_cold": int(sol.iterations),
        "iterations_warm": int(warm_sol.iterations),
        "warm_unknowns_only_ms": 1e3 * plain,
        "iterations_warm_unknowns_only": int(plain_sol.iterations),
        "warm_front_ms": 1e3 * warm_front,
        "iterations_warm_front": int(front_sol.iterations),
        "iterations_warm_front_from_scaled_unknowns": int(scaled.iterations),
        "tip_dx_mm": float(sol.tip.displacement[0]),
        "compile_s": compile_s,
        "direct_compile_s": direct_compile_s,
        "cold_ms": 1e3 * cold,
        "warm_ms": 1e3 * warm,
        "repeats": [n_cold, n_warm],
        "steps_per_segment": integrator.steps,
        "backend": integrator.backend,
        "linear_solver": opts.linear_solver,
    }


def bench_eager(case, mode, repeats=30):
    """A user's call: `solve_finger` from Python (checks the finger, then runs the
    compiled direct solve), cold, after its compile."""
    finger = fr.ref_finger_a(case)
    topo = fr.topology_of(finger, mode)
    call = lambda: jax.block_until_ready(fr.solve_finger(finger, topology=topo).unknowns)
    call()
    t, n = median_time(call, repeats)
    return {"case": case, "mode": mode, "solve_finger_ms": 1e3 * t, "repeats": n}


NEW_PROCESS = """
import sys, time
t0 = time.perf_counter()
import jax, finray_jax as fr
from finray_jax import cli
cli.enable_compilation_cache()  # as every `finray` command but validate does
t1 = time.perf_counter()
sol = fr.solve_finger(fr.ref_finger_a("L1"), mode=sys.argv[1])
jax.block_until_ready(sol.unknowns)
print(t1 - t0, time.perf_counter() - t1, sol.status)
"""


def bench_new_process(mode):
    """What a new process (a CLI run) pays for its first `solve_finger`: with an empty
    compilation cache (compiles, then stores) and with the cache filled by that run."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, FINRAY_NO_CACHE="0", FINRAY_CACHE_DIR=cache)
        out = {}
        for label in ("empty_cache", "filled_cache"):
            run = subprocess.run(
                [sys.executable, "-c", NEW_PROCESS, mode],
                env=env,
                capture_output=True,
                text=True,
                check=True,
            )
            imp, first, status = run.stdout.split()
            out[label] = {"import_s": float(imp), "first_solve_s": float(first), "status": status}
    return {"mode": mode, **out}


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
                f"{case} {mode:8s} {row['status']:10s} compile {row['compile_s']:6.1f} s "
                f"(direct {row['direct_compile_s']:4.1f} s)  "
                f"cold {row['cold_ms']:8.2f} ms ({row['iterations_cold']} it)  "
                f"warm {row['warm_ms']:8.2f} ms ({row['iterations_warm']} it; from the "
                f"unknowns alone {row['warm_unknowns_only_ms']:.2f} ms, "
                f"{row['iterations_warm_unknowns_only']} it)  "
                f"warm, front 1 % thicker {row['warm_front_ms']:6.2f} ms "
                f"({row['iterations_warm_front']} it; "
                f"{row['iterations_warm_front_from_scaled_unknowns']} from the scaled unknowns)",
                flush=True,
            )
    eager = []
    for mode in ("planar", "spatial"):
        row = bench_eager("L1", mode)
        eager.append(row)
        print(f"solve_finger L1 {mode} from Python: {row['solve_finger_ms']:.2f} ms", flush=True)
    fresh = []
    for mode in ("planar", "spatial"):
        row = bench_new_process(mode)
        fresh.append(row)
        print(
            f"new process, first solve_finger L1 {mode}: "
            f"{row['empty_cache']['first_solve_s']:.1f} s with an empty compilation cache, "
            f"{row['filled_cache']['first_solve_s']:.1f} s with it filled "
            f"(import {row['filled_cache']['import_s']:.1f} s)",
            flush=True,
        )
    base = bench_case("L1", "planar", fr.Integrator(backend=fr.DiffeqsolveBackend()), repeats=5)
    print(
        f"baseline diffeqsolve L1 planar: compile {base['compile_s']:.1f} s  cold "
        f"{base['cold_ms']:.2f} ms  warm {base['warm_ms']:.2f} ms"
    )
    dense = []
    for mode in ("planar", "spatial"):
        d = bench_case(
            "L1", mode, repeats=5, opts=fr.SolverOptions(linear_solver=fr.DenseLinearSolver())
        )
        dense.append(d)
        print(
            f"baseline dense LU L1 {mode}: compile {d['compile_s']:.1f} s  cold "
            f"{d['cold_ms']:.2f} ms  warm {d['warm_ms']:.2f} ms"
        )
    newton = []  # the same solves without chord steps (SolverOptions.reuse_jacobian)
    for mode in ("planar", "spatial"):
        for case in cases:
            d = bench_case(case, mode, repeats=5, opts=fr.SolverOptions(reuse_jacobian=False))
            newton.append(d)
            print(
                f"baseline Newton only {case} {mode}: cold {d['cold_ms']:.2f} ms "
                f"({d['iterations_cold']} it)  warm {d['warm_ms']:.2f} ms "
                f"({d['iterations_warm']} it)",
                flush=True,
            )
    path = write(
        "solve",
        {
            "pinned_cores": cores,
            "machine": machine(),
            "rows": rows,
            "solve_finger": eager,
            "new_process": fresh,
            "baseline_diffeqsolve": base,
            "baseline_dense_lu": dense,
            "baseline_newton_only": newton,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
