"""The streaming reference loop: audio chunks of any size in, SMPL-X frames out, zero look-ahead.

Per motion token t (133.3 ms of audio), as soon as its audio has arrived:

1. ``StreamingLogMel`` yields the token's ``mel_frames_per_token`` log-mel frames;
2. ``audio_encoder.step`` -> audio token a_t (computed once, shared by both guidance branches);
3. every ``expert_<region>.step`` reads x_{t-1}^r and a_t -> hidden h_t^r; the conditional and the
   unconditional (null-audio) branches are two streams on the batch axis;
4. ``fusion.step`` -> logits per region for both branches;
5. classifier-free guidance and the seeded sampler (``livegesture.sampling``) draw x_t^r per region;
6. ``decoder_<region>.step`` turns x_t^r into frames 4t..4t+3 of region features;
7. ``livegesture.motion`` assembles SMPL-X frames (rot6d -> axis-angle).

Guidance is disabled (a single conditional branch, no unconditional stream) when gamma == 1.
"""
from __future__ import annotations

import numpy as np
import torch

from . import families
from .frames import Frame, frames_to_arrays
from .frontend import StreamingLogMel
from .models.model import LiveGesture
from .motion import features_to_motion
from .regions import FPS, FRAMES_PER_TOKEN
from .sampling import SplitMix64, sample_token

__all__ = ["Frame", "LiveGestureStream", "frames_to_arrays", "generate_clip"]


