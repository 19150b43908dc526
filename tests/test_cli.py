"""The `finray` command line, run in-process through `cli.main`.

Solves are expensive to compile (20-40 s), so the default tests solve only ref-A under L1
(the topology other tests in the process share): once as filed and once scaled far beyond
its limit load. `demo` and `limit` compile other programs and are marked slow.
"""

import contextlib
import io
import json
import os
import pathlib
import subprocess
import sys

import jax
import numpy as np
import pytest

import finray_jax as fr
from finray_jax import cli

ROOT = pathlib.Path(__file__).resolve().parents[1]
REF_A = str(ROOT / "examples" / "ref_a.toml")
SWEEP = str(ROOT / "examples" / "sweep_clamp.toml")

SOLUTION_KEYS = {
    "finray_jax_version",
    "units",
    "mode",
    "status",
    "message",
    "load_factor",
    "iterations",
    "max_residual",
    "tip",
    "reactions",
    "beams",
    "crossbeam_wrenches",
}


def run(argv):
    """cli.main(argv) with stdout and stderr captured: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def ref_a_solved(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("solve")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FINRAY_NO_CACHE", "1")
        code, out, err = run(
            ["solve", REF_A, "--out", str(tmp / "result.json"), "--plot", str(tmp / "shape.png")]
        )
    data = json.loads((tmp / "result.json").read_text())
    return code, out, err, data, tmp


@pytest.fixture(scope="module")
def ref_a_reference():
    return fr.solve_finger(fr.ref_finger_a("L1"))


# --------------------------------------------------------------------------------------
# solve
# --------------------------------------------------------------------------------------


def test_solve_exit_code_and_summary(ref_a_solved):
    code, out, err, data, _ = ref_a_solved
    assert code == 0, err
    assert all(line.startswith("  ... ") for line in err.splitlines()), err  # (progress only)
    assert "status: converged" in out
    assert "tip displacement" in out and "reactions" in out


def test_quiet_silences_progress_and_keeps_the_results(monkeypatch):
    """--quiet leaves stderr without progress lines (the compile notice included), and
    stdout with the same results."""
    from finray_jax import _cli_common

    monkeypatch.setattr(_cli_common._Voice, "compiled", set())  # (a fresh process's state)
    code, out, err = run(["solve", REF_A, "--quiet"])
    assert code == 0 and err == "" and "tip displacement" in out
    monkeypatch.setattr(_cli_common._Voice, "compiled", set())
    code, loud, err = run(["solve", REF_A])
    assert code == 0 and "  ... compiling the planar solver for this finger" in err
    strip = lambda text: [ln for ln in text.splitlines() if not ln.startswith("status:")]
    assert strip(loud) == strip(out)  # (the status line holds the solve's time)


def test_solve_json_keys(ref_a_solved):
    _, _, _, data, _ = ref_a_solved
    assert SOLUTION_KEYS <= set(data)
    assert data["status"] == "converged" and data["converged"] is True
    assert data["message"] == ""
    assert data["mode"] == "planar"
    assert data["finray_jax_version"] == fr.__version__
    assert data["units"]["length"] == "mm" and data["units"]["force"] == "N"
    assert data["load_factor"] == 1.0
    assert set(data["tip"]) >= {"position", "displacement", "rotation"}
    for beam in ("front", "back"):
        assert set(data["reactions"][beam]) == {"force", "moment"}
    beams = data["beams"]
    assert len(beams["crossbeams"]) == 7
    for b in [beams["front"], beams["back"], *beams["crossbeams"]]:
        n = len(b["s"])
        assert n > 2
        for key in ("position", "force", "moment"):
            assert np.shape(b[key]) == (n, 3)
    for key in ("front_force", "front_moment", "back_force", "back_moment"):
        assert np.shape(data["crossbeam_wrenches"][key]) == (7, 3)


def test_solve_json_matches_library(ref_a_solved, ref_a_reference):
    """The CLI's answer is the library's answer for the same finger."""
    _, _, _, data, _ = ref_a_solved
    sol = ref_a_reference
    assert sol.status == "converged"
    # Same finger, same compiled program: equal up to round-off.
    tol = dict(rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(data["tip"]["displacement"], sol.tip.displacement, **tol)
    np.testing.assert_allclose(data["tip"]["rotation"], sol.tip.rotation, **tol)
    np.testing.assert_allclose(
        data["reactions"]["front"]["force"], sol.reactions_front.force, **tol
    )
    np.testing.assert_allclose(
        data["reactions"]["back"]["moment"], sol.reactions_back.moment, **tol
    )
    np.testing.assert_allclose(data["beams"]["front"]["position"], sol.front.position, **tol)
    np.testing.assert_allclose(
        data["beams"]["crossbeams"][3]["force"], sol.crossbeam(3).force, **tol
    )
    assert data["iterations"] == int(sol.iterations)


def test_solve_plot_written(ref_a_solved):
    *_, tmp = ref_a_solved
    png = (tmp / "shape.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_solve_beyond_limit_load(tmp_path):
    """50 x L1 = 2.5 N at s = 60: beyond ref-A's fold (a little under 2 N)."""
    path = tmp_path / "beyond.json"
    code, out, err = run(["solve", REF_A, "--load-scale", "50", "--out", str(path)])
    assert code == 2, out + err
    assert "beyond_limit_load" in out
    data = json.loads(path.read_text())
    assert data["status"] == "beyond_limit_load"
    assert data["converged"] is False
    # the equilibrium reported is at the fold: 1.5 N .. 2 N of the scaled 2.5 N
    assert 0.6 < data["load_factor"] < 0.8
    np.testing.assert_allclose(data["loads"][0]["force"], [2.5, 0.0, 0.0], rtol=1e-12)


