"""Cost of a design gradient: implicit (finray_jax) against finite differences (peers).

Ten design values of ref-A: material E, front, back and crossbeam thickness (one value for
all seven crossbeams), and the front attachment arc length `front_s` of six crossbeams
(all but the one at s = 60, where the L1/L2 load acts). The finger is built from the
vector with `equinox.tree_at`. Outputs: the tip displacement x and the front base
reaction force x.

finray_jax: jax.value_and_grad (one output) and jax.jacrev (both outputs) through
solve_finger (implicit function theorem on the last root solve), jitted, against the
jitted forward solve from the same start; cold (undeformed guess) and warm (init = the
solution of the same design, as in an optimisation loop).
SciPy (benchmarks/scipy_procedure.py) and openseespy (tests/reference/opensees_ref_a.py,
the mesh peers.py chose): forward differences, 11 solves. The SciPy base solve starts cold
and the 10 perturbed solves start from its solution. openseespy cannot move a crossbeam on
its fixed mesh, so its 11 solves are the base, the four perturbed material/thickness
designs, and the base design again for the six positions (same cost per solve).

Run:  taskset -c 1 .venv/bin/python benchmarks/gradients.py [--quick] [--case L2]
"""

import argparse
import pathlib
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, median_time, pin_to_one_core, write

import finray_jax as fr

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "reference"))

NAMES = [
    "E",
    "front.thickness",
    "back.thickness",
    "crossbeam thickness",
    "front_s[0]",
    "front_s[1]",
    "front_s[2]",
    "front_s[4]",
    "front_s[5]",
    "front_s[6]",
]
MOVED = np.array([0, 1, 2, 4, 5, 6])


def design_vector(finger):
    cb = finger.crossbeams
    return jnp.concatenate(
        [
            jnp.stack(
                [finger.material.E, finger.front.thickness, finger.back.thickness, cb.thickness[0]]
            ),
            cb.front_s[MOVED],
        ]
    )


def finger_of(p, base):
    """The base finger with the ten design values p (works traced and eagerly)."""
    f = eqx.tree_at(lambda f: f.material.E, base, p[0])
    f = eqx.tree_at(lambda f: f.front.thickness, f, p[1])
    f = eqx.tree_at(lambda f: f.back.thickness, f, p[2])
    cb = f.crossbeams
    f = eqx.tree_at(lambda f: f.crossbeams.thickness, f, jnp.full_like(cb.thickness, p[3]))
    return eqx.tree_at(lambda f: f.crossbeams.front_s, f, cb.front_s.at[MOVED].set(p[4:]))


def finray_gradients(case, repeats):
    base = fr.ref_finger_a(case)
    topo = fr.topology_of(base, "planar")
    p0 = design_vector(base)

    def outputs(p, init):
        sol = fr.solve_finger(finger_of(p, base), mode="planar", topology=topo, init=init)
        return jnp.stack([sol.tip.displacement[0], sol.reactions_front.force[0]]), sol

    fwd = jax.jit(lambda p, init: outputs(p, init)[0])
    vg_tip = jax.jit(jax.value_and_grad(lambda p, init: outputs(p, init)[0][0]))
    vg_rx = jax.jit(jax.value_and_grad(lambda p, init: outputs(p, init)[0][1]))
    jac = jax.jit(jax.jacrev(lambda p, init: outputs(p, init)[0]))
    t0 = time.perf_counter()
    sol0 = jax.block_until_ready(fr.solve_finger(base, mode="planar"))
    print(f"{case}: eager solve_finger (compiles) {time.perf_counter() - t0:.1f} s", flush=True)
    # Cold = Newton from the undeformed state. solve_finger carries init.deformation onto
    # the design, so a Solution with zero deformation starts exactly as init=None does
    # (at the undeformed unknowns), and cold and warm share one compiled function.
    cold_init = eqx.tree_at(lambda s: s.deformation, sol0, jnp.zeros_like(sol0.deformation))
    rows = {}
    for name, fn in (
        ("forward", fwd),
        ("value_and_grad_tip_x", vg_tip),
        ("value_and_grad_reaction_x", vg_rx),
        ("jacrev_both", jac),
    ):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(p0, cold_init))
        first = time.perf_counter() - t0
        for start, init in (("cold", cold_init), ("warm", sol0)):
            t, n = median_time(
                lambda fn=fn, init=init: jax.block_until_ready(fn(p0, init)), repeats, 0.3
            )
            rows.setdefault(start, {})[name] = {"s": t, "repeats": n, "first_call_s": first}
        print(
            f"{case} {name}: first call {first:.1f} s, cold {1e3 * rows['cold'][name]['s']:.2f}"
            f" ms, warm {1e3 * rows['warm'][name]['s']:.2f} ms",
            flush=True,
        )
    for start, r in rows.items():
        for name in ("value_and_grad_tip_x", "value_and_grad_reaction_x", "jacrev_both"):
            r[name]["ratio_to_forward"] = r[name]["s"] / r["forward"]["s"]
        print(
            f"finray_jax {case} {start}: forward {1e3 * r['forward']['s']:.2f} ms, "
            f"grad tip {1e3 * r['value_and_grad_tip_x']['s']:.2f} ms "
            f"({r['value_and_grad_tip_x']['ratio_to_forward']:.2f}x), grad reaction "
            f"{r['value_and_grad_reaction_x']['ratio_to_forward']:.2f}x, jacrev (both) "
            f"{r['jacrev_both']['ratio_to_forward']:.2f}x",
            flush=True,
        )
    J = np.asarray(jac(p0, cold_init))
    y = np.asarray(fwd(p0, cold_init))
    return rows, J, y, np.asarray(p0), base


