"""ONNX export: tiny bundles round-trip, the manifest validates, broken steps are caught by the exporter."""
import json
from pathlib import Path

import jsonschema
import numpy as np
import onnx
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]

from export import export as exporter  # noqa: E402
from export.verify import ExportCheckError  # noqa: E402

from helpers import scrambled_model  # noqa: E402
from livegesture.compare import assert_within  # noqa: E402
from livegesture.models import layers  # noqa: E402
from livegesture.stream import generate_clip  # noqa: E402
from livegesture.models.expert import RegionExpert  # noqa: E402


def build(model, out, rollout_tokens=6):
    return exporter.build_bundle(model, out, provenance={"training": "none (test)"}, reference_wav=None,
                                 ref_seconds=1.0, rollout_tokens=rollout_tokens, log=lambda *a: None)


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    out = tmp_path_factory.mktemp("b") / "tiny"
    model = scrambled_model("tiny", seed=4)
    return out, build(model, out), model


def test_manifest_validates_and_files_match(bundle):
    out, manifest, _ = bundle
    schema = json.loads((ROOT / "export" / "manifest.schema.json").read_text())
    on_disk = json.loads((out / "manifest.json").read_text())
    jsonschema.validate(on_disk, schema)
    for rel, info in on_disk["files"].items():
        assert exporter.sha256(out / rel) == info["sha256"], rel
    assert {g["name"] for g in on_disk["graphs"]} == {"audio_encoder", "fusion", "experts_fused", "decoders_fused",
                                                      "fusion_attention",
                                                      *(f"{k}_{r}" for k in ("expert", "decoder")
                                                        for r in ("upper", "hands", "lower", "face"))}
    bad = dict(on_disk, schema_version=2)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)


def test_graphs_are_stateful_step_graphs(bundle):
    out, manifest, _ = bundle
    for g in manifest["graphs"]:
        m = onnx.load(out / g["file"])
        meta = {p.key: p.value for p in m.metadata_props}
        assert meta["livegesture.graph"] == g["name"] and meta["livegesture.schema_version"] == "1"
        assert max(o.version for o in m.opset_import if o.domain in ("", "ai.onnx")) >= 17
        assert not {n.op_type for n in m.graph.node} & {"If", "Loop", "Scan"}
        names_in = [i.name for i in m.graph.input]
        names_out = [o.name for o in m.graph.output]
        for c in g["caches"]:
            assert c["input"] in names_in and c["output"] in names_out
        for v in list(m.graph.input) + list(m.graph.output):
            assert v.type.tensor_type.shape.dim[0].dim_param, f"{g['name']}.{v.name}: batch axis is not dynamic"


def test_reference_vectors_replay_on_onnxruntime(bundle):
    """The bundle's own reference vectors, fed to onnxruntime with chained caches, match within 1e-5 (scaled)."""
    import onnxruntime as ort
    out, manifest, _ = bundle
    for g in manifest["graphs"]:
        ref = np.load(out / g["reference"])
        sess = ort.InferenceSession(str(out / g["file"]), providers=["CPUExecutionProvider"])
        cache = {c["input"]: np.zeros([int(ref["batch"]) if d == "batch" else d for d in c["shape"]],
                                      dtype=np.int64 if c["dtype"] == "int64" else np.float32) for c in g["caches"]}
        names = [o.name for o in sess.get_outputs()]
        for s in range(int(ref["n_steps"])):
            feed = {i["name"]: ref[f"step{s}.input.{i['name']}"] for i in g["inputs"]}
            feed.update(cache)
            res = dict(zip(names, sess.run(None, feed)))
            for o in g["outputs"]:
                assert_within(res[o["name"]], ref[f"step{s}.output.{o['name']}"], 1e-5,
                              f"{g['name']}.{o['name']} step {s}")
            cache = {c["input"]: res[c["output"]] for c in g["caches"]}
        last = int(ref["n_steps"]) - 1
        for c in g["caches"]:
            assert_within(cache[c["input"]], ref[f"step{last}.new_cache.{c['name']}"], 1e-5,
                          f"{g['name']}.{c['output']} after step {last}")


