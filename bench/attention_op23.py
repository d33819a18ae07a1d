#!/usr/bin/env python
"""Probe: the opset-23 ONNX ``Attention`` op for the attention step's core, against the graphs' form (A of
``bench/attention_forms.py``) and the fusion cross-attention's query-major form (the current fusion graph).

    taskset -c 1 $LIVEGESTURE_PY bench/attention_op23.py --rows 64 --queries 4 --out /tmp/attn23/fusion
    taskset -c 1 target/release/examples/onnx_time /tmp/attn23/fusion_E.onnx 64x4x4x32 64x4x32x32 64x4x32x32 64x1x1x32

Forms (window-relative RoPE, query at slot W - 1), inputs q (rows, queries, h, hd), keys and values (rows, h, W,
hd), bias (rows, 1, 1, W); output (rows, queries, h, hd):
  A  one MatMul by the constant (hd, W*hd) query-rotation matrix, Mul + ReduceSum scores, Mul + ReduceSum values;
  Q  (queries > 1) A laid out query-major, keys broadcast on the leading axis, values by a batched MatMul (the
     fusion graph's cross-attention since branch tractfuse);
  E  the keys rotated elementwise (cos/sin tables, half swap by Gather), then one opset-23 ``Attention`` node
     (4-D q/k/v, additive float mask, scale 1/sqrt(hd)); the file is opset 23.
Each form is checked against A (max abs printed) and timed on onnxruntime (1 thread); the files are written
for tract (`onnx_time`). A backend that cannot load or run a form prints the error instead of a time.
"""
import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import TensorProto, helper, numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "python"))
from livegesture.models.layers import key_rotations, step_query_rotations  # noqa: E402

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("--rows", type=int, default=64)
ap.add_argument("--queries", type=int, default=4)
ap.add_argument("--heads", type=int, default=4)
ap.add_argument("--head-dim", type=int, default=32)
ap.add_argument("--window", type=int, default=32)
ap.add_argument("--runs", type=int, default=400)
ap.add_argument("--out", required=True, help="prefix of the ONNX files written (<out>_<form>.onnx)")
a = ap.parse_args()
rows, n_q, h, hd, W = a.rows, a.queries, a.heads, a.head_dim, a.window
Path(a.out).parent.mkdir(parents=True, exist_ok=True)

qrot = step_query_rotations(W, hd)
cos, S_k, swap = key_rotations(W, hd)   # slot j rotated back by m = W - 1 - j: R_-m k = k cos + swap(k) S_k


class A(torch.nn.Module):
    def forward(self, q, k, v, bias):
        qr = (q @ qrot).reshape(-1, n_q, h, W, hd)
        p = torch.softmax((qr * k[:, None]).sum(-1) + bias, -1)
        return (p[..., None] * v[:, None]).sum(-2)


class Q(torch.nn.Module):
    def forward(self, q, k, v, bias):
        qr = (q.transpose(0, 1) @ qrot).reshape(n_q, -1, h, W, hd)
        p = torch.softmax((qr * k[None]).sum(-1) + bias.reshape(1, -1, 1, W), -1).permute(1, 2, 0, 3)
        return (p @ v).transpose(1, 2)


def attention_op23(path: str):
    """keys rotated back by m = W-1-j (elementwise), then Attention(q, k_rot, v, mask) with q (rows, h, n_q, hd)."""
    init = [numpy_helper.from_array(cos.numpy(), "cos"), numpy_helper.from_array(S_k.numpy(), "sin"),
            numpy_helper.from_array(swap.numpy().astype(np.int64), "swap"),
            numpy_helper.from_array(np.array([1, 1, n_q, 1], np.int64), "mask_shape")]
    nodes = [
        helper.make_node("Gather", ["k", "swap"], ["k_sw"], axis=3),
        helper.make_node("Mul", ["k", "cos"], ["k_c"]),
        helper.make_node("Mul", ["k_sw", "sin"], ["k_s"]),
        helper.make_node("Add", ["k_c", "k_s"], ["k_rot"]),
        helper.make_node("Transpose", ["q"], ["q_h"], perm=[0, 2, 1, 3]),          # (rows, h, n_q, hd)
        # onnxruntime wants the mask's query axis at full size (no broadcast there): Expand it to n_q
        helper.make_node("Expand", ["bias", "mask_shape"], ["mask"]),
        helper.make_node("Attention", ["q_h", "k_rot", "v", "mask"], ["y_h"], scale=1.0 / math.sqrt(hd)),
        helper.make_node("Transpose", ["y_h"], ["y"], perm=[0, 2, 1, 3]),          # (rows, n_q, h, hd)
    ]
    inputs = [helper.make_tensor_value_info("q", TensorProto.FLOAT, [rows, n_q, h, hd]),
              helper.make_tensor_value_info("k", TensorProto.FLOAT, [rows, h, W, hd]),
              helper.make_tensor_value_info("v", TensorProto.FLOAT, [rows, h, W, hd]),
              helper.make_tensor_value_info("bias", TensorProto.FLOAT, [rows, 1, 1, W])]
    out = [helper.make_tensor_value_info("y", TensorProto.FLOAT, [rows, n_q, h, hd])]
    g = helper.make_graph(nodes, "attention_op23", inputs, out, init)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 23)])
    m.ir_version = 10
    onnx.checker.check_model(m)
    onnx.save(m, path)


g = torch.Generator().manual_seed(0)
q = torch.randn(rows, n_q, h, hd, generator=g)
k = torch.randn(rows, h, W, hd, generator=g)
v = torch.randn(rows, h, W, hd, generator=g)
bias = torch.zeros(rows, 1, 1, W)
bias[: rows // 2, ..., : W // 3] = float("-inf")   # half the rows on a cold start (not-yet-filled slots masked)
feed = {"q": q.numpy(), "k": k.numpy(), "v": v.numpy(), "bias": bias.numpy()}
ref = A()(q, k, v, bias).numpy()
so = ort.SessionOptions()
so.intra_op_num_threads = so.inter_op_num_threads = 1
forms = [("A", A())] + ([("Q", Q())] if n_q > 1 else []) + [("E", None)]
for name, mod in forms:
    f = f"{a.out}_{name}.onnx"
    if mod is None:
        attention_op23(f)
    else:
        torch.onnx.export(mod, (q, k, v, bias), f, input_names=list(feed), output_names=["y"], opset_version=17,
                          dynamo=False)
    try:
        sess = ort.InferenceSession(f, so, providers=["CPUExecutionProvider"])
        y = sess.run(None, feed)[0]
    except Exception as e:  # noqa: BLE001 - the probe reports what the backend says
        print(f"{name}: onnxruntime {ort.__version__} cannot run {f}: {str(e).splitlines()[0]}")
        continue
    err = float(np.abs(y - ref).max())
    for _ in range(50):
        sess.run(None, feed)
    ts = []
    for _ in range(a.runs):
        t = time.perf_counter()
        sess.run(None, feed)
        ts.append(time.perf_counter() - t)
    print(f"{name}: rows {rows} queries {n_q} heads {h} hd {hd} W {W}: ort median {np.median(ts) * 1e3:.3f} ms, "
          f"max |form - A| {err:.1e}, {f}")
