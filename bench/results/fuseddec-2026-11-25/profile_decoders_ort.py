#!/usr/bin/env python
# usage: taskset -c 1 python bench/results/fuseddec-2026-11-25/profile_decoders_ort.py BUNDLE BATCH
# onnxruntime (Python, 1 thread, subnormals flushed, profiling on): the four canonical decoders vs decoders_fused,
# 60 chained runs each (the first 10 not counted), per-op kernel time per run.
import sys, json, os, tempfile, collections, numpy as np, onnxruntime as ort
b = sys.argv[1]; B = int(sys.argv[2])
m = json.load(open(b + "/manifest.json")); spec = {g["name"]: g for g in m["graphs"]}
regs = ["upper", "hands", "lower", "face"]
res = {}
for names in ([f"decoder_{r}" for r in regs], ["decoders_fused"]):
    agg = collections.Counter(); tot = 0.0
    for n in names:
        so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
        so.add_session_config_entry("session.set_denormal_as_zero", "1")
        so.enable_profiling = True; so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), f"prof_{n}")
        s = ort.InferenceSession(f"{b}/{spec[n]['file']}", so, providers=["CPUExecutionProvider"])
        caches = {c["input"]: np.zeros([B] + c["shape"][1:], np.float32) for c in spec[n]["caches"]}
        rng = np.random.RandomState(0)
        for t in range(60):
            tok = rng.randint(0, 256, [B] + spec[n]["inputs"][0]["shape"][1:]).astype(np.int64)
            out = s.run(None, {"token": tok, **caches})
            caches = {c["input"]: o for c, o in zip(spec[n]["caches"], out[1:])}
        f = s.end_profiling()
        ev = json.load(open(f)); os.remove(f)
        runs = [e for e in ev if e.get("cat") == "Session" and e["name"] == "model_run"][10:]
        tot += sum(e["dur"] for e in runs) / len(runs)
        t0 = runs[0]["ts"]
        for e in ev:
            if e.get("cat") == "Node" and e["name"].endswith("_kernel_time") and e["ts"] >= t0:
                agg[e["args"]["op_name"]] += e["dur"] / len(runs)
    res[names[0] if len(names) == 1 else "canonical x4"] = (tot, agg)
for k, (tot, agg) in res.items():
    print(f"{k}: run {tot/1000:.3f} ms; per op (ms): " + ", ".join(f"{op} {v/1000:.3f}" for op, v in agg.most_common(8)))
