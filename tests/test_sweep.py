"""Sweep files and `finray sweep`: the rows written, resuming after an interruption
without losing or duplicating rows, refusing another sweep's directory, bad input.

All solving tests share one compiled batch program (same value names, outputs and chunk
size; about 15 s to compile on one core).
"""

import contextlib
import csv
import io
import json
import os
import pathlib
import shutil

import numpy as np
import pytest

import finray_jax as fr
from finray_jax import cli
from finray_jax import io as fio
from finray_jax import sweep as fsweep
from finray_jax.batch import Diagnosis, solve_batch

ROOT = pathlib.Path(__file__).resolve().parents[1]

GRID = """\
finger = "ref_a.toml"
outputs = ["tip.dx", "reaction.front.fx", "max_strain"]
mode = "planar"
chunk_size = 4

[sampling]
kind = "grid"

[[design]]
name = "adaptor.back_clamp_length"
range = [0.0, 10.0]
points = 3

[[design]]
name = "crossbeams.thickness[1]"
range = [0.8, 1.2]
points = 2
"""


@pytest.fixture
def sweep_file(tmp_path):
    shutil.copy(ROOT / "examples" / "ref_a.toml", tmp_path / "ref_a.toml")
    path = tmp_path / "grid.toml"
    path.write_text(GRID)
    return path


def _csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The grid's designs solved by solve_batch directly."""
    tmp = tmp_path_factory.mktemp("ref")
    shutil.copy(ROOT / "examples" / "ref_a.toml", tmp / "ref_a.toml")
    (tmp / "grid.toml").write_text(GRID)
    sw = fsweep.load_sweep(tmp / "grid.toml")
    return solve_batch(sw.finger, sw.designs(), sw.outputs, chunk_size=sw.chunk_size)


# --------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------


def test_grid_sweep_writes_one_row_per_design(sweep_file, tmp_path, reference):
    sw = fsweep.load_sweep(sweep_file)
    assert sw.size == 6
    out = tmp_path / "out"
    result = fsweep.run_sweep(sw, out, progress=None)
    assert result.finished and result.counts == {"converged": 6}
    head, rows = _csv(result.csv)
    assert head == [
        "index",
        "adaptor.back_clamp_length",
        "crossbeams.thickness[1]",
        "tip.dx",
        "reaction.front.fx",
        "max_strain",
        "status",
        "iterations",
        "max_residual",
        "reason",
    ]
    assert [r[0] for r in rows] == [str(i) for i in range(6)]
    # The grid, the last name varying fastest.
    clamp = [float(r[1]) for r in rows]
    thick = [float(r[2]) for r in rows]
    assert clamp == [0.0, 0.0, 5.0, 5.0, 10.0, 10.0]
    assert thick == [0.8, 1.2] * 3
    for j, name in enumerate(sw.outputs):
        np.testing.assert_array_equal([float(r[3 + j]) for r in rows], reference.outputs[name])
    assert all(r[6] == "converged" and int(r[7]) > 0 and float(r[8]) < 1e-10 for r in rows)
    assert all(r[9] == "" for r in rows)  # no reason: converged
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sweep_hash"] == sw.digest and manifest["finished"] is True
    assert (out / "sweep.png").stat().st_size > 0


def test_interrupted_sweep_resumes_without_losing_or_duplicating_rows(
    sweep_file, tmp_path, reference
):
    sw = fsweep.load_sweep(sweep_file)
    out = tmp_path / "out"

    def interrupt(done):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fsweep.run_sweep(sw, out, progress=None, after_chunk=interrupt)
    _, rows = _csv(out / "results.csv")
    assert [r[0] for r in rows] == ["0", "1", "2", "3"]  # the first chunk, complete
    assert not json.loads((out / "manifest.json").read_text())["finished"]
    # A kill in the middle of a write leaves a torn last line: it is dropped on resume.
    with open(out / "results.csv", "a") as fh:
        fh.write("4,10.0,0.8,0.0")
    # Continued from a copy of the file (the same sweep): the manifest keeps the first.
    copy = sweep_file.with_name("copy.toml")
    copy.write_text(sweep_file.read_text())
    result = fsweep.run_sweep(fsweep.load_sweep(copy), out, progress=None)
    assert result.finished and result.done == 6
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sweep_file"] == os.path.abspath(sweep_file)
    _, rows = _csv(out / "results.csv")
    assert [r[0] for r in rows] == [str(i) for i in range(6)]
    np.testing.assert_array_equal([float(r[3]) for r in rows], reference.outputs["tip.dx"])
    # Running a finished sweep again changes nothing.
    before = (out / "results.csv").read_bytes()
    assert fsweep.run_sweep(sw, out, progress=None, plot=False).done == 6
    assert (out / "results.csv").read_bytes() == before


