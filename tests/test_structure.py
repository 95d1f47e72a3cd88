"""The package's house rules, read from its source: no import circles, no private names taken from another
module, imports at the top (a lazy import of a heavy or optional library says why on its line), and functions
that fit on a screen."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "slmlab"
MAX_FUNCTION_LINES = 80


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute module name a (relative) ``from`` import names."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str, path: Path):
    """``(target module, imported name, node, inside a function)`` for every import of a slmlab module."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    inside = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
              for n in ast.walk(f) if n is not f}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            target = _resolve(module, path, node)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                yield (sub if sub in MODULES else target), alias.name, node, id(node) in inside
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, None, node, id(node) in inside


def _graph() -> dict[str, set[str]]:
    graph = {m: set() for m in MODULES}
    for module, path in MODULES.items():
        for target, _, _, _ in _imports(module, path):
            if target in MODULES and target != module:
                graph[module].add(target)
    return graph


def test_no_import_circle_among_the_package_modules():
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                raise AssertionError("import circle: " + " -> ".join(stack[stack.index(n):] + [n]))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_no_private_name_is_taken_from_another_module():
    bad = [f"{module}: {name} from {target}" for module, path in MODULES.items()
           for target, name, _, _ in _imports(module, path)
           if target.startswith("slmlab") and name and name.startswith("_") and not name.startswith("__")
           and target != module]
    assert not bad, bad


def test_imports_inside_functions_are_third_party_and_say_why():
    bad = []
    for module, path in MODULES.items():
        lines = path.read_text(encoding="utf-8").splitlines()
        for target, _, node, inside in _imports(module, path):
            if not inside:
                continue
            if target.startswith("slmlab"):
                bad.append(f"{module}:{node.lineno} imports {target} inside a function")
            elif "#" not in lines[node.lineno - 1]:
                bad.append(f"{module}:{node.lineno} imports {target} inside a function without saying why")
    assert not bad, bad


@pytest.mark.parametrize("module", sorted(MODULES))
def test_functions_fit_on_a_screen(module):
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    long = [f"{n.name} ({n.end_lineno - n.lineno + 1} lines)" for n in ast.walk(tree)
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, long


def test_every_name_a_module_exports_exists():
    import importlib

    missing = []
    for module in MODULES:
        if module.endswith("__main__"):
            continue
        mod = importlib.import_module(module)
        missing += [f"{module}.{n}" for n in getattr(mod, "__all__", []) if not hasattr(mod, n)]
    assert not missing, missing
