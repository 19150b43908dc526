"""Sweeps and the clamp study on a real Ray cluster started on this machine: a head node
(no CPUs of its own) and a worker node with 2 CPUs, joined by `ray start` as on a real
cluster. The results (examples/sweep_clamp.toml, a grasp sweep with the holding force, the
clamp study) equal the local engine's, row for row; a worker process killed while it holds
a task costs nothing (Ray retries it), or, with no retries left, its chunk is reported by
its design indices and the rest completes; a driver interrupted by Ctrl-C and run again
loses and repeats no row. Those three run examples/sweep_clamp.toml cut into chunks of 4
designs (8 tasks). Without Ray, `--engine ray` says how to install it. Ray's own processes
are stopped when the module ends.
"""

import csv
import os
import pathlib
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from finray_jax import cli, studies
from finray_jax import io as fio
from finray_jax import sweep as fsweep
from finray_jax.engines import LocalEngine, RayEngine

ray = pytest.importorskip("ray")

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
BIN = pathlib.Path(sys.executable).parent
FINRAY = shutil.which("finray", path=str(BIN))
RAY = shutil.which("ray", path=str(BIN))

# A small grasp sweep: Finger-1 on the modified adaptor closing 6 mm on the 18 mm cylinder
# (examples/grasp_finger1_modified.toml), two back-beam clamp lengths in one-grasp chunks,
# with the contact and the holding force. The cylinder sits at z = 95 mm (25 mm below
# the tips) and the contact has friction 0.3 (FINGER_EDITS): its release trace, pulled in
# 4 mm steps, holds it over the first ~28 mm and ends in ~10 contact solves.
GRASP_SWEEP = """
finger = "finger.toml"
outputs = ["contact.normal_force", "contact.length", "max_strain", "release.peak"]
chunk_size = 1

[sampling]
kind = "grid"

[[design]]
name = "adaptor.back_clamp_length"
range = [16.5, 31.0]
points = 2
"""
FINGER_EDITS = {
    "center = [-11.0, 60.0]": "center = [-11.0, 95.0]",
    "[contact]\n": "[contact]\nfriction = 0.3\n",
    "pull_step = 2.0 ": "pull_step = 4.0 ",
}
CLAMP_CHUNK = 4  # designs per chunk of the clamp sweep that is killed and interrupted


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ray(*args, env):
    subprocess.run([RAY, *args], env=env, check=True, capture_output=True, timeout=120)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The address of a Ray cluster of two nodes on this machine: a head with no CPUs and
    a worker node with 2, so that every task runs on the worker node."""
    if RAY is None:
        pytest.skip("the ray command is not installed")
    port = _free_port()
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    store = "--object-store-memory=150000000"
    _ray(
        "start",
        "--head",
        f"--port={port}",
        "--num-cpus=0",
        "--include-dashboard=false",
        store,
        env=env,
    )
    address = f"127.0.0.1:{port}"
    try:
        _ray("start", f"--address={address}", "--num-cpus=2", store, env=env)
        yield address
    finally:
        subprocess.run([RAY, "stop", "--force"], env=env, capture_output=True, timeout=120)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """The workers' compilation cache: the suite's when it has one (the local runs of
    this module fill it), else one for this module."""
    return os.environ.get("FINRAY_TEST_CACHE_DIR") or str(tmp_path_factory.mktemp("xla"))


def _engine(cluster, cache, **kw) -> RayEngine:
    return RayEngine(address=cluster, workers=2, cache_dir=cache, **kw)


def _rows(path) -> list[list[str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.reader(fh))


def assert_same_rows(got, want) -> None:
    """Two results CSVs hold the same rows in the same order: indices, statuses and
    reasons equal, numbers to 1e-12 (relative; the same compiled program on the same
    inputs, in another process)."""
    a, b = _rows(got), _rows(want)
    assert a[0] == b[0] and len(a) == len(b), (len(a), len(b))
    text = {b[0].index(n) for n in ("index", "status", "reason")}
    for ra, rb in zip(a[1:], b[1:]):
        for k, (x, y) in enumerate(zip(ra, rb)):
            if k in text:
                assert x == y, (b[0][k], ra, rb)
            else:
                np.testing.assert_allclose(
                    float(x), float(y), rtol=1e-12, atol=0.0, err_msg=b[0][k]
                )


@pytest.fixture(scope="module")
def clamp_sweep(tmp_path_factory):
    """examples/sweep_clamp.toml (29 designs of ref-A, 2 chunks) and its local results."""
    sw = fsweep.load_sweep(EXAMPLES / "sweep_clamp.toml")
    local = fsweep.run_sweep(sw, tmp_path_factory.mktemp("clamp") / "local", plot=False)
    assert local.finished
    return sw, local.csv


@pytest.fixture(scope="module")
def clamp_chunks(tmp_path_factory, clamp_sweep):
    """examples/sweep_clamp.toml in chunks of CLAMP_CHUNK designs (8 tasks, the last of one
    design), and the local results of the original (chunks of 16): a design's row does not
    depend on the length of the chunk it is solved in."""
    text = (EXAMPLES / "sweep_clamp.toml").read_text()
    text = text.replace('"ref_a.toml"', f'"{(EXAMPLES / "ref_a.toml").as_posix()}"')
    text = text.replace("chunk_size = 16", f"chunk_size = {CLAMP_CHUNK}")
    path = tmp_path_factory.mktemp("chunks") / "sweep_clamp.toml"
    path.write_text(text)
    sw = fsweep.load_sweep(path)
    assert sw.chunk_size == CLAMP_CHUNK and sw.size == clamp_sweep[0].size
    return sw, clamp_sweep[1]


def test_the_clamp_sweep_on_ray_equals_the_local_engine(cluster, cache, clamp_sweep, tmp_path):
    sw, local_csv = clamp_sweep
    run = fsweep.run_sweep(sw, tmp_path / "ray", engine=_engine(cluster, cache), parquet=True)
    assert run.finished and not run.failed_chunks
    assert_same_rows(run.csv, local_csv)
    assert os.path.exists(run.figure)
    assert sum(t.chunks for t in run.workers.values()) == 2  # (two chunks of 16 designs)
    import pyarrow.parquet as pq

    table = pq.read_table(run.parquet).to_pydict()
    data = fsweep.read_results(local_csv)
    assert table["index"] == list(range(sw.size))
    np.testing.assert_array_equal(table["tip.dx"], data["tip.dx"])
    assert table["status"] == data["status"].tolist()


def test_a_holding_force_sweep_on_ray_equals_the_local_engine(cluster, cache, tmp_path):
    """Two one-grasp chunks with their release traces, on two workers, land in any
    order; the CSV is sorted, and both designs hold the cylinder."""
    finger = (EXAMPLES / "grasp_finger1_modified.toml").read_text()
    for old, new in FINGER_EDITS.items():
        assert finger.count(old) == 1, old
        finger = finger.replace(old, new)
    (tmp_path / "finger.toml").write_text(finger)
    (tmp_path / "sweep.toml").write_text(GRASP_SWEEP)
    sw = fsweep.load_sweep(tmp_path / "sweep.toml")
    local = fsweep.run_sweep(sw, tmp_path / "local", plot=False)
    assert local.finished and local.converged == sw.size
    run = fsweep.run_sweep(sw, tmp_path / "ray", engine=_engine(cluster, cache), plot=False)
    assert run.finished and not run.failed_chunks
    assert_same_rows(run.csv, local.csv)
    assert sum(t.chunks for t in run.workers.values()) == 2
    peak = fsweep.read_results(run.csv)["release.peak"]
    assert np.all(np.isfinite(peak) & (peak > 0)), peak


def test_the_clamp_study_on_ray_equals_the_local_engine(cluster, cache):
    """A clamp study of one grasp (the modified adaptor, l_c = 10 mm, on the 18 mm
    cylinder) runs as a task on the worker node and lands as on the local engine."""
    finger, _ = fio.load_packaged_finger(cli.DEMO_FINGER)
    settings = dict(diameters=(18.0,), clamp_lengths=(10.0,), closing=6.0)
    local = studies.clamp_study(finger, **settings, engine=LocalEngine())
    said = []
    on_ray = studies.clamp_study(
        finger, **settings, engine=_engine(cluster, cache), progress=said.append
    )
    assert np.all(np.isfinite(local.normal_force) & (local.normal_force > 0))
    np.testing.assert_allclose(on_ray.normal_force, local.normal_force, rtol=1e-12, atol=0)
    np.testing.assert_allclose(on_ray.closing, local.closing, rtol=1e-12, atol=0)
    assert sum("l_c =" in m for m in said) == 1


def _busy_workers() -> list[int]:
    """Ray worker processes running one of our tasks now (their title names the task)."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmd = pathlib.Path(f"/proc/{entry}/cmdline").read_bytes()
            except OSError:
                continue
            if cmd.startswith(b"ray::_task"):
                pids.append(int(entry))
    return pids


