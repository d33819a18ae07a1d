"""Tables and the pre-registered verdict of README.md: the confirmation's tables.py
(../realspeech-confirm-2026-11-25/tables.py, the same rules 1-4 and commands) run on this folder's reports
(real/, synth/). Run with $LIVEGESTURE_PY from the repository root, e.g.

  python docs/eval/realspeech-scratch-2026-11-25/tables.py verdict shipped scratch
"""
import os
import runpy

HERE = os.path.dirname(os.path.abspath(__file__))
os.environ["TABLES_DIR"] = HERE
runpy.run_path(os.path.join(HERE, "..", "realspeech-confirm-2026-11-25", "tables.py"), run_name="__main__")
