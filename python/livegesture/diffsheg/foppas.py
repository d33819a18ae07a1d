"""DDIM, classifier-free guidance and FOPPAS (paper sections 3.2, 3.5 and Algorithm 1 of appendix B).

This module is the sampler's definition; the Rust runtime reproduces it operation by operation. Graph
outputs are float32; everything the sampler computes itself is IEEE float64 per element, in the written
order (no fused multiply-add), and is rounded to float32 only where stated.

**Windows.** ``T = ceil(n_samples * fps / sample_rate)`` = ``(n_samples * 30 + 15999) // 16000`` frames
cover the whole audio (docs/output.md). Window k starts at ``s_0 = 0``, ``s_{k+1} = s_k + N - L`` (N = window,
L = overlap) and has ``n_k = min(N, T - s_k)`` frames; the last window is the first with ``s_k + N >= T``
(it may be shorter than N: the Transformer drops the remaining positional rows). Window k needs the
log-mel frames ``2 s_k .. 2 (s_k + n_k) - 1`` (``livegesture.frontend``; audio past the end is zeros): in a
stream it runs as soon as sample ``(s_k + N) * 16000 // 30`` has arrived, or at the end of the stream.
It emits its first ``n_k - L`` frames and holds back the last L (the ``overlap`` state) -- the next window
re-creates them (blended, see below) and emits them; the last window emits all of its frames. If the
stream ends exactly where the held frames end (``T - s_{k+1} == L``) no window runs: the held frames are
emitted unchanged.

**One window** (x is float32 (n, D), normalised motion; ``ab`` = ``alpha_bar`` table (float64);
``tau_j`` the DDIM timesteps, ``schedule.ddim_timesteps``; ``known`` = the held overlap frames (L, D)
float32 of the previous window, absent (L = 0) for the first window; ``noise.take`` = the next normals of
the stream's ``noise`` position, row-major)::

    x = noise.take((n, D))                                         # x_T
    for j = S-1 down to 0:
        a_t = ab[tau_j];  a_p = ab[tau_{j-1}] if j > 0 else 1.0
        U_j = jumps if (L > 0 and j > 0) else 1                    # the first window is plain DDIM
        for u = 0 .. U_j - 1:
            if L > 0:                                              # the known part, noised to step j-1
                if j > 0: xk = sqrt(a_p) * known + sqrt(1.0 - a_p) * noise.take((L, D))
                else:     xk = known
            eps = guided_eps(x, tau_j)                             # float64 (n, D), see below
            x0  = (x - sqrt(1.0 - a_t) * eps) / sqrt(a_t)          # DDIM, eta = 0
            xp  = sqrt(a_p) * x0 + sqrt(1.0 - a_p) * eps
            if L > 0:                                              # frames i < L only
                if j >= blend_steps: xp[i] = xk[i]
                else:                xp[i] = (1.0 - w_i) * xk[i] + w_i * xp[i],  w_i = i / (L - 1)  (0 if L == 1)
            if u < U_j - 1:                                        # RePaint jump back to step j
                r = a_t / a_p
                x = float32(sqrt(r) * xp + sqrt(1.0 - r) * noise.take((n, D)))
            else:
                x = float32(xp)
    return x                                                       # the window's clean motion

Every scalar coefficient (``sqrt(a_t)``, ``sqrt(1.0 - a_t)``, ``a_t / a_p``, ...) is computed in float64
from the table values exactly as written; normals are float32 values promoted to float64.

**Guidance.** The denoiser runs on a batch of 2 rows with the same ``x``, ``t``, ``audio`` and ``speaker``:
row 0 ``cond = 1`` (conditional), row 1 ``cond = 0`` (null audio). ``eps = u + gamma * (c - u)`` in float64
(c, u: the rows' float32 outputs promoted). With ``gamma == 1.0`` only the conditional row runs and
``eps = c``.

**Output.** The window's float32 rows are de-normalised per element in float32: ``feat = x * std + mean``
(one float32 multiply, then one float32 add; std/mean from the manifest's ``normalisation``), split into
regions by ``motion.layout`` and assembled into frames exactly like LiveGesture's decoder output.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch

from ..frames import Frame, frames_to_arrays
from ..frontend import logmel_frames
from ..motion import features_to_motion
from ..regions import FPS, SAMPLE_RATE
from .denoiser import MOTION_DIM
from .model import MOTION_ORDER, DiffSHEG, motion_layout
from .noise import NoiseStream
from .schedule import alphas_cumprod, ddim_timesteps


@dataclass(frozen=True)
class SamplerOptions:
    steps: int = 25
    guidance: float = 1.25
    window: int = 88
    overlap: int = 10
    jumps: int = 2
    blend_steps: int = 2

    @staticmethod
    def from_config(cfg, **overrides) -> "SamplerOptions":
        o = SamplerOptions(steps=cfg.ddim_steps, guidance=cfg.guidance, window=cfg.window, overlap=cfg.overlap,
                           jumps=cfg.jumps, blend_steps=cfg.blend_steps)
        o = replace(o, **{k: v for k, v in overrides.items() if v is not None})
        o.validate(cfg.window)
        return o

    def validate(self, max_window: int):
        if not 1 <= self.steps <= 1000 or 1000 % self.steps:
            raise ValueError(f"sampler: steps must divide 1000, got {self.steps}")
        if not 1 <= self.window <= max_window:
            raise ValueError(f"sampler: window must be in 1..{max_window} (the model's positional table), "
                             f"got {self.window}")
        if not 0 <= self.overlap < self.window:
            raise ValueError(f"sampler: overlap must be in 0..window-1, got {self.overlap}")
        if self.jumps < 1 or self.blend_steps < 0:
            raise ValueError(f"sampler: jumps must be >= 1 and blend_steps >= 0, got {self.jumps}, {self.blend_steps}")
        if not math.isfinite(self.guidance):
            raise ValueError("sampler: guidance must be finite")

    def to_dict(self) -> dict:
        return asdict(self)


def n_frames_for(n_samples: int, sample_rate: int = SAMPLE_RATE, fps: int = FPS) -> int:
    """ceil(n_samples * fps / sample_rate), integer arithmetic."""
    return (n_samples * fps + sample_rate - 1) // sample_rate


def plan_windows(T: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """[(start, n)] of every window for a stream of T frames."""
    out, s = [], 0
    while T > 0:
        n = min(window, T - s)
        out.append((s, n))
        if s + window >= T:
            break
        s += window - overlap
    return out


# ----------------------------------------------------------------------------- backends

class TorchBackend:
    """The graphs' torch reference: ``encode(mel) -> audio``, ``denoise(x, t, audio, speaker, cond) -> eps``,
    numpy in, numpy out (float32)."""

    def __init__(self, model: DiffSHEG):
        self.model = model.eval()
        self.device = next(model.parameters()).device     # CPU or a GPU: inputs go there, outputs come back

    def _in(self, a, dtype) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=dtype)).to(self.device)

    @torch.no_grad()
    def encode(self, mel: np.ndarray) -> np.ndarray:
        return self.model.speech_encoder(self._in(mel, np.float32)).cpu().numpy()

    @torch.no_grad()
    def denoise(self, x, t, audio, speaker, cond) -> np.ndarray:
        f = self._in
        return self.model.denoiser(f(x, np.float32), f(t, np.int64), f(audio, np.float32), f(speaker, np.int64),
                                   f(cond, np.float32)).cpu().numpy()


def guided_eps(backend, x: np.ndarray, t: int, audio: np.ndarray, speaker: int, guidance: float) -> np.ndarray:
    """x (n, D) float32, audio (n, Da) -> guided eps (n, D) float64 (module docstring)."""
    B = 1 if guidance == 1.0 else 2
    out = backend.denoise(np.broadcast_to(x, (B,) + x.shape), np.full(B, t, np.int64),
                          np.broadcast_to(audio, (B,) + audio.shape), np.full(B, speaker, np.int64),
                          np.array([1.0, 0.0][:B], np.float32))
    c = out[0].astype(np.float64)
    if B == 1:
        return c
    u = out[1].astype(np.float64)
    return u + guidance * (c - u)


def sample_window(backend, audio: np.ndarray, speaker: int, noise: NoiseStream, known: np.ndarray | None,
                  opts: SamplerOptions, ab: np.ndarray, trace: list | None = None) -> np.ndarray:
    """One FOPPAS window (module docstring). audio (n, Da); known (L, D) float32 or None -> x0 (n, D) float32.
    ``trace`` (a list) receives one dict per denoiser call: x, t, eps (guided)."""
    return sample_windows(backend, audio[None], [speaker], [noise], None if known is None else known[None],
                          opts, ab, trace)[0]


def sample_windows(backend, audio: np.ndarray, speakers, noises: list, known: np.ndarray | None,
                   opts: SamplerOptions, ab: np.ndarray, trace: list | None = None) -> np.ndarray:
    """M windows of M independent streams at once (same n, all with or all without known frames): audio
    (M, n, Da), known (M, L, D) or None, one NoiseStream per stream -> (M, n, D). Each stream draws its own
    normals in the order of the module docstring, and every element's arithmetic is that of one window, so
    stream m's result equals ``sample_window`` of stream m alone up to the denoiser's batch-size rounding
    (bit-identical for M = 1); the denoiser runs once per pass on 2M rows (M with 1.0 guidance)."""
    M, n = audio.shape[0], audio.shape[1]
    L = 0 if known is None else known.shape[1]
    taus = ddim_timesteps(opts.steps)
    kn = None if known is None else known.astype(np.float64)
    if L:
        w = np.arange(L, dtype=np.float64)[:, None] / (L - 1) if L > 1 else np.zeros((1, 1))
    take = lambda rows: np.stack([ns.take((rows, MOTION_DIM)) for ns in noises])  # noqa: E731
    x = take(n)
    spk = np.asarray(speakers, dtype=np.int64)
    for j in range(opts.steps - 1, -1, -1):
        a_t = float(ab[taus[j]])
        a_p = float(ab[taus[j - 1]]) if j > 0 else 1.0
        U = opts.jumps if (L > 0 and j > 0) else 1
        for u in range(U):
            if L:
                if j > 0:
                    xk = math.sqrt(a_p) * kn + math.sqrt(1.0 - a_p) * take(L).astype(np.float64)
                else:
                    xk = kn
            eps = guided_eps_batch(backend, x, int(taus[j]), audio, spk, opts.guidance)
            if trace is not None:
                trace.append({"x": x[0].copy(), "t": int(taus[j]), "eps": eps[0].copy()})
            x0 = (x.astype(np.float64) - math.sqrt(1.0 - a_t) * eps) / math.sqrt(a_t)
            xp = math.sqrt(a_p) * x0 + math.sqrt(1.0 - a_p) * eps
            if L:
                if j >= opts.blend_steps:
                    xp[:, :L] = xk
                else:
                    xp[:, :L] = (1.0 - w) * xk + w * xp[:, :L]
            if u < U - 1:
                r = a_t / a_p
                x = (math.sqrt(r) * xp + math.sqrt(1.0 - r) * take(n).astype(np.float64)).astype(np.float32)
            else:
                x = xp.astype(np.float32)
    return x


def guided_eps_batch(backend, x: np.ndarray, t: int, audio: np.ndarray, speakers: np.ndarray,
                     guidance: float) -> np.ndarray:
    """x (M, n, D) float32 -> guided eps (M, n, D) float64; rows [cond=1 x M, cond=0 x M]."""
    M = x.shape[0]
    if guidance == 1.0:
        return backend.denoise(x, np.full(M, t, np.int64), audio, speakers, np.ones(M, np.float32)).astype(np.float64)
    out = backend.denoise(np.concatenate([x, x]), np.full(2 * M, t, np.int64), np.concatenate([audio, audio]),
                          np.concatenate([speakers, speakers]),
                          np.concatenate([np.ones(M, np.float32), np.zeros(M, np.float32)]))
    c = out[:M].astype(np.float64)
    u = out[M:].astype(np.float64)
    return u + guidance * (c - u)


# ----------------------------------------------------------------------------- the stream

class DiffSHEGStream:
    """One stream: audio buffer, window position, held overlap frames, noise position.

    ``push(chunk)`` takes float samples at 16 kHz (any chunk size) and returns the frames whose windows are
    complete; ``finish()`` ends the stream (pads with silence, runs the remaining windows) and returns the rest.
    State carried between windows (manifest ``foppas.state``): ``next_start`` (frame), ``overlap`` (L, D)
    float32 normalised frames, ``noise_position`` (normals drawn so far), plus the frontend's sample buffer.
    """

    def __init__(self, model: DiffSHEG, seed: int = 0, speaker: int | None = None, backend=None,
                 options: SamplerOptions | None = None, record: bool = False):
        self.model = model.eval()
        self.cfg = model.cfg
        self.opts = options or SamplerOptions.from_config(self.cfg)
        self.opts.validate(self.cfg.window)
        self.speaker = model.default_speaker() if speaker is None else int(speaker)
        if not 0 <= self.speaker < self.cfg.n_speakers:
            raise ValueError(f"diffsheg: speaker id {self.speaker} outside 0..{self.cfg.n_speakers - 1}")
        self.backend = backend or TorchBackend(model)
        self.seed = int(seed)
        self.ab = alphas_cumprod(self.cfg.diffusion_steps, self.cfg.beta_start, self.cfg.beta_end)
        self.record = record
        self.reset()

    def reset(self):
        self.buf = np.zeros(0, dtype=np.float32)
        self.buf_offset = 0
        self.n_samples = 0
        self.next_start = 0
        self.overlap: np.ndarray | None = None
        self.noise = NoiseStream(self.seed)
        self.emitted = 0
        self.finished = False
        self.windows: list[dict] = []      # with record=True: every window's inputs and outputs

    @property
    def noise_position(self) -> int:
        return self.noise.position

    def _mel(self, start: int, n: int) -> np.ndarray:
        fc = self.cfg.frontend
        return logmel_frames(self.buf, 2 * start, 2 * n, fc, offset=self.buf_offset)

    def _run_window(self, n: int, last: bool) -> list[Frame]:
        s, L = self.next_start, (0 if self.overlap is None else self.overlap.shape[0])
        mel = self._mel(s, n)
        audio = self.backend.encode(mel[None])[0]
        pos0 = self.noise.position
        trace = [] if (self.record and len(self.windows) == 1) else None
        x0 = sample_window(self.backend, audio, self.speaker, self.noise, self.overlap, self.opts, self.ab, trace)
        emit = n if last else n - self.opts.overlap
        if self.record:
            self.windows.append({"start": s, "n": n, "overlap_in": L, "mel": mel, "audio": audio,
                                 "known": self.overlap, "noise_start": pos0, "noise_end": self.noise.position,
                                 "x0": x0, "emit": emit, "trace": trace})
        frames = self._emit(x0[:emit], s)
        if last:
            self.overlap = None
            self.finished = True
        else:
            self.overlap = x0[n - self.opts.overlap:].copy() if self.opts.overlap else None
            self.next_start = s + n - self.opts.overlap
            keep_from = int(self.cfg.frontend.frame_end(2 * self.next_start)) - self.cfg.frontend.win_length
            drop = keep_from - self.buf_offset
            if drop > 0:
                self.buf = self.buf[drop:]
                self.buf_offset += drop
        return frames

    def _emit(self, x: np.ndarray, start: int) -> list[Frame]:
        if len(x) == 0:
            return []
        feats = self.model.denormalise(x)
        regions = {e["region"]: feats[:, e["offset"]:e["offset"] + e["dim"]] for e in motion_layout()}
        assert tuple(regions) == MOTION_ORDER
        m = features_to_motion(regions)
        out = []
        for i in range(len(x)):
            k = start + i
            out.append(Frame(k, k / FPS, m["poses"][i], m["trans"][i], m["expressions"][i], m["foot_contact"][i]))
        self.emitted = start + len(x)
        return out

    def push(self, chunk: np.ndarray) -> list[Frame]:
        if self.finished:
            raise RuntimeError("diffsheg stream: push after finish (call reset)")
        chunk = np.asarray(chunk, dtype=np.float32).reshape(-1)
        if not np.isfinite(chunk).all():
            raise ValueError("diffsheg stream: audio contains NaN or Inf samples")
        self.buf = np.concatenate([self.buf, chunk])
        self.n_samples += len(chunk)
        frames = []
        N = self.opts.window
        while (self.next_start + N) * SAMPLE_RATE // FPS <= self.n_samples:
            frames += self._run_window(N, last=False)
        return frames

    def finish(self) -> list[Frame]:
        if self.finished:
            return []
        T = n_frames_for(self.n_samples)
        frames = []
        if T == 0:
            self.finished = True
            return frames
        need = T * SAMPLE_RATE // FPS          # mel frame 2T-1 ends at this sample
        pad = need - (self.buf_offset + len(self.buf))
        if pad > 0:
            self.buf = np.concatenate([self.buf, np.zeros(pad, np.float32)])
        N, L = self.opts.window, self.opts.overlap
        s = self.next_start
        if self.overlap is not None and T - s <= L:      # nothing new after the held frames
            frames += self._emit(self.overlap[: T - s], s)
            self.overlap, self.finished = None, True
            return frames
        while not self.finished:
            s = self.next_start
            n = min(N, T - s)
            frames += self._run_window(n, last=s + N >= T)
        return frames


def generate_clip(model: DiffSHEG, audio_16k: np.ndarray, seed: int = 0, speaker: int | None = None,
                  guidance: float | None = None, chunk: int | None = None, backend=None, record: bool = False,
                  **opts) -> dict:
    """The whole stream over a clip: dict(poses, trans, expressions, foot_contact) covering
    ceil(duration * 30) frames, plus ``stream`` (the DiffSHEGStream, for its recorded windows)."""
    options = SamplerOptions.from_config(model.cfg, guidance=guidance, **opts)
    s = DiffSHEGStream(model, seed=seed, speaker=speaker, backend=backend, options=options, record=record)
    audio = np.asarray(audio_16k, dtype=np.float32)
    chunk = chunk or len(audio) or 1
    frames = []
    for i in range(0, len(audio), chunk):
        frames += s.push(audio[i:i + chunk])
    frames += s.finish()
    out = frames_to_arrays(frames)
    out["stream"] = s
    return out


def generate_clips(model: DiffSHEG, audios: list, seeds: list, speaker: int | None = None,
                   guidance: float | None = None, backend=None, **opts) -> list[dict]:
    """Several whole clips at once (evaluation): the offline window plan of each clip (the same windows and
    frames as its stream, see ``plan_windows``), with the windows of equal length and overlap state of all
    clips sampled together in one batch. Returns one dict(poses, trans, expressions, foot_contact) per clip."""
    options = SamplerOptions.from_config(model.cfg, guidance=guidance, **opts)
    backend = backend or TorchBackend(model)
    spk = model.default_speaker() if speaker is None else int(speaker)
    ab = alphas_cumprod(model.cfg.diffusion_steps, model.cfg.beta_start, model.cfg.beta_end)
    fc = model.cfg.frontend
    N, L = options.window, options.overlap
    clips = []
    for a, sd in zip(audios, seeds):
        a = np.asarray(a, dtype=np.float32)
        T = n_frames_for(len(a))
        pad = np.concatenate([a, np.zeros(max(0, T * SAMPLE_RATE // FPS - len(a)), np.float32)])
        clips.append({"audio": pad, "plan": plan_windows(T, N, L), "noise": NoiseStream(sd), "known": None,
                      "out": []})
    k = 0
    while any(k < len(c["plan"]) for c in clips):
        groups: dict = {}
        for i, c in enumerate(clips):
            if k < len(c["plan"]):
                groups.setdefault((c["plan"][k][1], c["known"] is not None), []).append(i)
        for (n, has_known), idx in groups.items():
            mels = np.stack([logmel_frames(clips[i]["audio"], 2 * clips[i]["plan"][k][0], 2 * n, fc) for i in idx])
            audio = backend.encode(mels)
            known = np.stack([clips[i]["known"] for i in idx]) if has_known else None
            x0 = sample_windows(backend, audio, [spk] * len(idx), [clips[i]["noise"] for i in idx], known,
                                options, ab)
            for m, i in enumerate(idx):
                c = clips[i]
                last = k == len(c["plan"]) - 1
                c["out"].append(x0[m] if last else x0[m][: n - L])
                c["known"] = None if last or L == 0 else x0[m][n - L:].copy()
        k += 1
    results = []
    for c in clips:
        x = np.concatenate(c["out"]) if c["out"] else np.zeros((0, MOTION_DIM), np.float32)
        feats = model.denormalise(x)
        regions = {e["region"]: feats[:, e["offset"]:e["offset"] + e["dim"]] for e in motion_layout()}
        results.append(features_to_motion(regions) if len(x) else frames_to_arrays([]))
    return results

