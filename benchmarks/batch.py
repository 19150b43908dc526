"""Batch throughput and gradient cost of differentiable design.

Pinned to one core. Designs are small random perturbations of ref-A under L1: the back
clamp length in [0, 5] mm and the attachment arc lengths of crossbeams 0-2 and 4-6 on both
beams by up to +-1 mm (crossbeam 3 sits at the load point; moving it changes the topology).

For batch sizes 1, 16, 64, 256, 1024 (one chunk each), with the designs of a chunk
vmapped (vectorize=True) and mapped one after another (vectorize=False, the CPU default),
each design started from the undeformed shape (cold) and, for batches above 1, from the
base finger's solution (`solve_batch(..., init=...)`, warm),
it records the compile time (first call, apart) and the median wall time of
`solve_batch` end to end (checks, padding, transfer, solve, outputs; the base finger's
topology is built and validated once, outside, an eager cost of its own), as
designs/s. For comparison, in the same process: a Python loop of single jitted direct
solves.

Gradient cost: `jax.value_and_grad` and `jax.jacfwd` of tip dx with respect to 10 design
values against the forward solve alone, all jitted through `solve_finger(...,
topology=...)`.

With --resolutions, instead: 64 designs at 10, 5, 4 and 3 steps per segment (interleaved
rounds) beside the resolution check of each count (`finray_jax.check_resolution`).

Run:  taskset -c 0 .venv/bin/python benchmarks/batch.py [--quick | --resolutions]
"""

import argparse
import functools
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, median_time, pin_to_one_core, write

import finray_jax as fr
from finray_jax import _solve, design
from finray_jax.batch import solve_batch

BASE = fr.ref_finger_a("L1")
TOPO = fr.topology_of(BASE, "planar")
MOVED = (0, 1, 2, 4, 5, 6)
GRAD_NAMES = (
    "adaptor.back_clamp_length",
    "crossbeams.front_s[1]",
    "crossbeams.back_s[5]",
    "crossbeams.thickness[2]",
    "crossbeams.angle[4]",
    "front.thickness",
    "back.thickness",
    "depth",
    "material.E",
    "tip.z",
)


def designs(n, seed=0):
    rng = np.random.default_rng(seed)
    v = {"adaptor.back_clamp_length": rng.uniform(0.0, 5.0, n)}
    for i in MOVED:
        v[f"crossbeams.front_s[{i}]"] = float(BASE.crossbeams.front_s[i]) + rng.uniform(-1, 1, n)
        v[f"crossbeams.back_s[{i}]"] = float(BASE.crossbeams.back_s[i]) + rng.uniform(-1, 1, n)
    return v


@functools.cache
def base_solution():
    return fr.solve_finger(BASE, topology=TOPO)


def bench_batch(n, vectorize, repeats, warm=False):
    values = designs(n)
    kw = dict(chunk_size=n, vectorize=vectorize, topology=TOPO)
    if warm:
        kw["init"] = base_solution()
    run = lambda: solve_batch(BASE, values, ["tip.dx"], **kw)
    t0 = time.perf_counter()
    res = run()
    compile_s = time.perf_counter() - t0
    t, k = median_time(run, repeats, 0.0)
    return {
        "batch": n,
        "vectorize": "vmap" if vectorize else "map",
        "start": "base solution" if warm else "undeformed",
        "compile_s": compile_s,
        "batch_ms": 1e3 * t,
        "ms_per_design": 1e3 * t / n,
        "designs_per_s": n / t,
        "repeats": k,
        "converged": int(np.sum(res.status == "converged")),
        "mean_iterations": float(np.mean(res.iterations)),
    }


@eqx.filter_jit
def _direct_tip(finger):
    sol, _, _ = _solve.direct_core(TOPO, fr.Integrator(), fr.SolverOptions(), finger, None)
    return sol.tip.displacement[0]


def bench_resolutions(n, step_counts, rounds):
    """Batch throughput (n designs, one chunk, one after another, cold) at several steps
    per segment, timed in interleaved rounds, beside each count's resolution check on the
    base finger (`check_resolution`: the estimated relative tip error)."""
    values = designs(n)
    runs = {}
    for k in step_counts:
        integ = fr.Integrator(steps=k)
        runs[k] = functools.partial(
            solve_batch,
            BASE,
            values,
            ["tip.dx"],
            chunk_size=n,
            vectorize=False,
            topology=TOPO,
            integrator=integ,
        )
        res = runs[k]()  # compile
        assert np.all(res.status == "converged"), k
    times = {k: [] for k in step_counts}
    for _ in range(rounds):
        for k in step_counts:
            times[k].append(median_time(runs[k], 5, 0.0)[0])
    out = []
    for k in step_counts:
        check = fr.check_resolution(BASE, mode="planar", integrator=fr.Integrator(steps=k))
        t = float(np.median(times[k]))
        out.append(
            {
                "steps": k,
                "ms_per_design": 1e3 * t / n,
                "designs_per_s": n / t,
                "designs_per_s_by_round": [n / x for x in times[k]],
                "tip_relative_error": check.tip_relative_error,
                "observed_order": check.to_dict()["observed_order"],  # None: at noise
                "reliable": check.reliable,
            }
        )
    return out


