#!/usr/bin/env python
"""Copy a bundle and change ONE thing the parity checks compare against, for the must-fail tests.

    edit_reference.py SRC DST --array reference/logmel.npy --index 1000 --add 1e-3
    edit_reference.py SRC DST --array reference/rollout.npz:poses --index 4000 --set nan
    edit_reference.py SRC DST --array reference/fusion.npz:step3.output.logits --index 5 --set nan
    edit_reference.py SRC DST --drop-check fusion.torch_step_vs_offline_max_abs

--array FILE[:KEY]  a .npy file, or one array of a .npz file, of the bundle; --index is the flat index of the
                    value changed (--add D adds D to it; --set V sets it, V a float or nan/inf)
--drop-check G.K    deletes ``checks[G][K]`` from the manifest (a figure the exporter records)

The manifest's sha256 and size of the changed file are rewritten so the copy loads. Prints one JSON line
describing the change. Needs ``numpy`` (the project's venv, $LIVEGESTURE_PY).
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--array")
    ap.add_argument("--index", type=int, default=0)
    how = ap.add_mutually_exclusive_group()
    how.add_argument("--add", type=float)
    how.add_argument("--set", type=float)
    ap.add_argument("--drop-check")
    a = ap.parse_args(argv)
    src, dst = Path(a.src), Path(a.dst)
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    for p in dst.rglob("*"):   # the source may be read-only (models/default)
        p.chmod(p.stat().st_mode | 0o200)
    manifest = json.loads((dst / "manifest.json").read_text())
    info: dict = {}
    if a.array:
        if a.add is None and a.set is None:
            raise SystemExit("edit_reference: --array needs --add or --set")
        rel, _, key = a.array.partition(":")
        path = dst / rel
        if key:
            arrays = dict(np.load(path))
            if key not in arrays:
                raise SystemExit(f"edit_reference: {rel} has no array '{key}' (has {sorted(arrays)[:8]}...)")
            arr = arrays[key]
        else:
            arr = np.load(path)
        arr = np.array(arr)
        before = float(arr.flat[a.index])
        arr.flat[a.index] = (before + a.add) if a.add is not None else a.set
        if key:
            arrays[key] = arr
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
                for k, v in arrays.items():
                    b = io.BytesIO()
                    np.save(b, v, allow_pickle=False)
                    z.writestr(k + ".npy", b.getvalue())
            path.write_bytes(buf.getvalue())
        else:
            np.save(path, arr, allow_pickle=False)
        if rel in manifest.get("files", {}):
            manifest["files"][rel] = {"sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                                      "bytes": path.stat().st_size}
        after = float(arr.flat[a.index])
        # JSON has no NaN or Inf: non-finite values are written as text
        info.update(array=a.array, index=a.index, before=before if np.isfinite(before) else str(before),
                    after=after if np.isfinite(after) else str(after))
    if a.drop_check:
        g, _, k = a.drop_check.partition(".")
        if k not in manifest.get("checks", {}).get(g, {}):
            raise SystemExit(f"edit_reference: the manifest has no checks.{g}.{k}")
        del manifest["checks"][g][k]
        info.update(dropped=f"checks.{g}.{k}")
    (dst / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(json.dumps(info, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
