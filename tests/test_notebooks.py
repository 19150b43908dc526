"""The notebooks in notebooks/ run top to bottom in a fresh kernel (quick mode), so they
cannot rot, and are stored without outputs.

Each notebook is executed by nbclient in a child Python process, which writes the executed
notebook to a file: the test process never imports zmq or starts nbclient's IO threads,
whose state would otherwise stay in it for the rest of the suite."""

import importlib.util
import os
import pathlib
import subprocess
import sys

import pytest

nbformat = pytest.importorskip("nbformat")
for _name in ("nbclient", "ipykernel"):  # (found, not imported: see above)
    if importlib.util.find_spec(_name) is None:
        pytest.skip(f"{_name} is not installed", allow_module_level=True)

NOTEBOOKS = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
PATHS = sorted(NOTEBOOKS.glob("*.ipynb"))
# Notebooks that take several minutes even in quick mode (two grasp topologies to
# compile, differentiated grasps): run with --runslow.
SLOW = {"02_adaptors_and_clamp_study", "03_design_optimisation"}
RUNS = [pytest.param(p, marks=[pytest.mark.slow] if p.stem in SLOW else []) for p in PATHS]

# Text each notebook must print: the headline results of its story.
EXPECTED = {
    "01_fig3_internal_forces": ["converged in", "force balance", "finite difference"],
    "02_adaptors_and_clamp_study": ["paper: +260 %", "holding-force change", "best l_c"],
    "03_design_optimisation": ["finite difference", "grasp from scratch", "designs in"],
}
FIGURES = {  # at least this many figures
    "01_fig3_internal_forces": 3,
    "02_adaptors_and_clamp_study": 4,
    "03_design_optimisation": 3,
}


# Run in the child: execute the notebook (argv[1]) in a fresh kernel, write it to argv[2].
_EXECUTE = """
import pathlib, sys
import nbclient, nbformat
path, out = sys.argv[1:]
nb = nbformat.read(path, as_version=4)
client = nbclient.NotebookClient(
    nb,
    timeout=900,  # per cell: the first grasp of a topology compiles for minutes
    kernel_name="python3",
    resources={"metadata": {"path": str(pathlib.Path(path).parent)}},
)
client.execute()
nbformat.write(nb, out)
"""


def test_notebooks_are_known():
    assert {p.stem for p in PATHS} == set(EXPECTED)


@pytest.mark.parametrize("path", PATHS, ids=[p.stem for p in PATHS])
def test_notebook_is_stored_clean(path):
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, "strip the outputs"


@pytest.mark.parametrize("path", RUNS, ids=[p.stem for p in PATHS])
def test_notebook_runs(path, tmp_path):
    executed = tmp_path / path.name
    env = dict(os.environ, FINRAY_QUICK="1", MPLBACKEND="module://matplotlib_inline.backend_inline")
    proc = subprocess.run(
        [sys.executable, "-c", _EXECUTE, str(path), str(executed)],
        env=env, capture_output=True, text=True, timeout=3600,
    )  # fmt: skip
    # (nbclient raises CellExecutionError on the first failing cell, with its traceback)
    assert proc.returncode == 0, proc.stderr[-4000:]
    nb = nbformat.read(executed, as_version=4)
    text, figures = [], 0
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert out.get("output_type") != "error"
            if out.get("output_type") == "stream":
                text.append(out["text"])
            figures += "image/png" in out.get("data", {})
    text = "".join(text)
    for phrase in EXPECTED[path.stem]:
        assert phrase in text, f"{path.name} did not print {phrase!r}"
    assert "quick mode: True" in text
    assert figures >= FIGURES[path.stem]
