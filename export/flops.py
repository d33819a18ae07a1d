#!/usr/bin/env python
"""Count FLOPs and weight bytes per token step of every graph in a bundle (batch 1), for roofline figures.

    python export/flops.py --bundle models/default [--json out.json]

FLOPs: 2 x multiply-accumulates of MatMul, Gemm and Conv nodes (the rest is elementwise and negligible
for these models, and is reported separately as an element count). MatMuls by a ``Constant`` node (not a
weight initializer) are the attention step's query-rotation tables (``qrot``: one query becomes W rotated
queries, W x the work of applying RoPE elementwise): they are counted apart as ``rope_expansion`` and left
out of ``model_flops``, the model's own arithmetic that roofline fractions are quoted against. Shapes come from ONNX shape inference
with the batch axis set to 1. Weight bytes: the size of all initializers (what one step must read).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper, shape_inference


def _fix_batch(model: onnx.ModelProto, batch: int):
    for v in list(model.graph.input) + list(model.graph.output):
        d = v.type.tensor_type.shape.dim
        if d and d[0].dim_param:
            d[0].ClearField("dim_param")
            d[0].dim_value = batch


def count(path: str | Path, batch: int = 1) -> dict:
    m = onnx.load(str(path))
    _fix_batch(m, batch)
    m = shape_inference.infer_shapes(m, data_prop=True)
    shapes = {}
    for v in list(m.graph.value_info) + list(m.graph.input) + list(m.graph.output):
        dims = [d.dim_value if d.HasField("dim_value") else None for d in v.type.tensor_type.shape.dim]
        shapes[v.name] = dims
    inits = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    for i in inits:
        shapes[i] = list(inits[i].shape)
    constants = set()
    for n in m.graph.node:
        if n.op_type == "Constant":
            constants.add(n.output[0])
            for a in n.attribute:
                if a.name == "value":
                    shapes[n.output[0]] = list(numpy_helper.to_array(a.t).shape)
    flops, rope_expansion, unknown, elementwise = 0, 0, [], 0
    for n in m.graph.node:
        try:
            if n.op_type == "MatMul":
                a, b = shapes[n.input[0]], shapes[n.input[1]]
                out = shapes.get(n.output[0])
                k = a[-1]
                flops += 2 * int(np.prod(out)) * k
                if n.input[1] in constants:
                    rope_expansion += 2 * int(np.prod(out)) * k
            elif n.op_type == "Gemm":
                a, out = shapes[n.input[0]], shapes[n.output[0]]
                trans_a = any(x.name == "transA" and x.i for x in n.attribute)
                k = a[0] if trans_a else a[-1]
                flops += 2 * int(np.prod(out)) * k
            elif n.op_type == "Conv":
                w, out = shapes[n.input[1]], shapes[n.output[0]]
                groups = next((x.i for x in n.attribute if x.name == "group"), 1)
                flops += 2 * int(np.prod(out)) * int(np.prod(w[1:]))
                del groups
            elif n.output and shapes.get(n.output[0]) and None not in shapes[n.output[0]]:
                elementwise += int(np.prod(shapes[n.output[0]]))
        except (KeyError, TypeError):
            unknown.append(n.name or n.op_type)
    weight_bytes = int(sum(a.nbytes for a in inits.values()))
    return {"flops": int(flops), "rope_expansion_flops": int(rope_expansion),
            "model_flops": int(flops - rope_expansion), "weight_bytes": weight_bytes,
            "elementwise_elements": elementwise, "uncounted_nodes": unknown}


def bundle_counts(bundle: str | Path) -> dict:
    bundle = Path(bundle)
    man = json.loads((bundle / "manifest.json").read_text())
    out = {}
    for g in man["graphs"]:
        b = 2 if g["name"].startswith(("expert", "fusion")) else 1      # both guidance branches (experts_fused too)
        c1 = count(bundle / g["file"], 1)
        cb = count(bundle / g["file"], b) if b != 1 else c1
        out[g["name"]] = {"flops_per_stream": c1["flops"], "flops_per_step_guided": cb["flops"],
                          "model_flops_per_step_guided": cb["model_flops"],
                          "rope_expansion_flops_per_step_guided": cb["rope_expansion_flops"],
                          "weight_bytes": c1["weight_bytes"], "uncounted_nodes": c1["uncounted_nodes"]}
    keys = ["flops_per_step_guided", "model_flops_per_step_guided", "rope_expansion_flops_per_step_guided",
            "weight_bytes"]
    # one form's graphs per step: the canonical ones (a fused form's graphs compute the same, docs/bundle.md#forms-and-precision)
    canonical = {g["name"] for g in man["graphs"] if g.get("form", "canonical") == "canonical"}
    out["_total"] = {k: sum(v[k] for n, v in out.items() if n in canonical) for k in keys}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--json", help="write the counts here")
    args = ap.parse_args(argv)
    res = bundle_counts(args.bundle)
    for k, v in res.items():
        print(f"{k:<16} {v['model_flops_per_step_guided'] / 1e6:10.3f} MFLOP/step model "
              f"(+ {v['rope_expansion_flops_per_step_guided'] / 1e6:.3f} query-rotation; guided)   "
              f"{v['weight_bytes'] / 1e6:9.3f} MB weights")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