def bench_loop(n):
    values = designs(n, seed=1)
    fingers = [design.set_design(BASE, {k: v[i] for k, v in values.items()}) for i in range(n)]
    jax.block_until_ready(_direct_tip(fingers[0]))
    loop, _ = median_time(lambda: [jax.block_until_ready(_direct_tip(f)) for f in fingers], 3, 0.0)
    return {"designs": n, "loop_of_single_jitted_solves_ms_per_design": 1e3 * loop / n}


def bench_gradient(repeats):
    x0 = jnp.stack([jnp.asarray(v) for v in design.get_design(BASE, GRAD_NAMES).values()])

    def tip_dx(x):
        finger = design.set_design(BASE, dict(zip(GRAD_NAMES, x)))
        return fr.solve_finger(finger, topology=TOPO).tip.displacement[0]

    forward = jax.jit(tip_dx)
    both = jax.jit(jax.value_and_grad(tip_dx))
    jacfwd = jax.jit(jax.jacfwd(tip_dx))
    out = {}
    for name, fn in (("forward", forward), ("value_and_grad", both), ("jacfwd", jacfwd)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(x0))
        out[f"{name}_compile_s"] = time.perf_counter() - t0
        t, _ = median_time(lambda fn=fn: jax.block_until_ready(fn(x0)), repeats)
        out[f"{name}_ms"] = 1e3 * t
    out["ratio"] = out["value_and_grad_ms"] / out["forward_ms"]
    out["jacfwd_ratio"] = out["jacfwd_ms"] / out["forward_ms"]
    out["n_design_values"] = len(GRAD_NAMES)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="batch sizes 1 and 16 only")
    ap.add_argument(
        "--resolutions",
        action="store_true",
        help="only: throughput of 64 designs at 10, 5, 4 and 3 steps per segment, with the "
        "resolution check of each (results/batch_resolution.json)",
    )
    args = ap.parse_args()
    cores = pin_to_one_core()
    if args.resolutions:
        rows = bench_resolutions(64, (10, 5, 4, 3), rounds=3)
        for r in rows:
            print(
                f"{r['steps']:2d} steps per segment: {r['ms_per_design']:.3f} ms/design, "
                f"{r['designs_per_s']:.0f} designs/s (rounds "
                + ", ".join(f"{x:.0f}" for x in r["designs_per_s_by_round"])
                + f"); estimated tip error {r['tip_relative_error']:.1e} (relative)",
                flush=True,
            )
        meta = {"pinned_cores": cores, "machine": machine(), "finger": "ref-A L1, planar"}
        print(f"wrote {write('batch_resolution', {**meta, 'rows': rows})}")
        return
    sizes = (1, 16) if args.quick else (1, 16, 64, 256, 1024)
    rows = []
    cases = [(v, n, False) for v in (True, False) for n in sizes]
    cases += [(v, n, True) for v in (True, False) for n in sizes if n > 1]
    for vectorize, n, warm in cases:
        row = bench_batch(n, vectorize, repeats=max(3, 64 // n), warm=warm)
        rows.append(row)
        start = "warm" if warm else "cold"
        print(
            f"{row['vectorize']:4s} {start} batch {n:5d}: compile {row['compile_s']:6.1f} s  "
            f"{row['ms_per_design']:7.2f} ms/design  {row['designs_per_s']:7.1f} designs/s  "
            f"({row['converged']}/{n} converged, {row['mean_iterations']:.1f} it.)",
            flush=True,
        )
    compare = bench_loop(64)
    loop_ms = compare["loop_of_single_jitted_solves_ms_per_design"]
    print(f"64 designs: loop of single jitted direct solves {loop_ms:.2f} ms/design", flush=True)
    grad = bench_gradient(repeats=5 if args.quick else 15)
    print(
        f"gradient of tip dx w.r.t. {grad['n_design_values']} values: "
        f"forward {grad['forward_ms']:.2f} ms, "
        f"value_and_grad {grad['value_and_grad_ms']:.2f} ms (x{grad['ratio']:.2f}), "
        f"jacfwd {grad['jacfwd_ms']:.2f} ms (x{grad['jacfwd_ratio']:.2f}); compile "
        f"{grad['forward_compile_s']:.0f} / {grad['value_and_grad_compile_s']:.0f} / "
        f"{grad['jacfwd_compile_s']:.0f} s",
        flush=True,
    )
    path = write(
        "batch",
        {
            "pinned_cores": cores,
            "machine": machine(),
            "finger": "ref-A L1, planar",
            "target_designs_per_s": 1000,
            "batch": rows,
            "sequential": compare,
            "gradient": grad,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
