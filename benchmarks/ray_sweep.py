"""Sweeps on a Ray cluster against the local engine, on this machine: a 2,000-design solve
sweep (ref-A L1, planar, five design values drawn at random, chunks of 100) and a
200-design grasp sweep (Finger-1 on the modified adaptor closing 6 mm on the 18 mm
cylinder, clamp and support lengths drawn at random, one design after another in chunks
of 10).

Each configuration runs in a new process with the compilation cache off, so that every
worker compiles: the local engine pinned to core 0; Ray with 1 worker (a one-node
cluster of 1 CPU pinned to core 0) and with 2 workers (2 CPUs, cores 0 and 1). Reported:
wall time and designs/s, each worker's first chunk (its compile) apart from the steady
chunks, steady designs/s, the scaling efficiency of 2 workers over 1, and the driver's
cost of writing one chunk (append + fsync), the bound on how many chunks a driver takes
per second. The machine's own scaling is the in-run baseline: two local processes at
once, one a core, each with half of the designs.

    python benchmarks/ray_sweep.py [--solve-n 2000] [--grasp-n 200] [--only solve|grasp]
                                   [--pair-only]
"""

import argparse
import json
import os
import pathlib
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = pathlib.Path(sys.executable).parent
sys.path.insert(0, str(pathlib.Path(__file__).parent))

SOLVE = """
finger = "ref_a.toml"
outputs = ["tip.dx", "tip.dz", "reaction.back.fx", "max_strain"]
mode = "planar"
chunk_size = 100
[sampling]
kind = "random"
n = {n}
seed = 1
[[design]]
name = "adaptor.back_clamp_length"
range = [0.0, 14.0]
[[design]]
name = "crossbeams.front_s[2]"
range = [41.0, 49.0]
[[design]]
name = "crossbeams.angle[2]"
range = [-0.05, 0.05]
[[design]]
name = "crossbeams.thickness[2]"
range = [0.8, 1.2]
[[design]]
name = "material.E"
range = [10.0, 14.0]
"""

GRASP = """
finger = "grasp_finger1_modified.toml"
outputs = ["contact.normal_force", "contact.length", "max_strain"]
chunk_size = 10
[sampling]
kind = "random"
n = {n}
seed = 1
[[design]]
name = "adaptor.back_clamp_length"
range = [16.5, 31.0]
[[design]]
name = "adaptor.support_length"
range = [48.0, 62.5]
"""


def one_run(args) -> None:
    """(In a new process) one sweep on one engine; prints its figures as JSON."""
    from finray_jax import sweep as fsweep
    from finray_jax.engines import LocalEngine, RayEngine

    sw = fsweep.load_sweep(args.sweep)
    if args.engine == "local":
        engine = LocalEngine()
    else:
        engine = RayEngine(address=args.address, workers=args.workers)
    t0 = time.perf_counter()
    run = fsweep.run_sweep(sw, args.out, engine=engine, plot=False)
    wall = time.perf_counter() - t0
    workers = {
        name: {"chunks": t.chunks, "seconds": t.seconds, "first_seconds": t.first_seconds}
        for name, t in run.workers.items()
    }
    print(json.dumps({"wall_s": wall, "done": run.done, "counts": run.counts, "workers": workers}))


