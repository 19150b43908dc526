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
import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import finray_jax as fr
from finray_jax import _objective as OBJ
from finray_jax import io as fio
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
        (
            ('objective = "contact_force"', 'objective = "grip"'),
            r'objective = "grip": must be one of',
        ),
        (
            ("bounds = [16.5, 31.0]", "bounds = [31.0, 16.5]"),
            r"design\[0\].bounds = \[31.0, 16.5\]: needs lo < hi",
        ),
        (
            ("bounds = [48.0, 62.5]", "bounds = [48.0, 55.0]"),
            r"design\[1\].bounds = \[48.0, 55.0\]: the initial value 60.0",
        ),
        (
            ('name = "adaptor.back_clamp_length"', 'name = "adaptor.clamp"'),
            r'design\[0\].name = "adaptor.clamp": unknown design value',
        ),
        (
            ("max_strain = 10.0", "max_strain = -0.1"),
            r"constraints.max_strain = -0.1: must be positive",
        ),
        (("max_strain = 10.0", "max_stress = 1.0"), r"constraints.max_stress = 1.0: unknown key"),
        (
            ("learning_rate = 0.3", "learning_rate = 0"),
            r"optimizer.learning_rate = 0: must be positive",
        ),
        (
            ("iterations = 6", "iterations = 0"),
            r"optimizer.iterations = 0: must be an integer >= 1",
        ),
        (
            ("bounds = [16.5, 31.0]", "bounds = [16.5, 61.0]"),
            r"design: the bounds let the clamp \(up to 61.0 mm\) pass",
        ),
        (('finger = "', 'finger = "nothere/'), r"finger = .*no such finger file"),
        (
            ('objective = "contact_force"', 'objective = "contact_force"\nfriction = 0.3'),
            r"friction = 0.3: .*is for objective",
        ),
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


def _one_design(name, bounds, more=""):
    return f'finger = "{FINGER}"\n[[design]]\nname = "{name}"\nbounds = {bounds}\n{more}'


_EVERY = "; every value in [lo, hi] must give a valid finger"


@pytest.mark.parametrize(
    "name, bounds, message",
    [
        (
            "front.thickness",
            "[-3.0, 3.0]",
            "front.thickness = -3.0 (the bound lo) makes the finger invalid: front.thickness "
            "must be positive, got -3.0",
        ),
        (
            "material.E",
            "[0.0, 20.0]",
            "material.E = 0.0 (the bound lo) makes the finger invalid: material.E must be "
            "positive, got 0.0",
        ),
        (
            "material.nu",
            "[0.3, 0.5]",
            "material.nu = 0.5 (the bound hi) makes the finger invalid: material.nu must lie in "
            "(-1, 0.5), got 0.5",
        ),
        (
            "crossbeams.depth[2]",
            "[0.0, 30.0]",
            "crossbeams.depth[2] = 0.0 (the bound lo) makes the finger invalid: "
            "crossbeams[2].depth must be positive, got 0.0",
        ),
        (
            "adaptor.back_clamp_length",
            "[-1.0, 25.0]",
            "adaptor.back_clamp_length = -1.0 (the bound lo) makes the finger invalid: "
            "adaptor.back_clamp_length must lie in [0, 126.491), got -1.0",
        ),
        (
            "adaptor.front_clamp_length",
            "[0.0, 5.0]",
            "adaptor.front_clamp_length = 5.0 (the bound hi) makes the finger invalid: "
            "adaptor.front_clamp_length = 5.0 needs adaptor.front_base = 'clamped', got 'pinned'",
        ),
        (
            "adaptor.support_length",
            "[50.0, 200.0]",
            "adaptor.support_length = 200.0 (the bound hi) makes the finger invalid: "
            "adaptor.support_length = 200.0 must lie in [back_clamp_length, back beam length]",
        ),
        (
            "crossbeams.front_s[6]",
            "[100.0, 130.0]",
            "crossbeams.front_s[6] = 130.0 (the bound hi) makes the finger invalid: "
            "crossbeams[6].front_s = 130.0 lies outside the front beam (0, 120)",
        ),
        (
            "crossbeams.front_s[4]",
            "[70.0, 95.0]",
            "crossbeams.front_s[4] = 95.0 (the bound hi) makes the finger invalid: crossbeams 4 "
            "and 5 cross or touch: front_s 95.0 -> 90.0",
        ),
        (
            "crossbeams.angle[4]",
            "[-1.2, 0.2]",
            "crossbeams.angle[4] = -1.2 (the bound lo) makes the finger invalid: "
            "crossbeams[4].back_s = -206.1",
        ),
    ],
)
def test_bounds_that_allow_an_invalid_finger_are_refused(tmp_path, name, bounds, message):
    """Every value between the bounds must make a valid finger: checked at both ends
    when the file is read (a thickness in [-3, 3] is refused)."""
    with pytest.raises(O.OptimizeError) as e:
        _load(_one_design(name, bounds), tmp_path)
    msg = str(e.value)
    assert msg.startswith(f"{tmp_path / 'opt.toml'}: design[0].bounds = {bounds}: {message}"), msg
    assert msg.endswith(_EVERY)


