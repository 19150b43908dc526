"""Batches of designs (finray_jax.batch.solve_batch): a vmapped batch (and the default
lax.map on CPU) equals a loop of single solves, bad members are flagged without touching
the others, new values never recompile, and sharding over several devices gives the same
answers.

The default tests share two compiled programs (vmap and map; the same outputs, value
names and chunk size): about 15 s each to compile on one core.
"""

import dataclasses
import os
import pathlib
import subprocess
import sys

import jax
import numpy as np
import pytest

import finray_jax as fr
from finray_jax import _solve, batch, design

ROOT = pathlib.Path(__file__).resolve().parents[1]
BASE = fr.ref_finger_a("L1")
OUTS = ("tip.dx", "tip.dz", "reaction.front.fx", "max_strain", "load_factor")
CHUNK = 4


def _values(**changes):
    """Six designs (two chunks of 4, the second padded); changes: name -> {row: value}."""
    v = {
        "adaptor.back_clamp_length": np.array([0.0, 3.0, 6.0, 9.0, 12.0, 5.0]),
        "crossbeams.front_s[2]": np.array([45.0, 44.0, 46.0, 43.0, 47.0, 45.5]),
        "crossbeams.thickness[1]": np.array([1.0, 0.9, 1.1, 1.2, 0.8, 1.0]),
        "material.E": np.full(6, 12.0),
    }
    for name, rows in changes.items():
        for i, x in rows.items():
            v[name][i] = x
    return v


def _single(values, i, options=fr.SolverOptions()):
    finger = design.set_design(BASE, {k: v[i] for k, v in values.items()})
    sol = fr.solve_finger(finger, mode="planar", options=options)
    out = design.evaluate_outputs(sol, finger, OUTS)
    return sol, {k: float(x) for k, x in out.items()}


@pytest.fixture(scope="module")
def clean():
    values = _values()
    return values, batch.solve_batch(BASE, values, OUTS, chunk_size=CHUNK)


@pytest.fixture(scope="module")
def clean_vmapped():
    values = _values()
    return values, batch.solve_batch(BASE, values, OUTS, chunk_size=CHUNK, vectorize=True)


@pytest.mark.parametrize("which", ["clean_vmapped", "clean"])
def test_batch_equals_loop_of_single_solves(request, which):
    """vmapped (vectorize=True), and the default (lax.map on CPU, vmapped elsewhere). A
    vmapped batch takes no chord steps (both branches of a batched lax.cond would run): it
    equals single solves with reuse_jacobian=False."""
    values, res = request.getfixturevalue(which)
    assert res.size == 6
    assert res.status.tolist() == ["converged"] * 6
    mapped = which == "clean" and jax.default_backend() == "cpu"
    options = fr.SolverOptions(reuse_jacobian=mapped)
    for i in range(6):
        sol, out = _single(values, i, options)
        assert int(res.iterations[i]) == int(sol.iterations)
        for k in OUTS:
            # Batched and single LU factorisations round differently: ~1e-13 relative.
            assert res.outputs[k][i] == pytest.approx(out[k], rel=1e-10), (i, k)
        assert res.max_residual[i] < 1e-10
    np.testing.assert_array_equal(res.inputs["material.E"], values["material.E"])


def test_invalid_members_are_flagged_and_leave_the_others_alone(clean):
    values, ref = clean
    # Row 1: NaN thickness. Row 4: crossbeam 2 moved past the load point at s = 60 (and
    # past crossbeam 3): another topology. Row 5: a negative modulus.
    bad = _values(
        **{
            "crossbeams.thickness[1]": {1: np.nan},
            "crossbeams.front_s[2]": {4: 70.0},
            "material.E": {5: -1.0},
        }
    )
    res = batch.solve_batch(BASE, bad, OUTS, chunk_size=CHUNK)
    assert res.status.tolist() == [
        "converged",
        "invalid",
        "converged",
        "converged",
        "invalid",
        "invalid",
    ]
    assert res.result[1] == batch.INVALID and res.iterations[1] == 0
    # each says why: the field and its value, or the rule and the values that break it
    assert res.message(1) == "crossbeams[1].thickness must be finite, got nan"
    assert res.message(4).startswith(
        "crossbeams 2 and 3 cross or touch: front_s 70.0 -> 60.0, back_s 47.434"
    )
    assert res.message(5) == "material.E must be positive, got -1.0"
    assert res.message(0) == "converged"
    for k in OUTS:
        assert np.all(np.isnan(res.outputs[k][[1, 4, 5]]))
        np.testing.assert_allclose(res.outputs[k][[0, 2, 3]], ref.outputs[k][[0, 2, 3]], rtol=1e-12)


