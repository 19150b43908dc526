"""`finray grasp`, `compare` and `clamp-study` (the paper comparisons are slow)."""

import json
import pathlib

import pytest
from test_cli import run

ROOT = pathlib.Path(__file__).resolve().parents[1]
GRASP = str(ROOT / "examples" / "grasp_finger1.toml")


def test_grasp_command_writes_contact_outputs(tmp_path):
    out = tmp_path / "g.json"
    png = tmp_path / "g.png"
    code, stdout, err = run(["grasp", GRASP, "--out", str(out), "--plot", str(png)])
    assert code == 0, err
    assert "contact force" in stdout and "actuator force" in stdout
    assert "  ... grasp, closing 6 mm" in err  # (on stderr, before the solve)
    # The shipped example says what it holds equal, and traces the release with its
    # stated friction ([grasp] release = true, friction = 0.3): a holding force, not 0 N.
    assert stdout.startswith("grasp: closing 6 mm held, the actuator force follows")
    holding = next(line for line in stdout.splitlines() if "holding force" in line)
    assert "friction mu = 0.3" in holding and float(holding.split()[2]) > 0.1
    d = json.loads(out.read_text())
    assert d["status"] == "converged"
    c = d["contact"]
    assert c["normal_force"] > 0 and c["max_penetration"] <= 0.02 * 3.0
    assert len(c["pressure_front"]["s"]) == len(c["pressure_front"]["q"])
    assert set(d["reactions"]) == {"front", "back"}
    assert png.stat().st_size > 10_000


def test_an_actuator_force_out_of_reach_says_so(tmp_path):
    """20 N is more than Finger-1 applies to the 18 mm cylinder frictionless (its force
    peaks near 10.7 N): exit 3, with the closing and the force at the peak."""
    path = tmp_path / "strong.toml"
    text = pathlib.Path(GRASP).read_text()
    assert "\nclosing = 6.0" in text
    path.write_text(text.replace("\nclosing = 6.0", "\nactuator_force = 20.0"))
    code, stdout, err = run(["grasp", str(path)])
    assert code == 3, stdout + err
    assert "failed at closing" in stdout
    assert "The actuator force was not reached: along the closing path the force rose" in stdout
    line = next(x for x in stdout.splitlines() if x.startswith("  peak actuator force"))
    assert line.endswith("mm, short of the 20 N asked"), line
    peak = float(line.split()[3])
    assert 10 < peak < 11


def test_solve_on_a_grasp_file_points_at_finray_grasp(monkeypatch):
    """The note comes before the solve, which a stand-in replaces here (a finger with
    objects compiles its own program, ~40 s; `finray solve` itself: test_cli)."""
    from finray_jax import cli

    def stand_in(finger, settings, mode):
        raise cli.UserError(f"stand-in solve of {len(finger.objects)} object(s)")

    monkeypatch.setattr(cli, "_solve", stand_in)
    code, _, err = run(["solve", GRASP])
    assert code == 1 and "stand-in solve of 1 object(s)" in err
    assert f"`finray grasp {GRASP}` closes the finger" in err
    code, _, err = run(["solve", str(ROOT / "examples" / "ref_a.toml")])
    assert code == 1 and "stand-in solve of 0 object(s)" in err and "finray grasp" not in err


def test_grasp_file_errors_name_the_key(tmp_path):
    text = pathlib.Path(GRASP).read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('kind = "circle"', 'kind = "sphere"'))
    code, _, err = run(["grasp", str(bad)])
    assert code == 1 and "objects[0].kind" in err and "Traceback" not in err
    bad.write_text(text.replace("closing = 6.0", "closing = 6.0\nactuator_force = 1.0"))
    code, _, err = run(["grasp", str(bad)])
    assert code == 1 and "exactly one of closing" in err
    bad.write_text(text.replace("radius = 9.0", "radius = 12.0"))
    code, _, err = run(["grasp", str(bad)])
    assert code == 1 and "overlaps the front beam" in err
    nograsp = tmp_path / "nograsp.toml"
    nograsp.write_text(text.split("[grasp]")[0])
    code, _, err = run(["grasp", str(nograsp)])
    assert code == 1 and "no [grasp] table" in err
    code, _, err = run(["grasp", GRASP, "--check-resolution", "1.5"])
    assert code == 1 and "RTOL must lie in (0, 1), got 1.5" in err


