"""Where is the upper-body speed coupling lost on real speech? (issue 16 diagnostic; no training, selects nothing)

Three probes, each scored on the real-speech VALIDATION split (8 clips) and the synthetic test split:

    python coupling.py decode --checkpoint CKPT --set real --seeds 13 14 15 16 17 18 --out DIR
    python coupling.py decode --checkpoint CKPT --set synth --synth /tmp/corpus_default --seeds 13 14 15 --out DIR
    python coupling.py encoder --checkpoint CKPT --synth /tmp/corpus_default --out FILE.json
    python coupling.py hidden --checkpoint CKPT --synth /tmp/corpus_default --seed 13 --out FILE.json
    python coupling.py generator --synth /tmp/corpus_default --out FILE.json

``decode``: the Python streaming reference (``livegesture.stream``) with two switches, everything else as shipped:

- ``heads``: ``fuse`` (default, xAR-Fuse logits for every region) or ``local`` (the upper and hands tokens drawn
  from the eXperts' LOCAL heads, ``expert.classifier(h_t^r)``; the fuse still runs for lower and face, and its
  caches advance as usual). The classifier weights are the same modules in both (shared, paper supp. B.2): only
  the hidden state differs (h^r vs the fused x^r);
- ``sampler``: ``sample`` (SPEC's temperature / top_k / guidance) or ``greedy`` (top_k = 1: argmax of the guided
  logits; deterministic, one realisation).

Each mode's motion is scored with ``livegesture.eval.generalise.evaluate_set`` (the metric of all issue-16 figures:
speed_env / jaw_env / bc gaps, audio swap and motion swap, realisations averaged per clip). Paired differences
between modes: per-clip gap differences, 95 % bootstrap CI over clips. Rollouts are cached as npz in ``--out``.
Also recorded per step in ``fuse`` mode: how often the local head's argmax equals the fuse's argmax (upper, hands).

``encoder``: ridge regression from the audio encoder's tokens a_t (offline forward, the same causal computation as
the streaming step) to the speech envelope of token t (mean of its 4 frames; raw and Gaussian-smoothed with
generalise's 0.2 s), fitted on the synthetic TRAIN split, R^2 on the synthetic test split and the real
validation split (per clip and pooled; ridge lambda chosen by 5-fold CV over train clips).

``hidden``: the same linear read-out of the envelope along the chain, from one default rollout per clip: the audio
token a_t, every eXpert's hidden h_t^r and the fuse's output per region (face: the jaw's contrast case); ridge fitted on the
synthetic test split's rollouts, per-clip Pearson r on synthetic test (5-fold CV over clips) and on real speech.

``generator``: the corpus generator's motion model (``synth.generate_motion``, speaker 2's style, seed 0 - the
``reference`` of the generalise reports) on each clip with features of the audio analysis ablated, speed_env gap
(audio swap) per ablation; plus the onset statistics that drive the arm strokes.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from livegesture.eval import generalise as G
from livegesture.eval import corpus as C
from livegesture.regions import FPS, FRAMES_PER_TOKEN, REGION_NAMES, SAMPLE_RATE
from livegesture.stream import LiveGestureStream, frames_to_arrays

LOCAL_REGIONS = ("upper", "hands")


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- decode probe

class ProbeStream(LiveGestureStream):
    """The streaming reference with the upper/hands logits optionally from the eXperts' local heads."""

    def __init__(self, model, seed, heads="fuse", top_k=None):
        super().__init__(model, seed=seed, top_k=top_k)
        if heads not in ("fuse", "local"):
            raise ValueError(heads)
        self.heads = heads
        self.agree = {r: [] for r in LOCAL_REGIONS}

    @torch.no_grad()
    def step_token(self, mel):
        # LiveGestureStream.step_token with the upper/hands rows of the logits swapped for the local heads'
        hidden, logits = self.hidden_and_logits(mel)
        logits = logits.copy()                                  # (B, R, K)
        for r in LOCAL_REGIONS:
            i = REGION_NAMES.index(r)
            loc = self.model.experts[r].logits(hidden[r]).numpy()
            self.agree[r].append(int(np.argmax(loc[0]) == np.argmax(logits[0, i])))
            if self.heads == "local":
                logits[:, i] = loc
        return self.emit(logits)


