"""Synthetic BEAT2-layout corpus: espeak-ng speech and SMPL-X motion computed from that same audio.

BEAT2 cannot be downloaded on our machines (docs/data.md), so the shipped model learns from this::

    python -m livegesture.data.synth --out DIR --minutes N --seed S [--jobs J]

writes exactly the BEAT2 layout of docs/data.md into ``DIR``: ``smplxflame_30/{id}.npz``,
``wave16k/{id}.wav`` (16 kHz mono int16), ``textgrid/{id}.TextGrid`` (a ``words`` tier, approximate
timing) and ``train_test_split.csv``. ``--minutes`` is the total audio duration. Needs the ``espeak-ng``
program (``apt-get install -y espeak-ng``). The same seed gives byte-identical files, whatever ``--jobs``.

Options for training data that transfers to real speech (issue 16; the defaults give the original corpus):
``--engines espeak-ng,flite`` adds, per speaker style, more espeak-ng accents and variants and the
Festival-Lite voices (``flite``: kal at 8 kHz, kal16, awb, rms, slt;
:data:`~livegesture.data.synth_speech.EXTRA_VOICES`); Debian has no mbrola voices (non-free), so there are
none. ``--real-variants N`` adds the real-speech TRAIN split
(:mod:`livegesture.data.real_speech`; never its VALIDATION split) N times per recording (variant 0 as
recorded, the others pitch-shifted and tempo-changed), with motion computed from that audio by the same motion
model as every synthetic clip. Channel degradations (noise, reverberation, band limits, codecs) are not
baked in: ``python -m livegesture.train --augment N`` draws them (:mod:`livegesture.data.augment`).

The speech (sentence grammar, speaker styles, espeak-ng and flite) is :mod:`livegesture.data.synth_speech`;
the audio analysis and the motion model (the full description of the motion) are
:mod:`livegesture.data.synth_motion`. This module plans the corpus (clip lengths, speakers, splits, the
real-speech clips) and writes it.

Public API: :func:`main`, :func:`generate_corpus`, :func:`plan_corpus`, :func:`plan_real_clips`,
:func:`onset_times` (from :mod:`~livegesture.data.synth_motion`), :func:`write_npz`, :class:`ClipPlan`.
"""
from __future__ import annotations

import argparse
import io
import os
import shutil
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from ..regions import FPS, SAMPLE_RATE
from .synth_motion import STROKE_DRIVES, analyse_audio, generate_motion
from .synth_motion import onset_times  # noqa: F401  (a public entry point of this module)
from .synth_speech import (ENGINES, ESPEAK, EXTRA_VOICES, FLITE, STYLE_BY_SPEAKER, STYLES, ClipPlan,
                           synth_speech)


# ----------------------------------------------------------------------------- corpus plan

def plan_corpus(minutes: float, seed: int, clip_seconds: tuple[float, float] = (20.0, 60.0),
                min_clips: int = 8) -> list[ClipPlan]:
    """Clip ids, speakers, splits and exact lengths (samples) summing to ``minutes`` of audio."""
    if minutes <= 0:
        raise ValueError("--minutes must be positive")
    lo, hi = clip_seconds
    if not 0 < lo <= hi:
        raise ValueError(f"bad clip length range {clip_seconds}")
    rng = np.random.default_rng([seed, 0x5EED])
    total = int(round(minutes * 60 * SAMPLE_RATE))
    scale = min(1.0, minutes * 60 / (min_clips * (lo + hi) / 2))  # tiny corpora: shorter clips, >= min_clips
    lo_s, hi_s = int(lo * scale * SAMPLE_RATE), int(hi * scale * SAMPLE_RATE)
    lengths, left = [], total
    while left > 0:
        n = int(rng.integers(lo_s, hi_s + 1))
        if left - n < lo_s:            # the remainder would be too short: take it all (or split it in two)
            n = left if left <= hi_s else left // 2
        lengths.append(n)
        left -= n
    n_clips = len(lengths)
    # speakers: speaker 2 gets its share (and at least 5 clips when possible), others round-robin
    shares = np.array([s.clip_share for s in STYLES])
    counts = np.floor(shares / shares.sum() * n_clips).astype(int)
    counts[0] = max(counts[0], min(5, n_clips))
    while counts.sum() > n_clips:
        i = int(np.argmax(counts[1:])) + 1 if counts[1:].sum() > 0 else 0
        counts[i] -= 1
    k = 1
    while counts.sum() < n_clips:
        counts[k % len(STYLES)] += 1
        k += 1
    speakers = np.repeat([s.speaker for s in STYLES], counts)
    speakers = speakers[rng.permutation(n_clips)]
    plans, per_spk = [], {}
    splits: dict[int, list[str]] = {}
    for s in STYLES:
        n = int((speakers == s.speaker).sum())
        if n >= 3:
            n_test, n_val = max(1, round(0.15 * n)), max(1, round(0.1 * n))
        else:
            n_test = n_val = 0
        n_add = round(0.1 * n) if (s.speaker != 2 and n >= 10) else 0
        lab = ["test"] * n_test + ["val"] * n_val + ["additional"] * n_add
        lab += ["train"] * (n - len(lab))
        splits[s.speaker] = [lab[i] for i in rng.permutation(n)]
    for i, (spk, n) in enumerate(zip(speakers, lengths)):
        spk = int(spk)
        k = per_spk.get(spk, 0)
        per_spk[spk] = k + 1
        st = STYLE_BY_SPEAKER[spk]
        plans.append(ClipPlan(index=i, id=f"{spk}_{st.name}_0_{k + 1}_{k + 1}", speaker=spk,
                              split=splits[spk][k], n_samples=int(n), seed=(seed, i)))
    return plans


