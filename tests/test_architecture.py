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


#: (package, package it must never import, other than itself): the map's experiments know nothing of how their runs
#: travel to a GPU and back (pokeworld.remote imports pokeworld.experiments, never the reverse); the published
#: values are data, importing nothing of pokeworld.
NEVER_IMPORTS = [("pokeworld.experiments", "pokeworld.remote"), ("pokeworld.published", "pokeworld")]


def _inside(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def test_imports_point_one_way_between_packages():
    mods = _modules()
    wrong = [f"{name} imports {target}" for lower, upper in NEVER_IMPORTS
             for name, (path, tree) in mods.items() if _inside(name, lower)
             for target, _ in _imports(name, path, tree, mods)
             if _inside(target, upper) and not _inside(target, lower)]
    assert not wrong, wrong
    assert all(any(_inside(m, p) for m in mods) for pair in NEVER_IMPORTS for p in pair), "a package listed is gone"
    assert _inside("pokeworld.remote.run", "pokeworld.remote") and not _inside("pokeworld.remoteness", "pokeworld.remote")


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


# --------------------------------------------------------------------- the output contract and the JSON reader
# Every file pokeworld writes goes through pokeworld.io (atomic_path's private temporary, or open_nofollow), which
# refuses a file it did not write and never follows a link; every JSON record it reads back goes through
# io.read_json / read_jsonl / parse_json (bounded, regular files only, one-line errors). A new call site that writes
# or parses outside them fails here; the few that may are listed with the reason.

WRITE_CALLS = {"write_text", "write_bytes", "savefig", "save", "savez", "savez_compressed", "imwrite"}
READ_CALLS = {"read_text", "read_bytes"}
WRITE_ALLOWED = {
    # writers handed a path inside a private temporary folder by their caller's atomic_path
    ("pokeworld.real.fixtures", "write_mp4"): "its callers write inside atomic_path's private folder",
    ("pokeworld.real.fixtures", "save_dict"): "its callers write inside atomic_path's private folder",
    ("pokeworld.real.fixtures", "save_array"): "as save_dict: inside atomic_path's private folder, or a test folder",
    ("pokeworld.real.fixtures", "write_scene"): "test fixtures: a fresh pytest tmp_path folder",
    ("pokeworld.real.fixtures", "write_calib"): "test fixtures: a fresh pytest tmp_path folder",
    ("pokeworld.real.synthetic", "_write_cameras"): "called inside write_scene's atomic_path",
    ("pokeworld.real.synthetic", "_write_metadata"): "called inside write_scene's atomic_path",
    ("pokeworld.real.synthetic", "write_calib"): "inside its own atomic_path",
    ("pokeworld.remote.pack", "compact_bytes"): "serialises into memory (BytesIO), no file",
    ("pokeworld.swm.targets_table", "figure_png"): "renders into memory (BytesIO) before any output is written",
}
READ_ALLOWED = {
    ("pokeworld.config", "to_dict"): "a JSON round trip of a config in memory, no file",
    ("pokeworld.swm.certify_env", "corpus"): "a JSON round trip of a key in memory, no file",
    ("pokeworld.real.npy_child", "_serve"): "the child's request line from its parent's pipe",
    ("pokeworld.real.npy_child", "load"): "the child's reply on a pipe, bounded by the protocol",
    ("pokeworld.real.rh20t.assembly", "*"): "an attribute of the converter's own HDF5 cache, bounded by HDF5",
    ("pokeworld.real.rh20t.convert", "*"): "RH20T files read through rh20t.files' bounded regular-file readers",
    ("pokeworld.real.rh20t.scene", "*"): "RH20T files read through rh20t.files' bounded regular-file readers",
    ("pokeworld.swm.dataset", "*"): "an swm HDF5 root attribute, bounded by its declared size",
    ("pokeworld.real.fixtures", "*"): "test fixtures damaging files they wrote",
}


def _call_name(node: ast.Call) -> tuple[str, str]:
    """(receiver, attribute) of a call: ('json', 'loads'), ('', 'open'), ('path', 'write_text')."""
    f = node.func
    if isinstance(f, ast.Attribute):
        return (f.value.id if isinstance(f.value, ast.Name) else "", f.attr)
    return ("", f.id if isinstance(f, ast.Name) else "")


def _writes(node: ast.Call) -> bool:
    recv, name = _call_name(node)
    if name == "open" and recv == "":
        mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
        return isinstance(mode, ast.Constant) and any(c in str(mode.value) for c in "wax")
    if name in ("save", "savez", "savez_compressed"):
        return recv in ("np", "numpy", "torch")
    return name in WRITE_CALLS and name not in ("save", "savez", "savez_compressed")


def _reads(node: ast.Call) -> bool:
    recv, name = _call_name(node)
    return (recv == "json" and name in ("load", "loads")) or name in READ_CALLS


def _sites(tree: ast.Module):
    """(function name, call, inside an atomic_path block) for every call in a module."""
    out = []

    def visit(node, func: str, guarded: bool):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            func, guarded = node.name, False
        if isinstance(node, (ast.With, ast.AsyncWith)):
            guarded = guarded or any(isinstance(i.context_expr, ast.Call)
                                     and _call_name(i.context_expr)[1] in ("atomic_path", "open_nofollow")
                                     for i in node.items)
        if isinstance(node, ast.Call):
            out.append((func, node, guarded))
        for child in ast.iter_child_nodes(node):
            visit(child, func, guarded)

    visit(tree, "<module>", False)
    return out


def test_every_write_and_json_read_goes_through_io():
    bypass = []
    for name, (path, tree) in _modules().items():
        if name == "pokeworld.io":
            continue
        for func, call, guarded in _sites(tree):
            where = f"{path.relative_to(ROOT.parent)}:{call.lineno} ({func})"
            allowed = lambda table: (name, func) in table or (name, "*") in table  # noqa: E731
            if _writes(call) and not guarded and not allowed(WRITE_ALLOWED):
                bypass.append(f"write outside pokeworld.io's contract: {where}")
            if _reads(call) and not allowed(READ_ALLOWED):
                bypass.append(f"JSON/text read outside io.read_json: {where}")
    assert not bypass, "\n".join(bypass)


def test_the_allow_lists_name_real_functions():
    """An allow-list entry whose function is gone would silently allow a future one of that name."""
    defined = {(name, n.name) for name, (_, tree) in _modules().items() for n in ast.walk(tree)
               if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
    stale = [k for k in (*WRITE_ALLOWED, *READ_ALLOWED) if k[1] != "*" and k not in defined]
    assert not stale, stale
