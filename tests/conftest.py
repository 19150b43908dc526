"""Test configuration (as in diffrax's test/conftest.py): float64 everywhere, strict dtype
promotion, and slow tests opt-in (--runslow or -m slow).
"""

import gc
import importlib
import os

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

# JAX's persistent compilation cache, when FINRAY_TEST_CACHE_DIR names a directory (`make
# test` does): the suite's processes (pytest-xdist workers, and the CLI, scripts and
# notebook kernels it runs as subprocesses, through jax's own environment variables) and
# the recompiles after a cache clear (below) load a program compiled once instead of
# compiling it again. The cache key holds the program, the compiler's options and the
# versions, so a changed solver never loads a stale program. Without the variable no
# persistent cache is used (jax decides at its first compile whether it is used, and keeps
# to it for the life of the process).
CACHE_DIR = os.environ.get("FINRAY_TEST_CACHE_DIR", "").strip() or None
if CACHE_DIR:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = CACHE_DIR
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.2"
    jax.config.update("jax_compilation_cache_dir", CACHE_DIR)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
else:
    jax.config.update("jax_enable_compilation_cache", False)


@pytest.fixture(autouse=True)
def _no_cli_cache(monkeypatch):
    """No CLI call, in this process or a subprocess, points the compilation cache at the
    user's directory (FINRAY_NO_CACHE): the suite's cache, if any, is set above. A test of
    the cache settings sets its own."""
    monkeypatch.setenv("FINRAY_NO_CACHE", "1")


# The suite compiles a few hundred XLA programs in one process, and every compiled CPU
# program keeps its own memory mappings (ref-A's planar solve, its jitted parts together:
# ~790). Linux refuses new mappings beyond vm.max_map_count (65530 by default), and XLA's
# compiler then segfaults: the default suite did, at 84-90 % (test_validation), here and in
# CI. When a test leaves more than MAX_MAPS mappings, every jax cache is cleared (the
# programs are freed with their mappings; a later test that needs one compiles it again).
MAX_MAPS = 40_000
_MAPS = "/proc/self/maps"
_CLEARED = "jax caches cleared"  # (a user property: xdist carries it from its workers)
_cleared = []  # the lines to print in the summary


def _mappings() -> int | None:
    try:
        with open(_MAPS) as f:
            return sum(1 for _ in f)
    except OSError:  # (not Linux)
        return None


def pytest_runtest_teardown(item):
    n = _mappings()
    if n is not None and n > MAX_MAPS:
        jax.clear_caches()
        gc.collect()
        item.user_properties.append((_CLEARED, f"{n} -> {_mappings()} memory mappings"))


def pytest_runtest_logreport(report):
    for key, value in getattr(report, "user_properties", ()):
        if key == _CLEARED and report.when == "teardown":
            _cleared.append(f"{_CLEARED} after {report.nodeid}: {value}")


def pytest_terminal_summary(terminalreporter):
    for line in _cleared:
        terminalreporter.write_line(line)


def pytest_addoption(parser):
    parser.addoption(
        "--runslow",
        action="store_true",
        default=False,
        help="also run tests marked slow (full resolution, limit loads)",
    )
    parser.addoption(
        "--require",
        action="append",
        default=[],
        metavar="MODULE",
        help="fail at start-up if MODULE cannot be imported, instead of skipping the tests "
        "that need it (`make test` requires the openseespy reference and nbformat)",
    )


def pytest_configure(config):
    for name in config.getoption("--require"):
        try:
            importlib.import_module(name)
        except Exception as error:  # (openseespy fails with an OSError without LAPACK)
            raise pytest.UsageError(
                f"--require {name}: cannot import {name!r} ({error}); its tests would be skipped"
            ) from error


# The files that cost the most worker time (a cold compilation cache, --runslow), costliest
# first. They are collected first, so that with `--dist loadfile --no-loadscope-reorder`
# (`make test`) the two workers start on the long files and end on short ones instead of
# one waiting while the other finishes a long file. Only the order depends on this list.
HEAVY_FIRST = (
    "test_contact.py",
    "test_explore.py",
    "test_optimizer.py",
    "test_gradients.py",
    "test_cli_grasp.py",
    "test_optimize_scripts.py",
    "test_notebooks.py",
    "test_ray.py",
    "test_finger_invariants.py",
    "test_studies.py",
    "test_reference_grasp.py",
    "test_resolution.py",
    "test_grasp_forces.py",
    "test_wrap.py",
    "test_members.py",
    "test_banded.py",
    "test_cli.py",
    "test_sweep.py",
)


def pytest_collection_modifyitems(config, items):
    """The heavy files first (HEAVY_FIRST), the others in their order. Tests marked slow
    are skipped unless --runslow is given or -m asks for them."""
    rank = {name: k for k, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
    markexpr = config.getoption("markexpr", default="") or ""
    if config.getoption("--runslow") or "slow" in markexpr.replace("not slow", ""):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow (or -m slow)")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