def read_clip(path):
    """The reference clip as the exporter used it (16-bit samples / 32768)."""
    import wave
    with wave.open(str(path), "rb") as w:
        assert w.getsampwidth() == 2 and w.getnchannels() == 1
        return (np.frombuffer(w.readframes(w.getnframes()), dtype="<i2") / 32768.0).astype(np.float32)


def assert_rollout_reproduced(ro, again):
    """A stored rollout equals a fresh run with the same model, clip and seed: identical tokens, every frame
    value within 1e-6 (scaled; the same torch computation, so exact in practice)."""
    assert np.array_equal(ro["tokens"], again["tokens"]), "tokens differ"
    for k in ("poses", "trans", "expressions", "foot_contact"):
        assert_within(ro[k], again[k], 1e-6, f"rollout '{k}'")


def test_rollout_reference_is_reproducible(bundle):
    out, manifest, model = bundle
    ro = dict(np.load(out / "reference" / "rollout.npz"))
    assert ro["tokens"].shape == (manifest["reference"]["rollout_tokens"], 4)
    assert ro["poses"].shape == (4 * ro["tokens"].shape[0], 165)
    # the values: the model run again on the clip the manifest names, with its seed
    clip = read_clip(out / "reference" / "clip.wav")
    again = generate_clip(model, np.tile(clip, int(ro["clip_repeats"])), seed=int(ro["seed"]))
    assert_rollout_reproduced(ro, again)
    # the comparison fails on a broken rollout: one pose moved, a NaN, one token changed
    for k, i, how in (("poses", 11, "move"), ("expressions", 3, "nan"), ("tokens", 2, "token")):
        bad = {**ro, k: ro[k].copy()}
        if how == "move":
            bad[k].flat[i] += 1e-3
        elif how == "nan":
            bad[k].flat[i] = np.nan
        else:
            bad[k].flat[i] += 1
        with pytest.raises(AssertionError):
            assert_rollout_reproduced(bad, again)


def test_dropped_cache_update_is_caught(tmp_path, monkeypatch):
    orig = RegionExpert.step

    def broken(self, prev_token, audio, cond, cache):
        out, new = orig(self, prev_token, audio, cond, cache)
        if self.region == "hands":
            for kv in ("k", "v"):                             # forgets its self-attention history
                new[f"layer1.sattn.{kv}"] = cache[f"layer1.sattn.{kv}"]
        return out, new
    monkeypatch.setattr(RegionExpert, "step", broken)
    with pytest.raises(ExportCheckError, match=r"graph 'expert_hands', output 'hidden', step \d+"):
        build(scrambled_model("tiny"), tmp_path / "bad")
    assert not (tmp_path / "bad").exists(), "a failed export must leave no bundle behind"
    assert not list(tmp_path.glob(".bad.*")), "a failed export must leave no temporary folder behind"


def test_future_reading_attention_is_caught(tmp_path, monkeypatch):
    """An offline attention that lets token t see token t+1 (look-ahead) disagrees with the causal step."""
    orig = layers.WindowedAttention.forward

    def peeking(self, x, kv_in):
        shifted = torch.cat([kv_in[:, 1:], kv_in[:, -1:]], 1)     # position t reads t+1
        return orig(self, x, shifted)
    monkeypatch.setattr(layers.WindowedAttention, "forward", peeking)
    with pytest.raises(ExportCheckError, match=r"torch step-by-step vs offline causal forward: graph 'expert_upper'"):
        build(scrambled_model("tiny"), tmp_path / "bad")


