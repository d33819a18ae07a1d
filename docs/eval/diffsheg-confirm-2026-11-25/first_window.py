"""Is the fast head of DiffSHEG's motion the first FOPPAS window's plain DDIM (no RePaint jumps)?

    python docs/eval/diffsheg-confirm-2026-11-25/first_window.py --checkpoint CKPT [--seeds 7 8 9] [--guidance 3]

The sampler (livegesture.diffsheg.foppas, SPEC 13) runs the first window of a stream as plain DDIM
(U_j = 1: it has no known frames to re-impose) and every later window with U = 2 RePaint jumps. This
script samples ONE window (the first N = 88 frames of each real-speech validation recording, its own mel,
the bundle's speaker) with the Python reference sampler in three ways, same seeds and noise streams:

- ``plain``: as shipped (plain DDIM, 25 steps);
- ``jumps``: the same window with the U = 2 RePaint jumps of the later windows (re-noise x_{t-1} -> x_t and
  denoise again, RePaint's resampling without a known part);
- ``known``: the same window with U = 2 jumps AND its first L = 10 frames given as known frames, as every
  later window is sampled (the known frames: the first 10 frames of the ``plain`` sample, since the first
  window has no predecessor; so frames 0-9 of ``known`` are ``plain``'s, read frames 15-77).

and prints the mean smoothed upper-body speed of frames [0, 15), [15, 78) per variant (generalise's
``upper_speed`` and 0.2 s smoothing).
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np
import torch

from livegesture.checkpoint import load as load_checkpoint
from livegesture.diffsheg import foppas as F
from livegesture.diffsheg.denoiser import MOTION_DIM
from livegesture.diffsheg.noise import NoiseStream
from livegesture.diffsheg.schedule import alphas_cumprod, ddim_timesteps
from livegesture.eval import generalise as G
from livegesture.frontend import logmel_frames
from livegesture.motion import features_to_motion
from livegesture.diffsheg.model import motion_layout


def sample_jumps_no_known(backend, audio, speaker, noise, opts, ab):
    """sample_windows for one window without known frames, but with opts.jumps RePaint jumps for j > 0
    (the shipped sampler uses U_j = 1 when L = 0)."""
    n = audio.shape[0]
    taus = ddim_timesteps(opts.steps)
    x = noise.take((n, MOTION_DIM))[None]
    spk = np.asarray([speaker], np.int64)
    for j in range(opts.steps - 1, -1, -1):
        a_t = float(ab[taus[j]])
        a_p = float(ab[taus[j - 1]]) if j > 0 else 1.0
        U = opts.jumps if j > 0 else 1
        for u in range(U):
            eps = F.guided_eps_batch(backend, x, int(taus[j]), audio[None], spk, opts.guidance)
            x0 = (x.astype(np.float64) - math.sqrt(1.0 - a_t) * eps) / math.sqrt(a_t)
            xp = math.sqrt(a_p) * x0 + math.sqrt(1.0 - a_p) * eps
            if u < U - 1:
                r = a_t / a_p
                x = (math.sqrt(r) * xp + math.sqrt(1.0 - r) * noise.take((n, MOTION_DIM))[None].astype(np.float64)
                     ).astype(np.float32)
            else:
                x = xp.astype(np.float32)
    return x[0]


def speed_of(model, x):
    feats = model.denormalise(x)
    regions = {e["region"]: feats[:, e["offset"]:e["offset"] + e["dim"]] for e in motion_layout()}
    m = features_to_motion(regions)
    cm = G.ClipMotion({"poses": m["poses"], "trans": m["trans"]})
    return G._smooth(cm.speed)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9])
    p.add_argument("--guidance", type=float, default=3.0)
    p.add_argument("--offset", type=float, default=0.0,
                   help="start the window this many seconds into each recording (0: the real first window; "
                        "> 0: a window that starts in speech, sampled as if it were a first window)")
    p.add_argument("--variants", nargs="+", default=["plain", "jumps", "known"])
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    model = load_checkpoint(a.checkpoint)
    opts = F.SamplerOptions.from_config(model.cfg, guidance=a.guidance)
    backend = F.TorchBackend(model)
    ab = alphas_cumprod(model.cfg.diffusion_steps, model.cfg.beta_start, model.cfg.beta_end)
    N, L = opts.window, opts.overlap
    spk = model.default_speaker()
    ids, audios = G.real_set()
    res = {k: [] for k in a.variants}
    s0 = int(round(a.offset * 30))
    for cid, x in zip(ids, audios):
        x = np.asarray(x, np.float32)
        if len(x) < (s0 + N) * 16000 // 30:
            continue
        mel = logmel_frames(x, 2 * s0, 2 * N, model.cfg.frontend)
        audio = backend.encode(mel[None])[0]
        for sd in a.seeds:
            out = {"plain": F.sample_window(backend, audio, spk, NoiseStream(sd), None, opts, ab)}
            if "jumps" in res:
                out["jumps"] = sample_jumps_no_known(backend, audio, spk, NoiseStream(sd), opts, ab)
            if "known" in res:
                out["known"] = F.sample_window(backend, audio, spk, NoiseStream(sd), out["plain"][:L].copy(), opts, ab)
            for k in res:
                v = out[k]
                s = speed_of(model, v)
                res[k].append((float(s[:15].mean()), float(s[15:78].mean()), float(s.mean())))
        print(f"{cid} done", file=sys.stderr, flush=True)
    print(f"one window (N = {N} frames, from {a.offset} s) of {len(next(iter(res.values()))) // len(a.seeds)} recordings x seeds {a.seeds}, "
          f"guidance {a.guidance}, jumps {opts.jumps}: mean smoothed upper-body speed")
    print(f"{'variant':<8} {'frames 0-14':>12} {'frames 15-77':>13} {'all 88':>8}")
    for k, v in res.items():
        m = np.mean(np.array(v), 0)
        print(f"{k:<8} {m[0]:>12.3f} {m[1]:>13.3f} {m[2]:>8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