def test_max_chunks_and_the_cli(sweep_file, tmp_path):
    out = tmp_path / "out"
    code, stdout, err = run(["sweep", str(sweep_file), "--out", str(out), "--max-chunks", "1"])
    assert code == 0, err
    assert "4 of 6 designs" in stdout and "run the same command to continue" in stdout
    # the progress bar (tqdm): designs done of the sweep, and those that did not converge
    assert "sweep:" in err and "4/6" in err and "0 not converged" in err, err
    code, stdout, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 0, err
    assert f"resuming: 4 of 6 designs are in {out / 'results.csv'}" in err, err
    assert "6 of 6 designs: 6 converged" in stdout
    assert (out / "sweep.png").exists()
    _, rows = _csv(out / "results.csv")
    assert len(rows) == 6


def test_another_sweep_in_the_same_directory_is_refused(sweep_file, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    sw = fsweep.load_sweep(sweep_file)
    (out / "manifest.json").write_text(
        json.dumps({"sweep_hash": "0" * 64, "sweep_file": "other.toml"})
    )
    with pytest.raises(fsweep.SweepError, match=r"holds another sweep \(from other.toml"):
        fsweep.run_sweep(sw, out, progress=None)
    other = sweep_file.with_name("other.toml")
    other.write_text(GRID.replace("points = 3", "points = 4"))
    code, _, err = run(["sweep", str(other), "--out", str(out)])
    assert code == 1 and err.startswith("finray: error: ") and "Traceback" not in err


# --------------------------------------------------------------------------------------
# Why a design did not converge: the reason column, and exit 3 when none did
# --------------------------------------------------------------------------------------

THICKNESS_RANGE = "range = [0.8, 1.2]"


def test_a_sweep_in_which_no_design_converged_exits_3_and_says_why(sweep_file, tmp_path):
    """Every design refused by validation: exit 3 (it exited 0), a line on stderr, and
    each row's reason names the rule the design breaks."""
    sweep_file.write_text(GRID.replace(THICKNESS_RANGE, "range = [-1.2, -0.8]"))
    out = tmp_path / "out"
    code, stdout, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 3, err
    assert "6 of 6 designs: 6 invalid" in stdout
    assert (
        f"finray: no design of the sweep converged (6 invalid); see the reason column of {out}"
        in err
    )
    assert "most frequent (3 of 6): crossbeams[1].thickness must be positive, got -1.2" in err
    head, rows = _csv(out / "results.csv")
    assert head[-4:] == ["status", "iterations", "max_residual", "reason"]
    assert [r[-4] for r in rows] == ["invalid"] * 6
    assert [r[-1] for r in rows] == [
        f"crossbeams[1].thickness must be positive, got {t}" for t in ("-1.2", "-0.8") * 3
    ]
    # nothing to plot: no figure, and none claimed
    assert not (out / "sweep.png").exists() and "sweep.png" not in stdout
    # Run again (finished): the same answer.
    code, _, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 3 and "no design of the sweep converged" in err


def test_a_sweep_with_some_converged_designs_exits_0(sweep_file, tmp_path):
    sweep_file.write_text(GRID.replace(THICKNESS_RANGE, "range = [-1.2, 1.2]"))
    out = tmp_path / "out"
    code, stdout, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 0, err
    assert "6 of 6 designs: 3 converged, 3 invalid" in stdout
    assert "no design" not in err
    _, rows = _csv(out / "results.csv")
    assert [(r[-4], r[-1]) for r in rows] == [
        ("invalid", "crossbeams[1].thickness must be positive, got -1.2"),
        ("converged", ""),
    ] * 3


def _drop_reason_column(path):
    """The results file in the format without a reason column: the same rows without it."""
    head, rows = _csv(path)
    assert head[-1] == "reason"
    text = "".join(",".join(r[:-1]) + "\n" for r in [head, *rows])
    pathlib.Path(path).write_text(text)
    return text


def test_a_sweep_started_before_the_reason_column_continues(sweep_file, tmp_path):
    """A results.csv without the reason column (an older finray_jax) is upgraded when the
    sweep continues: its rows get a reason (re-validated for invalid rows; not recorded
    for failed ones), and the new rows follow."""
    sweep_file.write_text(GRID.replace(THICKNESS_RANGE, "range = [-1.2, 1.2]"))
    out = tmp_path / "out"
    code, _, err = run(["sweep", str(sweep_file), "--out", str(out), "--max-chunks", "1"])
    assert code == 0, err
    old = _drop_reason_column(out / "results.csv")
    lines = old.splitlines(keepends=True)
    assert lines[0].endswith(",max_residual\n") and len(lines) == 5
    # an old failed row (its solver message was never written), and a torn last line
    failed = lines[2].replace(",converged,", ",failed,")
    assert failed != lines[2]
    torn = "4,10.0,-1.2,nan"
    (out / "results.csv").write_text("".join(lines[:2]) + failed + "".join(lines[3:]) + torn)
    code, stdout, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 0, err
    assert "6 of 6 designs" in stdout
    head, rows = _csv(out / "results.csv")
    assert head[-1] == "reason" and [r[0] for r in rows] == [str(i) for i in range(6)]
    assert all(len(r) == len(head) for r in rows)
    invalid = "crossbeams[1].thickness must be positive, got -1.2"
    assert [(r[-4], r[-1]) for r in rows] == [
        ("invalid", invalid),
        ("failed", fsweep._UNRECORDED),
        ("invalid", invalid),
        ("converged", ""),
        ("invalid", invalid),
        ("converged", ""),
    ]
    assert "older finray_jax" in fsweep._UNRECORDED


def test_reasons_round_trip_through_the_csv(sweep_file, tmp_path):
    """A reason with commas and quotes is quoted in the CSV, read back as written, and a
    resume counts its row (no solve)."""
    from finray_jax._solution import RESULTS
    from finray_jax._sweep_chunks import rows_text, solver_reason
    from finray_jax.batch import INVALID, BatchResult

    sw = fsweep.load_sweep(sweep_file)
    d = sw.designs()
    codes = [
        INVALID,
        int(RESULTS.nonlinear_divergence._value),
        int(RESULTS.beyond_limit_load._value),
        int(RESULTS.successful._value),
    ]
    res = BatchResult(
        inputs={k: v[:4] for k, v in d.items()},
        outputs={k: np.arange(4.0) for k in sw.outputs},
        result=np.asarray(codes),
        iterations=np.asarray([0, 50, 30, 5]),
        max_residual=np.asarray([np.nan, 1.0, 1e-12, 1e-14]),
    )
    reasons = ['a, "quoted", reason', *(solver_reason(c) for c in codes[1:])]
    assert reasons[1:] == [
        "nonlinear_divergence: Nonlinear solve diverged.",
        "beyond_limit_load: No equilibrium on the loading branch: the load is beyond the "
        "finger's limit (fold) load.",
        "",
    ]
    path = tmp_path / "results.csv"
    path.write_text(",".join(sw.columns) + "\n" + rows_text(sw, range(4), res, reasons))
    data = fsweep.read_results(path)
    assert data["reason"].tolist() == reasons
    assert data["status"].tolist() == ["invalid", "failed", "beyond_limit_load", "converged"]
    have = fsweep._resume(sw, str(path), d, Diagnosis(sw.finger, sw.mode))
    assert have[:4].all() and not have[4:].any()


def test_the_reason_of_an_invalid_design_names_the_rule_or_the_topology_change():
    text = GRID.replace("adaptor.back_clamp_length", "crossbeams.front_s[3]").replace(
        "range = [0.0, 10.0]", "range = [55.0, 65.0]"
    )
    sw = fsweep.loads_sweep(text, source="s.toml", base_dir=str(ROOT / "examples"))
    why = Diagnosis(sw.finger, sw.mode)
    # ref-A's point load acts at s = 60, where crossbeam 3 sits: moving it past the load
    # changes the order of events along the front beam
    assert why({"crossbeams.front_s[3]": 62.0, "crossbeams.thickness[1]": 1.0}) == (
        "changes the base finger's topology (the order of events along a beam): on the front "
        "beam, loads[0] at s = 60 now comes before crossbeam 3 at s = 62"
    )
    assert why({"crossbeams.front_s[3]": 60.0, "crossbeams.thickness[1]": 0.0}) == (
        "crossbeams[1].thickness must be positive, got 0.0"
    )
    assert why({"crossbeams.front_s[3]": 500.0, "crossbeams.thickness[1]": 1.0}).startswith(
        "crossbeams[3].front_s = 500.0 lies outside the front beam (0, 12"
    )


# --------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "old, new, match",
    [
        (
            'name = "crossbeams.thickness[1]"',
            'name = "crossbeams.thicknes[1]"',
            r"design\[1\].name = \"crossbeams.thicknes\[1\]\": unknown design value "
            r".*valid names: material.E",
        ),
        (
            'name = "crossbeams.thickness[1]"',
            'name = "crossbeams.thickness"',
            r"design\[1\].name = \"crossbeams.thickness\": .*array of 7 numbers",
        ),
        (
            'name = "crossbeams.thickness[1]"',
            'name = "crossbeams.thickness[9]"',
            r"design\[1\].name = .*no crossbeam 9",
        ),
        (
            "range = [0.8, 1.2]",
            "range = [1.2, 0.8]",
            r"design\[1\].range = \[1.2, 0.8\]: needs lo < hi",
        ),
        (
            "range = [0.8, 1.2]",
            "range = [0.8]",
            r"design\[1\].range = \[0.8\]: expected \[lo, hi\]",
        ),
        (
            '"max_strain"]',
            '"max_stress"]',
            r"outputs\[2\] = \"max_stress\": unknown output; valid outputs: tip.dx",
        ),
        (
            'outputs = ["tip.dx", "reaction.front.fx", "max_strain"]\n',
            "",
            r"outputs: missing required key",
        ),
        (
            'kind = "grid"',
            'kind = "sobol"',
            r"sampling.kind = \"sobol\": must be one of \"grid\" \| \"random\"",
        ),
        ("points = 2", "", r"design\[1\].points: missing required key"),
        ("points = 2", "points = 1", r"design\[1\].points = 1: must be an integer >= 2"),
        (
            'finger = "ref_a.toml"',
            'finger = "nope.toml"',
            r"finger = \"nope.toml\": no such finger file",
        ),
        ("chunk_size = 4", "chunk_size = 0", r"chunk_size = 0: must be an integer >= 1"),
        (
            "chunk_size = 4",
            "chunksize = 4",
            r"chunksize = 4: unknown key at the top level \(did you mean 'chunk_size'\?\)",
        ),
        ('kind = "grid"', 'kind = "random"', r"sampling.n: missing required key"),
        (
            'name = "adaptor.back_clamp_length"',
            'name = "adaptor.support_length"',
            r"design\[0\].name = \"adaptor.support_length\": .*has no support",
        ),
    ],
)
def test_bad_sweep_files(sweep_file, old, new, match):
    assert old in GRID
    sweep_file.write_text(GRID.replace(old, new))
    with pytest.raises(fsweep.SweepError, match=match):
        fsweep.load_sweep(sweep_file)


