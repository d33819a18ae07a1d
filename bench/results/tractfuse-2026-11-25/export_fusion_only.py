# export only fusion.onnx of the default checkpoint with the current code into a copy of models/default
import sys, json, shutil, hashlib, time
from pathlib import Path
sys.path.insert(0, "export")
import torch
torch.set_num_threads(1)
import export as ex
out = Path(sys.argv[1])
if out.exists(): shutil.rmtree(out)
shutil.copytree("models/default", out)
model = ex.ckpt.load("models/default.train/checkpoint.pt") if hasattr(ex, "ckpt") else None
model.eval()
ex.export_graph(model, "fusion", out / "fusion.onnx")
m = json.load(open(out / "manifest.json"))
p = out / "fusion.onnx"
m["files"]["fusion.onnx"] = {"sha256": ex.sha256(p), "bytes": p.stat().st_size}
ex.write_manifest(out, m)
print("wrote", out)
