"""The design optimiser (finray_jax.optimizer, `finray optimize`).

Fast tests: the optimisation file's errors, the bounds' reparameterisation, the design
constraints' margins and penalty, the progress log's truncation on resume. Slow tests
(marked; each shares one compiled objective per module fixture, as compiling a grasp's
gradient takes minutes on this machine): gradients against central finite differences,
the optimiser improving the contact force under bounds and constraints (each constraint
active: the constrained optimum respects a limit that the unconstrained one violates),
the holding-force gradient (envelope theorem), resuming an interrupted run and the CLI.
"""

import csv
import dataclasses
import json
import os
import shutil

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import finray_jax as fr
from finray_jax import optimizer as O
from finray_jax.cli import main

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")
FINGER = os.path.abspath(os.path.join(EXAMPLES, "grasp_finger1_modified.toml"))

CLAMP = """
finger = "{finger}"
[[design]]
name = "adaptor.back_clamp_length"
bounds = [16.5, 31.0]
[[design]]
name = "adaptor.support_length"
bounds = [48.0, 62.5]
[constraints]
max_strain = {strain}
max_pressure = {pressure}
[optimizer]
learning_rate = 0.3
iterations = {iterations}
"""


def _clamp_text(strain=10.0, pressure=100.0, iterations=6):
    return CLAMP.format(finger=FINGER, strain=strain, pressure=pressure, iterations=iterations)


def _load(text, tmp_path, name="opt.toml"):
    path = tmp_path / name
    path.write_text(text)
    return O.load_optimize(path)


# ---------------------------------------------------------------------------------------
# Files and errors
# ---------------------------------------------------------------------------------------


def test_example_files_load():
    for name in ("optimize_clamp.toml", "optimize_layout.toml"):
        p = O.load_optimize(os.path.join(EXAMPLES, name))
        assert p.design and all(d.lo < d.initial < d.hi for d in p.design)


@pytest.mark.parametrize(
    "change, match",
    [
        (('objective = "contact_force"', 'objective = "grip"'), r'objective = "grip": must be one of'),
        (("bounds = [16.5, 31.0]", "bounds = [31.0, 16.5]"), r"design\[0\].bounds = \[31.0, 16.5\]: needs lo < hi"),
        (("bounds = [48.0, 62.5]", "bounds = [48.0, 55.0]"), r"design\[1\].bounds = \[48.0, 55.0\]: the initial value 60.0"),
        (('name = "adaptor.back_clamp_length"', 'name = "adaptor.clamp"'), r'design\[0\].name = "adaptor.clamp": unknown design value'),
        (("max_strain = 10.0", "max_strain = -0.1"), r"constraints.max_strain = -0.1: must be positive"),
        (("max_strain = 10.0", "max_stress = 1.0"), r"constraints.max_stress = 1.0: unknown key"),
        (("learning_rate = 0.3", "learning_rate = 0"), r"optimizer.learning_rate = 0: must be positive"),
        (("iterations = 6", "iterations = 0"), r"optimizer.iterations = 0: must be an integer >= 1"),
        (("bounds = [16.5, 31.0]", "bounds = [16.5, 61.0]"), r"design: the bounds let the clamp \(up to 61.0 mm\) pass"),
        (('finger = "', 'finger = "nothere/'), r"finger = .*no such finger file"),
        (("[optimizer]", 'friction = 0.3\n[optimizer]'), r"friction = 0.3: .*is for objective"),
    ],
)
def test_bad_files_name_the_key_and_value(tmp_path, change, match):
    text = 'objective = "contact_force"\n' + _clamp_text()
    old, new = change
    assert old in text
    with pytest.raises(O.OptimizeError, match=match):
        _load(text.replace(old, new, 1), tmp_path)


