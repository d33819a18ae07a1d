import sys, time, numpy as np, onnxruntime as ort
def sess(path):
    so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
def feeds_for(s, B, rng):
    f = {}
    for i in s.get_inputs():
        if i.name == "phase": f[i.name] = np.array(3, np.int64); continue
        shape = [B if isinstance(d, str) else d for d in i.shape]
        if "int64" in i.type: f[i.name] = (np.full(shape, 100, np.int64) if "step" in i.name or i.name == "step" else rng.integers(0, 8, shape).astype(np.int64))
        else: f[i.name] = rng.standard_normal(shape).astype(np.float32)
    return f
def binding(s, f, B):
    b = s.io_binding()
    for k, v in f.items(): b.bind_ortvalue_input(k, ort.OrtValue.ortvalue_from_numpy(v))
    outs = []
    for o in s.get_outputs():
        shape = [B if isinstance(d, str) else d for d in o.shape]
        a = np.empty(shape, np.int64 if "int64" in o.type else np.float32); outs.append(a)
        b.bind_ortvalue_output(o.name, ort.OrtValue.ortvalue_from_numpy(a))
    return b, outs
base, ring = sess(sys.argv[1]), sess(sys.argv[2])
rng = np.random.default_rng(0)
for B in [int(b) for b in sys.argv[3].split(",")]:
    fb, fr = feeds_for(base, B, rng), feeds_for(ring, B, rng)
    bb, _ = binding(base, fb, B); br, outr = binding(ring, fr, B)
    caches = [k for k in fr if (k[0] == "c" and k[1:].isdigit()) or (k.startswith("cache.") and k != "cache.step")]
    n = 40 if B <= 4 else 5
    tb, tr, tw = [], [], []
    for rnd in range(int(sys.argv[4]) if len(sys.argv) > 4 else 7):
        t0 = time.thread_time()
        for _ in range(n): base.run_with_iobinding(bb)
        tb.append((time.thread_time() - t0) / n * 1e3)
        t0 = time.thread_time()
        for _ in range(n): ring.run_with_iobinding(br)
        tr.append((time.thread_time() - t0) / n * 1e3)
        t0 = time.thread_time()
        for _ in range(n):
            for ci, k in enumerate(caches):
                fr[k][..., 3, :] = outr[-len(caches) + ci][..., 0, :]
        tw.append((time.thread_time() - t0) / n * 1e3)
    r = [b_ / a for a, b_ in zip(tb, tr)]
    print(f"batch {B}: base {np.median(tb):.3f} ms, ring {np.median(tr):.3f} ms (+ write {np.median(tw):.3f}), ring/base per-round median {np.median(r):.3f} [{min(r):.2f}-{max(r):.2f}]", flush=True)