def fd_steps(p0):
    return 1e-6 * np.maximum(np.abs(p0), 1.0)


def scipy_fd(base, p0, J, y):
    from scipy_procedure import ShootingModel

    h = fd_steps(p0)
    t0 = time.perf_counter()
    sol = ShootingModel.from_finger(base).solve()
    t_base = time.perf_counter() - t0
    y0 = np.array([sol.tip_displacement[0], sol.reaction_front[0]])
    G = np.zeros((2, len(p0)))
    times = []
    for j in range(len(p0)):
        p = p0.copy()
        p[j] += h[j]
        t0 = time.perf_counter()
        s = ShootingModel.from_finger(finger_of(jnp.asarray(p), base)).solve(guess=sol.unknowns)
        times.append(time.perf_counter() - t0)
        G[:, j] = (np.array([s.tip_displacement[0], s.reaction_front[0]]) - y0) / h[j]
    agree = np.max(np.abs(G - J), axis=1) / np.max(np.abs(J), axis=1)
    print(
        f"SciPy FD: base {t_base:.2f} s (cold) + 10 warm perturbed {sum(times):.2f} s; "
        f"max |FD - implicit| / max |implicit|: tip {agree[0]:.1e}, reaction {agree[1]:.1e}",
        flush=True,
    )
    return {
        "base_cold_s": t_base,
        "perturbed_warm_s": times,
        "total_s": t_base + sum(times),
        "total_warm_base_s": float(np.median(times)) + sum(times),
        "fd_gradient": G.tolist(),
        "values": y0.tolist(),
        "agreement_with_implicit": agree.tolist(),
    }


