"""Checkpoints: one file holding the config, the weights and the provenance of a LiveGesture model."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import torch

from .config import LiveGestureConfig, get_config
from .models.model import LiveGesture

FORMAT = "livegesture-checkpoint"
VERSION = 1


def save(model: LiveGesture, path: str | os.PathLike, provenance: dict | None = None, extra: dict | None = None):
    """Write atomically (temp file + rename): an interrupted save never leaves a half-written checkpoint."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": FORMAT, "version": VERSION, "config": model.cfg.to_dict(),
               "state_dict": model.state_dict(), "provenance": provenance or {}, "extra": extra or {}}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def load_payload(path: str | os.PathLike) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path}: no such file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # noqa: BLE001 - re-raised with the file named
        raise ValueError(f"checkpoint {path}: cannot be read ({e})") from e
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"checkpoint {path}: not a {FORMAT} file")
    return payload


def load(path: str | os.PathLike) -> LiveGesture:
    """Load a model (eval mode) from a checkpoint file."""
    payload = load_payload(path)
    model = LiveGesture(LiveGestureConfig.from_dict(payload["config"]))
    missing, unexpected = model.load_state_dict(payload["state_dict"], strict=False)
    missing = [k for k in missing if not k.endswith(("win_cos", "win_sin", "slot"))]
    if missing or unexpected:
        raise ValueError(f"checkpoint {path}: weights do not match the config "
                         f"(missing {missing[:5]}, unexpected {unexpected[:5]})")
    model.provenance = payload.get("provenance", {})
    return model.eval()


def random_model(config: str | LiveGestureConfig, seed: int = 0) -> LiveGesture:
    """A model with random weights (tests, benchmarks of the paper config)."""
    cfg = get_config(config) if isinstance(config, str) else config
    torch.manual_seed(seed)
    model = LiveGesture(cfg).eval()
    model.provenance = {"training": "none: random weights", "seed": seed}
    return model
