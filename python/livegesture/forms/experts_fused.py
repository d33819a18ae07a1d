"""Fused region forms (docs/bundle.md#forms-and-precision): the four region eXperts as one step graph on a region axis.

The canonical form runs one ``expert_<region>`` graph per region, about 150 small nodes each, and a
LiveGesture token on the ``default`` config is bound by per-node dispatch. :class:`FusedExperts` computes
exactly the four eXperts' steps on a leading region axis: every elementwise, normalisation and attention node runs
once for the four regions. The linear layers are one Split, a MatMul + Add per region with that region's
2-D weight, and one Concat (not one batched MatMul with (R, d_in, d_out) weights: see :meth:`_lin`).

Contract (recorded in the manifest's ``forms``):

- graph ``experts_fused``; data inputs ``prev_token`` (B, R) int64 (column r: region r's previous token,
  regions in the manifest's order), ``audio`` (B, audio_dim), ``cond`` (B,); data output ``hidden``
  (B, R, d_model) (row r: region r's hidden state, what ``expert_<r>`` returns as ``hidden``);
- caches: ``step`` (B,) int64 (the regions step together), and per attention layer ``<layer>.k`` /
  ``<layer>.v`` of shape (B, R * heads, window - 1, head_dim): region r's canonical cache of the same name,
  (heads, window - 1, head_dim), is rows r * heads .. (r + 1) * heads of axis 1 (the canonical caches
  stacked on a region axis 1 and that axis merged with the heads). Batch stays axis 0 of every tensor.

Inside the graph the activations are batch-major with the regions side by side on the feature axis,
(B, R * d): a Split gives each region's block to its LayerNorm and Gemms (the canonical nodes with the canonical
weights), a Concat joins the Gemm outputs; the attention core, residuals, GELU and masks run once on all
regions, the attention on R * heads heads exactly as the canonical step on its heads. No Transpose anywhere.

This is a different arrangement of the same arithmetic, not a different model: the weights are copies of
the eXperts' (taken when the module is built) and :func:`check_fused_experts` compares it with the four
canonical steps.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from ..models.expert import RegionExpert
from ..models.layers import CacheSpec, PerRegionWeights, check_cache, check_shape, window_bias, worst_difference

FUSED_EXPERTS = "experts_fused"


class FusedExperts(PerRegionWeights):
    """The region eXperts ``experts`` (in region order) as one step on a region axis (module docs)."""

    def __init__(self, experts: list[RegionExpert]):
        super().__init__()
        e0 = experts[0]
        self.cfg, self.regions = e0.cfg, [e.region for e in experts]
        self.name = FUSED_EXPERTS
        R = len(experts)
        self.R, self.d, self.eps = R, e0.cfg.d_model, e0.norm.eps
        n_emb = e0.embed.num_embeddings

        # per region: the canonical Linear's (d_out, d_in) weight and bias (one Gemm each), or LayerNorm's (d,)
        # scale and shift (one LayerNormalization each)
        def per_region(key, mods):
            self._per_region(key, [(m.weight, m.bias) for m in mods])
        buf = self._frozen

        # one flat embedding table: region r's token x is row r * n_emb + x
        buf("embed", torch.cat([e.embed.weight.detach() for e in experts], 0))
        buf("embed_offset", torch.arange(R, dtype=torch.int64) * n_emb)   # (R,)
        self.embed_dim = e0.embed.embedding_dim
        for i in (0, 2):
            per_region(f"mlp{i}", [e.embed_mlp[i] for e in experts])
        buf("null_audio", torch.stack([e.null_audio.detach() for e in experts]))   # (R, Da)
        self.layer_names = e0.layer_names()
        self.layer_meta = []
        for li, name in enumerate(self.layer_names):
            layers = [e.layers[li] for e in experts]
            a0 = layers[0].attn
            p = f"l{li}_"
            for key, lins in (("q", [l.attn.q for l in layers]), ("kv", [l.attn.kv for l in layers]),
                              ("o", [l.attn.o for l in layers]), ("fc1", [l.ffn.fc1 for l in layers]),
                              ("fc2", [l.ffn.fc2 for l in layers])):
                per_region(p + key, lins)
            per_region(p + "ln1", [l.ln1 for l in layers])
            per_region(p + "ln2", [l.ln2 for l in layers])
            self.register_buffer(p + "qrot", a0.qrot.detach().clone(), persistent=False)   # a constant
            self.layer_meta.append({"name": name, "cross": layers[0].is_cross, "w": a0.w, "h": a0.h, "hd": a0.hd,
                                    "ln_eps": layers[0].ln1.eps})
        per_region("norm", [e.norm for e in experts])
        self.additive = e0.additive       # variant additive-audio: each region's audio projection added
        if self.additive:
            per_region("audio_add", [e.audio_add for e in experts])

    def cache_specs(self) -> list[CacheSpec]:
        specs = [CacheSpec("step", (), "int64")]
        for m in self.layer_meta:
            shape = (self.R * m["h"], m["w"] - 1, m["hd"])
            specs += [CacheSpec(f"{m['name']}.k", shape), CacheSpec(f"{m['name']}.v", shape)]
        return specs

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def _ln(self, x, key, eps):
        """x (B, R*d) -> the R region blocks (B, d), each through its region's LayerNorm (scale and shift inside
        the LayerNormalization as in the canonical graph: a shared normalisation followed by a per-region
        Mul + Add rounds differently, 4e-6 on the default model)."""
        xs = self._split(x, self.d)
        return [F.layer_norm(xs[r], (self.d,), getattr(self, f"{key}_w{r}"), getattr(self, f"{key}_b{r}"), eps)
                for r in range(self.R)]

    def _split(self, x, width):
        return torch.split(x, width, dim=1)   # (B, R*width) -> R blocks (B, width): one Split

    def step(self, prev_token: torch.Tensor, audio: torch.Tensor, cond: torch.Tensor, cache: dict):
        """prev_token (B, R) int64, audio (B, audio_dim), cond (B,) float32 ->
        ({'hidden': (B, R, d_model)}, new_cache)."""
        R, d = self.R, self.d
        check_shape(self.name, "prev_token", prev_token, (None, R), torch.int64)
        B = prev_token.shape[0]
        Da = self.cfg.audio_dim
        check_shape(self.name, "audio", audio, (B, Da), torch.float32)
        check_shape(self.name, "cond", cond, (B,), torch.float32)
        check_cache(self.name, self.cache_specs(), cache, B)
        new_cache: dict = {}
        step = cache["step"]
        # activations are batch-major, regions side by side on the feature axis: (B, R*d)
        e = F.embedding(prev_token + self.embed_offset, self.embed).reshape(-1, R * self.embed_dim)
        x = self._lin(self._split(F.gelu(self._lin(self._split(e, self.embed_dim), "mlp0")), d), "mlp2")
        c = cond.to(audio.dtype)[:, None, None]                                       # (B, 1, 1)
        a = (c * audio[:, None, :] + (1 - c) * self.null_audio).reshape(-1, R * Da)   # (B, R*Da)
        a_blocks = self._split(a, Da)
        if self.additive:
            x = x + self._lin(a_blocks, "audio_add")
        bias = {w: window_bias(step, w) for w in {m["w"] for m in self.layer_meta}}   # (B, 1, W)
        for li, m in enumerate(self.layer_meta):
            p = f"l{li}_"
            W, h, hd, name = m["w"], m["h"], m["hd"], m["name"]
            hx = self._ln(x, p + "ln1", m["ln_eps"])
            kv = self._lin(a_blocks if m["cross"] else hx, p + "kv").reshape(-1, R, 2 * d)
            k_new = kv[..., :d].reshape(-1, R * h, 1, hd)                            # region-major heads
            v_new = kv[..., d:].reshape(-1, R * h, 1, hd)
            k_all = torch.cat([cache[f"{name}.k"], k_new], dim=-2)                    # (B, R*h, W, hd)
            v_all = torch.cat([cache[f"{name}.v"], v_new], dim=-2)
            new_cache[f"{name}.k"] = k_all[..., 1:, :]
            new_cache[f"{name}.v"] = v_all[..., 1:, :]
            q = self._lin(hx, p + "q").reshape(-1, R * h, hd)
            qr = (q @ getattr(self, p + "qrot")).reshape(-1, R * h, W, hd)
            scores = (qr * k_all).sum(-1) + bias[W]                                   # (B, R*h, W)
            pr = torch.softmax(scores, dim=-1)
            y = (pr[..., None] * v_all).sum(-2).reshape(-1, R * d)
            x = x + self._lin(self._split(y, d), p + "o")
            hf = self._ln(x, p + "ln2", m["ln_eps"])
            x = x + self._lin(self._split(F.gelu(self._lin(hf, p + "fc1")), self.cfg.ffn_mult * d), p + "fc2")
        new_cache["step"] = step + 1
        return {"hidden": torch.stack(self._ln(x, "norm", self.eps), 1)}, new_cache

    def split_cache(self, cache: dict) -> list[dict]:
        """The fused caches as the canonical eXperts' caches, one dict per region."""
        out = []
        for r in range(self.R):
            d = {}
            for k, v in cache.items():
                d[k] = v if k == "step" else v.reshape(v.shape[0], self.R, -1, *v.shape[2:])[:, r]
            out.append(d)
        return out


