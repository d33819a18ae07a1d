"""Loader for the real BEAT2 layout (docs/data.md), also written by :mod:`livegesture.data.synth`.

``root`` is the ``beat_english_v2.0.0/`` directory (a directory that contains it is accepted too)::

    smplxflame_30/{id}.npz     poses (T,165), trans (T,3), expressions (T,100), mocap_frame_rate 30, ...
    wave16k/{id}.wav           16 kHz mono (other rates/channels are converted)
    textgrid/{id}.TextGrid     optional, not read here
    train_test_split.csv       header ``id,type``; type in train, val, test, additional

Alignment (integer arithmetic, no drift): audio sample ``k * 16000 // 30`` starts motion frame k; a clip
has ``n_tokens = min(T // 4, FrontendConfig.n_tokens(len(audio)))`` complete tokens. Log-mel frames are
computed once over the whole clip with :func:`livegesture.frontend.logmel`, i.e. exactly the frames the
streaming frontend produces, and sliced: a window of tokens ``[s, s + N)`` has motion frames
``[4s, 4(s + N))``, mel rows ``[8s, 8(s + N))`` and audio samples
``[frame_start(4s), frame_start(4(s + N)))``.

Every problem with a file raises :class:`Beat2Error` naming the file and the problem; nothing is skipped
silently. ``skip_broken=True`` skips broken clips with a warning that lists each of them.

Public API: :class:`Beat2Error`, :func:`resolve_root`, :func:`read_split_csv`, :func:`speaker_of`,
:func:`load_motion`, :func:`load_audio`, :class:`Clip`, :class:`Beat2Corpus`, :func:`get_corpus`,
:func:`compute_stats`, :class:`Beat2Windows`.
"""
from __future__ import annotations

import csv
import warnings
import wave
from dataclasses import dataclass
from math import gcd
from pathlib import Path
from typing import Iterable

import numpy as np

from ..frontend import FrontendConfig, logmel
from ..regions import FPS, FRAMES_PER_TOKEN, N_EXPRESSIONS, N_JOINTS, REGION_NAMES, SAMPLE_RATE, frame_start_sample
from .features import NormStats, RunningStats, motion_to_features

SPLIT_TYPES = ("train", "val", "test", "additional")
MOTION_DIR, AUDIO_DIR, TEXTGRID_DIR, SPLIT_CSV = "smplxflame_30", "wave16k", "textgrid", "train_test_split.csv"
MAX_AUDIO_SHORTFALL_S = 1.0


class Beat2Error(ValueError):
    """A missing or malformed BEAT2 file; the message names the file and the problem."""


# ----------------------------------------------------------------------------- files

def resolve_root(root: str | Path) -> Path:
    """The directory holding ``train_test_split.csv`` (``root`` itself or ``root/beat_english_v2.0.0``)."""
    root = Path(root)
    if (root / SPLIT_CSV).exists():
        return root
    if (root / "beat_english_v2.0.0" / SPLIT_CSV).exists():
        return root / "beat_english_v2.0.0"
    if not root.is_dir():
        raise Beat2Error(f"{root}: BEAT2 root directory not found")
    raise Beat2Error(f"{root / SPLIT_CSV}: missing (not a BEAT2 beat_english_v2.0.0 directory)")


def speaker_of(clip_id: str) -> int:
    """Speaker number of a BEAT2 id (its first field): ``2_scott_0_1_1`` -> 2."""
    head = clip_id.split("_", 1)[0]
    if not head.isdigit():
        raise Beat2Error(f"clip id {clip_id!r}: does not start with a speaker number (like 2_scott_0_1_1)")
    return int(head)