def test_bounds_that_keep_the_finger_valid_are_accepted(tmp_path):
    _load(_one_design("crossbeams.angle[4]", "[-0.2, 0.2]"), tmp_path)
    _load(_one_design("front.thickness", "[0.5, 6.0]"), tmp_path)
    # neighbours that both move may overlap: the crossing constraint keeps them apart
    both = _one_design(
        "crossbeams.front_s[4]",
        "[70.0, 95.0]",
        '[[design]]\nname = "crossbeams.front_s[5]"\nbounds = [80.0, 98.0]\n',
    )
    assert "crossing" in _load(both, tmp_path).active_constraints()
    # the clamp and the support's end, both moving: their bounds are compared together
    both = _one_design(
        "adaptor.back_clamp_length",
        "[16.5, 61.0]",
        '[[design]]\nname = "adaptor.support_length"\nbounds = [62.0, 70.0]\ninitial = 65.0\n',
    )
    _load(both, tmp_path)


DIAMETERS = "[objects]\ndiameters = [18.0, 35.0]\n"


@pytest.mark.parametrize(
    "height, spans",
    [("500.0", "z = 491 to 509 mm"), ("-30.0", "z = -39 to -21 mm")],
)
def test_object_height_out_of_reach_is_refused_when_the_file_is_read(tmp_path, height, spans):
    """objects.height that puts the cylinders out of the finger's reach: refused at parse
    time naming the key (it failed at the first grasp, naming a generated objects[0])."""
    text = _clamp_text() + DIAMETERS + f"height = {height}\n"
    with pytest.raises(O.OptimizeError) as e:
        _load(text, tmp_path)
    msg = str(e.value)
    assert msg.startswith(
        f"{tmp_path / 'opt.toml'}: objects.height = {height}: the cylinder of "
        "objects.diameters[0] = 18 mm (0.5 mm clear of the front beam), placed at this "
        "height, is outside the reach of the finger: "
    )
    assert f"(the cylinder spans {spans}, the beams z = 0 to 120 mm)" in msg
    # in reach: accepted (an edge of the finger's span)
    _load(text.replace(f"height = {height}", "height = 125.0"), tmp_path)


def test_object_height_error_through_the_cli_before_any_solve(tmp_path, capsys):
    path = tmp_path / "opt.toml"
    path.write_text(_clamp_text() + DIAMETERS + "height = 500.0\n")
    out = tmp_path / "out"
    code = main(["optimize", str(path), "--out", str(out)])
    captured = capsys.readouterr()
    err = captured.err
    assert code == 1 and captured.out == "" and "Traceback" not in err
    assert err.startswith(f"finray: error: {path}: objects.height = 500.0: the cylinder")
    assert not out.exists()


