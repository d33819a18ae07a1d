"""Phone labels from pocketsphinx's allphone decoder (its wheel's en-us acoustic model and phone LM).

Settings (pocketsphinx's documented phoneme-recognition settings): ``allphone=en-us-phone.lm.bin``,
``lw=2.0``, ``beam=1e-20``, ``pbeam=1e-20``, 100 frames per second, 16 kHz mono 16-bit input. A 30 fps
frame j takes the phone decoded at its centre, time (j + 0.5) / 30 s.
"""
from __future__ import annotations

import os

import numpy as np

FPS = 30
SETTINGS = {"allphone": "en-us/en-us-phone.lm.bin", "hmm": "en-us/en-us", "lw": 2.0, "beam": 1e-20,
            "pbeam": 1e-20, "samprate": 16000, "frate": 100}


def _decoder():
    try:
        from pocketsphinx import Decoder, get_model_path
    except ImportError:
        raise RuntimeError("face labels need pocketsphinx (pip install pocketsphinx==5.1.1)") from None
    mp = get_model_path()
    return Decoder(hmm=os.path.join(mp, SETTINGS["hmm"]), allphone=os.path.join(mp, SETTINGS["allphone"]),
                   lw=SETTINGS["lw"], beam=SETTINGS["beam"], pbeam=SETTINGS["pbeam"],
                   samprate=SETTINGS["samprate"], frate=SETTINGS["frate"], loglevel="FATAL")


def allphone_segments(audio_16k: np.ndarray) -> list[tuple[str, int, int]]:
    """Mono float audio at 16 kHz in [-1, 1] -> [(phone, first 10 ms frame, last 10 ms frame)]."""
    x = np.asarray(audio_16k, dtype=np.float64).reshape(-1)
    if not np.isfinite(x).all():
        raise ValueError("face labels: audio contains NaN or Inf")
    pcm = (np.clip(x, -1.0, 1.0) * 32767.0).astype("<i2").tobytes()
    d = _decoder()
    d.start_utt()
    d.process_raw(pcm, full_utt=True)
    d.end_utt()
    return [(s.word, int(s.start_frame), int(s.end_frame)) for s in d.seg()]


def frame_phones(segments: list[tuple[str, int, int]], n_frames: int, fps: int = FPS) -> list[str]:
    """Per-frame phone at each 30 fps frame's centre ('SIL' where no segment covers it)."""
    rate = SETTINGS["frate"]
    lab = ["SIL"] * (int(max((e for _, _, e in segments), default=-1)) + 2)
    for p, s, e in segments:
        for f in range(s, e + 1):
            lab[f] = p
    out = []
    for j in range(n_frames):
        f = int((j + 0.5) * rate / fps)
        out.append(lab[f] if f < len(lab) else "SIL")
    return out


def label_audio(audio_16k: np.ndarray, n_frames: int | None = None) -> list[str]:
    n = n_frames if n_frames is not None else int(np.ceil(len(audio_16k) * FPS / 16000))
    return frame_phones(allphone_segments(audio_16k), n)