def opensees_fd(base, p0, J, h_mesh, case):
    import opensees_ref_a as osr
    import openseespy.opensees as ops

    def solve(E, tf, tb, tc):
        saved = osr.E_MOD, osr.G_MOD, osr.T_FRONT, osr.T_BACK, osr.T_CROSS
        osr.E_MOD, osr.G_MOD = E, E / (2 * (1 + osr.NU))
        osr.T_FRONT, osr.T_BACK, osr.T_CROSS = tf, tb, tc
        try:
            for n in (1, 2, 5, 10, 20):
                fg = osr.Finger(h_mesh, 5.0 / 6.0)
                fg.apply_pattern(case)
                osr.static_analysis(("LoadControl", 1.0 / n), tol=1e-8)
                if all(ops.analyze(1) == 0 for _ in range(n)):
                    ops.reactions()
                    return np.array([ops.nodeDisp(fg.tip, 1), ops.nodeReaction(fg.front[0])[0]])
            raise RuntimeError("openseespy did not converge")
        finally:
            osr.E_MOD, osr.G_MOD, osr.T_FRONT, osr.T_BACK, osr.T_CROSS = saved

    h = fd_steps(p0)
    q0 = [float(v) for v in p0[:4]]
    t0 = time.perf_counter()
    y0 = solve(*q0)
    G = np.zeros((2, 4))
    for j in range(4):
        q = list(q0)
        q[j] += h[j]
        G[:, j] = (solve(*q) - y0) / h[j]
    for _ in range(6):
        solve(*q0)
    total = time.perf_counter() - t0
    agree = np.max(np.abs(G - J[:, :4]), axis=1) / np.max(np.abs(J[:, :4]), axis=1)
    print(
        f"openseespy FD (h = {h_mesh} mm): 11 solves {total:.2f} s; first four columns vs "
        f"implicit: tip {agree[0]:.1e}, reaction {agree[1]:.1e}",
        flush=True,
    )
    return {
        "h_mm": h_mesh,
        "total_s": total,
        "fd_gradient_first_four": G.tolist(),
        "agreement_with_implicit_first_four": agree.tolist(),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="L1 only, fewer repeats")
    ap.add_argument("--cases", default=None, help="comma list (default L1,L2)")
    ap.add_argument(
        "--opensees-h", type=float, default=2.5, help="openseespy mesh (peers.py's choice: 2.5 mm)"
    )
    args = ap.parse_args()
    cores = pin_to_one_core()
    cases = (args.cases or ("L1" if args.quick else "L1,L2")).split(",")
    repeats = 5 if args.quick else 15
    out = {
        "pinned_cores": cores,
        "machine": machine(),
        "design_values": NAMES,
        "outputs": ["tip displacement x", "front base reaction force x"],
        "cases": {},
    }
    for case in cases:
        rows, J, y, p0, base = finray_gradients(case, repeats)
        entry = {
            "finray_jax": rows,
            "implicit_jacobian": J.tolist(),
            "values": y.tolist(),
            "design": p0.tolist(),
        }
        # check: the tip scales as 1/E (dead loads), so E d(tip)/dE = -tip
        entry["check_E_dtip_dE_plus_tip"] = float(p0[0] * J[0, 0] + y[0])
        sp = scipy_fd(base, p0, J, y)
        osd = opensees_fd(base, p0, J, args.opensees_h, case)
        g = rows["cold"]["jacrev_both"]["s"]
        g1 = rows["cold"]["value_and_grad_tip_x"]["s"]
        sp["ratio_to_finray_jacrev_cold"] = sp["total_s"] / g
        sp["ratio_to_finray_grad_tip_cold"] = sp["total_s"] / g1
        osd["ratio_to_finray_jacrev_cold"] = osd["total_s"] / g
        osd["ratio_to_finray_grad_tip_cold"] = osd["total_s"] / g1
        entry["scipy_fd"], entry["opensees_fd"] = sp, osd
        out["cases"][case] = entry
    print("\ngradient of 10 design values (one core); ratio = time / finray_jax forward")
    for case, e in out["cases"].items():
        for start in ("cold", "warm"):
            r = e["finray_jax"][start]
            print(
                f"{case} finray_jax {start}: forward {1e3 * r['forward']['s']:8.2f} ms | "
                f"grad tip x {1e3 * r['value_and_grad_tip_x']['s']:8.2f} ms "
                f"({r['value_and_grad_tip_x']['ratio_to_forward']:.2f}x) | grad reaction x "
                f"({r['value_and_grad_reaction_x']['ratio_to_forward']:.2f}x) | both "
                f"{1e3 * r['jacrev_both']['s']:8.2f} ms "
                f"({r['jacrev_both']['ratio_to_forward']:.2f}x)"
            )
        print(
            f"{case} SciPy FD (11 solves): {e['scipy_fd']['total_s']:.2f} s = "
            f"{e['scipy_fd']['ratio_to_finray_jacrev_cold']:.0f}x finray_jax (both outputs)"
        )
        print(
            f"{case} openseespy FD (11 solves): {e['opensees_fd']['total_s']:.2f} s = "
            f"{e['opensees_fd']['ratio_to_finray_jacrev_cold']:.0f}x finray_jax (both outputs)"
        )
    path = write("gradients", out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