def test_bad_file_through_the_cli_exits_1_without_traceback(tmp_path, capsys):
    path = tmp_path / "opt.toml"
    path.write_text(_clamp_text().replace("bounds = [16.5, 31.0]", "bounds = [31.0, 16.5]"))
    assert main(["optimize", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "design[0].bounds = [31.0, 16.5]: needs lo < hi" in err
    assert "Traceback" not in err


# ---------------------------------------------------------------------------------------
# Bounds and constraints without a solve
# ---------------------------------------------------------------------------------------


def test_reparameterisation_keeps_every_value_inside_its_bounds():
    lo, hi = np.array([16.5, -0.2]), np.array([31.0, 0.2])
    data = eqx.tree_at(lambda d: (d.lo, d.hi), _dummy_data(), (jnp.asarray(lo), jnp.asarray(hi)))
    for z in ([-40.0, 40.0], [40.0, -40.0], [0.0, 0.0], [3.0, -7.0]):
        x = np.asarray(O._design_of(data, jnp.asarray(z)))
        assert np.all(x >= lo) and np.all(x <= hi)
    x0 = np.array([20.0, 0.05])
    z0 = O._z_of(lo, hi, x0)
    np.testing.assert_allclose(np.asarray(O._design_of(data, jnp.asarray(z0))), x0, rtol=1e-14)


def _dummy_data(limits=(0.0,) * 5, scales=(1.0,) * 5):
    return O._Data(
        bases=None,
        lo=jnp.zeros(1),
        hi=jnp.ones(1),
        limits=jnp.asarray(limits, dtype=jnp.float64),
        scales=jnp.asarray(scales, dtype=jnp.float64),
        objective_scale=jnp.ones(()),
        temperature=jnp.asarray(0.02),
        weight=jnp.asarray(100.0),
        shift=jnp.asarray(0.01),
    )


def _static(constraints, aggregate="mean"):
    return O._Static(
        names=(),
        objective="contact_force",
        aggregate=aggregate,
        constraints=constraints,
        topology=None,
        direction=(-1.0, 0.0),
        pull=(0.0, 1.0),
        holding_factor=2,
        integrator=fr.Integrator(),
        options=fr.SolverOptions(),
    )


def test_design_constraint_margins_thickness_spacing_crossing():
    finger, _ = fr.io.load_finger(FINGER)
    cb = finger.crossbeams
    st = _static(("min_thickness", "min_spacing", "crossing"))
    data = _dummy_data(limits=(2.5, 4.0, 0.0, 0.0, 0.0), scales=(2.5, 4.0, 1.0, 1.0, 1.0))
    rel, true = O._design_margins(st, data, finger)
    # thinnest beam: the crossbeams' 2 mm, limit 2.5 mm
    assert float(true["min_thickness"]) == pytest.approx(2.0 - 2.5)
    gaps = np.concatenate([np.diff(np.asarray(cb.front_s)), np.diff(np.asarray(cb.back_s))])
    assert float(true["min_spacing"]) == pytest.approx(gaps.min() - 2.0 - 4.0)
    assert float(true["crossing"]) == pytest.approx(gaps.min())
    # crossbeam 3's back end moved past crossbeam 2's: crossed (negative margin)
    crossed = eqx.tree_at(lambda f: f.crossbeams.back_s, finger, cb.back_s.at[3].set(40.0))
    _, t2 = O._design_margins(st, data, crossed)
    assert float(t2["crossing"]) == pytest.approx(40.0 - float(cb.back_s[2]))
    assert float(t2["crossing"]) < 0


def test_worst_case_is_a_smooth_minimum_below_the_true_one():
    st = _static((), aggregate="worst")
    data = eqx.tree_at(lambda d: d.objective_scale, _dummy_data(), jnp.asarray(10.0))
    values = jnp.array([10.0, 10.5, 14.0])
    smooth, true = O._aggregate(st, data, values)
    T = 0.02 * 10.0
    assert float(true) == 10.0
    assert 10.0 - T * np.log(3) <= float(smooth) <= 10.0
    g = jax.grad(lambda v: O._aggregate(st, data, v)[0])(values)
    assert float(jnp.sum(g)) == pytest.approx(1.0) and float(g[0]) > float(g[1]) > float(g[2])


def test_progress_rows_after_the_checkpoint_are_dropped(tmp_path):
    path = str(tmp_path / "progress.csv")
    header = "iteration,objective\n"
    with open(path, "w") as fh:
        fh.write(header + "0,1.0\n1,2.0\n2,3.0\n3,4")  # torn last row
    O._truncate_rows(path, header, 2)
    assert open(path).read() == header + "0,1.0\n1,2.0\n"
    with pytest.raises(O.OptimizeError, match="has 2 rows but the checkpoint has 3"):
        O._truncate_rows(path, header, 3)
    with pytest.raises(O.OptimizeError, match="header"):
        O._truncate_rows(path, "iteration,loss\n", 1)