@pytest.mark.slow
def test_grasp_check_resolution(tmp_path):
    out = tmp_path / "g.json"
    code, stdout, err = run(["grasp", GRASP, "--check-resolution", "1e-3", "--out", str(out)])
    assert code == 0, err
    assert "resolution: solving at 32 and 64 steps per segment" in stdout
    res = json.loads(out.read_text())["resolution"]
    assert res["quantity"] == "normal_force" and res["order"] == 2
    assert res["steps"] == [16, 32, 64] and res["status"] == "converged"
    assert 0.0 < res["normal_force_relative_error"] < 1e-3 and res["resolved"] is True


@pytest.mark.slow
def test_grasp_rigid_estimate(tmp_path):
    """The modified adaptor's grasp with --rigid-estimate: the support's force and
    penetration within its limit on the first screen, the table of the grasp at 1, 4 and
    16 times its stiffnesses, and the same in the JSON (NaN orders as null)."""
    out = tmp_path / "g.json"
    path = str(ROOT / "examples" / "grasp_finger1_modified.toml")
    code, stdout, err = run(["grasp", path, "--rigid-estimate", "--out", str(out)])
    assert code == 0, err
    assert "support force" in stdout and "rigid-contact estimate" in stdout
    assert "warning" not in stdout
    d = json.loads(out.read_text())
    r = d["rigid_estimate"]
    assert r["factors"] == [1.0, 4.0, 16.0]
    assert r["stiffness"][0] == d["penalty_stiffness"]
    assert r["support_stiffness"][0] == d["support_penalty_stiffness"]
    assert r["values"]["normal_force"][0] == pytest.approx(d["contact"]["normal_force"], rel=1e-12)
    assert 0 < d["contact"]["support_penetration"] <= 0.02 * 3.0
    for name, v in r["values"].items():
        assert len(v) == 3 and r["rigid"][name] is not None
        assert r["order"][name] is None or 0.2 <= r["order"][name]


@pytest.mark.slow
@pytest.mark.extended
def test_compare_and_clamp_study(tmp_path):
    code, stdout, err = run(["compare", "--out", str(tmp_path)])
    assert code == 0, err
    assert "paper" in stdout and "+260 %" in stdout
    first = stdout.splitlines()[0]
    assert "the closing is held equal" in first and "friction mu = 0.3" in first
    d = json.loads((tmp_path / "compare.json").read_text())
    assert d["modified"]["contact"]["normal_force"] > d["original"]["contact"]["normal_force"]
    assert set(d["release"]) == {"35.0", "50.0", "65.0"}
    # The paper's +260 % (a ratio of 3.6) where the object presses 18 mm above the
    # support's end; over 1-10 mm of closing the ratio there stays within 3.37-3.64
    placed = d["placed"]
    assert placed["height"] == 78.0 and "object at 78 mm" in stdout
    assert placed["contact_force_gain_percent"] == pytest.approx(260.0, abs=15.0)
    assert d["contact_force_gain_percent"] > 4 * placed["contact_force_gain_percent"]
    assert placed["modified"]["stability"]["stable"]
    grid = ["--diameters", "18,35", "--clamp-lengths", "10,30"]
    code, stdout, err = run(["clamp-study", "--out", str(tmp_path), *grid])
    assert code == 0, err
    s = json.loads((tmp_path / "clamp_study.json").read_text())
    assert s["diameters"] == [18.0, 35.0] and s["clamp_lengths"] == [10.0, 30.0]
    assert s["complete"] and s["support_length"] == 60.0
    assert len(s["best_clamp_length"]) == 2 and set(s["best_clamp_length"]) <= {10.0, 30.0}
    assert "l_c=10" in stdout and "l_c=30" in stdout


