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
    if getattr(model, "family", "livegesture") != "livegesture":
        payload["family"] = model.family          # absent = livegesture (checkpoints before DiffSHEG)
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


def family_of(payload: dict) -> str:
    return payload.get("family", "livegesture")


def load(path: str | os.PathLike):
    """Load a model (eval mode) from a checkpoint file: a LiveGesture, or a DiffSHEG model for a checkpoint
    whose ``family`` is ``diffsheg``."""
    payload = load_payload(path)
    fam = family_of(payload)
    if fam == "diffsheg":
        from .diffsheg.config import DiffSHEGConfig
        from .diffsheg.model import DiffSHEG
        model = DiffSHEG(DiffSHEGConfig.from_dict(payload["config"]))
    elif fam == "livegesture":
        model = LiveGesture(LiveGestureConfig.from_dict(payload["config"]))
    else:
        raise ValueError(f"checkpoint {path}: unknown model family {fam!r} (expected livegesture or diffsheg)")
    missing, unexpected = model.load_state_dict(payload["state_dict"], strict=False)
    missing = [k for k in missing if not k.endswith(("win_cos", "win_sin", "slot"))]
    if missing or unexpected:
        raise ValueError(f"checkpoint {path}: weights do not match the config "
                         f"(missing {missing[:5]}, unexpected {unexpected[:5]})")
    model.provenance = payload.get("provenance", {})
    return model.eval()


def load_to_fine_tune(path: str | os.PathLike, family: str, cfg, config_name: str):
    """The trained model that ``train --init-from PATH`` continues from: refused (SystemExit, naming the file)
    unless it is of ``family`` and its model config equals ``cfg`` (the run's ``--config config_name``)."""
    model = load(path)
    if getattr(model, "family", "livegesture") != family:
        name = {"livegesture": "LiveGesture", "diffsheg": "DiffSHEG"}.get(family, family)
        raise SystemExit(f"--init-from {path}: not a {name} checkpoint")
    theirs, ours = model.cfg.to_dict(), cfg.to_dict()
    if theirs != ours:
        diff = sorted(k for k in ours.keys() | theirs.keys() if theirs.get(k) != ours.get(k))
        raise SystemExit(f"--init-from {path}: its model config differs from --config {config_name} ({diff})")
    return model


def random_model(config, seed: int = 0, family: str = "livegesture"):
    """A model with random weights (tests, benchmarks of the paper config)."""
    if family == "diffsheg":
        from .diffsheg.config import DiffSHEGConfig, get_config as get_diffsheg_config
        from .diffsheg.model import DiffSHEG
        cfg = get_diffsheg_config(config) if isinstance(config, str) else config
        torch.manual_seed(seed)
        model = DiffSHEG(cfg).eval()
        with torch.no_grad():   # zero-initialised layers (outputs, AdaIN, null audio) would make eps == 0
            for p in model.parameters():
                if bool((p == 0).all()):
                    p.normal_(0.0, 0.05)
        model.provenance = {"training": "none: random weights", "seed": seed}
        return model
    if family != "livegesture":
        raise ValueError(f"unknown model family {family!r} (expected livegesture or diffsheg)")
    cfg = get_config(config) if isinstance(config, str) else config
    torch.manual_seed(seed)
    model = LiveGesture(cfg).eval()
    model.provenance = {"training": "none: random weights", "seed": seed}
    return model
