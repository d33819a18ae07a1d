"""``python -m livegesture.eval``: BEAT2-style evaluation report (docs/evaluation.md).

    python -m livegesture.eval --data DIR [--split test] [--generated GEN_DIR ...] [--checkpoint CKPT]
                               [--fgd-encoder PATH] [--out report.json]

- ``--data``: a BEAT2-layout corpus (``smplxflame_30/``, ``wave16k/``, ``train_test_split.csv``).
- ``--generated``: a folder of generated ``{id}.npz`` (BEAT2 output layout) for the split's clips; give it
  several times for several realisations of the same audio (needed for the paper's L1 diversity, eq. 2).
- ``--checkpoint``: generate with a trained model instead (``livegesture.checkpoint.load`` +
  ``livegesture.stream.generate_clip``; either family: a DiffSHEG checkpoint runs the FOPPAS reference
  sampler ``livegesture.diffsheg.foppas`` with its default options), ``--n-realisations`` seeds per clip
  (``--seed`` upwards).
- ``--fgd-encoder``: the FGD feature encoder; trained on the corpus's train split and saved there if the
  file does not exist.

The report holds, for the generated motion (realisation 0 for everything but eq. 2) AND for the corpus's
own motion of the split (the reference):

- ``bc``: Beat Constancy against the clip's own audio; ``bc_mismatched_audio``: against the audio of
  another clip (a fixed derangement: clip i of the sorted ids gets the audio of clip i+1, cyclically) —
  motion that follows its audio scores clearly higher matched than mismatched; ``bc_gap`` is the
  difference and ``bc_matched_wins`` the fraction of clips whose matched BC beats their mismatched BC;
- ``bc_mismatched_motion``, ``bc_gap_motion_swap``, ``bc_motion_swap_wins``: the motion swap, clip i's own
  audio against the motion of clip i+1 over the frames both have. The onset track is the same on both sides,
  so the gap is not the onset-density difference of two recordings (``livegesture.eval.generalise`` and
  docs/evaluation.md explain why the audio swap has no power on dense real speech);
- ``l1div_realisations`` (paper eq. 2, generated only, >= 2 realisations), ``l1div_beat2`` (the EMAGE
  code's L1div), ``l1div_across_clips``;
- ``fgd`` (generated vs real motion of the split; for the reference, real split vs real train split)
  and ``fgd_vs_train`` (vs the train split, for both);
- ``face``: MSE of jaw rotation and expressions against the real clip of the same id (0 for the reference
  by definition); ``face_vertex_mse`` when ``--face-model`` is given.

BC of a set is the mean of the clips' BC weighted by their trimmed lengths (EMAGE). Joint positions come
from the project skeleton (``livegesture.skeleton``), global translation removed.
"""
from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from . import corpus
from . import metrics as M
from .report import jsonable
from .. import families
from ..regions import FPS, SAMPLE_RATE


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- loading

def _load_generated(dirs: list[str], ids: list[str]) -> tuple[list[str], list[list[dict]], list[str]]:
    """-> (ids present in every folder, realisations per id, missing ids)."""
    present, reals, missing = [], [], []
    for cid in ids:
        paths = [Path(d) / f"{cid}.npz" for d in dirs]
        if not all(p.exists() for p in paths):
            missing.append(cid)
            continue
        present.append(cid)
        reals.append([corpus.load_motion(p) for p in paths])
    return present, reals, missing


def _generate(ckpt: str, ids: list[str], audio: dict, n: int, seed: int, guidance, save_dir,
              device: str = "cpu") -> list[list[dict]]:
    try:
        from ..checkpoint import load as load_checkpoint
        from ..stream import generate_clip
    except ImportError as e:
        raise SystemExit(f"--checkpoint needs livegesture.checkpoint.load and livegesture.stream.generate_clip, "
                         f"which cannot be imported here ({e}); generate the clips and pass --generated DIR") from e
    model = load_checkpoint(ckpt).to(device)     # the streaming loops run where the model is
    fam = families.of_model(model)
    if fam.batch_sampler:     # the family samples many clips at once (DiffSHEG: windows of all clips batched)
        return _generate_batched(fam, model, ids, audio, n, seed, guidance, save_dir)
    out = []
    for k, cid in enumerate(ids):
        x = audio[cid]
        reals = []
        for r in range(n):
            t0 = time.time()
            g = generate_clip(model, x.astype(np.float32), seed=seed + r, guidance=guidance)
            m = {"poses": np.asarray(g["poses"], np.float64).reshape(len(g["poses"]), -1),
                 "trans": np.asarray(g["trans"], np.float64).reshape(-1, 3),
                 "expressions": np.asarray(g["expressions"], np.float64).reshape(len(g["expressions"]), -1)}
            reals.append(m)
            if save_dir:
                from ..motion import beat2_npz_dict
                d = Path(save_dir) / (f"seed{seed + r}" if n > 1 else "")
                d.mkdir(parents=True, exist_ok=True)
                np.savez(d / f"{cid}.npz", **beat2_npz_dict(m))
            _log(f"generated {cid} seed {seed + r}: {len(m['poses'])} frames in {time.time() - t0:.1f} s "
                 f"({k + 1}/{len(ids)})")
        out.append(reals)
    return out