def test_bad_sweep_file_in_the_cli(sweep_file, tmp_path):
    sweep_file.write_text(GRID.replace("range = [0.8, 1.2]", "range = [1.2, 0.8]"))
    code, stdout, err = run(["sweep", str(sweep_file), "--out", str(tmp_path / "out")])
    assert code == 1
    assert err == f"finray: error: {sweep_file}: design[1].range = [1.2, 0.8]: needs lo < hi\n"
    code, _, err = run(["sweep", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "o")])
    assert code == 1 and "cannot read the sweep file" in err


def test_random_sampling_and_hash():
    text = GRID.replace('kind = "grid"', 'kind = "random"\nn = 5\nseed = 3').replace(
        "points = 3\n", ""
    )
    text = text.replace("points = 2\n", "")
    sw = fsweep.loads_sweep(text, source="r.toml", base_dir=str(ROOT / "examples"))
    d = sw.designs()
    assert sw.size == 5 and set(d) == {"adaptor.back_clamp_length", "crossbeams.thickness[1]"}
    assert np.all((d["crossbeams.thickness[1]"] >= 0.8) & (d["crossbeams.thickness[1]"] <= 1.2))
    again = fsweep.loads_sweep(text, source="r.toml", base_dir=str(ROOT / "examples"))
    np.testing.assert_array_equal(
        again.designs()["adaptor.back_clamp_length"], d["adaptor.back_clamp_length"]
    )
    assert again.digest == sw.digest
    other = fsweep.loads_sweep(
        text.replace("seed = 3", "seed = 4"), source="r.toml", base_dir=str(ROOT / "examples")
    )
    assert other.digest != sw.digest
    # chunk_size only groups rows: the same sweep.
    same = fsweep.loads_sweep(
        text.replace("chunk_size = 4", "chunk_size = 2"),
        source="r.toml",
        base_dir=str(ROOT / "examples"),
    )
    assert same.digest == sw.digest and same.chunk_size == 2
    # without it, solve_batch's default for the platform (256 on a CPU, 4096 on a GPU)
    unset = fsweep.loads_sweep(
        text.replace("chunk_size = 4\n", ""), source="r.toml", base_dir=str(ROOT / "examples")
    )
    assert unset.chunk_size is None and unset.digest == sw.digest
    with pytest.raises(fsweep.SweepError, match=r"sampling.n = 0: must be an integer >= 1"):
        fsweep.loads_sweep(
            text.replace("n = 5", "n = 0"), source="r.toml", base_dir=str(ROOT / "examples")
        )