def _figures(result: dict, n: int, per_chunk: int) -> dict:
    """Designs/s over the wall time, and each worker's compile (its first chunk less a
    steady chunk) and steady designs/s."""
    steady, compiles, steady_s, steady_designs = [], [], 0.0, 0
    for t in result["workers"].values():
        later = t["chunks"] - 1
        chunk_s = (t["seconds"] - t["first_seconds"]) / later if later else float("nan")
        steady.append(chunk_s)
        compiles.append(t["first_seconds"] - chunk_s)
        steady_s = max(steady_s, t["seconds"] - t["first_seconds"])
        steady_designs += later * per_chunk
    return {
        **result,
        "designs_per_s": n / result["wall_s"],
        "compile_s_per_worker": compiles,
        "steady_chunk_s": steady,
        "steady_designs_per_s": steady_designs / steady_s if steady_s else float("nan"),
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(cmd, cores=None, env=None) -> str:
    if cores is not None:
        cmd = ["taskset", "-c", cores, *cmd]
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{done.stderr[-3000:]}")
    return done.stdout


def local_pair(text: str, n: int, per_chunk: int, work: pathlib.Path) -> dict:
    """The machine's own scaling, without Ray: two local processes at once, one a core,
    each with half of the designs (two seeds)."""
    env = dict(os.environ, FINRAY_NO_CACHE="1")
    procs = []
    for k in (0, 1):
        path = work.parent / f"{work.name}_half{k}.toml"  # (beside the finger files)
        path.write_text(text.format(n=n // 2).replace("seed = 1", f"seed = {k + 1}"))
        cmd = ["taskset", "-c", str(k), sys.executable, __file__, "--one", "local", str(path)]
        cmd.append(str(work / f"half{k}"))
        procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env))
    t0 = time.perf_counter()
    halves = [json.loads(p.communicate()[0].splitlines()[-1]) for p in procs]
    wall = time.perf_counter() - t0
    result = {"wall_s": wall, "halves": [_figures(h, n // 2, per_chunk) for h in halves]}
    result["designs_per_s"] = n / wall
    steady = [h["steady_designs_per_s"] for h in result["halves"]]
    result["steady_designs_per_s"] = sum(steady)
    return result


def measure(sweep_file: pathlib.Path, n: int, per_chunk: int, work: pathlib.Path) -> dict:
    env = dict(os.environ, FINRAY_NO_CACHE="1", RAY_USAGE_STATS_ENABLED="0")
    me = [sys.executable, __file__, "--one"]
    out = {}
    line = _run([*me, "local", str(sweep_file), str(work / "local")], cores="0", env=env)
    out["local"] = _figures(json.loads(line.splitlines()[-1]), n, per_chunk)
    print(f"  local: {out['local']['designs_per_s']:.1f} designs/s", flush=True)
    ray = str(BIN / "ray")
    for k, cores in ((1, "0"), (2, "0,1")):
        port = _free_port()
        head = [ray, "start", "--head", f"--port={port}", f"--num-cpus={k}"]
        _run([*head, "--include-dashboard=false", "--object-store-memory=150000000"], cores, env)
        try:
            cmd = [*me, "ray", str(sweep_file), str(work / f"ray{k}")]
            line = _run([*cmd, "--address", f"127.0.0.1:{port}", "--workers", str(k)], env=env)
        finally:
            subprocess.run([ray, "stop", "--force"], capture_output=True, env=env)
        out[f"ray_{k}"] = _figures(json.loads(line.splitlines()[-1]), n, per_chunk)
        print(f"  ray, {k} workers: {out[f'ray_{k}']['designs_per_s']:.1f} designs/s", flush=True)
    one, two = out["ray_1"], out["ray_2"]
    out["efficiency_wall"] = two["designs_per_s"] / (2 * one["designs_per_s"])
    out["efficiency_steady"] = two["steady_designs_per_s"] / (2 * one["steady_designs_per_s"])
    return out


def driver_write_cost(rows: int = 100, repeats: int = 50) -> float:
    """Seconds to append and fsync one chunk of `rows` CSV rows (what the driver does per
    chunk)."""
    line = "12345," + ",".join(["0.12345678901234567"] * 8) + ",converged,5,1e-13,\n"
    with tempfile.NamedTemporaryFile("a", suffix=".csv") as fh:
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fh.write(line * rows)
            fh.flush()
            os.fsync(fh.fileno())
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--solve-n", type=int, default=2000)
    ap.add_argument("--grasp-n", type=int, default=200)
    ap.add_argument("--only", choices=("solve", "grasp"), default=None)
    ap.add_argument(
        "--pair-only",
        action="store_true",
        help="measure only the two local processes at once, added to the results file",
    )
    ap.add_argument("--one", nargs=3, metavar=("ENGINE", "SWEEP", "OUT"), default=None)
    ap.add_argument("--address", default=None)
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args()
    if args.one is not None:
        args.engine, args.sweep, args.out = args.one
        return one_run(args)
    from _common import RESULTS, machine, write

    work = pathlib.Path(tempfile.mkdtemp(prefix="finray_ray_bench_"))
    for name in ("ref_a.toml", "grasp_finger1_modified.toml"):
        shutil.copy(ROOT / "examples" / name, work / name)
    saved = RESULTS / "ray_sweep.json"
    keep = (args.pair_only or args.only) and saved.exists()  # (other cases stay)
    payload = json.loads(saved.read_text()) if keep else {}
    payload.update(machine=machine(), driver_chunk_write_s=driver_write_cost())
    cases = {"solve": (SOLVE, args.solve_n, 100), "grasp": (GRASP, args.grasp_n, 10)}
    for name, (text, n, per_chunk) in cases.items():
        if args.only not in (None, name):
            continue
        (work / name).mkdir()
        print(f"{name} sweep, {n} designs:", flush=True)
        pair = local_pair(text, n, per_chunk, work / name)
        print(f"  two local processes: {pair['designs_per_s']:.3f} designs/s", flush=True)
        if not args.pair_only:
            path = work / f"{name}.toml"
            path.write_text(text.format(n=n))
            payload[name] = {"n": n, "chunk": per_chunk, **measure(path, n, per_chunk, work / name)}
        payload[name]["local_pair"] = pair
        print(json.dumps(payload[name], indent=1), flush=True)
    print(f"wrote {write('ray_sweep', payload)}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
