"""Step graphs: wrap each component's ``step`` as a module with flat, named inputs and outputs.

Naming (the contract with the runtime, recorded in manifest.json):
  data inputs        audio_encoder: mel | expert_<r>: prev_token, audio, cond |
                     experts_fused (docs/bundle.md#forms-and-precision fused form of the four eXperts): prev_token (B, R), audio, cond |
                     fusion: hidden_upper, hidden_hands, hidden_lower, hidden_face, audio, cond |
                     fusion_attention (docs/bundle.md#forms-and-precision form ``attention``): fusion's inputs |
                     decoder_<r>: token | decoders_fused (docs/bundle.md#forms-and-precision fused form of the four decoders): token (B, R) |
                     <graph>_ring (docs/bundle.md#ring-caches, the ring variant of expert_<r>, experts_fused, fusion,
                     fusion_attention): <graph>'s inputs, then phase (B,) int64 (the cohort's write position, the
                     same in every row)
  data outputs       audio | hidden | logits | motion
  caches             input ``cache.<name>``, output ``new_cache.<name>``, in the component's cache_specs order (a ring
                     graph returns the new entry of each attention cache, one slot, as ``new_cache.<name>``)
"""
from __future__ import annotations

import torch
import torch.nn as nn

from livegesture.forms.experts_fused import FUSED_EXPERTS, FusedExperts
from livegesture.forms.decoders_fused import FUSED_DECODERS, FusedDecoders
from livegesture.forms.fusion_attention import FUSION_ATTENTION, FusionAttention
from livegesture.forms.ring import RingStep, ring_base, ring_graph
from livegesture.models.layers import ATTENTION_DOMAIN
from livegesture.models.model import LiveGesture


def fused_components(model: LiveGesture) -> dict[str, nn.Module]:
    """The fused forms (docs/bundle.md#forms-and-precision) by graph name: ``experts_fused``, the four eXperts on a region axis, and
    ``decoders_fused``, the four SVQ decoders side by side. Built from the model's current weights (a copy);
    cached on the model so every export step sees one module."""
    cached = getattr(model, "_fused_components", None)
    if cached is None:
        cached = {FUSED_EXPERTS: FusedExperts([model.experts[r] for r in model.region_names]).eval(),
                  FUSED_DECODERS: FusedDecoders([model.svq[r] for r in model.region_names]).eval()}
        object.__setattr__(model, "_fused_components", cached)
    return cached


def attention_components(model: LiveGesture) -> dict[str, nn.Module]:
    """The ``attention`` form's own graphs (docs/bundle.md#forms-and-precision) by graph name: ``fusion_attention``, the model's fusion
    with its attention cores as the ONNX ``Attention`` op (cached on the model like :func:`fused_components`)."""
    cached = getattr(model, "_attention_components", None)
    if cached is None:
        cached = {FUSION_ATTENTION: FusionAttention(model.fuse).eval()}
        object.__setattr__(model, "_attention_components", cached)
    return cached


def ring_components(model: LiveGesture) -> dict[str, nn.Module]:
    """The ring variants (docs/bundle.md#ring-caches) of the graphs that carry attention caches, by graph name:
    ``expert_<r>_ring``, ``experts_fused_ring``, ``fusion_ring``, ``fusion_attention_ring`` (:class:`RingStep`
    around the shift-layout component; cached on the model like :func:`fused_components`)."""
    cached = getattr(model, "_ring_components", None)
    if cached is None:
        shift = {f"expert_{r}": model.experts[r] for r in model.region_names}
        shift["fusion"] = model.fuse
        shift[FUSED_EXPERTS] = fused_components(model)[FUSED_EXPERTS]
        shift[FUSION_ATTENTION] = attention_components(model)[FUSION_ATTENTION]
        cached = {ring_graph(g): RingStep(c).eval() for g, c in shift.items()}
        object.__setattr__(model, "_ring_components", cached)
    return cached


def component(model: LiveGesture, graph: str) -> nn.Module:
    """The step component of a canonical graph (``model.components()``) or of another form's graph."""
    comps = model.components()
    if graph in comps:
        return comps[graph]
    for forms in (fused_components(model), attention_components(model)):
        if graph in forms:
            return forms[graph]
    if ring_base(graph) is not None and graph in ring_components(model):
        return ring_components(model)[graph]
    raise ValueError(f"unknown graph {graph!r}")


