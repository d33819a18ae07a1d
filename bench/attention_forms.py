#!/usr/bin/env python
"""Micro-benchmark of the attention step's core (scores, softmax, weighted values) in four RoPE forms, on
onnxruntime (timed here) and as ONNX files for tract (time them with the `onnx_time` example).

    taskset -c 1 $LIVEGESTURE_PY bench/attention_forms.py --rows 64 --queries 1 --out /tmp/attn/expert
    taskset -c 1 target/release/examples/onnx_time /tmp/attn/expert_A.onnx 64x1x4x32 64x4x32x32 64x4x32x32 64x1x1x32

Forms (window-relative RoPE, query at slot W - 1; all equal to A within float rounding, printed):
  A  the graphs' form: one MatMul by the constant (hd, W*hd) query-rotation matrix, Mul + ReduceSum scores;
  B  the query rotated elementwise by (W, hd) cos/sin tables (half swap by Gather);
  C  the cached keys rotated back elementwise, Mul + ReduceSum scores;
  D  as C with per-head MatMul scores.
Inputs: q (rows, queries, h, hd), keys and values (rows, h, W, hd), bias (rows, 1, 1, W).
"""
import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "python"))
from livegesture.models.layers import rope_tables, step_query_rotations  # noqa: E402

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("--rows", type=int, default=64, help="streams x guidance branches (x regions)")
ap.add_argument("--queries", type=int, default=1, help="queries per row (the fusion's cross-attention: 4)")
ap.add_argument("--heads", type=int, default=4)
ap.add_argument("--head-dim", type=int, default=32)
ap.add_argument("--window", type=int, default=32)
ap.add_argument("--runs", type=int, default=400)
ap.add_argument("--out", required=True, help="prefix of the ONNX files written (<out>_<form>.onnx)")
a = ap.parse_args()
rows, n_q, h, hd, W = a.rows, a.queries, a.heads, a.head_dim, a.window
Path(a.out).parent.mkdir(parents=True, exist_ok=True)

qrot = step_query_rotations(W, hd)
cos, sin = (t.flip(0) / math.sqrt(hd) for t in rope_tables(W, hd))   # slot j: m = W - 1 - j positions back
sign = torch.cat([-torch.ones(hd // 2), torch.ones(hd // 2)])
C = cos
S_q = sin * sign    # R_m q = q cos + swap(q) [-sin, sin]
S_k = -S_q          # R_-m k = k cos + swap(k) [sin, -sin]
swap = torch.cat([torch.arange(hd // 2, hd), torch.arange(hd // 2)])


def attend(scores, bias, v):
    p = torch.softmax(scores + bias, -1)
    return (p[..., None] * v[:, None]).sum(-2)


class A(torch.nn.Module):
    def forward(self, q, k, v, bias):
        qr = (q @ qrot).reshape(-1, n_q, h, W, hd)
        return attend((qr * k[:, None]).sum(-1), bias, v)


class B(torch.nn.Module):
    def forward(self, q, k, v, bias):
        qe = q[..., None, :]
        qr = qe * C + qe[..., swap] * S_q
        return attend((qr * k[:, None]).sum(-1), bias, v)


class Ck(torch.nn.Module):
    def forward(self, q, k, v, bias):
        kr = k * C + k[..., swap] * S_k
        return attend((q[..., None, :] * kr[:, None]).sum(-1), bias, v)


class D(torch.nn.Module):
    def forward(self, q, k, v, bias):
        kr = k * C + k[..., swap] * S_k
        return attend((q.transpose(1, 2) @ kr.transpose(-1, -2)).transpose(1, 2), bias, v)


g = torch.Generator().manual_seed(0)
q = torch.randn(rows, n_q, h, hd, generator=g)
k = torch.randn(rows, h, W, hd, generator=g)
v = torch.randn(rows, h, W, hd, generator=g)
bias = torch.zeros(rows, 1, 1, W)
feed = {"q": q.numpy(), "k": k.numpy(), "v": v.numpy(), "bias": bias.numpy()}
ref = A()(q, k, v, bias)
so = ort.SessionOptions()
so.intra_op_num_threads = so.inter_op_num_threads = 1
for name, mod in [("A", A()), ("B", B()), ("C", Ck()), ("D", D())]:
    err = (mod(q, k, v, bias) - ref).abs().max().item()
    f = f"{a.out}_{name}.onnx"
    torch.onnx.export(mod, (q, k, v, bias), f, input_names=list(feed), output_names=["y"], opset_version=17,
                      dynamo=False)
    sess = ort.InferenceSession(f, so, providers=["CPUExecutionProvider"])
    for _ in range(50):
        sess.run(None, feed)
    ts = []
    for _ in range(a.runs):
        t = time.perf_counter()
        sess.run(None, feed)
        ts.append(time.perf_counter() - t)
    print(f"{name}: rows {rows} queries {n_q} heads {h} hd {hd} W {W}: ort median {np.median(ts) * 1e3:.3f} ms, "
          f"max |form - A| {err:.1e}, {f}")
