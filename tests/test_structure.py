"""The package's module structure, read from the source with `ast` (nothing is imported):
its internal imports form no cycle (counting the imports inside functions), they are all
at module top level, and no module reaches for another module's private (underscore)
names."""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "finray_jax"
INIT = "__init__"

# Private names another module may use (none: a shared name is public where it is defined).
ALLOWED_PRIVATE: set[tuple[str, str]] = set()


def _modules() -> dict[str, ast.Module]:
    return {p.stem: ast.parse(p.read_text(encoding="utf-8")) for p in sorted(PACKAGE.glob("*.py"))}


def _imports(name: str, tree: ast.Module, modules):
    """Every package-internal import in a module, wherever it is: (node, target module,
    the names it takes from the target (None: the module itself), alias -> module for the
    modules it binds)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:
                parts = node.module.split(".") if node.module else []
            elif node.level == 0 and (node.module or "").split(".")[0] == "finray_jax":
                parts = node.module.split(".")[1:]
            else:
                continue
            assert node.level <= 1 and len(parts) <= 1, ast.unparse(node)
            if parts:  # from .mod import a, b
                out.append((node, parts[0], [a.name for a in node.names], {}))
            else:  # from . import mod (a module), or from . import name (the package's)
                for a in node.names:
                    if a.name in modules and a.name != INIT:
                        out.append((node, a.name, None, {a.asname or a.name: a.name}))
                    else:
                        out.append((node, INIT, [a.name], {}))
        elif isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if parts[0] != "finray_jax":
                    continue
                target = parts[1] if len(parts) > 1 else INIT
                alias = {a.asname: target} if a.asname else {}
                out.append((node, target, None, alias))
    return [x for x in out if x[1] != name]


def _graph(modules) -> dict[str, set[str]]:
    return {
        name: {target for _, target, _, _ in _imports(name, tree, modules)}
        for name, tree in modules.items()
    }


def _cycle(graph):
    """One import cycle as a list of modules (first == last), or None."""
    state, stack = {}, []

    def visit(u):
        state[u] = "open"
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == "open":
                return stack[stack.index(v) :] + [v]
            if v not in state:
                found = visit(v)
                if found:
                    return found
        stack.pop()
        state[u] = "done"
        return None

    for u in sorted(graph):
        if u not in state:
            found = visit(u)
            if found:
                return found
    return None


def test_every_internal_import_names_a_module_of_the_package():
    modules = _modules()
    unknown = {
        f"{name} imports {target}"
        for name, tree in modules.items()
        for _, target, _, _ in _imports(name, tree, modules)
        if target not in modules
    }
    assert not unknown, sorted(unknown)


def test_the_internal_import_graph_has_no_cycle():
    graph = _graph(_modules())
    assert "_contact" in graph and graph["_grasp"]  # (the parse found the package)
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_internal_imports_are_at_module_top_level():
    modules = _modules()
    inner = []
    for name, tree in modules.items():
        top = {id(node) for node in tree.body}
        for node, _, _, _ in _imports(name, tree, modules):
            if id(node) not in top:
                inner.append(f"{name}.py:{node.lineno}: {ast.unparse(node)}")
    assert not inner, inner


def _private_uses(name, tree, modules):
    """(target module, private name, line) for each private name of another module this
    one imports, or reads as an attribute of a module it imported."""
    uses, aliases = [], {}
    for node, target, names, alias in _imports(name, tree, modules):
        aliases.update(alias)
        for n in names or ():
            if n.startswith("_") and not n.startswith("__"):
                uses.append((target, n, node.lineno))
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in aliases
            and node.attr.startswith("_")
            and not node.attr.startswith("__")
        ):
            uses.append((aliases[node.value.id], node.attr, node.lineno))
    return uses


def test_no_module_uses_another_modules_private_names():
    modules = _modules()
    found, allowed_used = [], set()
    for name, tree in modules.items():
        for target, private, line in _private_uses(name, tree, modules):
            if (target, private) in ALLOWED_PRIVATE:
                allowed_used.add((target, private))
            else:
                found.append(f"{name}.py:{line}: {target}.{private}")
    assert not found, found
    # The exceptions stay in use (an unused one is removed from the list).
    assert allowed_used == ALLOWED_PRIVATE, sorted(ALLOWED_PRIVATE - allowed_used)


def test_private_name_finder_sees_both_forms():
    tree = ast.parse(
        "from ._a import _x, y\nfrom . import _b as b\nimport finray_jax._c as c\n"
        "def f():\n    return b._z + c._w + b.public + y"
    )
    modules = {"m": None, "_a": None, "_b": None, "_c": None}
    uses = {(t, n) for t, n, _ in _private_uses("m", tree, modules)}
    assert uses == {("_a", "_x"), ("_b", "_z"), ("_c", "_w")}


# One concern per file, and functions a reader takes in at once: a module over this many
# lines holds more than one thing, a function over this many does several steps that want
# names of their own.
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 85


def test_no_module_is_longer_than_a_concern():
    long = {
        p.name: n
        for p in sorted(PACKAGE.glob("*.py"))
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    }
    assert not long, long


def test_no_function_is_longer_than_a_few_steps():
    long = {}
    for name, tree in _modules().items():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long[f"{name}.{node.name}"] = n
    assert not long, long
