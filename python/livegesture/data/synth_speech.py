"""Speech of the synthetic corpus (:mod:`livegesture.data.synth`): the sentence grammar, the five speaker
styles (voices and rates, and the gesture parameters :mod:`livegesture.data.synth_motion` reads), the
espeak-ng and flite engines, the clip plan record, and :func:`synth_speech`, one clip's audio and word timing.

Audio: random sentences from a small grammar and word list, one espeak-ng call per phrase with the clip's
voice and per-phrase rate/pitch/amplitude jitter, pauses between phrases and sentences (and occasional
long pauses), resampled 22050 -> 16000 Hz, a random spectral tilt and a low noise floor.
"""
from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..regions import SAMPLE_RATE

ESPEAK = "espeak-ng"
FLITE = "flite"
ENGINES = (ESPEAK, FLITE)
ESPEAK_RATE = 22050

# ----------------------------------------------------------------------------- text

_W = {
    "det": "the a this that every some my our your their another each".split(),
    "adj": ("small big little old new young good great long short strange simple quiet bright dark warm cold "
            "early late happy serious careful famous local open whole real best final next important "
            "beautiful difficult different easy natural personal public special").split(),
    "noun": ("house garden river city story idea problem friend teacher student window morning evening "
             "question answer reason market music family country picture water paper mountain road train "
             "project meeting language company village summer winter weekend result moment system table "
             "office letter kitchen camera doctor party season ocean forest history science movie dinner "
             "computer phone street number minute voice lesson game journey decision").split(),
    "verb": ("found made took saw told gave built wrote brought kept left showed bought changed opened "
             "started finished visited remember need like want love know see make take find build "
             "explain understand believe follow discuss prepare describe improve").split(),
    "adv": ("really always never often quickly slowly finally suddenly probably actually certainly "
            "honestly simply clearly usually almost").split(),
    "prep": "in on with about from after before during under over through around near behind".split(),
    "conj": "and but so because although while when since".split(),
    "pron": "I we you they she he".split(),
    "intj": "well okay right so yes now look".split(),
}
_TEMPLATES = (
    "pron verb det noun",
    "det adj noun verb prep det noun",
    "pron adv verb det adj noun",
    "conj pron verb prep det noun",
    "intj pron verb det noun",
    "det noun prep det adj noun",
    "pron verb det adj noun prep det noun",
    "conj det noun adv verb",
    "pron adv verb",
    "det adj noun",
    "intj det noun verb det adj noun",
)


def _phrase(rng: np.random.Generator) -> list[str]:
    tpl = _TEMPLATES[rng.integers(len(_TEMPLATES))].split()
    return [_W[c][rng.integers(len(_W[c]))] for c in tpl]


def _syllables(word: str) -> int:
    v, n, prev = "aeiouy", 0, False
    for ch in word.lower():
        cur = ch in v
        n += cur and not prev
        prev = cur
    if word.lower().endswith("e") and n > 1:
        n -= 1
    return max(1, n)


# ----------------------------------------------------------------------------- speaker styles

@dataclass(frozen=True)
class Style:
    speaker: int
    name: str
    voices: tuple[str, ...]
    rate: tuple[float, float]         # espeak words per minute
    pitch: tuple[float, float]        # espeak pitch 0..99
    amp: float                        # stroke amplitude scale
    right_prob: float                 # dominant hand = right with this probability per stroke
    both_prob: float                  # both hands
    gesture_rate: float               # probability that a stressed onset gets an arm stroke
    min_gap: float                    # seconds between strokes of one arm
    tau: tuple[float, float]          # stroke rise time range (s)
    stroke_weights: tuple[float, float, float, float]  # beat, sweep, push, point
    rest: str                         # rest posture: hang, clasp, front
    raise_amount: float               # elbow flexion added while speaking
    nod_amp: float
    nod_rate: float
    sway: float
    jaw_gain: float
    expr_gain: float
    shift_rate: float                 # weight shifts per second
    step_prob: float                  # probability that a weight shift is a step
    pause_scale: float
    clip_share: float                 # share of the corpus