@torch.no_grad()
def check_fused_experts(model, steps: int, batch: int = 2, seed: int = 0) -> tuple[float, str, int, float]:
    """Compares :class:`FusedExperts` with the four canonical eXpert steps over ``steps`` chained steps from
    the zero caches with random inputs (BOS first): every region's hidden state and every cache. Returns the
    max abs difference and where it occurred (output name, step)."""
    experts = [model.experts[r] for r in model.region_names]
    fused = FusedExperts(experts).eval()
    cfg = model.cfg
    g = torch.Generator().manual_seed(seed)
    f_cache = fused.init_cache(batch)
    c_caches = [e.init_cache(batch) for e in experts]
    cond = torch.tensor([1.0 if i % 2 == 0 else 0.0 for i in range(batch)])
    worst = (-1.0, "hidden", 0, 1.0)
    for s in range(steps):
        prev = torch.randint(0, cfg.codebook_size, (batch, len(experts)), generator=g)
        if s == 0:
            prev[:] = cfg.bos_token
        audio = torch.randn(batch, cfg.audio_dim, generator=g)
        fo, f_cache = fused.step(prev, audio, cond, f_cache)
        pairs = []
        for r, e in enumerate(experts):
            co, c_caches[r] = e.step(prev[:, r], audio, cond, c_caches[r])
            pairs.append((f"hidden[:, {r}] ({model.region_names[r]})", fo["hidden"][:, r], co["hidden"]))
        for r, split in enumerate(fused.split_cache(f_cache)):
            pairs += [(f"new_cache.{k}[:, {r}]", v, c_caches[r][k]) for k, v in split.items()]
        worst = worst_difference(worst, pairs, s)
    return worst