class _Killer(threading.Thread):
    """Kills (SIGKILL) the first Ray worker process seen running a task."""

    def __init__(self):
        super().__init__(daemon=True)
        self.killed, self.stop = None, threading.Event()

    def run(self):
        while not self.stop.is_set():
            busy = _busy_workers()
            if busy:
                time.sleep(0.2)  # (well inside the task)
                os.kill(busy[0], signal.SIGKILL)
                self.killed = busy[0]
                return
            time.sleep(0.05)


def test_a_worker_killed_mid_task_is_retried_and_every_design_lands_once(
    cluster, cache, clamp_chunks, tmp_path
):
    """A worker killed in its first task (which loads the sweep's program): Ray runs the
    chunk again, and all 8 chunks land once, as on the local engine."""
    sw, local_csv = clamp_chunks
    killer = _Killer()
    killer.start()
    run = fsweep.run_sweep(sw, tmp_path / "ray", engine=_engine(cluster, cache), plot=False)
    killer.stop.set()
    assert killer.killed is not None, "no worker was seen running a task"
    assert run.finished and not run.failed_chunks
    assert sum(t.chunks for t in run.workers.values()) == 8
    assert_same_rows(run.csv, local_csv)


def test_a_chunk_that_fails_for_good_is_reported_and_the_rest_completes(
    cluster, cache, clamp_chunks, tmp_path
):
    """No retries: the killed worker's chunk is reported with its design indices, the
    other designs are written; the same sweep run again solves that chunk alone."""
    sw, local_csv = clamp_chunks
    killer = _Killer()
    killer.start()
    run = fsweep.run_sweep(
        sw, tmp_path / "ray", engine=_engine(cluster, cache, max_retries=0), plot=False
    )
    killer.stop.set()
    assert killer.killed is not None, "no worker was seen running a task"
    assert len(run.failed_chunks) == 1 and not run.finished
    (chunk,) = run.failed_chunks
    first = chunk.indices[0]
    assert first % CLAMP_CHUNK == 0 and "died" in chunk.error
    assert chunk.indices == tuple(range(first, min(first + CLAMP_CHUNK, sw.size)))
    n = len(chunk.indices)
    span = f"design {first}" if n == 1 else f"designs {first} to {chunk.indices[-1]}"
    assert chunk.describe().startswith(f"chunk of {span} ({n}) failed")
    assert run.done == sw.size - n
    written = [int(r[0]) for r in _rows(run.csv)[1:]]
    assert sorted(written) == sorted(set(range(sw.size)) - set(chunk.indices))
    again = fsweep.run_sweep(sw, tmp_path / "ray", engine=_engine(cluster, cache), plot=False)
    assert again.finished and sum(t.chunks for t in again.workers.values()) == 1
    assert_same_rows(again.csv, local_csv)


