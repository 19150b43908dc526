"""The same timings of two versions of finray_jax, interleaved on one core: the check that
a change of the code kept its speed (machines here are noisy; runs that alternate on the
same core see the same noise).

    python benchmarks/paired.py REF [--rounds 5] [--core 0] [--out FILE.json]

REF is a git revision: it is checked out into a temporary worktree, and each round runs
one fresh process of it and one of the working tree (in alternating order), pinned to
`--core`. Each process times, with the compilation cache off:

- compile: the first `solve_finger` of planar ref-A L1 (trace, compile and solve);
- solve: planar ref-A L1, median of 30 calls;
- grad: `jax.value_and_grad` of the tip's x displacement in the front-beam thickness,
  median of 30 calls (compiled once before);
- limit: `limit_load` of planar ref-A L2, median of 5 calls;
- grasp: the Finger-1 grasp of examples/grasp_finger1.toml, median of 3 (the first,
  compiling, call apart as grasp_compile).

It prints each figure's median over the rounds for both versions and their ratio.
"""

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]

WORKER = r"""
import json, statistics, sys, time
import jax
import finray_jax as fr
from finray_jax import io as fio

def median_time(fn, n):
    out = []
    for _ in range(n):
        t0 = time.perf_counter(); jax.block_until_ready(fn()); out.append(time.perf_counter() - t0)
    return statistics.median(out)

f = fr.ref_finger_a("L1")
res = {}
t0 = time.perf_counter(); jax.block_until_ready(fr.solve_finger(f, mode="planar").unknowns)
res["compile"] = time.perf_counter() - t0
res["solve"] = median_time(lambda: fr.solve_finger(f, mode="planar").unknowns, 30)
topo = fr.topology_of(f, "planar")
tip = lambda t: fr.solve_finger(
    fr.set_design(f, {"front.thickness": t}), mode="planar", topology=topo
).tip.displacement[0]
vg = jax.jit(jax.value_and_grad(tip))
jax.block_until_ready(vg(1.5))
res["grad"] = median_time(lambda: vg(1.5), 30)
f2 = fr.ref_finger_a("L2")
jax.block_until_ready(fr.limit_load(f2, mode="planar").load_factor)
res["limit"] = median_time(lambda: fr.limit_load(f2, mode="planar").load_factor, 5)
finger, settings = fio.load_finger(sys.argv[1])
kw = settings.grasp.grasp_kwargs()
t0 = time.perf_counter(); jax.block_until_ready(fr.grasp(finger, **kw).contact.normal_force)
res["grasp_compile"] = time.perf_counter() - t0
res["grasp"] = median_time(lambda: fr.grasp(finger, **kw).contact.normal_force, 3)
print("RESULT " + json.dumps(res))
"""


def run_once(tree: pathlib.Path, core: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), FINRAY_NO_CACHE="1")
    grasp_file = str(tree / "examples" / "grasp_finger1.toml")
    cmd = ["taskset", "-c", str(core), sys.executable, "-c", WORKER, grasp_file]
    out = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, check=True)
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("ref", help="git revision to compare the working tree with")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--core", type=int, default=0)
    ap.add_argument("--out", default=None, help="write the figures as JSON")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ref_tree = pathlib.Path(tmp) / "ref"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(ref_tree), args.ref],
            cwd=ROOT,
            check=True,
            capture_output=True,
        )
        try:
            runs = {"ref": [], "head": []}
            for k in range(args.rounds):
                order = [("ref", ref_tree), ("head", ROOT)]
                for name, tree in order if k % 2 == 0 else order[::-1]:
                    runs[name].append(run_once(tree, args.core))
                    print(f"round {k + 1} {name}: {runs[name][-1]}", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(ref_tree)], cwd=ROOT)
    summary = {}
    for key in runs["ref"][0]:
        a = statistics.median(r[key] for r in runs["ref"])
        b = statistics.median(r[key] for r in runs["head"])
        summary[key] = {"ref": a, "head": b, "ratio": b / a}
        unit, scale = ("s", 1.0) if key.endswith("compile") or key == "grasp" else ("ms", 1e3)
        print(
            f"{key:14s} {args.ref}: {scale * a:9.3f} {unit}   working tree: {scale * b:9.3f} "
            f"{unit}   ratio {b / a:.3f}"
        )
    if args.out:
        pathlib.Path(args.out).write_text(
            json.dumps({"ref": args.ref, "rounds": runs, "summary": summary}, indent=1)
        )


if __name__ == "__main__":
    main()
