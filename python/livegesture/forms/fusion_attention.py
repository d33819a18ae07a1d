"""The ``attention`` form of the fusion (docs/bundle.md#forms-and-precision): ``fusion`` with its attention cores as the ONNX
``Attention`` op (opset 23).

The canonical ``fusion`` graph computes every attention core from elementwise products, ReduceSums and small
MatMuls (``WindowedAttention.step``, ``_step_queries``, ``SpatialAttention.step``), the form onnxruntime runs
fastest. tract 0.23 runs the opset-23 ``Attention`` op as one kernel, several times faster than those nodes for
the fusion's cross-attention, while onnxruntime 1.31 runs it slower: so the bundle carries both, and the
manifest's ``backend_forms`` says which fusion each backend runs (BENCHMARKS.md, "A tract form of the fusion").

Contract (recorded in the manifest's ``forms.attention``): graph ``fusion_attention`` has the canonical
``fusion`` graph's inputs, outputs and caches (names, shapes, layouts: keys cached before rotation); only the
graph's arithmetic differs: the cached keys are rotated back elementwise by their distance to the query and
each attention core is one ``Attention`` node (4-D q/k/v, additive float mask, scale 1/sqrt(head_dim); the
spatial attention has no mask). The ``attention`` form runs the canonical eXperts and decoders.

The weights are the model's own fusion (``XARFuse``); :func:`check_fusion_attention` compares the form with the
canonical fusion step.
"""
from __future__ import annotations

import torch
import torch.nn as nn

from ..models.fuse import XARFuse
from ..models.layers import CacheSpec, worst_difference

FUSION_ATTENTION = "fusion_attention"
ATTENTION_FORM = "attention"


class FusionAttention(nn.Module):
    """``fuse``'s step with the attention cores as the ONNX ``Attention`` op (module docs)."""

    name = FUSION_ATTENTION

    def __init__(self, fuse: XARFuse):
        super().__init__()
        self.fuse = fuse
        self.cfg = fuse.cfg

    def cache_specs(self) -> list[CacheSpec]:
        return self.fuse.cache_specs()

    def init_cache(self, batch: int, device=None) -> dict:
        return self.fuse.init_cache(batch, device)

    def step(self, hidden: dict, audio: torch.Tensor, cond: torch.Tensor, cache: dict):
        """As ``XARFuse.step``: hidden {region: (B, d)}, audio (B, audio_dim), cond (B,) -> ({'logits'}, new_cache)."""
        return self.fuse.step(hidden, audio, cond, cache, attention_op=True)


@torch.no_grad()
def check_fusion_attention(model, steps: int, batch: int = 2, seed: int = 0) -> tuple[float, str, int, float]:
    """Compares :class:`FusionAttention` with the canonical fusion step over ``steps`` chained steps from the zero
    caches with random inputs: the logits and every cache. Returns the max abs difference and where it occurred
    (output name, step)."""
    fuse = model.fuse.eval()
    form = FusionAttention(fuse).eval()
    cfg = model.cfg
    g = torch.Generator().manual_seed(seed)
    c_cache, a_cache = fuse.init_cache(batch), form.init_cache(batch)
    cond = torch.tensor([1.0 if i % 2 == 0 else 0.0 for i in range(batch)])
    worst = (-1.0, "logits", 0, 1.0)
    for s in range(steps):
        hidden = {r: torch.randn(batch, cfg.d_model, generator=g) for r in model.region_names}
        audio = torch.randn(batch, cfg.audio_dim, generator=g)
        co, c_cache = fuse.step(hidden, audio, cond, c_cache)
        ao, a_cache = form.step(hidden, audio, cond, a_cache)
        pairs = [("logits", ao["logits"], co["logits"])] + [(f"new_cache.{k}", a_cache[k], c_cache[k]) for k in c_cache]
        worst = worst_difference(worst, pairs, s)
    return worst
