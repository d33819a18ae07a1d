"""The real-speech recordings (``shared/data/real-speech/``) and their fixed split.

Sixteen recordings of real people (read speech, broadcast, meetings, narrowband, Mandarin; 8-24 kHz; licences
and credits in the folder's ``SOURCES.md``). They have no motion capture: they are used

- to **check** that a model follows real speech (``VALIDATION``: never used in training, by any family or
  stage; every figure about real speech is reported on this split), and
- optionally to **train** the audio side on real voices (``TRAIN``), with motion computed from the audio by
  the synthetic corpus generator's motion model.

The split is fixed here, once, so that every tool and every model family uses the same one. It balances
duration (about 108 s validation, 103 s train), sources (LibriSpeech, LibriVox, AMI meetings, VCTK,
LJSpeech, AISHELL-1 Mandarin, CMU ARCTIC, TIMIT) and sample rates.
"""
from __future__ import annotations

import os
from pathlib import Path

VALIDATION: tuple[str, ...] = (
    "aishell1_BAC009S0764W0121",
    "ami_trn05_f32",
    "librispeech_198-209-0000",
    "librispeech_other_2609-156975-0007",
    "librispeech_other_3331-159605-0008",
    "librivox_sense01_0920",
    "ljspeech_LJ050-0131",
    "vctk_p240_00000_24k",
)

TRAIN: tuple[str, ...] = (
    "ami_trn01_f32",
    "arctic_a0024",
    "librispeech_3436-172162-0000",
    "librispeech_5703-47212-0000",
    "librispeech_other_3080-5032-0009",
    "librispeech_stereo_2utt",
    "librivox_sense01_0870",
    "timit_LDC93S1",
)

ENV = "LIVEGESTURE_REAL_SPEECH"

assert not set(VALIDATION) & set(TRAIN)


def real_speech_dir(explicit: str | os.PathLike | None = None) -> Path:
    """The recordings' folder: ``explicit``, else ``$LIVEGESTURE_REAL_SPEECH``, else ``shared/data/real-speech``
    beside the repository (where CI and the developers' checkouts have it). Raises if it does not exist."""
    if explicit is not None:
        d = Path(explicit)
    elif os.environ.get(ENV):
        d = Path(os.environ[ENV])
    else:
        d = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "real-speech"
    if not d.is_dir():
        raise FileNotFoundError(
            f"real-speech folder {d} not found: pass it explicitly or set ${ENV} "
            "(the 16 recordings of shared/data/real-speech)")
    return d


def split_paths(split: str, explicit: str | os.PathLike | None = None) -> list[Path]:
    """WAV paths of ``split`` (``"validation"`` or ``"train"``), checked to exist."""
    ids = {"validation": VALIDATION, "train": TRAIN}.get(split)
    if ids is None:
        raise ValueError(f"unknown real-speech split {split!r}: expected 'validation' or 'train'")
    d = real_speech_dir(explicit)
    paths = [d / f"{i}.wav" for i in ids]
    missing = [p.name for p in paths if not p.exists()]
    if missing:
        raise FileNotFoundError(f"real-speech folder {d} lacks {', '.join(missing)}")
    return paths