def rollout(model, audio, seed, heads, sampler) -> tuple[dict, dict]:
    s = ProbeStream(model, seed, heads, top_k=1 if sampler == "greedy" else None)
    fr = s.push(np.asarray(audio, np.float32))
    arr = frames_to_arrays(fr)
    return ({k: np.asarray(arr[k], np.float64) for k in ("poses", "trans", "expressions")},
            {r: float(np.mean(v)) for r, v in s.agree.items()})


MODES = {"fuse_sample": ("fuse", "sample"), "local_sample": ("local", "sample"),
         "fuse_greedy": ("fuse", "greedy"), "local_greedy": ("local", "greedy")}


def _paired(a_rows, b_rows, key, n_boot=2000):
    d = np.array([b[key]["gap"] - a[key]["gap"] for a, b in zip(a_rows, b_rows)])
    d = d[~np.isnan(d)]
    lo, hi = G.bootstrap_ci(d, n_boot)
    return {"mean": float(d.mean()), "ci95": [lo, hi], "clips_better": int((d > 0).sum()), "clips": int(len(d))}


def cmd_decode(a):
    from livegesture.checkpoint import load
    torch.set_num_threads(1)
    model = load(a.checkpoint)
    if a.set == "real":
        ids, aud = G.real_set(a.real_speech)
        speed_ref = G.train_speed_ref(a.synth) if a.synth else None
    else:
        ids, aud, _ = G.synth_set(a.synth, "test", a.max_clips)
        speed_ref = G.train_speed_ref(a.synth)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    ca = [G.ClipAudio(x) for x in aud]
    report = {"checkpoint": a.checkpoint, "set": a.set, "ids": ids, "seeds": a.seeds, "modes": {}}
    rows = {}
    for mode in a.modes:
        heads, sampler = MODES[mode]
        seeds = a.seeds if sampler == "sample" else [a.seeds[0]]   # greedy: deterministic (checked below)
        motions, agree = [], []
        for cid, x in zip(ids, aud):
            reals = []
            for sd in seeds:
                p = out / f"{mode}_s{sd}_{cid}.npz"
                if p.exists():
                    z = np.load(p)
                    m = {k: z[k] for k in ("poses", "trans", "expressions")}
                    ag = {r: float(z[f"agree_{r}"]) for r in LOCAL_REGIONS}
                else:
                    t0 = time.time()
                    m, ag = rollout(model, x, sd, heads, sampler)
                    np.savez(p, **m, **{f"agree_{r}": v for r, v in ag.items()})
                    _log(f"{mode} seed {sd} {cid}: {len(m['poses'])} frames {time.time() - t0:.1f} s")
                reals.append(m)
                agree.append(ag)
            motions.append(reals)
        cm = [[G.ClipMotion(m) for m in reals] for reals in motions]
        res = {}
        for design in G.DESIGNS:
            res[design] = G.evaluate_set(ids, cm, ca, speed_ref, design=design)
        res["mean_upper_speed_m_s"] = float(np.mean([np.mean([c.speed.mean() for c in reals]) for reals in cm]))
        res["argmax_agreement_local_vs_fuse"] = {r: float(np.mean([g[r] for g in agree])) for r in LOCAL_REGIONS}
        res["realisations"] = len(seeds)
        report["modes"][mode] = res
        rows[mode] = res
    pairs = [("fuse_sample", "local_sample"), ("fuse_sample", "fuse_greedy"), ("local_sample", "local_greedy"),
             ("fuse_greedy", "local_greedy")]
    report["paired"] = {}
    for x, y in pairs:
        if x in rows and y in rows:
            for design in G.DESIGNS:
                for k in ("speed_env", "jaw_env"):
                    report["paired"][f"{y} - {x}, {design}, {k}"] = _paired(
                        rows[x][design]["per_clip"], rows[y][design]["per_clip"], k)
    Path(a.report).write_text(json.dumps(report, indent=1, default=float))
    print(format_decode(report))


