"""Finger files: every bad-input rule names the field and the value; TOML round trips;
the example files. No solves here (fast)."""

import copy
import math
import pathlib

import diffrax as dfx
import equinox as eqx
import jax
import numpy as np
import pytest
from helpers import round_trip_finger

import finray_jax as fr
from finray_jax import io as fio

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


# --------------------------------------------------------------------------------------
# Helpers: a small TOML writer for test documents, and finger equality.
# --------------------------------------------------------------------------------------


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return repr(v)


def to_toml(doc: dict) -> str:
    """Scalars first, then tables, then arrays of tables (enough for finger files)."""
    out = [
        f"{k} = {_value(v)}"
        for k, v in doc.items()
        if not isinstance(v, dict) and not (isinstance(v, list) and v and isinstance(v[0], dict))
    ]
    for k, v in doc.items():
        if isinstance(v, dict):
            out += ["", f"[{k}]"] + [f"{kk} = {_value(vv)}" for kk, vv in v.items()]
    for k, v in doc.items():
        if isinstance(v, list) and v and isinstance(v[0], dict):
            for t in v:
                out += ["", f"[[{k}]]"] + [f"{kk} = {_value(vv)}" for kk, vv in t.items()]
    return "\n".join(out) + "\n"


BASE = {
    "material": {"E": 12.0, "nu": 0.45},
    "front": {"base": [0.0, 0.0], "tip": [0.0, 120.0], "thickness": 1.5, "depth": 20.0},
    "back": {"base": [40.0, 0.0], "thickness": 1.5, "depth": 20.0},
    "adaptor": {"front_base": "clamped", "back_base": "clamped"},
    "crossbeams": [
        {
            "front_s": 30.0 * (i + 1),
            "back_s": 30.0 * (i + 1) * math.hypot(40, 120) / 120,
            "thickness": 1.0,
            "depth": 20.0,
        }
        for i in range(3)
    ],
    "loads": [{"kind": "point", "beam": "front", "s": 60.0, "force": [0.05, 0.0, 0.0]}],
}


def doc():
    return copy.deepcopy(BASE)


def pattern_doc():
    """`doc()` with its crossbeams given as the equivalent [crossbeam_pattern]: three
    horizontal crossbeams at front_s 30, 60, 90."""
    d = doc()
    del d["crossbeams"]
    d["crossbeam_pattern"] = {
        "count": 3,
        "front_s": [30.0, 90.0],
        "horizontal": True,
        "thickness": 1.0,
        "depth": 20.0,
    }
    return d


def load(d):
    return fio.loads_finger(to_toml(d), source="bad.toml")


def assert_error(d, *fragments):
    """Reading `d` fails; the message names the file and contains every fragment."""
    with pytest.raises(fio.FingerFileError) as info:
        load(d)
    msg = str(info.value)
    assert msg.startswith("bad.toml: "), msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    assert isinstance(info.value, ValueError)
    return msg


