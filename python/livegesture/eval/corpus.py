"""The evaluation's view of a BEAT2-layout corpus (docs/data.md): thin adapters over
:mod:`livegesture.data.beat2`, which owns the reading and validation of the files."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..data import beat2
from ..regions import SAMPLE_RATE

MOTION_DIR = beat2.MOTION_DIR
AUDIO_DIR = beat2.AUDIO_DIR
SPLIT_FILE = beat2.SPLIT_CSV


def read_split(data_dir: str | os.PathLike, split: str | None = None) -> list[str]:
    """Sorted ids of ``split`` (train, val, test, additional) or of every row when ``split`` is None."""
    table = beat2.read_split_csv(Path(data_dir) / SPLIT_FILE)
    return sorted(i for i, t in table.items() if split is None or t == split)


def load_motion(path: str | os.PathLike) -> dict:
    """A BEAT2 motion npz -> dict(poses (T,165), trans (T,3), expressions (T,100)) as float64, validated."""
    return {k: v.astype(np.float64) for k, v in beat2.load_motion(path).items()}


def load_audio(path: str | os.PathLike, target_sr: int = SAMPLE_RATE) -> tuple[np.ndarray, int]:
    """A wav file -> (mono float64 samples in [-1, 1] at ``target_sr``, ``target_sr``)."""
    return beat2.load_audio(path, target_sr).astype(np.float64), int(target_sr)


def motion_path(data_dir, clip_id) -> Path:
    return Path(data_dir) / MOTION_DIR / f"{clip_id}.npz"


def audio_path(data_dir, clip_id) -> Path:
    return Path(data_dir) / AUDIO_DIR / f"{clip_id}.wav"
