"""Probe helper: a copy of a bundle with only fusion.onnx re-exported by the current code (and its sha256 in the
manifest), to time a fusion formulation without a whole export. Not a bundle to ship (its references are the
old export's). Run from the repository root:

    $LIVEGESTURE_PY bench/results/tractfuse-2026-11-25/export_fusion_only.py OUT SOURCE_BUNDLE [CONFIG]

without CONFIG the weights are models/default.train/checkpoint.pt; with CONFIG, random weights of that config,
seed 0 (as `export/export.py --config CONFIG --random-seed 0`)."""
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, "export")
import torch  # noqa: E402

torch.set_num_threads(1)
import export as ex  # noqa: E402

out, src = Path(sys.argv[1]), Path(sys.argv[2])
if out.exists():
    shutil.rmtree(out)
shutil.copytree(src, out)
model = ex.ckpt.random_model(sys.argv[3], 0) if len(sys.argv) > 3 else ex.ckpt.load("models/default.train/checkpoint.pt")
model.eval()
ex.export_graph(model, "fusion", out / "fusion.onnx")
m = json.load(open(out / "manifest.json"))
p = out / "fusion.onnx"
m["files"]["fusion.onnx"] = {"sha256": ex.sha256(p), "bytes": p.stat().st_size}
ex.write_manifest(out, m)
print("wrote", out)
