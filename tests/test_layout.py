"""The code layout that docs/reference/layout.md states: the layers import one way (experiments ->
estimator -> actions -> physics), no import circle among the modules, the filter imports at most five
project modules, no library module much over 400 lines, and the hybrid modes are asked through
their registry (:mod:`actions.modes`), not compared by code. Read from the source with ``ast``: a
module's imports are those at its top level (not inside a function, not under ``TYPE_CHECKING``)."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("physics", "actions", "estimator", "experiments")
"""Lowest first: a layer imports only those before it and itself."""
MAX_LINES = 415


def _modules() -> dict[str, Path]:
    out = {}
    for layer in LAYERS:
        for path in sorted((ROOT / layer).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _top_level_imports(name: str) -> set[str]:
    path = MODULES[name]
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found: set[str] = set()
    stack = list(ast.parse(path.read_text()).body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            stack.extend(ast.iter_child_nodes(node))
            continue
        for t in targets:
            while t and t not in MODULES and "." in t:
                t = t.rsplit(".", 1)[0]
            if t in MODULES and t != name:
                found.add(t)
    return found


GRAPH = {name: _top_level_imports(name) for name in MODULES}


def test_the_layers_import_one_way():
    rank = {layer: i for i, layer in enumerate(LAYERS)}
    wrong = [(m, d) for m, deps in GRAPH.items() for d in deps
             if rank[d.split(".")[0]] > rank[m.split(".")[0]]]
    assert wrong == []


def test_no_import_circle():
    # a package importing its own submodules (and they it) is how packages are built, not a circle
    def own(a: str, b: str) -> bool:
        return a.startswith(b + ".") or b.startswith(a + ".")

    graph = {m: {d for d in deps if not own(m, d)} for m, deps in GRAPH.items()}
    done: set[str] = set()
    for start in graph:
        on_path: list[str] = []
        visiting: set[str] = set()

        def visit(m: str) -> None:
            if m in done:
                return
            assert m not in visiting, " -> ".join(on_path[on_path.index(m):] + [m])
            visiting.add(m)
            on_path.append(m)
            for d in sorted(graph[m]):
                visit(d)
            on_path.pop()
            visiting.discard(m)
            done.add(m)

        visit(start)


def test_the_filter_imports_at_most_five_project_modules():
    deps = GRAPH["estimator.filter"]
    assert "estimator.model" in deps and len(deps) <= 5, sorted(deps)


def test_no_library_module_much_over_four_hundred_lines():
    long = {name: n for name, path in MODULES.items() if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def test_modes_are_asked_through_the_registry():
    compared = re.compile(r"[!=]=\s*(FREE|HELD)\b|\b(FREE|HELD)\s*[!=]=")
    found = [f"{name}:{i}" for name, path in MODULES.items() if name != "actions.modes"
             for i, line in enumerate(path.read_text().splitlines(), 1) if compared.search(line)]
    assert found == []


def test_nothing_imports_the_command_line():
    found = [(m, d) for m, deps in GRAPH.items() if not m.startswith("experiments.cli")
             for d in deps if d.startswith("experiments.cli")]
    assert found == []