@pytest.mark.skipif(FINRAY is None, reason="the finray console script is not installed")
def test_a_driver_interrupted_and_run_again_loses_and_repeats_no_row(
    cluster, cache, clamp_chunks, tmp_path
):
    """`finray sweep --engine ray` gets Ctrl-C once a row is written: exit 130 and one
    line; the same command run again finishes with every design once. The driver is
    stopped (SIGSTOP) the moment the test sees a row, given the SIGINT and continued, so
    that the interrupt lands with chunks still to come however fast the workers are."""
    sw, local_csv = clamp_chunks
    out = tmp_path / "out"
    argv = [FINRAY, "sweep", sw.source, "--out", str(out), "--engine", "ray"]
    argv += ["--address", cluster, "--workers", "2", "--cache-dir", cache]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / "results.csv").exists() and len(_rows(out / "results.csv")) >= 2:
            os.kill(proc.pid, signal.SIGSTOP)
            break
        time.sleep(0.02)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    os.kill(proc.pid, signal.SIGCONT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert lines[-1].startswith("finray: interrupted;") and "Traceback" not in stderr, stderr
    kept = [int(r[0]) for r in _rows(out / "results.csv")[1:]]
    assert 1 <= len(kept) < sw.size and len(set(kept)) == len(kept)
    done = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert f"resuming: {len(kept)} of {sw.size} designs" in done.stderr
    assert_same_rows(out / "results.csv", local_csv)


def test_a_sweep_stopped_in_a_program_connected_to_ray_leaves_it_connected(
    cluster, cache, clamp_chunks, tmp_path
):
    """A program that connected to Ray itself (a notebook, say) and stops a sweep early:
    the sweep's remaining tasks are cancelled, the program stays connected, and the same
    sweep run again there completes with every design once."""
    import logging

    import ray

    sw, local_csv = clamp_chunks
    ray.init(
        address=cluster, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR
    )
    try:

        def stop(rows_done):
            raise KeyboardInterrupt

        engine = _engine(cluster, cache)
        with pytest.raises(KeyboardInterrupt):
            fsweep.run_sweep(sw, tmp_path / "ray", engine=engine, plot=False, after_chunk=stop)
        assert ray.is_initialized()
        kept = [int(r[0]) for r in _rows(tmp_path / "ray" / "results.csv")[1:]]
        assert len(kept) in (CLAMP_CHUNK, sw.size % CLAMP_CHUNK)  # (one chunk: the last is short)
        run = fsweep.run_sweep(sw, tmp_path / "ray", engine=engine, plot=False)
        assert run.finished and not run.failed_chunks and ray.is_initialized()
        assert_same_rows(run.csv, local_csv)
    finally:
        ray.shutdown()


@pytest.mark.skipif(FINRAY is None, reason="the finray console script is not installed")
def test_without_ray_the_ray_engine_says_how_to_install_it(tmp_path):
    """A Python without Ray (a `ray` package that cannot be imported stands in for it):
    one line naming the extra, exit 1, before any work."""
    fake = tmp_path / "no_ray" / "ray"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError(\"No module named 'ray'\")\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(fake.parent), *sys.path]))
    argv = [FINRAY, "sweep", str(EXAMPLES / "sweep_clamp.toml")]
    done = subprocess.run(
        [*argv, "--out", str(tmp_path / "out"), "--engine", "ray"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines() == [
        "finray: error: the ray engine needs Ray, which is not installed here: "
        "pip install 'finray_jax[ray]'"
    ]
    assert not (tmp_path / "out" / "results.csv").exists()


def test_the_package_never_imports_ray_unless_asked():
    code = (
        "import sys, finray_jax, finray_jax.cli, finray_jax.sweep, finray_jax.studies, "
        "finray_jax.engines; print('ray' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.stdout.strip() == "False", done.stderr