# --------------------------------------------------------------------------------------
# validate and user errors (no solves)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["ref_a", "finger1", "finger2"])
def test_validate_examples(name):
    code, out, err = run(["validate", str(ROOT / "examples" / f"{name}.toml")])
    assert code == 0, err
    assert "OK" in out and err == ""
    assert " crossbeams, 1 load, mode " in out  # (each example has one load)


@pytest.mark.parametrize(
    "name, says",
    [
        ("sweep_clamp", "sweep of 29 designs (grid) over adaptor.back_clamp_length; 5 outputs"),
        ("sweep_random_10k", "sweep of 10000 designs (random) over adaptor.back_clamp_length, "),
        ("optimize_clamp", "optimise contact_force over adaptor.back_clamp_length, "),
    ],
)
def test_validate_reads_sweep_and_optimisation_files(name, says):
    """A study file is checked as one (its base finger too), not refused as a finger file
    with an unknown key `finger`."""
    code, out, err = run(["validate", str(ROOT / "examples" / f"{name}.toml")])
    assert code == 0 and err == "", err
    assert f"{name}.toml: OK: {says}" in out and "; base finger " in out


def test_validate_reports_a_bad_study_file(tmp_path, capsys):
    text = (ROOT / "examples" / "sweep_clamp.toml").read_text()
    (tmp_path / "ref_a.toml").write_text((ROOT / "examples" / "ref_a.toml").read_text())
    path = tmp_path / "bad_sweep.toml"
    path.write_text(text.replace("points = 29", "points = 1"))
    assert cli.main(["validate", str(path)]) == 1
    err = capsys.readouterr().err
    assert err == f"finray: error: {path}: design[0].points = 1: must be an integer >= 2\n"


def test_validate_warns_of_a_load_in_the_clamp_in_one_line(tmp_path):
    text = (ROOT / "examples" / "ref_a.toml").read_text()
    text = text.replace(
        'back_base = "clamped"\n', 'back_base = "clamped"\nback_clamp_length = 10.0\n'
    )
    text += '\n[[loads]]\nkind = "point"\nbeam = "back"\ns = 5.0\nforce = [0.01, 0.0, 0.0]\n'
    path = tmp_path / "clamped_load.toml"
    path.write_text(text)
    code, out, err = run(["validate", str(path)])
    assert code == 0 and "OK" in out
    assert err.startswith("finray: warning: loads[1] (beam back, s = 5.0) lies inside the back ")
    assert err.count("\n") == 1 and "Traceback" not in err, err