STYLES: tuple[Style, ...] = (
    Style(2, "scott", ("en-us", "en-us+m3", "en+m1", "en-gb-x-rp", "en-us+f2"), (150, 185), (38, 58),
          1.0, 0.7, 0.25, 0.75, 0.32, (0.15, 0.2), (0.5, 0.2, 0.15, 0.15), "hang", 1.0, 0.09, 0.6, 1.0,
          0.26, 1.0, 1 / 9, 0.3, 1.0, 0.6),
    Style(1, "wayne", ("en", "en+m2"), (160, 200), (30, 50),
          1.35, 0.55, 0.45, 0.85, 0.28, (0.13, 0.17), (0.35, 0.35, 0.2, 0.1), "front", 1.1, 0.12, 0.7, 1.4,
          0.3, 1.3, 1 / 7, 0.35, 0.8, 0.1),
    Style(3, "solomon", ("en+m3", "en-gb-scotland"), (125, 155), (28, 45),
          0.7, 0.3, 0.15, 0.55, 0.45, (0.19, 0.24), (0.6, 0.1, 0.2, 0.1), "clasp", 0.7, 0.07, 0.5, 0.7,
          0.22, 0.8, 1 / 12, 0.2, 1.3, 0.1),
    Style(4, "lawrence", ("en-us+m1", "en-029"), (140, 175), (40, 60),
          1.15, 0.85, 0.2, 0.7, 0.35, (0.16, 0.2), (0.4, 0.15, 0.3, 0.15), "hang", 0.9, 0.1, 0.55, 1.2,
          0.25, 1.0, 1 / 10, 0.25, 1.0, 0.1),
    Style(6, "carla", ("en+f3", "en-us+f4", "en+f2"), (150, 190), (55, 75),
          1.1, 0.6, 0.35, 0.8, 0.3, (0.14, 0.18), (0.35, 0.3, 0.15, 0.2), "front", 1.0, 0.11, 0.65, 1.1,
          0.24, 1.5, 1 / 8, 0.3, 0.9, 0.1),
)
STYLE_BY_SPEAKER = {s.speaker: s for s in STYLES}


# ----------------------------------------------------------------------------- clip plan record
# (made by livegesture.data.synth.plan_corpus and plan_real_clips; synth_speech reads its length)

@dataclass(frozen=True)
class ClipPlan:
    index: int
    id: str
    speaker: int
    split: str
    n_samples: int
    seed: tuple[int, int]
    source: str | None = None      # a real recording (real-speech TRAIN split) instead of synthetic speech
    channel: int | None = None     # its channel (None: mono, or the channels averaged)
    variant: int = 0               # 0: as recorded; > 0: pitch and tempo changed (motion follows the change)


# ----------------------------------------------------------------------------- speech

