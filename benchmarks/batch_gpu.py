"""Batch throughput on a GPU: planar ref-A L1 designs, vmapped per chunk.

The designs are those of benchmarks/batch.py (random perturbations of ref-A under L1: back
clamp length in [0, 5] mm, attachment arc lengths of crossbeams 0-2 and 4-6 by up to
+-1 mm), solved by `solve_batch` end to end (padding, transfer, solve, outputs back to
the host) on the default device, which must be an accelerator.

In one process it records:
- agreement: the same designs solved on the GPU and on the host CPU (`jax.default_device`),
  status and tip dx compared; again for designs made so soft that some need the
  continuation stage and some are beyond their limit load;
- for each chunk size, the first call's time (compile and run) and the median wall time of
  a batch of `--designs` designs split into chunks of that size, as designs/s, cold (each
  design from the undeformed shape) and, for the last chunk size, warm (from the base
  finger's solution, `init=`);
- the gradient: `jax.vmap(jax.value_and_grad(tip dx))` with respect to the 10 design values
  of benchmarks/batch.py, over a batch of designs, against the vmapped forward solve.

Run (on the GPU machine):  python benchmarks/batch_gpu.py [--designs N] [--chunks 1024 4096]
Writes benchmarks/results/batch_gpu.json (or --out PATH).
"""

import argparse
import json
import pathlib
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import machine, median_time  # noqa: E402
from batch import BASE, GRAD_NAMES, TOPO, designs  # noqa: E402

import finray_jax as fr  # noqa: E402
from finray_jax import design  # noqa: E402
from finray_jax.batch import solve_batch  # noqa: E402


def run_batch(values, chunk, init=None):
    return solve_batch(BASE, values, ["tip.dx"], chunk_size=chunk, topology=TOPO, init=init)


def agreement(n, hard=False):
    """The same n designs on the accelerator and on the host CPU. hard: Young's modulus
    spread from 12 down to 0.1 MPa as well, so that some designs need the continuation
    stage (a vmapped `lax.cond` on the accelerator) and some are beyond their limit load."""
    values = designs(n, seed=3)
    if hard:
        values["material.E"] = np.geomspace(12.0, 0.1, n)
    gpu = run_batch(values, n)
    with jax.default_device(jax.devices("cpu")[0]):
        cpu = solve_batch(
            BASE,
            values,
            ["tip.dx"],
            chunk_size=n,
            topology=TOPO,
            devices=jax.devices("cpu"),
            vectorize=False,  # (the CPU default; vmap is chosen by the default backend)
        )
    both = (gpu.status == cpu.status) & np.isin(cpu.status, ["converged", "beyond_limit_load"])
    diff = np.abs(gpu.outputs["tip.dx"] - cpu.outputs["tip.dx"])[both]
    return {
        "designs": n,
        "status_counts": {
            str(k): int(v) for k, v in zip(*np.unique(cpu.status, return_counts=True))
        },
        "same_status": int(np.sum(gpu.status == cpu.status)),
        "compared": int(np.sum(both)),
        "max_abs_tip_dx_difference_mm": float(np.max(diff)) if diff.size else None,
        "max_relative_tip_dx_difference": float(np.max(diff / np.abs(cpu.outputs["tip.dx"][both])))
        if diff.size
        else None,
    }


def throughput(n, chunk, warm, repeats):
    values = designs(n)
    init = fr.solve_finger(BASE, topology=TOPO) if warm else None
    t0 = time.perf_counter()
    res = run_batch(values, chunk, init)
    first = time.perf_counter() - t0
    t, k = median_time(lambda: run_batch(values, chunk, init), repeats, 0.0)
    return {
        "designs": n,
        "chunk_size": chunk,
        "start": "base solution" if warm else "undeformed",
        "first_call_s": first,
        "batch_s": t,
        "designs_per_s": n / t,
        "us_per_design": 1e6 * t / n,
        "repeats": k,
        "converged": int(np.sum(res.status == "converged")),
        "mean_iterations": float(np.mean(res.iterations)),
        "max_iterations": int(np.max(res.iterations)),
    }