def test_fused_form_is_listed_checked_and_equal_to_the_canonical_one(bundle):
    """docs/bundle.md#forms-and-precision: the fused eXperts are a form in the manifest, checked against the canonical torch steps and on
    the rollout (identical tokens), and computed exactly as the canonical steps in torch."""
    from livegesture.forms.experts_fused import check_fused_experts
    out, manifest, model = bundle
    assert manifest["forms"]["canonical"]["experts"] == [f"expert_{r}" for r in ("upper", "hands", "lower", "face")]
    assert manifest["forms"]["fused"]["experts"] == ["experts_fused"]
    assert manifest["backend_forms"] == {"ort": "fused", "tract": "attention"}
    assert manifest["checks"]["experts_fused"]["torch_fused_vs_canonical_max_abs"] <= 1e-6
    assert manifest["checks"]["forms"]["rollout_tokens_identical"] == manifest["reference"]["rollout_tokens"]
    err, _, _, _ = check_fused_experts(model, steps=12)
    assert err <= 1e-6


def test_fused_decoders_are_listed_checked_and_equal_to_the_canonical_ones(bundle):
    """docs/bundle.md#forms-and-precision: the fused SVQ decoders are in the fused form, checked against the four canonical torch decoder
    steps, computed exactly as they are (every motion value and cache, bit-identical in torch), and their ONNX graph
    has the documented contract: token (B, R), motion (B, frames, sum of the region dims), caches with the regions'
    channels side by side."""
    from livegesture.forms.decoders_fused import FusedDecoders, check_fused_decoders
    from livegesture.regions import REGION_NAMES
    out, manifest, model = bundle
    assert manifest["forms"]["canonical"]["decoders"] == [f"decoder_{r}" for r in REGION_NAMES]
    assert manifest["forms"]["fused"]["decoders"] == ["decoders_fused"]
    assert "decoders_fused" in manifest["forms"]["fused"]["contract"]
    assert manifest["checks"]["decoders_fused"]["torch_fused_vs_canonical_max_abs"] == 0.0
    assert manifest["checks"]["decoders_fused"]["ort_vs_torch_max_abs"] <= 1e-5
    assert manifest["checks"]["forms"]["rollout_frames_max_abs"] == 0.0
    err, _, _, _ = check_fused_decoders(model, steps=10, batch=3)
    assert err == 0.0
    spec = {g["name"]: g for g in manifest["graphs"]}
    fused, canon = spec["decoders_fused"], [spec[f"decoder_{r}"] for r in REGION_NAMES]
    assert fused["form"] == "fused"
    assert fused["inputs"] == [{"name": "token", "dtype": "int64", "shape": ["batch", len(REGION_NAMES)]}]
    fpt = model.cfg.frontend.frames_per_token
    dims = [r["dim"] for r in manifest["regions"]]
    assert fused["outputs"][0]["shape"] == ["batch", fpt, sum(dims)]
    assert [c["name"] for c in fused["caches"]] == [c["name"] for c in canon[0]["caches"]]
    for cf, cc in zip(fused["caches"], canon[0]["caches"]):
        assert cf["shape"] == cc["shape"][:-1] + [len(REGION_NAMES) * cc["shape"][-1]]
    # the regions' columns of motion are the canonical decoders' outputs, in region order
    fd = FusedDecoders([model.svq[r] for r in REGION_NAMES]).eval()
    tok = torch.randint(0, model.cfg.codebook_size, (2, len(REGION_NAMES)))
    with torch.no_grad():
        motion = fd.step(tok, fd.init_cache(2))[0]["motion"]
        for r, name in enumerate(REGION_NAMES):
            want = model.svq[name].step(tok[:, r], model.svq[name].init_cache(2))[0]["motion"]
            off = sum(dims[:r])
            assert torch.equal(motion[..., off:off + dims[r]], want), name