def format_decode(rep) -> str:
    L = [f"{rep['checkpoint']} on {rep['set']} ({len(rep['ids'])} clips), seeds {rep['seeds']}"]
    L.append(f"{'mode':<14} {'design':<12} {'speed own':>9} {'other':>7} {'gap':>7} {'95% CI':>17} {'wins':>5}"
             f"  {'jaw gap':>7} {'95% CI':>17}  agree(up,ha)")
    for mode, res in rep["modes"].items():
        for design in G.DESIGNS:
            s, j = res[design]["summary"]["speed_env"], res[design]["summary"]["jaw_env"]
            ag = res["argmax_agreement_local_vs_fuse"]
            L.append(f"{mode:<14} {design:<12} {s['own']:>9.3f} {s['other']:>7.3f} {s['gap']:>+7.3f} "
                     f"[{s['gap_ci95'][0]:+.3f}, {s['gap_ci95'][1]:+.3f}] {round(s['wins'] * s['clips'])}/{s['clips']}"
                     f"  {j['gap']:>+7.3f} [{j['gap_ci95'][0]:+.3f}, {j['gap_ci95'][1]:+.3f}]"
                     f"  {ag['upper']:.2f},{ag['hands']:.2f}")
    L.append("paired per-clip differences (95% bootstrap CI over clips):")
    for k, v in rep["paired"].items():
        L.append(f"  {k:<48} {v['mean']:+.3f} [{v['ci95'][0]:+.3f}, {v['ci95'][1]:+.3f}] "
                 f"better {v['clips_better']}/{v['clips']}")
    L.append("per clip speed_env gap (audio swap / motion swap):")
    for i, cid in enumerate(rep["ids"]):
        L.append(f"  {cid[:36]:<36} " + "  ".join(
            f"{m[:11]} {res['audio_swap']['per_clip'][i]['speed_env']['gap']:+.3f}/"
            f"{res['motion_swap']['per_clip'][i]['speed_env']['gap']:+.3f}" for m, res in rep["modes"].items()))
    return "\n".join(L)


# ----------------------------------------------------------------------------- hidden-state probe

@torch.no_grad()
def hidden_states(model, audio, seed):
    """One default (fuse, sampled) rollout; per token: audio token, the eXperts' hidden h^r (conditional branch)
    and the fuse's normalised output x^r (input of the classifiers), every region."""
    s = ProbeStream(model, seed, "fuse")
    rec = {"audio": [], "fuse_out": []}
    enc_step, fuse_cls = model.audio_encoder.step, model.fuse._classify
    exp_steps = {r: model.experts[r].step for r in REGION_NAMES}

    def enc(mel, cache):
        o, c = enc_step(mel, cache)
        rec["audio"].append(o["audio"][0].numpy().copy())
        return o, c

    def cls(x):
        rec["fuse_out"].append(model.fuse.norm(x)[0].numpy().copy())
        return fuse_cls(x)

    def make(r):
        def st(prev, audio, cond, cache):
            o, c = exp_steps[r](prev, audio, cond, cache)
            rec.setdefault(f"expert_{r}", []).append(o["hidden"][0].numpy().copy())
            return o, c
        return st
    model.audio_encoder.step, model.fuse._classify = enc, cls
    for r in REGION_NAMES:
        model.experts[r].step = make(r)
    try:
        s.push(np.asarray(audio, np.float32))
    finally:
        del model.audio_encoder.step, model.fuse._classify
        for r in REGION_NAMES:
            del model.experts[r].step
    fo = np.stack(rec["fuse_out"])          # (T, R, d)
    out = {"audio": np.stack(rec["audio"])}
    for r in REGION_NAMES:
        out[f"expert_{r}"] = np.stack(rec[f"expert_{r}"])
        out[f"fuse_{r}"] = fo[:, REGION_NAMES.index(r)]
    return out