def gradients(n, repeats):
    """vmapped value_and_grad of tip dx in 10 design values, against the vmapped solve."""
    x0 = np.stack([np.asarray(v) for v in design.get_design(BASE, GRAD_NAMES).values()])
    rng = np.random.default_rng(5)
    xs = jnp.asarray(x0 * (1.0 + rng.uniform(-0.02, 0.02, (n, x0.size))))

    def tip_dx(x):
        finger = design.set_design(BASE, dict(zip(GRAD_NAMES, x)))
        return fr.solve_finger(finger, topology=TOPO).tip.displacement[0]

    forward = jax.jit(jax.vmap(tip_dx))
    both = jax.jit(jax.vmap(jax.value_and_grad(tip_dx)))
    out = {"designs": n, "n_design_values": len(GRAD_NAMES)}
    for name, fn in (("forward", forward), ("value_and_grad", both)):
        t0 = time.perf_counter()
        r = jax.block_until_ready(fn(xs))
        out[f"{name}_first_call_s"] = time.perf_counter() - t0
        t, _ = median_time(lambda fn=fn: jax.block_until_ready(fn(xs)), repeats, 0.0)
        out[f"{name}_s"] = t
        out[f"{name}_designs_per_s"] = n / t
        if name == "value_and_grad":
            out["finite_gradients"] = int(np.sum(np.all(np.isfinite(np.asarray(r[1])), axis=1)))
    out["ratio"] = out["value_and_grad_s"] / out["forward_s"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--designs", type=int, default=65536, help="designs per timed batch")
    ap.add_argument("--chunks", type=int, nargs="+", default=[1024, 4096, 16384, 65536])
    ap.add_argument("--grad-designs", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    parts = ("agreement", "hard", "throughput", "gradient")
    ap.add_argument("--parts", nargs="+", choices=parts, default=list(parts))
    ap.add_argument("--allow-cpu", action="store_true", help="smoke test without a GPU")
    ap.add_argument("--out", type=pathlib.Path, default=None)
    args = ap.parse_args()
    dev = jax.devices()[0]
    if dev.platform == "cpu" and not args.allow_cpu:
        raise SystemExit(f"batch_gpu.py: the default device is {dev}, not an accelerator")
    out = {"machine": machine(), "device_kind": dev.device_kind, "finger": "ref-A L1, planar"}
    print(f"device {dev} ({dev.device_kind}), jax {jax.__version__}", flush=True)

    path = args.out or pathlib.Path(__file__).parent / "results" / "batch_gpu.json"
    save = lambda: path.write_text(json.dumps(out, indent=2))  # after each part

    if "agreement" in args.parts:
        out["agreement"] = a = agreement(256)
        save()
        print(f"agreement with the host CPU: {json.dumps(a)}", flush=True)
    if "hard" in args.parts:
        out["agreement_hard"] = a = agreement(64, hard=True)
        save()
        print(f"agreement with the host CPU, soft designs: {json.dumps(a)}", flush=True)
    rows = out["throughput"] = []
    for chunk in args.chunks if "throughput" in args.parts else ():
        for warm in (False, True) if chunk == args.chunks[-1] else (False,):
            n = max(args.designs, chunk)
            try:
                r = throughput(n, chunk, warm, args.repeats)
            except Exception as e:  # (out of memory, say: keep the rows measured so far)
                rows.append({"designs": n, "chunk_size": chunk, "error": repr(e)[:500]})
                print(f"chunk {chunk}: {e!r}"[:500], flush=True)
                continue
            rows.append(r)
            save()
            print(
                f"chunk {chunk:6d} {'warm' if warm else 'cold'}: {n} designs in "
                f"{r['batch_s']:.3f} s = {r['designs_per_s']:8.0f} designs/s "
                f"(first call {r['first_call_s']:.1f} s; {r['converged']}/{n} converged, "
                f"{r['mean_iterations']:.2f} it. mean, {r['max_iterations']} max)",
                flush=True,
            )
    if "gradient" in args.parts:
        out["gradient"] = g = gradients(args.grad_designs, args.repeats)
        print(
            f"vmapped gradient over {g['designs']} designs: forward {g['forward_s']:.3f} s, "
            f"value_and_grad {g['value_and_grad_s']:.3f} s (x{g['ratio']:.2f}), "
            f"{g['value_and_grad_designs_per_s']:.0f} gradients/s; first calls "
            f"{g['forward_first_call_s']:.0f} / {g['value_and_grad_first_call_s']:.0f} s",
            flush=True,
        )
    save()
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
