#!/usr/bin/env python3
"""The layout rules of the source tree (issue 37 item 5), checked by the test command:

1. **No module cycle in a Rust crate.** For every crate root (a `lib.rs` or `main.rs` under `src/`), the
   module tree is read from its `mod` declarations (`#[path]` included, inline `mod x { ... }` blocks
   too), and every path that names a module of the crate (`crate::a::b`, `super::x`, `self::x`, a child
   module's name, brace groups of `use` expanded) is an edge from the module it is written in to the
   deepest module it names. An edge between a module and one of its ancestors is containment (a
   submodule is part of its parent's implementation) and is not counted; any other edge A -> B is lifted
   to the two children of their lowest common ancestor that contain A and B. The submodules of every
   module must form a DAG: `model/a.rs` using `model/b.rs` while `b` uses `a` fails, wherever in the two
   subtrees the uses are.
2. **No long function or file without its reason.** A Rust or Python function body over
   {FN_LINES} lines, or a source file over {FILE_LINES} lines, must carry its reason: a comment starting
   `long:` (`// long: ...`, `# long: ...`) within the {REASON_WINDOW} lines above the function's `fn`/`def`
   line (its doc comment and attributes) or the first {REASON_WINDOW} lines of the file.

The import graph of the Python package has its own test (python/tests/test_import_graph.py).

    scripts/check_structure.py [ROOT]      exit 0: all rules hold; 1: the offenders, one a line, on stderr
"""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

FN_LINES = 120
FILE_LINES = 800
REASON_WINDOW = 8
__doc__ = __doc__.replace("{FN_LINES}", str(FN_LINES)).replace("{FILE_LINES}", str(FILE_LINES)) \
    .replace("{REASON_WINDOW}", str(REASON_WINDOW))

# what is scanned, relative to the root: the Rust crates and the Python sources of the project
RUST_DIRS = ["runtime", "tools", "cli", "bindings", "parity-tests", "fuzz"]
PY_DIRS = ["python/livegesture", "export", "bench", "scripts", "parity-tests/tools"]
# Cycles that exist and are to be removed, each with its reason: the check fails when one of them changes
# (a module joins or leaves it) or disappears (then the entry goes), and on every other cycle.
KNOWN_CYCLES = {
    # face/ (issue 41, reworked by another change this turn) holds both data that the lower modules use
    # (bundle: FaceManifest; output: ARKIT/viseme names, FaceValues) and the face runtime on top of the model
    # (FacedModel, with_face, called by model::load_with). To remove: the data into bundle/output, the
    # runtime under model/.
    # (error is in it only through that cycle: it uses bundle, model uses it)
    ("runtime/src/lib.rs", ()): {"backend", "bundle", "error", "face", "model", "output"},
}
SKIP_PARTS = {"target", "node_modules", "dist", "pkg", ".venv", "__pycache__"}


def _skipped(p: Path, root: Path) -> bool:
    return any(part in SKIP_PARTS for part in p.relative_to(root).parts)


# --- Rust source, without comments and literals ------------------------------------------------------------