ATTENTION_OPSET = 23
# Ops of the fusion graph whose schema changed between opset 17 and 23 only by accepting more types (Cast and
# Constant: float8/int4/float4 types; Identity, Reshape, Squeeze, Unsqueeze, Transpose: the same), or, for Split, by the
# optional attribute num_outputs (opset 18), which our Splits do not need: they have the ``split`` input.
_SAME_MEANING_17_TO_23 = {"Cast", "Constant", "Identity", "Reshape", "Squeeze", "Unsqueeze", "Transpose", "Split"}


def to_attention_opset(m, graph: str):
    """Rewrites an exported opset-17 graph holding :class:`livegesture.models.layers.AttentionOp` nodes (domain
    ``livegesture.attention``) into an opset-23 graph with the standard ``Attention`` op: the nodes move to the
    default domain and the opset import becomes 23. Every other op must mean the same at opset 23 as at 17
    (its schema unchanged, or in ``_SAME_MEANING_17_TO_23``; a Split must have its ``split`` input), else a
    ValueError names the op. The model is changed in place."""
    from onnx import defs
    for n in m.graph.node:
        if n.domain == ATTENTION_DOMAIN:
            if n.op_type != "Attention":
                raise ValueError(f"graph '{graph}': unexpected op {n.op_type} in domain {ATTENTION_DOMAIN}")
            n.domain = ""
            continue
        if n.domain not in ("", "ai.onnx"):
            raise ValueError(f"graph '{graph}': op {n.domain}::{n.op_type} outside the default domain")
        if defs.get_schema(n.op_type, 17).since_version != defs.get_schema(n.op_type, ATTENTION_OPSET).since_version:
            if n.op_type not in _SAME_MEANING_17_TO_23 or (n.op_type == "Split" and len(n.input) < 2):
                raise ValueError(f"graph '{graph}': op {n.op_type} ({n.name}) changed between opset 17 and "
                                 f"{ATTENTION_OPSET}; the opset-23 rewrite does not know it")
    imports = [o for o in m.opset_import if o.domain not in ("", "ai.onnx", ATTENTION_DOMAIN)]
    del m.opset_import[:]
    m.opset_import.extend(imports)
    o = m.opset_import.add()
    o.domain, o.version = "", ATTENTION_OPSET
    m.ir_version = max(m.ir_version, 10)   # IR 10: opset 23 loads on onnxruntime 1.31 and tract 0.23


def data_io(model: LiveGesture, graph: str) -> tuple[list[dict], list[dict]]:
    """(inputs, outputs) of a graph without caches: dicts {name, dtype, shape} with 'batch' on axis 0."""
    cfg = model.cfg
    d, Da, K = cfg.d_model, cfg.audio_dim, cfg.codebook_size
    f32, i64 = "float32", "int64"
    base = ring_base(graph)
    if base is not None:   # a ring graph: its shift-layout graph's, and the phase (docs/bundle.md#ring-caches)
        ins, outs = data_io(model, base)
        return ins + [{"name": "phase", "dtype": i64, "shape": ["batch"]}], outs
    if graph == "audio_encoder":
        return ([{"name": "mel", "dtype": f32, "shape": ["batch", cfg.frontend.mel_frames_per_token, cfg.frontend.n_mels]}],
                [{"name": "audio", "dtype": f32, "shape": ["batch", Da]}])
    if graph.startswith("expert_"):
        return ([{"name": "prev_token", "dtype": i64, "shape": ["batch"]},
                 {"name": "audio", "dtype": f32, "shape": ["batch", Da]},
                 {"name": "cond", "dtype": f32, "shape": ["batch"]}],
                [{"name": "hidden", "dtype": f32, "shape": ["batch", d]}])
    if graph == FUSED_EXPERTS:
        R = len(model.region_names)
        return ([{"name": "prev_token", "dtype": i64, "shape": ["batch", R]},
                 {"name": "audio", "dtype": f32, "shape": ["batch", Da]},
                 {"name": "cond", "dtype": f32, "shape": ["batch"]}],
                [{"name": "hidden", "dtype": f32, "shape": ["batch", R, d]}])
    if graph in ("fusion", FUSION_ATTENTION):
        # a fusion without audio cross-attention (variants no-fuse-audio, experts-only) reads no audio or cond:
        # the graph has no such inputs, and the runtime feeds the inputs the manifest lists
        audio = ([{"name": "audio", "dtype": f32, "shape": ["batch", Da]}, {"name": "cond", "dtype": f32, "shape": ["batch"]}]
                 if model.fuse.uses_audio else [])
        return ([{"name": f"hidden_{r}", "dtype": f32, "shape": ["batch", d]} for r in model.region_names] + audio,
                [{"name": "logits", "dtype": f32, "shape": ["batch", len(model.region_names), K]}])
    if graph == FUSED_DECODERS:
        return ([{"name": "token", "dtype": i64, "shape": ["batch", len(model.region_names)]}],
                [{"name": "motion", "dtype": f32, "shape": ["batch", cfg.frontend.frames_per_token,
                                                           sum(model.svq[r].d_in for r in model.region_names)]}])
    if graph.startswith("decoder_"):
        r = graph[len("decoder_"):]
        return ([{"name": "token", "dtype": i64, "shape": ["batch"]}],
                [{"name": "motion", "dtype": f32, "shape": ["batch", cfg.frontend.frames_per_token, model.svq[r].d_in]}])
    raise ValueError(f"unknown graph {graph!r}")


