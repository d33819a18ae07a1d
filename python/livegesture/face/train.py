"""Train the viseme head (:mod:`.head`) on phone labels: the real-speech TRAIN split (each channel of a
multi-channel file separately) and synthetic speech (espeak-ng and Festival-Lite voices of the corpus
generator), both labelled by pocketsphinx's allphone decoder (:mod:`.labels`). Never the VALIDATION split.

  python -m livegesture.face.train --out models/face/face.pt [--synthetic 60] [--steps 3000] [--seed 0]

Loss: cross-entropy over the 15 visemes, classes weighted by 1 / sqrt(frequency); training crops of 48
tokens; random gain (+-12 dB, an additive constant on the log-mel) as augmentation; Adam.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .head import FaceConfig, VisemeHead
from .names import VISEME_NAMES, phone_viseme


def load_head(path) -> VisemeHead:
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = FaceConfig(**{**ck["config"], "dilations": tuple(ck["config"]["dilations"])})
    head = VisemeHead(cfg)
    head.load_state_dict(ck["state_dict"])
    head.eval()
    return head


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.face.train")
    ap.add_argument("--out", required=True)
    ap.add_argument("--synthetic", type=int, default=60, help="synthetic clips (10 s each)")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--crop-tokens", type=int, default=48)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--real-speech", default=None)
    ap.add_argument("--labels-cache", default="target/face-labels")
    a = ap.parse_args(argv)
    torch.manual_seed(a.seed)
    torch.set_num_threads(1)
    rng = np.random.default_rng(a.seed)
    from .data import real_clips, synthetic_clips

    t0 = time.time()
    cache = Path(a.labels_cache)
    clips = real_clips("train", cache, a.real_speech, channels=True)
    n_real = len(clips)
    clips += synthetic_clips(a.synthetic, 10.0, 1000 + a.seed, cache)
    print(f"[face] {n_real} real + {len(clips) - n_real} synthetic clips labelled in {time.time() - t0:.0f} s")
    cfg = FaceConfig()
    head = VisemeHead(cfg)
    allmel = np.concatenate([c.mel for c in clips])
    head.mel_mean.copy_(torch.from_numpy(allmel.mean(0)))
    head.mel_std.copy_(torch.from_numpy(allmel.std(0) + 1e-3))
    M, P = cfg.mel_frames_per_token, head.P
    data = []
    for c in clips:
        y = np.array([phone_viseme(p) for p in c.phones], dtype=np.int64)
        n_fr = c.mel.shape[0] // P
        yy = np.full(n_fr, -100, dtype=np.int64)
        yy[:len(y)] = y
        data.append((c.mel, yy))
    counts = np.bincount(np.concatenate([y[y >= 0] for _, y in data]), minlength=len(VISEME_NAMES))
    w = 1.0 / np.sqrt(np.maximum(counts, 1) / counts.sum())
    w = torch.tensor(w / w.mean(), dtype=torch.float32)
    # real clips drawn as often as synthetic ones in total (they are what the model must follow)
    probs = np.array([len(y) for _, y in data], dtype=np.float64)
    probs[:n_real] *= probs[n_real:].sum() / max(probs[:n_real].sum(), 1) if len(data) > n_real else 1.0
    probs /= probs.sum()
    opt = torch.optim.Adam(head.parameters(), lr=a.lr)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=a.lr, total_steps=a.steps, pct_start=0.1)
    T = a.crop_tokens * M
    log = []
    for step in range(a.steps):
        mels, ys = [], []
        for i in rng.choice(len(data), a.batch, p=probs):
            mel, y = data[i]
            n_tok = mel.shape[0] // M
            if n_tok > a.crop_tokens:
                s = int(rng.integers(0, n_tok - a.crop_tokens + 1))
            else:
                s = 0
            m = mel[s * M:s * M + T]
            yy = y[s * M // P:(s * M + T) // P]
            if m.shape[0] < T:   # pad short clips with -100 labels (ignored) and the mean frame
                pad = T - m.shape[0]
                m = np.concatenate([m, np.repeat(head.mel_mean.numpy()[None], pad, 0)])
                yy = np.concatenate([yy, np.full(pad // P, -100)])
            gain = rng.uniform(-12, 12) / 20 * np.log(10) * 2        # ln(g^2) for g in +-12 dB
            mels.append(m + np.float32(gain))
            ys.append(yy)
        x = torch.from_numpy(np.stack(mels).astype(np.float32))
        y = torch.from_numpy(np.stack(ys))
        logits = head(x)
        loss = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), y.reshape(-1), weight=w, ignore_index=-100)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(head.parameters(), 1.0)
        opt.step()
        sched.step()
        if step % 200 == 0 or step == a.steps - 1:
            print(f"[face] step {step} loss {loss.item():.3f} ({time.time() - t0:.0f} s)", flush=True)
            log.append({"step": step, "loss": float(loss.item())})
    head.eval()
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    prov = {"real_train": [c.name for c in clips[:n_real]], "synthetic_clips": len(clips) - n_real,
            "synthetic_seconds_each": 10.0, "steps": a.steps, "batch": a.batch, "crop_tokens": a.crop_tokens,
            "lr": a.lr, "seed": a.seed, "label_counts": dict(zip(VISEME_NAMES, counts.tolist())),
            "seconds": round(time.time() - t0, 1)}
    torch.save({"config": cfg.to_dict(), "state_dict": head.state_dict(), "provenance": prov, "log": log}, out)
    print(f"[face] wrote {out}: {json.dumps(prov)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
