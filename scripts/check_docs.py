#!/usr/bin/env python3
"""Docs check (run by scripts/test.sh): every relative link in the tracked Markdown files resolves, and no
tracked text cites the outside specification (the word SPEC followed by a section number) instead of the repository's own docs pages.

    python3 scripts/check_docs.py            # the repository's tracked files; exit 1 on any problem
    python3 scripts/check_docs.py FILE.md... # only these files (links are still resolved in the tree)

A link `[text](target)` or `![alt](target)` whose target is not a URL (`http:`, `https:`, `mailto:`) must
name an existing file or folder, relative to the Markdown file (or to the repository root when it starts with
`/`); a `#fragment` on a Markdown target (or a bare `#fragment`) must match one of that file's headings, with
GitHub's rule for heading anchors (lower case, punctuation dropped, spaces to `-`, `-1`, `-2` for repeats).
Links inside code blocks and inline code are ignored. Standard library only.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parent.parent
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
SPEC_REF = re.compile(r"\bSPEC\s+(?:section\s+)?\d")
TEXT_SUFFIXES = {".md", ".rs", ".py", ".sh", ".toml", ".json", ".txt", ".js", ".mjs", ".ts", ".html", ".c", ".h", ".yml", ".yaml"}


def tracked_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, check=True, capture_output=True).stdout
    return [ROOT / p for p in out.decode().split("\0") if p and not p.startswith("fuzz/corpus/")]


def strip_code(text: str, inline: bool = True) -> str:
    """Blank out fenced code blocks (and inline code when ``inline``), keeping line numbers."""
    lines, fenced = [], False
    for line in text.split("\n"):
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
            lines.append("")
            continue
        lines.append("" if fenced else re.sub(r"`[^`]*`", "", line) if inline else line)
    return "\n".join(lines)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading's text."""
    h = re.sub(r"`", "", heading.strip().lower())
    h = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", h)  # a link in a heading: its text
    h = re.sub(r"[^\w\- ]", "", h)
    return h.replace(" ", "-")


def rel(p: Path) -> str:
    return str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else str(p)


_anchors: dict[Path, set[str]] = {}


def anchors(md: Path) -> set[str]:
    if md not in _anchors:
        seen: dict[str, int] = {}
        found = set()
        for line in strip_code(md.read_text(encoding="utf-8"), inline=False).split("\n"):
            m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
            if not m:
                continue
            s = slug(m.group(1))
            n = seen.get(s, 0)
            seen[s] = n + 1
            found.add(s if n == 0 else f"{s}-{n}")
        _anchors[md] = found
    return _anchors[md]


def check_links(md: Path) -> list[str]:
    problems = []
    text = strip_code(md.read_text(encoding="utf-8"))
    for lineno, line in enumerate(text.split("\n"), 1):
        for m in LINK.finditer(line):
            target = m.group(1)
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):
                continue  # a URL
            path_part, _, fragment = target.partition("#")
            path_part = unquote(path_part)
            if path_part:
                dest = (ROOT / path_part.lstrip("/")) if path_part.startswith("/") else (md.parent / path_part)
            else:
                dest = md
            dest = dest.resolve()
            where = f"{rel(md)}:{lineno}"
            if not dest.exists():
                problems.append(f"{where}: link to {target!r}: no such file {rel(dest)}")
                continue
            if fragment and dest.suffix == ".md" and dest.is_file() and fragment.lower() not in anchors(dest):
                problems.append(f"{where}: link to {target!r}: {rel(dest)} has no heading with anchor #{fragment}")
    return problems


def check_spec_refs(path: Path) -> list[str]:
    if path.suffix not in TEXT_SUFFIXES or "dist" in path.parts:
        return []
    try:
        text = path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, OSError):
        return []
    return [f"{rel(path)}:{i}: cites the outside specification ({m.group(0)!r}); cite the docs page instead"
            for i, line in enumerate(text.split("\n"), 1) for m in SPEC_REF.finditer(line)]


def main(argv: list[str]) -> int:
    files = [Path(a).resolve() for a in argv] if argv else tracked_files()
    problems = []
    for f in files:
        if f.suffix == ".md":
            problems += check_links(f)
        problems += check_spec_refs(f)
    for p in problems:
        print(p, file=sys.stderr)
    n_md = sum(f.suffix == ".md" for f in files)
    if problems:
        print(f"docs check: {len(problems)} problem(s) in {len(files)} files", file=sys.stderr)
        return 1
    print(f"docs check: {n_md} Markdown files, every relative link resolves; no outside-specification reference")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