def assert_same_finger(a: fr.Finger, b: fr.Finger):
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    assert len(la) == len(lb)
    for x, y in zip(la, lb, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


def test_base_document_is_valid():
    finger, settings = load(doc())
    assert finger.n_crossbeams == 3
    assert settings == fio.SolveSettings()
    assert isinstance(finger.loads[0], fr.PointLoad)


# --------------------------------------------------------------------------------------
# Every bad-input rule: the message names the key path and the value.
# --------------------------------------------------------------------------------------


def test_missing_key():
    d = doc()
    del d["material"]["E"]
    assert_error(d, "material.E", "missing")


def test_missing_table():
    d = doc()
    del d["back"]
    assert_error(d, "back", "missing")


def test_missing_crossbeam_key():
    d = doc()
    del d["crossbeams"][1]["depth"]
    assert_error(d, "crossbeams[1].depth", "missing")


def test_unknown_key_suggests():
    d = doc()
    d["front"]["thicknes"] = d["front"].pop("thickness")
    assert_error(d, "front.thicknes = 1.5", "did you mean 'thickness'")


def test_unknown_top_level_table_suggests():
    d = doc()
    d["materal"] = d.pop("material")
    assert_error(d, "materal", "did you mean 'material'")


def test_unknown_crossbeam_key_suggests():
    d = doc()
    d["crossbeams"][2]["front"] = 90.0
    assert_error(d, "crossbeams[2].front = 90.0", "did you mean")


def test_back_tip_hint():
    d = doc()
    d["back"]["tip"] = [0.0, 120.0]
    assert_error(d, "back.tip = [0.0, 120.0]", "front.tip")


# A top-level key written after a [table] is, in TOML, a key of that table.
def test_top_level_key_after_a_table_is_named_as_such():
    text = to_toml(doc())
    assert "torsion" not in text
    late = text.replace("[adaptor]\n", '[adaptor]\ntorsion = "rectangle"\n')
    with pytest.raises(fio.FingerFileError) as info:
        fio.loads_finger(late, source="bad.toml")
    assert str(info.value) == (
        "bad.toml: adaptor.torsion = \"rectangle\": unknown key in [adaptor] ('torsion' is a "
        "top-level key, and a top-level key must come before the first [table] in the file: "
        "TOML reads it as adaptor.torsion here); known keys: front_base, back_base, "
        "front_clamp_length, back_clamp_length, support_length"
    )
    # after an array of tables it lands in the last one; a top-level table name too
    for extra, where in (('torsion = "paper"', "loads[0].torsion"), ("meta = 1", "loads[0].meta")):
        with pytest.raises(fio.FingerFileError) as info:
            fio.loads_finger(text + extra + "\n", source="bad.toml")
        assert f"TOML reads it as {where} here)" in str(info.value)
    # before the first table it is read, and a misspelt key still gets a suggestion
    finger, _ = fio.loads_finger('torsion = "rectangle"\n' + text, source="ok.toml")
    assert finger.torsion == fr.SaintVenantTorsion()
    d = doc()
    d["adaptor"]["torsoin"] = "paper"
    msg = assert_error(d, "adaptor.torsoin", "unknown key in [adaptor]")
    assert "top-level" not in msg
    # a key the file has at its top level is not a misplaced one
    d = doc()
    d["crossbeams"][2]["front"] = 90.0
    msg = assert_error(d, "crossbeams[2].front = 90.0", "did you mean 'front_s'")
    assert "top-level" not in msg


def test_missing_top_level_key_found_in_a_table():
    text = (
        to_toml(doc())
        .replace("[material]\nE = 12.0\nnu = 0.45\n", "")
        .replace("[front]\n", "[front]\nmaterial = { E = 12.0, nu = 0.45 }\n")
    )
    with pytest.raises(fio.FingerFileError) as info:
        fio.loads_finger(text, source="bad.toml")
    assert str(info.value) == (
        "bad.toml: material: missing required key (table [material] with E and nu) (the file "
        "has front.material: a top-level key must come before the first [table] in the file, "
        "or TOML reads it as a key of the table above it)"
    )


def test_study_file_top_level_key_after_a_table():
    """Sweep and optimisation files share the reader: a sweep's `mode` after [sampling]."""
    from finray_jax.sweep import SweepError, loads_sweep

    text = (
        'finger = "examples/ref_a.toml"\noutputs = ["tip.dx"]\n\n[sampling]\nkind = "grid"\n'
        'mode = "planar"\n\n[[design]]\nname = "adaptor.back_clamp_length"\n'
        "range = [0.0, 10.0]\npoints = 3\n"
    )
    with pytest.raises(
        SweepError,
        match=r"sampling\.mode = \"planar\": unknown key in "
        r"\[sampling\] \('mode' is a top-level key, and a top-level key must "
        r"come before the first \[table\] in the file: TOML reads it as "
        r"sampling\.mode here\)",
    ):
        loads_sweep(text, source="sweep.toml", base_dir=str(ROOT))
    moved = text.replace('outputs = ["tip.dx"]\n', "").replace(
        "[sampling]\n", '[sampling]\noutputs = ["tip.dx"]\n'
    )
    with pytest.raises(
        SweepError,
        match=r"outputs: missing required key .*the file has "
        r"sampling\.outputs: a top-level key must come before the first",
    ):
        loads_sweep(moved, source="sweep.toml", base_dir=str(ROOT))


def test_string_where_number():
    d = doc()
    d["front"]["thickness"] = "1.5"
    assert_error(d, 'front.thickness = "1.5"', "expected a number")


def test_boolean_where_number():
    d = doc()
    d["material"]["nu"] = True
    assert_error(d, "material.nu = true", "expected a number")


def test_wrong_list_length():
    d = doc()
    d["front"]["base"] = [0.0]
    assert_error(d, "front.base = [0.0]", "2 numbers")


def test_wrong_force_length():
    d = doc()
    d["loads"][0]["force"] = [1.0, 0.0]
    assert_error(d, "loads[0].force = [1.0, 0.0]", "3 numbers")


def test_string_in_list():
    d = doc()
    d["back"]["base"] = [40.0, "0"]
    assert_error(d, 'back.base = [40.0, "0"]', "element 1")


def test_nonpositive_thickness():
    d = doc()
    d["crossbeams"][2]["thickness"] = -1.0
    assert_error(d, "crossbeams[2].thickness = -1.0", "positive")


def test_nonpositive_depth():
    d = doc()
    d["back"]["depth"] = 0.0
    assert_error(d, "back.depth = 0.0", "positive")


def test_nonpositive_modulus():
    d = doc()
    d["material"]["E"] = 0
    assert_error(d, "material.E = 0", "positive")


def test_nan_modulus():
    d = doc()
    d["material"]["E"] = float("nan")
    assert_error(d, "material.E = nan", "finite")


def test_nan_in_crossbeam():
    d = doc()
    d["crossbeams"][1]["front_s"] = float("nan")
    assert_error(d, "crossbeams[1].front_s = nan", "finite")


def test_inf_in_point():
    d = doc()
    d["front"]["tip"] = [0.0, float("inf")]
    assert_error(d, "front.tip = [0.0, inf]", "finite")


def test_poisson_ratio_out_of_range():
    d = doc()
    d["material"]["nu"] = 0.6
    assert_error(d, "material.nu", "0.6")


def test_attachment_outside_front_beam():
    d = doc()
    d["crossbeams"][2]["front_s"] = 130.0
    assert_error(d, "crossbeams[2].front_s = 130.0", "outside the front beam")


def test_attachment_outside_back_beam():
    d = doc()
    d["crossbeams"][0]["back_s"] = -2.0
    assert_error(d, "crossbeams[0].back_s = -2.0", "outside the back beam")


def test_crossbeams_cross():
    d = doc()
    d["crossbeams"][1]["back_s"] = 100.0  # beyond crossbeam 2's back end (94.9)
    assert_error(d, "crossbeams 1 and 2 cross", "100.0")


def test_unknown_base_kind():
    d = doc()
    d["adaptor"]["front_base"] = "welded"
    assert_error(d, 'adaptor.front_base = "welded"', "clamped")


def test_base_kind_suggests():
    d = doc()
    d["adaptor"]["back_base"] = "clampd"
    assert_error(d, 'adaptor.back_base = "clampd"', "did you mean 'clamped'")


@pytest.mark.parametrize(
    "table, key, typed, meant",
    [
        ("adaptor", "front_base", "fixed", "clamped"),
        ("adaptor", "front_base", "Hinged", "pinned"),
        ("adaptor", "back_base", "released", "free"),
        ("solver", "mode", "2D", "planar"),
        ("solver", "mode", "3d", "spatial"),
    ],
)
def test_choice_suggests_by_meaning(table, key, typed, meant):
    """Words that mean a choice are suggested as it (by spelling alone "fixed" would
    get 'pinned')."""
    d = doc()
    d.setdefault(table, {})[key] = typed
    assert_error(d, f'{table}.{key} = "{typed}"', f"did you mean '{meant}'")


def test_clamp_length_needs_clamped_base():
    d = doc()
    d["adaptor"]["front_base"] = "pinned"
    d["adaptor"]["front_clamp_length"] = 5.0
    assert_error(d, "adaptor.front_clamp_length = 5.0", "clamped")


def test_negative_clamp_length():
    d = doc()
    d["adaptor"]["back_clamp_length"] = -1.0
    assert_error(d, "adaptor.back_clamp_length = -1.0", "negative")


def test_bad_beam_name():
    d = doc()
    d["loads"][0]["beam"] = "frnt"
    assert_error(d, 'loads[0].beam = "frnt"', "did you mean 'front'")


def test_bad_crossbeam_index():
    d = doc()
    d["loads"][0]["beam"] = 9
    assert_error(d, "loads[0].beam = 9", "3 crossbeams")


def test_load_outside_beam():
    d = doc()
    d["loads"][0]["s"] = 200.0
    assert_error(d, "loads[0].s = 200.0", "outside the front beam")


def test_bad_load_kind():
    d = doc()
    d["loads"][0]["kind"] = "pressure"
    assert_error(d, 'loads[0].kind = "pressure"', "point")


def test_missing_load_kind():
    d = doc()
    del d["loads"][0]["kind"]
    assert_error(d, "loads[0].kind", "missing")


def test_distributed_load_with_force():
    d = doc()
    d["loads"] = [
        {"kind": "distributed", "beam": "front", "s_range": [75.0, 105.0], "force": [1.0, 0.0, 0.0]}
    ]
    assert_error(d, "loads[0].force = [1.0, 0.0, 0.0]", "total_force")


def test_distributed_load_with_s():
    d = doc()
    d["loads"] = [
        {"kind": "distributed", "beam": "front", "s": 80.0, "total_force": [1.0, 0.0, 0.0]}
    ]
    assert_error(d, "loads[0].s = 80.0", "s_range")


def test_point_load_with_total_force():
    d = doc()
    d["loads"][0]["total_force"] = d["loads"][0].pop("force")
    assert_error(d, "loads[0].total_force = [0.05, 0.0, 0.0]", "force")


def test_distributed_range_reversed():
    d = doc()
    d["loads"] = [
        {"kind": "distributed", "beam": 1, "s_range": [20.0, 10.0], "total_force": [1.0, 0.0, 0.0]}
    ]
    assert_error(d, "loads[0].s_range = [20.0, 10.0]", "s0 < s1")


def test_distributed_range_beyond_beam():
    d = doc()
    d["loads"] = [
        {
            "kind": "distributed",
            "beam": "back",
            "s_range": [100.0, 130.0],
            "total_force": [1.0, 0.0, 0.0],
        }
    ]
    assert_error(d, "loads[0].s_range = [100.0, 130.0]", "back beam")


def test_crossbeams_as_single_table():
    text = to_toml({k: v for k, v in doc().items() if k != "crossbeams"})
    text += "\n[crossbeams]\nfront_s = 30.0\nback_s = 31.6\nthickness = 1.0\ndepth = 20.0\n"
    with pytest.raises(fio.FingerFileError, match=r"crossbeams.*\[\[crossbeams\]\]"):
        fio.loads_finger(text, source="bad.toml")


def test_coinciding_bases():
    d = doc()
    d["back"]["base"] = [0.0, 0.0]
    assert_error(d, "front.base and back.base coincide")


def test_torsion_kind():
    d = doc()
    d["torsion"] = "warping"
    assert_error(d, 'torsion = "warping"', "rectangle")


def test_invalid_toml():
    with pytest.raises(fio.FingerFileError, match="bad.toml: not valid TOML"):
        fio.loads_finger("[material\nE = 1", source="bad.toml")


def test_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    with pytest.raises(fio.FingerFileError, match="nope.toml"):
        fio.load_finger(path)


def test_file_name_in_message(tmp_path):
    d = doc()
    d["crossbeams"][2]["thickness"] = -1.0
    path = tmp_path / "finger.toml"
    path.write_text(to_toml(d))
    with pytest.raises(fio.FingerFileError) as info:
        fio.load_finger(path)
    assert str(info.value).startswith(f"{path}: crossbeams[2].thickness = -1.0")


# -- [solver], [meta], [crossbeam_pattern] -------------------------------------------


def test_solver_settings():
    d = doc()
    d["solver"] = {
        "mode": "spatial",
        "integrator": "dopri5",
        "steps": 20,
        "rtol": 1e-9,
        "max_newton_steps": 30,
        "max_continuation_steps": 50,
        "linear_solver": "dense",
    }
    d["meta"] = {"name": "test", "description": "a test finger"}
    _, s = load(d)
    assert s.mode == "spatial"
    assert isinstance(s.integrator.solver, dfx.Dopri5)
    assert s.integrator.solver == dfx.Dopri5(scan_kind="lax")
    assert s.integrator.steps == 20
    assert s.options.rtol == 1e-9 and s.options.atol == fr.SolverOptions().atol
    assert s.options.max_newton_steps == 30 and s.options.max_continuation_steps == 50
    assert s.options.linear_solver == fr.DenseLinearSolver()
    assert (s.name, s.description) == ("test", "a test finger")
    assert s.solve_kwargs()["mode"] == "spatial"


def test_bad_solver_mode():
    d = doc()
    d["solver"] = {"mode": "3d"}
    assert_error(d, 'solver.mode = "3d"', "planar")


def test_bad_linear_solver():
    d = doc()
    d["solver"] = {"linear_solver": "sparse"}
    assert_error(d, 'solver.linear_solver = "sparse"', "banded")


def test_bad_integrator():
    d = doc()
    d["solver"] = {"integrator": "RK4"}
    assert_error(d, 'solver.integrator = "RK4"', "Tsit5")


def test_bad_steps():
    d = doc()
    d["solver"] = {"steps": 0}
    assert_error(d, "solver.steps = 0", ">= 1")


def test_absurd_step_and_iteration_counts():
    d = doc()
    d["solver"] = {"steps": 10**20}
    assert_error(d, f"solver.steps = {10**20}", "<= 10000")
    d["solver"] = {"max_newton_steps": 10**12}
    assert_error(d, f"solver.max_newton_steps = {10**12}", "<= 1000000")


def test_integer_beyond_the_float_range():
    d = doc()
    d["material"]["E"] = 10**400
    assert_error(d, "material.E = 1000", "finite")


def test_bad_tolerance():
    d = doc()
    d["solver"] = {"rtol": -1e-8}
    assert_error(d, "solver.rtol = -1e-08", "positive")


def test_unknown_meta_key():
    d = doc()
    d["meta"] = {"title": "x"}
    assert_error(d, "meta.title", "known keys: name, description")


def test_pattern_horizontal_equals_explicit():
    d = pattern_doc()
    f_pattern, _ = load(d)
    f_explicit, _ = load(doc())
    for key in ("front_s", "back_s", "thickness", "depth"):
        np.testing.assert_allclose(
            getattr(f_pattern.crossbeams, key), getattr(f_explicit.crossbeams, key), rtol=1e-14
        )


def test_pattern_explicit_back_s():
    d = doc()
    del d["crossbeams"]
    d["crossbeam_pattern"] = {
        "count": 4,
        "front_s": [20.0, 80.0],
        "back_s": [25.0, 100.0],
        "thickness": 1.2,
        "depth": 15.0,
    }
    f, _ = load(d)
    np.testing.assert_allclose(f.crossbeams.front_s, [20.0, 40.0, 60.0, 80.0])
    np.testing.assert_allclose(f.crossbeams.back_s, [25.0, 50.0, 75.0, 100.0])
    np.testing.assert_allclose(f.crossbeams.thickness, 1.2)


def test_pattern_and_crossbeams_conflict():
    d = doc()
    d["crossbeam_pattern"] = pattern_doc()["crossbeam_pattern"]
    assert_error(d, "crossbeam_pattern", "not both")


def test_pattern_needs_back_s_or_horizontal():
    d = doc()
    del d["crossbeams"]
    d["crossbeam_pattern"] = {"count": 3, "front_s": [30.0, 90.0], "thickness": 1.0, "depth": 20.0}
    assert_error(d, "crossbeam_pattern.back_s", "horizontal = true")


def test_pattern_bad_count():
    d = pattern_doc()
    d["crossbeam_pattern"]["count"] = 2.5
    assert_error(d, "crossbeam_pattern.count = 2.5", "integer")


def test_pattern_outside_beam_is_reported():
    d = pattern_doc()
    d["crossbeam_pattern"]["front_s"] = [30.0, 125.0]
    assert_error(d, "crossbeams[2].front_s = 125.0", "crossbeam_pattern")


# --------------------------------------------------------------------------------------
# Round trips and the example files
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", fr._reference.REF_A_LOADS)
def test_round_trip_ref_a(case):
    finger = fr.ref_finger_a(case)
    back, settings = fio.loads_finger(fio.finger_to_toml(finger))
    assert_same_finger(finger, back)
    assert settings == fio.SolveSettings()


def test_round_trip_everything():
    finger = round_trip_finger(
        adaptor=fr.Adaptor(fr.ClampedBase(), fr.PinnedBase(), front_clamp_length=4.0 / 3.0),
        loads=(
            fr.PointLoad(0, 50.0 + 1e-9, (0.1, 0.2, -0.3), (1.0, 2.0, 3.0)),
            fr.PointLoad(3, 5.0, (0.0, 0.0, 1.0 / 3.0)),
            fr.DistributedLoad(1, (20.0, 60.0), (-0.5, 0.0, 0.25)),
        ),
        torsion=fr.SaintVenantTorsion(),
    )
    settings = fio.SolveSettings(
        mode="spatial",
        integrator=fr.Integrator(solver=dfx.Bosh3(scan_kind="lax"), steps=7),
        options=fr.SolverOptions(
            rtol=1e-9, atol=3e-11, max_newton_steps=11, max_continuation_steps=33
        ),
        name='a "quoted" name',
        description="line one\nline two: é",
    )
    text = fio.finger_to_toml(finger, settings)
    back, back_settings = fio.loads_finger(text)
    assert_same_finger(finger, back)
    assert back_settings == settings
    # and once more: writing what was read gives the same text
    assert fio.finger_to_toml(back, back_settings) == text


@pytest.mark.parametrize(
    "grasp",
    [
        fio.GraspSettings(closing=6.5, pull_step=1.5, release=True, friction=0.3),
        fio.GraspSettings(actuator_force=4.25, direction=(-0.6, -0.8), symmetric=False),
    ],
)
def test_grasp_settings_round_trip(grasp):
    """A finger with objects and its [grasp] table, written and read back, is the same
    finger with the same grasp settings."""
    finger, _ = fio.load_finger(str(ROOT / "examples" / "grasp_finger1_modified.toml"))
    settings = fio.SolveSettings(mode="planar", grasp=grasp)
    text = fio.finger_to_toml(finger, settings)
    back, back_settings = fio.loads_finger(text)
    assert_same_finger(finger, back)
    assert back_settings.grasp == grasp


def test_rotation_cap_switched_off_round_trips():
    """SolverOptions(max_rotation_step=None) (no cap) is written `false` and read back as
    None (left out, it would come back as the default cap, 0.2 rad)."""
    settings = fio.SolveSettings(options=fr.SolverOptions(max_rotation_step=None))
    text = fio.finger_to_toml(fr.ref_finger_a("L1"), settings)
    assert "max_rotation_step = false" in text
    _, back = fio.loads_finger(text)
    assert back.options.max_rotation_step is None
    assert back == settings
    # the default rule of reuse_jacobian_below (None) is not written, and stays None
    assert "reuse_jacobian_below" not in text and back.options.reuse_jacobian_below is None


def test_rotation_cap_true_is_refused():
    text = fio.finger_to_toml(fr.ref_finger_a("L1")) + "\n[solver]\nmax_rotation_step = true\n"
    with pytest.raises(fio.FingerFileError, match=r"solver\.max_rotation_step.*false"):
        fio.loads_finger(text)


def test_round_trip_no_crossbeams_no_loads():
    finger = fr.Finger(
        material=fr.Material(12.0, 0.45),
        front_base=(0.0, 0.0),
        back_base=(30.0, 0.0),
        tip=(0.0, 80.0),
        front=fr.Section(2.0, 20.0),
        back=fr.Section(2.0, 20.0),
        crossbeams=fr.Crossbeams(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)),
    )
    back, _ = fio.loads_finger(fio.finger_to_toml(finger))
    assert_same_finger(finger, back)


