"""Test configuration (as in diffrax's test/conftest.py): float64 everywhere, strict dtype
promotion, and slow tests opt-in (--runslow or -m slow).
"""

import gc

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
# No persistent compilation cache in the test process. Setting jax_compilation_cache_dir
# back to None does not turn one off: jax decides at its first compile whether the cache
# is used (compilation_cache.is_cache_used latches) and opens it at the first compile
# that finds a directory set (_initialize_cache, once), then reads and writes it for the
# rest of the process. With this off, neither ever happens.
jax.config.update("jax_enable_compilation_cache", False)


@pytest.fixture(autouse=True)
def _no_persistent_cache(monkeypatch):
    """No CLI call in-process sets a compilation cache directory (it would be unused, see
    above: the suite twice segfaulted in jax's cache code when a CLI call had opened the
    user's cache in-process). A test of the cache settings sets its own and restores it."""
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


def pytest_collection_modifyitems(config, items):
    """Tests marked slow are skipped unless --runslow is given or -m asks for them."""
    markexpr = config.getoption("markexpr", default="") or ""
    if config.getoption("--runslow") or "slow" in markexpr.replace("not slow", ""):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow (or -m slow)")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
