import sys, time, numpy as np, onnx
sys.path.insert(0, "/tmp/speed4/pylib")
import tract
def shapes_of(path, B):
    m = onnx.load(path, load_external_data=False)
    out = []
    for i in m.graph.input:
        t = i.type.tensor_type
        dims = [B if d.dim_param else d.dim_value for d in t.shape.dim]
        dt = {1: "f32", 7: "i64"}[t.elem_type]
        out.append((i.name, dims, dt))
    return out
def load(path, B):
    im = tract.onnx().load(path)
    sh = shapes_of(path, B)
    for i, (n, dims, dt) in enumerate(sh):
        im.set_input_fact(i, ",".join([str(d) for d in dims] + [dt]))
    m = im.into_model()
    try:
        m.transform("optimize") if len(sys.argv) > 5 else None
    except Exception as e:
        print("no optimize transform:", e)
    return m.into_runnable(), sh
def feeds(sh, rng):
    f = []
    for n, dims, dt in sh:
        if n == "phase": f.append(np.array(3, np.int64))
        elif dt == "i64": f.append(np.full(dims, 100, np.int64) if "step" in n else rng.integers(0, 8, dims).astype(np.int64))
        else: f.append(rng.standard_normal(dims).astype(np.float32))
    return f
base_p, ring_p = sys.argv[1], sys.argv[2]
rng = np.random.default_rng(0)
for B in [int(b) for b in sys.argv[3].split(",")]:
    rb, sb = load(base_p, B); rr, sr = load(ring_p, B)
    fb, fr = feeds(sb, rng), feeds(sr, rng)
    stb, st_r = rb.spawn_state(), rr.spawn_state()
    def run(st, f):
        outs = st.run(f)
        return [o.to_numpy() for o in outs]     # the runtime copies every output out of tract
    n = 40 if B <= 4 else 4
    for _ in range(2): run(stb, fb); run(st_r, fr)
    tb, tr = [], []
    for rnd in range(int(sys.argv[4])):
        t0 = time.thread_time()
        for _ in range(n): run(stb, fb)
        tb.append((time.thread_time() - t0) / n * 1e3)
        t0 = time.thread_time()
        for _ in range(n): run(st_r, fr)
        tr.append((time.thread_time() - t0) / n * 1e3)
    r = [b_ / a for a, b_ in zip(tb, tr)]
    print(f"tract batch {B}: base {np.median(tb):.3f} ms, ring {np.median(tr):.3f} ms, ring/base per-round median {np.median(r):.3f} [{min(r):.2f}-{max(r):.2f}]", flush=True)