def read_split_csv(path: str | Path) -> dict[str, str]:
    """``train_test_split.csv`` -> {id: type}, in file order. Checks the header and every row."""
    path = Path(path)
    if not path.exists():
        raise Beat2Error(f"{path}: missing split file")
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise Beat2Error(f"{path}: empty file, expected a header 'id,type'")
    header = [h.strip() for h in rows[0]]
    if len(header) < 2 or "id" not in header or "type" not in header:
        raise Beat2Error(f"{path}: bad header {rows[0]!r}, expected columns 'id,type'")
    i_id, i_type = header.index("id"), header.index("type")
    out: dict[str, str] = {}
    for ln, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) < len(header):
            raise Beat2Error(f"{path}: line {ln}: expected {len(header)} columns, got {row!r}")
        cid, typ = row[i_id].strip(), row[i_type].strip()
        if typ not in SPLIT_TYPES:
            raise Beat2Error(f"{path}: line {ln}: unknown type {typ!r} for {cid!r} (expected one of {SPLIT_TYPES})")
        if not cid:
            raise Beat2Error(f"{path}: line {ln}: empty id")
        try:
            speaker_of(cid)
        except Beat2Error as e:
            raise Beat2Error(f"{path}: line {ln}: {e}") from None
        if cid in out:
            raise Beat2Error(f"{path}: line {ln}: duplicate id {cid!r}")
        out[cid] = typ
    return out


def load_motion(path: str | Path) -> dict[str, np.ndarray]:
    """A BEAT2 motion npz -> dict(poses (T,165), trans (T,3), expressions (T,100)) as float32, validated."""
    path = Path(path)
    if not path.exists():
        raise Beat2Error(f"{path}: missing motion file")
    try:
        npz = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is reported the same way
        raise Beat2Error(f"{path}: cannot read npz ({e})") from None
    with npz:
        keys = set(npz.files)
        need = ("poses", "trans", "expressions")
        missing = [k for k in need if k not in keys]
        if missing:
            raise Beat2Error(f"{path}: missing key(s) {missing}; the file has {sorted(keys)}")
        out = {}
        try:
            for k in need:
                out[k] = npz[k]
            fps = npz["mocap_frame_rate"] if "mocap_frame_rate" in keys else None
        except Exception as e:  # noqa: BLE001
            raise Beat2Error(f"{path}: cannot read arrays ({e})") from None
    if fps is not None:
        try:
            fps_v = float(np.asarray(fps).reshape(-1)[0])
        except (ValueError, TypeError, IndexError):
            raise Beat2Error(f"{path}: mocap_frame_rate {fps!r} is not a number") from None
        if abs(fps_v - FPS) > 1e-6:
            raise Beat2Error(f"{path}: mocap_frame_rate is {fps_v:g}, expected {FPS}")
    widths = {"poses": 3 * N_JOINTS, "trans": 3, "expressions": N_EXPRESSIONS}
    for k, w in widths.items():
        a = out[k]
        if not np.issubdtype(a.dtype, np.floating):
            raise Beat2Error(f"{path}: '{k}' has dtype {a.dtype}, expected a float array")
        if a.ndim != 2 or a.shape[1] != w:
            raise Beat2Error(f"{path}: '{k}' has shape {a.shape}, expected (T, {w})")
        if not np.isfinite(a).all():
            raise Beat2Error(f"{path}: '{k}' contains NaN or Inf")
        out[k] = a.astype(np.float32, copy=False)
    T = {k: out[k].shape[0] for k in widths}
    if len(set(T.values())) != 1:
        raise Beat2Error(f"{path}: frame count mismatch between poses/trans/expressions: {T}")
    if T["poses"] == 0:
        raise Beat2Error(f"{path}: no frames")
    return out