def test_broken_fused_decoders_are_caught_naming_them(tmp_path, monkeypatch):
    from livegesture.forms.decoders_fused import FusedDecoders
    orig = FusedDecoders.step

    def broken(self, token, cache):
        out, new = orig(self, token, cache)
        m = out["motion"].clone()
        off = sum(self.dims[:2])
        m[..., off:off + self.dims[2]] *= 1.001                 # the lower region's columns drift
        return {"motion": m}, new
    monkeypatch.setattr(FusedDecoders, "step", broken)
    with pytest.raises(ExportCheckError, match=r"graph 'decoders_fused', output 'motion\[\.\.\., lower\]', step \d+"):
        build(scrambled_model("tiny"), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_broken_fused_form_is_caught_naming_it(tmp_path, monkeypatch):
    from livegesture.forms.experts_fused import FusedExperts
    orig = FusedExperts.step

    def broken(self, prev_token, audio, cond, cache):
        out, new = orig(self, prev_token, audio, cond, cache)
        h = out["hidden"].clone()
        h[:, 2] = h[:, 2] * 1.001                               # the lower region drifts
        return {"hidden": h}, new
    monkeypatch.setattr(FusedExperts, "step", broken)
    with pytest.raises(ExportCheckError, match=r"graph 'experts_fused', output 'hidden\[:, 2\] \(lower\)', step \d+"):
        build(scrambled_model("tiny"), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_attention_form_is_listed_checked_and_uses_the_opset23_attention_op(bundle):
    """docs/bundle.md#forms-and-precision: the attention form's fusion (``fusion_attention``) is listed in the manifest with the canonical
    eXperts and decoders, has the canonical fusion's inputs, outputs and caches, is checked against the canonical
    torch fusion and on the rollout (identical tokens), and its ONNX file is opset 23 with one standard
    ``Attention`` node per attention core and no other domain."""
    from livegesture.forms.fusion_attention import check_fusion_attention
    out, manifest, model = bundle
    form = manifest["forms"]["attention"]
    assert form["fusion"] == "fusion_attention" and form["opset"] == 23
    assert form["experts"] == manifest["forms"]["canonical"]["experts"]
    assert form["decoders"] == manifest["forms"]["canonical"]["decoders"]
    assert "Attention" in form["contract"]
    spec = {g["name"]: g for g in manifest["graphs"]}
    g, canon = spec["fusion_attention"], spec["fusion"]
    assert g["form"] == "attention"
    assert (g["inputs"], g["outputs"], g["caches"]) == (canon["inputs"], canon["outputs"], canon["caches"])
    checks = manifest["checks"]
    assert 0 < checks["fusion_attention"]["torch_form_vs_canonical_max_abs"] <= 1e-5
    assert checks["fusion_attention"]["ort_vs_torch_max_abs"] <= 1e-5
    assert checks["forms_attention"]["rollout_tokens_identical"] == manifest["reference"]["rollout_tokens"]
    err, _, _, _ = check_fusion_attention(model, steps=model.cfg.audio_window + 3)
    assert err <= 1e-5
    m = onnx.load(out / g["file"])
    assert [(o.domain, o.version) for o in m.opset_import] == [("", 23)]
    assert {n.domain for n in m.graph.node} == {""}
    n_attn = sum(n.op_type == "Attention" for n in m.graph.node)
    assert n_attn == 3 * model.cfg.fuse_blocks          # spatial, temporal and cross per block
    # the canonical fusion keeps opset 17 and has no Attention node
    c = onnx.load(out / canon["file"])
    assert max(o.version for o in c.opset_import if o.domain == "") == 17
    assert not any(n.op_type == "Attention" for n in c.graph.node)


def test_a_wrong_attention_form_fails_the_export_naming_the_graph(tmp_path, monkeypatch):
    """The attention form's torch step is checked against the canonical fusion before anything is written."""
    orig = layers.WindowedAttention.step_op

    def shifted(self, *a, **k):
        return orig(self, *a, **k) * 1.01     # (a constant shift would vanish in the LayerNorms)
    monkeypatch.setattr(layers.WindowedAttention, "step_op", shifted)
    with pytest.raises(ExportCheckError, match=r"torch attention form vs the canonical fusion: graph 'fusion_attention'"):
        build(scrambled_model("tiny"), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_the_opset23_rewrite_refuses_an_op_whose_meaning_changed():
    """to_attention_opset moves the Attention nodes to the default domain at opset 23 and refuses a graph with an
    op whose definition changed between opset 17 and 23 that it does not know (here Pad, changed at 18)."""
    from export.graphs import to_attention_opset
    from onnx import TensorProto, helper
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 3, 4])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 2, 3, 4])

    def model(extra):
        nodes = [helper.make_node("Attention", ["x", "x", "x"], ["a"], domain=layers.ATTENTION_DOMAIN, scale=0.5)]
        nodes += extra or [helper.make_node("Identity", ["a"], ["y"])]
        m = helper.make_model(helper.make_graph(nodes, "g", [x], [y]),
                              opset_imports=[helper.make_opsetid("", 17), helper.make_opsetid(layers.ATTENTION_DOMAIN, 1)])
        return m
    m = model(None)
    to_attention_opset(m, "g")
    assert [(o.domain, o.version) for o in m.opset_import] == [("", 23)] and m.graph.node[0].domain == ""
    onnx.checker.check_model(m, full_check=True)
    pads = helper.make_node("Pad", ["a", "p"], ["y"])
    with pytest.raises(ValueError, match=r"graph 'g': op Pad .* changed between opset 17 and 23"):
        to_attention_opset(model([pads]), "g")


