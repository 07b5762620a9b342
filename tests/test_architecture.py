"""The package's shape: no import cycle (imports inside functions and type-only imports count), no private name
imported across modules, no function over 100 lines. An AST walk of src/pokeworld, so a new cycle or a new
private reach-in fails here rather than in a reviewer's head."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "src" / "pokeworld"


def _modules() -> dict[str, tuple[Path, ast.Module]]:
    out = {}
    for p in sorted(ROOT.rglob("*.py")):
        name = ".".join(p.relative_to(ROOT.parent).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = (p, ast.parse(p.read_text()))
    return out


def _imports(name: str, path: Path, tree: ast.Module, mods) -> list[tuple[str, str]]:
    """(target module, imported name) of every package import in a module, wherever it sits."""
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("pokeworld"):
                found += [(f"{target}.{a.name}" if f"{target}.{a.name}" in mods else target, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(a.name, "") for a in node.names if a.name.startswith("pokeworld")]
    return found


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_and_no_private_names_across_modules():
    mods = _modules()
    edges, private = {}, []
    for name, (path, tree) in mods.items():
        for target, imported in _imports(name, path, tree, mods):
            if target in mods and target != name and not name.startswith(target + "."):
                edges.setdefault(name, set()).add(target)
            if imported.startswith("_") and not imported.startswith("__"):
                private.append(f"{name} imports {imported} from {target}")
    assert not private, private
    assert not _cycles(edges), _cycles(edges)


def test_no_function_over_100_lines():
    long = [f"{name}.{node.name}: {node.end_lineno - node.lineno + 1} lines"
            for name, (_, tree) in _modules().items() for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > 100]
    assert not long, long


def test_the_checks_can_fail():
    """A planted two-module cycle and a planted private import are found (the walk is not vacuous)."""
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    tree = ast.parse("from .state import _trunk_at\n")
    mods = {"pokeworld.evaluate.state": None, "pokeworld.evaluate.measure": None}
    got = _imports("pokeworld.evaluate.measure", Path("measure.py"), tree, mods)
    assert got == [("pokeworld.evaluate.state", "_trunk_at")]
    with pytest.raises(AssertionError):
        assert not [imp for _, imp in got if imp.startswith("_")]