def _bad_file(tmp_path):
    text = (ROOT / "examples" / "ref_a.toml").read_text()
    text = text.replace(
        "front_s = 45.0\nback_s = 47.43416490252569\nthickness = 1.0",
        "front_s = 45.0\nback_s = 47.43416490252569\nthickness = -1.0",
    )
    assert "thickness = -1.0" in text
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


def test_validate_bad_file(tmp_path, capsys):
    path = _bad_file(tmp_path)
    code = cli.main(["validate", str(path)])
    captured = capsys.readouterr()
    assert code == 1
    assert captured.out == ""
    assert captured.err.startswith("finray: error: ")
    assert str(path) in captured.err
    assert "crossbeams[2].thickness = -1.0" in captured.err
    assert "Traceback" not in captured.err
    assert captured.err.count("\n") == 1


@pytest.mark.parametrize(
    "argv, message",
    [
        (["solve", REF_A, "--plot", "shape.xyz"], "--plot: 'shape.xyz': unknown figure format"),
        (["grasp", REF_A, "--release", "--friction", "-0.5"], "--friction: must be >= 0"),
        (["compare", "--closing", "0"], "--closing: must be > 0, got '0'"),
        (["clamp-study", "--closing", "-6"], "--closing: must be > 0, got '-6'"),
        (["clamp-study", "--actuator-force", "0"], "--actuator-force: must be > 0, got '0'"),
        (["clamp-study", "--friction", "0.3"], "--friction applies to the release traces: add"),
        (
            ["clamp-study", "--closing", "5", "--actuator-force", "15"],
            "--closing 5 and --actuator-force 15: give one",
        ),
        (["sweep", SWEEP, "--out", "x", "--workers", "2"], "--workers: options of --engine ray"),
        (["clamp-study", "--address", "auto"], "--address: options of --engine ray"),
        (["sweep", SWEEP, "--out", "x", "--engine", "ray", "--workers", "0"], "must be >= 1"),
        (["sweep", SWEEP, "--out", "x", "--engine", "ray", "--task-cpus", "-1"], "must be >= 0"),
        (["sweep", SWEEP, "--out", "x", "--engine", "dask"], "invalid choice: 'dask'"),
    ],
)
def test_bad_options_are_refused_before_any_solve(argv, message):
    code, out, err = run(argv)
    assert code == 1 and out == "" and message in err and "Traceback" not in err


def test_output_paths_through_a_file_are_refused_before_any_solve(tmp_path):
    a_file = tmp_path / "taken"
    a_file.write_text("")
    for argv, message in (
        (["solve", REF_A, "--out", str(a_file / "r.json")], "is a file, not a directory"),
        (["solve", REF_A, "--plot", str(a_file / "s.png")], "is a file, not a directory"),
        (["solve", REF_A, "--out", str(tmp_path)], "is a directory, not a file name"),
        (["compare", "--out", str(a_file)], f"--out {a_file}: is a file, not a directory"),
    ):
        code, out, err = run(argv)
        assert code == 1 and out == "" and message in err, (argv, err)


def test_unwritable_outputs_are_refused_before_any_solve(tmp_path):
    """An output folder that cannot take a file (here /proc, which takes no new file even
    from root; and a folder without write permission where permissions apply) is refused
    before the finger is even compiled: no progress line, exit 1, one error naming it."""
    places = [pathlib.Path("/proc")]
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        places.append(locked)
    for place in places:
        for argv in (
            ["solve", REF_A, "--out", str(place / "new" / "r.json")],
            [
                "grasp",
                str(ROOT / "examples" / "grasp_finger1.toml"),
                "--plot",
                str(place / "g.png"),
            ],
            ["sweep", str(ROOT / "examples" / "sweep_clamp.toml"), "--out", str(place / "sweep")],
        ):
            code, out, err = run(argv)
            assert code == 1 and out == "", (argv, err)
            assert f"cannot write in {place}" in err and "compiling" not in err, (argv, err)


