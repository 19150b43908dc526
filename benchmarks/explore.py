"""Design explorer benchmark: the time from a control change to the new figure's data
(the solve from the previous equilibrium plus the arrays the page draws), for the load
case (a plain solve) and for the grasp of Finger-1 (modified adaptor, 18 mm cylinder,
closing 6 mm), pinned to one core. Compiles (at start-up) are reported apart.

Each change moves one control by one slider step from the state the previous change
left (back clamp length, E, crossbeam thickness, closing or load scale, alternately up
and down), as a slider drag does; the page's sensitivities (the tangent that predicts the
next equilibrium and draws the gradient bars) are refreshed after each change and timed
apart, as the page computes them once the figure is out.

    taskset -c 0 python benchmarks/explore.py [--quick]
"""

import argparse
import statistics
import time

import jax
from _common import machine, pin_to_one_core, write  # noqa: I001

from finray_jax import io as fio
from finray_jax._explore_design import BY_NAME, Choices, choices_of, values_of
from finray_jax._explore_grad import sensitivities
from finray_jax._explore_model import Explorer
from finray_jax._explore_views import view_of

MOVES = {
    "grasp": ("back_clamp_length", "E", "crossbeam_thickness", "closing"),
    "solve": ("back_clamp_length", "E", "crossbeam_thickness", "load_scale"),
}


def _case(explorer, choices, values, changes):
    t = time.perf_counter()
    state = explorer.solve(choices, values)
    view_of(state)
    first = time.perf_counter() - t
    t = time.perf_counter()
    explorer.sensitivities = sensitivities(explorer, state)
    sens_compile = time.perf_counter() - t
    update, sens, how = [], [], []
    for k in range(changes):
        name = MOVES[choices.mode][k % len(MOVES[choices.mode])]
        sign = 1.0 if (k // len(MOVES[choices.mode])) % 2 == 0 else -1.0
        values = dict(values, **{name: values[name] + sign * BY_NAME[name].step})
        t = time.perf_counter()
        state = explorer.solve(choices, values)
        view_of(state)
        update.append(time.perf_counter() - t)
        how.append(state.how)
        assert state.converged, state.message
        t = time.perf_counter()
        explorer.sensitivities = sensitivities(explorer, state)
        jax.block_until_ready(explorer.sensitivities.d_unknowns)
        sens.append(time.perf_counter() - t)
    return {
        "first_solve_s (compiles)": first,
        "sensitivities_first_s (compiles)": sens_compile,
        "update_median_ms": 1e3 * statistics.median(update),
        "update_p90_ms": 1e3 * sorted(update)[int(0.9 * (len(update) - 1))],
        "update_min_ms": 1e3 * min(update),
        "sensitivities_median_ms": 1e3 * statistics.median(sens),
        "changes": changes,
        "warm_fraction": how.count("warm") / len(how),
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer changes")
    args = ap.parse_args()
    cores = pin_to_one_core()
    changes = 8 if args.quick else 24
    finger, settings = fio.load_packaged_finger("grasp_finger1_modified.toml")
    explorer = Explorer(finger, settings.grasp)
    values = values_of(finger, settings.grasp.closing)
    grasp = choices_of(finger)
    results = {"machine": machine(), "pinned_cores": cores, "cases": {}}
    for name, choices in (("load case (plain solve)", Choices(mode="solve")), ("grasp", grasp)):
        r = _case(explorer, choices, values, changes)
        results["cases"][name] = r
        print(
            f"{name:24s} change -> figure data: median {r['update_median_ms']:.1f} ms "
            f"(p90 {r['update_p90_ms']:.1f}, min {r['update_min_ms']:.1f}; "
            f"{100 * r['warm_fraction']:.0f} % warm); sensitivities "
            f"{r['sensitivities_median_ms']:.1f} ms; "
            f"first solve {r['first_solve_s (compiles)']:.1f} s, "
            f"first sensitivities {r['sensitivities_first_s (compiles)']:.1f} s (compiles)"
        )
    print(f"wrote {write('explore', results)}")


if __name__ == "__main__":
    main()
