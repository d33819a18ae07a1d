"""Adds the face graph to a bundle (docs/face.md): ``face.onnx``, its reference vectors, and the
manifest's ``graphs`` row, ``checks.face``, ``reference.graphs.face``, ``files`` entries and ``face`` section.

  python -m livegesture.face.export --checkpoint models/face.train/face.pt --bundle models/default

The graph is one token's step, like every other graph (docs/bundle.md): inputs ``mel`` (batch, 8, 64) and the caches
``cache.<name>``; outputs ``visemes`` (batch, 4, 15), ``arkit_mouth`` (batch, 4, 52) and ``new_cache.<name>``.
Checked before anything is written: torch step-by-step vs the offline causal forward (1e-5 scaled) and
onnxruntime vs torch over chained steps at batches 1, 2 and 5 (1e-5 scaled); the figures go to
``checks.face``. The bundle's manifest is rewritten last (atomically), so a failed export leaves the bundle
as it was.
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

from ..compare import diff
from .blink import BLINK
from .head import VisemeHead
from .names import ARKIT_NAMES, VISEME_ARKIT, VISEME_NAMES
from .train import load_head

GRAPH = "face"
OPSET = 17
BOUND = 1e-5
REFERENCE_STEPS = 10
REFERENCE_BATCH = 2


class FaceExportError(RuntimeError):
    pass


class _Step(nn.Module):
    def __init__(self, head: VisemeHead):
        super().__init__()
        self.head = head
        self.names = [s.name for s in head.cache_specs()]

    def forward(self, mel, *caches):
        out, new = self.head.step(mel, dict(zip(self.names, caches)))
        return (out["visemes"], out["arkit_mouth"], *[new[n] for n in self.names])


def _inputs(head, B, g):
    cfg = head.cfg
    return torch.randn(B, cfg.mel_frames_per_token, cfg.n_mels, generator=g) * head.mel_std + head.mel_mean


def graph_spec(head: VisemeHead) -> dict:
    cfg = head.cfg
    return {"name": GRAPH, "file": f"{GRAPH}.onnx", "component": "VisemeHead", "region": None,
            "inputs": [{"name": "mel", "dtype": "float32", "shape": ["batch", cfg.mel_frames_per_token, cfg.n_mels]}],
            "outputs": [{"name": "visemes", "dtype": "float32", "shape": ["batch", cfg.frames_per_token, len(VISEME_NAMES)]},
                        {"name": "arkit_mouth", "dtype": "float32", "shape": ["batch", cfg.frames_per_token, len(ARKIT_NAMES)]}],
            "caches": [{"name": s.name, "input": f"cache.{s.name}", "output": f"new_cache.{s.name}", "dtype": s.dtype,
                        "shape": ["batch", *s.shape], "init": s.init} for s in head.cache_specs()],
            "reference": f"reference/{GRAPH}.npz"}


def export_onnx(head: VisemeHead, path: Path):
    import onnx

    w = _Step(head).eval()
    caches = head.init_cache(2)
    args = (_inputs(head, 2, torch.Generator().manual_seed(0)),) + tuple(caches[n] for n in w.names)
    names_in = ["mel"] + [f"cache.{n}" for n in w.names]
    names_out = ["visemes", "arkit_mouth"] + [f"new_cache.{n}" for n in w.names]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(w, args, str(path), input_names=names_in, output_names=names_out,
                          dynamic_axes={n: {0: "batch"} for n in names_in + names_out}, opset_version=OPSET,
                          do_constant_folding=True, dynamo=False)
    m = onnx.load(str(path))
    onnx.checker.check_model(m, full_check=True)
    bad = sorted({n.op_type for n in m.graph.node if n.op_type in ("If", "Loop", "Scan")})
    if bad:
        raise FaceExportError(f"graph '{GRAPH}': data-dependent control flow {bad}")
    if [i.name for i in m.graph.input] != names_in:
        raise FaceExportError(f"graph '{GRAPH}': exported inputs {[i.name for i in m.graph.input]} != {names_in}")
    import livegesture
    for k, v in {"livegesture.schema_version": "1", "livegesture.graph": GRAPH,
                 "livegesture.component": "VisemeHead", "livegesture.version": livegesture.__version__}.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    m.producer_name = "livegesture-export"
    onnx.save(m, str(path))


@torch.no_grad()
def check_step_vs_offline(head: VisemeHead, n_tokens: int = 24) -> tuple[float, float]:
    M = head.cfg.mel_frames_per_token
    mel = _inputs(head, 2, torch.Generator().manual_seed(1)).repeat(1, n_tokens, 1)
    mel = mel + torch.randn(mel.shape, generator=torch.Generator().manual_seed(2)) * head.mel_std
    off = head.outputs(head(mel))
    cache, st = head.init_cache(2), {"visemes": [], "arkit_mouth": []}
    for t in range(n_tokens):
        o, cache = head.step(mel[:, t * M:(t + 1) * M], cache)
        for k in st:
            st[k].append(o[k])
    worst = (0.0, 1.0)
    for k in st:
        d = diff(torch.cat(st[k], 1).numpy(), off[k].numpy())
        if not d.within(BOUND):
            raise FaceExportError(f"torch step vs offline: graph '{GRAPH}', output '{k}': {d.describe()} "
                                  f"> {BOUND} (scaled)")
        if d.scaled_error > worst[0] / worst[1]:
            worst = (d.max_abs, d.scale)
    return worst


@torch.no_grad()
def check_ort_vs_torch(head: VisemeHead, path: Path, n_steps: int = 8, batches=(1, 2, 5)) -> tuple[float, float]:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    out_names = [o.name for o in sess.get_outputs()]
    specs = head.cache_specs()
    worst = (0.0, 1.0)
    for B in batches:
        g = torch.Generator().manual_seed(100 + B)
        t_cache = head.init_cache(B)
        o_cache = {s.name: t_cache[s.name].numpy() for s in specs}
        for step in range(n_steps):
            mel = _inputs(head, B, g)
            t_out, t_cache = head.step(mel, t_cache)
            feed = {"mel": mel.numpy(), **{f"cache.{k}": v for k, v in o_cache.items()}}
            res = dict(zip(out_names, sess.run(None, feed)))
            ref = {k: v.numpy() for k, v in t_out.items()}
            ref.update({f"new_cache.{k}": v.numpy() for k, v in t_cache.items()})
            for name, want in ref.items():
                d = diff(res[name], want)
                if res[name].shape != want.shape or not d.within(BOUND):
                    raise FaceExportError(f"onnxruntime vs torch: graph '{GRAPH}', output '{name}', step {step}, "
                                          f"batch {B}: {d.describe()} > {BOUND} (scaled)")
                if d.scaled_error > worst[0] / worst[1]:
                    worst = (d.max_abs, d.scale)
            o_cache = {s.name: res[f"new_cache.{s.name}"] for s in specs}
    return worst


@torch.no_grad()
def reference_vectors(head: VisemeHead) -> dict[str, np.ndarray]:
    g = torch.Generator().manual_seed(7)
    cache = head.init_cache(REFERENCE_BATCH)
    out = {"n_steps": np.array(REFERENCE_STEPS), "batch": np.array(REFERENCE_BATCH)}
    for s in range(REFERENCE_STEPS):
        mel = _inputs(head, REFERENCE_BATCH, g)
        o, new = head.step(mel, cache)
        out[f"step{s}.input.mel"] = mel.numpy()
        for k, v in o.items():
            out[f"step{s}.output.{k}"] = v.numpy()
        if s == REFERENCE_STEPS - 1:
            for k, v in new.items():
                out[f"step{s}.new_cache.{k}"] = v.numpy()
        cache = new
    return out


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


def _write_atomic(path: Path, data: bytes):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def face_section(head: VisemeHead, checkpoint: Path, provenance: dict, evaluation: dict | None) -> dict:
    return {
        "graph": GRAPH,
        "contract": "per token: the token's log-mel frames (the body graphs' frontend) -> the 4 frames' visemes "
                    "(softmax over 15) and arkit_mouth (visemes @ viseme_arkit, clamped to [0, 1]); arkit = "
                    "arkit_mouth with eyeBlinkLeft/eyeBlinkRight set by the seeded blink process (blink); "
                    "causal: a frame uses no audio after its own end (docs/face.md)",
        "visemes": list(VISEME_NAMES),
        "arkit": list(ARKIT_NAMES),
        "viseme_arkit": {v: VISEME_ARKIT[v] for v in VISEME_NAMES},
        "blink": BLINK,
        "brows": "not driven (0): no prosody model yet",
        "training": {"checkpoint_sha256": _sha(Path(checkpoint).read_bytes()), **provenance},
        "evaluation": evaluation,
    }


def add_to_bundle(checkpoint: Path, bundle: Path, log=print) -> dict:
    bundle = Path(bundle)
    mpath = bundle / "manifest.json"
    if not mpath.exists():
        raise FaceExportError(f"{mpath}: no manifest (is {bundle} a bundle folder?)")
    manifest = json.loads(mpath.read_text())
    fr = manifest.get("frontend", {})
    head = load_head(checkpoint)
    want = {"sample_rate": 16000, "fps": 30, "frames_per_token": head.cfg.frames_per_token,
            "mel_frames_per_token": head.cfg.mel_frames_per_token, "n_mels": head.cfg.n_mels}
    wrong = {k: (fr.get(k), v) for k, v in want.items() if fr.get(k) != v}
    if wrong:
        raise FaceExportError(f"{mpath}: frontend {wrong} (bundle, face head) differ: the face head reads the "
                              "body graphs' log-mel frames")
    so = check_step_vs_offline(head)
    with tempfile.TemporaryDirectory() as tmp:
        onnx_tmp = Path(tmp) / "face.onnx"
        export_onnx(head, onnx_tmp)
        ot = check_ort_vs_torch(head, onnx_tmp)
        onnx_bytes = onnx_tmp.read_bytes()
    buf = io.BytesIO()
    np.savez(buf, **reference_vectors(head))
    ref_bytes = buf.getvalue()
    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    ev_path = Path(checkpoint).parent / "eval.json"
    evaluation = json.loads(ev_path.read_text())["mean"] if ev_path.exists() else None
    _write_atomic(bundle / "face.onnx", onnx_bytes)
    _write_atomic(bundle / "reference" / "face.npz", ref_bytes)
    spec = graph_spec(head)
    manifest["graphs"] = [g for g in manifest["graphs"] if g["name"] != GRAPH] + [spec]
    manifest.setdefault("checks", {})[GRAPH] = {
        "torch_step_vs_offline_max_abs": so[0], "torch_step_vs_offline_scale": so[1],
        "ort_vs_torch_max_abs": ot[0], "ort_vs_torch_scale": ot[1], "batches_checked": [1, 2, 5]}
    manifest.setdefault("reference", {}).setdefault("graphs", {})[GRAPH] = spec["reference"]
    manifest["files"]["face.onnx"] = {"sha256": _sha(onnx_bytes), "bytes": len(onnx_bytes)}
    manifest["files"]["reference/face.npz"] = {"sha256": _sha(ref_bytes), "bytes": len(ref_bytes)}
    manifest["files"] = dict(sorted(manifest["files"].items()))
    manifest["face"] = face_section(head, checkpoint, ck.get("provenance", {}), evaluation)
    _write_atomic(mpath, (json.dumps(manifest, indent=1) + "\n").encode())
    log(f"[face] {bundle}: face.onnx ({len(onnx_bytes)} bytes), torch step vs offline {so[0]:.2e} (scale "
        f"{so[1]:.2f}), ort vs torch {ot[0]:.2e} (scale {ot[1]:.2f})")
    return manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.face.export", description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--bundle", required=True, action="append", help="a bundle folder (repeatable)")
    a = ap.parse_args(argv)
    try:
        for b in a.bundle:
            add_to_bundle(Path(a.checkpoint), Path(b))
    except (FaceExportError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
