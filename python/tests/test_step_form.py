"""Step-graph forms (layers.StepForm, export --cache-layout / --step-masks): the ring cache layout and the
table masks compute the same steps as the canonical form, offline and through onnxruntime, and export the
graph form they describe."""
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "export"))

import export as exporter  # noqa: E402

import test_step_vs_offline as svo  # noqa: E402
from helpers import scrambled_model  # noqa: E402
from livegesture.models.layers import (StepForm, StepTables, mask_table, ring_rotation_table,  # noqa: E402
                                       set_step_form, step_query_rotations, window_bias)
from livegesture.regions import REGION_NAMES  # noqa: E402

FORMS = {"table": StepForm(masks="table"), "ring": StepForm(cache_layout="ring")}


@pytest.fixture(scope="module", params=[("tiny", "ring"), ("default", "ring"), ("tiny", "table")],
                ids=lambda p: "-".join(p))
def model(request):
    torch.manual_seed(0)
    return set_step_form(scrambled_model(request.param[0]), FORMS[request.param[1]])


@pytest.mark.parametrize("region", REGION_NAMES)
def test_expert_step_equals_offline(model, region):
    svo.test_expert(model, region)


def test_fusion_step_equals_offline(model):
    svo.test_fusion(model)


def test_cold_start_ignores_unfilled_slots(model):
    svo.test_cold_start_ignores_unfilled_slots(model)


def test_broken_cache_update_is_detected(model):
    svo.test_broken_cache_update_is_detected(model)


def test_ring_cache_shapes(model):
    ex = model.experts["upper"]
    a = ex.layers[0].attn
    slots = a.w if ex.step_form.ring else a.w - 1
    assert ex.init_cache(1)["layer0.xattn.k"].shape == (1, a.h, slots, a.hd)


@torch.no_grad()
def test_rows_at_different_steps(model):
    """A batched step whose rows are at different steps (streams that started at different times, the
    runtime's batching) equals each stream stepped alone: the ring slot, rotation and mask are per row."""
    cfg, ex, fuse = model.cfg, model.experts["hands"], model.fuse
    lag = max(cfg.history, cfg.audio_window, cfg.fuse_window) + 2    # row 0 has wrapped, row 1 has not
    T = lag + 6
    prev, audio, cond = svo.expert_inputs(cfg, T, B=2)
    hid = torch.randn(2, T, len(REGION_NAMES), cfg.d_model)

    def alone(b, t0, t1, ce, cf):
        outs = []
        for t in range(t0, t1):
            o, ce = ex.step(prev[b:b + 1, t], audio[b:b + 1, t], cond[b:b + 1], ce)
            of, cf = fuse.step({r: hid[b:b + 1, t, i] for i, r in enumerate(REGION_NAMES)}, audio[b:b + 1, t],
                               cond[b:b + 1], cf)
            outs.append((o["hidden"], of["logits"]))
        return outs, ce, cf

    # row 0 runs lag steps alone, then row 1 joins from zero caches; row 1 sees row 0's inputs shifted by lag
    _, ce0, cf0 = alone(0, 0, lag, ex.init_cache(1), fuse.init_cache(1))
    ref0, _, _ = alone(0, lag, T, ce0, cf0)
    ref1, _, _ = alone(1, 0, T - lag, ex.init_cache(1), fuse.init_cache(1))
    ce = {k: torch.cat([v, ex.init_cache(1)[k]]) for k, v in ce0.items()}
    cf = {k: torch.cat([v, fuse.init_cache(1)[k]]) for k, v in cf0.items()}
    for i, t in enumerate(range(lag, T)):
        o, ce = ex.step(torch.stack([prev[0, t], prev[1, i]]), torch.stack([audio[0, t], audio[1, i]]), cond, ce)
        of, cf = fuse.step({r: torch.stack([hid[0, t, j], hid[1, i, j]]) for j, r in enumerate(REGION_NAMES)},
                           torch.stack([audio[0, t], audio[1, i]]), cond, cf)
        for row, ref in ((0, ref0[i]), (1, ref1[i])):
            assert svo.max_err(o["hidden"][row], ref[0][0]) <= svo.BOUND, f"expert row {row} step {i}"
            assert svo.max_err(of["logits"][row], ref[1][0]) <= svo.BOUND, f"fusion row {row} step {i}"


