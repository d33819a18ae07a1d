"""The package's modules import each other without cycles (function-level imports included), and each one
imports on its own in a fresh interpreter.

The graph is read from the source with ``ast``: an edge A -> B for every ``import``/``from ... import`` in A
(anywhere in the file) naming module B of the package (``from . import x`` names module ``x`` when it is
one). Packages' ``__init__`` modules are nodes like the others.
"""
from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

PKG_DIR = Path(__file__).resolve().parents[1] / "livegesture"
PKG = "livegesture"

# one cycle finder for the Rust crates and this package: the test command's layout check's
_spec = importlib.util.spec_from_file_location(
    "check_structure", Path(__file__).resolve().parents[2] / "scripts" / "check_structure.py")
_check_structure = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_check_structure)
find_cycle = _check_structure.find_cycle


def modules() -> dict[str, Path]:
    out = {}
    for p in sorted(PKG_DIR.rglob("*.py")):
        parts = list(p.relative_to(PKG_DIR.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    graph = {m: set() for m in mods}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        base = name.split(".") if is_pkg else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    root = base[: len(base) - (node.level - 1)]
                    mod = ".".join(root + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
            for t in targets:
                if t in mods and t != name:
                    graph[name].add(t)
    return graph


def test_the_graph_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None
    g = import_graph(modules())
    # the edges the reader must see: a relative module import, a function-level import, a package import
    assert "livegesture.trainkit" in g["livegesture.train"]
    assert "livegesture.variants" in g["livegesture.families"]             # inside Family.variants()
    assert "livegesture.families" in g["livegesture.stream"]               # from . import families
    assert "livegesture.checkpoint" in g["livegesture.train"]              # from . import checkpoint


def test_no_import_cycles():
    cycle = find_cycle(import_graph(modules()))
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_every_module_imports_alone():
    names = [m for m in modules() if not m.endswith("__main__")]
    code = ("import importlib, sys\nfor n in sys.argv[1:]:\n"
            "    for k in [k for k in sys.modules if k.startswith('livegesture')]: del sys.modules[k]\n"
            "    importlib.import_module(n)\n")
    r = subprocess.run([sys.executable, "-c", code, *names], cwd=PKG_DIR.parent, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