@pytest.mark.parametrize(
    "option, value, words",
    [
        ("--diameters", "18,-3", "argument --diameters: must be > 0, got '-3'"),
        ("--diameters", "18,,35", "argument --diameters: expected a number, got ''"),
        ("--clamp-lengths", "10,70", "clamp lengths lie within the support's 60 mm, got '10,70'"),
        ("--clamp-lengths", "nan", "argument --clamp-lengths: expected a finite number"),
    ],
)
def test_clamp_study_grid_options_are_checked_before_any_grasp(tmp_path, option, value, words):
    code, _, err = run(["clamp-study", "--out", str(tmp_path), option, value])
    assert code == 1 and words in err, err
    assert not (tmp_path / "clamp_study.json").exists()


# --------------------------------------------------------------------------------------
# finray validate runs the grasp's object checks (no solve)
# --------------------------------------------------------------------------------------

_OBJECT = (
    "[[objects]]               # an 18 mm cylinder 0.5 mm in front of the front beam\n"
    'kind = "circle"\ncenter = [-11.0, 60.0]\nradius = 9.0\n'
)


@pytest.mark.parametrize(
    "old, new, message",
    [
        (
            "direction = [-1.0, 0.0]",
            "direction = [0.0, 0.0]",
            "{path}: grasp.direction must be a non-zero (x, z) direction, got [0.0, 0.0]",
        ),
        (
            "direction = [-1.0, 0.0]",
            "direction = [1.0, 0.0]",
            "{path}: objects[0] (circle) lies behind the finger: closing along [1.0, 0.0] moves "
            "the finger away from it",
        ),
        (
            "center = [-11.0, 60.0]",
            "center = [-11.0, 300.0]",
            "{path}: objects[0] (circle) is outside the reach of the finger: it spans [-309, "
            "-291] mm across the closing direction, the finger [-120, 0] mm",
        ),
        (
            _OBJECT,
            "",
            "{path}: grasp: a [grasp] table needs at least one [[objects]] entry to close the "
            "finger on",
        ),
    ],
)
def test_validate_runs_the_grasp_checks(tmp_path, old, new, message):
    """A file `finray grasp` would refuse is not 'OK' for `finray validate`: the same
    checks, without solving, naming the file and the key; exit 1."""
    text = pathlib.Path(GRASP).read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new))
    code, out, err = run(["validate", str(path)])
    assert (code, out) == (1, ""), out
    assert err == f"finray: error: {message.format(path=path)}\n"
    # finray grasp refuses it before any solve, with the same message
    code, out, err = run(["grasp", str(path)])
    assert (code, out) == (1, "") and err == f"finray: error: {message.format(path=path)}\n"


def test_validate_leaves_objects_without_a_grasp_table_alone(tmp_path):
    # Objects without [grasp] are obstacles of a loaded solve: no closing direction, so
    # none of the grasp's reach or direction checks apply (even far off the finger).
    text = pathlib.Path(GRASP).read_text().split("[grasp]")[0]
    path = tmp_path / "objects.toml"
    for center in ("[-11.0, 60.0]", "[-11.0, 300.0]", "[120.0, 60.0]"):
        path.write_text(text.replace("center = [-11.0, 60.0]", f"center = {center}"))
        code, out, err = run(["validate", str(path)])
        assert code == 0, err
        assert out.endswith("loads, mode auto\n"), out


def test_validate_grasp_examples():
    for name in ("grasp_finger1.toml", "grasp_finger1_modified.toml"):
        code, out, err = run(["validate", str(ROOT / "examples" / name)])
        assert code == 0 and err == "", err
        assert out.endswith("; grasp: 1 object ahead and in reach, closing along [-1, 0]\n")