def strip_rust(text: str) -> str:
    """The source with comments, string and char literals blanked (newlines kept, so lines still count)."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "r" and re.match(r'r#*"', text[i:i + 40]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            hashes = re.match(r'r(#*)"', text[i:]).group(1)
            end = text.find('"' + hashes, i + 2 + len(hashes))
            j = n if end < 0 else end + 1 + len(hashes)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('"' + re.sub(r"[^\n]", " ", text[i + 1:j]) + '"')
            i = j + 1
        elif c == "'":
            m = re.match(r"'(\\.[^']*|[^\\'])'", text[i:i + 12])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
            else:  # a lifetime or a label
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


# --- Rust module trees ---------------------------------------------------------------------------------------

MOD_DECL = re.compile(r"(?:#\[path\s*=\s*\"(?P<path>[^\"]+)\"\]\s*)?(?:#\[[^\]]*\]\s*)*"
                      r"(?:pub(?:\([^)]*\))?\s+)?mod\s+(?P<name>[a-z_][a-z0-9_]*)\s*(?P<end>[;{])")


def _path_attrs(raw: str) -> dict[int, str]:
    """`#[path = "..."]` attributes by the offset of the `mod` they precede (read from the raw text: the
    stripped one has lost the string)."""
    out = {}
    for m in re.finditer(r"#\[path\s*=\s*\"([^\"]+)\"\]\s*(?:#\[[^\]]*\]\s*)*(?:pub(?:\([^)]*\))?\s+)?(mod)\b", raw):
        out[m.start(2)] = m.group(1)
    return out


class Crate:
    """One crate's modules: path tuple -> (file, [(start, end) offsets of its text in that file])."""

    def __init__(self, root_file: Path):
        self.root_file = root_file
        self.modules: dict[tuple, Path] = {}
        self.spans: dict[tuple, list] = {}  # module -> [(file, stripped text, start, end, inner spans)]
        self.edges: dict[tuple, set] = {}
        self._load_file((), root_file, is_mod_rs=True)

    def _load_file(self, path: tuple, f: Path, is_mod_rs: bool):
        raw = f.read_text(encoding="utf-8", errors="replace")
        text = strip_rust(raw)
        self.modules[path] = f
        self._scan_block(path, f, raw, text, 0, len(text), is_mod_rs, inline_dirs=())

    def _scan_block(self, path, f, raw, text, start, end, is_mod_rs, inline_dirs):
        """Declares the modules in text[start:end] (module `path`) and records its spans."""
        attrs = _path_attrs(raw)
        inner = []
        i = start
        while True:
            m = MOD_DECL.search(text, i, end)
            if not m:
                break
            name = m.group("name")
            mod_at = text.rfind("mod", m.start(), m.start("name"))
            child = path + (name,)
            if m.group("end") == ";":
                base = f.parent if is_mod_rs else f.parent / f.stem
                base = base.joinpath(*inline_dirs)
                attr = attrs.get(mod_at)
                if attr:
                    cands = [(f.parent.joinpath(*inline_dirs) / attr)]
                else:
                    cands = [base / f"{name}.rs", base / name / "mod.rs"]
                target = next((c for c in cands if c.is_file()), None)
                if target is not None and child not in self.modules:
                    self._load_file(child, target.resolve(), is_mod_rs=target.name == "mod.rs" or bool(attr))
                i = m.end()
            else:
                close = _matching_brace(text, m.end() - 1)
                self.modules.setdefault(child, f)
                self._scan_block(child, f, raw, text, m.end(), close, is_mod_rs, inline_dirs + (name,))
                inner.append((m.start(), close + 1))
                i = close + 1
        self.spans.setdefault(path, []).append((f, text, start, end, inner))

    def build_edges(self):
        for mod, spans in self.spans.items():
            for _f, text, start, end, inner in spans:
                body = list(text[start:end])
                for a, b in inner:  # an inline module's text is its own
                    for k in range(a - start, b - start):
                        if body[k] != "\n":
                            body[k] = " "
                for target in self._references(mod, "".join(body)):
                    if target != mod:
                        self.edges.setdefault(mod, set()).add(target)

    def _references(self, mod: tuple, body: str):
        paths = []
        for u in re.finditer(r"\buse\s+([^;]+);", body):
            paths += expand_use(u.group(1))
        for p in re.finditer(r"\b(?:crate|super|self|[a-z_][a-z0-9_]*)(?:\s*::\s*[A-Za-z_][A-Za-z0-9_]*)+", body):
            paths.append(re.sub(r"\s+", "", p.group(0)))
        for p in paths:
            t = self.resolve(mod, p.split("::"))
            if t is not None:
                yield t

    def resolve(self, mod: tuple, segs: list[str]):
        """The deepest module of this crate that the path names, or None."""
        if not segs:
            return None
        if segs[0] == "crate":
            cur, rest = (), segs[1:]
        elif segs[0] in ("super", "self"):
            cur, rest = mod, segs
            while rest and rest[0] in ("super", "self"):
                if rest[0] == "super":
                    if not cur:
                        return None
                    cur = cur[:-1]
                rest = rest[1:]
        elif mod + (segs[0],) in self.modules:  # a child module by its name
            cur, rest = mod, segs
        else:
            return None
        for s in rest:
            if cur + (s,) in self.modules:
                cur = cur + (s,)
            else:
                break
        return cur

    def sibling_cycles(self):
        """Cycles among the submodules of each module, after lifting every edge (see the module doc)."""
        lifted: dict[tuple, dict[str, set]] = {}
        why: dict[tuple, tuple] = {}
        for a, targets in self.edges.items():
            for b in targets:
                k = 0
                while k < min(len(a), len(b)) and a[k] == b[k]:
                    k += 1
                if k == len(a) or k == len(b):  # one contains the other
                    continue
                parent, x, y = a[:k], a[k], b[k]
                lifted.setdefault(parent, {}).setdefault(x, set()).add(y)
                why.setdefault((parent, x, y), (a, b))
        out = []
        for parent, g in sorted(lifted.items()):
            for scc in strongly_connected(g):
                c = find_cycle({x: g.get(x, set()) & scc for x in scc})
                steps = []
                for x, y in zip(c, c[1:]):
                    a, b = why[(parent, x, y)]
                    steps.append(f"{'::'.join(a) or 'crate'} uses {'::'.join(b) or 'crate'}")
                out.append((parent, scc, c, steps))
        return out