# ----------------------------------------------------------------------------- writing

def write_npz(path: str | Path, arrays: dict[str, np.ndarray]):
    """Like ``np.savez`` but byte-deterministic (fixed zip timestamps)."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
        for k, v in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(v), allow_pickle=False)
            zi = zipfile.ZipInfo(f"{k}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            zi.compress_type = zipfile.ZIP_STORED
            zi.external_attr = 0o644 << 16
            zf.writestr(zi, buf.getvalue())
    os.replace(tmp, path)


def _write_wav(path: Path, audio: np.ndarray):
    from scipy.io import wavfile

    pcm = np.clip(np.round(audio.astype(np.float64) * 32767.0), -32768, 32767).astype(np.int16)
    tmp = path.with_suffix(".wav.tmp")
    wavfile.write(tmp, SAMPLE_RATE, pcm)
    os.replace(tmp, path)


def _textgrid(words: list[tuple[float, float, str]], dur: float) -> str:
    iv, cur = [], 0.0
    for s, e, w in words:
        if s > cur + 1e-4:
            iv.append((cur, s, ""))
        s = max(s, cur)
        iv.append((s, e, w))
        cur = e
    if cur < dur - 1e-4:
        iv.append((cur, dur, ""))
    lines = ['File type = "ooTextFile"', 'Object class = "TextGrid"', "", "xmin = 0 ", f"xmax = {dur:.4f} ",
             "tiers? <exists> ", "size = 1 ", "item []: ", "    item [1]:", '        class = "IntervalTier" ',
             '        name = "words" ', "        xmin = 0 ", f"        xmax = {dur:.4f} ",
             f"        intervals: size = {len(iv)} "]
    for k, (s, e, w) in enumerate(iv, 1):
        lines += [f"        intervals [{k}]:", f"            xmin = {s:.4f} ", f"            xmax = {e:.4f} ",
                  f'            text = "{w}" ']
    return "\n".join(lines) + "\n"


def _real_audio(plan: ClipPlan, rng: np.random.Generator) -> np.ndarray:
    """A real recording's channel at 16 kHz; variants > 0 get a pitch shift (+-3 semitones) and a tempo
    change (0.85-1.15), both through :mod:`livegesture.data.augment` (the motion is computed afterwards,
    from the changed audio, so it follows the change)."""
    from .augment import pitch_shift, time_stretch
    from .beat2 import load_audio, _resample
    if plan.channel is None:
        x = load_audio(plan.source, SAMPLE_RATE).astype(np.float64)
    else:
        from scipy.io import wavfile
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sr, raw = wavfile.read(plan.source)
        raw = raw[:, plan.channel]
        x = raw.astype(np.float64) / (32768.0 if raw.dtype == np.int16 else 1.0)
        if sr != SAMPLE_RATE:
            x = _resample(x, int(sr), SAMPLE_RATE).astype(np.float64)
    if plan.variant > 0:
        x = pitch_shift(x, float(rng.uniform(-3, 3)), SAMPLE_RATE)
        x = time_stretch(x, float(rng.uniform(0.85, 1.15)), SAMPLE_RATE)
    return np.clip(x, -1.0, 1.0)


def plan_real_clips(real_dir, variants: int, seed: int, first_index: int) -> list[ClipPlan]:
    """Clips from the real-speech TRAIN split (never VALIDATION; :mod:`livegesture.data.real_speech`):
    every recording (each channel of a multi-channel one: they hold different utterances) ``variants``
    times (variant 0 as recorded, the others pitch- and tempo-changed), with the speaker styles taken in
    turn. Ids ``{speaker}_{name}_9_{n}_{n}``, split ``train``."""
    from . import real_speech
    from .beat2 import load_audio
    if variants < 1:
        return []
    import warnings
    from scipy.io import wavfile
    plans, per_spk, i = [], {}, first_index
    for path in real_speech.split_paths("train", real_dir):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _, raw = wavfile.read(path, mmap=True)
        nch = 1 if raw.ndim == 1 else raw.shape[1]
        del raw
        channels = [None] if nch == 1 else list(range(nch))
        for chn in channels:
            n0 = len(load_audio(path, SAMPLE_RATE))
            for v in range(variants):
                style = STYLES[(i + v) % len(STYLES)]
                k = per_spk.get(style.speaker, 0) + 1
                per_spk[style.speaker] = k
                plans.append(ClipPlan(index=i, id=f"{style.speaker}_{style.name}_9_{k}_{k}", speaker=style.speaker,
                                      split="train", n_samples=n0, seed=(seed, i), source=str(path),
                                      channel=chn, variant=v))
                i += 1
    return plans


def _clip_job(args):
    """(plan, out folder[, extra voices]) -> writes the clip's files, returns its length in samples."""
    plan, out, *rest = args
    extra = bool(rest and rest[0])
    drive = rest[1] if len(rest) > 1 else "flux"
    import torch
    torch.set_num_threads(1)
    style = STYLE_BY_SPEAKER[plan.speaker]
    rng = np.random.default_rng(list(plan.seed))
    if plan.source is not None:
        audio = _real_audio(plan, rng)
        words: list = []
    else:
        voices = style.voices + EXTRA_VOICES[plan.speaker] if extra else None
        with tempfile.TemporaryDirectory(prefix="lgsynth_") as tmp:
            audio, words = synth_speech(plan, style, rng, Path(tmp), voices)
    n_samples = len(audio)
    # what the loader sees: the int16 file
    pcm_audio = np.clip(np.round(audio.astype(np.float64) * 32767.0), -32768, 32767) / 32768.0
    an = analyse_audio(pcm_audio)
    T = n_samples * FPS // SAMPLE_RATE
    poses, trans, expr = generate_motion(an, T, style, rng, drive)
    out = Path(out)
    _write_wav(out / "wave16k" / f"{plan.id}.wav", audio)
    write_npz(out / "smplxflame_30" / f"{plan.id}.npz", {
        "betas": np.zeros(300, dtype=np.float32),
        "poses": poses, "trans": trans, "expressions": expr,
        "model": np.array("smplx2020"), "gender": np.array("neutral"),
        "mocap_frame_rate": np.array(FPS, dtype=np.int64),
    })
    (out / "textgrid" / f"{plan.id}.TextGrid").write_text(_textgrid(words, n_samples / SAMPLE_RATE))
    return n_samples


