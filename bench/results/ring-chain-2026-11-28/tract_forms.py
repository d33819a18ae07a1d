"""tract (Python bindings 0.23.9, same as the runtime): thread CPU per token of each form's graphs, interleaved."""
import sys, time, numpy as np
sys.path.insert(0, "/tmp/speed4"); sys.argv += ["x", "y", "2", "1"]
src = open("/tmp/speed4/tract_ab.py").read().split("base_p, ring_p")[0]
exec(src)
B0 = "/work/wt/streams/models/default/"
sets = {"experts canonical (4 graphs)": [f"expert_{r}" for r in ("upper", "hands", "lower", "face")],
        "experts_fused": ["experts_fused"],
        "decoders canonical (4 graphs)": [f"decoder_{r}" for r in ("upper", "hands", "lower", "face")],
        "decoders_fused": ["decoders_fused"],
        "fusion": ["fusion"], "fusion_attention": ["fusion_attention"]}
rng = np.random.default_rng(0)
for rows in (2, 96):
    loaded = {}
    for k, gs in sets.items():
        b = rows if not k.startswith("decoders") else rows // 2
        loaded[k] = []
        for g in gs:
            r, sh = load(B0 + g + ".onnx", b); loaded[k].append((r.spawn_state(), feeds(sh, rng)))
    res = {k: [] for k in sets}
    n = 20 if rows == 2 else 2
    for rnd in range(7):
        for k, items in loaded.items():
            c0 = time.thread_time()
            for _ in range(n):
                for st, f in items: [o.to_numpy() for o in st.run(f)]
            res[k].append((time.thread_time() - c0) / n * 1e3)
    print(f"rows {rows}: " + "; ".join(f"{k} {np.median(v):.2f} ms" for k, v in res.items()), flush=True)
