"""Builds the face mesh asset (``runtime/assets/face/ict_face.bin``) from ICT-FaceKit (USC ICT, MIT licence;
github.com/ICT-VGL/ICT-FaceKit, folder ``FaceXModel/``): the face region of the generic neutral mesh (its
first 9,409 vertices, the faces that use only them, triangulated) and one morph target per ARKit name, the
ICT shape of that name minus the neutral, stored sparse (only vertices that move more than 0.01 mm) in
float16 metres. ARKit names with one ICT shape per side and one ARKit shape (``browInnerUp``, ``cheekPuff``)
sum the two sides; ``tongueOut`` has no ICT shape (the face region has no tongue) and is an empty target.

  python -m livegesture.face.mesh --ict-git-dir /work/.mirror/ICT-VGL+ICT-FaceKit/repo --out runtime/assets/face

Format of ``ict_face.bin`` (little-endian): magic ``LGFACE01``; u32 n_vertices, u32 n_triangles,
u32 n_targets; positions f32[n_vertices][3] (metres, y up, the head's local frame); triangles
u16[n_triangles][3]; then per target (ARKit order): u32 count, u16 vertex[count], f16 delta[count][3].
"""
from __future__ import annotations

import argparse
import struct
import subprocess
from pathlib import Path

import numpy as np

from .names import ARKIT_NAMES

FACE_VERTICES = 9409
SCALE = 0.01            # ICT-FaceKit units are centimetres
THRESHOLD = 1e-5        # metres: smaller deltas are dropped
MAGIC = b"LGFACE01"


def ict_files(name: str) -> list[str]:
    """ARKit name -> the ICT-FaceKit shape files it sums."""
    if name == "tongueOut":
        return []
    if name in ("jawLeft", "jawRight", "mouthLeft", "mouthRight"):   # one shape each, named as ARKit names it
        return [name]
    for side, suf in (("Left", "_L"), ("Right", "_R")):
        if name.endswith(side):
            return [name[: -len(side)] + suf]
    if name in ("browInnerUp", "cheekPuff"):
        return [name + "_L", name + "_R"]
    return [name]


def _show(git_dir: Path, rel: str) -> str:
    return subprocess.run(["git", "--git-dir", str(git_dir), "show", f"HEAD:{rel}"], check=True,
                          capture_output=True).stdout.decode()


def _vertices(text: str, n: int) -> np.ndarray:
    out = []
    for line in text.splitlines():
        if line.startswith("v "):
            out.append([float(x) for x in line.split()[1:4]])
            if len(out) == n:
                break
    return np.asarray(out, dtype=np.float64)


def build(git_dir: Path, out: Path) -> dict:
    neutral_txt = _show(git_dir, "FaceXModel/generic_neutral_mesh.obj")
    v0 = _vertices(neutral_txt, FACE_VERTICES)
    tris = []
    for line in neutral_txt.splitlines():
        if line.startswith("f "):
            idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
            if max(idx) < FACE_VERTICES:
                for k in range(1, len(idx) - 1):
                    tris.append((idx[0], idx[k], idx[k + 1]))
    tris = np.asarray(tris, dtype=np.uint16)
    centre = v0.mean(0)
    pos = ((v0 - centre) * SCALE).astype(np.float32)
    targets = []
    for name in ARKIT_NAMES:
        d = np.zeros_like(v0)
        for f in ict_files(name):
            d += _vertices(_show(git_dir, f"FaceXModel/{f}.obj"), FACE_VERTICES) - v0
        d *= SCALE
        keep = np.nonzero(np.abs(d).max(1) > THRESHOLD)[0].astype(np.uint16)
        targets.append((keep, d[keep].astype(np.float16)))
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "ict_face.bin", "wb") as f:
        f.write(MAGIC)
        f.write(struct.pack("<III", len(pos), len(tris), len(targets)))
        f.write(pos.astype("<f4").tobytes())
        f.write(tris.astype("<u2").tobytes())
        for keep, d in targets:
            f.write(struct.pack("<I", len(keep)))
            f.write(keep.astype("<u2").tobytes())
            f.write(d.astype("<f2").tobytes())
    return {"vertices": len(pos), "triangles": len(tris), "bytes": (out / "ict_face.bin").stat().st_size,
            "moving": {n: int(len(k)) for n, (k, _) in zip(ARKIT_NAMES, targets)}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.face.mesh")
    ap.add_argument("--ict-git-dir", required=True, help="a git directory of github.com/ICT-VGL/ICT-FaceKit")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    info = build(Path(a.ict_git_dir), Path(a.out))
    print({k: v for k, v in info.items() if k != "moving"})
    print("empty targets:", [n for n, c in info["moving"].items() if c == 0])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
