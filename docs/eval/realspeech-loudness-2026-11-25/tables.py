"""Tables and the pre-registered verdict of README.md: the confirmation's tables.py
(../realspeech-confirm-2026-11-25/tables.py, the same rules 1-4) on this folder's reports (real/, synth/), with
the real-speech seeds 19-24 (REAL_SEED0=19). Run with $LIVEGESTURE_PY from the repository root, e.g.

  python docs/eval/realspeech-loudness-2026-11-25/tables.py verdict shipped loud
"""
import os
import runpy

HERE = os.path.dirname(os.path.abspath(__file__))
os.environ["TABLES_DIR"] = HERE
os.environ.setdefault("REAL_SEED0", "19")   # the next sitting: REAL_SEED0=25
runpy.run_path(os.path.join(HERE, "..", "realspeech-confirm-2026-11-25", "tables.py"), run_name="__main__")
