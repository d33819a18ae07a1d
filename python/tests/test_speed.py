"""Issue 15 tools on a tiny export: the onnxruntime-from-Python peer (bench/ort_python_peer.py) runs the same
computation as the bundle's reference rollout, and the reduced-precision bundle (export/quantize.py) is a
complete bundle with its precision and measured error in the manifest."""
import json
import shutil
import sys
from pathlib import Path

import jsonschema
import numpy as np
import onnx
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

from export import export as exporter  # noqa: E402
import ort_python_peer as peer  # noqa: E402
from export import quantize  # noqa: E402

from helpers import scrambled_model  # noqa: E402

ROLLOUT_TOKENS = 12


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("speed") / "tiny"
    exporter.build_bundle(scrambled_model("tiny", seed=4), out, provenance={"training": "none (test)"},
                          reference_wav=None, ref_seconds=1.0, rollout_tokens=ROLLOUT_TOKENS, log=lambda *a: None)
    return out


@pytest.fixture(scope="module")
def tiny_int8(tiny, tmp_path_factory):
    out = tmp_path_factory.mktemp("speed") / "tiny-int8"
    quantize.build(tiny, out, "int8", per_channel=True, log=lambda *a: None)
    return out


def run_peer(bundle, tmp_path, *extra):
    js = tmp_path / "peer.json"
    rc = peer.main(["--bundle", str(bundle), "--tokens", "3", "--warmup", "1", "--streams", "1,3",
                    "--batch-steps", "3", "--batch-warmup", "1", "--batch-min-steps", "1", "--json", str(js), *extra])
    return rc, (json.loads(js.read_text()) if js.exists() else None)


def test_ort_python_peer_reproduces_the_reference_rollout(tiny, tmp_path):
    rc, res = run_peer(tiny, tmp_path)
    assert rc == 0
    n_ref = len(np.load(tiny / "reference" / "rollout.npz")["tokens"])
    assert n_ref >= ROLLOUT_TOKENS
    assert res["check"]["tokens_checked"] == n_ref and res["check"]["identical"]
    assert res["single"]["step_ms"]["n"] == 3
    # the peer chains the canonical graphs (a bundle's fused form, docs/bundle.md#forms-and-precision, is the Rust runtime's)
    assert set(res["single"]["graphs_ms_median"]) == {g["name"] for g in json.loads((tiny / "manifest.json").read_text())["graphs"]
                                                      if g.get("form", "canonical") == "canonical"}
    b = {r["streams"]: r for r in res["batched"]}
    assert b[3]["churn"] and b[3]["stream0_tokens_checked"] == 3 and b[1]["stream0_tokens_checked"] == 4