def _ridge_fit(Xs, ys, lam):
    X = np.vstack(Xs)
    mu, sd = X.mean(0), X.std(0) + 1e-6
    Z = lambda A: np.hstack([(A - mu) / sd, np.ones((len(A), 1))])
    X = Z(X)
    w = np.linalg.solve(X.T @ X + lam * np.eye(X.shape[1]), X.T @ np.concatenate(ys))
    return lambda A: Z(A) @ w


def cmd_hidden(a):
    """Envelope decodability along the chain audio token -> eXpert hidden -> fuse output (every region), from
    one default rollout (seed ``--seed``) per clip; ridge fitted on the synthetic test split's rollouts (5-fold
    CV over clips for the synthetic score, all clips for the real score), scored by per-clip Pearson r."""
    from livegesture.checkpoint import load
    torch.set_num_threads(1)
    model = load(a.checkpoint)
    ids_s, aud_s, _ = G.synth_set(a.synth, "test")
    ids_r, aud_r = G.real_set(a.real_speech)
    t0 = time.time()
    Hs = [hidden_states(model, x, a.seed) for x in aud_s]
    Hr = [hidden_states(model, x, a.seed) for x in aud_r]
    _log(f"rollouts {time.time() - t0:.1f} s")
    env = lambda x, n: token_envelope(x, n, False)
    ys = [env(x, len(h["audio"])) for x, h in zip(aud_s, Hs)]
    yr = [env(x, len(h["audio"])) for x, h in zip(aud_r, Hr)]
    report = {"checkpoint": a.checkpoint, "seed": a.seed, "lambda": a.lam, "features": {}}
    for feat in ["audio"] + [f"{k}_{r}" for r in REGION_NAMES for k in ("expert", "fuse")]:
        folds = np.arange(len(Hs)) % 5
        rs = []
        for f in range(5):
            pr = _ridge_fit([h[feat] for h, k in zip(Hs, folds) if k != f], [y for y, k in zip(ys, folds) if k != f], a.lam)
            rs += [G.pearson(y, pr(h[feat])) for h, y, k in zip(Hs, ys, folds) if k == f]
        pr = _ridge_fit([h[feat] for h in Hs], ys, a.lam)
        rr = [G.pearson(y, pr(h[feat])) for h, y in zip(Hr, yr)]
        report["features"][feat] = {"synth_test_cv_r": float(np.mean(rs)), "synth_test_cv_r_ci95": list(G.bootstrap_ci(rs)),
                                    "real_r": float(np.mean(rr)), "real_r_ci95": list(G.bootstrap_ci(rr)),
                                    "real_per_clip": dict(zip(ids_r, rr))}
        f_ = report["features"][feat]
        print(f"{feat:<14} synth test (5-fold CV) r {f_['synth_test_cv_r']:.3f} [{f_['synth_test_cv_r_ci95'][0]:.3f}, "
              f"{f_['synth_test_cv_r_ci95'][1]:.3f}]   real val r {f_['real_r']:.3f} [{f_['real_r_ci95'][0]:.3f}, "
              f"{f_['real_r_ci95'][1]:.3f}]")
    Path(a.out).write_text(json.dumps(report, indent=1, default=float))


# ----------------------------------------------------------------------------- encoder probe

def token_envelope(audio, n_tok, smooth):
    env = G.speech_envelope(audio, n_tok * FRAMES_PER_TOKEN)
    if smooth:
        env = G._smooth(env)
    return env.reshape(n_tok, FRAMES_PER_TOKEN).mean(1)


