"""A sweep of 10,000 designs on this machine: `examples/sweep_random_10k.toml`
(ref-A L1, planar; 5 design values drawn at random) run through `finray_jax.sweep`, the
same code as `finray sweep`, pinned to one core. Reports the wall time with and without
the first chunk (which compiles), designs per second, and the status counts; a plain
single solve of ref-A L1 is timed in the same process as the baseline.

    python benchmarks/sweep.py [--n N] [--out DIR]
"""

import argparse
import dataclasses
import pathlib
import shutil
import tempfile
import time

import jax
from _common import machine, median_time, pin_to_one_core, write  # noqa: I001

import finray_jax as fr
from finray_jax import sweep as fsweep

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=None, help="designs (default: the file's 10,000)")
    ap.add_argument("--out", default=None, help="output folder (default: a temporary one)")
    args = ap.parse_args()
    cores = pin_to_one_core()
    sw = fsweep.load_sweep(ROOT / "examples" / "sweep_random_10k.toml")
    if args.n is not None:
        sw = dataclasses.replace(sw, n_random=args.n)
    out = pathlib.Path(args.out or tempfile.mkdtemp(prefix="finray_sweep_"))
    if out.exists():
        shutil.rmtree(out)

    ref = fr.ref_finger_a("L1")
    jax.block_until_ready(fr.solve_finger(ref, mode="planar"))
    base, _ = median_time(lambda: jax.block_until_ready(fr.solve_finger(ref, mode="planar")))

    marks = []
    t0 = time.perf_counter()
    run = fsweep.run_sweep(
        sw, out, plot=True, after_chunk=lambda done: marks.append((done, time.perf_counter() - t0))
    )
    total = time.perf_counter() - t0
    first_done, first_t = marks[0]
    steady = (marks[-1][1] - first_t) / max(marks[-1][0] - first_done, 1)
    res = {
        "machine": machine(),
        "pinned_cores": cores,
        "designs": run.total,
        "chunk_size": sw.chunk_size,
        "wall_s": total,
        "first_chunk_s_incl_compile": first_t,
        "steady_ms_per_design": 1e3 * steady,
        "steady_designs_per_s": 1.0 / steady,
        "status_counts": run.counts,
        "baseline_single_solve_ms": 1e3 * base,
    }
    print(
        f"{run.total} designs in {total:.1f} s (first chunk of {first_done} incl. compile "
        f"{first_t:.1f} s); steady {1e3 * steady:.2f} ms/design = {1 / steady:.0f} designs/s; "
        f"status {run.counts}; baseline single solve {1e3 * base:.2f} ms"
    )
    print(f"wrote {write('sweep', res)}; results in {out}")


if __name__ == "__main__":
    main()