# ------------------------------------------------------------------ scaled bounds, provenance, no import cycle

def test_export_checks_scale_with_the_magnitude():
    """docs/parity.md: a bound scales with the reference's magnitude. A step-vs-offline comparison whose values
    are near 40 and 3 float32 ulps apart passes 1e-5 (absolute error above 1e-5); a real error at the same
    magnitude fails, naming the step, the error and the scale."""
    from export import verify
    off = torch.linspace(38.0, 41.0, 2 * 5 * 3, dtype=torch.float32).reshape(2, 5, 3)
    st = off.clone()
    st[1, 3, 2] = torch.nextafter(torch.nextafter(torch.nextafter(st[1, 3, 2], torch.tensor(1e9)),
                                                  torch.tensor(1e9)), torch.tensor(1e9))
    assert float((st - off).abs().max()) > 1e-5
    step, err, scale, _ = verify._first_bad_step(st, off, 1, verify.STEP_VS_OFFLINE)
    assert step is None and err > 1e-5 and scale > 40
    bad = st.clone()
    bad[0, 2, 1] += 0.01
    step, err, scale, detail = verify._first_bad_step(bad, off, 1, verify.STEP_VS_OFFLINE)
    assert step == 2 and abs(err - 0.01) < 1e-4 and scale > 39
    with pytest.raises(ExportCheckError, match=r"graph 'g', output 'o', step 2: .* x scale 4\d"):
        verify.fail("g", "o", step, err, verify.STEP_VS_OFFLINE, "torch step-by-step vs offline", scale, detail)
    nan = st.clone()
    nan[1, 4, 0] = float("nan")
    step, err, _, detail = verify._first_bad_step(nan, off, 1, verify.STEP_VS_OFFLINE)
    assert step == 4 and "non-finite" in detail


def test_manifest_records_the_scale_of_every_recorded_check(bundle):
    _, manifest, _ = bundle
    for g in manifest["graphs"]:
        c = manifest["checks"][g["name"]]
        assert c["ort_vs_torch_scale"] >= 1.0 and c["ort_vs_torch_max_abs"] <= 1e-5 * c["ort_vs_torch_scale"]
        for key in ("torch_step_vs_offline", "torch_fused_vs_canonical", "torch_form_vs_canonical"):
            if f"{key}_max_abs" in c:
                assert c[f"{key}_scale"] >= 1.0, (g["name"], key)


