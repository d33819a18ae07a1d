#!/usr/bin/env python3
"""Every crate linked into one build, with the licence texts each crate ships, as one text file.

    scripts/licences.py PACKAGE TRIPLE FEATURES OUT.txt      (FEATURES: comma-separated, or "" for the defaults)

The crates are those `cargo tree -p PACKAGE --target TRIPLE -e normal` lists with exactly the build's features
(what is linked: no dev- or build-dependencies; cargo metadata would unify the whole workspace's features). For
each: name, version, SPDX licence expression, repository and the text of its LICENSE*/LICENCE*/COPYING*/NOTICE*
files, from cargo's registry sources (scripts/release.sh, docs/install.md). Run from the repository root.
"""
import json
import pathlib
import re
import subprocess
import sys

package, triple, features, out = sys.argv[1:5]
flags = ["--no-default-features", "--features", features] if features else []
tree = subprocess.run(["cargo", "tree", "-p", package, "--target", triple, "-e", "normal", "--prefix", "none",
                       "-f", "{p}", *flags], check=True, capture_output=True, text=True).stdout
wanted = set()
for line in tree.splitlines():
    m = re.match(r"(\S+) v(\S+)", line)
    if m:
        wanted.add((m.group(1), m.group(2)))
meta = json.loads(subprocess.run(["cargo", "metadata", "--format-version", "1"], check=True,
                                 capture_output=True, text=True).stdout)
pkgs = {(p["name"], p["version"]): p for p in meta["packages"]}
lines, missing = [], []
for key in sorted(wanted):
    p = pkgs.get(key)
    if p is None:
        sys.exit(f"licences.py: {key[0]} {key[1]} (from cargo tree) is not in cargo metadata")
    d = pathlib.Path(p["manifest_path"]).parent
    files = sorted(f for f in d.iterdir()
                   if f.is_file() and f.name.upper().startswith(("LICENSE", "LICENCE", "COPYING", "NOTICE")))
    lines.append("=" * 78 + f"\n{p['name']} {p['version']}  licence: {p.get('license') or p.get('license_file')}\n"
                 f"repository: {p.get('repository') or '-'}\n" + "=" * 78 + "\n")
    for f in files:
        lines.append(f"--- {f.name}\n{f.read_text(errors='replace')}\n")
    if not files:
        missing.append(p["name"])
        lines.append(f"(no licence file in the crate's package; its licence expression is {p.get('license')})\n")
pathlib.Path(out).write_text("".join(lines))
print(f"licences.py: {len(wanted)} crates, {len(wanted) - len(missing)} with licence files"
      + (f"; without a file (licence expression only): {', '.join(missing)}" if missing else ""), file=sys.stderr)
