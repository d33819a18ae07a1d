"""Audio augmentation for training: make clean synthetic speech look like speech as users record it.

    from livegesture.data.augment import augment
    y = augment(wave, 16000, np.random.default_rng(seed))        # same length as wave, float in [-1, 1]

One call draws a random chain of channel effects; every random choice comes from ``rng``, so the same
generator state gives the same output (deterministic per rng). Effects, each applied with its own
probability (:class:`AugmentConfig`), in this order:

1. **pitch** shift of up to +-``pitch_semitones`` with the duration kept (resample, then WSOLA time-stretch
   back to the original length) — motion aligned to the clean wave stays aligned;
2. **tempo** change (WSOLA time-stretch, pitch kept) by a factor in ``tempo_range``: this CHANGES the
   length, so it is off unless ``tempo=True`` (for callers that derive the motion from the augmented wave,
   like the corpus generator, or that rescale the motion themselves);
3. **reverberation**: a synthetic room impulse response (direct path + exponentially decaying noise tail,
   RT60 in ``rt60_range``), wet/dry mix;
4. **band limits**: telephone (300-3400 Hz through an 8 kHz resampling, the narrowest), other low-pass
   corners down to 3.4 kHz, and/or a high-pass (small microphones);
5. **codec-like artefacts**: G.711 mu-law 8-bit companding, coarse PCM quantisation, or a low-bitrate
   transform codec imitation (STFT magnitudes quantised, weak high-frequency bins dropped);
6. **noise** at an SNR drawn from ``snr_db`` (measured over the speech's active frames): white, pink,
   brown, mains hum with harmonics, or babble (time-shifted, reversed copies of the wave itself);
7. **gain** over ``gain_db``, then clipping to [-1, 1] (a hot recording clips, as real ones do).

The module needs only numpy and scipy (the project's dependencies), so any training loop — LiveGesture's
``livegesture.train`` or another model family's — can use it.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import gcd

import numpy as np

__all__ = ["AugmentConfig", "augment", "pitch_shift", "time_stretch", "reverb", "band_limit", "codec",
           "add_noise", "EFFECTS"]

EFFECTS = ("pitch", "tempo", "reverb", "band", "codec", "noise", "gain")


@dataclass(frozen=True)
class AugmentConfig:
    p_pitch: float = 0.35
    pitch_semitones: float = 3.0
    p_tempo: float = 0.5                   # only with tempo=True
    tempo_range: tuple[float, float] = (0.85, 1.15)
    p_reverb: float = 0.35
    rt60_range: tuple[float, float] = (0.15, 0.9)
    p_band: float = 0.4
    p_codec: float = 0.25
    p_noise: float = 0.6
    snr_db: tuple[float, float] = (0.0, 30.0)
    p_gain: float = 0.9
    gain_db: tuple[float, float] = (-24.0, 8.0)


# ----------------------------------------------------------------------------- helpers

def _resample(x: np.ndarray, up: int, down: int) -> np.ndarray:
    from scipy.signal import resample_poly
    g = gcd(up, down)
    return resample_poly(x, up // g, down // g)


def _fit(x: np.ndarray, n: int) -> np.ndarray:
    """Cut or zero-pad to n samples."""
    if len(x) >= n:
        return x[:n]
    return np.concatenate([x, np.zeros(n - len(x))])


def _active_power(x: np.ndarray, sr: int) -> float:
    """Mean power over the loudest frames (speech activity: frames within 30 dB of the 95th percentile)."""
    hop = max(1, sr // 100)
    n = len(x) // hop
    if n < 1:
        return float(np.mean(x * x)) + 1e-12
    p = (x[:n * hop].reshape(n, hop) ** 2).mean(1) + 1e-12
    db = 10 * np.log10(p)
    act = db > np.percentile(db, 95) - 30
    return float(p[act].mean())


# ----------------------------------------------------------------------------- effects

def time_stretch(x: np.ndarray, rate: float, sr: int = 16000, frame_s: float = 0.032,
                 tol_s: float = 0.01) -> np.ndarray:
    """WSOLA time-scale modification: ``rate`` > 1 plays faster (output ``len(x) / rate`` samples), the
    pitch is kept. Hann frames of ``frame_s`` at 50 % overlap; each input frame is shifted by up to
    ``tol_s`` to best continue the previous one (cross-correlation)."""
    x = np.asarray(x, np.float64)
    N = max(16, int(frame_s * sr)) // 2 * 2
    hs = N // 2
    tol = int(tol_s * sr)
    n_out = int(round(len(x) / rate))
    if n_out < N or len(x) < N + 2 * tol:       # too short to stretch: plain interpolation
        return np.interp(np.linspace(0, len(x) - 1, n_out), np.arange(len(x)), x) if n_out > 0 else np.zeros(0)
    win = np.hanning(N + 2)[1:-1]
    xp = np.concatenate([np.zeros(tol), x, np.zeros(N + 2 * tol + hs)])
    n_frames = n_out // hs + 1
    y = np.zeros(n_frames * hs + N)
    wsum = np.zeros_like(y)
    prev = 0                                 # input position (in x) of the previous frame
    for k in range(n_frames):
        nominal = int(round(k * hs * rate))
        if k == 0:
            pos = nominal
        else:
            target = xp[tol + prev + hs: tol + prev + hs + N]     # natural continuation of the last frame
            seg = xp[nominal: nominal + N + 2 * tol]              # candidates nominal-tol .. nominal+tol
            if len(seg) < N + 2 * tol or not target.any():
                pos = nominal
            else:
                c = np.correlate(seg, target, mode="valid")
                pos = nominal - tol + int(np.argmax(c))
        pos = max(0, pos)
        fr = xp[tol + pos: tol + pos + N]
        if len(fr) < N:
            fr = _fit(fr, N)
        y[k * hs: k * hs + N] += win * fr
        wsum[k * hs: k * hs + N] += win
        prev = pos
    y = y / np.maximum(wsum, 1e-3)
    return y[:n_out]


def pitch_shift(x: np.ndarray, semitones: float, sr: int = 16000) -> np.ndarray:
    """Pitch up by ``semitones`` (down if negative) with the length kept: resample to ``1 / r`` of the
    length (``r = 2^(s/12)``, played at the same rate: pitch times r, r times faster), then WSOLA-stretch
    back to the original length."""
    from fractions import Fraction
    x = np.asarray(x, np.float64)
    fr = Fraction(2.0 ** (semitones / 12.0)).limit_denominator(64)   # r ~ p/q with small factors
    y = _resample(x, fr.denominator, fr.numerator)
    if len(y) == 0:
        return np.zeros_like(x)
    return _fit(time_stretch(y, len(y) / len(x), sr), len(x))


def reverb(x: np.ndarray, sr: int, rng: np.random.Generator, rt60: float | None = None,
           wet: float | None = None) -> np.ndarray:
    """Convolution with a synthetic room impulse response; the output keeps the input's active power."""
    from scipy.signal import fftconvolve
    rt60 = rng.uniform(0.15, 0.9) if rt60 is None else rt60
    wet = rng.uniform(0.3, 1.0) if wet is None else wet
    n = int(min(rt60, 1.2) * sr)
    t = np.arange(n) / sr
    tail = rng.normal(size=n) * np.exp(-6.9 * t / rt60)       # -60 dB at rt60
    pre = int(rng.uniform(0.002, 0.02) * sr)                  # pre-delay before the diffuse tail
    tail[:pre] = 0.0
    if rng.random() < 0.7:                                    # wall absorption: duller tail
        from scipy.signal import lfilter
        a = rng.uniform(0.2, 0.7)
        tail = lfilter([1 - a], [1, -a], tail)
    tail /= np.sqrt((tail ** 2).sum()) + 1e-12
    h = wet * tail
    h[0] += 1.0
    y = fftconvolve(x, h)[:len(x)]
    return y * np.sqrt(_active_power(x, sr) / _active_power(y, sr))