@torch.no_grad()
def encoder_tokens(model, audio):
    from livegesture.frontend import logmel
    mel = logmel(np.asarray(audio, np.float32), model.cfg.frontend)
    a = model.audio_encoder(torch.as_tensor(mel)[None])[0].numpy().astype(np.float64)
    return a


def _r2(y, p):
    ss = float(((y - y.mean()) ** 2).sum())
    return 1.0 - float(((y - p) ** 2).sum()) / ss if ss > 0 else float("nan")


def cmd_encoder(a):
    from livegesture.checkpoint import load
    torch.set_num_threads(1)
    model = load(a.checkpoint)
    sets = {}
    for split in ("train", "test"):
        ids = C.read_split(a.synth, split)
        sets[f"synth_{split}"] = (ids, [C.load_audio(C.audio_path(a.synth, c))[0] for c in ids])
    sets["real_val"] = G.real_set(a.real_speech)
    feats = {}
    for name, (ids, aud) in sets.items():
        t0 = time.time()
        feats[name] = []
        for cid, x in zip(ids, aud):
            A = encoder_tokens(model, x)
            feats[name].append((cid, A, token_envelope(x, len(A), False), token_envelope(x, len(A), True)))
        _log(f"encoder features {name}: {len(ids)} clips {time.time() - t0:.1f} s")
    train = feats["synth_train"]
    mu = np.concatenate([f[1] for f in train]).mean(0)
    sd = np.concatenate([f[1] for f in train]).std(0) + 1e-6
    Z = lambda A: np.hstack([(A - mu) / sd, np.ones((len(A), 1))])
    report = {"checkpoint": a.checkpoint, "target": {}}
    for ti, tname in ((2, "envelope"), (3, "envelope_smoothed_0.2s")):
        # lambda by 5-fold CV over train clips
        folds = np.arange(len(train)) % 5
        best = None
        for lam in (0.1, 1.0, 10.0, 100.0, 1000.0, 10000.0):
            pred, ys = [], []
            for f in range(5):
                tr = [train[i] for i in range(len(train)) if folds[i] != f]
                te = [train[i] for i in range(len(train)) if folds[i] == f]
                X = np.vstack([Z(c[1]) for c in tr]); y = np.concatenate([c[ti] for c in tr])
                w = np.linalg.solve(X.T @ X + lam * np.eye(X.shape[1]), X.T @ y)
                pred.append(np.concatenate([Z(c[1]) @ w for c in te])); ys.append(np.concatenate([c[ti] for c in te]))
            r2 = _r2(np.concatenate(ys), np.concatenate(pred))
            if best is None or r2 > best[1]:
                best = (lam, r2)
        lam = best[0]
        X = np.vstack([Z(c[1]) for c in train]); y = np.concatenate([c[ti] for c in train])
        w = np.linalg.solve(X.T @ X + lam * np.eye(X.shape[1]), X.T @ y)
        res = {"lambda": lam, "cv_r2_train": best[1]}
        for name in ("synth_test", "real_val"):
            per = []
            for cid, A, e, es in feats[name]:
                yy = (e, es)[ti - 2]
                p = Z(A) @ w
                per.append({"id": cid, "r2": _r2(yy, p), "pearson": G.pearson(yy, p)})
            pooled_y = np.concatenate([(c[2], c[3])[ti - 2] for c in feats[name]])
            pooled_p = np.concatenate([Z(c[1]) @ w for c in feats[name]])
            r2s = [r["r2"] for r in per]
            prs = [r["pearson"] for r in per]
            res[name] = {"pooled_r2": _r2(pooled_y, pooled_p), "mean_clip_r2": float(np.mean(r2s)),
                         "mean_clip_r2_ci95": list(G.bootstrap_ci(r2s)), "mean_clip_pearson": float(np.mean(prs)),
                         "mean_clip_pearson_ci95": list(G.bootstrap_ci(prs)), "per_clip": per}
        report["target"][tname] = res
    Path(a.out).write_text(json.dumps(report, indent=1, default=float))
    for tname, res in report["target"].items():
        print(f"{tname}: lambda {res['lambda']}, CV R^2 on synth train {res['cv_r2_train']:.3f}")
        for name in ("synth_test", "real_val"):
            r = res[name]
            print(f"  {name:<10} pooled R^2 {r['pooled_r2']:.3f}; per-clip R^2 mean {r['mean_clip_r2']:.3f} "
                  f"[{r['mean_clip_r2_ci95'][0]:.3f}, {r['mean_clip_r2_ci95'][1]:.3f}], per-clip r "
                  f"{r['mean_clip_pearson']:.3f} [{r['mean_clip_pearson_ci95'][0]:.3f}, {r['mean_clip_pearson_ci95'][1]:.3f}]")
        for c in res["real_val"]["per_clip"]:
            print(f"    {c['id'][:36]:<36} R^2 {c['r2']:+.3f} r {c['pearson']:+.3f}")


