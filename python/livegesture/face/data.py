"""Training and evaluation clips of the face head: 16 kHz audio, its log-mel frames (the runtime's frontend)
and per-frame (30 fps) phone labels from pocketsphinx (:mod:`.labels`), cached under a folder by content
hash so that a clip is decoded once."""
from __future__ import annotations

import hashlib
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..frontend import FrontendConfig, logmel_frames
from .labels import SETTINGS, label_audio

FRONTEND = FrontendConfig()
TOKEN_SAMPLES = FRONTEND.sample_rate * FRONTEND.frames_per_token / FRONTEND.fps


@dataclass
class Clip:
    name: str
    audio: np.ndarray        # float64 (n,), 16 kHz
    n_frames: int            # ceil(duration * 30): the frames the runtime emits
    mel: np.ndarray          # (n_tokens * 8, 64) float32, the last partial token completed with silence
    phones: list[str]        # (n_frames,)


def n_frames_of(n_samples: int) -> int:
    return -(-n_samples * FRONTEND.fps // FRONTEND.sample_rate)


def clip_mel(audio: np.ndarray) -> np.ndarray:
    """Log-mel frames of every token that covers the audio (the last one completed with silence), as the
    runtime computes them at the end of a stream (docs/output.md)."""
    n_tok = -(-n_frames_of(len(audio)) // FRONTEND.frames_per_token)
    need = int(FRONTEND.token_end(n_tok - 1))
    x = np.concatenate([np.asarray(audio, np.float64), np.zeros(max(0, need - len(audio)))])
    return logmel_frames(x, 0, n_tok * FRONTEND.mel_frames_per_token, FRONTEND)


def make_clip(name: str, audio: np.ndarray, cache_dir: Path | None) -> Clip:
    audio = np.asarray(audio, dtype=np.float64).reshape(-1)
    n = n_frames_of(len(audio))
    phones = None
    if cache_dir is not None:
        key = hashlib.sha256(audio.astype(np.float32).tobytes() + json.dumps(SETTINGS).encode()).hexdigest()[:20]
        f = Path(cache_dir) / f"{key}.json"
        if f.exists():
            phones = json.loads(f.read_text())
    if phones is None:
        phones = label_audio(audio, n)
        if cache_dir is not None:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
            f.write_text(json.dumps(phones))
    return Clip(name, audio, n, clip_mel(audio), phones)


def real_clips(split: str, cache_dir: Path | None, real_dir=None, channels: bool = False) -> list[Clip]:
    """The real-speech recordings of ``split`` (``train`` or ``validation``; :mod:`..data.real_speech`).
    ``channels``: a multi-channel file gives one clip per channel (training); else channels are averaged as
    the runtime does."""
    from scipy.io import wavfile

    from ..data import real_speech
    from ..data.beat2 import _resample, load_audio

    out = []
    for p in real_speech.split_paths(split, real_dir):
        if channels:
            sr, raw = wavfile.read(p)
            if raw.ndim == 2:
                for c in range(raw.shape[1]):
                    x = raw[:, c].astype(np.float64) / (32768.0 if raw.dtype == np.int16 else 1.0)
                    if sr != FRONTEND.sample_rate:
                        x = _resample(x, int(sr), FRONTEND.sample_rate)
                    out.append(make_clip(f"{p.stem}.ch{c}", x, cache_dir))
                continue
        out.append(make_clip(p.stem, load_audio(p), cache_dir))
    return out


def synthetic_clips(n: int, seconds: float, seed: int, cache_dir: Path | None) -> list[Clip]:
    """``n`` clips of synthetic speech (the corpus generator's grammar, styles and voices: espeak-ng and
    Festival-Lite), labelled by the same allphone decoder as the real speech."""
    from ..data.synth_speech import EXTRA_VOICES, STYLES, ClipPlan, synth_speech

    rng = np.random.default_rng(seed)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            style = STYLES[i % len(STYLES)]
            voices = style.voices + EXTRA_VOICES.get(style.speaker, ())
            plan = ClipPlan(i, f"face_synth_{i}", style.speaker, "train", int(seconds * FRONTEND.sample_rate),
                            (seed, i))
            audio, _ = synth_speech(plan, style, rng, Path(tmp), voices)
            out.append(make_clip(plan.id, audio, cache_dir))
    return out
