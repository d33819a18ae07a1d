#!/usr/bin/env python
"""Copy a LiveGesture bundle and break ONE graph in the copy, for the parity suite's negative tests.

    break_bundle.py SRC DST --graph expert_hands --perturb-weight [--delta 0.01] [--relative]
    break_bundle.py SRC DST --graph expert_hands --freeze-cache layer0.xattn.k
    break_bundle.py SRC DST --graph all --magnify 40 --ulps 3

--perturb-weight   adds --delta to one element (the first) of the weight initializer of the graph's first
                   MatMul/Gemm whose weight is an initializer (float32, or float16 behind a Cast as
                   export/quantize.py --precision f16 writes it). With --relative the element is multiplied by
                   1 + delta instead (docs/targets.md's must-fail case: --delta 0.02 --relative).
--freeze-cache N   makes the graph return its input cache `cache.N` unchanged as `new_cache.N` (the node
                   that computed `new_cache.N` keeps computing it under another name for its other
                   consumers; an Identity node now produces the graph output from the input).

--magnify M        not a break: scales every data output of the graph(s) (``--graph`` a name, a comma-separated
                   list, or ``all``) so that its largest reference value is about M: a Mul by a float32
                   constant appended to the ONNX graph (caches untouched, so chaining is unchanged) and the
                   reference vectors' outputs multiplied by the same constant in float32, then moved --ulps
                   float32 spacings away from zero (``np.nextafter``). A correct runtime then differs from the
                   reference by a few float32 ulps at values near M: more than an absolute 1e-5 for M = 40,
                   far below docs/parity.md's bound scaled by the magnitude. For a bundle's graph check only
                   (its rollout reference is not rewritten).

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


def perturb_weight(model: onnx.ModelProto, delta: float, relative: bool = False) -> dict:
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
            if relative and before == 0.0:
                continue
            w.flat[0] += w.dtype.type(before * delta if relative else delta)
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


def magnify_graph(model: onnx.ModelProto, outputs: list[str], factors: dict[str, float]) -> None:
    """Appends ``output = output.unscaled * factor`` for each data output (the producer renamed)."""
    g = model.graph
    for name in outputs:
        raw = f"{name}.unscaled"
        for node in g.node:
            for i, o in enumerate(node.output):
                if o == name:
                    node.output[i] = raw
            for i, x in enumerate(node.input):
                if x == name:
                    node.input[i] = raw
        const = f"{name}.magnify"
        g.initializer.append(numpy_helper.from_array(np.array(factors[name], dtype=np.float32), const))
        g.node.append(helper.make_node("Mul", [raw, const], [name], name=f"break_bundle.magnify.{name}"))


def magnify_reference(path: Path, outputs: list[str], target: float, ulps: int) -> dict[str, float]:
    """Rewrites the reference npz: every ``*.output.<o>`` array of the data outputs multiplied by o's factor (so
    the largest |value| of o is ``target``) in float32, then ``ulps`` float32 spacings away from zero. Returns
    the factors."""
    ref = dict(np.load(path))
    factors = {}
    for o in outputs:
        keys = [k for k in ref if k.endswith(f".output.{o}")]
        peak = max(float(np.abs(ref[k]).max()) for k in keys) if keys else 0.0
        factors[o] = float(np.float32(target / peak)) if peak > 0 else 1.0
        for k in keys:
            v = (ref[k].astype(np.float32) * np.float32(factors[o])).astype(np.float32)
            away = np.where(v >= 0, np.float32(np.inf), np.float32(-np.inf)).astype(np.float32)
            for _ in range(ulps):
                v = np.nextafter(v, away).astype(np.float32)
            ref[k] = v
    np.savez_compressed(path, **ref)
    return factors


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
    how.add_argument("--magnify", type=float, metavar="M")
    ap.add_argument("--delta", type=float, default=0.01)
    ap.add_argument("--relative", action="store_true", help="with --perturb-weight: multiply by 1 + delta")
    ap.add_argument("--ulps", type=int, default=3, help="with --magnify: float32 spacings added to the reference")
    a = ap.parse_args(argv)
    src, dst = Path(a.src), Path(a.dst)
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    for p in dst.rglob("*"):   # the source may be read-only (models/default)
        p.chmod(p.stat().st_mode | 0o200)
    manifest = json.loads((dst / "manifest.json").read_text())
    graphs = {g["name"]: g for g in manifest["graphs"]}
    if a.magnify is not None:
        names = list(graphs) if a.graph == "all" else a.graph.split(",")
        changed = []
        for name in names:
            if name not in graphs:
                raise SystemExit(f"break_bundle: no graph '{name}' (graphs: {sorted(graphs)})")
            spec = graphs[name]
            outs = [o["name"] for o in spec["outputs"] if o["dtype"] == "float32"]
            rel = spec.get("reference") or f"reference/{name}.npz"
            factors = magnify_reference(dst / rel, outs, a.magnify, a.ulps)
            path = dst / spec["file"]
            model = onnx.load(str(path))
            magnify_graph(model, outs, factors)
            onnx.checker.check_model(model)
            onnx.save(model, str(path))
            for f in (spec["file"], rel):
                manifest["files"][f] = {"sha256": sha256(dst / f), "bytes": (dst / f).stat().st_size}
            changed.append({"graph": name, "factors": factors})
        (dst / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
        print(json.dumps({"change": "magnify", "target": a.magnify, "ulps": a.ulps, "graphs": changed}))
        return 0
    if a.graph not in graphs:
        raise SystemExit(f"break_bundle: no graph '{a.graph}' (graphs: {sorted(graphs)})")
    file = graphs[a.graph]["file"]
    path = dst / file
    model = onnx.load(str(path))
    info = perturb_weight(model, a.delta, a.relative) if a.perturb_weight else freeze_cache(model, a.freeze_cache)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    manifest["files"][file] = {"sha256": sha256(path), "bytes": path.stat().st_size}
    (dst / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(json.dumps({"graph": a.graph, "file": file, **info}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
