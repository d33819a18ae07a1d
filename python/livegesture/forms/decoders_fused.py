"""Fused region forms (docs/bundle.md#forms-and-precision), part two: the four region SVQ stream decoders as one step graph.

The canonical form runs one ``decoder_<region>`` graph per region (:meth:`livegesture.models.svq.SVQ.step`).
Each is the projection head W^region on the token's codebook entry, then the causal stream decoder D_CS
(paper section 3.1, supp. B.1), channels-last, for one token x_t^r:

    c      = C^r[x_t^r]                                        codebook entry (code_dim)
    z      = W2^r GELU(W1^r c + b1^r) + b2^r                    projection head W^r -> one latent frame
    h      = ReLU(Conv_inp^r(z))                                causal conv, kernel 3
    for s in 0, 1:                                              two upsampling stages: 1 -> 2 -> 4 frames
        h  = Up2(h)                                             nearest-neighbour, x2 in time
        h  = Conv_up_s^r(h)                                     causal conv, kernel 3
        for j, d in enumerate(dilations):                       causal dilated ResNet1D
            h = h + Mix_s,j^r(ReLU(Conv_s,j^r(ReLU(h))))        Conv: kernel 3, dilation d; Mix: kernel 1
    y      = Conv_out2^r(ReLU(Conv_out1^r(h)))                  (4, dim_r): frames 4t .. 4t+3
    motion = y * std^r + mean^r                                 de-normalised region features

where every causal conv is ``conv_as_gemm`` (:mod:`livegesture.models.layers`): its cache (the last
(kernel - 1) * dilation input frames) is prepended, the kernel's taps of every output frame are gathered with
a constant index (im2col) and multiplied by the (kernel * C_in, C_out) weight in one Gemm.

:class:`FusedDecoders` computes exactly these four steps with the regions side by side on the feature axis:
activations are (B, T, R * C), channels r * C .. (r + 1) * C being region r's. Every data-movement and
elementwise node (cache Concat and Slice, im2col Gather, Up2, ReLU, GELU, residual Add, de-normalisation)
runs once for the four regions; each linear map is one Split into the region blocks, one Gemm per region with
that region's canonical 2-D weight, and one Concat (2-D Gemm weights, as in :class:`FusedExperts`: a batched
MatMul with stacked (R, d_in, d_out) weights is packed again at every onnxruntime run). No Transpose.

Contract (recorded in the manifest's ``forms``):

- graph ``decoders_fused``; data input ``token`` (B, R) int64 (column r: region r's token, regions in the
  manifest's order); data output ``motion`` (B, frames_per_token, sum of the region dims): region r's
  features (what ``decoder_<r>`` returns as ``motion``) are columns off_r .. off_r + dim_r, off_r the sum of
  the dims of the regions before r (the manifest's ``regions[*].dim`` in order);
- caches: the canonical decoders' cache names; each (B, frames, R * C) where channels r * C .. (r + 1) * C
  of the last axis are ``decoder_<r>``'s cache of the same name, (frames, C). Batch stays axis 0.

A different arrangement of the same arithmetic, not a different model: the weights are copies of the SVQs'
(taken when the module is built) and :func:`check_fused_decoders` compares it with the four canonical steps.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from ..models.layers import (CacheSpec, CausalConv1d, PerRegionWeights, check_cache, check_shape, gemm_weight,
                     worst_difference)
from ..models.svq import SVQ, upsample2_channels_last

FUSED_DECODERS = "decoders_fused"


class FusedDecoders(PerRegionWeights):
    """The region SVQ decoders ``svqs`` (in region order) as one step, regions side by side (module docs)."""

    def __init__(self, svqs: list[SVQ]):
        super().__init__()
        s0 = svqs[0]
        self.cfg, self.regions = s0.cfg, [s.region for s in svqs]
        self.name = FUSED_DECODERS
        R = len(svqs)
        self.R = R
        self.dims = [s.d_in for s in svqs]                        # region feature dims, in region order
        K, D = s0.quantizer.codebook.shape
        self.code_dim = D

        buf = self._frozen

        # one flat codebook: region r's token x is row r * K + x
        buf("codebook", torch.cat([s.quantizer.codebook for s in svqs], 0))
        buf("codebook_offset", torch.arange(R, dtype=torch.int64) * K)   # (R,)
        self.head_widths = (s0.head[0].out_features, s0.head[2].out_features)
        for i in (0, 2):
            self._per_region(f"head{i}", [(s.head[i].weight, s.head[i].bias) for s in svqs])
        # the causal convs, in the canonical cache order; per conv and region the canonical Gemm weight
        self.convs = []   # (name, kernel, dilation, C_in, [C_out per region]); a None name: a 1x1 mix, no cache
        for name, pick in self._conv_names(s0):
            convs = [pick(s.decoder) for s in svqs]
            c0 = convs[0]
            k, dil = c0.kernel_size[0], c0.dilation[0]
            key = name.replace(".", "_")
            # (C_out, k * C_in), [o, i * C_in + c] = W[o, c, i]
            self._per_region(key, [(gemm_weight(c), c.bias) for c in convs])
            self.convs.append((name, key, k, dil, c0.in_channels, [c.out_channels for c in convs]))
        self.conv_meta = {c[0]: c for c in self.convs}
        buf("std", torch.cat([s.std for s in svqs]))
        buf("mean", torch.cat([s.mean for s in svqs]))

    @staticmethod
    def _conv_names(svq: SVQ):
        """(name, the conv of a decoder): the canonical decoder's caches' names; ``<res>.mix`` for a ResNet1D
        block's 1x1 conv (no cache)."""
        dec = svq.decoder
        out = [("inp", lambda d: d.inp.conv)]
        for s in range(2):
            out.append((f"up{s}", lambda d, s=s: d.up_convs[s].conv))
            for j in range(len(dec.res[s])):
                out.append((f"up{s}.res{j}", lambda d, s=s, j=j: d.res[s][j].conv.conv))
                out.append((f"up{s}.res{j}.mix", lambda d, s=s, j=j: d.res[s][j].mix))
        out += [("out1", lambda d: d.out1.conv), ("out2", lambda d: d.out2.conv)]
        return out

    def cache_specs(self) -> list[CacheSpec]:
        specs = []
        for name, _, k, dil, c_in, _ in self.convs:
            pad = (k - 1) * dil
            if pad > 0:
                specs.append(CacheSpec(name, (pad, self.R * c_in)))
        return specs

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def _conv(self, x, name, cache, new_cache):
        """The causal conv ``name`` of every region on x (B, T, R * C_in) -> (B, T, sum of C_out): one cache
        Concat and Slice, one im2col Gather and one Split for the four regions, one Gemm per region."""
        _, key, k, dil, c_in, c_out = self.conv_meta[name]
        pad = (k - 1) * dil
        T = int(x.shape[1])
        if pad > 0:
            xx = torch.cat([cache[name], x], dim=1)                    # (B, pad + T, R * C_in)
            new_cache[name] = xx[:, -pad:, :]                          # constant bounds
        else:
            xx = x
        if k == 1:
            blocks = torch.split(xx.reshape(-1, self.R * c_in), c_in, dim=1)              # R x (B * T, C_in)
        else:
            idx = (torch.arange(T)[:, None] + dil * torch.arange(k)[None, :]).to(x.device)  # (T, k), constant
            cols = xx[:, idx]                                          # (B, T, k, R * C_in)
            blocks = [b.reshape(-1, k * c_in) for b in torch.split(cols, c_in, dim=-1)]  # R x (B * T, k * C_in)
        return self._lin(blocks, key).reshape(-1, T, sum(c_out))

    def _res(self, x, name, cache, new_cache):
        """x + Mix(ReLU(Conv(ReLU(x)))) of every region (a ResNet1D block, ``ResBlock1D.step``)."""
        y = F.relu(self._conv(F.relu(x), name, cache, new_cache))
        return x + self._conv(y, f"{name}.mix", cache, new_cache)

    def step(self, token: torch.Tensor, cache: dict) -> tuple[dict, dict]:
        """token (B, R) int64 -> ({'motion': (B, frames_per_token, sum of region dims)}, new_cache)."""
        R, D = self.R, self.code_dim
        check_shape(self.name, "token", token, (None, R), torch.int64)
        check_cache(self.name, self.cache_specs(), cache, token.shape[0])
        new_cache: dict = {}
        c = F.embedding(token + self.codebook_offset, self.codebook).reshape(-1, R * D)   # (B, R * D)
        h1, h2 = self.head_widths
        h = F.gelu(self._lin(torch.split(c, D, dim=1), "head0"))               # (B, R * hidden)
        z = self._lin(torch.split(h, h1, dim=1), "head2").reshape(-1, 1, R * h2)  # (B, 1, R * latent)
        x = F.relu(self._conv(z, "inp", cache, new_cache))
        for s in range(2):
            x = upsample2_channels_last(x)
            x = self._conv(x, f"up{s}", cache, new_cache)
            j = 0
            while f"up{s}.res{j}" in self.conv_meta:
                x = self._res(x, f"up{s}.res{j}", cache, new_cache)
                j += 1
        x = F.relu(self._conv(x, "out1", cache, new_cache))
        y = self._conv(x, "out2", cache, new_cache)                    # (B, frames, sum of region dims)
        return {"motion": y * self.std + self.mean}, new_cache

    def split_motion(self, motion: torch.Tensor) -> list[torch.Tensor]:
        """The fused ``motion`` as the canonical decoders' outputs, one (B, frames, dim_r) per region."""
        return list(torch.split(motion, self.dims, dim=-1))

    def split_cache(self, cache: dict) -> list[dict]:
        """The fused caches as the canonical decoders' caches, one dict per region."""
        out = []
        for r in range(self.R):
            d = {}
            for k, v in cache.items():
                c = v.shape[-1] // self.R
                d[k] = v[..., r * c:(r + 1) * c]
            out.append(d)
        return out