def _read_engine_wav(out: Path, amp: int | None = None) -> np.ndarray:
    """A speech engine's 16-bit WAV as float64 mono at SAMPLE_RATE; ``amp`` (percent) scales it when given."""
    from math import gcd

    from scipy.io import wavfile
    from scipy.signal import resample_poly

    sr, x = wavfile.read(out)
    x = x.astype(np.float64) / 32768.0
    if amp is not None:
        x = x * amp / 100.0
    if x.ndim == 2:
        x = x.mean(1)
    if sr != SAMPLE_RATE:
        g = gcd(int(sr), SAMPLE_RATE)
        x = resample_poly(x, SAMPLE_RATE // g, int(sr) // g)
    return x


def _espeak(text: str, voice: str, rate: int, pitch: int, amp: int, gap: int, tmp: Path) -> np.ndarray:
    out = tmp / "phrase.wav"
    cmd = [ESPEAK, "-v", voice, "-s", str(rate), "-p", str(pitch), "-a", str(amp), "-g", str(gap),
           "-w", str(out), text]
    try:
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    except FileNotFoundError:
        raise RuntimeError("espeak-ng not found: install it (apt-get install -y espeak-ng)") from None
    except subprocess.CalledProcessError as e:
        raise RuntimeError(f"espeak-ng failed ({' '.join(cmd)}): {e.stderr.decode(errors='replace')}") from None
    return _read_engine_wav(out)


def _flite(text: str, voice: str, rate: int, pitch: int, amp: int, tmp: Path) -> np.ndarray:
    """Festival-Lite speech at 16 kHz: espeak's words per minute -> duration stretch, espeak's pitch 0..99
    -> target mean f0 (70..270 Hz), amplitude in percent."""
    out = tmp / "phrase.wav"
    f0 = 70 + 2 * pitch
    cmd = [FLITE, "-voice", voice, "--setf", f"duration_stretch={175.0 / max(rate, 60):.3f}",
           "--setf", f"int_f0_target_mean={f0}", "--setf", f"int_f0_target_stddev={0.15 * f0:.0f}",
           "-t", text, "-o", str(out)]
    try:
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    except FileNotFoundError:
        raise RuntimeError("flite not found: install it (apt-get install -y flite) or leave it out of "
                           "--engines") from None
    except subprocess.CalledProcessError as e:
        raise RuntimeError(f"flite failed ({' '.join(cmd)}): {e.stderr.decode(errors='replace')}") from None
    return _read_engine_wav(out, amp)


def _speak(text: str, voice: str, rate: int, pitch: int, amp: int, gap: int, tmp: Path) -> np.ndarray:
    """``voice`` is an espeak-ng voice (``en-us+m3``) or ``flite:<voice>`` (``flite:slt``)."""
    if voice.startswith("flite:"):
        return _flite(text, voice.split(":", 1)[1], rate, pitch, amp, tmp)
    return _espeak(text, voice, rate, pitch, amp, gap, tmp)


# More voices per style for ``--engines espeak-ng,flite`` (``extra_voices``): espeak-ng accents and
# variants (klatt formant synthesis, other male/female variants) and the Festival-Lite voices (kal is
# 8 kHz, i.e. narrowband speech). Debian has no mbrola voices (non-free), so none are used.
EXTRA_VOICES: dict[int, tuple[str, ...]] = {
    2: ("en-us+klatt", "en-gb-x-gbclan", "en-us+m4", "flite:rms", "flite:kal16", "flite:awb", "flite:kal"),
    1: ("en-gb-x-gbcwmd", "en+klatt2", "flite:awb", "flite:rms"),
    3: ("en-gb+m7", "en+croak", "flite:kal16", "flite:kal"),
    4: ("en-029+m5", "en-us+Andy", "flite:rms", "flite:awb"),
    6: ("en+f5", "en-us+f1", "flite:slt", "flite:slt"),
}


def synth_speech(plan: ClipPlan, style: Style, rng: np.random.Generator, tmp: Path,
                 voices: tuple[str, ...] | None = None):
    """-> (audio float32 (n_samples,), words [(start_s, end_s, word)]). ``voices`` defaults to the style's."""
    n_total = plan.n_samples
    voices = voices or style.voices
    voice = voices[rng.integers(len(voices))]
    rate0 = rng.uniform(*style.rate)
    pitch0 = rng.uniform(*style.pitch)
    audio = np.zeros(n_total, dtype=np.float64)
    words: list[tuple[float, float, str]] = []
    pos = int(rng.uniform(0.15, 0.6) * SAMPLE_RATE)
    tail = int(0.25 * SAMPLE_RATE)
    failures = 0
    while pos < n_total - tail and failures < 4:
        n_phr = int(rng.integers(1, 4))
        end_p = rng.choice([".", ".", "?", "!"])
        for j in range(n_phr):
            ws = _phrase(rng)
            if j == 0:
                ws[0] = ws[0].capitalize()
            text = " ".join(ws) + ("," if j < n_phr - 1 else end_p)
            x = _speak(text, voice, int(rate0 * rng.uniform(0.92, 1.08)), int(np.clip(pitch0 + rng.uniform(-6, 6), 0, 99)),
                        int(100 * rng.uniform(0.75, 1.25)), int(rng.integers(0, 2)), tmp)
            loud = np.nonzero(np.abs(x) > 0.02 * (np.abs(x).max() + 1e-9))[0]
            if len(loud) == 0:
                continue
            a, b = max(0, loud[0] - 80), min(len(x), loud[-1] + 160)
            x = x[a:b]
            if pos + len(x) > n_total - tail:
                failures += 1
                break
            failures = 0
            audio[pos:pos + len(x)] += x
            # approximate word timing: the voiced span shared by syllable counts
            wts = np.array([_syllables(w) + 0.3 for w in ws])
            edges = np.concatenate([[0], np.cumsum(wts)]) / wts.sum() * len(x)
            for w, e0, e1 in zip(ws, edges[:-1], edges[1:]):
                words.append(((pos + e0) / SAMPLE_RATE, (pos + e1) / SAMPLE_RATE, w.lower()))
            pos += len(x)
            pause = rng.uniform(0.12, 0.45) if j < n_phr - 1 else rng.uniform(0.5, 1.4)
            if j == n_phr - 1 and rng.random() < 0.25:
                pause = rng.uniform(1.3, 2.8)   # thinking pause: the speaker returns to rest
            pos += int(pause * style.pause_scale * SAMPLE_RATE)
            if pos >= n_total - tail:
                break
    # channel: level, spectral tilt, noise floor
    from scipy.signal import lfilter

    peak = np.abs(audio).max()
    if peak > 0:
        audio *= rng.uniform(0.3, 0.8) / peak
    alpha = np.exp(-2 * np.pi * rng.uniform(800, 3000) / SAMPLE_RATE)
    low = lfilter([1 - alpha], [1, -alpha], audio)
    audio = audio + rng.uniform(-0.4, 0.4) * (audio - low)
    audio += rng.normal(0.0, 10 ** (rng.uniform(-72, -52) / 20), n_total)
    audio = np.clip(audio, -1.0, 1.0)
    return audio.astype(np.float32), words
