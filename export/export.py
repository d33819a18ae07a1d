#!/usr/bin/env python
"""Export a LiveGesture checkpoint to a model bundle: stateful step ONNX graphs, manifest.json, reference vectors.

    python export/export.py --checkpoint runs/default/final.pt --out models/default
    python export/export.py --config tiny --random-seed 0 --out target/tiny-bundle          # random weights
    python export/export.py --config paper --random-seed 0 --out target/paper-bundle --rollout-tokens 16
    python export/export.py --family diffsheg --config tiny --random-seed 0 --out target/diffsheg-tiny
    python export/export.py --checkpoint runs/diffsheg/final.pt --out models/diffsheg    # family from the checkpoint
    python export/export.py --checkpoint runs/diffsheg/final.pt --out target/g3 --guidance 3   # DiffSHEG sampler defaults

The bundle is written to a temporary folder beside ``--out`` and moved into place only after every check
passed (see verify.py): a failed export leaves no half-written bundle. The format is documented in
docs/bundle.md and described by export/manifest.schema.json.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

if __name__ == "__main__" and not __package__:
    # run as a file (python export/export.py): run the package module, as `python -m export.export` from the
    # repository root does (the repository root instead of export/ first on the module path)
    import runpy
    sys.path[0] = str(Path(__file__).resolve().parents[1])
    runpy.run_module("export.export", run_name="__main__", alter_sys=True)
    raise SystemExit(0)

from livegesture import checkpoint as ckpt  # noqa: E402
from livegesture import families, variants  # noqa: E402
from livegesture.compare import diff  # noqa: E402
from livegesture.frontend import logmel  # noqa: E402
from livegesture.sampling import __doc__ as SAMPLER_DOC  # noqa: E402
from livegesture.stream import generate_clip  # noqa: E402

from livegesture.forms.decoders_fused import FUSED_DECODERS, check_fused_decoders  # noqa: E402
from livegesture.forms.experts_fused import FUSED_EXPERTS, check_fused_experts  # noqa: E402
from livegesture.forms.fusion_attention import ATTENTION_FORM, FUSION_ATTENTION, check_fusion_attention  # noqa: E402
from livegesture.forms.ring import RING_FORMS, is_ring_cache, ring_base, ring_graph, to_phase, write_entries  # noqa: E402
from livegesture.models.layers import worst_difference  # noqa: E402
from livegesture.models.layers import ATTENTION_DOMAIN  # noqa: E402

from .graphs import (ATTENTION_OPSET, StepGraph, attention_components, call_step, component, data_io,  # noqa: E402
                    fused_components, random_inputs, ring_components, to_attention_opset)
from .bundle_writer import (OPSET, SCHEMA_VERSION, absolute_paths, checkpoint_record, export_provenance,  # noqa: E402
                           file_table, manifest_head, reference_audio, relative_paths, save_stamped, sha256,
                           staged_folder, write_manifest, write_wav)
from .verify import (ExportCheckError, check_onnx_structure, check_ort_vs_torch, check_step_vs_offline,  # noqa: E402
                    fail)

REFERENCE_STEPS = 10
REFERENCE_BATCH = 2
ROLLOUT_SEED = 1234
FUSED_VS_CANONICAL = 1e-5    # torch fused form vs the canonical eXperts / decoders, every output and cache
ROLLOUT_FRAMES = 1e-4        # docs/parity.md, rollout frames
FORMS = ("canonical", "fused", "attention", "ring")
# the forms written by default: the ring forms (docs/bundle.md#ring-caches) only when asked for (--forms ...,ring)
DEFAULT_FORMS = ("canonical", "fused", "attention")
RING_PHASE0 = 7   # the phase of the reference vectors' first step (any: a ring graph reads its phase)
# The form each backend runs (docs/bundle.md#forms-and-precision). ort runs the fused eXperts: bit-identical to the canonical graphs on
# ort and faster. tract runs the canonical eXperts: its kernels round differently for another head count (like
# for another batch size), so the fused form's logits differ from the canonical form's by ~1e-7 on tract, which
# flips numerical near-ties of the sampler (the rollout of the tiny config's seed-0 weights has one at step 1044); see
# BENCHMARKS.md "Fused region forms". tract runs them in the attention form, with the fusion whose attention
# cores are the opset-23 Attention op (tract's fused kernel; slower on ort): BENCHMARKS.md "A tract form of the
# fusion".
DEFAULT_BACKEND_FORMS = {"ort": "fused", "tract": "attention"}


def cache_entries(comp, ring: bool = False) -> list[dict]:
    """The manifest's cache entries; a ring graph's attention caches also state ``output_shape``: the graph returns
    the new entry (one slot of axis -2), which the runtime writes at the phase (docs/bundle.md#ring-caches)."""
    out = []
    for s in comp.cache_specs():
        e = {"name": s.name, "input": f"cache.{s.name}", "output": f"new_cache.{s.name}", "dtype": s.dtype,
             "shape": ["batch", *s.shape], "init": s.init}
        if ring and is_ring_cache(s.name):
            e["output_shape"] = ["batch", *s.shape[:-2], 1, s.shape[-1]]
        out.append(e)
    return out


@torch.no_grad()
def check_ring_vs_shift(model, graph: str, steps: int, batch: int = 3, phase0: int = 5, seed: int = 0):
    """The ring graph's torch step against its shift-layout graph's over ``steps`` chained steps from the zero
    caches (entries written at consecutive phases from ``phase0``; a stream joins at another phase half way:
    its shift caches rotated in): every output and every cache (rotated back to the shift layout). Returns
    (max abs difference, output name, step, scale) of the worst comparison (:func:`worst_difference`)."""
    base = ring_base(graph)
    g = torch.Generator().manual_seed(seed)
    s_cache = component(model, base).init_cache(batch)
    r_cache = component(model, graph).init_cache(batch)
    phase = phase0
    worst = (-1.0, "", 0, 1.0)
    for t in range(steps):
        inp = random_inputs(model, base, batch, g)
        if t == 0 and "prev_token" in inp:
            inp["prev_token"][:] = model.cfg.bos_token
        if t == steps // 2:   # the stream's caches join a cohort at another phase
            r_cache = to_phase(s_cache, 0, phase + 11)
            phase += 11
        so, s_cache = call_step(model, base, inp, s_cache)
        ro, new = call_step(model, graph, {**inp, "phase": torch.full((batch,), phase)}, r_cache)
        r_cache = write_entries(r_cache, new, phase)
        phase += 1
        back = to_phase(r_cache, phase, 0)
        worst = worst_difference(worst, [(k, ro[k], so[k]) for k in so]
                                 + [(f"new_cache.{k}", back[k], s_cache[k]) for k in s_cache], t)
    return worst


def export_graph(model, graph: str, path: Path):
    import onnx
    wrapper = StepGraph(model, graph).eval()
    g = torch.Generator().manual_seed(0)
    inputs = random_inputs(model, graph, 2, g)
    cache = component(model, graph).init_cache(2)
    args = tuple(inputs[i["name"]] for i in wrapper.inputs) + tuple(cache[s.name] for s in wrapper.cache_specs)
    names_in, names_out = wrapper.input_names(), wrapper.output_names()
    dyn = {n: {0: "batch"} for n in names_in + names_out}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(wrapper, args, str(path), input_names=names_in, output_names=names_out,
                          dynamic_axes=dyn, opset_version=OPSET, do_constant_folding=True, dynamo=False,
                          custom_opsets={ATTENTION_DOMAIN: 1} if (graph in attention_components(model) or ring_base(graph)
                                                                 == FUSION_ATTENTION) else None)
    m = onnx.load(str(path))
    if any(n.domain == ATTENTION_DOMAIN for n in m.graph.node):
        try:
            to_attention_opset(m, graph)   # the AttentionOp nodes as the opset-23 Attention op
        except ValueError as e:
            raise ExportCheckError(str(e)) from None
    got_in = [i.name for i in m.graph.input]
    if got_in != names_in:
        raise ExportCheckError(f"graph '{graph}': exported inputs {got_in} differ from {names_in} "
                               "(an input the step does not use was dropped)")
    save_stamped(m, path, model, graph, component_name=type(component(model, graph)).__name__)


@torch.no_grad()
def graph_reference(model, graph: str, seed: int) -> dict[str, np.ndarray]:
    """Torch inputs and outputs over REFERENCE_STEPS chained steps (batch REFERENCE_BATCH), starting from the
    zero caches, and the caches after the last step: ``step{s}.input.<name>``, ``step{s}.output.<name>``,
    ``step{S-1}.new_cache.<name>`` (a ring graph: the caches after the entries were written at the phase)."""
    g = torch.Generator().manual_seed(seed)
    cache = component(model, graph).init_cache(REFERENCE_BATCH)
    out = {"n_steps": np.array(REFERENCE_STEPS), "batch": np.array(REFERENCE_BATCH)}
    ring = ring_base(graph) is not None
    for s in range(REFERENCE_STEPS):
        inp = random_inputs(model, graph, REFERENCE_BATCH, g)
        if (graph.startswith("expert_") or graph.startswith(FUSED_EXPERTS)) and s == 0:
            inp["prev_token"][:] = model.cfg.bos_token
        if ring:   # consecutive phases; the state is the caches after the runtime's write (docs/bundle.md#ring-caches)
            inp["phase"][:] = RING_PHASE0 + s
        o, new = call_step(model, graph, inp, cache)
        if ring:
            new = write_entries(cache, new, RING_PHASE0 + s)
        for k, v in inp.items():
            out[f"step{s}.input.{k}"] = v.numpy()
        for k, v in o.items():
            out[f"step{s}.output.{k}"] = v.numpy()
        if s == REFERENCE_STEPS - 1:   # the chained state after the last step (earlier ones are implied)
            for k, v in new.items():
                out[f"step{s}.new_cache.{k}"] = v.numpy()
        cache = new
    return out


def build_bundle(model, out: Path, *, provenance: dict, reference_wav: str | None, ref_seconds: float,
                 rollout_tokens: int, log=print, builder=None, **kw) -> dict:
    """Write the bundle into a temporary folder beside ``out``, then move it into place (atomic).
    ``builder(model, tmp, ...)`` writes the folder's contents: ``_build`` (LiveGesture) by default,
    ``diffsheg_export.build`` for the diffsheg family."""
    with staged_folder(out) as tmp:
        return (builder or _build)(model, tmp, provenance=provenance, reference_wav=reference_wav,
                                   ref_seconds=ref_seconds, rollout_tokens=rollout_tokens, log=log, **kw)


# long: the bundle's files in the order they are verified and written (graphs per form, reference clip, rollout, manifest)
def _build(model, tmp: Path, *, provenance, reference_wav, ref_seconds, rollout_tokens, log,
           forms=DEFAULT_FORMS, backend_forms: dict | None = None) -> dict:
    backend_forms = dict(backend_forms or DEFAULT_BACKEND_FORMS)
    cfg = model.cfg
    names = model.region_names
    if len(names) < 2:   # one region (the full-body SVQ): the canonical graphs are already one per component
        forms = tuple(f for f in forms if f != "fused")
    (tmp / "reference").mkdir()
    files, graphs, checks = {}, [], {}

    def export_checked(graph, comp, entry: dict) -> tuple[float, float]:
        """Export one graph, check its structure and ort vs torch, write its reference vectors and its
        manifest entry (``entry`` adds to it); returns the ort-vs-torch (error, scale) of the worst comparison."""
        path = tmp / f"{graph}.onnx"
        export_graph(model, graph, path)
        check_onnx_structure(str(path), graph, OPSET)
        e_ort = check_ort_vs_torch(model, graph, str(path))
        np.savez_compressed(tmp / "reference" / f"{graph}.npz", **graph_reference(model, graph, seed=len(graphs)))
        ins, outs = data_io(model, graph)
        graphs.append({"name": graph, "file": path.name, "component": type(comp).__name__, **entry,
                       "inputs": ins, "outputs": outs, "caches": cache_entries(comp, ring_base(graph) is not None),
                       "reference": f"reference/{graph}.npz"})
        return e_ort

    for graph, comp in model.components().items():
        t0 = time.time()
        e_off, s_off = check_step_vs_offline(model, graph)
        region = graph.split("_", 1)[1] if "_" in graph and graph != "audio_encoder" else None
        e_ort, s_ort = export_checked(graph, comp, {"region": region})
        checks[graph] = {"torch_step_vs_offline_max_abs": e_off, "torch_step_vs_offline_scale": s_off,
                         "ort_vs_torch_max_abs": e_ort, "ort_vs_torch_scale": s_ort}
        log(f"  {graph:<16} step-vs-offline {e_off:.2e} (scale {s_off:.3g})  ort-vs-torch {e_ort:.2e} "
            f"(scale {s_ort:.3g})  ({time.time() - t0:.1f}s)")

    # the fused forms (docs/bundle.md#forms-and-precision): checked against the canonical torch steps, then like every graph
    fused_graphs = []
    against = {FUSED_EXPERTS: (check_fused_experts, max(cfg.history, cfg.audio_window) + 5, "eXperts"),
               # past the longest conv cache (in frames; a token adds at least one frame to every cache)
               FUSED_DECODERS: (check_fused_decoders, max(s.shape[0] for s in
                                                          fused_components(model)[FUSED_DECODERS].cache_specs()) + 5,
                                "SVQ decoders")}
    for graph, comp in (fused_components(model).items() if "fused" in forms else ()):
        t0 = time.time()
        check, n_steps, what = against[graph]
        e_can, out_name, step, s_can = check(model, steps=n_steps)
        if not e_can <= FUSED_VS_CANONICAL * s_can:
            fail(graph, out_name, step, e_can, FUSED_VS_CANONICAL, f"torch fused form vs the canonical {what}", s_can)
        e_ort, s_ort = export_checked(graph, comp, {"region": None, "form": "fused"})
        fused_graphs.append(graph)
        checks[graph] = {"torch_fused_vs_canonical_max_abs": e_can, "torch_fused_vs_canonical_scale": s_can,
                         "ort_vs_torch_max_abs": e_ort, "ort_vs_torch_scale": s_ort}
        log(f"  {graph:<16} fused-vs-canonical {e_can:.2e} (scale {s_can:.3g})  ort-vs-torch {e_ort:.2e} "
            f"(scale {s_ort:.3g})  ({time.time() - t0:.1f}s)")

    attention_graphs = []   # after the fused forms: the earlier graphs' reference seeds stay as they were
    for graph, comp in (attention_components(model).items() if ATTENTION_FORM in forms else ()):
        # the attention form's fusion (docs/bundle.md#forms-and-precision): checked against the canonical torch fusion step, then like
        # every graph (its file is opset 23)
        t0 = time.time()
        e_can, out_name, step, s_can = check_fusion_attention(model, steps=max(cfg.fuse_window, cfg.audio_window) + 5)
        if not e_can <= FUSED_VS_CANONICAL * s_can:
            fail(graph, out_name, step, e_can, FUSED_VS_CANONICAL, "torch attention form vs the canonical fusion",
                 s_can)
        e_ort, s_ort = export_checked(graph, comp, {"region": None, "form": ATTENTION_FORM})
        attention_graphs.append(graph)
        checks[graph] = {"torch_form_vs_canonical_max_abs": e_can, "torch_form_vs_canonical_scale": s_can,
                         "ort_vs_torch_max_abs": e_ort, "ort_vs_torch_scale": s_ort}
        log(f"  {graph:<16} form-vs-canonical {e_can:.2e} (scale {s_can:.3g})  ort-vs-torch {e_ort:.2e} "
            f"(scale {s_ort:.3g})  ({time.time() - t0:.1f}s)")

    # the ring forms (docs/bundle.md#ring-caches): the ring variant of each graph with attention caches of the
    # forms written, checked against its shift-layout graph's torch step, then like every graph
    ring_forms = {}
    for rform, base_form in (RING_FORMS.items() if "ring" in forms else ()):
        if base_form not in forms or (base_form == "fused" and not fused_graphs) or (
                base_form == ATTENTION_FORM and not attention_graphs):
            continue
        shift = ([FUSED_EXPERTS, "fusion"] if base_form == "fused"
                 else [*(f"expert_{r}" for r in names), FUSION_ATTENTION])
        for base in shift:
            graph = ring_graph(base)
            if any(g["name"] == graph for g in graphs):
                continue
            t0 = time.time()
            steps = 2 * max(cfg.history, cfg.audio_window, cfg.fuse_window) + 3
            e_can, out_name, step, s_can = check_ring_vs_shift(model, graph, steps)
            if not e_can <= FUSED_VS_CANONICAL * s_can:
                fail(graph, out_name, step, e_can, FUSED_VS_CANONICAL, f"torch ring form vs the shift layout ({base})",
                     s_can)
            e_ort, s_ort = export_checked(graph, ring_components(model)[graph], {"region": None, "form": rform})
            checks[graph] = {"torch_form_vs_canonical_max_abs": e_can, "torch_form_vs_canonical_scale": s_can,
                             "torch_form_vs_canonical_against": base,
                             "ort_vs_torch_max_abs": e_ort, "ort_vs_torch_scale": s_ort}
            log(f"  {graph:<16} ring-vs-shift {e_can:.2e} (scale {s_can:.3g})  ort-vs-torch {e_ort:.2e} "
                f"(scale {s_ort:.3g})  ({time.time() - t0:.1f}s)")
        ring_forms[rform] = shift

    # reference clip, its log-mel frames, and a whole seeded rollout of >= rollout_tokens steps
    clip, clip_desc = reference_audio(reference_wav, ref_seconds)
    write_wav(tmp / "reference" / "clip.wav", clip)
    clip = (np.clip(np.round(clip * 32767), -32768, 32767) / 32768.0).astype(np.float32)  # what the wav holds
    np.save(tmp / "reference" / "logmel.npy", logmel(clip, cfg.frontend))
    per_token = cfg.frontend.frames_per_token * cfg.frontend.sample_rate / cfg.frontend.fps
    reps = max(1, int(np.ceil(rollout_tokens * per_token / len(clip))))
    rollout_audio = np.tile(clip, reps)
    t0 = time.time()
    ro = generate_clip(model, rollout_audio, seed=ROLLOUT_SEED)
    np.savez_compressed(tmp / "reference" / "rollout.npz", tokens=ro["tokens"], poses=ro["poses"],
                        trans=ro["trans"], expressions=ro["expressions"], foot_contact=ro["foot_contact"],
                        seed=np.array(ROLLOUT_SEED, dtype=np.uint64), clip_repeats=np.array(reps))
    log(f"  rollout          {len(ro['tokens'])} tokens in {time.time() - t0:.1f}s")
    forms_manifest = {"canonical": {"experts": [f"expert_{r}" for r in names],
                                    "decoders": [f"decoder_{r}" for r in names]}}

    def rollout_vs_canonical(form: str, form_graphs: list[str]) -> dict:
        """The torch rollout in ``form`` against the canonical one (docs/bundle.md#forms-and-precision): identical tokens, frames within
        ROLLOUT_FRAMES; returns the check's record."""
        t0 = time.time()
        rf = generate_clip(model, rollout_audio, seed=ROLLOUT_SEED, form=form)
        same = rf["tokens"] == ro["tokens"]
        if rf["tokens"].shape != ro["tokens"].shape or not same.all():
            bad = int(np.argwhere(~same)[0][0]) if rf["tokens"].shape == ro["tokens"].shape else 0
            raise ExportCheckError(f"torch rollout, {form} form vs canonical: graphs "
                                   f"{', '.join(map(repr, form_graphs))}, output 'tokens', step {bad}: tokens differ "
                                   f"({form} {rf['tokens'][bad].tolist()}, canonical {ro['tokens'][bad].tolist()})")
        # each frame field over the whole rollout, judged at its scale (docs/parity.md)
        worst = None
        for k in ("poses", "trans", "expressions", "foot_contact"):
            d = diff(rf[k], ro[k])
            if not d.within(ROLLOUT_FRAMES):
                fail(", ".join(form_graphs), f"rollout {k}", -1, d.max_abs, ROLLOUT_FRAMES,
                     f"torch rollout, {form} form vs canonical", d.scale, d.describe())
            worst = d if worst is None else worst.worst(d)
        e_frames = worst.max_abs
        log(f"  rollout {form:<8} {len(rf['tokens'])} tokens identical, frames max abs {e_frames:.2e} "
            f"({time.time() - t0:.1f}s)")
        return {"rollout_tokens_identical": int(len(ro["tokens"])), "rollout_frames_max_abs": e_frames}

    if fused_graphs:
        checks["forms"] = rollout_vs_canonical("fused", fused_graphs)
        forms_manifest["fused"] = {
            "experts": [FUSED_EXPERTS],
            "decoders": [FUSED_DECODERS],
            "region_axis": 1,
            "regions": list(names),
            "contract": "experts_fused runs the region eXperts at once: prev_token (batch, regions) int64, "
                        "audio and cond as expert_<region>; hidden (batch, regions, d_model), row r = expert_<r>'s "
                        "hidden; caches: step (batch,) shared by the regions; every attention cache is "
                        "(batch, regions * heads, window - 1, head_dim) where rows r * heads .. (r + 1) * heads of "
                        "axis 1 are expert_<r>'s cache of the same name (regions in region order). "
                        "decoders_fused runs the region SVQ decoders at once: token (batch, regions) int64, "
                        "column r = decoder_<r>'s token; motion (batch, frames_per_token, sum of the region dims), "
                        "columns off_r .. off_r + dim_r = decoder_<r>'s motion (off_r: the dims of the regions "
                        "before r); caches: decoder_<r>'s cache names, each (batch, frames, regions * channels) "
                        "where channels r * channels .. (r + 1) * channels of the last axis are decoder_<r>'s "
                        "cache of the same name",
        }
    if attention_graphs:
        # the checks record of each form's rollout: checks.forms (fused, the name predates other forms),
        # checks.forms_<form> for the others
        checks[f"forms_{ATTENTION_FORM}"] = rollout_vs_canonical(ATTENTION_FORM, attention_graphs)
        forms_manifest[ATTENTION_FORM] = {
            "experts": forms_manifest["canonical"]["experts"],
            "decoders": forms_manifest["canonical"]["decoders"],
            "fusion": FUSION_ATTENTION,
            "opset": ATTENTION_OPSET,
            "contract": "fusion_attention has the fusion graph's inputs, outputs and caches (names, shapes, "
                        "layouts); its attention cores are the opset-23 ONNX Attention op (4-D q/k/v, additive "
                        "float mask expanded to the query length, scale 1/sqrt(head_dim); the cached keys, stored "
                        "before rotation, are rotated back elementwise by their distance to the query). The file "
                        "is opset 23. The form runs the canonical eXperts and decoders",
        }

    ring_contract = ("the ring layout of the caches (docs/bundle.md#ring-caches): each graph <g>_ring has <g>'s inputs "
                     "then phase (batch,) int64, the cohort's write position c, the same in every row; its attention "
                     "caches are read-only inputs of <g>'s shapes whose slot axis (-2, W - 1 slots) is a ring: slot "
                     "j holds the entry ((c mod (W - 1)) - 1 - j) mod (W - 1) + 1 tokens old; new_cache.<name> is the "
                     "new entry (output_shape: one slot), which the caller writes into slot c mod (W - 1) before "
                     "stepping at c + 1; new_cache.step as in <g>. Caches at phase a move to phase b by rolling the "
                     "slot axis by (b - a) mod (W - 1); the shift layout is phase 0")
    for rform, shift in ring_forms.items():
        base = forms_manifest[RING_FORMS[rform]]
        forms_manifest[rform] = {
            "experts": [ring_graph(g) if ring_graph(g) in {x["name"] for x in graphs} else g
                        for g in base["experts"]],
            "decoders": base["decoders"],
            "fusion": ring_graph(base.get("fusion", "fusion")),
            "ring": True,
            **({"opset": base["opset"]} if "opset" in base else {}),
            "contract": f"the {RING_FORMS[rform]} form on ring caches: " + ring_contract,
        }

    files.update(file_table(tmp))
    manifest = {
        **manifest_head("livegesture", "LiveGesture", cfg, model, {
            "tokens_per_second": cfg.frontend.fps / cfg.frontend.frames_per_token,
            "frame_start_sample": "k * sample_rate // fps"}),
        "vocab": {"codebook_size": cfg.codebook_size, "bos_token": cfg.bos_token, "mask_token": cfg.mask_token},
        "graphs": graphs,
        "pipeline": {
            "order": ["audio_encoder", *[f"expert_{r}" for r in names], "fusion", "sample",
                      *[f"decoder_{r}" for r in names]],
            "guidance_branches": "expert_* and fusion run both branches on the batch axis: cond=1 (conditional) "
                                 "and cond=0 (unconditional, null audio); audio_encoder and decoder_* run once per stream",
            "first_prev_token": "bos_token",
        },
        "forms": forms_manifest,
        "backend_forms": {b: (f if f in forms_manifest else "canonical") for b, f in backend_forms.items()},
        "normalisation": model.normalisation(),
        "sampling": {"guidance": cfg.guidance, "temperature": cfg.temperature, "top_k": cfg.top_k,
                     "guidance_disabled_when": "guidance == 1.0 (no unconditional branch)",
                     "region_order": list(names), "prng": "splitmix64", "definition": SAMPLER_DOC.strip()},
        "reference": {"graphs": {g["name"]: g["reference"] for g in graphs}, "steps": REFERENCE_STEPS,
                      "batch": REFERENCE_BATCH, "clip": "reference/clip.wav", "clip_source": clip_desc,
                      "clip_seconds": round(len(clip) / 16000, 3), "logmel": "reference/logmel.npy",
                      "rollout": "reference/rollout.npz", "rollout_seed": ROLLOUT_SEED,
                      "rollout_audio": f"reference/clip.wav repeated {reps} times",
                      "rollout_tokens": int(len(ro["tokens"])), "rollout_guidance": cfg.guidance},
        "checks": checks,
        "files": files,
        "provenance": {**provenance, "export": export_provenance()},
    }
    write_manifest(tmp, manifest)
    return manifest


# long: the command's arguments and the export steps they select, in order
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="trained checkpoint (.pt) written by livegesture.train")
    src.add_argument("--config", help="export random weights of this config (tiny, default, paper)")
    ap.add_argument("--random-seed", type=int, default=0, help="seed of the random weights (with --config)")
    ap.add_argument("--variant", default=None, help="with --config: a variant of the model (livegesture.variants; "
                                                   "a checkpoint records its own)")
    ap.add_argument("--family", choices=families.NAMES, default=None,
                    help=f"model family of --config (default {families.DEFAULT.name}); a checkpoint names its own family")
    ap.add_argument("--out", required=True, help="bundle folder to write (replaced atomically)")
    ap.add_argument("--reference-wav", help="reference speech clip (default: a synthetic speech-like signal)")
    ap.add_argument("--reference-seconds", type=float, default=30.0)
    ap.add_argument("--rollout-tokens", type=int, default=1000, help="length of the reference rollout (>= 1000 for CI)")
    ap.add_argument("--rollout-windows", type=int, default=5,
                    help="diffsheg: FOPPAS windows of the reference rollout (>= 4; the last one is shorter)")
    ap.add_argument("--forms", default=",".join(DEFAULT_FORMS),
                    help="graph forms to write (docs/bundle.md#forms-and-precision): canonical (always), fused (the four eXperts as one "
                         "graph on a region axis, the four SVQ decoders as one graph), attention (the fusion "
                         "with the opset-23 Attention op, fusion_attention) and ring (the forms fused_ring and "
                         "attention_ring of the forms written: their graphs on ring caches, docs/bundle.md#ring-caches); "
                         "default canonical,fused,attention")
    ap.add_argument("--backend-forms", default=",".join(f"{b}={f}" for b, f in DEFAULT_BACKEND_FORMS.items()),
                    help="the form each backend runs by default, e.g. ort=fused,tract=attention (a form not "
                         "written falls back to canonical)")
    ap.add_argument("--guidance", type=float, default=None,
                    help="diffsheg: the bundle's default classifier-free guidance scale (manifest "
                         "diffusion.guidance.scale; default: the checkpoint config's)")
    ap.add_argument("--jumps", type=int, default=None,
                    help="diffsheg: the bundle's default RePaint jumps per DDIM step (manifest foppas.jumps; "
                         "default: the checkpoint config's)")
    ap.add_argument("--provenance", help="JSON file merged into the manifest's provenance (training data "
                                         "description, evaluation figures, commands)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    if args.checkpoint and args.variant:
        print(f"export failed: --variant {args.variant}: a checkpoint records its own variant (use it with --config)",
              file=sys.stderr)
        return 2
    if args.checkpoint:
        try:
            model = ckpt.load(args.checkpoint)
        except (OSError, ValueError) as e:
            print(f"export failed: {e}", file=sys.stderr)
            return 2
        if args.family and families.get(args.family) is not families.of_model(model):
            print(f"export failed: --family {args.family} but {args.checkpoint} is a "
                  f"{families.of_model(model).name} checkpoint", file=sys.stderr)
            return 2
        provenance = dict(getattr(model, "provenance", {}))
        trained_as = provenance.pop("checkpoint", None)
        if trained_as is not None and trained_as != Path(args.checkpoint).name:
            provenance["checkpoint_when_trained"] = trained_as
    else:
        try:
            fam = families.get(args.family)
            cfg = variants.apply(fam.get_config(args.config), fam.name, args.variant)
            model = ckpt.random_model(cfg, args.random_seed, family=fam.name)
        except ValueError as e:
            print(f"export failed: {e}", file=sys.stderr)
            return 2
        provenance = {"training": f"none: random weights (config {args.config}, seed {args.random_seed}); "
                                  "for tests and benchmarks only, produces meaningless motion"}
    if args.provenance:
        try:
            provenance.update(json.loads(Path(args.provenance).read_text()))
        except (OSError, ValueError) as e:
            print(f"export failed: --provenance {args.provenance}: {e}", file=sys.stderr)
            return 2
    if args.checkpoint:
        # the checkpoint by file name and content, never by a path of this machine
        provenance["checkpoint"] = checkpoint_record(Path(args.checkpoint))
    provenance["export_command"] = " ".join(["python export/export.py", *(sys.argv[1:] if argv is None else argv)])
    # a bundle names files, never where they were on the machine that trained or exported it
    provenance = relative_paths(provenance)
    out = Path(args.out).resolve()
    fam = families.of_model(model)
    family = fam.name
    sampler = {k: v for k, v in (("guidance", args.guidance), ("jumps", args.jumps)) if v is not None}
    if sampler:
        if not set(sampler) <= set(fam.export_options):
            print(f"export failed: --{' / --'.join(sampler)} set a DiffSHEG bundle's sampler defaults; "
                  f"this is a {family} model", file=sys.stderr)
            return 2
        import dataclasses
        from livegesture.diffsheg.foppas import SamplerOptions
        cfg = dataclasses.replace(model.cfg, **sampler)
        try:
            SamplerOptions.from_config(cfg)
        except ValueError as e:
            print(f"export failed: {e}", file=sys.stderr)
            return 2
        provenance["sampler_defaults"] = {
            "set_at_export": sampler, "model_config": {k: getattr(model.cfg, k) for k in sampler},
            "meaning": "the model's config (trained with) had the model_config values as its sampling defaults; "
                       "export --guidance/--jumps wrote set_at_export into model.config, the diffusion and foppas "
                       "sections and the reference rollout instead (sampling only, the weights are unchanged)"}
        model.cfg = cfg
    out.parent.mkdir(parents=True, exist_ok=True)
    print(f"exporting {family} {model.cfg.name} -> {out}")
    forms = [f.strip() for f in args.forms.split(",") if f.strip()]
    if "canonical" not in forms or any(f not in FORMS for f in forms):
        print(f"export failed: --forms {args.forms}: expected canonical[,fused][,attention][,ring]", file=sys.stderr)
        return 2
    try:
        backend_forms = dict(kv.split("=", 1) for kv in args.backend_forms.split(",") if kv.strip())
    except ValueError:
        backend_forms = None
    if (not backend_forms or set(backend_forms) - {"ort", "tract"}
            or any(f not in (*FORMS, *RING_FORMS) or f == "ring" for f in backend_forms.values())):
        print(f"export failed: --backend-forms {args.backend_forms}: expected BACKEND=FORM pairs "
              f"(backends ort, tract; forms {', '.join(f for f in (*FORMS, *RING_FORMS) if f != 'ring')})",
              file=sys.stderr)
        return 2
    given = {"forms": tuple(forms), "backend_forms": backend_forms, "rollout_windows": args.rollout_windows}
    kw = {"builder": fam.resolve(fam.exporter), **{k: given[k] for k in fam.export_options if k in given}}
    try:
        build_bundle(model, out, provenance=provenance, reference_wav=args.reference_wav,
                     ref_seconds=args.reference_seconds, rollout_tokens=args.rollout_tokens, **kw)
    except ExportCheckError as e:
        print(f"export failed: {e}", file=sys.stderr)
        return 1
    print(f"ok: {out}/manifest.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