# ----------------------------------------------------------------------------- generator probe

def _ablate(an, what):
    r = dataclasses.replace
    if what == "full":
        return an
    if what == "no_onsets":          # no strokes, no wrist flicks, no nods, no phrase-start re-keying
        z = np.zeros(0)
        return r(an, onsets=z, onset_strength=z, phrase_start=np.zeros(0, bool))
    if what == "const_strength":     # strokes at the same onsets, strength = the clip's median
        return r(an, onset_strength=np.full_like(an.onset_strength, float(np.median(an.onset_strength))
                                                 if len(an.onset_strength) else 0.0))
    if what == "no_phrase_start":
        return r(an, phrase_start=np.zeros_like(an.phrase_start))
    if what == "flat_pitch":
        return r(an, f0=np.zeros_like(an.f0))
    if what == "always_active":      # engagement (gesture space) constant
        return r(an, active=np.ones_like(an.active))
    if what in ("strength_from_env", "strength_from_env+always_active"):
        # what-if, not an ablation: onset strength = the analysis envelope at the onset (10 ms hop), so that
        # the stroke probability/amplitude follow the loudness of the syllable (a candidate target change)
        idx = np.clip(np.round(an.onsets / (an.times[1] - an.times[0])).astype(int), 0, len(an.env) - 1) \
            if len(an.onsets) else np.zeros(0, int)
        b = r(an, onset_strength=an.env[idx].astype(np.float64))
        return b if what == "strength_from_env" else r(b, active=np.ones_like(an.active))
    raise ValueError(what)


ABLATIONS = ("full", "no_onsets", "const_strength", "no_phrase_start", "flat_pitch", "always_active",
             "strength_from_env", "strength_from_env+always_active")