@torch.no_grad()
def check_fused_decoders(model, steps: int, batch: int = 2, seed: int = 0) -> tuple[float, str, int, float]:
    """Compares :class:`FusedDecoders` with the four canonical SVQ decoder steps over ``steps`` chained steps
    from the zero caches with random tokens: every region's motion and every cache. Returns the max abs
    difference and where it occurred (output name, step)."""
    svqs = [model.svq[r] for r in model.region_names]
    fused = FusedDecoders(svqs).eval()
    g = torch.Generator().manual_seed(seed)
    f_cache = fused.init_cache(batch)
    c_caches = [s.init_cache(batch) for s in svqs]
    worst = (-1.0, "motion", 0, 1.0)
    for s in range(steps):
        tok = torch.randint(0, model.cfg.codebook_size, (batch, len(svqs)), generator=g)
        fo, f_cache = fused.step(tok, f_cache)
        pairs = []
        for r, (svq, m) in enumerate(zip(svqs, fused.split_motion(fo["motion"]))):
            co, c_caches[r] = svq.step(tok[:, r], c_caches[r])
            pairs.append((f"motion[..., {model.region_names[r]}]", m, co["motion"]))
        for r, split in enumerate(fused.split_cache(f_cache)):
            pairs += [(f"new_cache.{k} ({model.region_names[r]})", v, c_caches[r][k]) for k, v in split.items()]
        worst = worst_difference(worst, pairs, s)
    return worst