def strongly_connected(graph: dict) -> list[frozenset]:
    """The strongly connected components of more than one node."""
    nodes = set(graph) | {m for ms in graph.values() for m in ms}

    def reach(n):
        seen, todo = set(), [n]
        while todo:
            for m in graph.get(todo.pop(), ()):
                if m not in seen:
                    seen.add(m)
                    todo.append(m)
        return seen

    r = {n: reach(n) for n in nodes}
    comps = {frozenset([n] + [m for m in r[n] if n in r[m]]) for n in nodes}
    return sorted((c for c in comps if len(c) > 1), key=sorted)


def _matching_brace(text: str, i: int) -> int:
    depth = 0
    for j in range(i, len(text)):
        if text[j] == "{":
            depth += 1
        elif text[j] == "}":
            depth -= 1
            if depth == 0:
                return j
    return len(text) - 1


def expand_use(tree: str) -> list[str]:
    """`a::{b, c::{d, e}}` -> [a::b, a::c::d, a::c::e] (aliases and globs dropped to their path)."""
    tree = re.sub(r"\s+as\s+[A-Za-z_][A-Za-z0-9_]*", "", tree)
    tree = re.sub(r"\s+", "", tree)

    def split_top(s):
        parts, depth, cur = [], 0, ""
        for ch in s:
            if ch == "," and depth == 0:
                parts.append(cur)
                cur = ""
                continue
            depth += ch == "{"
            depth -= ch == "}"
            cur += ch
        if cur:
            parts.append(cur)
        return parts

    def go(s):
        if "{" not in s:
            return [s.rstrip(":*").rstrip(":")]
        i = s.index("{")
        prefix = s[:i].rstrip(":")
        inner = s[i + 1:s.rindex("}")]
        out = []
        for part in split_top(inner):
            for q in go(part):
                out.append(prefix if q in ("self", "") else f"{prefix}::{q}" if prefix else q)
        return out

    return [p for p in go(tree) if p]


def find_cycle(graph: dict) -> list | None:
    """One cycle of the directed graph (its nodes, the first repeated at the end), or None."""
    state: dict = {}
    stack: list = []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                c = visit(m)
                if c:
                    return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            c = visit(n)
            if c:
                return c
    return None


def crate_roots(root: Path) -> list[Path]:
    out = []
    for d in RUST_DIRS:
        for p in sorted((root / d).rglob("src/*.rs")) if (root / d).is_dir() else []:
            if p.name in ("lib.rs", "main.rs") and not _skipped(p, root):
                out.append(p)
    return out


# --- long functions and files --------------------------------------------------------------------------------

def _has_reason(lines: list[str], first: int, last: int) -> bool:
    return any(re.search(r"(//|#)\s*long:", lines[k]) for k in range(max(first, 0), min(last, len(lines))))