def band_limit(x: np.ndarray, sr: int, rng: np.random.Generator, kind: str | None = None) -> np.ndarray:
    """``telephone`` (300-3400 Hz band, through 8 kHz), ``lowpass`` (corner 3.4-7 kHz) or ``highpass``
    (corner 100-400 Hz)."""
    from scipy.signal import butter, sosfilt
    kind = kind or str(rng.choice(["telephone", "telephone", "lowpass", "highpass"]))
    if kind == "telephone":
        y = _resample(x, 8000, sr) if sr > 8000 else x
        sos = butter(4, [300, 3400], btype="bandpass", fs=min(sr, 8000), output="sos")
        y = sosfilt(sos, y)
        return _fit(_resample(y, sr, 8000), len(x)) if sr > 8000 else y
    if kind == "lowpass":
        fc = min(rng.uniform(3400, 7000), 0.45 * sr)
        return sosfilt(butter(int(rng.integers(4, 9)), fc, btype="lowpass", fs=sr, output="sos"), x)
    if kind == "highpass":
        return sosfilt(butter(2, rng.uniform(100, 400), btype="highpass", fs=sr, output="sos"), x)
    raise ValueError(f"band_limit: unknown kind {kind!r} (telephone, lowpass, highpass)")


def codec(x: np.ndarray, sr: int, rng: np.random.Generator, kind: str | None = None) -> np.ndarray:
    """``mulaw`` (G.711 8-bit companding), ``pcm`` (6-10 bit uniform quantisation) or ``transform`` (STFT
    magnitudes quantised on a log scale, bins 25-45 dB below the frame's peak dropped, as a low-bitrate
    perceptual codec leaves holes)."""
    kind = kind or str(rng.choice(["mulaw", "pcm", "transform", "transform"]))
    x = np.clip(x, -1, 1)
    if kind == "mulaw":
        mu = 255.0
        c = np.sign(x) * np.log1p(mu * np.abs(x)) / np.log1p(mu)
        c = np.round(c * 127.5) / 127.5
        return np.sign(c) * np.expm1(np.abs(c) * np.log1p(mu)) / mu
    if kind == "pcm":
        q = 2.0 ** int(rng.integers(6, 11))
        peak = np.abs(x).max() + 1e-9
        return np.round(x / peak * q) / q * peak
    if kind == "transform":
        from scipy.signal import istft, stft
        nper = 512 if sr >= 16000 else 256
        _, _, Z = stft(x, fs=sr, nperseg=nper)
        mag, ph = np.abs(Z), np.angle(Z)
        step_db = rng.uniform(1.5, 4.0)
        ldb = 20 * np.log10(mag + 1e-9)
        ldb = np.round(ldb / step_db) * step_db
        floor = ldb.max(0, keepdims=True) - rng.uniform(25, 45)
        mag = np.where(ldb > floor, 10 ** (ldb / 20), 0.0)
        cut = rng.uniform(0.55, 1.0) * (Z.shape[0] - 1)      # bandwidth of the codec
        mag[int(cut):] = 0.0
        _, y = istft(mag * np.exp(1j * ph), fs=sr, nperseg=nper)
        return _fit(y, len(x))
    raise ValueError(f"codec: unknown kind {kind!r} (mulaw, pcm, transform)")


