#!/usr/bin/env python
"""Copy a LiveGesture bundle and break ONE graph in the copy, for the parity suite's negative tests.

    break_bundle.py SRC DST --graph expert_hands --perturb-weight [--delta 0.01]
    break_bundle.py SRC DST --graph expert_hands --freeze-cache layer0.xattn.k

--perturb-weight   adds --delta to one element (the first) of the weight initializer of the graph's first
                   MatMul/Gemm whose weight is an initializer (float32, or float16 behind a Cast as
                   export/quantize.py --precision f16 writes it).
--freeze-cache N   makes the graph return its input cache `cache.N` unchanged as `new_cache.N` (the node
                   that computed `new_cache.N` keeps computing it under another name for its other
                   consumers; an Identity node now produces the graph output from the input).

The manifest's sha256 and size of the changed file are rewritten so the copy loads. Prints one JSON line
describing the change. Needs the `onnx` and `numpy` packages (the project's venv, $LIVEGESTURE_PY).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper


def perturb_weight(model: onnx.ModelProto, delta: float) -> dict:
    inits = {t.name: t for t in model.graph.initializer}
    # a float16 bundle (export/quantize.py --precision f16) stores the weight as a float16 initializer + Cast
    cast_from = {n.output[0]: n.input[0] for n in model.graph.node if n.op_type == "Cast" and n.input[0] in inits}
    for node in model.graph.node:
        if node.op_type in ("MatMul", "Gemm") and len(node.input) > 1 and \
                cast_from.get(node.input[1], node.input[1]) in inits:
            t = inits[cast_from.get(node.input[1], node.input[1])]
            w = numpy_helper.to_array(t).copy()
            if w.dtype not in (np.float32, np.float16) or w.size == 0:
                continue
            before = float(w.flat[0])
            w.flat[0] += w.dtype.type(delta)
            t.CopyFrom(numpy_helper.from_array(w, t.name))
            return {"change": "perturb-weight", "node": node.name, "op": node.op_type, "initializer": t.name,
                    "shape": list(w.shape), "index": 0, "before": before, "after": float(w.flat[0])}
    raise SystemExit("break_bundle: no MatMul/Gemm with a float32 or float16 initializer weight in this graph")


def freeze_cache(model: onnx.ModelProto, name: str) -> dict:
    g = model.graph
    cin, cout = f"cache.{name}", f"new_cache.{name}"
    if cin not in [i.name for i in g.input] or cout not in [o.name for o in g.output]:
        raise SystemExit(f"break_bundle: the graph has no cache '{name}' ({cin} -> {cout})")
    renamed = f"{cout}.computed"
    for node in g.node:   # keep the computed value for its other consumers under another name
        for i, o in enumerate(node.output):
            if o == cout:
                node.output[i] = renamed
        for i, x in enumerate(node.input):
            if x == cout:
                node.input[i] = renamed
    g.node.append(helper.make_node("Identity", [cin], [cout], name="break_bundle.freeze_cache"))
    return {"change": "freeze-cache", "cache": name, "output": cout, "now_returns": cin}


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--graph", required=True, help="graph name, e.g. expert_hands")
    how = ap.add_mutually_exclusive_group(required=True)
    how.add_argument("--perturb-weight", action="store_true")
    how.add_argument("--freeze-cache", metavar="NAME")
    ap.add_argument("--delta", type=float, default=0.01)
    a = ap.parse_args(argv)
    src, dst = Path(a.src), Path(a.dst)
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    for p in dst.rglob("*"):   # the source may be read-only (models/default)
        p.chmod(p.stat().st_mode | 0o200)
    manifest = json.loads((dst / "manifest.json").read_text())
    graphs = {g["name"]: g for g in manifest["graphs"]}
    if a.graph not in graphs:
        raise SystemExit(f"break_bundle: no graph '{a.graph}' (graphs: {sorted(graphs)})")
    file = graphs[a.graph]["file"]
    path = dst / file
    model = onnx.load(str(path))
    info = perturb_weight(model, a.delta) if a.perturb_weight else freeze_cache(model, a.freeze_cache)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    manifest["files"][file] = {"sha256": sha256(path), "bytes": path.stat().st_size}
    (dst / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(json.dumps({"graph": a.graph, "file": file, **info}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