def _generate_batched(fam, model, ids, audio, n, seed, guidance, save_dir) -> list[list[dict]]:
    """Every clip and seed sampled together by the family's batch sampler (DiffSHEG:
    ``livegesture.diffsheg.foppas.generate_clips``: the windows of all clips batched; each clip's frames are
    those of its own stream)."""
    from ..motion import beat2_npz_dict
    generate_clips = fam.resolve(fam.batch_sampler)
    t0 = time.time()
    jobs = [(cid, r) for cid in ids for r in range(n)]
    gens = generate_clips(model, [audio[cid].astype(np.float32) for cid, _ in jobs], [seed + r for _, r in jobs],
                          guidance=guidance)
    out = {cid: [] for cid in ids}
    for (cid, r), g in zip(jobs, gens):
        m = {"poses": np.asarray(g["poses"], np.float64).reshape(len(g["poses"]), -1),
             "trans": np.asarray(g["trans"], np.float64).reshape(-1, 3),
             "expressions": np.asarray(g["expressions"], np.float64).reshape(len(g["expressions"]), -1)}
        out[cid].append(m)
        if save_dir:
            d = Path(save_dir) / (f"seed{seed + r}" if n > 1 else "")
            d.mkdir(parents=True, exist_ok=True)
            np.savez(d / f"{cid}.npz", **beat2_npz_dict(m))
    _log(f"generated {len(jobs)} clips ({fam.name}, batched) in {time.time() - t0:.1f} s")
    return [out[cid] for cid in ids]


def _load_face_model(spec: str | None):
    if not spec:
        return None
    if ":" not in spec:
        raise SystemExit("--face-model must be module:function (a callable f(poses, trans, expressions) -> "
                         "(T, V, 3) vertices built on the user's SMPL-X model)")
    mod, fn = spec.split(":", 1)
    return getattr(importlib.import_module(mod), fn)


# ----------------------------------------------------------------------------- metrics of a motion set

def _bc_set(joints: list[np.ndarray], onsets: list[np.ndarray], audio_frames: list[int], ref, args):
    """BC of clip i's motion against onsets[i] (audio of audio_frames[i] frames) -> (weighted mean, per clip)."""
    vals, weights = [], []
    for J, on, af in zip(joints, onsets, audio_frames):
        T = min(len(J), af)
        try:
            bc, d = M.beat_constancy(J[:T], onset_times=on, fps=FPS, speed_ref=ref, rule=args.bc_rule,
                                     mode=args.bc_mode, return_details=True)
        except ValueError:  # too short for the trim
            vals.append(float("nan"))
            weights.append(0)
            continue
        vals.append(bc)
        weights.append(d["weight"])
    ok = [i for i, w in enumerate(weights) if w > 0]
    return M.weighted_mean([vals[i] for i in ok], [weights[i] for i in ok]), vals