def test_limit_of_zero_loads_is_refused(tmp_path):
    text = (ROOT / "examples" / "ref_a.toml").read_text()
    assert "force = [0.05, 0.0, 0.0]" in text
    path = tmp_path / "zero.toml"
    path.write_text(text.replace("force = [0.05, 0.0, 0.0]", "force = [0.0, 0.0, 0.0]"))
    code, out, err = run(["limit", str(path)])
    assert code == 1 and "every load is zero" in err and str(path) in err


def test_solve_bad_file(tmp_path, capsys):
    path = _bad_file(tmp_path)
    code = cli.main(["solve", str(path), "--out", str(tmp_path / "r.json")])
    captured = capsys.readouterr()
    assert code == 1
    assert "crossbeams[2].thickness = -1.0" in captured.err
    assert "Traceback" not in captured.err
    assert not (tmp_path / "r.json").exists()


def test_ctrl_c_is_one_line_and_exit_130(tmp_path, capsys, monkeypatch):
    """Ctrl-C in any command (here inside the solve) ends it with one line, no traceback."""

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fr, "solve_finger", interrupted)
    out = tmp_path / "r.json"
    try:
        code = cli.main(["solve", str(ROOT / "examples" / "ref_a.toml"), "--out", str(out)])
    except KeyboardInterrupt:  # (uncaught, it would stop the whole test session)
        pytest.fail("cli.main let KeyboardInterrupt through")
    err = capsys.readouterr().err
    assert code == 130
    assert err.strip().splitlines()[-1] == "finray: interrupted"
    assert "Traceback" not in err
    assert not out.exists()


def test_unknown_key_in_file(tmp_path, capsys):
    path = tmp_path / "typo.toml"
    path.write_text((ROOT / "examples" / "ref_a.toml").read_text().replace("nu = ", "nuu = "))
    assert cli.main(["validate", str(path)]) == 1
    err = capsys.readouterr().err
    assert "material.nuu = 0.45" in err and "did you mean 'nu'" in err


def test_missing_file(tmp_path, capsys):
    code = cli.main(["solve", str(tmp_path / "nope.toml")])
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith("finray: error: ") and "nope.toml" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["frobnicate"],
        ["solve"],
        ["solve", REF_A, "--mode", "3d"],
        ["solve", REF_A, "--load-scale", "abc"],
        ["solve", REF_A, "--load-scale", "nan"],
        ["solve", REF_A, "--check-resolution", "0"],
        ["solve", REF_A, "--check-resolution", "abc"],
    ],
)
def test_usage_errors(argv, capsys):
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith("finray: error: ")
    assert len(err.strip().splitlines()) == 1  # (argparse's usage text left out)
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv, helps",
    [
        (["solve", "--bogus", REF_A], "finray solve --help"),
        (["validate", REF_A, "extra.toml"], "finray validate --help"),
        (["--bogus", "solve", REF_A], "finray --help"),
    ],
)
def test_usage_error_points_at_the_commands_help(argv, helps, capsys):
    """An unknown option of a command is reported with that command's help, which lists
    its options; argparse on its own sends the user to the top-level help."""
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("finray: error: unrecognized arguments: ")
    assert err.strip().endswith(f"(see {helps})")


def test_help_and_version(capsys):
    assert cli.main(["--help"]) == 0
    assert "solve" in capsys.readouterr().out
    assert cli.main(["--version"]) == 0
    assert fr.__version__ in capsys.readouterr().out


