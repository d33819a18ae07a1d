"""Step graphs: wrap each component's ``step`` as a module with flat, named inputs and outputs.

Naming (the contract with the runtime, recorded in manifest.json):
  data inputs        audio_encoder: mel | expert_<r>: prev_token, audio, cond |
                     experts_fused (SPEC 14 fused form of the four eXperts): prev_token (B, R), audio, cond |
                     fusion: hidden_upper, hidden_hands, hidden_lower, hidden_face, audio, cond |
                     decoder_<r>: token | decoders_fused (SPEC 14 fused form of the four decoders): token (B, R)
  data outputs       audio | hidden | logits | motion
  caches             input ``cache.<name>``, output ``new_cache.<name>``, in the component's cache_specs order
"""
from __future__ import annotations

import torch
import torch.nn as nn

from livegesture.models.fused import FUSED_EXPERTS, FusedExperts
from livegesture.models.fused_decoders import FUSED_DECODERS, FusedDecoders
from livegesture.models.model import LiveGesture
from livegesture.regions import REGION_NAMES


def fused_components(model: LiveGesture) -> dict[str, nn.Module]:
    """The fused forms (SPEC 14) by graph name: ``experts_fused``, the four eXperts on a region axis, and
    ``decoders_fused``, the four SVQ decoders side by side. Built from the model's current weights (a copy);
    cached on the model so every export step sees one module."""
    cached = getattr(model, "_fused_components", None)
    if cached is None:
        cached = {FUSED_EXPERTS: FusedExperts([model.experts[r] for r in REGION_NAMES]).eval(),
                  FUSED_DECODERS: FusedDecoders([model.svq[r] for r in REGION_NAMES]).eval()}
        object.__setattr__(model, "_fused_components", cached)
    return cached


def component(model: LiveGesture, graph: str) -> nn.Module:
    """The step component of a canonical graph (``model.components()``) or of a fused form."""
    comps = model.components()
    if graph in comps:
        return comps[graph]
    fused = fused_components(model)
    if graph in fused:
        return fused[graph]
    raise ValueError(f"unknown graph {graph!r}")


def data_io(model: LiveGesture, graph: str) -> tuple[list[dict], list[dict]]:
    """(inputs, outputs) of a graph without caches: dicts {name, dtype, shape} with 'batch' on axis 0."""
    cfg = model.cfg
    d, Da, K = cfg.d_model, cfg.audio_dim, cfg.codebook_size
    f32, i64 = "float32", "int64"
    if graph == "audio_encoder":
        return ([{"name": "mel", "dtype": f32, "shape": ["batch", cfg.frontend.mel_frames_per_token, cfg.frontend.n_mels]}],
                [{"name": "audio", "dtype": f32, "shape": ["batch", Da]}])
    if graph.startswith("expert_"):
        return ([{"name": "prev_token", "dtype": i64, "shape": ["batch"]},
                 {"name": "audio", "dtype": f32, "shape": ["batch", Da]},
                 {"name": "cond", "dtype": f32, "shape": ["batch"]}],
                [{"name": "hidden", "dtype": f32, "shape": ["batch", d]}])
    if graph == FUSED_EXPERTS:
        R = len(REGION_NAMES)
        return ([{"name": "prev_token", "dtype": i64, "shape": ["batch", R]},
                 {"name": "audio", "dtype": f32, "shape": ["batch", Da]},
                 {"name": "cond", "dtype": f32, "shape": ["batch"]}],
                [{"name": "hidden", "dtype": f32, "shape": ["batch", R, d]}])
    if graph == "fusion":
        return ([{"name": f"hidden_{r}", "dtype": f32, "shape": ["batch", d]} for r in REGION_NAMES]
                + [{"name": "audio", "dtype": f32, "shape": ["batch", Da]},
                   {"name": "cond", "dtype": f32, "shape": ["batch"]}],
                [{"name": "logits", "dtype": f32, "shape": ["batch", len(REGION_NAMES), K]}])
    if graph == FUSED_DECODERS:
        return ([{"name": "token", "dtype": i64, "shape": ["batch", len(REGION_NAMES)]}],
                [{"name": "motion", "dtype": f32, "shape": ["batch", cfg.frontend.frames_per_token,
                                                           sum(model.svq[r].d_in for r in REGION_NAMES)]}])
    if graph.startswith("decoder_"):
        r = graph[len("decoder_"):]
        return ([{"name": "token", "dtype": i64, "shape": ["batch"]}],
                [{"name": "motion", "dtype": f32, "shape": ["batch", cfg.frontend.frames_per_token, model.svq[r].d_in]}])
    raise ValueError(f"unknown graph {graph!r}")


def call_step(model: LiveGesture, graph: str, inputs: dict, cache: dict) -> tuple[dict, dict]:
    """Run a component's torch step with named inputs."""
    comp = component(model, graph)
    if graph == "audio_encoder":
        return comp.step(inputs["mel"], cache)
    if graph.startswith("expert_") or graph == FUSED_EXPERTS:
        return comp.step(inputs["prev_token"], inputs["audio"], inputs["cond"], cache)
    if graph == "fusion":
        return comp.step({r: inputs[f"hidden_{r}"] for r in REGION_NAMES}, inputs["audio"], inputs["cond"], cache)
    return comp.step(inputs["token"], cache)


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
        elif name == "cond":
            out[name] = torch.tensor([1.0 if i % 2 == 0 else 0.0 for i in range(batch)])
        elif name == "mel":
            out[name] = torch.randn(shape, generator=gen) * 2.0 - 6.0
        else:
            out[name] = torch.randn(shape, generator=gen)
    return out
