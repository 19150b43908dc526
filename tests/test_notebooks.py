"""The notebooks in notebooks/ run top to bottom in a fresh kernel (quick mode), so they
cannot rot, and are stored without outputs."""

import pathlib

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

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


def test_notebooks_are_known():
    assert {p.stem for p in PATHS} == set(EXPECTED)


@pytest.mark.parametrize("path", PATHS, ids=[p.stem for p in PATHS])
def test_notebook_is_stored_clean(path):
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, "strip the outputs"


@pytest.mark.parametrize("path", RUNS, ids=[p.stem for p in PATHS])
def test_notebook_runs(path, monkeypatch):
    monkeypatch.setenv("FINRAY_QUICK", "1")
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        timeout=900,  # per cell: the first grasp of a topology compiles for minutes
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOKS)}},
    )
    client.execute()  # raises CellExecutionError on the first failing cell
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