def call_step(model: LiveGesture, graph: str, inputs: dict, cache: dict) -> tuple[dict, dict]:
    """Run a component's torch step with named inputs. A ring graph (docs/bundle.md#ring-caches) reads its
    caches in ring order at ``inputs['phase'][0]`` and returns the new entries of its attention caches."""
    comp = component(model, graph)
    base = ring_base(graph)
    if base is not None:
        phase = inputs["phase"][0]
        step = lambda *a: comp.step(*a, cache=cache, phase=phase)  # noqa: E731
        graph = base
    else:
        step = lambda *a: comp.step(*a, cache)  # noqa: E731
    if graph == "audio_encoder":
        return step(inputs["mel"])
    if graph.startswith("expert_") or graph == FUSED_EXPERTS:
        return step(inputs["prev_token"], inputs["audio"], inputs["cond"])
    if graph in ("fusion", FUSION_ATTENTION):
        hidden = {r: inputs[f"hidden_{r}"] for r in model.region_names}
        if "audio" not in inputs:    # a fusion that reads no audio (data_io): any audio gives the same step
            B = hidden[model.region_names[0]].shape[0]
            inputs = {**inputs, "audio": torch.zeros(B, model.cfg.audio_dim), "cond": torch.ones(B)}
        return step(hidden, inputs["audio"], inputs["cond"])
    return step(inputs["token"])


class StepGraph(nn.Module):
    """forward(*data_inputs, *caches) -> (*data_outputs, *new_caches), for torch.onnx.export."""

    def __init__(self, model: LiveGesture, graph: str):
        super().__init__()
        self.model, self.graph = model, graph
        self.inputs, self.outputs = data_io(model, graph)
        self.comp = component(model, graph)   # registered, so a fused form's weights are module state
        self.cache_specs = self.comp.cache_specs()

    def input_names(self):
        return [i["name"] for i in self.inputs] + [f"cache.{s.name}" for s in self.cache_specs]

    def output_names(self):
        return [o["name"] for o in self.outputs] + [f"new_cache.{s.name}" for s in self.cache_specs]

    def forward(self, *args):
        n = len(self.inputs)
        inputs = {spec["name"]: a for spec, a in zip(self.inputs, args[:n])}
        cache = {s.name: a for s, a in zip(self.cache_specs, args[n:])}
        out, new = call_step(self.model, self.graph, inputs, cache)
        return tuple(out[o["name"]] for o in self.outputs) + tuple(new[s.name] for s in self.cache_specs)


def random_inputs(model: LiveGesture, graph: str, batch: int, gen: torch.Generator) -> dict:
    """Plausible random data inputs for one step of a graph."""
    cfg = model.cfg
    out = {}
    for spec in data_io(model, graph)[0]:
        shape = [batch if s == "batch" else s for s in spec["shape"]]
        name = spec["name"]
        if name in ("prev_token", "token"):
            out[name] = torch.randint(0, cfg.codebook_size, shape, generator=gen)
        elif name == "phase":   # one write position for every row (the cohort's)
            out[name] = torch.full(shape, int(torch.randint(0, 1000, (1,), generator=gen)), dtype=torch.int64)
        elif name == "cond":
            out[name] = torch.tensor([1.0 if i % 2 == 0 else 0.0 for i in range(batch)])
        elif name == "mel":
            out[name] = torch.randn(shape, generator=gen) * 2.0 - 6.0
        else:
            out[name] = torch.randn(shape, generator=gen)
    return out
