"""Weight-space interpolation of a fine-tuned checkpoint with the checkpoint it was fine-tuned from (WiSE-FT,
Wortsman et al., "Robust fine-tuning of zero-shot models", CVPR 2022): every weight becomes
``(1 - alpha) * base + alpha * tuned``. alpha = 0 gives the base model, 1 the fine-tuned one; values between
trade what the fine-tuning gained against what it lost, without another training run. With several
``--tuned`` checkpoints (fine-tuned from the same base) their uniform average is taken first (a "uniform
model soup", Wortsman et al., ICML 2022); alpha = 1 then gives the soup itself.

Only meaningful for a pair made by ``train --init-from BASE``: the two must be LiveGesture checkpoints of the
same model config, with the same motion tokenizer (svq1/svq2 weights) and the same normalisation statistics
(the fine-tuning keeps both); anything else is refused, naming the file and the first differing tensors.

    python -m livegesture.interpolate --base models/default.train/checkpoint.pt --tuned runs/ft/final.pt \
        --alpha 0.5 --out runs/ft/wise_0.5.pt
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from . import checkpoint as ckpt
from . import families


def interpolate(base_path, tuned_path, alpha: float):
    """The interpolated model (LiveGesture, eval mode) and its provenance dict. ``tuned_path``: one checkpoint,
    or a list of them (averaged uniformly before the interpolation)."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"--alpha {alpha}: must lie in [0, 1]")
    paths = [tuned_path] if isinstance(tuned_path, (str, Path)) else list(tuned_path)
    if not paths:
        raise ValueError("no fine-tuned checkpoint given")
    base = ckpt.load_payload(base_path)
    if families.of_payload(base) is not families.LIVEGESTURE:
        raise ValueError(f"checkpoint {base_path}: not a LiveGesture checkpoint")
    tuned, data = None, []
    for i, path in enumerate(paths):
        t = _checked_pair(base, base_path, ckpt.load_payload(path), path)
        data.append(t.get("provenance", {}).get("training_data"))
        if tuned is None:
            tuned = {**t, "state_dict": {k: v.clone() for k, v in t["state_dict"].items()}}
        else:
            for k, v in tuned["state_dict"].items():
                if v.is_floating_point():
                    v.mul_(i / (i + 1)).add_(t["state_dict"][k], alpha=1 / (i + 1))     # running mean
    sb, st = base["state_dict"], tuned["state_dict"]
    out = {}
    for k, vb in sb.items():
        out[k] = torch.lerp(vb, st[k], alpha) if vb.is_floating_point() else vb.clone()
    model = ckpt.load(base_path)
    model.load_state_dict(out, strict=False)
    prov = {**tuned.get("provenance", {}),
            "interpolation": {"method": "WiSE-FT (1 - alpha) * base + alpha * tuned"
                                        + ("; tuned = uniform average of the tuned checkpoints" if len(paths) > 1 else ""),
                              "alpha": alpha, "base": str(base_path),
                              "tuned": [str(p) for p in paths] if len(paths) > 1 else str(paths[0]),
                              "tuned_training_data": data if len(paths) > 1 else data[0]}}
    return model.eval(), prov


def _checked_pair(base, base_path, tuned, tuned_path):
    """``tuned`` unchanged, after checking that it was fine-tuned from ``base`` (ValueError naming the file)."""
    if families.of_payload(tuned) is not families.LIVEGESTURE:
        raise ValueError(f"checkpoint {tuned_path}: not a LiveGesture checkpoint")
    if base["config"] != tuned["config"]:
        diff = sorted(k for k in base["config"].keys() | tuned["config"].keys()
                      if base["config"].get(k) != tuned["config"].get(k))
        raise ValueError(f"checkpoint {tuned_path}: model config differs from {base_path} ({diff})")
    sb, st = base["state_dict"], tuned["state_dict"]
    if set(sb) != set(st):
        raise ValueError(f"checkpoint {tuned_path}: weight names differ from {base_path} "
                         f"({sorted(set(sb) ^ set(st))[:5]})")
    # the fine-tuning keeps the tokenizer and the statistics; a pair that differs there was not made by it
    kept = [k for k in sb if k.startswith("svq.") or "norm_" in k or k.endswith(("_mean", "_std"))]
    changed = [k for k in kept if not torch.equal(sb[k], st[k])]
    if changed:
        raise ValueError(f"checkpoint {tuned_path}: its motion tokenizer or statistics differ from {base_path} "
                         f"({changed[:5]}); interpolation needs a pair made by train --init-from")
    for k, vb in sb.items():
        vt = st[k]
        if vb.shape != vt.shape:
            raise ValueError(f"checkpoint {tuned_path}: {k} has shape {tuple(vt.shape)}, {base_path} {tuple(vb.shape)}")
        if not vb.is_floating_point() and not torch.equal(vb, vt):
            raise ValueError(f"checkpoint {tuned_path}: integer tensor {k} differs from {base_path}")
    return tuned


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the checkpoint that was fine-tuned (train --init-from)")
    ap.add_argument("--tuned", required=True, action="append",
                    help="a checkpoint fine-tuned from --base (repeatable: the uniform average of all is used)")
    ap.add_argument("--alpha", type=float, required=True, help="weight of the fine-tuned model, in [0, 1]")
    ap.add_argument("--out", required=True, help="checkpoint to write")
    args = ap.parse_args(argv)
    try:
        model, prov = interpolate(args.base, args.tuned, args.alpha)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(str(e)) from e
    ckpt.save(model, Path(args.out), provenance=prov)
    print(f"{args.out}: {1 - args.alpha:g} x {args.base} + {args.alpha:g} x mean({', '.join(args.tuned)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