def test_ref_a_file_equals_ref_finger_a():
    finger, settings = fio.load_finger(EXAMPLES / "ref_a.toml")
    assert_same_finger(finger, fr.ref_finger_a("L1"))
    assert settings.mode == "auto" and settings.name


def test_packaged_fingers_are_the_examples():
    """Finger-1 and its grasps ship as package data (the CLI's default finger); examples/
    holds the same files for users to copy: they may not drift apart."""
    from importlib import resources

    from finray_jax import cli

    data = resources.files("finray_jax") / "data"
    shipped = sorted(p.name for p in data.iterdir() if p.name.endswith(".toml"))
    assert shipped == sorted(fio.PACKAGED_FINGERS)
    assert cli.DEMO_FINGER in fio.PACKAGED_FINGERS
    for name in fio.PACKAGED_FINGERS:
        example = (EXAMPLES / name).read_text(encoding="utf-8")
        assert fio.packaged_finger_text(name) == example, name
        finger, _ = fio.load_packaged_finger(name)
        assert_same_finger(finger, fio.load_finger(EXAMPLES / name)[0])
    with pytest.raises(ValueError, match="no packaged finger file"):
        fio.packaged_finger_text("ref_a.toml")


@pytest.mark.parametrize("name", ["finger1", "finger2"])
def test_example_fingers(name):
    finger, settings = fio.load_finger(EXAMPLES / f"{name}.toml")
    fr.validate_finger(finger)
    length = {"finger1": 120.0, "finger2": 80.0}[name]
    np.testing.assert_allclose(np.asarray(finger.tip)[1] - np.asarray(finger.front_base)[1], length)
    # horizontal crossbeams: both ends at the same height
    fb, bb, tip = (np.asarray(x) for x in (finger.front_base, finger.back_base, finger.tip))
    cb = finger.crossbeams
    zf = fb[1] + np.asarray(cb.front_s) * (tip[1] - fb[1]) / np.linalg.norm(tip - fb)
    zb = bb[1] + np.asarray(cb.back_s) * (tip[1] - bb[1]) / np.linalg.norm(tip - bb)
    np.testing.assert_allclose(zf, zb, rtol=1e-13)
    assert settings.name