def test_ort_python_peer_fails_when_a_token_differs(tiny, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(tiny, bad)
    ro = dict(np.load(bad / "reference" / "rollout.npz"))
    K = json.loads((bad / "manifest.json").read_text())["vocab"]["codebook_size"]
    ro["tokens"][7, 2] = (ro["tokens"][7, 2] + 1) % K
    np.savez_compressed(bad / "reference" / "rollout.npz", **ro)
    rc, _ = run_peer(bad, tmp_path, "--check-tokens", "20")
    assert rc == 1
    # a check shorter than the difference passes
    rc, res = run_peer(bad, tmp_path, "--check-tokens", "7", "--streams", "")
    assert rc == 0 and res["check"]["tokens_checked"] == 7


def test_int8_bundle_manifest_graphs_and_reference(tiny, tiny_int8, tmp_path):
    m = json.loads((tiny_int8 / "manifest.json").read_text())
    jsonschema.validate(m, json.loads((ROOT / "export" / "manifest.schema.json").read_text()))
    f32 = json.loads((tiny / "manifest.json").read_text())
    assert m["precision"]["weights"] == "int8"
    for rel, info in m["files"].items():
        assert exporter.sha256(tiny_int8 / rel) == info["sha256"], rel
    err = m["precision"]["error_vs_f32"]
    assert set(err["graphs_max_abs"]) == {g["name"] for g in f32["graphs"]}
    assert 0 < err["graphs_max_abs"]["fusion"]["logits"] < 1.0      # int8 changes the numbers, a little
    ro = err["rollout"]
    assert ro["tokens"] == len(np.load(tiny / "reference" / "rollout.npz")["tokens"])
    assert 0 <= ro["teacher_forced_identical_tokens"] <= 1 and ro["teacher_forced_guided_logits_max_abs"] > 0
    for g in m["graphs"]:
        ops = [n.op_type for n in onnx.load(tiny_int8 / g["file"]).graph.node]
        assert ops.count("MatMulInteger") == m["precision"]["graphs"][g["name"]]["quantized_products"] > 0, g["name"]
        assert "DynamicQuantizeLinear" in ops
        # 7-bit weights: no uint8 x int8 pair sum saturates on a CPU without VNNI (export/quantize.py)
        assert quantize.saturating_weights(onnx.load(tiny_int8 / g["file"])) == [], g["name"]
        # the f32 graph's inputs, outputs and caches are unchanged (the runtime reads them from the manifest)
        assert g == next(x for x in f32["graphs"] if x["name"] == g["name"])
    # the reduced bundle's rollout is reproduced by the peer; its graph reference vectors are the f32 bundle's
    # (torch), which onnxruntime on the reduced graph meets within the bound stated in the manifest
    rc, res = run_peer(tiny_int8, tmp_path, "--streams", "")
    assert rc == 0 and res["precision"] == "int8"
    assert_reference_is_the_f32_torch_one(tiny, tiny_int8, m)


def test_full_8_bit_weights_are_caught_as_saturating(tiny, tmp_path):
    """Full-range int8 weights (onnxruntime's default, without reduce_range) reach +-127: the check that keeps them
    out of a bundle names them; on an AVX2-only CPU they gave 0.30-0.61 scaled error (docs/bundle.md)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic
    spec = next(g for g in json.loads((tiny / "manifest.json").read_text())["graphs"] if g["name"] == "expert_hands")
    full = tmp_path / "full.onnx"
    quantize_dynamic(str(tiny / spec["file"]), str(full), op_types_to_quantize=["MatMul", "Gemm"],
                     weight_type=QuantType.QInt8, per_channel=True, extra_options={"MatMulConstBOnly": True})
    bad = quantize.saturating_weights(onnx.load(full))
    assert len(bad) > 0
    ok = tmp_path / "seven.onnx"
    quantize.quantize_graph(tiny / spec["file"], ok, "int8", True)
    assert quantize.saturating_weights(onnx.load(ok)) == []


def test_quantize_refuses_bad_requests(tiny, tiny_int8, tmp_path):
    assert quantize.main(["--bundle", str(tiny), "--out", str(tiny)]) == 2
    assert quantize.main(["--bundle", str(tmp_path / "nothing"), "--out", str(tmp_path / "x")]) == 2
    assert quantize.main(["--bundle", str(tiny_int8), "--out", str(tmp_path / "again")]) == 1
    assert not (tmp_path / "again").exists()


def test_int8_forms_and_batch_row_independence(tiny, tmp_path):
    """The weight-only form (f32 activations) keeps every batch row independent of the others; the dynamic form's
    per-tensor activation scale couples them (why it fails `livegesture parity`'s batch check, BENCHMARKS.md)."""
    import onnxruntime as ort
    spec = next(g for g in json.loads((tiny / "manifest.json").read_text())["graphs"] if g["name"] == "expert_upper")
    ref = dict(np.load(tiny / spec["reference"]))
    feed = {i["name"]: ref[f"step3.input.{i['name']}"] for i in spec["inputs"]}
    feed["audio"] = feed["audio"] * np.array([[1.0], [8.0]], np.float32)     # row 1 with a much larger range
    caches = {c["input"]: np.zeros([2, *c["shape"][1:]], np.dtype(c["dtype"])) for c in spec["caches"]}
    rows = {}
    for act in ("f32", "dynamic"):
        path = tmp_path / f"{act}.onnx"
        info = quantize.quantize_graph(tiny / spec["file"], path, "int8", True, act)
        ops = [n.op_type for n in onnx.load(path).graph.node]
        assert ops.count("DequantizeLinear" if act == "f32" else "MatMulInteger") == info["quantized_products"] > 0
        sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        both = sess.run(["hidden"], {**feed, **caches})[0]
        alone = sess.run(["hidden"], {**{k: v[:1] for k, v in feed.items()}, **{k: v[:1] for k, v in caches.items()}})[0]
        rows[act] = float(np.abs(both[:1] - alone).max())
    assert rows["f32"] <= 1e-6
    assert rows["dynamic"] > 1e-4


@pytest.fixture(scope="module")
def tiny_f16(tiny, tmp_path_factory):
    out = tmp_path_factory.mktemp("speed") / "tiny-f16"
    quantize.build(tiny, out, "f16", per_channel=False, log=lambda *a: None)
    return out


def test_f16_bundle_stores_weights_in_float16_with_f32_arithmetic(tiny, tiny_f16, tmp_path):
    m = json.loads((tiny_f16 / "manifest.json").read_text())
    jsonschema.validate(m, json.loads((ROOT / "export" / "manifest.schema.json").read_text()))
    f32 = json.loads((tiny / "manifest.json").read_text())
    p = m["precision"]
    assert p["weights"] == "float16" and p["activations"] == "float32" and "Cast" in p["method"]
    assert p["source"]["manifest_sha256"] == exporter.sha256(tiny / "manifest.json")
    for rel, info in m["files"].items():
        assert exporter.sha256(tiny_f16 / rel) == info["sha256"], rel
    # every form of the f32 bundle (the fused eXperts included) is reduced, with the same contract
    assert [g["name"] for g in m["graphs"]] == [g["name"] for g in f32["graphs"]]
    assert "experts_fused" in p["graphs"] and m["forms"] == f32["forms"] and m["backend_forms"] == f32["backend_forms"]
    for g in m["graphs"]:
        assert g == next(x for x in f32["graphs"] if x["name"] == g["name"])
        q, src = onnx.load(tiny_f16 / g["file"]), onnx.load(tiny / g["file"])
        n_big = sum(1 for i in src.graph.initializer if i.data_type == onnx.TensorProto.FLOAT and np.prod(i.dims) > 1)
        halves = [i for i in q.graph.initializer if i.data_type == onnx.TensorProto.FLOAT16]
        assert len(halves) == n_big > 0, g["name"]
        casts = {n.input[0]: n for n in q.graph.node if n.op_type == "Cast"}
        for h in halves:   # each float16 weight becomes float32 again, under its original name, before use
            assert casts[h.name].attribute[0].i == onnx.TensorProto.FLOAT
            w = onnx.numpy_helper.to_array(next(i for i in src.graph.initializer if i.name == casts[h.name].output[0]))
            assert np.array_equal(onnx.numpy_helper.to_array(h), w.astype(np.float16))
        # the weights take half the bytes (the tiny graphs' files are dominated by their node lists)
        assert sum(len(i.raw_data) for i in halves) * 2 == sum(
            len(i.raw_data) for i in src.graph.initializer if i.name in {casts[x.name].output[0] for x in halves})
        assert p["graphs"][g["name"]]["file_bytes"] < p["graphs"][g["name"]]["file_bytes_f32"]
    err = p["error_vs_f32"]
    assert set(err["graphs_max_abs"]) == {g["name"] for g in f32["graphs"]}
    assert 0 < err["graphs_max_abs"]["fusion"]["logits"] < 0.05     # float16 rounding of the weights only
    assert err["rollout"]["tokens"] == len(np.load(tiny / "reference" / "rollout.npz")["tokens"])
    assert p["metrics"] is None
    # the reduced bundle's rollout is reproduced by the peer; its graph reference vectors are the f32 bundle's
    rc, res = run_peer(tiny_f16, tmp_path, "--streams", "")
    assert rc == 0 and res["precision"] == "float16"
    assert_reference_is_the_f32_torch_one(tiny, tiny_f16, m)


def assert_reference_is_the_f32_torch_one(tiny, reduced, m):
    """Every graph's reference vectors are the f32 bundle's files (torch on the f32 weights: an independent
    side), and onnxruntime on the reduced graph meets them within the bound the manifest states, which is
    the measured error x BOUND_MARGIN (below the precision's limit)."""
    import onnxruntime as ort
    w = m["precision"]["weights"]
    for spec in m["graphs"]:
        assert exporter.sha256(reduced / spec["reference"]) == exporter.sha256(tiny / spec["reference"]), spec["name"]
        c = m["checks"][spec["name"]]
        assert 0 < c["reduced_vs_f32_torch_scaled"] <= quantize.ERROR_LIMIT[w]
        # the bound is stated once, from the scaled error (the checker scales it): not from the absolute one
        assert c["reduced_vs_f32_torch_bound"] == quantize.stated_bound(c["reduced_vs_f32_torch_scaled"])
        assert c["reduced_vs_f32_torch_scaled"] < c["reduced_vs_f32_torch_bound"] \
            <= 4 * c["reduced_vs_f32_torch_scaled"] or c["reduced_vs_f32_torch_bound"] == quantize.F32_BOUND
    spec = next(g for g in m["graphs"] if g["name"] == "fusion")
    sess = ort.InferenceSession(str(reduced / spec["file"]), providers=["CPUExecutionProvider"])
    _, e = quantize.graph_reference(sess, spec, dict(np.load(reduced / spec["reference"])))
    assert e["scaled"] <= m["checks"]["fusion"]["reduced_vs_f32_torch_bound"]


def test_a_wrong_reduced_graph_is_refused(tiny, tmp_path, monkeypatch):
    """quantize checks each reduced graph against the f32 bundle's torch reference vectors: a graph the reduction
    got wrong (one weight matrix doubled) is refused, naming it, and no bundle is written. (With reference
    vectors made by the reduced graphs themselves, it would pass every check.)"""
    orig = quantize.quantize_graph

    def wrong(src, dst, precision, per_channel, activations="dynamic"):
        info = orig(src, dst, precision, per_channel, activations)
        if dst.name.startswith("expert_hands"):
            q = onnx.load(str(dst))
            t = next(i for i in q.graph.initializer if i.data_type == onnx.TensorProto.FLOAT16 and np.prod(i.dims) > 1)
            t.CopyFrom(onnx.numpy_helper.from_array(onnx.numpy_helper.to_array(t) * np.float16(2), t.name))
            onnx.save(q, str(dst))
        return info
    monkeypatch.setattr(quantize, "quantize_graph", wrong)
    with pytest.raises(RuntimeError, match=r"graph 'expert_hands'.*wrong, not rounded"):
        quantize.build(tiny, tmp_path / "bad", "f16", per_channel=False, log=lambda *a: None)
    assert not (tmp_path / "bad").exists()


def test_bf16_rounding_and_out_of_range_tensors(tmp_path):
    a = np.array([1.0, 1.00390625, 1.01171875, -3.5e-3, 65504.0, 1e5], np.float32)
    bits = quantize.to_bf16_bits(a)
    back = quantize.bf16_bits_to_f32(bits)
    # round to nearest even on the 16 dropped bits; the relative error of bfloat16 is at most 2^-9
    assert back[0] == 1.0 and back[1] == 1.0 and back[2] == 1.015625
    assert np.all(np.abs(back - a) <= np.abs(a) * 2.0 ** -8)
    assert quantize.reduced_tensor(a, "w", "float16") is None           # 1e5 is beyond float16
    t, back16 = quantize.reduced_tensor(a[:5], "w", "float16")
    assert t.data_type == onnx.TensorProto.FLOAT16 and back16[4] == 65504.0
    t, back_bf = quantize.reduced_tensor(a, "w", "bfloat16")
    assert t.data_type == onnx.TensorProto.BFLOAT16 and np.array_equal(back_bf, back)
    assert quantize.reduced_tensor(np.array([1.0, -1e9], np.float32), "m", "float16") is None


def test_bf16_graph_runs_on_onnxruntime(tiny, tmp_path):
    """A bfloat16-weight graph loads on onnxruntime and computes with the rounded weights (tract 0.23 has no
    bfloat16 type, see BENCHMARKS.md)."""
    import onnxruntime as ort
    spec = next(g for g in json.loads((tiny / "manifest.json").read_text())["graphs"] if g["name"] == "decoder_upper")
    info = quantize.quantize_graph(tiny / spec["file"], tmp_path / "bf16.onnx", "bf16", False)
    assert info["reduced_tensors"] > 0 and 0 < info["weight_rounding_max_abs"]
    ref = dict(np.load(tiny / spec["reference"]))
    sess = ort.InferenceSession(str(tmp_path / "bf16.onnx"), providers=["CPUExecutionProvider"])
    _, e = quantize.graph_reference(sess, spec, ref)
    assert 0 < e["motion"] < 0.5


def test_record_metrics_puts_both_reports_in_the_manifest(tiny_f16, tiny, tmp_path):
    work = tmp_path / "b"
    shutil.copytree(tiny_f16, work)
    a, b = tmp_path / "f32.json", tmp_path / "f16.json"
    a.write_text(json.dumps({"generated": {"fgd": 2.0, "bc": 0.8}, "ground_truth": {"fgd": 0.5}}))
    b.write_text(json.dumps({"generated": {"fgd": 2.1, "bc": 0.81}, "ground_truth": {"fgd": 0.5}}))
    assert quantize.main(["--record-metrics", str(work), "--metrics-f32", str(a), "--metrics-reduced", str(b),
                          "--metrics-command", "eval"]) == 0
    met = json.loads((work / "manifest.json").read_text())["precision"]["metrics"]
    assert met["generated"] == {"float32": {"fgd": 2.0, "bc": 0.8}, "float16": {"fgd": 2.1, "bc": 0.81}}
    assert met["command"] == "eval" and met["ground_truth"] == {"fgd": 0.5}
    # not a report, or not a reduced bundle: refused
    (tmp_path / "bad.json").write_text("{}")
    assert quantize.main(["--record-metrics", str(work), "--metrics-f32", str(a), "--metrics-reduced",
                          str(tmp_path / "bad.json"), "--metrics-command", "eval"]) == 1
    assert quantize.main(["--record-metrics", str(tiny), "--metrics-f32", str(a), "--metrics-reduced", str(b),
                          "--metrics-command", "eval"]) == 1


def test_weights_roofline_reads_the_forms_real_bytes(tiny, tmp_path):
    """`python -m livegesture.bench weights` (issue 42 item 1's roofline): the bytes it streams are exactly
    the float tensors of the graphs each backend's form runs, the state is the guided stream's caches, and the
    roofline is the larger of the memory and compute bounds."""
    import onnx
    from onnx import numpy_helper
    from livegesture import bench
    man = json.loads((tiny / "manifest.json").read_text())
    files = {g["name"]: g for g in man["graphs"]}
    for backend in ("ort", "tract"):
        r = bench.weights_roofline(tiny, backend, repeats=2, evict_mb=8)
        form = man["forms"][man["backend_forms"][backend]]
        # tract runs the fused decoders with its attention form (runtime's default_decoders)
        decoders = ["decoders_fused"] if backend == "tract" else form["decoders"]
        assert bench.default_decoders(man, backend) == decoders
        want = ["audio_encoder", *form["experts"], form.get("fusion", "fusion"), *decoders]
        assert r["graphs"][:len(want)] == want
        total = 0
        for n in r["graphs"]:
            m = onnx.load(str(tiny / files[n]["file"]))
            ts = [numpy_helper.to_array(i) for i in m.graph.initializer]
            ts += [numpy_helper.to_array(a.t) for nd in m.graph.node if nd.op_type == "Constant"
                   for a in nd.attribute if a.name == "value"]
            nb = sum(t.nbytes for t in ts if t.dtype.kind == "f")
            assert r["weight_bytes_per_graph"][n] == nb
            total += nb
        assert r["weight_bytes"] == total > 0
        state = sum((2 if n.startswith(("expert", "fusion")) else 1) * 4 * int(np.prod([d for d in c["shape"] if d != "batch"]))
                    for n in r["graphs"] for c in files[n].get("caches", []) if c.get("dtype", "float32") == "float32")
        assert r["state_bytes"] == state > 0
        assert r["roofline_ms"] == max(r["weights_and_state_read_ms"], r["compute_ms"]) > 0
        assert r["target_ms"] == pytest.approx(1.6 * r["roofline_ms"])


def test_weights_roofline_refuses_a_bad_bundle(tiny, tmp_path):
    from livegesture import bench
    with pytest.raises(ValueError, match="backend_forms has no entry for backend 'cuda'"):
        bench.weights_roofline(tiny, "cuda", repeats=1, evict_mb=1)
    bad = tmp_path / "bad"
    shutil.copytree(tiny, bad)
    (bad / "audio_encoder.onnx").unlink()
    with pytest.raises(ValueError, match="audio_encoder.onnx: graph 'audio_encoder' of the ort form is missing"):
        bench.weights_roofline(bad, "ort", repeats=1, evict_mb=1)
    assert bench.main(["weights", "--bundle", str(bad), "--backend", "ort"]) == 2
    with pytest.raises(ValueError, match="manifest.json: no such file"):
        bench.weights_roofline(tmp_path, "ort", repeats=1, evict_mb=1)