def test_objects_behind_the_finger_are_refused_when_the_file_is_read(tmp_path):
    """A closing direction that moves the finger away from its object: refused at parse
    time, naming the optimisation file's finger key and the finger file."""
    text = open(FINGER).read()
    assert "direction = [-1.0, 0.0]" in text
    backward = tmp_path / "backward.toml"
    backward.write_text(text.replace("direction = [-1.0, 0.0]", "direction = [1.0, 0.0]"))
    opt = _clamp_text().replace(FINGER, str(backward))
    with pytest.raises(O.OptimizeError) as e:
        _load(opt, tmp_path)
    assert str(e.value) == (
        f'{tmp_path / "opt.toml"}: finger = "{backward}": {backward}: objects[0] (circle) lies '
        "behind the finger: closing along [1.0, 0.0] moves the finger away from it"
    )
    with pytest.raises(O.OptimizeError) as e:
        _load(opt + DIAMETERS, tmp_path)
    assert str(e.value) == (
        f'{tmp_path / "opt.toml"}: finger = "{backward}": the cylinder of objects.diameters[0] = '
        "18 mm (0.5 mm clear of the front beam) lies behind the finger: closing along [1.0, 0.0] "
        "moves the finger away from it (the closing direction of the finger file's [grasp])"
    )


# ---------------------------------------------------------------------------------------
# Bounds and constraints without a solve
# ---------------------------------------------------------------------------------------


def test_holding_force_friction_defaults_to_the_finger_files(tmp_path):
    finger_50 = os.path.abspath(os.path.join(EXAMPLES, "grasp_finger1_modified_50mm.toml"))
    f_file = float(fio.load_finger(finger_50)[0].contact.friction)
    assert f_file > 0
    text = CLAMP.format(finger=finger_50, strain=10.0, pressure=100.0, iterations=2)
    held = _load('objective = "holding_force"\n' + text, tmp_path)
    assert held.friction == f_file
    assert _load('objective = "holding_force"\nfriction = 0.0\n' + text, tmp_path).friction == 0
    assert _load(text, tmp_path).friction == 0  # the closing's contact force: frictionless


def test_best_design_files_hold_each_optimised_object_and_the_friction(tmp_path):
    """best.toml (and best_object<i>.toml for more objects) are finger files with the
    design values, the object as the optimiser placed it and the release's friction."""
    text = CLAMP.format(finger=FINGER, strain=10.0, pressure=100.0, iterations=2)
    extra = 'objective = "holding_force"\nfriction = 0.4\n[objects]\ndiameters = [20.0, 35.0]\n'
    text = text.replace("[[design]]", extra + "[[design]]", 1)
    p = _load(text, tmp_path)
    x = np.array([18.0, 50.0])
    anchors = types.SimpleNamespace(stiffness=np.array([[3.0, 30.0], [4.0, 40.0]]))  # (k, k_s)
    texts = O._best_tomls(p, x, 3, 1.25, anchors)
    assert len(texts) == 2
    assert O._best_path("d/best.toml", 1) == "d/best_object1.toml"
    for text, want, base in zip(texts, p.diameters, p.object_fingers(), strict=True):
        finger, _ = fio.loads_finger(text)
        assert finger.n_crossbeams == p.finger.n_crossbeams
        assert float(finger.adaptor.back_clamp_length) == 18.0
        assert float(finger.adaptor.support_length) == 50.0
        assert float(finger.contact.friction) == 0.4
        (obj,) = finger.objects
        assert float(obj.radius) == pytest.approx(0.5 * want, rel=1e-15)
        np.testing.assert_allclose(obj.center, base.objects[0].center, rtol=1e-15)
    assert "best_object1.toml" in texts[0] and "best.toml" in texts[1]


def test_reparameterisation_keeps_every_value_inside_its_bounds():
    lo, hi = np.array([16.5, -0.2]), np.array([31.0, 0.2])
    data = eqx.tree_at(lambda d: (d.lo, d.hi), _dummy_data(), (jnp.asarray(lo), jnp.asarray(hi)))
    for z in ([-40.0, 40.0], [40.0, -40.0], [0.0, 0.0], [3.0, -7.0]):
        x = np.asarray(OBJ.design_of(data, jnp.asarray(z)))
        assert np.all(x >= lo) and np.all(x <= hi)
    x0 = np.array([20.0, 0.05])
    z0 = OBJ.z_of(lo, hi, x0)
    np.testing.assert_allclose(np.asarray(OBJ.design_of(data, jnp.asarray(z0))), x0, rtol=1e-14)


