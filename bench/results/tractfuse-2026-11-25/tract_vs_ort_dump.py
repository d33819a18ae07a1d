"""Probe helper: compare the output that `onnx_time` wrote (ONNX_TIME_DUMP=FILE) with onnxruntime's on the same
deterministic inputs (element i: ((i * 7919) % 1000) / 1000 - 0.5).

    ONNX_TIME_DUMP=/tmp/out.bin target/release/examples/onnx_time F.onnx SHAPE...
    $LIVEGESTURE_PY bench/results/tractfuse-2026-11-25/tract_vs_ort_dump.py F.onnx /tmp/out.bin SHAPE...
"""
import sys, numpy as np, onnxruntime as ort
f, dump = sys.argv[1], sys.argv[2]
shapes = [tuple(int(x) for x in s.split("x")) for s in sys.argv[3:]]
feeds = {}
sess = ort.InferenceSession(f, providers=["CPUExecutionProvider"])
for i, s in zip(sess.get_inputs(), shapes):
    n = int(np.prod(s)); feeds[i.name] = (((np.arange(n) * 7919) % 1000) / 1000.0 - 0.5).astype(np.float32).reshape(s)
y = sess.run(None, feeds)[0]
t = np.fromfile(dump, dtype="<f4").reshape(y.shape)
print(f"{f}: tract vs ort max abs {np.abs(y - t).max():.2e} (|y| max {np.abs(y).max():.2f})")