def cmd_generator(a):
    from livegesture.data import synth
    sets = {"real_val": G.real_set(a.real_speech)}
    ids, aud, _ = G.synth_set(a.synth, "test")
    sets["synth_test"] = (ids, aud)
    report = {}
    for name, (ids, aud) in sets.items():
        ca = [G.ClipAudio(x) for x in aud]
        ans, stats = [], []
        for x in aud:
            pcm = np.clip(np.round(np.asarray(x, np.float64) * 32767.0), -32768, 32767) / 32768.0
            an = synth.analyse_audio(pcm)
            ans.append(an)
            dur = len(x) / SAMPLE_RATE
            T = len(x) * FPS // SAMPLE_RATE
            # onset impulse train (strength-weighted) smoothed like the speed, against the envelope
            imp = np.zeros(T)
            for t0, s0 in zip(an.onsets, an.onset_strength):
                k = int(t0 * FPS)
                if k < T:
                    imp[k] += s0
            env = G.speech_envelope(x, T)
            q = np.quantile(an.onset_strength, 0.45) if len(an.onset_strength) else 0.0
            stressed = (an.onset_strength >= q) | an.phrase_start
            stats.append({"onsets_per_s": len(an.onsets) / dur, "stressed_per_s": float(stressed.sum()) / dur,
                          "phrase_starts_per_s": float(an.phrase_start.sum()) / dur,
                          "active_fraction": float(an.active.mean()),
                          "mean_strength": float(an.onset_strength.mean()) if len(an.onsets) else float("nan"),
                          "onset_train_vs_env_r": G.pearson(G._smooth(imp), G._smooth(env)),
                          "active_vs_env_r": G.pearson(G._smooth(synth._at_frames(an, an.active.astype(float), T)),
                                                       G._smooth(env))})
        res = {"stats_mean": {k: float(np.nanmean([s[k] for s in stats])) for k in stats[0]},
               "stats_per_clip": [dict(id=c, **s) for c, s in zip(ids, stats)], "ablations": {}}
        for ab in ABLATIONS:
            ms = []
            for x, an in zip(aud, ans):
                T = len(x) * FPS // SAMPLE_RATE
                p, tr, ex = synth.generate_motion(_ablate(an, ab), T, synth.STYLE_BY_SPEAKER[2],
                                                  np.random.default_rng(0))
                ms.append([G.ClipMotion({"poses": p, "trans": tr, "expressions": ex})])
            ev = G.evaluate_set(ids, ms, ca, None, design="audio_swap")
            s = ev["summary"]["speed_env"]
            res["ablations"][ab] = {"speed_env": s, "per_clip_gap": [r["speed_env"]["gap"] for r in ev["per_clip"]],
                                    "mean_upper_speed_m_s": float(np.mean([m[0].speed.mean() for m in ms]))}
        report[name] = res
    Path(a.out).write_text(json.dumps(report, indent=1, default=float))
    for name, res in report.items():
        print(f"== {name}: " + ", ".join(f"{k} {v:.3f}" for k, v in res["stats_mean"].items()))
        for ab, r in res["ablations"].items():
            s = r["speed_env"]
            print(f"  {ab:<16} speed_env own {s['own']:.3f} other {s['other']:.3f} gap {s['gap']:+.3f} "
                  f"[{s['gap_ci95'][0]:+.3f}, {s['gap_ci95'][1]:+.3f}] wins {round(s['wins'] * s['clips'])}/{s['clips']}, "
                  f"mean upper speed {r['mean_upper_speed_m_s']:.4f} m/s")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("decode")
    d.add_argument("--checkpoint", required=True)
    d.add_argument("--set", choices=("real", "synth"), required=True)
    d.add_argument("--synth", default="/tmp/corpus_default")
    d.add_argument("--real-speech")
    d.add_argument("--max-clips", type=int)
    d.add_argument("--seeds", type=int, nargs="+", required=True)
    d.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    d.add_argument("--out", required=True, help="folder for the cached rollouts")
    d.add_argument("--report", required=True, help="JSON report path")
    e = sub.add_parser("encoder")
    e.add_argument("--checkpoint", required=True)
    e.add_argument("--synth", default="/tmp/corpus_default")
    e.add_argument("--real-speech")
    e.add_argument("--out", required=True)
    h = sub.add_parser("hidden")
    h.add_argument("--checkpoint", required=True)
    h.add_argument("--synth", default="/tmp/corpus_default")
    h.add_argument("--real-speech")
    h.add_argument("--seed", type=int, default=13)
    h.add_argument("--lam", type=float, default=100.0)
    h.add_argument("--out", required=True)
    g = sub.add_parser("generator")
    g.add_argument("--synth", default="/tmp/corpus_default")
    g.add_argument("--real-speech")
    g.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    {"decode": cmd_decode, "encoder": cmd_encoder, "hidden": cmd_hidden, "generator": cmd_generator}[a.cmd](a)


if __name__ == "__main__":
    main()
