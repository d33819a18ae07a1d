#!/usr/bin/env python
"""What onnxruntime's CPU provider does with float16 on this machine (issue 15 deliverable 3, BENCHMARKS.md
"Reduced precision: f16 bundles"):

1. a float16 MatMul/Gemm/Add/Softmax/LayerNormalization graph: the node list after onnxruntime's graph
   optimisations (a float16 op without a CPU kernel is wrapped in Cast -> float32 op -> Cast by onnxruntime's
   InsertCastTransformer, i.e. computed in float32);
2. each graph of a float16 bundle (export/quantize.py --precision f16): the Cast nodes before and after
   onnxruntime's optimisations (the Cast of a float16 constant is folded at load: float32 weights in memory).

    python bench/f16_ort_kernels.py [--bundle /tmp/default-f16]
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto as T
from onnx import helper as h
from onnx import numpy_helper as nh


def optimised_ops(model: onnx.ModelProto | Path, td: str, tag: str) -> list[str]:
    o = ort.SessionOptions()
    o.intra_op_num_threads = 1
    o.log_severity_level = 3
    o.optimized_model_filepath = str(Path(td) / f"{tag}.onnx")
    src = model.SerializeToString() if isinstance(model, onnx.ModelProto) else str(model)
    ort.InferenceSession(src, o, providers=["CPUExecutionProvider"])
    return [n.op_type for n in onnx.load(o.optimized_model_filepath).graph.node]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", help="a float16 bundle: count its Cast nodes before and after the optimisations")
    a = ap.parse_args()
    out = {"onnxruntime": ort.__version__, "float16_ops": {}, "bundle": {}}
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as td:
        for op in ("MatMul", "Gemm", "Add", "Softmax", "LayerNormalization"):
            inits = []
            if op in ("MatMul", "Gemm"):
                ins, inits = ["x", "W"], [nh.from_array(rng.standard_normal((512, 512)).astype(np.float16), "W")]
            elif op == "LayerNormalization":
                ins, inits = ["x", "g"], [nh.from_array(np.ones(512, np.float16), "g")]
            else:
                ins = ["x", "x"] if op == "Add" else ["x"]
            g = h.make_graph([h.make_node(op, ins, ["y"])], "g", [h.make_tensor_value_info("x", T.FLOAT16, [2, 512])],
                             [h.make_tensor_value_info("y", T.FLOAT16, None)], inits)
            m = h.make_model(g, opset_imports=[h.make_opsetid("", 17)])
            m.ir_version = 8
            out["float16_ops"][op] = optimised_ops(m, td, op)
        if a.bundle:
            man = json.loads((Path(a.bundle) / "manifest.json").read_text())
            for spec in man["graphs"]:
                p = Path(a.bundle) / spec["file"]
                before = [n.op_type for n in onnx.load(str(p)).graph.node].count("Cast")
                after = optimised_ops(p, td, spec["name"]).count("Cast")
                out["bundle"][spec["name"]] = {"cast_nodes": before, "cast_nodes_after_ort_optimisation": after}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