@pytest.mark.slow
def test_crossing_members_are_invalid():
    """Members whose back beam, precurved, crosses the front beam (validate_finger's
    geometry rules) are flagged invalid, not solved; the others converge (compiles a
    batch of its own: ~20 s)."""
    kappa = np.array([0.0, 0.01, 0.004, 0.015])
    res = batch.solve_batch(BASE, {"back.curvature": kappa}, ["tip.dx"], chunk_size=CHUNK)
    assert res.status.tolist() == ["converged", "invalid", "converged", "invalid"]
    for k in kappa[[1, 3]]:
        with pytest.raises(fr.FingerError, match="the back beam crosses the front beam"):
            fr.validate_finger(design.set_design(BASE, {"back.curvature": k}))
    assert np.all(np.isnan(res.outputs["tip.dx"][[1, 3]]))
    assert np.all(np.isfinite(res.outputs["tip.dx"][[0, 2]]))


@pytest.mark.parametrize("vectorize", [True, None])
def test_new_values_never_recompile(clean, vectorize):
    """A second batch of the same shape with other values reuses the first's compiled
    program. The first batch is solved here, not taken from a fixture: the suite may clear
    jax's caches between tests (conftest's mapping limit), which would count as a trace."""
    values, _ = clean
    batch.solve_batch(BASE, values, OUTS, chunk_size=CHUNK, vectorize=vectorize)
    compiles = []
    listener = lambda event, duration, **kw: compiles.append(event)
    jax.monitoring.register_event_duration_secs_listener(listener)
    traces = batch._traces
    try:
        shifted = {k: v * 1.01 for k, v in values.items()}
        res = batch.solve_batch(BASE, shifted, OUTS, chunk_size=CHUNK, vectorize=vectorize)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert res.status.tolist() == ["converged"] * 6
    assert batch._traces == traces
    assert "/jax/core/compile/backend_compile_duration" not in compiles


def test_warm_started_batch_gives_the_same_answers_in_fewer_iterations(clean):
    """init=: every design starts Newton from the base finger's deformation carried onto
    its own undeformed shape. Counted in Newton iterations alone (no chord steps, which
    would make the counts a mix of costs)."""
    values, _ = clean
    newton = fr.SolverOptions(reuse_jacobian=False)
    ref = batch.solve_batch(BASE, values, OUTS, chunk_size=CHUNK, options=newton)
    base_sol = fr.solve_finger(BASE, mode="planar")
    res = batch.solve_batch(BASE, values, OUTS, chunk_size=CHUNK, init=base_sol, options=newton)
    assert res.status.tolist() == ["converged"] * 6
    for k in OUTS:
        # both converged to the root (tolerance 1e-10 on the scaled unknowns)
        np.testing.assert_allclose(res.outputs[k], ref.outputs[k], rtol=1e-8, atol=1e-12)
    assert np.all(res.iterations <= ref.iterations)
    assert res.iterations.sum() < ref.iterations.sum(), (res.iterations, ref.iterations)
    # each member is solved as a single solve from that start would be; the base finger's
    # unknowns themselves (which also carry its undeformed geometry: the clamp and
    # crossbeam 2 moved) are a worse start
    topo = fr.topology_of(BASE, "planar")
    deformation = _solve.deformation_of(topo, BASE, base_sol.unknowns)
    absolute = []
    for i in range(len(res.iterations)):
        finger = design.set_design(BASE, {k: v[i] for k, v in values.items()})
        start = _solve.start_from_deformation(topo, finger, deformation)
        single = _solve.direct_core(topo, fr.Integrator(), newton, finger, start)[0]
        assert int(single.iterations) == int(res.iterations[i])
        own = _solve.direct_core(topo, fr.Integrator(), newton, finger, base_sol.unknowns)[0]
        absolute.append(int(own.iterations))
    assert res.iterations.sum() < sum(absolute), (res.iterations, absolute)
    # the same finger: its own unknowns back, to round-off
    again = _solve.start_from_deformation(topo, BASE, deformation)
    np.testing.assert_allclose(again, base_sol.unknowns, rtol=0, atol=1e-14)