def _colored(n: int, rng: np.random.Generator, exponent: float) -> np.ndarray:
    """Noise with power spectrum ~ 1 / f^exponent (0 white, 1 pink, 2 brown)."""
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.arange(len(spec), dtype=np.float64)
    f[0] = 1.0
    return np.fft.irfft(spec / f ** (exponent / 2), n)


def add_noise(x: np.ndarray, sr: int, rng: np.random.Generator, snr_db: float | None = None,
              kind: str | None = None) -> np.ndarray:
    """Add ``white``, ``pink``, ``brown``, ``hum`` or ``babble`` noise at ``snr_db`` (signal power over its
    active frames)."""
    n = len(x)
    snr_db = rng.uniform(0, 30) if snr_db is None else snr_db
    kind = kind or str(rng.choice(["white", "pink", "pink", "brown", "hum", "babble", "babble"]))
    if kind in ("white", "pink", "brown"):
        v = _colored(n, rng, {"white": 0.0, "pink": 1.0, "brown": 2.0}[kind])
    elif kind == "hum":
        t = np.arange(n) / sr
        f0 = float(rng.choice([50.0, 60.0]))
        v = sum(rng.uniform(0.2, 1.0) / h * np.sin(2 * np.pi * f0 * h * t + rng.uniform(0, 6)) for h in range(1, 8))
        v = v + 0.1 * _colored(n, rng, 1.0)
    elif kind == "babble":
        v = np.zeros(n)
        for _ in range(int(rng.integers(3, 7))):
            seg = x[::-1] if rng.random() < 0.5 else x
            v += np.roll(seg, int(rng.integers(0, max(1, n)))) * rng.uniform(0.5, 1.0)
    else:
        raise ValueError(f"add_noise: unknown kind {kind!r}")
    pv = float(np.mean(v * v)) + 1e-12
    return x + v * np.sqrt(_active_power(x, sr) / pv / 10 ** (snr_db / 10))