def generate_corpus(out: str | Path, minutes: float, seed: int, jobs: int = 1,
                    clip_seconds: tuple[float, float] = (20.0, 60.0), progress: bool = True,
                    overwrite: bool = False, engines: tuple[str, ...] = (ESPEAK,),
                    real_train: str | os.PathLike | None = None, real_variants: int = 0,
                    drive: str = "flux") -> list[ClipPlan]:
    """Write a synthetic corpus in the BEAT2 layout into ``out``; returns the clip plans.

    ``engines``: ``("espeak-ng",)`` (the original corpus, byte for byte) or ``("espeak-ng", "flite")``: every
    style also speaks with :data:`EXTRA_VOICES`. ``real_variants`` > 0 adds the real-speech TRAIN split
    (folder ``real_train``, None = the default location) ``real_variants`` times each, with motion from the
    same motion model (:func:`plan_real_clips`). ``drive``: the strokes' onset drive (:func:`generate_motion`);
    the audio does not depend on it."""
    if drive not in STROKE_DRIVES:
        raise ValueError(f"--stroke-drive {drive}: expected one of {', '.join(STROKE_DRIVES)}")
    bad = [e for e in engines if e not in ENGINES]
    if bad or ESPEAK not in engines:
        raise ValueError(f"--engines {','.join(engines)}: expected espeak-ng, optionally with flite")
    for e in engines:
        if shutil.which(e) is None:
            raise RuntimeError(f"{e} not found: install it (apt-get install -y {e})")
    out = Path(out)
    layout = ("smplxflame_30", "wave16k", "textgrid", "train_test_split.csv")
    existing = [n for n in layout if (out / n).exists()]
    if existing:
        if not overwrite:
            raise FileExistsError(f"{out}: already holds {existing}; pass --overwrite to replace them")
        for n in existing:
            p = out / n
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    for d in layout[:3]:
        (out / d).mkdir(parents=True, exist_ok=True)
    plans = plan_corpus(minutes, seed, clip_seconds)
    plans += plan_real_clips(real_train, real_variants, seed, len(plans))
    extra = FLITE in engines
    tasks = [(p, str(out), extra, drive) for p in plans]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(plans), unit="clip",
                   desc=f"synth corpus ({sum(p.n_samples for p in plans) / SAMPLE_RATE / 60:.1f} min)")
    if jobs > 1:
        import multiprocessing as mp
        ctx = mp.get_context("fork") if sys.platform.startswith("linux") else mp.get_context()
        with ctx.Pool(jobs) as pool:
            for n in pool.imap_unordered(_clip_job, tasks, chunksize=1):
                if bar is not None:
                    bar.update(1)
    else:
        for tk in tasks:
            n = _clip_job(tk)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    csv = "id,type\n" + "".join(f"{p.id},{p.split}\n" for p in plans)
    (out / "train_test_split.csv").write_text(csv)
    return plans


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.data.synth", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output directory (receives the BEAT2 layout)")
    ap.add_argument("--minutes", type=float, required=True, help="total audio duration in minutes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=min(4, os.cpu_count() or 1), help="worker processes")
    ap.add_argument("--clip-seconds", type=float, nargs=2, default=(20.0, 60.0), metavar=("MIN", "MAX"),
                    help="clip length range (shrunk for tiny corpora so that there are at least 8 clips)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing corpus in --out")
    ap.add_argument("--engines", default=ESPEAK, help="comma-separated speech engines: espeak-ng (default, the "
                    "original corpus) or espeak-ng,flite (more voices per style: EXTRA_VOICES)")
    ap.add_argument("--real-variants", type=int, default=0, help="add the real-speech TRAIN split (never the "
                    "validation split) this many times (variant 0 as recorded, others pitch/tempo-changed), "
                    "motion computed from the audio like the synthetic clips")
    ap.add_argument("--real-speech", default=None, help="real-speech folder (default $LIVEGESTURE_REAL_SPEECH "
                    "or shared/data/real-speech beside the repository)")
    ap.add_argument("--stroke-drive", default="flux", choices=STROKE_DRIVES,
                    help="what picks and scales the arm strokes, nods and flicks at each onset: flux (spectral-flux "
                    "onset strength, the original corpus), loudness (the energy envelope at the onset), syllable "
                    "(its mean over the first 60 ms; the onset's events start 60 ms later) or syllable-body "
                    "(syllable for the body, the brows on the flux strength)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    t0 = time.time()
    try:
        plans = generate_corpus(a.out, a.minutes, a.seed, max(1, a.jobs), tuple(a.clip_seconds),
                                progress=not a.no_progress, overwrite=a.overwrite,
                                engines=tuple(e.strip() for e in a.engines.split(",") if e.strip()),
                                real_train=a.real_speech, real_variants=a.real_variants, drive=a.stroke_drive)
    except (RuntimeError, FileExistsError, FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    counts: dict[str, int] = {}
    for p in plans:
        key = f"speaker {p.speaker} {p.split}"
        counts[key] = counts.get(key, 0) + 1
    print(f"wrote {len(plans)} clips ({sum(p.n_samples for p in plans) / SAMPLE_RATE / 60:.2f} min) to {a.out} "
          f"in {time.time() - t0:.1f} s: " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())),
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