def test_bad_arguments():
    with pytest.raises(design.DesignError, match="unknown design value 'front.thicknes'"):
        batch.solve_batch(BASE, {"front.thicknes": np.ones(2)}, OUTS)
    with pytest.raises(
        design.DesignError, match=r"values\['material.E'\] has 3 designs, the others 2"
    ):
        batch.solve_batch(BASE, {"front.thickness": np.ones(2), "material.E": np.ones(3)}, OUTS)
    with pytest.raises(design.DesignError, match=r"must have shape \(B,\) \+ \(7,\)"):
        batch.solve_batch(BASE, {"crossbeams.front_s": np.ones(3)}, OUTS)
    with pytest.raises(design.DesignError, match="unknown output 'tip.d'"):
        batch.solve_batch(BASE, {"material.E": np.ones(2)}, ["tip.d"])
    with pytest.raises(ValueError, match="chunk_size must be a positive integer, got 0"):
        batch.solve_batch(BASE, {"material.E": np.ones(2)}, OUTS, chunk_size=0)
    with pytest.raises(TypeError, match="init must be a Solution of the base finger, got ndarray"):
        batch.solve_batch(BASE, {"material.E": np.ones(2)}, OUTS, init=np.zeros(144))
    planar = fr.solve_finger(BASE, mode="planar")
    spatial = dataclasses.replace(planar, mode="spatial")  # a mismatch of modes
    with pytest.raises(ValueError, match="init is a spatial solution with 144 unknowns"):
        batch.solve_batch(BASE, {"material.E": np.ones(2)}, OUTS, init=spatial)


def test_placement_follows_the_default_device():
    """Designs go where jax's default device is (set to the CPU on a GPU machine, the
    CPU's platform decides map against vmap and the chunk size), or to the devices given."""
    if jax.default_backend() != "cpu":
        pytest.skip(f"places on the CPU by default; the default backend is {jax.default_backend()}")
    cpu = jax.devices("cpu")[0]
    assert batch._placement(None) == (None, cpu, "cpu")
    assert batch._placement([cpu]) == (None, cpu, "cpu")
    with pytest.raises(ValueError, match="devices must name at least one device"):
        batch._placement([])
    old = jax.config.jax_default_device
    try:
        for setting in ("cpu", cpu):
            jax.config.update("jax_default_device", setting)
            assert batch._default_device() == cpu
    finally:
        jax.config.update("jax_default_device", old)
    assert batch.default_chunk_size("cpu") == 256
    assert batch.default_chunk_size("gpu") == 4096
    # off the CPU a chunk is vmapped unless told otherwise; on it, only the direct stage
    assert batch._vectorize(batch._full, None, "gpu", None) is True
    assert batch._vectorize(batch._full, None, "gpu", False) is False
    assert batch._vectorize(batch._full, None, "cpu", True) is False
    assert batch._vectorize(batch._direct, None, "cpu", True) is True
    assert batch._vectorize(batch._direct, None, "cpu", None) is False


@pytest.mark.slow
def test_overloaded_member_goes_to_its_fold_alone(clean):
    """A 120x softer finger is far beyond its limit load: continuation to the fold, while
    the others keep their direct solves (compiles the vmapped continuation: ~1.5 min)."""
    values, ref = clean
    res = batch.solve_batch(BASE, _values(**{"material.E": {2: 0.1}}), OUTS, chunk_size=CHUNK)
    assert res.status.tolist() == ["converged"] * 2 + ["beyond_limit_load"] + ["converged"] * 3
    assert 0 < res.outputs["load_factor"][2] < 1
    others = [0, 1, 3, 4, 5]
    for k in OUTS:
        np.testing.assert_allclose(res.outputs[k][others], ref.outputs[k][others], rtol=1e-12)
    sol, out = _single(_values(**{"material.E": {2: 0.1}}), 2)
    assert sol.status == "beyond_limit_load"
    for k in OUTS:
        assert res.outputs[k][2] == pytest.approx(out[k], rel=1e-9), k


_SHARDED = """
import jax, numpy as np
import finray_jax as fr
from finray_jax import batch
assert jax.device_count() == 2, jax.devices()
f = fr.ref_finger_a("L1")
v = {
    "crossbeams.thickness[1]": np.array([0.9, 1.0, 1.1]),
    "front.thickness": np.array([1.5, 1.6, np.nan]),
}
two = batch.solve_batch(f, v, ["tip.dx"], chunk_size=3)    # padded to 4 rows, 2 per device
one = batch.solve_batch(f, v, ["tip.dx"], chunk_size=3, devices=jax.devices()[:1])
assert two.status.tolist() == one.status.tolist() == ["converged", "converged", "invalid"]
np.testing.assert_allclose(two.outputs["tip.dx"], one.outputs["tip.dx"], rtol=1e-10)
print("OK")
"""


@pytest.mark.slow
def test_sharded_over_two_host_devices():
    """Two CPU devices in a subprocess: the chunk is padded and sharded (~1 min)."""
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    out = subprocess.run(
        [sys.executable, "-c", _SHARDED],
        env=env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("OK")