def _motion_block(name, motions, joints, real, onsets, audio_frames, perm, ref, feats, real_feats,
                  train_feats, args, face_model, realisation_joints=None) -> dict:
    n = len(motions)
    bc, bc_clips = _bc_set(joints, onsets, audio_frames, ref, args)
    out = {"clips": n, "frames": int(sum(len(m["poses"]) for m in motions)), "bc": bc}
    if n >= 2:
        bcm, bcm_clips = _bc_set(joints, [onsets[p] for p in perm], [audio_frames[p] for p in perm], ref, args)
        pairs = [(a, b) for a, b in zip(bc_clips, bcm_clips) if not (math.isnan(a) or math.isnan(b))]
        out.update(bc_mismatched_audio=bcm, bc_gap=bc - bcm,
                   bc_matched_wins=float(np.mean([a > b for a, b in pairs])) if pairs else float("nan"))
        # motion swap: clip i's OWN audio scored against the motion of clip perm[i], over the frames both have,
        # so the onset track is the same on both sides of the gap (livegesture.eval.generalise, "motion swap")
        bcs, bcs_clips = _bc_set([joints[p] for p in perm], onsets, audio_frames, ref, args)
        own, own_clips = _bc_set([J[:len(joints[p])] for J, p in zip(joints, perm)], onsets, audio_frames, ref,
                                 args)
        pairs_s = [(a, b) for a, b in zip(own_clips, bcs_clips) if not (math.isnan(a) or math.isnan(b))]
        out.update(bc_mismatched_motion=bcs, bc_gap_motion_swap=own - bcs,
                   bc_motion_swap_wins=float(np.mean([a > b for a, b in pairs_s])) if pairs_s else float("nan"))
    else:
        bcm_clips = bcs_clips = [float("nan")] * n
        out.update(bc_mismatched_audio=None, bc_gap=None, bc_matched_wins=None, bc_mismatched_motion=None,
                   bc_gap_motion_swap=None, bc_motion_swap_wins=None)
    if realisation_joints is not None:
        eq2 = [M.l1_diversity_realisations(r) for r in realisation_joints if len(r) >= 2]
        out["l1div_realisations"] = float(np.mean(eq2)) if eq2 else None
    else:
        out["l1div_realisations"] = None
    out["l1div_beat2"] = M.l1_diversity_beat2(joints)
    out["l1div_across_clips"] = M.l1_diversity_across_clips(joints) if n >= 2 else None
    cat = np.concatenate([f for f in feats if len(f)]) if any(len(f) for f in feats) else np.zeros((0, 1))
    rcat = np.concatenate([f for f in real_feats if len(f)]) if any(len(f) for f in real_feats) else cat
    out["fgd_windows"] = int(len(cat))
    out["fgd"] = M.frechet_distance(cat, rcat if name == "generated" else train_feats) if len(cat) >= 2 else None
    out["fgd_vs_train"] = M.frechet_distance(cat, train_feats) if len(cat) >= 2 and len(train_feats) >= 2 else None
    faces = []
    fw = []
    vert = []
    for m, r in zip(motions, real):
        if m.get("expressions") is None or r.get("expressions") is None:
            continue
        f = M.face_param_mse(r["poses"], r["expressions"], m["poses"], m["expressions"])
        faces.append(f)
        fw.append(f["frames"])
        if face_model is not None:
            vert.append(M.face_vertex_mse(r, m, face_model))
    if faces:
        out["face"] = {k: M.weighted_mean([f[k] for f in faces], fw) for k in ("jaw", "expressions", "face")}
    else:
        out["face"] = None
    out["face_vertex_mse"] = M.weighted_mean(vert, fw) if vert else None
    out["per_clip"] = [{"bc": a, "bc_mismatched_audio": b, "bc_mismatched_motion": c}
                       for a, b, c in zip(bc_clips, bcm_clips, bcs_clips)]
    return out


# ----------------------------------------------------------------------------- report

def _fmt(v, nd=4):
    if v is None:
        return "-"
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    return f"{v:.{nd}f}"


def _table(report: dict) -> str:
    rows = [("BC (matched audio)", "bc"), ("BC (mismatched audio)", "bc_mismatched_audio"),
            ("BC gap (matched - mismatched)", "bc_gap"), ("clips with matched > mismatched", "bc_matched_wins"),
            ("BC, own audio vs another clip's motion", "bc_mismatched_motion"),
            ("BC gap, motion swap", "bc_gap_motion_swap"), ("clips winning the motion swap", "bc_motion_swap_wins"),
            ("L1 div, paper eq. 2 (realisations)", "l1div_realisations"), ("L1 div, BEAT2 L1div", "l1div_beat2"),
            ("L1 div, across clips", "l1div_across_clips"), ("FGD (gen vs real split | real split vs train)", "fgd"),
            ("FGD vs train split", "fgd_vs_train"), ("face MSE jaw+expr", ("face", "face")),
            ("face MSE jaw", ("face", "jaw")), ("face MSE expressions", ("face", "expressions")),
            ("face vertex MSE", "face_vertex_mse")]
    cols = [c for c in ("generated", "ground_truth") if report.get(c)]
    w0 = max(len(r[0]) for r in rows) + 2
    lines = [f"{'metric':<{w0}}" + "".join(f"{c:>16}" for c in cols)]
    for label, key in rows:
        vals = []
        for c in cols:
            b = report[c]
            v = (b.get(key[0]) or {}).get(key[1]) if isinstance(key, tuple) else b.get(key)
            vals.append(_fmt(v))
        lines.append(f"{label:<{w0}}" + "".join(f"{v:>16}" for v in vals))
    return "\n".join(lines)