def test_finger1_carries_the_fig3_load():
    finger, _ = fio.load_finger(EXAMPLES / "finger1.toml")
    (load,) = finger.loads
    assert isinstance(load, fr.DistributedLoad) and load.beam == 0
    cb = np.asarray(finger.crossbeams.front_s)
    np.testing.assert_array_equal(np.asarray(load.s_range), [cb[4], cb[6]])  # l5 .. l7
    np.testing.assert_array_equal(np.asarray(load.total_force), [4.0, 0.0, 0.0])


def test_write_json_strict(tmp_path):
    import json

    path = tmp_path / "sub" / "x.json"
    fio.write_json(
        path,
        {
            "a": np.array([[1.0, np.nan], [2.0, 3.0]]),
            "b": np.float64(2.5),
            "c": [{"d": np.int64(3)}],
            "e": "text",
            "f": True,
        },
    )
    data = json.loads(path.read_text())
    assert data == {
        "a": [[1.0, None], [2.0, 3.0]],
        "b": 2.5,
        "c": [{"d": 3}],
        "e": "text",
        "f": True,
    }


def test_contact_near_segments():
    d = doc()
    d["contact"] = {"near_segments": "all"}
    assert load(d)[0].contact.near_segments is None
    d["contact"] = {"near_segments": 12}
    assert load(d)[0].contact.near_segments == 12
    assert fr.Contact().near_segments == 8
    bad = ((0, "must be an integer >= 1"), (2.5, "expected an integer"), ("some", '"all"'))
    for value, fragment in bad:
        d["contact"] = {"near_segments": value}
        assert_error(d, "contact.near_segments", fragment)
    # written back (with an object, so that the file has a [contact] table)
    for near in (None, 5):
        finger = load(doc())[0]
        finger = eqx.tree_at(
            lambda f: (f.objects, f.contact),
            finger,
            ((fr.Circle((-20.0, 60.0), 9.0),), fr.Contact(near_segments=near)),
        )
        back, _ = fio.loads_finger(fio.finger_to_toml(finger))
        assert back.contact.near_segments == near
    with pytest.raises(fr.FingerError, match=r"contact.near_segments must be a positive integer"):
        fr.validate_finger(eqx.tree_at(lambda f: f.contact, finger, fr.Contact(near_segments=0)))


@pytest.mark.parametrize(
    "beam,key,value,field",
    [("front", "tip", [0.0, 0.0], "front.tip"), ("back", "base", [0.0, 120.0], "back.base")],
)
def test_pattern_on_a_zero_length_beam_names_the_beam(beam, key, value, field):
    """A main beam whose two ends coincide is named as such, whatever else the pattern
    asks (a horizontal pattern needs a rising back beam, but that is not the fault)."""
    d = pattern_doc()
    d[beam][key] = value
    assert_error(d, f"{field} = {value}", f"the {beam} beam has zero length")