def test_sweep_error_is_a_finger_file_error():
    assert issubclass(fsweep.SweepError, fio.FingerFileError)


def test_example_sweep_file():
    sw = fsweep.load_sweep(ROOT / "examples" / "sweep_clamp.toml")
    assert sw.names == ("adaptor.back_clamp_length",) and sw.size == 29
    assert sw.finger_path == str(ROOT / "examples" / "ref_a.toml")


@pytest.mark.parametrize("kind", ["line", "heat", "scatter"])
def test_plots(tmp_path, kind):
    """The three figure kinds, from made-up rows (no solve)."""
    base = str(ROOT / "examples")
    text = GRID
    if kind == "line":
        text = text[: text.index('[[design]]\nname = "crossbeams')]
    elif kind == "scatter":
        text = text.replace('kind = "grid"', 'kind = "random"\nn = 7').replace("points = 3\n", "")
        text = text.replace("points = 2\n", "")
    sw = fsweep.loads_sweep(text, source="s.toml", base_dir=base)
    data = {k: v for k, v in sw.designs().items()}
    for j, out in enumerate(sw.outputs):
        data[out] = np.arange(sw.size, dtype=float) + j
    data["status"] = np.array(["converged"] * (sw.size - 1) + ["beyond_limit_load"], dtype=object)
    fsweep.plot_sweep(sw, data, str(tmp_path / "f.png"))
    assert (tmp_path / "f.png").stat().st_size > 1000