def test_provenance_names_the_checkpoint_by_file_and_sha256_and_no_machine_path(tmp_path):
    """A bundle exported from a checkpoint records it by file name and sha256; absolute paths of the machine
    (in the checkpoint's own provenance, the --provenance file or the command) become their last component."""
    from export import bundle_writer
    from livegesture import checkpoint as ckpt
    model = ckpt.random_model("tiny", 0)
    cp = tmp_path / "runs" / "final.pt"
    cp.parent.mkdir()
    ckpt.save(model, cp, provenance={"data": "/tmp/corpus_a + /work/corpora/b", "checkpoint": "final.pt (run x)"})
    prov = tmp_path / "prov.json"
    prov.write_text(json.dumps({"evaluation": {"command": "eval /root/x/eval.json --out /tmp/e", "ratio": "1/2"}}))
    out = tmp_path / "b"
    assert exporter.main(["--checkpoint", str(cp), "--out", str(out), "--provenance", str(prov),
                          "--forms", "canonical", "--rollout-tokens", "4", "--reference-seconds", "1"]) == 0
    p = json.loads((out / "manifest.json").read_text())["provenance"]
    assert p["checkpoint"] == {"file": "final.pt", "sha256": exporter.sha256(cp)}
    assert p["data"] == "corpus_a + b"
    assert p["evaluation"] == {"command": "eval eval.json --out e", "ratio": "1/2"}
    assert "--checkpoint final.pt" in p["export_command"] and "--out b" in p["export_command"]
    assert bundle_writer.absolute_paths(p) == []
    assert str(tmp_path) not in json.dumps(p)
    # the check itself finds what it must
    assert bundle_writer.absolute_paths({"a": ["x /tmp/y"]}) == ["provenance.a[0]: /tmp/y"]


def test_export_modules_import_no_circle():
    """export.py runs diffsheg_export's builder (through the family registry) and both use bundle_writer;
    diffsheg_export and quantize never import export.py (DESIGN: nothing imports in a circle). The package's
    modules import each other relatively (``from .graphs import``), none through a patched ``sys.path``."""
    import ast
    for name in ("diffsheg_export.py", "quantize.py", "bundle_writer.py", "verify.py", "graphs.py"):
        tree = ast.parse((ROOT / "export" / name).read_text())
        imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        for n in ast.walk(tree):
            if isinstance(n, ast.ImportFrom):
                mod = ("." * n.level) + (n.module or "")
                imported |= {mod} | ({mod + a.name for a in n.names} if not n.module else set())
        assert not imported & {"export", "export.export", ".export"}, f"export/{name} imports export.py"
        assert not imported & {"graphs", "verify", "bundle_writer", "ort_python_peer"}, \
            f"export/{name} imports a module by a patched sys.path ({sorted(imported)})"
    for name in ("export.py", "quantize.py"):
        assert "sys.path.insert" not in (ROOT / "export" / name).read_text(), f"export/{name} patches sys.path"


def test_graph_forms_live_apart_from_the_fuse_component():
    """The graph forms are livegesture.forms.*; livegesture.models keeps the model's components (models/fuse.py
    is xAR-Fuse), so the names cannot be confused."""
    import importlib
    for mod, cls in (("experts_fused", "FusedExperts"), ("decoders_fused", "FusedDecoders"),
                     ("fusion_attention", "FusionAttention")):
        assert hasattr(importlib.import_module(f"livegesture.forms.{mod}"), cls)
    models = ROOT / "python" / "livegesture" / "models"
    assert not {p.name for p in models.glob("fus*.py")} - {"fuse.py"}


