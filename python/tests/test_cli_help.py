"""Every command a user types (`python -m livegesture.X`, `python export/X.py`, `python bench/X.py`) parses its
arguments: `--help` exits 0 and prints a usage line. Function-level tests call the code behind these commands
directly, so a broken parser (a duplicated option, a bad default) would otherwise go unnoticed."""
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MODULES = ["livegesture.train", "livegesture.eval", "livegesture.eval.generalise", "livegesture.data.synth",
           "livegesture.bench", "livegesture.bench_train", "livegesture.interpolate",
           "livegesture.face.train", "livegesture.face.evaluate", "livegesture.face.export", "livegesture.face.mesh"]
SCRIPTS = sorted(str(p.relative_to(ROOT)) for d in ("export", "bench") for p in (ROOT / d).glob("*.py")
                 if "argparse" in p.read_text())


def _help(run, target, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [target, "--help"])
    with pytest.raises(SystemExit) as e:
        run()
    assert e.value.code in (0, None), f"{target} --help exited with {e.value.code}"
    assert "usage:" in capsys.readouterr().out.lower(), f"{target} --help printed no usage line"


@pytest.mark.parametrize("module", MODULES)
def test_module_help(module, monkeypatch, capsys):
    _help(lambda: runpy.run_module(module, run_name="__main__", alter_sys=True), module, monkeypatch, capsys)


@pytest.mark.parametrize("script", SCRIPTS)
def test_script_help(script, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(ROOT / Path(script).parent))
    if script.startswith("export/"):   # the package's modules run as the package module (their file-run shim);
        # one imported by an earlier test would be run a second time beside itself (runpy warns)
        monkeypatch.delitem(sys.modules, "export." + Path(script).stem, raising=False)
    _help(lambda: runpy.run_path(str(ROOT / script), run_name="__main__"), script, monkeypatch, capsys)


def test_every_entry_point_is_listed():
    # a new `python -m` entry point must be added above
    found = {".".join(p.relative_to(ROOT / "python").with_suffix("").parts).removesuffix(".__main__")
             for p in (ROOT / "python" / "livegesture").rglob("*.py")
             if p.name == "__main__.py" or 'if __name__ == "__main__"' in p.read_text()}
    assert set(found) <= set(MODULES), f"entry points without a --help test: {sorted(set(found) - set(MODULES))}"