def _dummy_data(limits=(0.0,) * 5, scales=(1.0,) * 5):
    return OBJ.Data(
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
    return OBJ.Static(
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
    rel, true = OBJ._design_margins(st, data, finger)
    # thinnest beam: the crossbeams' 2 mm, limit 2.5 mm
    assert float(true["min_thickness"]) == pytest.approx(2.0 - 2.5)
    gaps = np.concatenate([np.diff(np.asarray(cb.front_s)), np.diff(np.asarray(cb.back_s))])
    assert float(true["min_spacing"]) == pytest.approx(gaps.min() - 2.0 - 4.0)
    assert float(true["crossing"]) == pytest.approx(gaps.min())
    # crossbeam 3's back end moved past crossbeam 2's: crossed (negative margin)
    crossed = eqx.tree_at(lambda f: f.crossbeams.back_s, finger, cb.back_s.at[3].set(40.0))
    _, t2 = OBJ._design_margins(st, data, crossed)
    assert float(t2["crossing"]) == pytest.approx(40.0 - float(cb.back_s[2]))
    assert float(t2["crossing"]) < 0


def test_worst_case_is_a_smooth_minimum_below_the_true_one():
    st = _static((), aggregate="worst")
    data = eqx.tree_at(lambda d: d.objective_scale, _dummy_data(), jnp.asarray(10.0))
    values = jnp.array([10.0, 10.5, 14.0])
    smooth, true = OBJ._aggregate(st, data, values)
    T = 0.02 * 10.0
    assert float(true) == 10.0
    assert 10.0 - T * np.log(3) <= float(smooth) <= 10.0
    g = jax.grad(lambda v: OBJ._aggregate(st, data, v)[0])(values)
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


def test_a_header_without_a_checkpoint_starts_afresh(tmp_path):
    """Stopped between writing the progress header and the first checkpoint: nothing was
    computed, so the run starts again; a data row without a checkpoint is refused."""
    p = _load(_clamp_text(), tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "progress.csv").write_text("iteration,objective\n")
    assert O._load_checkpoint(p, str(out)) is None
    (out / "progress.csv").write_text("iteration,objective\n0,1.0\n")
    with pytest.raises(O.OptimizeError, match="without a checkpoint.json"):
        O._load_checkpoint(p, str(out))


def test_cli_exit_code_of_a_failed_optimisation(tmp_path, monkeypatch, capsys):
    """A run that stopped because an iteration could not be solved exits 3, not 0."""
    reason = "iteration 1: no step (halved 6 times) could be solved"

    def stopped(problem, out_dir, **kw):
        csv_path = str(tmp_path / "progress.csv")
        return O.OptimizeRun(1, True, reason, 1.0, None, csv_path, None, (), failed=True)

    monkeypatch.setattr(O, "run_optimize", stopped)
    path = tmp_path / "opt.toml"
    path.write_text(_clamp_text())
    assert main(["optimize", str(path), "--out", str(tmp_path / "out")]) == 3
    assert reason in capsys.readouterr().out


def test_the_stop_is_decided_by_the_current_settings(tmp_path):
    """iterations, tolerance and patience may change between runs: a finished run goes on
    when they are raised (the stall is counted again with the new tolerance)."""
    p = _load(_clamp_text(iterations=6), tmp_path)
    rows = [(10.0, True), (10.5, True), (10.5002, True), (10.5003, True), (10.5003, False)]
    assert O._stall(p, rows[:4]) == 2 and O._stall(p, rows) == 0
    p3 = dataclasses.replace(p, tolerance=1e-4, patience=2)
    assert O._stop_reason(p3, {"rows": 4, "stall": O._stall(p3, rows[:4])}).startswith("converged")
    p_tight = dataclasses.replace(p3, tolerance=1e-6)
    assert O._stall(p_tight, rows[:4]) == 0
    assert O._stop_reason(p_tight, {"rows": 4, "stall": 0}) == ""
    assert O._stop_reason(p_tight, {"rows": 6, "stall": 0}) == "reached iterations = 6"
    longer = dataclasses.replace(p_tight, iterations=8)
    assert O._stop_reason(longer, {"rows": 6, "stall": 0}) == ""


# ---------------------------------------------------------------------------------------
# The clamp problem (l_c, l_s): one compiled objective for every run below
# ---------------------------------------------------------------------------------------


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def loose(tmp_path_factory):
    """The clamp problem with limits far away (inactive): its run and its rows."""
    d = tmp_path_factory.mktemp("loose")
    p = _load(_clamp_text(iterations=6), d)
    run = O.run_optimize(p, d / "out", plot=False)
    return p, run, _rows(run.csv)


def _pressure(row, limit):
    return limit - float(row["margin.max_pressure"])


@pytest.mark.slow
def test_optimizer_improves_the_contact_force_within_the_bounds(loose):
    p, run, rows = loose
    assert run.rows == len(rows) == 6 and run.finished
    objective = [float(r["objective"]) for r in rows]
    assert run.best["objective"] > 1.05 * objective[0]  # +15 % in 25 iterations: see docs
    assert objective[-1] > objective[0]
    for r in rows:
        for d in p.design:
            assert d.lo < float(r[d.name]) < d.hi
    assert all(m >= 0 for m in run.best["margins"].values())
    # the best design file reproduces the best objective through a fresh grasp
    finger, settings = fr.io.load_finger(run.best_toml)
    k, k_s = (jnp.asarray(float(v)) for v in O._setup(p).anchors.stiffness[0])
    g = fr.grasp(
        eqx.tree_at(
            lambda f: (f.contact.stiffness, f.contact.support_stiffness),
            finger,
            (k, k_s),
            is_leaf=lambda x: x is None,
        ),
        settings.grasp.closing,
        stiffen=False,
    )
    assert float(g.contact.normal_force) == pytest.approx(run.best["objective"], rel=1e-6)


@pytest.mark.slow
def test_pressure_limit_is_respected_where_the_unconstrained_optimum_violates_it(loose, tmp_path):
    _, run0, rows0 = loose
    p_init = _pressure(rows0[0], 100.0)
    p_free = _pressure(rows0[int(run0.best["iteration"])], 100.0)
    assert p_free > p_init  # the unconstrained optimiser presses harder
    limit = 0.5 * (p_init + p_free)
    p = _load(_clamp_text(pressure=limit, iterations=6), tmp_path)
    run = O.run_optimize(p, tmp_path / "out", plot=False)
    best = run.best
    assert best["margins"]["max_pressure"] >= 0  # the limit holds at the saved design
    assert _pressure({"margin.max_pressure": best["margins"]["max_pressure"]}, limit) <= limit
    assert best["objective"] > float(rows0[0]["objective"])  # still an improvement
    assert best["objective"] < run0.best["objective"]  # the limit costs force
    # rows that violate it are never the best
    for r in _rows(run.csv):
        if float(r["margin.max_pressure"]) < 0:
            assert int(r["feasible"]) == 0


@pytest.mark.slow
def test_strain_limit_is_respected(loose, tmp_path):
    """A strain limit below the initial design's strain: the initial design is infeasible,
    the optimiser's best design respects the limit."""
    _, _, rows0 = loose
    e_init = 10.0 - float(rows0[0]["margin.max_strain"])
    e_min = min(10.0 - float(r["margin.max_strain"]) for r in rows0)
    assert e_min < e_init
    limit = 0.5 * (e_init + e_min)
    p = _load(_clamp_text(strain=limit, iterations=6), tmp_path)
    run = O.run_optimize(p, tmp_path / "out", plot=False)
    rows = _rows(run.csv)
    assert float(rows[0]["margin.max_strain"]) < 0 and int(rows[0]["feasible"]) == 0
    assert run.best is not None and run.best["margins"]["max_strain"] >= 0


@pytest.mark.slow
def test_interrupted_run_resumes_without_losing_or_repeating_rows(loose, tmp_path):
    p, run0, rows0 = loose
    out = tmp_path / "out"
    first = O.run_optimize(p, out, max_iterations=3, plot=False)
    assert first.rows == 3 and not first.finished
    # a row written after the checkpoint (killed in between) and a torn line
    with open(first.csv, "a") as fh:
        fh.write("3,999.0,0,0,1,0,20.0,60.0,1,1,999.0,1.0\n4,99")
    second = O.run_optimize(p, out, plot=False)
    rows = _rows(second.csv)
    assert [int(r["iteration"]) for r in rows] == list(range(6))
    for a, b in zip(rows, rows0):  # the same iterates as the uninterrupted run
        assert float(a["objective"]) == pytest.approx(float(b["objective"]), rel=1e-9)
        for d in p.design:
            assert float(a[d.name]) == pytest.approx(float(b[d.name]), rel=1e-9)
    assert second.finished
    # more iterations and patience (the same problem otherwise): the finished run goes on
    longer = dataclasses.replace(p, iterations=8, patience=100)
    third = O.run_optimize(longer, out, plot=False)
    assert third.finished and [int(r["iteration"]) for r in _rows(third.csv)] == list(range(8))
    # another problem in the same directory is refused
    other = _load(_clamp_text(pressure=50.0), tmp_path, "other.toml")
    with pytest.raises(O.OptimizeError, match="holds another optimisation"):
        O.run_optimize(other, out, plot=False)


@pytest.mark.slow
def test_cli_optimize(loose, tmp_path, capsys):
    path = tmp_path / "opt.toml"
    path.write_text(_clamp_text(iterations=2))
    out = tmp_path / "out"
    assert main(["optimize", str(path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "best (iteration" in text and "wrote" in text
    for name in ("progress.csv", "best.toml", "result.json", "design.png", "convergence.png"):
        assert (out / name).is_file(), name
    res = json.loads((out / "result.json").read_text())
    assert res["rows"] == 2 and res["best"]["objective"] > res["initial_objective"]
    best = (out / "best.toml").read_text()
    assert "penalty stiffness of the initial design fixed (k = " in best
    fio.load_finger(str(out / "best.toml"))  # (the comments keep it a finger file)


# ---------------------------------------------------------------------------------------
# Gradients against central finite differences
# ---------------------------------------------------------------------------------------

LAYOUT = """
finger = "{finger}"
objective = "{objective}"
[[design]]
name = "adaptor.back_clamp_length"
bounds = [16.5, 31.0]
[[design]]
name = "adaptor.support_length"
bounds = [48.0, 52.0]
initial = 50.0
[[design]]
name = "crossbeams.front_s[3]"
bounds = [55.0, 65.0]
[[design]]
name = "crossbeams.back_s[3]"
bounds = [53.0, 70.0]
[[design]]
name = "crossbeams.thickness[2]"
bounds = [1.0, 3.0]
[[design]]
name = "crossbeams.angle[4]"
bounds = [-0.2, 0.2]
[constraints]
min_thickness = 0.5
min_spacing = {spacing}
"""


def _fd_check(p, setup, z0, values_at, h=1e-4):
    """Gradient of the objective (object 0) in z by the IFT against central differences
    of the same discrete model at the same warm start and penalty stiffness."""
    (loss, aux), grad = OBJ.loss_and_grad(z0, setup.static, setup.data, setup.anchors)
    assert float(aux["penalty"]) == 0.0  # so d loss = -d J / J0 (J0 = 1 here)
    errors = {}
    for j, name in enumerate(p.names):
        e = jnp.zeros_like(z0).at[j].set(h)
        fd = (values_at(z0 + e) - values_at(z0 - e)) / (2 * h)
        errors[name] = abs(-float(grad[j]) - fd) / abs(fd)
    return errors


@pytest.mark.slow
def test_contact_force_gradient_matches_central_differences(tmp_path):
    p = _load(LAYOUT.format(finger=FINGER, objective="contact_force", spacing=1.0), tmp_path)
    setup = O._setup(p)
    z0 = jnp.asarray(OBJ.z_of(p.lo, p.hi, p.x0), jnp.float64)

    def values_at(z):
        (_, aux), _ = OBJ.loss_and_grad(z, setup.static, setup.data, setup.anchors)
        assert bool(aux["converged"][0])
        return float(aux["values"][0])

    errors = _fd_check(p, setup, z0, values_at)
    # relative error of the IFT gradient: Newton converges to ~1e-12, h = 1e-4 in z
    # leaves a truncation error ~1e-8 relative: 1e-5 is far above both
    assert max(errors.values()) < 1e-5, errors


@pytest.mark.slow
def test_reanchoring_keeps_the_initial_discretisation(tmp_path):
    """After a failed warm start the optimiser grasps afresh at the trial design. At a
    support length of 48.2 mm that finger's own cuts give the back beam one segment more
    (384 unknowns instead of 378), which the compiled loss cannot take: the re-grasp must
    be solved on the initial grasps' segment table."""
    p = _load(_clamp_text(iterations=1), tmp_path)
    setup = O._setup(p)
    x = np.array([17.09, 48.24])
    moved = fr.design.set_design(p.object_fingers()[0], dict(zip(p.names, x.tolist())))
    own = fr.topology_of(moved, "planar").band.n
    assert own != setup.grasps[0].topology.band.n  # (the case is not vacuous)
    anchors = O._reanchor(p, setup, x, setup.anchors, lambda m: None)
    assert anchors is not None
    assert anchors.unknowns.shape == setup.anchors.unknowns.shape
    z = jnp.asarray(OBJ.z_of(p.lo, p.hi, x), jnp.float64)
    _, aux = OBJ.loss_only(z, setup.static, setup.data, anchors)
    assert bool(jnp.all(aux["converged"])) and bool(aux["valid"])
    np.testing.assert_allclose(aux["x"], x, rtol=1e-12)


@pytest.mark.slow
def test_spacing_limit_is_respected_where_the_unconstrained_optimum_violates_it(tmp_path):
    """Crossbeam 3's back end moves down toward crossbeam 2's (more contact force); a
    minimum clear spacing stops it."""
    runs = {}
    for spacing in (0.0, 12.0):
        d = tmp_path / f"s{spacing:g}"
        d.mkdir()
        text = LAYOUT.format(finger=FINGER, objective="contact_force", spacing=spacing)
        p = _load(text + "[optimizer]\nlearning_rate = 0.3\niterations = 6\n", d)
        runs[spacing] = O.run_optimize(p, d / "out", plot=False)
    free, limited = runs[0.0].best, runs[12.0].best
    # clear gap of the unconstrained optimum (limit 0): violates 12 mm
    assert free["margins"]["min_spacing"] < 12.0
    assert limited["margins"]["min_spacing"] >= 0.0
    assert limited["margins"]["crossing"] > 0 and free["margins"]["crossing"] > 0


@pytest.mark.slow
def test_holding_force_gradient_is_the_envelope_gradient(tmp_path):
    """d(peak of the release trace)/d(design) by the envelope theorem (dF/dx at the peak
    pull t*) against central differences of the re-maximised peak max_t F(t, x +- h)."""
    # (with friction: without it this finger pushes the object out, see test_contact)
    text = CLAMP.format(finger=FINGER, strain=10.0, pressure=100.0, iterations=2)
    p = _load('objective = "holding_force"\nfriction = 0.5\n' + text, tmp_path)
    setup = O._setup(p)
    assert setup.static.topology.contact.friction  # the grasp's was built without
    z0 = jnp.asarray(OBJ.z_of(p.lo, p.hi, p.x0), jnp.float64)
    anchors = O._refine_pull(setup, z0, setup.anchors, p.pull_step)
    # at the refined peak dF/dt vanishes, or the peak is the onset of the pull (t* = 0,
    # F falling): the envelope theorem holds for both (t* fixed at the bound)
    v, s, _, _ = OBJ.pull_slope(z0, setup.static, setup.data, anchors)
    interior = abs(float(s[0])) * p.pull_step < 1e-8 * abs(float(v[0]))
    assert interior or (float(anchors.pull[0]) == 0.0 and float(s[0]) < 0)
    (_, aux), grad = OBJ.loss_and_grad(z0, setup.static, setup.data, anchors)
    assert float(aux["values"][0]) > 0

    def peak(z):
        a = O._refine_pull(setup, z, anchors, p.pull_step)
        return float(OBJ.pull_slope(z, setup.static, setup.data, a)[0][0])

    h = 1e-4
    for j, name in enumerate(p.names):
        e = jnp.zeros_like(z0).at[j].set(h)
        fd = (peak(z0 + e) - peak(z0 - e)) / (2 * h)
        assert -float(grad[j]) == pytest.approx(fd, rel=1e-5), name