def _resample(x: np.ndarray, sr: int, target: int) -> np.ndarray:
    from scipy.signal import resample_poly

    g = gcd(sr, target)
    return resample_poly(x, target // g, sr // g).astype(np.float32)


def load_audio(path: str | Path, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """A wav file -> mono float32 in [-1, 1] at ``sample_rate`` (channels averaged, resampled if needed)."""
    path = Path(path)
    if not path.exists():
        raise Beat2Error(f"{path}: missing audio file")
    try:
        from scipy.io import wavfile

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # WavFileWarning on unknown chunks (e.g. LIST)
            sr, x = wavfile.read(path)
    except Exception as e:  # noqa: BLE001 - fall back to the stdlib for odd headers
        try:
            with wave.open(str(path), "rb") as w:
                sr, nch, sw, n = w.getframerate(), w.getnchannels(), w.getsampwidth(), w.getnframes()
                raw = w.readframes(n)
            if sw != 2:
                raise ValueError(f"{8 * sw}-bit samples")
            x = np.frombuffer(raw, dtype="<i2").reshape(-1, nch)
        except Exception:  # noqa: BLE001
            raise Beat2Error(f"{path}: cannot read wav ({e})") from None
    x = np.asarray(x)
    if x.dtype == np.int16:
        x = x.astype(np.float32) / 32768.0
    elif x.dtype == np.int32:
        x = x.astype(np.float32) / 2147483648.0
    elif x.dtype == np.uint8:
        x = (x.astype(np.float32) - 128.0) / 128.0
    elif np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float32)
    else:
        raise Beat2Error(f"{path}: unsupported sample type {x.dtype}")
    if x.ndim == 2:
        x = x.mean(axis=1)
    if x.ndim != 1 or len(x) == 0:
        raise Beat2Error(f"{path}: no audio samples")
    if not np.isfinite(x).all():
        raise Beat2Error(f"{path}: audio contains NaN or Inf")
    if sr != sample_rate:
        x = _resample(x, int(sr), sample_rate)
    return x


# ----------------------------------------------------------------------------- clips and corpus

@dataclass
class Clip:
    """One aligned clip: ``n_tokens`` complete tokens, features (4 n, dim) per region (un-normalised,
    float32) and log-mel frames (8 n, n_mels) float32."""
    id: str
    speaker: int
    split: str
    n_tokens: int
    features: dict[str, np.ndarray]
    mel: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.n_tokens * FRAMES_PER_TOKEN


class Beat2Corpus:
    """A BEAT2 directory: the split table, and clips loaded on demand and cached in memory."""

    def __init__(self, root: str | Path, frontend_cfg: FrontendConfig = FrontendConfig(),
                 skip_broken: bool = False):
        self.root = resolve_root(root)
        self.frontend_cfg = frontend_cfg
        self.skip_broken = skip_broken
        self.split_table = read_split_csv(self.root / SPLIT_CSV)
        self._cache: dict[str, Clip] = {}
        self.broken: dict[str, str] = {}

    def motion_path(self, clip_id: str) -> Path:
        return self.root / MOTION_DIR / f"{clip_id}.npz"

    def audio_path(self, clip_id: str) -> Path:
        return self.root / AUDIO_DIR / f"{clip_id}.wav"

    def textgrid_path(self, clip_id: str) -> Path:
        return self.root / TEXTGRID_DIR / f"{clip_id}.TextGrid"

    def ids(self, split: str | Iterable[str] | None = None,
            speakers: int | Iterable[int] | None = None) -> list[str]:
        """Ids of the split table, in file order, filtered by split type(s) and speaker number(s)
        (None = all)."""
        splits = _as_set(split, str)
        if splits is not None:
            bad = splits - set(SPLIT_TYPES)
            if bad:
                raise ValueError(f"unknown split {sorted(bad)}; choose from {SPLIT_TYPES}")
        spk = _as_set(speakers, int)
        return [i for i, t in self.split_table.items()
                if (splits is None or t in splits) and (spk is None or speaker_of(i) in spk)]

    def motion(self, clip_id: str) -> dict[str, np.ndarray]:
        """The raw validated motion of a clip (not cached)."""
        return load_motion(self.motion_path(clip_id))

    def audio(self, clip_id: str) -> np.ndarray:
        """The clip's 16 kHz mono audio (not cached)."""
        return load_audio(self.audio_path(clip_id), self.frontend_cfg.sample_rate)

    def clip(self, clip_id: str) -> Clip:
        """Load, validate, align and featurise a clip (cached)."""
        if clip_id in self._cache:
            return self._cache[clip_id]
        if clip_id not in self.split_table:
            raise Beat2Error(f"{self.root / SPLIT_CSV}: no id {clip_id!r}")
        mpath, apath = self.motion_path(clip_id), self.audio_path(clip_id)
        motion = load_motion(mpath)
        audio = self.audio(clip_id)
        cfg = self.frontend_cfg
        T = motion["poses"].shape[0]
        motion_s, audio_s = T / cfg.fps, len(audio) / cfg.sample_rate
        if motion_s - audio_s > MAX_AUDIO_SHORTFALL_S:
            raise Beat2Error(f"{apath}: audio is {audio_s:.2f} s but the motion {mpath.name} is {motion_s:.2f} s "
                             f"(more than {MAX_AUDIO_SHORTFALL_S:g} s shorter)")
        n_tok = min(T // FRAMES_PER_TOKEN, cfg.n_tokens(len(audio)))
        if n_tok <= 0:
            raise Beat2Error(f"{mpath}: shorter than one motion token ({T} frames, {len(audio)} samples)")
        nf = n_tok * FRAMES_PER_TOKEN
        feats = motion_to_features(motion["poses"][:nf], motion["trans"][:nf], motion["expressions"][:nf])
        end = frame_start_sample(nf, cfg.sample_rate, cfg.fps)
        mel = logmel(audio[:end], cfg)
        assert mel.shape[0] == n_tok * cfg.mel_frames_per_token, (mel.shape, n_tok)
        clip = Clip(id=clip_id, speaker=speaker_of(clip_id), split=self.split_table[clip_id], n_tokens=n_tok,
                    features=feats, mel=mel)
        self._cache[clip_id] = clip
        return clip

    def clips(self, ids: Iterable[str], progress: bool = False) -> list[Clip]:
        """Load several clips; broken ones raise (or, with ``skip_broken``, are skipped with a warning)."""
        ids = list(ids)
        it = ids
        if progress:
            from tqdm import tqdm
            it = tqdm(ids, desc="loading BEAT2 clips", unit="clip")
        out, skipped = [], []
        for i in it:
            try:
                out.append(self.clip(i))
            except Beat2Error as e:
                if not self.skip_broken:
                    raise
                self.broken[i] = str(e)
                skipped.append(str(e))
        if skipped:
            warnings.warn(f"skipped {len(skipped)} broken BEAT2 clip(s):\n  " + "\n  ".join(skipped), stacklevel=2)
        return out

    def stats(self, split: str | Iterable[str] = "train", speakers: int | Iterable[int] | None = (2,),
              std_floor: float = 1e-3, progress: bool = False) -> NormStats:
        """Per-region normalisation statistics over all frames of the selected clips."""
        ids = self.ids(split, speakers)
        if not ids:
            raise Beat2Error(f"{self.root / SPLIT_CSV}: no clip of split {split!r} and speakers {speakers!r}")
        rs = RunningStats()
        for c in self.clips(ids, progress=progress):
            rs.update(c.features)
        st = rs.finish(std_floor)
        st.source = f"{self.root.name}: split={split!r} speakers={_describe(speakers)} clips={len(ids)}"
        return st


def _as_set(v, typ):
    if v is None:
        return None
    if isinstance(v, str):
        if v == "all":
            return None
        return {typ(x.strip()) for x in v.split(",") if x.strip()}
    if isinstance(v, (int, np.integer)) and typ is int:
        return {int(v)}
    return {typ(x) for x in v}


def _describe(speakers):
    s = _as_set(speakers, int)
    return "all" if s is None else sorted(s)


_CORPORA: dict[tuple, Beat2Corpus] = {}


def get_corpus(root: str | Path, frontend_cfg: FrontendConfig = FrontendConfig(),
               skip_broken: bool = False) -> Beat2Corpus:
    """A process-wide shared :class:`Beat2Corpus` per (root, frontend config), so the train and val
    datasets and the statistics share one in-memory clip cache."""
    key = (str(resolve_root(root).resolve()), frontend_cfg, skip_broken)
    if key not in _CORPORA:
        _CORPORA[key] = Beat2Corpus(root, frontend_cfg, skip_broken)
    return _CORPORA[key]


def compute_stats(root: str | Path, split: str | Iterable[str] = "train",
                  speakers: int | Iterable[int] | None = (2,), frontend_cfg: FrontendConfig = FrontendConfig(),
                  std_floor: float = 1e-3, progress: bool = False) -> NormStats:
    """Normalisation statistics of a BEAT2 directory (default: the train split of speaker 2)."""
    return get_corpus(root, frontend_cfg).stats(split, speakers, std_floor, progress)


# ----------------------------------------------------------------------------- torch dataset

try:
    from torch.utils.data import Dataset as _Dataset
except ImportError:  # pragma: no cover - torch is a dependency; keep the loader importable without it
    _Dataset = object


class Beat2Windows(_Dataset):
    """Fixed-length training windows of ``n_tokens`` tokens, every ``stride`` tokens, over the clips of
    ``split`` and ``speakers`` (None = all; the benchmark is speakers=(2,)).

    Item: ``dict(mel=(8N, n_mels) float32 tensor, motion={region: (4N, dim) float32 tensor},
    id=str, start=int)`` where ``start`` is the first token of the window; motion is normalised with
    ``stats`` (None = raw features). With ``return_audio=True`` the item also has ``audio``: the samples
    ``[frame_start(4 start), frame_start(4 (start + N)))`` (read from disk once per clip and cached).
    Clips shorter than a window give no window; ``short_clips`` lists them.
    """

    def __init__(self, root: str | Path, split: str | Iterable[str] = "train",
                 speakers: int | Iterable[int] | None = (2,), n_tokens: int = 16, stride: int | None = None,
                 stats: NormStats | None = None, frontend_cfg: FrontendConfig = FrontendConfig(),
                 *, corpus: Beat2Corpus | None = None, return_audio: bool = False,
                 skip_broken: bool = False, progress: bool = False):
        if n_tokens <= 0:
            raise ValueError(f"n_tokens must be positive, got {n_tokens}")
        stride = n_tokens if stride is None else stride
        if stride <= 0:
            raise ValueError(f"stride must be positive, got {stride}")
        self.corpus = corpus if corpus is not None else get_corpus(root, frontend_cfg, skip_broken)
        if self.corpus.frontend_cfg != frontend_cfg:
            raise ValueError("Beat2Windows: the corpus uses another frontend config")
        self.n_tokens, self.stride, self.stats = n_tokens, stride, stats
        self.return_audio = return_audio
        if stats is not None:
            missing = set(REGION_NAMES) - set(stats.mean)
            if missing:
                raise ValueError(f"Beat2Windows: stats lack regions {sorted(missing)}")
        ids = self.corpus.ids(split, speakers)
        if not ids:
            raise Beat2Error(f"{self.corpus.root / SPLIT_CSV}: no clip of split {split!r} and speakers "
                             f"{_describe(speakers)}")
        self.clips = self.corpus.clips(ids, progress=progress)
        self.index: list[tuple[int, int]] = []
        self.short_clips: list[str] = []
        for ci, c in enumerate(self.clips):
            starts = range(0, c.n_tokens - n_tokens + 1, stride)
            if len(starts) == 0:
                self.short_clips.append(c.id)
            self.index.extend((ci, s) for s in starts)
        self._audio: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.index)

    def window(self, i: int) -> dict:
        """The i-th window as numpy arrays (what ``__getitem__`` returns, before tensor conversion)."""
        ci, s = self.index[i]
        c = self.clips[ci]
        N, F, M = self.n_tokens, FRAMES_PER_TOKEN, self.corpus.frontend_cfg.mel_frames_per_token
        motion = {k: v[F * s:F * (s + N)] for k, v in c.features.items()}
        if self.stats is not None:
            motion = self.stats.normalize(motion)
        item = {"mel": c.mel[M * s:M * (s + N)], "motion": motion, "id": c.id, "start": s}
        if self.return_audio:
            if c.id not in self._audio:
                self._audio[c.id] = self.corpus.audio(c.id)
            cfg = self.corpus.frontend_cfg
            a0 = frame_start_sample(F * s, cfg.sample_rate, cfg.fps)
            a1 = frame_start_sample(F * (s + N), cfg.sample_rate, cfg.fps)
            item["audio"] = self._audio[c.id][a0:a1]
        return item

    def __getitem__(self, i: int) -> dict:
        import torch

        w = self.window(i)
        out = {"mel": torch.from_numpy(np.ascontiguousarray(w["mel"], dtype=np.float32)),
               "motion": {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32))
                          for k, v in w["motion"].items()},
               "id": w["id"], "start": w["start"]}
        if "audio" in w:
            out["audio"] = torch.from_numpy(np.ascontiguousarray(w["audio"], dtype=np.float32))
        return out
