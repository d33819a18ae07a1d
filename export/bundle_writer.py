"""What every bundle writer shares (LiveGesture ``export.py``, DiffSHEG ``diffsheg_export.py``, reduced precision
``quantize.py``): the staged output folder, the manifest's head, files table and provenance, the ONNX metadata
stamp, the reference clip. Each of those modules imports this one; none imports another writer, so nothing
imports in a circle.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

import livegesture
from livegesture import variants
from livegesture.regions import REGIONS, region_layout

HERE = Path(__file__).resolve().parent
SCHEMA_VERSION = 1
OPSET = 17


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@contextlib.contextmanager
def staged_folder(out: Path):
    """A temporary folder beside ``out`` to write a bundle into; when the block ends without an error it replaces
    ``out`` (``os.replace``, atomic), and it is removed whatever happens, so no half-written bundle remains."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    os.chmod(tmp, 0o755)
    try:
        yield tmp
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def variant_record(family: str, cfg) -> dict:
    """The manifest's ``model.variant``: the variant's name, its paper reference, and the model and training
    options it set (``livegesture.variants``); the graphs it has are the manifest's ``graphs``."""
    v = variants.get(family, getattr(cfg, "variant", "full"))
    return {"name": v.name, "paper": v.paper, "summary": v.summary,
            "model_options": {k: getattr(cfg, k) for k in v.model_fields(cfg)},
            "train_options": dict(v.train)}


def manifest_head(family: str, name: str, cfg, model, rates: dict) -> dict:
    """The manifest's first keys, the same for every family: schema, format, family, model (config and
    parameter counts per graph component), rates (the frontend's sample rate, fps and token sizes, then the
    family's own ``rates``), frontend, regions."""
    f = cfg.frontend
    return {
        "schema_version": SCHEMA_VERSION,
        "format": "livegesture-bundle",
        "family": family,
        "model": {"name": name, "config_name": cfg.name, "config": cfg.to_dict(),
                  "parameters": {g: int(sum(p.numel() for p in c.parameters())) for g, c in model.components().items()},
                  "variant": variant_record(family, cfg)},
        "rates": {"sample_rate": f.sample_rate, "fps": f.fps, "frames_per_token": f.frames_per_token,
                  "mel_frames_per_token": f.mel_frames_per_token, **rates},
        "frontend": f.to_dict(),
        "regions": region_layout(getattr(model, "regions", REGIONS)),
    }


def save_stamped(m, path: Path, model, graph: str, family: str | None = None, component_name: str | None = None):
    """Saves the exported ONNX model ``m`` to ``path`` with the project's metadata (``livegesture.*``:
    schema version, the family when given, graph, component class, config, package version; in that order)
    and producer name. ``component_name``: the class of the graph's component (default: the model's component
    of that name)."""
    import onnx
    if component_name is None:
        component_name = type(model.components()[graph]).__name__
    meta = {"livegesture.schema_version": str(SCHEMA_VERSION)}
    if family is not None:
        meta["livegesture.family"] = family
    meta.update({"livegesture.graph": graph, "livegesture.component": component_name,
                 "livegesture.config": model.cfg.name, "livegesture.version": livegesture.__version__})
    for k, v in meta.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    m.producer_name = "livegesture-export"
    onnx.save(m, str(path))


def reference_audio(path: str | None, seconds: float) -> tuple[np.ndarray, str]:
    """The reference speech clip (16 kHz mono float32) and a description of where it came from."""
    if path:
        from scipy.io import wavfile
        from scipy.signal import resample_poly
        sr, x = wavfile.read(path)
        x = x.astype(np.float32) / (32768.0 if x.dtype == np.int16 else 1.0)
        if x.ndim == 2:
            x = x.mean(1)
        if sr != 16000:
            g = np.gcd(sr, 16000)
            x = resample_poly(x, 16000 // g, sr // g).astype(np.float32)
        return x, f"file {Path(path).name}"
    # no clip given: a deterministic speech-like signal (harmonics with a syllabic envelope)
    rng = np.random.RandomState(0)
    t = np.arange(int(16000 * seconds)) / 16000
    env = np.clip(np.sin(2 * np.pi * 2.3 * t), 0, None) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.31 * t))
    f0 = 140 + 40 * np.sin(2 * np.pi * 0.5 * t)
    x = env * np.sin(2 * np.pi * np.cumsum(f0) / 16000) + 0.02 * rng.randn(len(t))
    desc = "synthetic harmonic signal with a syllabic envelope (no --reference-wav given)"
    reps = int(np.ceil(seconds * 16000 / max(len(x), 1)))
    x = np.tile(x, reps)[: int(seconds * 16000)]
    return (0.5 * x / (np.abs(x).max() + 1e-9)).astype(np.float32), desc


def write_wav(path: Path, x: np.ndarray):
    from scipy.io import wavfile
    wavfile.write(str(path), 16000, np.clip(np.round(x * 32767), -32768, 32767).astype(np.int16))


def git_commit() -> str:
    try:
        return subprocess.check_output(["git", "-C", str(HERE), "rev-parse", "HEAD"], text=True,
                                       stderr=subprocess.DEVNULL).strip()
    except Exception:  # noqa: BLE001
        return "unknown"


def file_table(tmp: Path) -> dict:
    """sha256 and size of every file of a bundle folder (the manifest's ``files``)."""
    return {str(p.relative_to(tmp)): {"sha256": sha256(p), "bytes": p.stat().st_size}
            for p in sorted(tmp.rglob("*")) if p.is_file()}


def write_manifest(tmp: Path, manifest: dict):
    with open(tmp / "manifest.json", "w") as f:
        json.dump(manifest, f, indent=1)
        f.write("\n")


def export_provenance(extra: dict | None = None) -> dict:
    import torch
    return {"date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "git_commit": git_commit(), "torch": torch.__version__, "onnx_opset": OPSET,
            "livegesture": livegesture.__version__, **(extra or {})}


def checkpoint_record(path: Path) -> dict:
    """How a bundle names the checkpoint it was exported from: its file name and sha256 (never a path of the
    machine that exported it)."""
    return {"file": Path(path).name, "sha256": sha256(Path(path))}


# an absolute path: a slash at the start of a token (not after a word character, a dot or another slash)
# followed by at least one path component
_ABS_PATH = re.compile(r"(?<![\w./~-])/(?:[\w.+-]+/)*([\w.+*-]+)")


def relative_paths(value):
    """``value`` (provenance: nested dicts, lists, strings) with every absolute path of the exporting machine
    replaced by its last component (``/tmp/corpus_sylb`` -> ``corpus_sylb``): a bundle names files, never where
    they were on one machine. Keys are kept; only string values change."""
    if isinstance(value, dict):
        return {k: relative_paths(v) for k, v in value.items()}
    if isinstance(value, list):
        return [relative_paths(v) for v in value]
    if isinstance(value, str):
        return _ABS_PATH.sub(lambda m: m.group(1), value)
    return value


def absolute_paths(value, where: str = "provenance") -> list[str]:
    """The absolute paths left in ``value``, each as ``key.path: text`` (empty when there are none)."""
    found = []
    if isinstance(value, dict):
        for k, v in value.items():
            found += absolute_paths(v, f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            found += absolute_paths(v, f"{where}[{i}]")
    elif isinstance(value, str):
        found += [f"{where}: {m.group(0)}" for m in _ABS_PATH.finditer(value)]
    return found