# ----------------------------------------------------------------------------- the chain

def augment(wave: np.ndarray, sr: int, rng: np.random.Generator, cfg: AugmentConfig = AugmentConfig(),
            tempo: bool = False, return_log: bool = False):
    """A random chain of the effects above (see the module doc). ``wave``: 1-D float samples in [-1, 1].
    Returns float32 samples in [-1, 1] of the same length (``tempo=True``: possibly another length), and
    with ``return_log`` also the list of applied effects with their parameters."""
    x = np.asarray(wave, np.float64).reshape(-1)
    if x.ndim != 1 or len(x) == 0:
        raise ValueError(f"augment: expected a non-empty 1-D wave, got shape {np.shape(wave)}")
    if not np.isfinite(x).all():
        raise ValueError("augment: wave contains NaN or Inf")
    log = []
    silent = not np.any(np.abs(x) > 1e-6)
    if not silent and rng.random() < cfg.p_pitch:
        s = float(rng.uniform(-cfg.pitch_semitones, cfg.pitch_semitones))
        x = pitch_shift(x, s, sr)
        log.append(("pitch", round(s, 2)))
    if tempo and not silent and rng.random() < cfg.p_tempo:
        r = float(rng.uniform(*cfg.tempo_range))
        x = time_stretch(x, r, sr)
        log.append(("tempo", round(r, 3)))
    if not silent and rng.random() < cfg.p_reverb:
        rt = float(rng.uniform(*cfg.rt60_range))
        x = reverb(x, sr, rng, rt60=rt)
        log.append(("reverb", round(rt, 2)))
    if rng.random() < cfg.p_band:
        kind = str(rng.choice(["telephone", "telephone", "lowpass", "highpass"]))
        x = band_limit(x, sr, rng, kind)
        log.append(("band", kind))
    if rng.random() < cfg.p_codec:
        kind = str(rng.choice(["mulaw", "pcm", "transform", "transform"]))
        x = codec(x, sr, rng, kind)
        log.append(("codec", kind))
    if not silent and rng.random() < cfg.p_noise:
        snr = float(rng.uniform(*cfg.snr_db))
        kind = str(rng.choice(["white", "pink", "pink", "brown", "hum", "babble", "babble"]))
        x = add_noise(x, sr, rng, snr, kind)
        log.append(("noise", kind, round(snr, 1)))
    if rng.random() < cfg.p_gain:
        g = float(rng.uniform(*cfg.gain_db))
        peak = np.abs(x).max() + 1e-9
        x = x / peak * min(peak, 0.9) * 10 ** (g / 20)   # gain relative to a sane level; may clip
        log.append(("gain", round(g, 1)))
    y = np.clip(x, -1.0, 1.0).astype(np.float32)
    return (y, log) if return_log else y