def test_mask_tables_equal_the_computed_masks():
    for W in (5, 7, 32):
        step = torch.arange(3 * W)
        shift = StepTables(step, StepForm(masks="table")).bias(W)
        assert torch.equal(shift, window_bias(step, W))
        ring = StepTables(step, StepForm(cache_layout="ring")).bias(W)
        # ring slot j holds the step congruent to j mod W among the last W: written iff j <= min(step, W - 1)
        ring_valid = torch.arange(W)[None, :] <= torch.clamp(step, max=W - 1)[:, None]
        assert torch.equal(ring[:, 0] == 0, ring_valid) and torch.equal(mask_table(W, True)[W - 1], torch.zeros(1, W))


def test_ring_rotations_are_the_shift_rotations_in_slot_order():
    """Row s, slot j of the ring table is the shift form's rotation of the key (s - j) mod W tokens old."""
    W, hd = 7, 8
    q = torch.randn(hd, dtype=torch.float64)
    shift = (q.float() @ step_query_rotations(W, hd)).reshape(W, hd)        # block j: age W - 1 - j
    rot = ring_rotation_table(W, hd)
    half = hd // 2
    q_rh = torch.cat([-q[half:], q[:half]]).float()
    for s in range(W):
        ring = q.float() * rot[s, 0] + q_rh * rot[s, 1]                      # (W, hd), ring slot order
        for j in range(W):
            age = (s - j) % W
            assert torch.allclose(ring[j], shift[W - 1 - age], atol=1e-6), (s, j)


def export(model, out, rollout_tokens=12):
    return exporter.build_bundle(model, out, provenance={"training": "none (test)"}, reference_wav=None,
                                 ref_seconds=1.0, rollout_tokens=rollout_tokens, log=lambda *a: None)


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("forms")
    out = {}
    for name, form in (("shift", StepForm()), ("ring", FORMS["ring"]), ("table", FORMS["table"])):
        out[name] = (root / name, export(set_step_form(scrambled_model("tiny", seed=4), form), root / name))
    return out


def test_ring_export_writes_scatter_caches_with_w_slots(bundles):
    path, manifest = bundles["ring"]
    assert manifest["provenance"]["export"]["step_form"] == {"cache_layout": "ring", "masks": "compute"}
    shift = {g["name"]: g for g in bundles["shift"][1]["graphs"]}
    for g in manifest["graphs"]:
        ops = [n.op_type for n in onnx.load(path / g["file"]).graph.node]
        attn = [c for c in g["caches"] if c["name"].endswith((".k", ".v"))]
        if not attn:
            assert g["caches"] == shift[g["name"]]["caches"], g["name"]
            continue
        assert ops.count("ScatterND") == len(attn), g["name"]
        assert "Range" not in ops and "Where" not in ops, g["name"]
        for c, cs in zip(attn, [c for c in shift[g["name"]]["caches"] if c["name"].endswith((".k", ".v"))]):
            assert c["shape"][-2] == cs["shape"][-2] + 1, (g["name"], c["name"])


def test_table_masks_export_has_no_mask_arithmetic(bundles):
    path, manifest = bundles["table"]
    for g in manifest["graphs"]:
        ops = [n.op_type for n in onnx.load(path / g["file"]).graph.node]
        assert "Range" not in ops and "Where" not in ops, g["name"]


def test_forms_roll_out_the_same_tokens(bundles):
    """The reference rollouts (torch steps; the export checked onnxruntime against them) of the three forms
    have identical tokens and frames within float rounding."""
    ref = np.load(bundles["shift"][0] / "reference" / "rollout.npz")
    for name in ("ring", "table"):
        got = np.load(bundles[name][0] / "reference" / "rollout.npz")
        assert np.array_equal(ref["tokens"], got["tokens"]), name
        assert np.abs(ref["poses"] - got["poses"]).max() <= 1e-4, name


def test_cli_options_export_the_form_and_refuse_other_families(tmp_path, capsys):
    import json
    import jsonschema
    out = tmp_path / "ring"
    assert exporter.main(["--config", "tiny", "--out", str(out), "--cache-layout", "ring", "--step-masks", "table",
                          "--rollout-tokens", "6", "--reference-seconds", "1"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    jsonschema.validate(manifest, json.loads((ROOT / "export" / "manifest.schema.json").read_text()))
    assert manifest["provenance"]["export"]["step_form"] == {"cache_layout": "ring", "masks": "table"}
    k = next(c for g in manifest["graphs"] if g["name"] == "expert_upper" for c in g["caches"]
             if c["name"] == "layer0.xattn.k")
    assert k["shape"][-2] == 5   # tiny audio_window: W slots
    assert exporter.main(["--family", "diffsheg", "--config", "tiny", "--out", str(tmp_path / "d"),
                          "--cache-layout", "ring"]) == 2
    assert "LiveGesture step graphs" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
