import json, sys, collections, numpy as np, onnxruntime as ort, time, os
bundle, graph, batch = sys.argv[1], sys.argv[2], int(sys.argv[3])
runs = int(sys.argv[4]) if len(sys.argv) > 4 else 30
m = json.load(open(f"{bundle}/manifest.json"))
spec = m["graphs"][graph] if isinstance(m["graphs"], dict) else [g for g in m["graphs"] if g["name"] == graph][0]
so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
so.enable_profiling = True; so.profile_file_prefix = f"/tmp/speed4/prof_{graph}_{batch}"
s = ort.InferenceSession(f"{bundle}/{spec['file']}", so, providers=["CPUExecutionProvider"])
rng = np.random.default_rng(0)
feeds = {}
for i in s.get_inputs():
    shape = [batch if isinstance(d, str) else d for d in i.shape]
    if "int64" in i.type:
        if i.name == "step": feeds[i.name] = np.full(shape, 100, np.int64)
        else: feeds[i.name] = rng.integers(0, 8, shape).astype(np.int64)
    else:
        a = rng.standard_normal(shape).astype(np.float32)
        if i.name == "cond": a = (np.arange(batch) % 2 == 0).astype(np.float32)
        feeds[i.name] = a
for _ in range(5): s.run(None, feeds)
t0 = time.perf_counter()
for _ in range(runs): s.run(None, feeds)
wall = (time.perf_counter() - t0) / runs * 1e3
p = s.end_profiling()
ev = json.load(open(p))
by = collections.defaultdict(float); cnt = collections.Counter(); tot = 0
for e in ev:
    if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
        op = e["args"]["op_name"]; by[op] += e["dur"]; cnt[op] += 1; tot += e["dur"]
os.remove(p)
n = runs + 5
print(f"{graph} batch {batch}: wall {wall:.3f} ms/run, kernels {tot/n/1e3:.3f} ms/run, nodes {sum(cnt.values())//n}")
for op, d in sorted(by.items(), key=lambda x: -x[1])[:14]:
    print(f"  {op:20s} {d/n/1e3:8.3f} ms  {100*d/tot:5.1f}%  x{cnt[op]//n}")