def test_console_entry_point_in_a_subprocess(tmp_path):
    """A real process: exit code 1 and one line on stderr, no traceback."""
    path = _bad_file(tmp_path)
    env = dict(os.environ, FINRAY_NO_CACHE="1")
    proc = subprocess.run(
        [sys.executable, "-m", "finray_jax.cli", "validate", str(path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 1
    assert proc.stderr.startswith("finray: error: ")
    assert "crossbeams[2].thickness = -1.0" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_compilation_cache_settings(monkeypatch, tmp_path):
    old_dir = jax.config.jax_compilation_cache_dir
    old_min = jax.config.jax_persistent_cache_min_compile_time_secs
    try:
        monkeypatch.setenv("FINRAY_NO_CACHE", "1")
        assert fr.enable_compilation_cache() is None
        monkeypatch.setenv("FINRAY_NO_CACHE", "0")
        monkeypatch.setenv("FINRAY_CACHE_DIR", str(tmp_path / "cache"))
        assert fr.enable_compilation_cache() == str(tmp_path / "cache")
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "cache")
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.5
        monkeypatch.delenv("FINRAY_CACHE_DIR")
        expected = os.path.expanduser("~/.cache/finray_jax/jax")
        assert fr.enable_compilation_cache() == expected
        assert cli.enable_compilation_cache is fr.enable_compilation_cache  # (the CLI's)
    finally:
        jax.config.update("jax_compilation_cache_dir", old_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", old_min)


def test_device_choice(monkeypatch, capsys):
    """FINRAY_DEVICE: on a machine whose default backend is an accelerator (simulated here:
    this one has none), single-solve commands move to the CPU and a sweep stays; "default"
    keeps jax's default for all; a bad value is a user error that names it."""
    old = jax.config.jax_default_device
    try:
        monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
        monkeypatch.delenv("FINRAY_DEVICE", raising=False)
        assert cli.choose_device("sweep") == "gpu"
        assert jax.config.jax_default_device is old
        monkeypatch.setenv("FINRAY_DEVICE", "default")
        assert cli.choose_device("solve") == "gpu"
        assert jax.config.jax_default_device is old
        for value in ("auto", "cpu", " CPU "):
            monkeypatch.setenv("FINRAY_DEVICE", value)
            assert cli.choose_device("solve") == "cpu"
            assert jax.config.jax_default_device == jax.devices("cpu")[0]
            jax.config.update("jax_default_device", old)
        monkeypatch.setenv("FINRAY_DEVICE", "cpu")
        assert cli.choose_device("sweep") == "cpu"
        monkeypatch.setenv("FINRAY_DEVICE", "tpu0")
        assert cli.main(["solve", REF_A]) == cli.EXIT_USER
        err = capsys.readouterr().err
        assert "FINRAY_DEVICE = 'tpu0'" in err and "auto, cpu, default" in err
    finally:
        jax.config.update("jax_default_device", old)


# --------------------------------------------------------------------------------------
# demo and limit (compile other programs: slow)
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_demo(tmp_path):
    code, out, err = run(["demo", "--out", str(tmp_path)])
    assert code == 0, out + err
    assert "status: converged" in out and "crossbeams (numbered from 0" in out
    data = json.loads((tmp_path / "demo.json").read_text())
    assert SOLUTION_KEYS <= set(data)
    assert data["status"] == "converged" and data["name"] == "Finger-1"
    np.testing.assert_allclose(data["loads"][0]["total_force"], [4.0, 0.0, 0.0])
    assert data["loads"][0]["s_range"] == [75.0, 105.0]
    # the load pushes the front beam toward the back beam
    assert data["tip"]["displacement"][0] > 0
    # global force balance: the reactions carry the 4 N
    fx = data["reactions"]["front"]["force"][0] + data["reactions"]["back"]["force"][0]
    np.testing.assert_allclose(fx, -4.0, rtol=1e-8)
    assert (tmp_path / "demo.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_limit_ref_a(tmp_path):
    path = tmp_path / "limit.json"
    code, out, err = run(["limit", REF_A, "--out", str(path)])
    assert code == 0, out + err
    data = json.loads(path.read_text())
    assert data["found"] is True
    # ref-A folds a little under 2 N under a point force at s = 60 (L1 is 0.05 N)
    assert 30.0 < data["limit_load_factor"] < 40.0
    np.testing.assert_allclose(
        data["limit_loads"][0]["force"][0], 0.05 * data["limit_load_factor"], rtol=1e-12
    )
    assert {"tip", "reactions"} <= set(data["equilibrium_at_limit"])
    assert data["solution"]["status"] == "converged"
    assert "limit load factor" in out


def test_limit_without_a_fold_says_where_it_stopped(tmp_path):
    """A tip pulled up along the finger stiffens it: no fold, exit 3, and the loads are
    reported where the continuation stopped, not 'at the limit'."""
    text = (ROOT / "examples" / "ref_a.toml").read_text()
    old = "s = 60.0                  # mm\nforce = [0.05, 0.0, 0.0]"
    assert old in text
    path = tmp_path / "tension.toml"
    path.write_text(text.replace(old, "s = 120.0\nforce = [0.0, 0.0, 1.0]"))
    out = tmp_path / "limit.json"
    code, stdout, err = run(["limit", str(path), "--out", str(out)])
    assert code == 3, err
    assert "no limit load found" in stdout and "where the continuation stopped" in stdout
    assert "at the limit" not in stdout
    # It ran out of arc-length steps with the load still rising (its step never
    # collapsed), and says so.
    assert "after 120 arc-length steps" in stdout, stdout
    assert "max_continuation_steps" in stdout and "still rising" in stdout
    assert "min_arc_step" not in stdout
    data = json.loads(out.read_text())
    assert data["found"] is False
    assert data["solution"]["message"] == fr.RESULTS[fr.RESULTS.continuation_steps_exhausted]


def test_mode_planar_with_an_out_of_plane_load_names_the_file(tmp_path):
    text = (ROOT / "examples" / "ref_a.toml").read_text()
    path = tmp_path / "fy.toml"
    path.write_text(text.replace("force = [0.05, 0.0, 0.0]", "force = [0.05, 0.01, 0.0]"))
    for command in ("solve", "limit"):
        code, _, err = run([command, str(path), "--mode", "planar"])
        assert code == 1
        assert err.startswith(f"finray: error: {path}: loads[0].force = [0.05, 0.01, 0.0]: ")
        assert "out of the x-z plane" in err and "Traceback" not in err


def test_comparison_table_says_n_a_for_an_unknown_release_force():
    """A release trace without a solved point has a NaN peak: its change reads "n/a", not
    "+nan %". (The table's other rows are plain numbers; no solve here.)"""
    from types import SimpleNamespace

    from finray_jax import studies

    contact = SimpleNamespace(normal_force=2.0, contact_length=3.0, crossbeam_force=[0.1, 0, 0.2])
    trace = lambda peak: SimpleNamespace(peak=peak)
    grasp = SimpleNamespace(contact=contact)
    cmp = studies.Comparison(6.0, grasp, grasp, {35.0: (trace(1.0), trace(float("nan")))})
    lines = cli._comparison_lines(cmp)
    row = next(line for line in lines if line.lstrip().startswith("holding force, 35 mm"))
    assert "n/a" in row and "nan %" not in row and "+0 %" in "\n".join(lines)


def test_clamp_study_prints_the_best_clamp_length_beside_the_measured_force(tmp_path, monkeypatch):
    """With --holding the best l_c is the holding force's, printed beside that table only;
    with --actuator-force the closing reached is printed too. (A study stands in for the
    solves.)"""
    from finray_jax import studies

    lc, dia = np.array([0.0, 10.0]), np.array([18.0, 35.0])
    study = studies.ClampStudy(
        dia,
        lc,
        60.0,
        np.array([[1.0, 2.0], [3.0, 4.0]]),
        closing=np.full((2, 2), 5.5),
        actuator_force=15.0,
        holding_force=np.array([[2.0, 1.0], [np.nan, np.nan]]),
        friction=0.3,
    )
    monkeypatch.setattr(studies, "clamp_study", lambda *a, **k: study)
    argv = ["clamp-study", "--out", str(tmp_path), "--actuator-force", "15", "--holding"]
    code, out, err = run([*argv, "--friction", "0.3"])
    assert code == 0, err
    blocks = out.split("\n\n")
    assert (
        blocks[0].startswith("contact force (N) of the modified adaptor")
        and "best" not in blocks[0]
    )
    assert blocks[1].startswith("closing (mm)") and "5.5" in blocks[1]
    assert blocks[2].startswith("holding force (N, mu = 0.3)") and "best l_c" in blocks[2]
    rows = blocks[2].splitlines()
    assert rows[2].split()[-1] == "0" and rows[3].split()[-1] == "nan"
