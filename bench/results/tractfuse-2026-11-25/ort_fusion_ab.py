"""Probe helper: two versions of one step graph (A B [RUNS]) on onnxruntime, 1 thread, random inputs, batch 2 and
64: max abs difference of their outputs and interleaved median run times.

    taskset -c 1 $LIVEGESTURE_PY bench/results/tractfuse-2026-11-25/ort_fusion_ab.py OLD/fusion.onnx NEW/fusion.onnx 200
"""
import sys, time, numpy as np, onnxruntime as ort
a, b = sys.argv[1], sys.argv[2]
so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
sa = ort.InferenceSession(a, so, providers=["CPUExecutionProvider"]); sb = ort.InferenceSession(b, so, providers=["CPUExecutionProvider"])
def feeds(sess, B, rng):
    f = {}
    for i in sess.get_inputs():
        shp = [B if not isinstance(d, int) else d for d in i.shape]
        if "int64" in i.type: f[i.name] = rng.integers(0, 100, size=shp).astype(np.int64)
        else: f[i.name] = rng.standard_normal(shp).astype(np.float32)
    return f
for B in (2, 64):
    f = feeds(sa, B, np.random.default_rng(0))
    oa = sa.run(None, f); ob = sb.run(None, f)
    err = max(float(np.abs(x - y).max()) for x, y in zip(oa, ob))
    ts = {0: [], 1: []}
    for r in range(int(sys.argv[3]) if len(sys.argv) > 3 else 200):
        for k, s in ((0, sa), (1, sb)) if r % 2 == 0 else ((1, sb), (0, sa)):
            t = time.perf_counter(); s.run(None, f); ts[k].append((time.perf_counter() - t) * 1e3)
    print(f"B={B}: max abs old vs new {err:.2e}; ort median old {np.median(ts[0]):.3f} ms new {np.median(ts[1]):.3f} ms")
