"""The scripts outside the package (benchmarks/, optimize/) name only what finray_jax has.

They run for minutes, so the default suite does not run them; a refactor that moves a name
would break them unseen. This reads each script's syntax tree instead:
every `from finray_jax... import NAME` and every attribute `ALIAS.NAME` of an imported
finray_jax module must exist.
"""

import ast
import importlib
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for d in ("benchmarks", "optimize") for p in (ROOT / d).glob("*.py"))


def missing_names(source: str) -> list[str]:
    """The finray_jax names that `source` imports or reads and that do not exist."""
    tree = ast.parse(source)
    modules, missing = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "finray_jax":
                    # `import finray_jax.x as y` binds y to finray_jax.x; plain
                    # `import finray_jax.x` binds finray_jax.
                    modules[a.asname or "finray_jax"] = a.name if a.asname else "finray_jax"
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "finray_jax":
            parent = importlib.import_module(node.module)
            for a in node.names:
                try:
                    modules[a.asname or a.name] = importlib.import_module(
                        f"{node.module}.{a.name}"
                    ).__name__
                except ModuleNotFoundError:
                    if not hasattr(parent, a.name):
                        missing.append(f"line {node.lineno}: from {node.module} import {a.name}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            module = modules.get(node.value.id)
            if module is not None and not hasattr(importlib.import_module(module), node.attr):
                missing.append(f"line {node.lineno}: {node.value.id}.{node.attr} ({module})")
    return missing


def test_the_check_finds_a_missing_name():
    source = (
        "from finray_jax import optimizer as O\n"
        "from finray_jax import solve_finger, no_such_function\n"
        "O._no_such_attribute\n"
        "O.run_optimize\n"
    )
    assert missing_names(source) == [
        "line 2: from finray_jax import no_such_function",
        "line 3: O._no_such_attribute (finray_jax.optimizer)",
    ]


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_script_names_exist(path):
    assert SCRIPTS, "no scripts found"
    assert missing_names(path.read_text()) == []
