#!/usr/bin/env python
# usage: taskset -c 1 python bench/results/ring-2026-11-25/profile_ort.py GRAPH BATCH BUNDLE [BUNDLE ...]
# onnxruntime (Python, 1 thread, subnormals flushed, profiling on): one graph of each bundle, 60 chained runs
# from zero caches (the first 10 not counted; pseudo-random data inputs, caches fed back), run time and
# per-op kernel time per run.
import collections, json, os, sys, tempfile
import numpy as np, onnxruntime as ort
g, B, bundles = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
for b in bundles:
    spec = {x["name"]: x for x in json.load(open(b + "/manifest.json"))["graphs"]}[g]
    so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
    so.add_session_config_entry("session.set_denormal_as_zero", "1")
    so.enable_profiling = True; so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), "prof")
    s = ort.InferenceSession(f"{b}/{spec['file']}", so, providers=["CPUExecutionProvider"])
    rng = np.random.RandomState(0)
    caches = {c["input"]: np.zeros([B] + c["shape"][1:], np.int64 if c["dtype"] == "int64" else np.float32)
              for c in spec["caches"]}
    data = {}
    for i in s.get_inputs():
        if i.name in caches:
            continue
        shape = [B] + [d for d in i.shape[1:]]
        data[i.name] = (rng.randint(0, 256, shape).astype(np.int64) if "int64" in i.type
                        else rng.rand(*shape).astype(np.float32))
    outs = [o.name for o in s.get_outputs()]
    for t in range(60):
        res = dict(zip(outs, s.run(None, {**data, **caches})))
        caches = {c["input"]: res[c["output"]] for c in spec["caches"]}
    f = s.end_profiling(); ev = json.load(open(f)); os.remove(f)
    runs = [e for e in ev if e.get("cat") == "Session" and e["name"] == "model_run"][10:]
    agg = collections.Counter(); t0 = runs[0]["ts"]
    for e in ev:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time") and e["ts"] >= t0:
            agg[e["args"]["op_name"]] += e["dur"] / len(runs)
    tot = np.median([e["dur"] for e in runs])
    print(f"{b} {g} batch {B}: run median {tot/1000:.3f} ms; kernels {sum(agg.values())/1000:.3f} ms; per op (ms): "
          + ", ".join(f"{op} {v/1000:.3f}" for op, v in agg.most_common(9)))
