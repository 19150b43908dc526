# One command each: `make demo` runs the main job, `make test` the test suite.
# Both create the virtual environment and install what they need.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Test processes (pytest-xdist; whole files per process, as they share compiled programs).
# Each holds up to ~5 GB; 0 runs the suite in this process.
TEST_WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

.PHONY: demo test test-all bench lint clean

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH (or run: make PYTHON=python3 ...)"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/finray demo --out demo_output

test: $(STAMP)
	$(PYTEST) -m "not slow and not opensees"

test-all: $(STAMP)
	$(PYTEST) --runslow

bench: $(STAMP)
	taskset -c 0 $(BIN)/python benchmarks/solve.py

lint: $(STAMP)
	$(BIN)/python -m pip install -q ruff && $(BIN)/ruff check . && $(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) demo_output .pytest_cache

# Side-by-side with openseespy, PyElastica and a SciPy single-shooting solver (issue 5);
# needs the bench extra (and the system BLAS/LAPACK for openseespy: see shared/NUMERICS.md).
.PHONY: bench-peers
bench-peers: $(STAMP)
	$(BIN)/python -m pip install -q -e ".[bench]"
	taskset -c 0 $(BIN)/python benchmarks/peers.py
	taskset -c 0 $(BIN)/python benchmarks/gradients.py
	taskset -c 0 $(BIN)/python benchmarks/scaling.py
