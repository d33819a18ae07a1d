"""Minimal readers for the BEAT2 layout (SPEC section 3) used by the evaluation.

``DIR/train_test_split.csv`` (columns ``id,type``), ``DIR/smplxflame_30/{id}.npz`` (``poses`` (T,165),
``trans`` (T,3), ``expressions`` (T,100)), ``DIR/wave16k/{id}.wav``. Kept self-contained (numpy, scipy)
so the evaluation does not depend on the training data pipeline.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import scipy.io.wavfile
import scipy.signal

MOTION_DIR = "smplxflame_30"
AUDIO_DIR = "wave16k"
SPLIT_FILE = "train_test_split.csv"


def read_split(data_dir: str | os.PathLike, split: str | None = None) -> list[str]:
    """Sorted ids of ``split`` (train, val, test, additional) or of every row when ``split`` is None."""
    path = Path(data_dir) / SPLIT_FILE
    if not path.exists():
        raise FileNotFoundError(f"{path}: no train_test_split.csv (is {data_dir} a BEAT2-layout corpus?)")
    ids = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            row = {(k or "").strip(): (v or "").strip() for k, v in row.items()}
            if "id" not in row or "type" not in row:
                raise ValueError(f"{path}: needs columns id,type")
            if split is None or row["type"] == split:
                ids.append(row["id"])
    return sorted(ids)


def load_motion(path: str | os.PathLike) -> dict:
    """A BEAT2 motion npz -> dict(poses (T,165) float64, trans (T,3), expressions (T,E) or None)."""
    with np.load(path, allow_pickle=False) as z:
        if "poses" not in z:
            raise ValueError(f"{path}: no 'poses' array")
        poses = np.asarray(z["poses"], dtype=np.float64).reshape(len(z["poses"]), -1)
        T = len(poses)
        trans = np.asarray(z["trans"], dtype=np.float64).reshape(T, 3) if "trans" in z else np.zeros((T, 3))
        expr = np.asarray(z["expressions"], dtype=np.float64).reshape(T, -1) if "expressions" in z else None
    if poses.shape[1] != 165:
        raise ValueError(f"{path}: poses must be (T, 165), got {poses.shape}")
    return {"poses": poses, "trans": trans, "expressions": expr}


def load_audio(path: str | os.PathLike, target_sr: int | None = None) -> tuple[np.ndarray, int]:
    """A wav file -> (mono float64 samples in [-1, 1], sample rate); resampled when ``target_sr`` is given."""
    sr, x = scipy.io.wavfile.read(str(path))
    if np.issubdtype(x.dtype, np.integer):
        x = x.astype(np.float64) / float(np.iinfo(x.dtype).max + 1)
    else:
        x = x.astype(np.float64)
    if x.ndim == 2:
        x = x.mean(axis=1)
    if target_sr is not None and sr != target_sr:
        from math import gcd
        g = gcd(int(sr), int(target_sr))
        x = scipy.signal.resample_poly(x, target_sr // g, sr // g)
        sr = target_sr
    return x, int(sr)


def motion_path(data_dir, clip_id) -> Path:
    return Path(data_dir) / MOTION_DIR / f"{clip_id}.npz"


def audio_path(data_dir, clip_id) -> Path:
    return Path(data_dir) / AUDIO_DIR / f"{clip_id}.wav"
