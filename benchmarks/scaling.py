"""How solve and compile time grow with the crossbeam count and the steps per segment.

1. A ref-A-like finger (same main beams, sections, material; 0.05 N at s = 60 on the front
   beam, as L1) with 4, 8, 16, 32 horizontal crossbeams spread evenly over the height
   (z_i = 120 i / (n + 1)).
2. ref-A L1 with Integrator(steps = 5, 10, 20, 40).
3. The floor: the pieces of one Newton iteration on ref-A L1 (24 segments, 144 unknowns),
   each jitted alone: one RK step of the planar rhs, the segment flow of all segments, the
   residual, the residual with its Jacobian, and the dense LU solve.

Timed path: `direct_core`, the jitted direct Newton solve that `solve_finger` runs for
these loads (it compiles and runs the continuation only when the direct solve fails).
Compile time = first call - one steady-state call. Planar mode (3-D with --spatial).

Run:  taskset -c 1 .venv/bin/python benchmarks/scaling.py [--quick] [--spatial]
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, median_time, pin_to_one_core, write
from jax import lax

import finray_jax as fr
from finray_jax import _solve
from finray_jax._integrator import rk_step
from finray_jax._planar_rod import PlanarRod


def finger_with_crossbeams(n):
    z = 120.0 * np.arange(1, n + 1) / (n + 1)
    lb = float(np.hypot(40.0, 120.0))
    base = fr.ref_finger_a("L1")
    return fr.Finger(
        material=base.material,
        front_base=(0.0, 0.0),
        back_base=(40.0, 0.0),
        tip=(0.0, 120.0),
        front=base.front,
        back=base.back,
        crossbeams=fr.Crossbeams(z, z * lb / 120.0, np.full(n, 1.0), np.full(n, 20.0)),
        adaptor=base.adaptor,
        loads=base.loads,
    )


def time_solve(finger, mode, integrator, repeats):
    topo = fr.topology_of(finger, mode)
    opts = fr.SolverOptions()
    run = lambda: jax.block_until_ready(_solve.direct_core(topo, integrator, opts, finger, None))
    t0 = time.perf_counter()
    sol, ok = run()
    first = time.perf_counter() - t0
    t, n = median_time(run, repeats, 0.3)
    unknowns = topo.n_segments * topo.model.n_unknown
    return {
        "segments": topo.n_segments,
        "unknowns": unknowns,
        "ok": bool(ok),
        "iterations": int(sol.iterations),
        "compile_s": first - t,
        "solve_s": t,
        "per_iteration_s": t / max(int(sol.iterations), 1),
        "repeats": n,
        "tip": np.asarray(sol.tip.displacement)[[0, 2]].tolist(),
    }


def floor(repeats):
    """Pieces of one Newton iteration on ref-A L1, planar, default Integrator."""
    finger = fr.ref_finger_a("L1")
    topo = fr.topology_of(finger, "planar")
    integ = fr.Integrator()
    problem = _solve.make_problem(topo, integ, finger)
    y = problem.undeformed().reshape(-1)
    lam = jnp.ones(())
    S = topo.n_segments
    out = {"segments": S, "unknowns": y.shape[0], "steps_per_segment": integ.steps}

    # one RK (Tsit5) step of the planar rhs, from a long scan on one state
    md = PlanarRod()
    q = problem.params(lam)[0]
    n_steps = 20000

    @jax.jit
    def many(y0):
        f = lambda t, yy: md.rhs(t, yy, q)
        return lax.scan(
            lambda yy, i: (rk_step(integ.solver.tableau, f, 0.0, yy, 1e-3), None),
            y0,
            jnp.arange(n_steps),
        )[0]

    y0 = problem.start_states(y.reshape(S, -1))[0]
    jax.block_until_ready(many(y0))
    t, _ = median_time(lambda: jax.block_until_ready(many(y0)), 5, 0.3)
    out["rk_step_s"] = t / n_steps

    from finray_jax._flow import segment_flow

    starts = problem.start_states(y.reshape(S, -1))
    Q = problem.params(lam)
    flow = jax.jit(lambda Y0, Q: segment_flow(md, integ, Y0, Q))
    resid = jax.jit(lambda y: _solve.natural_residual(y, (problem, lam)))
    jacres = jax.jit(
        lambda y: jax.jacfwd(
            lambda v: (lambda o: (o, o))(_solve.natural_residual(v, (problem, lam))), has_aux=True
        )(y)
    )
    J, _ = jacres(y)

    @jax.jit
    def lu_solve(J, r):
        lu, piv = jax.scipy.linalg.lu_factor(J)
        return jax.scipy.linalg.lu_solve((lu, piv), r)

    @jax.jit
    def iteration(y):  # what one Newton iteration of _newton_lean does, less the bookkeeping
        J, r = jax.jacfwd(
            lambda v: (lambda o: (o, o))(_solve.natural_residual(v, (problem, lam))), has_aux=True
        )(y)
        return y - lu_solve(J, r)

    for name, fn, args in (
        ("segment_flow_s", flow, (starts, Q)),
        ("residual_s", resid, (y,)),
        ("residual_and_jacobian_s", jacres, (y,)),
        ("lu_factor_and_solve_s", lu_solve, (J, y)),
        ("newton_iteration_s", iteration, (y,)),
    ):
        jax.block_until_ready(fn(*args))
        out[name], _ = median_time(
            lambda fn=fn, args=args: jax.block_until_ready(fn(*args)), repeats, 0.3
        )
    # Work count of one iteration: Tsit5 has 6 stages per step; the Jacobian is formed by
    # forward mode through every segment (6 state + parameter tangents at once).
    out["rhs_evaluations_per_flow"] = S * integ.steps * 6
    out["rk_steps_per_flow"] = S * integ.steps
    out["flow_time_over_rk_steps"] = out["segment_flow_s"] / (S * integ.steps * out["rk_step_s"])
    out["lu_flops"] = 2.0 / 3.0 * y.shape[0] ** 3
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer sizes and repeats")
    ap.add_argument("--spatial", action="store_true", help="also 3-D mode (slow to compile)")
    args = ap.parse_args()
    cores = pin_to_one_core()
    repeats = 5 if args.quick else 15
    modes = ("planar", "spatial") if args.spatial else ("planar",)
    counts = (4, 8) if args.quick else (4, 8, 16, 32)
    steps = (5, 10) if args.quick else (5, 10, 20, 40)
    out = {"pinned_cores": cores, "machine": machine(), "crossbeams": [], "steps": []}
    for mode in modes:
        for n in counts:
            r = time_solve(finger_with_crossbeams(n), mode, fr.Integrator(), repeats)
            r.update(mode=mode, crossbeams=n)
            out["crossbeams"].append(r)
            print(
                f"{mode} {n:3d} crossbeams: {r['segments']:4d} segments, {r['unknowns']:5d} "
                f"unknowns, compile {r['compile_s']:6.1f} s, solve {1e3 * r['solve_s']:8.2f} ms"
                f" ({r['iterations']} it, {1e3 * r['per_iteration_s']:.2f} ms/it)",
                flush=True,
            )
        for k in steps:
            r = time_solve(fr.ref_finger_a("L1"), mode, fr.Integrator(steps=k), repeats)
            r.update(mode=mode, steps_per_segment=k)
            out["steps"].append(r)
            print(
                f"{mode} steps {k:3d}: compile {r['compile_s']:6.1f} s, solve "
                f"{1e3 * r['solve_s']:8.2f} ms ({r['iterations']} it, "
                f"{1e3 * r['per_iteration_s']:.2f} ms/it), tip {r['tip']}",
                flush=True,
            )
    fl = floor(repeats)
    out["floor_ref_a_L1_planar"] = fl
    print(
        "floor (ref-A L1 planar, one piece at a time): "
        + ", ".join(
            f"{k} {v * 1e6:.1f} us" if k.endswith("_s") else f"{k} {v:.3g}" for k, v in fl.items()
        ),
        flush=True,
    )
    path = write("scaling", out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
