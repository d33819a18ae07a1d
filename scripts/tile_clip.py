"""Writes a bundle's reference clip tiled to SECONDS as one WAV (same rate, width and channels):

    python scripts/tile_clip.py BUNDLE SECONDS OUT.wav

The long input of the real-time-factor benchmarks (scripts/bench_rtf.sh, scripts/bench_diffsheg_ab.sh)."""
import json
import sys
import wave
from pathlib import Path

import numpy as np

bundle, seconds, out = Path(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
manifest = json.loads((bundle / "manifest.json").read_text())
clip = bundle / manifest.get("reference", {}).get("clip", "reference/clip.wav")
with wave.open(str(clip)) as w:
    rate, width, ch = w.getframerate(), w.getsampwidth(), w.getnchannels()
    data = np.frombuffer(w.readframes(w.getnframes()), dtype=np.int16 if width == 2 else np.int32)
n = int(seconds * rate) * ch
tiled = np.tile(data, -(-n // len(data)))[:n]
with wave.open(out, "wb") as w:
    w.setnchannels(ch); w.setsampwidth(width); w.setframerate(rate); w.writeframes(tiled.tobytes())
print(f"[tile_clip] {clip} tiled to {seconds:.0f} s ({rate} Hz)", file=sys.stderr)
