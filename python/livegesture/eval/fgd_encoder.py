"""The motion feature encoder for FGD, trained on the corpus (BEAT2's own FGD encoder is trained on BEAT2
and cannot ship; this one is trained the same way on whatever corpus the user evaluates on).

Input frames (``motion_frame_features``), per frame, 495 numbers:

- joint positions of the project skeleton relative to the pelvis (55 x 3; global translation removed),
- local joint rotations as rot6d (55 x 6, first two rows of the rotation matrix, the EMAGE encoder's input).

Each dimension is standardised with the training set's mean and standard deviation (floored at
``STD_FLOOR`` so constant dimensions, the eyes at rest for instance, do not explode).

Model: a 1D-convolutional autoencoder over windows of ``WINDOW`` = 64 frames (encoder: stem, then
2 x (stride-2 conv + dilated residual block), 4x downsampling to a ``latent``-channel sequence; decoder:
the mirror with nearest upsampling), trained with L1 reconstruction (plus L1 on frame-to-frame
differences) by Adam on random windows of the training split.

Feature of a window: the mean and the standard deviation over time of the encoder output, ``2 * latent``
numbers (64 by default). Clips are cut into windows of 64 frames with stride ``FEATURE_STRIDE`` (16).
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from . import corpus

WINDOW = 64
FEATURE_STRIDE = 16
STD_FLOOR = 0.02
FORMAT = "livegesture-fgd-encoder"
VERSION = 1


# ============================================================================ frame features

def motion_frame_features(poses: np.ndarray, trans: np.ndarray | None = None) -> np.ndarray:
    """(T,165) axis-angle (+ trans, ignored: translation is removed) -> (T, 495) float32 frame features."""
    from ..skeleton import axis_angle_to_matrix_np, forward_kinematics

    poses = np.asarray(poses, dtype=np.float64).reshape(len(poses), -1)
    T = len(poses)
    J = forward_kinematics(poses, np.zeros((T, 3)))                       # (T,55,3)
    rel = (J - J[:, :1]).reshape(T, -1)
    R = axis_angle_to_matrix_np(poses.reshape(T, -1, 3))                  # (T,55,3,3)
    r6 = R[..., :2, :].reshape(T, -1)
    return np.concatenate([rel, r6], axis=1).astype(np.float32)


def motion_windows(frames: np.ndarray, window: int = WINDOW, stride: int = FEATURE_STRIDE) -> np.ndarray:
    """(T, D) -> (N, window, D) windows starting at 0, stride, ...; empty (0, window, D) if T < window."""
    frames = np.asarray(frames)
    T, D = frames.shape
    if T < window:
        return np.zeros((0, window, D), dtype=frames.dtype)
    starts = np.arange(0, T - window + 1, stride)
    return np.stack([frames[s:s + window] for s in starts])


# ============================================================================ model

class _Res(nn.Module):
    def __init__(self, c: int, dilation: int):
        super().__init__()
        self.c1 = nn.Conv1d(c, c, 3, padding=dilation, dilation=dilation)
        self.c2 = nn.Conv1d(c, c, 1)

    def forward(self, x):
        return x + self.c2(F.leaky_relu(self.c1(F.leaky_relu(x, 0.2)), 0.2))


class MotionAutoencoder(nn.Module):
    def __init__(self, in_dim: int, width: int = 64, latent: int = 32):
        super().__init__()
        self.in_dim, self.width, self.latent = in_dim, width, latent
        self.encoder = nn.Sequential(
            nn.Conv1d(in_dim, width, 3, padding=1), nn.LeakyReLU(0.2),
            nn.Conv1d(width, width, 4, stride=2, padding=1), _Res(width, 1), _Res(width, 3),
            nn.Conv1d(width, width, 4, stride=2, padding=1), _Res(width, 1), _Res(width, 3),
            nn.LeakyReLU(0.2), nn.Conv1d(width, latent, 3, padding=1))
        self.decoder = nn.Sequential(
            nn.Conv1d(latent, width, 3, padding=1), _Res(width, 1), _Res(width, 3),
            nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv1d(width, width, 3, padding=1),
            _Res(width, 1), _Res(width, 3),
            nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv1d(width, width, 3, padding=1),
            nn.LeakyReLU(0.2), nn.Conv1d(width, in_dim, 3, padding=1))

    def encode(self, x):
        """x (B, T, D) normalised -> (B, latent, T/4)."""
        return self.encoder(x.transpose(1, 2))

    def forward(self, x):
        return self.decoder(self.encode(x)).transpose(1, 2)


def _pool(z: torch.Tensor) -> torch.Tensor:
    return torch.cat([z.mean(-1), z.std(-1, unbiased=False)], dim=1)


class FGDEncoder:
    """A trained encoder plus its input normalisation. ``features(windows) -> (N, 2 * latent)``."""

    def __init__(self, model: MotionAutoencoder, mean: np.ndarray, std: np.ndarray, window: int = WINDOW,
                 provenance: dict | None = None):
        self.model = model.eval()
        self.mean = np.asarray(mean, dtype=np.float32)
        self.std = np.asarray(std, dtype=np.float32)
        self.window = window
        self.provenance = provenance or {}

    @property
    def feature_dim(self) -> int:
        return 2 * self.model.latent

    @torch.no_grad()
    def features(self, windows: np.ndarray, batch: int = 256) -> np.ndarray:
        """(N, window, 495) frame-feature windows (``motion_windows`` of ``motion_frame_features``) ->
        (N, F) float64."""
        w = np.asarray(windows, dtype=np.float32)
        if w.ndim != 3 or w.shape[2] != len(self.mean):
            raise ValueError(f"FGDEncoder.features: expected (N, T, {len(self.mean)}) windows, got {w.shape}")
        out = []
        for i in range(0, len(w), batch):
            x = torch.from_numpy((w[i:i + batch] - self.mean) / self.std)
            out.append(_pool(self.model.encode(x)).double().numpy())
        return np.concatenate(out) if out else np.zeros((0, self.feature_dim))

    def clip_features(self, poses: np.ndarray, trans: np.ndarray | None = None,
                      stride: int = FEATURE_STRIDE) -> np.ndarray:
        """Features of every window (stride ``stride``) of one clip: (N, F)."""
        return self.features(motion_windows(motion_frame_features(poses, trans), self.window, stride))

    def save(self, path: str | os.PathLike):
        payload = {"format": FORMAT, "version": VERSION, "in_dim": self.model.in_dim, "width": self.model.width,
                   "latent": self.model.latent, "window": self.window, "mean": self.mean, "std": self.std,
                   "state_dict": self.model.state_dict(), "provenance": self.provenance}
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        torch.save(payload, tmp)
        os.replace(tmp, path)


def features(encoder: FGDEncoder, windows: np.ndarray) -> np.ndarray:
    """Module-level alias of ``encoder.features(windows)``: (N, window, 495) -> (N, F)."""
    return encoder.features(windows)


def load_fgd_encoder(path: str | os.PathLike) -> FGDEncoder:
    try:
        p = torch.load(str(path), map_location="cpu", weights_only=False)
    except Exception as e:  # noqa: BLE001
        raise ValueError(f"FGD encoder {path}: cannot be read ({e})") from e
    if not isinstance(p, dict) or p.get("format") != FORMAT:
        raise ValueError(f"FGD encoder {path}: not a {FORMAT} file")
    model = MotionAutoencoder(p["in_dim"], p["width"], p["latent"])
    model.load_state_dict(p["state_dict"])
    return FGDEncoder(model, p["mean"], p["std"], p["window"], p.get("provenance"))


# ============================================================================ training

def load_corpus_frames(corpus_dir: str | os.PathLike, split: str = "train",
                       min_frames: int = WINDOW) -> tuple[list[str], list[np.ndarray]]:
    """Frame features of every clip of a split that is at least ``min_frames`` long."""
    ids, frames = [], []
    for cid in corpus.read_split(corpus_dir, split):
        m = corpus.load_motion(corpus.motion_path(corpus_dir, cid))
        if len(m["poses"]) >= min_frames:
            ids.append(cid)
            frames.append(motion_frame_features(m["poses"], m["trans"]))
    return ids, frames


def train_fgd_encoder(corpus_dir: str | os.PathLike, out_path: str | os.PathLike | None, steps: int = 1000,
                      seed: int = 0, split: str = "train", batch: int = 32, lr: float = 1e-3,
                      width: int = 64, latent: int = 32, threads: int | None = 1,
                      log=print) -> FGDEncoder:
    """Train the FGD encoder on ``split`` of a BEAT2-layout corpus and save it to ``out_path`` (if given).

    Deterministic for a given seed and thread count. Runs on ``threads`` CPU threads (1 by default: this
    small model gains little from more, and loses a lot on a busy machine); about 0.05 s per step on one
    core, so the default 1000 steps take about a minute (the cost does not grow with corpus size beyond
    reading it).
    """
    prev_threads = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        return _train(corpus_dir, out_path, steps, seed, split, batch, lr, width, latent, log)
    finally:
        torch.set_num_threads(prev_threads)


def _train(corpus_dir, out_path, steps, seed, split, batch, lr, width, latent, log) -> FGDEncoder:
    t0 = time.time()
    ids, frames = load_corpus_frames(corpus_dir, split)
    if not frames:
        raise ValueError(f"train_fgd_encoder: no clip of at least {WINDOW} frames in split {split!r} of "
                         f"{corpus_dir}")
    allf = np.concatenate(frames)
    mean = allf.mean(0)
    std = np.maximum(allf.std(0), STD_FLOOR)
    normed = [((f - mean) / std).astype(np.float32) for f in frames]
    lengths = np.array([len(f) - WINDOW + 1 for f in normed], dtype=np.float64)
    probs = lengths / lengths.sum()

    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    model = MotionAutoencoder(allf.shape[1], width, latent)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, steps), eta_min=lr * 0.05)
    model.train()
    loss_hist = []
    for step in range(steps):
        clip = rng.choice(len(normed), size=batch, p=probs)
        starts = (rng.random(batch) * lengths[clip]).astype(np.int64)
        x = torch.from_numpy(np.stack([normed[c][s:s + WINDOW] for c, s in zip(clip, starts)]))
        y = model(x)
        loss = (y - x).abs().mean() + ((y[:, 1:] - y[:, :-1]) - (x[:, 1:] - x[:, :-1])).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        loss_hist.append(loss.item())
        if log is not None and (step + 1) % max(1, steps // 5) == 0:
            log(f"fgd-encoder step {step + 1}/{steps} loss {np.mean(loss_hist[-50:]):.4f} "
                f"({time.time() - t0:.0f} s)")
    model.eval()
    enc = FGDEncoder(model, mean, std, WINDOW, provenance={
        "corpus": str(corpus_dir), "split": split, "clips": len(ids), "frames": int(len(allf)), "steps": steps,
        "seed": seed, "batch": batch, "lr": lr, "final_loss": float(np.mean(loss_hist[-50:])),
        "train_seconds": round(time.time() - t0, 1)})
    if out_path is not None:
        enc.save(out_path)
    return enc
