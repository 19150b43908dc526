# One command each: `make demo` runs the main job, `make test` the test suite.
# Both create the virtual environment and install what they need.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The openseespy reference solver (the `bench` extra) and the system BLAS/LAPACK it loads,
# and Ray (the `ray` extra) for the tests on a local Ray cluster.
REFERENCE := $(VENV)/.installed-reference
# Test processes (pytest-xdist; whole files per process, as they share compiled programs;
# in the order tests/conftest.py gives them, the costliest first). Each holds up to ~7 GB;
# 0 runs the suite in this process.
TEST_WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

.PHONY: demo test test-all test-fast bench lint clean

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH (or run: make PYTHON=python3 ...)"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

$(REFERENCE): $(STAMP)
	@ldconfig -p 2>/dev/null | grep -q 'liblapack\.so\.3' || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libblas3 liblapack3 >/dev/null; \
	  else \
	    echo "openseespy needs the system BLAS/LAPACK (Debian: apt-get install libblas3 liblapack3)"; exit 1; \
	  fi; }
	$(BIN)/python -m pip install -q -e ".[test,bench,ray,explore]"
	touch $(REFERENCE)

# Headless Chromium and its driver (Debian packages): the explorer's browser tests.
BROWSER := $(VENV)/.installed-browser
$(BROWSER): $(STAMP)
	@{ command -v chromium && command -v chromedriver; } >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null; \
	  else \
	    echo "the explorer's browser tests need Chromium (Debian: apt-get install chromium chromium-driver)"; exit 1; \
	  fi; }
	touch $(BROWSER)

demo: $(STAMP)
	$(BIN)/finray demo --out demo_output

# What CI runs: the default and slow tests, the notebooks, `finray demo`, the explorer in
# headless Chromium, sweeps on a local Ray cluster, and the comparisons with the openseespy
# reference (re-run as well; a missing reference, Ray, Bokeh or selenium fails the run
# instead of skipping its tests), but not the tests marked `extended` (the optimize/
# scripts, `finray compare` with a clamp study, and the exhaustive finite-difference checks
# of every design value's derivative on Finger-1 and ref-A L2), which `make test-all`
# adds. The test processes and the CLI, script and notebook processes they start share
# one persistent compilation cache.
# A test still running after TEST_TIMEOUT seconds fails with its stack (pytest-timeout)
# instead of holding the run; the slowest tests' times are listed at the end.
TEST_CACHE ?= $(CURDIR)/.cache/test-xla
TEST_TIMEOUT ?= 1800
TEST_ALL := FINRAY_TEST_CACHE_DIR=$(TEST_CACHE) $(PYTEST) --runslow --require openseespy \
  --require nbformat --require ray --require bokeh --require selenium --timeout $(TEST_TIMEOUT) \
  --durations 25
test: $(REFERENCE) $(BROWSER)
	$(TEST_ALL) -m "not extended"

test-all: $(REFERENCE) $(BROWSER)
	$(TEST_ALL)

# The developers' subset: no slow and no openseespy-re-running tests.
test-fast: $(STAMP)
	$(PYTEST) -m "not slow and not opensees"

bench: $(STAMP)
	taskset -c 0 $(BIN)/python benchmarks/solve.py

lint: $(STAMP)
	$(BIN)/python -m pip install -q ruff && $(BIN)/ruff check . && $(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) demo_output .pytest_cache .cache

# Side-by-side with openseespy, PyElastica and a SciPy single-shooting solver.
.PHONY: bench-peers
bench-peers: $(REFERENCE)
	taskset -c 0 $(BIN)/python benchmarks/peers.py
	taskset -c 0 $(BIN)/python benchmarks/gradients.py
	taskset -c 0 $(BIN)/python benchmarks/scaling.py
