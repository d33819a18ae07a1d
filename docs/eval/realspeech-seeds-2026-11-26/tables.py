"""Tables and the pre-registered verdict of README.md: the confirmation's tables.py
(../realspeech-confirm-2026-11-25/tables.py, rules 1-4) on this folder's reports (real/, synth/). Run with
$LIVEGESTURE_PY from the repository root:

  python docs/eval/realspeech-seeds-2026-11-26/tables.py select            stage 1: the selection (seeds 25-30)
  REAL_SEED0=31 python docs/eval/realspeech-seeds-2026-11-26/tables.py verdict shipped NAME   stage 2 (seeds 31-36)
  python docs/eval/realspeech-seeds-2026-11-26/tables.py real|synth|perclip ...   as the confirmation's tables.py
"""
import os
import runpy
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
os.environ["TABLES_DIR"] = HERE
os.environ.setdefault("REAL_SEED0", "25")
CONFIRM = os.path.join(HERE, "..", "realspeech-confirm-2026-11-25", "tables.py")
CANDIDATES = ("flux1", "flux2", "sylb1", "sylb2")
# the second round (README.md "Round 2"): tables.py select2
if len(sys.argv) >= 2 and sys.argv[1] == "select2":
    CANDIDATES, sys.argv[1] = ("sylb3", "sylb4"), "select"

if len(sys.argv) >= 2 and sys.argv[1] == "select":
    T = runpy.run_path(CONFIRM, run_name="tables")
    rows = []
    for n in CANDIDATES:
        g = list(T["pooled"](n, "audio_swap", "speed_env")[0].values())
        speed = sum(g) / len(g)
        if not os.path.exists(os.path.join(HERE, "synth", f"{n}_s7.json")):
            print(f"## {n}\nno in-distribution reports (its export failed: README.md): not eligible\n")
            rows.append((n, speed, False))
            continue
        print(f"## {n}")
        ok = T["verdict"]("shipped", n)   # rules 1-4
        print()
        eligible = ok[1] and ok[3]
        rows.append((n, speed, eligible))
    ok = [r for r in rows if r[2]]
    for n, s, e in rows:
        print(f"{n}: speed {s:+.3f} (seeds 25-30), eligible (rules 2 and 4 pass): {e}")
    if ok:
        print(f"SELECTED: {max(ok, key=lambda r: r[1])[0]}")
    else:
        print("SELECTED: none (no candidate passes rules 2 and 4): FAIL, nothing ships")
else:
    runpy.run_path(CONFIRM, run_name="__main__")
