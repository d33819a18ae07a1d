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
sys.path.insert(0, str(ROOT / "export"))
sys.path.insert(0, str(ROOT / "bench"))

import export as exporter  # noqa: E402
import ort_python_peer as peer  # noqa: E402
import quantize  # noqa: E402

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
    # the peer chains the canonical graphs (a bundle's fused form, SPEC 14, is the Rust runtime's)
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
        # the f32 graph's inputs, outputs and caches are unchanged (the runtime reads them from the manifest)
        assert g == next(x for x in f32["graphs"] if x["name"] == g["name"])
    # the reduced bundle's own reference vectors are reproduced by onnxruntime, and its rollout by the peer
    rc, res = run_peer(tiny_int8, tmp_path, "--streams", "")
    assert rc == 0 and res["precision"] == "int8"
    import onnxruntime as ort
    spec = next(g for g in m["graphs"] if g["name"] == "fusion")
    sess = ort.InferenceSession(str(tiny_int8 / spec["file"]), providers=["CPUExecutionProvider"])
    ref = dict(np.load(tiny_int8 / spec["reference"]))
    _, e = quantize.graph_reference(sess, spec, ref)
    assert max(e.values()) < 1e-5


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
