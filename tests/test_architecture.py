"""docs/architecture.md's claims, checked on the sources: data flows one way between the
packages, studies sit above the library, and no module imports another that imports it
back (imports under ``if TYPE_CHECKING:`` are annotations, not dependencies)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dynamics", "controllers", "fmu", "scenarios")
ALLOWED = {  # package -> the packages it may import (the layers of docs/architecture.md)
    "dynamics": set(),
    "controllers": {"dynamics"},
    "fmu": {"dynamics", "controllers"},  # the controllers' laws exported as FMUs
    "scenarios": {"dynamics", "controllers", "fmu"},
}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = [p for p in f.relative_to(ROOT / pkg).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(["sarcomere", pkg, *parts])] = f
    return out


MODULES = _modules()


def _runtime_imports(tree: ast.AST):
    """Import nodes outside ``if TYPE_CHECKING:`` blocks."""
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            todo.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        todo.extend(ast.iter_child_nodes(node))


def _targets(module: str, node: ast.AST) -> set[str]:
    if isinstance(node, ast.Import):
        return {a.name for a in node.names}
    base = module.split(".")
    if node.level:
        is_package = MODULES[module].name == "__init__.py"
        base = base[: len(base) - node.level + is_package]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    return {f"{target}.{a.name}" if f"{target}.{a.name}" in MODULES else target for a in node.names}


def _graph() -> dict[str, set[str]]:
    graph = {}
    for module, path in MODULES.items():
        found = set()
        for node in _runtime_imports(ast.parse(path.read_text(encoding="utf-8"))):
            found |= {t for t in _targets(module, node) if t in MODULES}
        graph[module] = found - {module}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v: str) -> None:
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
            elif child not in index:
                index[child] = low[child] = counter[0]
                counter[0] += 1
                stack.append(child)
                on.add(child)
                work.append((child, iter(sorted(graph[child]))))
            elif child in on:
                low[node] = min(low[node], index[child])

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_import_graph_is_read_from_the_sources():
    graph = _graph()
    assert "sarcomere.dynamics.modeling.model" in graph["sarcomere.dynamics.simulation.common"]
    assert len(MODULES) > 80


def test_no_import_cycles():
    assert _cycles(_graph()) == []


def test_packages_import_only_the_layers_below():
    wrong = sorted(
        (a, b)
        for a, deps in _graph().items()
        for b in deps
        if a.split(".")[1] != b.split(".")[1] and b.split(".")[1] not in ALLOWED[a.split(".")[1]]
    )
    assert wrong == []


def test_the_library_never_imports_a_study():
    studies = {m for m in MODULES if ".studies" in m}
    wrong = sorted(
        (a, b) for a, deps in _graph().items() if a not in studies for b in deps if b in studies
    )
    # the CLI's `bench` command is the one door into the studies (scenarios sits above)
    assert [(a, b) for a, b in wrong if not a.startswith("sarcomere.scenarios.")] == []


def _imports_all(tree: ast.AST):
    """Every import node, those under ``if TYPE_CHECKING:`` included."""
    return [n for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)]


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_no_private_name_is_imported_across_modules():
    """A name with a leading underscore stays in its module: neither ``from m import _x``
    nor ``m._x`` on an imported module of the library, tests excluded."""
    wrong = []
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = {}
        for node in _imports_all(tree):
            if isinstance(node, ast.ImportFrom):
                for a in node.names:
                    target = _targets(module, ast.ImportFrom(node.module, [a], node.level))
                    if _private(a.name) and target & set(MODULES) and target != {module}:
                        wrong.append(f"{module}: from {node.module or '.'} import {a.name}")
                    full = next(iter(target))
                    if full in MODULES:
                        aliases[a.asname or a.name] = full
            else:
                for a in node.names:
                    if a.name in MODULES and a.asname:
                        aliases[a.asname] = a.name
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and _private(node.attr)
            ):
                wrong.append(f"{module}: {node.value.id}.{node.attr}")
    assert sorted(set(wrong)) == []


def test_no_import_cycles_even_for_annotations():
    """Type-only imports too: a cycle through ``if TYPE_CHECKING:`` is still a knot a
    reader has to untie."""
    graph = {}
    for module, path in MODULES.items():
        found = set()
        for node in _imports_all(ast.parse(path.read_text(encoding="utf-8"))):
            found |= {t for t in _targets(module, node) if t in MODULES}
        graph[module] = found - {module}
    assert _cycles(graph) == []


def test_no_library_file_over_600_lines():
    files = [
        f for pkg in PACKAGES for ext in ("py", "c", "h") for f in (ROOT / pkg).rglob(f"*.{ext}")
    ]
    long = {
        str(f.relative_to(ROOT)): n for f in files if (n := len(f.read_text().splitlines())) > 600
    }
    assert long == {}


def test_the_architecture_page_names_every_module():
    """docs/architecture.md stays a map of the whole house: a new module gets its line."""
    page = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    files = [
        f for pkg in PACKAGES for ext in ("py", "c", "h") for f in (ROOT / pkg).rglob(f"*.{ext}")
    ]
    missing = sorted(
        str(f.relative_to(ROOT)) for f in files if f.name != "__init__.py" and f.name not in page
    )
    assert missing == []