# long: the evaluation in order (arguments, real data, FGD statistics, reference, generated motion, the report)
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.eval", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="BEAT2-layout corpus directory")
    ap.add_argument("--split", default="test", help="split to evaluate (default test)")
    ap.add_argument("--generated", action="append", default=[],
                    help="folder of generated {id}.npz; repeat for several realisations of the same audio")
    ap.add_argument("--checkpoint", help="generate with this model checkpoint instead of --generated")
    ap.add_argument("--n-realisations", type=int, default=2, help="seeds per clip with --checkpoint (default 2)")
    ap.add_argument("--seed", type=int, default=0, help="first seed with --checkpoint")
    ap.add_argument("--guidance", type=float, default=None, help="CFG scale with --checkpoint (model default)")
    ap.add_argument("--save-generated", help="with --checkpoint: also write the generated npz files here")
    ap.add_argument("--device", default="cpu", help="with --checkpoint: run the model here (cpu, cuda)")
    ap.add_argument("--fgd-encoder", help="FGD encoder file (trained on the train split if missing; default "
                                          "DATA/fgd_encoder.pt)")
    ap.add_argument("--fgd-steps", type=int, default=1000, help="training steps if the encoder is trained")
    ap.add_argument("--max-clips", type=int, default=None, help="evaluate only the first N clips (sorted ids)")
    ap.add_argument("--bc-rule", choices=("emage", "prominence"), default=M.BC_RULE,
                    help="motion-beat filter (livegesture.eval.metrics): emage (default, EMAGE's rule, as the "
                         "papers' BC) or prominence (the project's rule; the figures before 2026-11-27 used it)")
    ap.add_argument("--bc-mode", choices=("per_joint", "mean_speed"), default="per_joint")
    ap.add_argument("--face-model", help="module:function computing SMPL-X vertices (user-supplied model) for "
                                         "the face vertex MSE")
    ap.add_argument("--out", help="write the report as JSON here")
    ap.add_argument("--no-per-clip", action="store_true", help="leave per-clip values out of the JSON")
    args = ap.parse_args(argv)
    t_start = time.time()

    data = Path(args.data)
    ids = corpus.read_split(data, args.split)
    if args.max_clips:
        ids = ids[: args.max_clips]
    if not ids:
        raise SystemExit(f"no clip of split {args.split!r} in {data}/train_test_split.csv")
    train_ids = corpus.read_split(data, "train")
    face_model = _load_face_model(args.face_model)

    # --- real motion and audio of the split
    real = [corpus.load_motion(corpus.motion_path(data, c)) for c in ids]
    audio = {}
    for c in ids:
        x, _ = corpus.load_audio(corpus.audio_path(data, c), target_sr=SAMPLE_RATE)
        audio[c] = x
    onsets = [M.detect_onsets(audio[c], SAMPLE_RATE) for c in ids]
    audio_frames = [int(len(audio[c]) * FPS // SAMPLE_RATE) for c in ids]
    real_joints = [M.joints_from_motion(m["poses"], m["trans"]) for m in real]
    n = len(ids)
    perm = [(i + 1) % n for i in range(n)]
    _log(f"{n} clips of split {args.split} ({sum(len(m['poses']) for m in real) / FPS / 60:.1f} min)")

    # --- FGD encoder and train-split statistics (BC reference speed, FGD reference features)
    from .fgd_encoder import load_fgd_encoder, train_fgd_encoder
    enc_path = Path(args.fgd_encoder) if args.fgd_encoder else data / "fgd_encoder.pt"
    if enc_path.exists():
        enc = load_fgd_encoder(enc_path)
    else:
        _log(f"training the FGD encoder on {data} (train split) -> {enc_path}")
        enc = train_fgd_encoder(data, enc_path, steps=args.fgd_steps, seed=0, log=_log)
    train_feats, speed_sum, speed_n = [], 0.0, 0
    for c in train_ids:
        m = corpus.load_motion(corpus.motion_path(data, c))
        J = M.joints_from_motion(m["poses"], m["trans"])
        s = M.joint_speed(J, FPS)
        speed_sum, speed_n = speed_sum + s.sum(0), speed_n + len(s)
        train_feats.append(enc.clip_features(m["poses"]))
    train_feats = np.concatenate(train_feats) if train_feats else np.zeros((0, enc.feature_dim))
    speed_ref = speed_sum / speed_n if speed_n else M.mean_joint_speed(real_joints, FPS)
    real_feats = [enc.clip_features(m["poses"]) for m in real]

    settings = {"fps": FPS, "sample_rate": SAMPLE_RATE, "bc_sigma_s": M.SIGMA_S, "bc_trim_s": M.TRIM_S,
                "bc_order": M.BEAT_ORDER, "bc_threshold": M.BEAT_THRESHOLD, "bc_rule": args.bc_rule,
                "bc_mode": args.bc_mode, "bc_speed_ref": "train split" if speed_n else "evaluated split",
                "bc_mismatch": "clip i gets the audio of clip (i + 1) mod n (sorted ids)",
                "bc_motion_swap": "clip i's own audio against the motion of clip (i + 1) mod n, over the frames "
                                  "both have (the onset track is the same on both sides of the gap)",
                "onsets": "spectral flux on log-mel STFT (10 ms hop, 32 ms window), librosa-style peak picking",
                "fgd_encoder": str(enc_path), "fgd_encoder_provenance": enc.provenance,
                "skeleton": "livegesture.skeleton (project-defined), global translation removed"}
    report = {"data": str(data), "split": args.split, "ids": ids, "settings": settings}

    # --- reference: the corpus's own motion
    report["ground_truth"] = _motion_block("ground_truth", real, real_joints, real, onsets,
                                           audio_frames, perm, speed_ref, real_feats, real_feats, train_feats,
                                           args, face_model)

    # --- generated motion
    gen_reals = None
    if args.checkpoint:
        if args.generated:
            raise SystemExit("give --generated or --checkpoint, not both")
        gen_reals = _generate(args.checkpoint, ids, audio, max(1, args.n_realisations), args.seed, args.guidance,
                              args.save_generated, device=args.device)
        gids = ids
        report["generated_source"] = {"checkpoint": args.checkpoint, "seeds": list(
            range(args.seed, args.seed + max(1, args.n_realisations))), "guidance": args.guidance}
    elif args.generated:
        gids, gen_reals, missing = _load_generated(args.generated, ids)
        report["generated_source"] = {"folders": args.generated, "missing_ids": missing}
        if missing:
            _log(f"warning: {len(missing)} clip(s) of the split missing from --generated: {missing[:5]}...")
        if not gids:
            raise SystemExit("no generated clip matches the split's ids")
    if gen_reals is not None:
        idx = [ids.index(c) for c in gids]
        g0 = [r[0] for r in gen_reals]
        gj = [M.joints_from_motion(m["poses"], m["trans"]) for m in g0]
        rj = [[M.joints_from_motion(m["poses"], m["trans"]) for m in r] for r in gen_reals]
        gfeats = [enc.clip_features(m["poses"]) for m in g0]
        ng = len(gids)
        report["generated"] = _motion_block(
            "generated", g0, gj, [real[i] for i in idx], [onsets[i] for i in idx],
            [audio_frames[i] for i in idx], [(k + 1) % ng for k in range(ng)], speed_ref, gfeats,
            [real_feats[i] for i in idx], train_feats, args, face_model,
            realisation_joints=rj if any(len(r) >= 2 for r in rj) else None)
        report["generated"]["ids"] = gids
        g = report["generated"]
        report["checks"] = {"generated_follows_audio": (g["bc_gap"] is not None and g["bc_gap"] > 0),
                            "ground_truth_follows_audio": (report["ground_truth"]["bc_gap"] is not None
                                                           and report["ground_truth"]["bc_gap"] > 0)}
    report["seconds"] = round(time.time() - t_start, 1)

    if args.no_per_clip:
        for k in ("ground_truth", "generated"):
            if k in report:
                report[k].pop("per_clip", None)
    else:
        for k in ("ground_truth", "generated"):
            if k in report:
                for cid, row in zip(report[k].get("ids", ids), report[k]["per_clip"]):
                    row["id"] = cid
    print(_table(report))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(jsonable(report), f, indent=2, allow_nan=False)
        _log(f"report written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