def test_ring_forms_are_listed_checked_and_replay_with_the_write(tmp_path):
    """docs/bundle.md#ring-caches: --forms ...,ring writes fused_ring and attention_ring; each ring graph takes a
    phase, returns one slot per attention cache (output_shape) and replays its reference vectors on onnxruntime
    when the entries are written at the reference's phase."""
    import onnxruntime as ort
    from livegesture.forms.ring import write_entries
    out = tmp_path / "ring"
    m = exporter.build_bundle(scrambled_model("tiny", seed=4), out, provenance={"training": "none (test)"},
                              reference_wav=None, ref_seconds=1.0, rollout_tokens=6, log=lambda *a: None,
                              forms=("canonical", "fused", "attention", "ring"),
                              backend_forms={"ort": "fused_ring", "tract": "attention_ring"})
    jsonschema.validate(m, json.loads((ROOT / "export" / "manifest.schema.json").read_text()))
    assert m["forms"]["fused_ring"]["experts"] == ["experts_fused_ring"] and m["forms"]["fused_ring"]["ring"]
    assert m["forms"]["attention_ring"]["fusion"] == "fusion_attention_ring"
    assert m["backend_forms"] == {"ort": "fused_ring", "tract": "attention_ring"}
    ring = [g for g in m["graphs"] if g["name"].endswith("_ring")]
    assert sorted(g["name"] for g in ring) == sorted(["experts_fused_ring", "fusion_ring", "fusion_attention_ring",
                                                      *(f"expert_{r}_ring" for r in ("upper", "hands", "lower", "face"))])
    for g in ring:
        assert g["inputs"][-1] == {"name": "phase", "dtype": "int64", "shape": ["batch"]}
        for c in g["caches"]:
            assert ("output_shape" in c) == (c["name"] != "step")
        assert m["checks"][g["name"]]["torch_form_vs_canonical_max_abs"] <= 1e-5 * m["checks"][g["name"]][
            "torch_form_vs_canonical_scale"]
        ref = np.load(out / g["reference"])
        sess = ort.InferenceSession(str(out / g["file"]), providers=["CPUExecutionProvider"])
        names = [o.name for o in sess.get_outputs()]
        cache = {c["name"]: torch.zeros([int(ref["batch"]), *c["shape"][1:]],
                                        dtype=torch.int64 if c["dtype"] == "int64" else torch.float32)
                 for c in g["caches"]}
        for s in range(int(ref["n_steps"])):
            feed = {i["name"]: ref[f"step{s}.input.{i['name']}"] for i in g["inputs"]}
            feed.update({f"cache.{k}": v.numpy() for k, v in cache.items()})
            res = dict(zip(names, sess.run(None, feed)))
            for o in g["outputs"]:
                assert_within(res[o["name"]], ref[f"step{s}.output.{o['name']}"], 1e-5, f"{g['name']} step {s}")
            new = {k: torch.from_numpy(res[f"new_cache.{k}"]) for k in cache}
            cache = write_entries(cache, new, int(feed["phase"][0]))
        for k, v in cache.items():
            assert_within(v.numpy(), ref[f"step{int(ref['n_steps']) - 1}.new_cache.{k}"], 1e-5, f"{g['name']} {k}")


def test_a_ring_graph_reading_at_the_wrong_phase_fails_the_export_check(monkeypatch):
    """Each ring graph's torch step is checked against its shift-layout graph before anything is written
    (``check_ring_vs_shift``, bound 1e-5 scaled): a ring read one slot off (the graph's rotation and the
    runtime's write disagree) fails it."""
    from livegesture.forms import ring
    model = scrambled_model("tiny")
    steps = 2 * max(model.cfg.history, model.cfg.audio_window, model.cfg.fuse_window) + 3
    for graph in ("experts_fused_ring", "fusion_attention_ring"):
        err, _, _, scale = exporter.check_ring_vs_shift(model, graph, steps)
        assert err <= 1e-5 * scale, graph
    orig = ring.ring_order
    monkeypatch.setattr(ring, "ring_order", lambda window, phase: orig(window, phase + 1))
    for graph in ("experts_fused_ring", "fusion_attention_ring"):
        err, _, _, scale = exporter.check_ring_vs_shift(model, graph, steps)
        assert err > 100 * 1e-5 * scale, f"{graph}: a ring read one slot off went unnoticed ({err:.2e})"
