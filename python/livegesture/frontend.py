"""The log-mel frontend. Owned numerics: ``runtime/src/frontend.rs`` reproduces this exactly.

Definition (all arithmetic in float64, output cast to float32):

- Input: mono float samples at ``sample_rate`` (16 kHz), sample n at index n >= 0; samples before the
  stream start (n < 0) are zeros.
- Mel frames run at ``mel_frames_per_token`` (8) per motion token, i.e. 60 per second. Mel frame m ends
  (exclusive) at sample ``e_m = (m + 1) * sample_rate * frames_per_token // (fps * mel_frames_per_token)``
  = ``(m + 1) * 800 // 3``. Integer arithmetic: mel frame ``8t + 7`` ends exactly where motion token t's
  audio ends (``4 (t + 1) * 16000 // 30``), so features line up with the token grid forever, no drift.
- Frame m analyses samples ``[e_m - win_length, e_m)`` (zeros before 0), multiplied by a periodic Hann
  window ``w[n] = 0.5 - 0.5 cos(2 pi n / win_length)``, zero-padded at the end to ``n_fft``.
- Power spectrum ``|rfft|^2`` (``n_fft // 2 + 1`` bins), mel filterbank (HTK mel scale
  ``2595 log10(1 + f / 700)``, ``n_mels`` triangles with edges equally spaced in mel between f_min and
  f_max, no area normalisation), then ``ln(energy + log_offset)``.

A frame depends only on samples before its end: the frontend has zero look-ahead by construction.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class FrontendConfig:
    sample_rate: int = 16000
    fps: int = 30
    frames_per_token: int = 4
    mel_frames_per_token: int = 8
    win_length: int = 400
    n_fft: int = 512
    n_mels: int = 64
    f_min: float = 0.0
    f_max: float = 8000.0
    log_offset: float = 1e-6

    def frame_end(self, m: int | np.ndarray):
        """Exclusive end sample of mel frame m (integer arithmetic)."""
        return (np.asarray(m, dtype=np.int64) + 1) * self.sample_rate * self.frames_per_token // (
            self.fps * self.mel_frames_per_token)

    def token_end(self, t: int) -> int:
        return (t + 1) * self.frames_per_token * self.sample_rate // self.fps

    def n_tokens(self, n_samples: int) -> int:
        """Number of complete motion tokens in ``n_samples`` samples."""
        return ((n_samples + 1) * self.fps - 1) // (self.sample_rate * self.frames_per_token)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.update(type="logmel", window="hann_periodic", mel_scale="htk", norm=None, log="ln(x + log_offset)",
                 frame_end="(m + 1) * sample_rate * frames_per_token // (fps * mel_frames_per_token)",
                 frame_span="[frame_end - win_length, frame_end), zeros before sample 0, zero-padded to n_fft at the end")
        return d


def hz_to_mel(f):
    return 2595.0 * np.log10(1.0 + np.asarray(f, dtype=np.float64) / 700.0)


def mel_to_hz(m):
    return 700.0 * (10.0 ** (np.asarray(m, dtype=np.float64) / 2595.0) - 1.0)


def mel_filterbank(cfg: FrontendConfig) -> np.ndarray:
    """(n_mels, n_fft // 2 + 1) float64 triangular filters."""
    n_bins = cfg.n_fft // 2 + 1
    freqs = np.arange(n_bins, dtype=np.float64) * cfg.sample_rate / cfg.n_fft
    edges = mel_to_hz(np.linspace(hz_to_mel(cfg.f_min), hz_to_mel(cfg.f_max), cfg.n_mels + 2))
    fb = np.zeros((cfg.n_mels, n_bins), dtype=np.float64)
    for i in range(cfg.n_mels):
        lo, c, hi = edges[i], edges[i + 1], edges[i + 2]
        up = (freqs - lo) / (c - lo)
        down = (hi - freqs) / (hi - c)
        fb[i] = np.maximum(0.0, np.minimum(up, down))
    return fb


def hann_periodic(n: int) -> np.ndarray:
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n, dtype=np.float64) / n)


def logmel_frames(samples: np.ndarray, first_frame: int, n_frames: int, cfg: FrontendConfig,
                  offset: int = 0) -> np.ndarray:
    """Log-mel frames ``first_frame .. first_frame + n_frames`` as (n_frames, n_mels) float32.

    ``samples[i]`` is stream sample ``offset + i``; every sample a frame needs must be present (or be < 0).
    """
    if n_frames <= 0:
        return np.zeros((0, cfg.n_mels), dtype=np.float32)
    x = np.asarray(samples, dtype=np.float64)
    ends = cfg.frame_end(np.arange(first_frame, first_frame + n_frames))
    starts = ends - cfg.win_length
    if ends[-1] - offset > len(x):
        raise ValueError(f"frontend: mel frame {first_frame + n_frames - 1} needs samples up to {ends[-1]}, "
                         f"only {offset + len(x)} given")
    idx = starts[:, None] + np.arange(cfg.win_length)[None, :] - offset
    if (idx[:, 0] + offset >= 0).all() and idx.min() < 0:
        raise ValueError("frontend: samples needed by the first frame were dropped")
    frames = np.where(idx + offset >= 0, x[np.clip(idx, 0, max(len(x) - 1, 0))] if len(x) else 0.0, 0.0)
    frames = frames * hann_periodic(cfg.win_length)[None, :]
    spec = np.fft.rfft(frames, n=cfg.n_fft, axis=-1)
    power = spec.real ** 2 + spec.imag ** 2
    mel = power @ mel_filterbank(cfg).T
    return np.log(mel + cfg.log_offset).astype(np.float32)


def logmel(samples: np.ndarray, cfg: FrontendConfig = FrontendConfig()) -> np.ndarray:
    """All complete tokens' log-mel frames of a whole clip: (n_tokens * mel_frames_per_token, n_mels)."""
    n_tok = cfg.n_tokens(len(samples))
    return logmel_frames(samples, 0, n_tok * cfg.mel_frames_per_token, cfg)


class StreamingLogMel:
    """Push samples in chunks of any size; pop the mel frames of each completed token.

    Keeps only the last ``win_length`` samples it still needs, so memory is bounded on endless streams.
    """

    def __init__(self, cfg: FrontendConfig = FrontendConfig()):
        self.cfg = cfg
        self.reset()

    def reset(self):
        self.buf = np.zeros(0, dtype=np.float64)
        self.buf_offset = 0      # stream index of buf[0]
        self.n_samples = 0       # samples received so far
        self.next_token = 0

    def push(self, chunk: np.ndarray) -> list[np.ndarray]:
        """Returns a list of (mel_frames_per_token, n_mels) arrays, one per token completed by this chunk."""
        chunk = np.asarray(chunk, dtype=np.float64).reshape(-1)
        if not np.isfinite(chunk).all():
            raise ValueError("frontend: audio contains NaN or Inf samples")
        self.buf = np.concatenate([self.buf, chunk])
        self.n_samples += len(chunk)
        out = []
        M = self.cfg.mel_frames_per_token
        while self.cfg.token_end(self.next_token) <= self.n_samples:
            t = self.next_token
            out.append(logmel_frames(self.buf, t * M, M, self.cfg, offset=self.buf_offset))
            self.next_token += 1
            keep_from = self.cfg.frame_end(self.next_token * M) - self.cfg.win_length
            drop = int(keep_from) - self.buf_offset
            if drop > 0:
                self.buf = self.buf[drop:]
                self.buf_offset += drop
        return out