def long_rust(f: Path) -> list[str]:
    raw = f.read_text(encoding="utf-8", errors="replace")
    lines = raw.splitlines()
    text = strip_rust(raw)
    out = []
    if len(lines) > FILE_LINES and not _has_reason(lines, 0, REASON_WINDOW):
        out.append(f"{f}: {len(lines)} lines (over {FILE_LINES}) and no `// long:` reason in its first "
                   f"{REASON_WINDOW} lines")
    for m in re.finditer(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)", text):
        # the body: the first `{` after the signature, unless a `;` comes first (a declaration)
        j = m.end()
        depth = 0
        while j < len(text) and text[j] not in "{;":
            if text[j] in "(<[":
                depth += 1
            elif text[j] in ")>]":
                depth -= 1
            j += 1
        if j >= len(text) or text[j] == ";":
            continue
        close = _matching_brace(text, j)
        start_line = text.count("\n", 0, m.start())
        n = text.count("\n", j, close) + 1
        if n > FN_LINES and not _has_reason(lines, start_line - REASON_WINDOW, start_line + 2):
            out.append(f"{f}:{start_line + 1}: fn {m.group(1)} is {n} lines (over {FN_LINES}) and has no "
                       f"`// long:` reason above it")
    return out


def long_python(f: Path) -> list[str]:
    raw = f.read_text(encoding="utf-8", errors="replace")
    lines = raw.splitlines()
    out = []
    if len(lines) > FILE_LINES and not _has_reason(lines, 0, REASON_WINDOW):
        out.append(f"{f}: {len(lines)} lines (over {FILE_LINES}) and no `# long:` reason in its first "
                   f"{REASON_WINDOW} lines")
    try:
        tree = ast.parse(raw, str(f))
    except SyntaxError as e:
        return out + [f"{f}: not Python ({e})"]
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list]) - 1
            n = node.end_lineno - node.lineno + 1
            if n > FN_LINES and not _has_reason(lines, first - REASON_WINDOW, node.lineno + 1):
                out.append(f"{f}:{node.lineno}: def {node.name} is {n} lines (over {FN_LINES}) and has no "
                           f"`# long:` reason above it")
    return out


def main(argv: list[str], known_cycles: dict | None = None) -> int:
    root = Path(argv[0] if argv else Path(__file__).resolve().parents[1]).resolve()
    problems = []
    known = dict(KNOWN_CYCLES if known_cycles is None else known_cycles)
    for r in crate_roots(root):
        c = Crate(r)
        c.build_edges()
        for parent, scc, cycle, steps in c.sibling_cycles():
            rel = str(r.relative_to(root))
            where = "::".join(parent) or "the crate root"
            if known.get((rel, parent)) == set(scc):
                del known[(rel, parent)]
                print(f"check_structure: known cycle (KNOWN_CYCLES) in {rel} under {where}: {sorted(scc)}")
                continue
            problems.append(f"{rel}: module cycle under {where}: {' -> '.join(cycle)} ({'; '.join(steps)})")
    for (rel, parent), scc in known.items():
        if (root / rel).is_file():
            problems.append(f"{rel}: KNOWN_CYCLES lists {sorted(scc)} under {'::'.join(parent) or 'the crate root'}, "
                            "which is no longer the cycle there: remove or correct the entry")
    for d in RUST_DIRS:
        for f in sorted((root / d).rglob("*.rs")) if (root / d).is_dir() else []:
            if not _skipped(f, root):
                problems += [p.replace(str(root) + "/", "") for p in long_rust(f)]
    for d in PY_DIRS:
        for f in sorted((root / d).rglob("*.py")) if (root / d).is_dir() else []:
            if not _skipped(f, root):
                problems += [p.replace(str(root) + "/", "") for p in long_python(f)]
    for p in problems:
        print(f"check_structure: {p}", file=sys.stderr)
    if not problems:
        print(f"check_structure: {len(crate_roots(root))} crates, no module cycle but the known ones; no function "
              f"over {FN_LINES} lines or file over {FILE_LINES} lines without its reason")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
