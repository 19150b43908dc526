"""The engines' settings and the sweep driver's side of them, without a cluster: rows that
landed in any order (as a cluster writes them) are resumed and the finished CSV is
sorted, the same file as a sweep run in order; rows that cannot be this sweep's are
refused by name; bad engine settings name the setting and the value."""

import pathlib
import shutil
import sys

import pytest

from finray_jax import sweep as fsweep
from finray_jax.engines import EngineError, LocalEngine, RayEngine, engine_named

ROOT = pathlib.Path(__file__).resolve().parents[1]
SWEEP = ROOT / "examples" / "sweep_clamp.toml"  # 29 designs in chunks of 16


def _square(shared, item):
    return shared * item * item


def test_the_local_engine_runs_each_item_here_in_order():
    landed = list(LocalEngine().map_unordered(_square, 2, [1, 2, 3]))
    assert [(x.item, x.value, x.error) for x in landed] == [
        (1, 2, None),
        (2, 8, None),
        (3, 18, None),
    ]
    assert len({x.worker for x in landed}) == 1 and all(x.seconds >= 0 for x in landed)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(workers=0), "workers must be a positive integer, got 0"),
        (dict(workers=2.5), "workers must be a positive integer, got 2.5"),
        (dict(task_cpus=-1), "task_cpus must be a non-negative number, got -1"),
        (dict(task_gpus=float("nan")), "task_gpus must be a non-negative number, got nan"),
        (dict(task_cpus=0), "a task must ask for CPUs or GPUs: task_cpus and task_gpus are 0"),
        (dict(max_retries=-1), "max_retries must be a whole number >= 0, got -1"),
        (dict(address=" "), "address must be 'auto' or HOST:PORT, got ' '"),
    ],
)
def test_bad_ray_settings_are_refused_by_name(kwargs, message):
    with pytest.raises(EngineError) as e:
        RayEngine(**kwargs)
    assert str(e.value) == message


def test_engines_by_name():
    assert engine_named("local") == LocalEngine()
    assert engine_named("ray", workers=3, address=None) == RayEngine(workers=3)
    with pytest.raises(EngineError, match="engine must be 'local' or 'ray', got 'dask'"):
        engine_named("dask")
    with pytest.raises(EngineError, match="workers: settings of the ray engine"):
        engine_named("local", workers=2)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The sweep run in order on the local engine: its directory."""
    out = tmp_path_factory.mktemp("ordered")
    run = fsweep.run_sweep(fsweep.load_sweep(SWEEP), out, plot=False)
    assert run.finished
    return out


def _lines(path):
    return path.read_text().splitlines(keepends=True)


def test_rows_in_any_order_are_resumed_and_the_finished_csv_is_sorted(reference, tmp_path):
    """A CSV as a cluster leaves it when interrupted: the second chunk's rows, then part
    of the first chunk's, then a torn line. The same sweep solves only designs 4 to 15
    and ends with the file of the sweep run in order, byte for byte."""
    shutil.copy(reference / fsweep.MANIFEST, tmp_path / fsweep.MANIFEST)
    head, *rows = _lines(reference / fsweep.RESULTS_CSV)
    torn = rows[4][: len(rows[4]) // 2]
    (tmp_path / fsweep.RESULTS_CSV).write_text(head + "".join(rows[16:] + rows[:4]) + torn)
    solved = []
    run = fsweep.run_sweep(
        fsweep.load_sweep(SWEEP), tmp_path, plot=False, after_chunk=solved.append
    )
    assert run.finished and solved == [29]
    got = (tmp_path / fsweep.RESULTS_CSV).read_text()
    assert got == (reference / fsweep.RESULTS_CSV).read_text()


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda rows: rows[:3] + rows[2:3], "design 2 has two rows; use another --out"),
        (
            lambda rows: [rows[0].replace("0,", "40,", 1)],
            "a row has index 40, outside this sweep's designs 0 to 28",
        ),
        (lambda rows: rows[3:4] + [rows[4].replace("4,", "3,", 1)], "row 3 has adaptor"),
    ],
)
def test_rows_that_are_not_this_sweeps_are_refused(reference, tmp_path, edit, message):
    shutil.copy(reference / fsweep.MANIFEST, tmp_path / fsweep.MANIFEST)
    head, *rows = _lines(reference / fsweep.RESULTS_CSV)
    (tmp_path / fsweep.RESULTS_CSV).write_text(head + "".join(edit(rows)))
    with pytest.raises(fsweep.SweepError, match=message):
        fsweep.run_sweep(fsweep.load_sweep(SWEEP), tmp_path, plot=False)


def test_parquet_without_pyarrow_is_refused_before_any_work(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(fsweep.SweepError, match="results.parquet needs pyarrow"):
        fsweep.run_sweep(fsweep.load_sweep(SWEEP), tmp_path / "out", parquet=True)
    assert not (tmp_path / "out").exists()
