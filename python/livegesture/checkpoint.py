"""Checkpoints: one file holding the config, the weights and the provenance of a LiveGesture model."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import torch

from . import families

FORMAT = "livegesture-checkpoint"
VERSION = 1


def save(model, path: str | os.PathLike, provenance: dict | None = None, extra: dict | None = None):
    """Write atomically (temp file + rename): an interrupted save never leaves a half-written checkpoint."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": FORMAT, "version": VERSION, "config": model.cfg.to_dict(),
               "state_dict": model.state_dict(), "provenance": provenance or {}, "extra": extra or {}}
    fam = families.of_model(model)
    if fam is not families.DEFAULT:
        payload["family"] = fam.name              # absent = the default family (checkpoints before DiffSHEG)
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
    """The name of a checkpoint payload's family (``livegesture.families``)."""
    return families.of_payload(payload).name


def load(path: str | os.PathLike):
    """Load a model (eval mode) from a checkpoint file: the model of the checkpoint's ``family``
    (``livegesture.families``; absent: LiveGesture)."""
    payload = load_payload(path)
    try:
        fam = families.of_payload(payload)
    except ValueError as e:
        raise ValueError(f"checkpoint {path}: {e}") from None
    model = fam.build_model(fam.config_from_dict(payload["config"]))
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
    want = families.get(family)
    if families.of_model(model) is not want:
        raise SystemExit(f"--init-from {path}: not a {want.title} checkpoint")
    theirs, ours = model.cfg.to_dict(), cfg.to_dict()
    if theirs != ours:
        diff = sorted(k for k in ours.keys() | theirs.keys() if theirs.get(k) != ours.get(k))
        raise SystemExit(f"--init-from {path}: its model config differs from --config {config_name} ({diff})")
    return model


def random_model(config, seed: int = 0, family: str = "livegesture"):
    """A model with random weights (tests, benchmarks of the paper config). ``config``: a config name of the
    family or a config object."""
    fam = families.get(family)
    cfg = fam.get_config(config)
    torch.manual_seed(seed)
    model = fam.build_model(cfg).eval()
    if fam.perturb_zero_init:
        with torch.no_grad():   # zero-initialised layers (outputs, AdaIN, null audio) would make eps == 0
            for p in model.parameters():
                if bool((p == 0).all()):
                    p.normal_(0.0, 0.05)
    model.provenance = {"training": "none: random weights", "seed": seed}
    return model
