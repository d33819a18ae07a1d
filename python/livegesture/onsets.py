"""The project's one audio onset detector: spectral flux on a log-mel STFT, librosa-style peak picking.

Two callers use it with different settings, each a named :class:`OnsetParams`:

- :data:`EVAL_ONSETS`, the audio beats of Beat Constancy (``livegesture.eval.metrics.detect_onsets``):
  centred periodic-Hann STFT over the whole FFT length, 64 mels, ``log1p`` compression, min-max
  normalisation, a symmetric +-30 ms max window, a 100 ms refractory wait, no speech gating;
- :data:`SYNTH_ONSETS`, the onsets the synthetic corpus gestures on
  (``livegesture.data.synth_motion.analyse_audio``, 16 kHz, 10 ms hop): a 25 ms symmetric Hann window
  zero-padded to 512 points, 40 mels, dB compression, a percentile normalisation clipped to [0, 1],
  librosa's default (asymmetric) windows at 100 Hz, onsets only where the caller's speech gate is open.

Pipeline (:func:`detect_onsets`):

1. frames: frame ``i`` covers samples ``[i * hop - win_length // 2, i * hop + win_length - win_length //
   2)`` (zeros outside the signal), weighted by the window and zero-padded to ``n_fft``;
   :attr:`OnsetParams.n_frames` says how many;
2. power spectrum -> mel filterbank (``livegesture.frontend.mel_filterbank``, 0 Hz to Nyquist) ->
   compression (:attr:`OnsetParams.log_gain`);
3. flux: frame i's mean over mel bands of the half-wave rectified difference to frame i - 1 (frame 0: 0);
4. normalisation (:attr:`OnsetParams.normalise`) to the envelope in [0, 1];
5. peak picking (:func:`peak_pick`), then the gate.

This module replaced two implementations (``eval/metrics.py`` and ``data/synth.py``); the onset times both
callers get are bit-identical to theirs on the fixed inputs of ``python/tests/test_refactor_frozen.py``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

from .frontend import FrontendConfig, hann_periodic, mel_filterbank


@dataclass(frozen=True)
class OnsetParams:
    """Settings of :func:`detect_onsets` (lengths in samples, windows in envelope frames)."""

    hop: int
    """STFT hop in samples; the envelope has one value per hop."""
    win_length: int
    """Analysis window length in samples; frames are centred on ``i * hop`` (offset ``win_length // 2``)."""
    n_fft: int
    """FFT length (``>= win_length``; the windowed frame is zero-padded)."""
    window: Literal["hann_periodic", "hann_inner"]
    """``hann_periodic``: ``0.5 - 0.5 cos(2 pi n / N)`` (librosa/scipy); ``hann_inner``: the symmetric Hann
    of ``win_length + 2`` points without its two zero end points (``np.hanning(N + 2)[1:-1]``)."""
    n_frames: Literal["centres", "cover"]
    """``centres``: a frame for every hop multiple in ``[0, len]`` (``1 + len // hop``, librosa's
    ``center=True``); ``cover``: the frames whose hop starts cover the signal (``ceil(len / hop)``, at
    least 1)."""
    n_mels: int
    log_gain: float | None
    """Compression: ``log1p(log_gain * mel / max(mel))`` (about 30 dB of range for 1000: quiet detail,
    background noise included, adds little flux); ``None``: dB, ``10 log10(max(mel, 1e-10))`` clipped
    ``top_db`` below its maximum (librosa's ``power_to_db``)."""
    top_db: float
    normalise: Literal["minmax", "percentile"]
    """``minmax``: ``(flux - min) / (max - min)`` (librosa's ``onset_detect``), no onsets when the flux is
    constant; ``percentile``: ``clip((flux - min) / (P + 1e-9), 0, 1)``, P the ``norm_percentile``-th
    percentile of ``flux - min`` (a few loud transients do not flatten the rest)."""
    norm_percentile: float
    pre_max: int
    post_max: int
    pre_avg: int
    post_avg: int
    delta: float
    wait: int
    """Peak picking (:func:`peak_pick`) in envelope frames; ``wait`` >= 1."""


def eval_onset_params(sample_rate: int, hop_s: float = 0.01, win_s: float = 0.032, delta: float = 0.07,
                      wait_s: float = 0.1, pre_max_s: float = 0.03, post_max_s: float = 0.03,
                      pre_avg_s: float = 0.1, post_avg_s: float = 0.1, log_gain: float | None = 1000.0,
                      n_mels: int = 64, top_db: float = 80.0) -> OnsetParams:
    """The Beat Constancy settings at ``sample_rate``, from times in seconds: the hop rounds to whole
    samples, the window to a power of two (at least 16 samples), the peak-picking windows to whole hops."""
    sr = int(sample_rate)
    hop = max(1, int(round(hop_s * sr)))
    n_fft = 1 << max(4, int(round(math.log2(max(16, win_s * sr)))))
    f = lambda s: max(0, int(round(s / (hop / sr))))  # noqa: E731
    return OnsetParams(hop=hop, win_length=n_fft, n_fft=n_fft, window="hann_periodic", n_frames="centres",
                       n_mels=n_mels, log_gain=log_gain, top_db=top_db, normalise="minmax",
                       norm_percentile=100.0, pre_max=f(pre_max_s), post_max=f(post_max_s),
                       pre_avg=f(pre_avg_s), post_avg=f(post_avg_s), delta=delta, wait=max(1, f(wait_s)))


EVAL_ONSETS = eval_onset_params(16000)
"""Beat Constancy's audio beats at 16 kHz (``eval_onset_params(sr)`` at other rates)."""

SYNTH_ONSETS = OnsetParams(hop=160, win_length=400, n_fft=512, window="hann_inner", n_frames="cover", n_mels=40,
                           log_gain=None, top_db=80.0, normalise="percentile", norm_percentile=99.5,
                           pre_max=3, post_max=1, pre_avg=10, post_avg=11, delta=0.07, wait=4)
"""The synthetic corpus' onsets (16 kHz): librosa's ``onset_detect`` defaults at a 100 Hz frame rate."""


class Onsets(NamedTuple):
    frames: np.ndarray
    """(k,) int64 envelope frame indices of the onsets, increasing."""
    envelope: np.ndarray
    """(n,) normalised onset envelope in [0, 1]."""


def _window(p: OnsetParams) -> np.ndarray:
    if p.window == "hann_periodic":
        return hann_periodic(p.win_length)
    if p.window == "hann_inner":
        return np.hanning(p.win_length + 2)[1:-1]
    raise ValueError(f"OnsetParams.window: unknown window {p.window!r} (hann_periodic or hann_inner)")


def spectral_flux(x: np.ndarray, sample_rate: int, p: OnsetParams) -> np.ndarray:
    """Steps 1-3 of the pipeline: the (n,) raw spectral flux of ``x`` (mono, or (n, channels) averaged)."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x.mean(axis=1)
    if p.n_frames == "centres":
        n = 1 + len(x) // p.hop
    elif p.n_frames == "cover":
        n = max(1, 1 + (len(x) - 1) // p.hop)
    else:
        raise ValueError(f"OnsetParams.n_frames: unknown rule {p.n_frames!r} (centres or cover)")
    xp = np.concatenate([np.zeros(p.win_length // 2), x, np.zeros(p.win_length + p.hop)])
    win = _window(p)
    fb = mel_filterbank(FrontendConfig(sample_rate=int(sample_rate), n_fft=p.n_fft, win_length=p.n_fft,
                                       n_mels=p.n_mels, f_min=0.0, f_max=sample_rate / 2.0))
    mel = np.empty((n, p.n_mels))
    block = 4096
    for b0 in range(0, n, block):
        b1 = min(n, b0 + block)
        idx = (np.arange(b0, b1) * p.hop)[:, None] + np.arange(p.win_length)[None, :]
        mel[b0:b1] = (np.abs(np.fft.rfft(xp[idx] * win, n=p.n_fft, axis=-1)) ** 2) @ fb.T
    if p.log_gain is None:
        db = 10.0 * np.log10(np.maximum(mel, 1e-10))
        db = np.maximum(db, db.max() - p.top_db)
    else:
        db = np.log1p(p.log_gain * mel / max(mel.max(), 1e-20))
    flux = np.zeros(n)
    flux[1:] = np.maximum(0.0, db[1:] - db[:-1]).mean(axis=1)
    return flux


def peak_pick(env: np.ndarray, pre_max: int, post_max: int, pre_avg: int, post_avg: int, delta: float,
              wait: int) -> np.ndarray:
    """librosa-style peak picking: n is a peak when ``env[n] == max(env[n-pre_max : n+post_max+1])``,
    ``env[n] > 0``, ``env[n] >= mean(env[n-pre_avg : n+post_avg+1]) + delta`` (both windows clipped to the
    signal) and n is at least ``wait`` frames after the previous peak. Returns (k,) int64 indices."""
    return _peaks(np.asarray(env, dtype=np.float64), pre_max, post_max, pre_avg, post_avg, delta, wait, None)


def _peaks(env, pre_max, post_max, pre_avg, post_avg, delta, wait, gate):
    N = len(env)
    if N == 0:
        return np.zeros(0, dtype=np.int64)
    n = np.arange(N)
    padded = np.concatenate([np.full(pre_max, -np.inf), env, np.full(post_max, -np.inf)])
    mx = np.lib.stride_tricks.sliding_window_view(padded, pre_max + post_max + 1).max(axis=1)
    c = np.concatenate([[0.0], np.cumsum(env)])
    lo, hi = np.maximum(0, n - pre_avg), np.minimum(N, n + post_avg + 1)
    avg = (c[hi] - c[lo]) / (hi - lo)
    ok = (env >= mx) & (env > 0) & (env >= avg + delta)
    if gate is not None:
        ok &= gate
    peaks = []
    last = -np.inf
    for i in np.nonzero(ok)[0]:
        if i - last >= wait:
            peaks.append(i)
            last = i
    return np.asarray(peaks, dtype=np.int64)


def detect_onsets(x: np.ndarray, sample_rate: int, p: OnsetParams, gate: np.ndarray | None = None) -> Onsets:
    """Onsets of mono ``x`` (or (n, channels), averaged): the whole pipeline of the module docs.

    ``gate`` ((n,) bool over envelope frames, optional) keeps only onsets where it is True; the
    refractory ``wait`` counts from the last onset kept (a gated-out peak does not hold the next back).
    """
    flux = spectral_flux(x, sample_rate, p)
    oe = flux - flux.min()
    if p.normalise == "minmax":
        span = flux.max() - flux.min()
        env = oe / span if span > 0 else np.zeros_like(oe)
    elif p.normalise == "percentile":
        env = np.clip(oe / (np.percentile(oe, p.norm_percentile) + 1e-9), 0.0, 1.0)
    else:
        raise ValueError(f"OnsetParams.normalise: unknown rule {p.normalise!r} (minmax or percentile)")
    if gate is not None:
        gate = np.asarray(gate, dtype=bool)
        if gate.shape != env.shape:
            raise ValueError(f"detect_onsets: gate of shape {gate.shape}, expected {env.shape}")
    peaks = _peaks(env, p.pre_max, p.post_max, p.pre_avg, p.post_avg, p.delta, p.wait, gate)
    return Onsets(peaks, env)
