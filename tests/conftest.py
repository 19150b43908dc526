"""Test configuration (as in diffrax's test/conftest.py): float64 everywhere, strict dtype
promotion, and slow tests opt-in (--runslow or -m slow).
"""

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


@pytest.fixture(autouse=True)
def _no_persistent_cache(monkeypatch):
    """No test reads or writes a persistent compilation cache: a CLI call in-process turns
    it on for the rest of the session, and the suite then read the user's cache (where an
    interrupted run can leave a half-written entry) and twice segfaulted in jax's cache
    code. A test of the cache sets its own; whatever a test leaves set is turned off."""
    monkeypatch.setenv("FINRAY_NO_CACHE", "1")
    yield
    if jax.config.jax_compilation_cache_dir is not None:
        jax.config.update("jax_compilation_cache_dir", None)


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
