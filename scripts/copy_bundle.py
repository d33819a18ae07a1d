#!/usr/bin/env python3
"""Copies a bundle's manifest.json and every file it lists (nothing else) into a folder:
    copy_bundle.py SRC DST
Used by scripts/build_web_static.sh to put a bundle beside the static page."""
import json
import shutil
import sys
from pathlib import Path

src, dst = Path(sys.argv[1]), Path(sys.argv[2])
manifest = json.loads((src / "manifest.json").read_text())
dst.mkdir(parents=True, exist_ok=True)
shutil.copy2(src / "manifest.json", dst / "manifest.json")
for rel in manifest["files"]:
    (dst / rel).parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src / rel, dst / rel)
print(f"{src} -> {dst}: manifest.json + {len(manifest['files'])} files")