# --------------------------------------------------------------------------------------
# Grasp sweeps: a finger file with objects and [grasp] closes every design on its objects
# --------------------------------------------------------------------------------------

GRASP_GRID = """\
finger = "grasp.toml"
outputs = ["contact.normal_force", "contact.length", "tip.dx"]
chunk_size = 2

[sampling]
kind = "grid"

[[design]]
name = "adaptor.back_clamp_length"
range = [10.0, 70.0]
points = 3
"""


def test_grasp_sweep_rows_are_the_grasps_of_the_designs(tmp_path):
    """Each row is `finray grasp` of its design (the modified adaptor on the 18 mm
    cylinder, closing 6 mm), solved on the base finger's segment table; l_c = 70 mm lies
    past the support's end (60 mm): invalid, with validate_finger's words; a run stopped
    after its first chunk continues without losing or repeating a row."""
    shutil.copy(ROOT / "examples" / "grasp_finger1_modified.toml", tmp_path / "grasp.toml")
    path = tmp_path / "grasp_grid.toml"
    path.write_text(GRASP_GRID)
    sw = fsweep.load_sweep(path)
    out = tmp_path / "out"
    first = fsweep.run_sweep(sw, out, max_chunks=1, plot=False)
    assert first.done == 2 and not first.finished
    run = fsweep.run_sweep(sw, out, plot=False)
    assert run.finished and run.counts == {"converged": 2, "invalid": 1}
    header, cells = _csv(run.csv)
    rows = [dict(zip(header, c)) for c in cells]
    assert [int(r["index"]) for r in rows] == [0, 1, 2]
    assert "adaptor.support_length = 60.0 must lie in [back_clamp_length" in rows[2]["reason"]
    base, settings = fio.load_finger(tmp_path / "grasp.toml")
    topo = fr.topology_of(base, "planar")
    for row in rows[:2]:
        lc = float(row["adaptor.back_clamp_length"])
        finger = fr.set_design(base, {"adaptor.back_clamp_length": lc})
        g = fr.grasp(finger, **settings.grasp.grasp_kwargs(), topology=topo)
        assert float(row["contact.normal_force"]) == pytest.approx(
            float(g.contact.normal_force), rel=1e-12
        )
        assert float(row["contact.length"]) == pytest.approx(
            float(g.contact.contact_length), rel=1e-12
        )
        assert float(row["tip.dx"]) == pytest.approx(float(g.solution.tip.displacement[0]))
    force = [float(r["contact.normal_force"]) for r in rows[:2]]
    assert 10.0 < force[0] < force[1] < 25.0  # (the demo's 15.9 N at l_c = 20 mm)