class LiveGestureStream:
    """One stream's state: frontend buffer, caches of every component, previous tokens, PRNG.

    ``push(chunk)`` accepts float samples at 16 kHz (any chunk size) and returns the frames completed.
    ``form``: ``canonical`` runs the region eXperts and SVQ decoders one by one, ``fused`` runs the eXperts as
    one step on a region axis (:class:`livegesture.forms.experts_fused.FusedExperts`) and the decoders as one step with the
    regions side by side (:class:`livegesture.forms.decoders_fused.FusedDecoders`), ``attention`` runs the canonical
    eXperts and decoders and the fusion with its attention cores as the ONNX ``Attention`` op
    (:class:`livegesture.forms.fusion_attention.FusionAttention`), docs/bundle.md#forms-and-precision; all give the same tokens and frames.
    """

    def __init__(self, model: LiveGesture, seed: int = 0, guidance: float | None = None,
                 temperature: float | None = None, top_k: int | None = None, form: str = "canonical"):
        if form not in ("canonical", "fused", "attention"):
            raise ValueError(f"form must be 'canonical', 'fused' or 'attention', got {form!r}")
        self.form = form
        # the model's device (CPU or a GPU): every tensor of the loop is made there, results come back as numpy
        self.device = next(model.parameters()).device
        self.fused = self.fused_decoders = None
        self.fuse = model.fuse
        if form == "attention":
            from .forms.fusion_attention import FusionAttention
            self.fuse = FusionAttention(model.fuse).eval().to(self.device)
        self.names = names = model.region_names
        if form == "fused":
            if len(names) < 2:
                raise ValueError(f"form 'fused' runs several regions as one graph; this model has one region ({names[0]})")
            from .forms.experts_fused import FusedExperts
            from .forms.decoders_fused import FusedDecoders
            self.fused = FusedExperts([model.experts[r] for r in names]).eval().to(self.device)
            self.fused_decoders = FusedDecoders([model.svq[r] for r in names]).eval().to(self.device)
        self.model = model.eval()
        cfg = model.cfg
        self.cfg = cfg
        self.gamma = cfg.guidance if guidance is None else float(guidance)
        self.temperature = cfg.temperature if temperature is None else float(temperature)
        self.top_k = cfg.top_k if top_k is None else int(top_k)
        self.seed = seed
        self.reset()

    @property
    def guided(self) -> bool:
        return self.gamma != 1.0

    def reset(self):
        m, B, dev = self.model, (2 if self.guided else 1), self.device
        self.frontend = StreamingLogMel(self.cfg.frontend)
        self.cache = {"audio_encoder": m.audio_encoder.init_cache(1, dev), "fusion": m.fuse.init_cache(B, dev)}
        for r in self.names:
            if self.fused is None:
                self.cache[f"expert_{r}"] = m.experts[r].init_cache(B, dev)
            if self.fused_decoders is None:
                self.cache[f"decoder_{r}"] = m.svq[r].init_cache(1, dev)
        if self.fused is not None:
            self.cache["experts_fused"] = self.fused.init_cache(B, dev)
        if self.fused_decoders is not None:
            self.cache["decoders_fused"] = self.fused_decoders.init_cache(1, dev)
        self.prev = {r: self.cfg.bos_token for r in self.names}
        self.rng = SplitMix64(self.seed)
        self.t = 0
        self.tokens: list[dict[str, int]] = []
        self.logits: list[np.ndarray] = []   # guided-branch logits per step (for reference vectors)

    @torch.no_grad()
    def step_token(self, mel: np.ndarray) -> list[Frame]:
        """One token step from its mel frames (mel_frames_per_token, n_mels)."""
        _, logits = self.hidden_and_logits(mel)
        return self.emit(logits)

    @torch.no_grad()
    def hidden_and_logits(self, mel: np.ndarray) -> tuple[dict, np.ndarray]:
        """The first half of :meth:`step_token`: the audio encoder, the eXperts and the fusion on one token's mel
        frames (their caches advanced). Returns the eXperts' hidden states {region: (B, d_model)} and the
        fusion's logits (B, R, K) (B = 2 with guidance: the conditional row first)."""
        m, dev = self.model, self.device
        B = 2 if self.guided else 1
        out, self.cache["audio_encoder"] = m.audio_encoder.step(
            torch.as_tensor(mel, dtype=torch.float32, device=dev)[None], self.cache["audio_encoder"])
        audio = out["audio"].expand(B, -1)
        cond = torch.tensor([1.0, 0.0][:B], device=dev)
        hidden = {}
        if self.fused is not None:
            prev = torch.tensor([[self.prev[r] for r in self.names]] * B, dtype=torch.int64, device=dev)
            o, self.cache["experts_fused"] = self.fused.step(prev, audio, cond, self.cache["experts_fused"])
            hidden = {r: o["hidden"][:, i] for i, r in enumerate(self.names)}
        else:
            for r in self.names:
                prev = torch.full((B,), self.prev[r], dtype=torch.int64, device=dev)
                o, self.cache[f"expert_{r}"] = m.experts[r].step(prev, audio, cond, self.cache[f"expert_{r}"])
                hidden[r] = o["hidden"]
        o, self.cache["fusion"] = self.fuse.step(hidden, audio, cond, self.cache["fusion"])
        return hidden, o["logits"].cpu().numpy()         # (B, R, K)

    @torch.no_grad()
    def emit(self, logits: np.ndarray) -> list[Frame]:
        """The second half of :meth:`step_token`: samples the region tokens from ``logits`` (B, R, K), decodes
        them and returns the token's frames."""
        m = self.model
        self.logits.append(logits)
        tokens = {}
        for i, r in enumerate(self.names):
            tokens[r] = sample_token(logits[0, i], logits[1, i] if self.guided else None, self.rng,
                                     self.gamma, self.temperature, self.top_k)
        feats = {}
        if self.fused_decoders is not None:
            tok = torch.tensor([[tokens[r] for r in self.names]], dtype=torch.int64, device=self.device)
            o, self.cache["decoders_fused"] = self.fused_decoders.step(tok, self.cache["decoders_fused"])
            for r, f in zip(self.names, self.fused_decoders.split_motion(o["motion"])):
                feats[r] = f[0].cpu().numpy()
        else:
            for r in self.names:
                o, self.cache[f"decoder_{r}"] = m.svq[r].step(torch.tensor([tokens[r]], device=self.device),
                                                              self.cache[f"decoder_{r}"])
                feats[r] = o["motion"][0].cpu().numpy()
        self.prev = tokens
        self.tokens.append(tokens)
        motion = features_to_motion(feats)
        frames = []
        for j in range(FRAMES_PER_TOKEN):
            k = FRAMES_PER_TOKEN * self.t + j
            frames.append(Frame(k, k / FPS, motion["poses"][j], motion["trans"][j], motion["expressions"][j],
                                motion["foot_contact"][j]))
        self.t += 1
        return frames

    def push(self, chunk: np.ndarray) -> list[Frame]:
        frames = []
        for mel in self.frontend.push(chunk):
            frames += self.step_token(mel)
        return frames

    def finish(self, n_in: int | None = None, rate_in: int | None = None) -> list[Frame]:
        """End of the audio (docs/output.md): completes the last partial token with silence and returns its frames
        cut at the audio's end, so that ceil(duration x fps) frames were emitted in total, computed in
        integers from the input's own sample count and rate: ``(n_in * fps + rate_in - 1) // rate_in``
        (default: the samples pushed, at the frontend's rate). The Rust runtime's ``finish`` is the same."""
        cfg = self.cfg.frontend
        if n_in is None:
            n_in, rate_in = self.frontend.n_samples, cfg.sample_rate
        total = (n_in * cfg.fps + rate_in - 1) // rate_in
        needed = -(-total // cfg.frames_per_token)
        produced = self.frontend.next_token
        if produced * cfg.frames_per_token > total or needed > produced + 1:
            raise ValueError(f"finish: the input ({n_in} samples at {rate_in} Hz, {total} frames) does not match "
                             f"the {self.frontend.n_samples} samples pushed ({produced} tokens)")
        frames = []
        if needed > produced:
            frames = self.push(np.zeros(cfg.token_end(needed - 1) - self.frontend.n_samples, np.float32))
        return [f for f in frames if f.index < total]


def generate_clip(model: LiveGesture, audio_16k: np.ndarray, seed: int = 0, guidance: float | None = None,
                  chunk: int | None = None, temperature: float | None = None, top_k: int | None = None,
                  finish: bool = False, form: str = "canonical") -> dict:
    """Run the streaming loop over a whole clip. Returns dict(poses, trans, expressions, foot_contact, tokens).
    ``form``: the graph form (see :class:`LiveGestureStream`).

    ``finish=True`` covers the whole audio as the runtime's ``generate`` does (docs/output.md, ``LiveGestureStream.finish``);
    the default stops at the last complete token, as the exported reference rollout does."""
    fam = families.of_model(model)      # the family's sampler (DiffSHEG: FOPPAS over the clip)
    options = {"temperature": temperature, "top_k": top_k, "finish": finish, "form": form}
    refused = [k for k in fam.sampler_options_refused if options[k] is not None]
    if refused:
        raise ValueError(f"{fam.name}: {' and '.join(refused)} do not apply to this family's sampler")
    return fam.resolve(fam.sampler)(model, audio_16k, seed=seed, guidance=guidance, chunk=chunk,
                                    **{k: options[k] for k in fam.sampler_options})


def generate_livegesture_clip(model: LiveGesture, audio_16k: np.ndarray, seed: int = 0, guidance: float | None = None,
                              chunk: int | None = None, temperature: float | None = None, top_k: int | None = None,
                              finish: bool = False, form: str = "canonical") -> dict:
    """:func:`generate_clip` for a LiveGesture model (the family registry's sampler of ``livegesture``)."""
    s = LiveGestureStream(model, seed=seed, guidance=guidance, temperature=temperature, top_k=top_k, form=form)
    audio = np.asarray(audio_16k, dtype=np.float32)
    chunk = chunk or len(audio) or 1
    frames = []
    for i in range(0, len(audio), chunk):
        frames += s.push(audio[i:i + chunk])
    if finish:
        frames += s.finish()
    out = frames_to_arrays(frames)
    out["tokens"] = np.array([[t[r] for r in s.names] for t in s.tokens], dtype=np.int64).reshape(-1, len(s.names))
    return out