RELEASE_GRID = """\
finger = "grasp.toml"
outputs = ["contact.normal_force", "release.peak", "release.peak_pull", "release.complete"]

[sampling]
kind = "grid"

[[design]]
name = "adaptor.support_length"
range = [50.0, 62.0]
points = 2
"""


def test_grasp_sweep_records_the_holding_force_of_each_design(tmp_path):
    """A sweep with release outputs pulls every grasped design out as `release_force` does
    (the [grasp] table's pull_step, the [contact] friction), on the grasp's segment table:
    the row is that trace's peak. Here a 50 mm cylinder with mu = 0.5 on the modified
    adaptor (examples/grasp_finger1_modified_50mm.toml); the longer support presses
    harder, and holds harder."""
    shutil.copy(ROOT / "examples" / "grasp_finger1_modified_50mm.toml", tmp_path / "grasp.toml")
    path = tmp_path / "release_grid.toml"
    path.write_text(RELEASE_GRID)
    run = fsweep.run_sweep(fsweep.load_sweep(path), tmp_path / "out", plot=False)
    assert run.finished and run.counts == {"converged": 2}
    header, cells = _csv(run.csv)
    rows = [dict(zip(header, c)) for c in cells]
    base, settings = fio.load_finger(tmp_path / "grasp.toml")
    finger = fr.set_design(base, {"adaptor.support_length": 50.0})
    g = fr.grasp(finger, **settings.grasp.grasp_kwargs(), topology=fr.topology_of(base, "planar"))
    tr = fr.release_force(g, step=settings.grasp.pull_step, topology=g.topology)
    assert tr.complete and tr.peak > 0.0
    assert float(rows[0]["release.peak"]) == pytest.approx(tr.peak, rel=1e-12)
    assert float(rows[0]["release.peak_pull"]) == pytest.approx(tr.peak_pull, abs=1e-12)
    assert [r["release.complete"] for r in rows] == ["1.0", "1.0"]
    normal = [float(r["contact.normal_force"]) for r in rows]
    held = [float(r["release.peak"]) for r in rows]
    assert normal[0] < normal[1] and 0.0 < held[0] < held[1]


@pytest.mark.parametrize("output", ["contact.normal_force", "release.peak"])
def test_grasp_outputs_need_a_grasp_file(sweep_file, output):
    sweep_file.write_text(GRID.replace('"max_strain"', f'"{output}"'))
    with pytest.raises(fsweep.SweepError, match=r"outputs\[2\].*needs objects and a \[grasp\]"):
        fsweep.load_sweep(sweep_file)


def test_ctrl_c_line_says_how_many_designs_are_kept(sweep_file, tmp_path, monkeypatch):
    """Interrupted before any chunk finished, the line says nothing is kept; after some
    did, it gives their count and says how to continue."""
    out = tmp_path / "out"

    def interrupted(sw, out_dir, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fsweep, "run_sweep", interrupted)
    code, _, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 130
    assert err.strip().splitlines()[-1] == (
        "finray: interrupted; no designs had finished (nothing written yet): "
        "the same command starts afresh"
    )
    out.mkdir()
    (out / fsweep.RESULTS_CSV).write_text("index,status\n0,converged\n1,converged\n")
    code, _, err = run(["sweep", str(sweep_file), "--out", str(out)])
    assert code == 130
    assert err.strip().splitlines()[-1] == (
        f"finray: interrupted; 2 finished designs are in {out / fsweep.RESULTS_CSV}: "
        "run the same command to continue"
    )


def test_every_design_value_is_documented():
    from finray_jax.design import DESIGN_VALUES

    text = (ROOT / "docs" / "sweep-format.md").read_text()
    for name, dv in DESIGN_VALUES.items():
        assert f"`{name}[i]`" in text if dv.per_crossbeam else f"`{name}`" in text, name
