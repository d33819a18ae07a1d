"""scripts/check_docs.py (the test command's docs check) fails on a dead relative link, a missing heading anchor
and a citation of the outside specification, and passes on good Markdown."""
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("check_docs", ROOT / "scripts" / "check_docs.py")
check_docs = importlib.util.module_from_spec(spec)
spec.loader.exec_module(check_docs)


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_good_markdown_passes(tmp_path):
    write(tmp_path, "other.md", "# Other page\n\n## Forms and precision\n\n## Graphs\n\n## Graphs\n")
    p = write(tmp_path, "page.md", "# Page `x`\n\nSee [other](other.md#forms-and-precision), [again](other.md#graphs-1),\n"
              "[here](#page-x), [web](https://example.org/x.md), `[code](missing.md)`.\n\n```\n[block](missing.md)\n```\n")
    assert check_docs.main([str(p)]) == 0


def test_dead_link_fails(tmp_path, capsys):
    p = write(tmp_path, "page.md", "# Page\n\nSee [gone](gone.md).\n")
    assert check_docs.main([str(p)]) == 1
    assert "gone.md" in capsys.readouterr().err


def test_missing_anchor_fails(tmp_path, capsys):
    write(tmp_path, "other.md", "# Other page\n")
    p = write(tmp_path, "page.md", "# Page\n\nSee [other](other.md#no-such-heading) and [self](#nope).\n")
    assert check_docs.main([str(p)]) == 1
    err = capsys.readouterr().err
    assert "#no-such-heading" in err and "#nope" in err


def test_outside_spec_reference_fails(tmp_path, capsys):
    ref = "SPEC" + " 7"  # spelled in two pieces so that this file itself passes the check
    p = write(tmp_path, "code.py", f"# the bound of {ref}\n")
    assert check_docs.main([str(p)]) == 1
    assert ref in capsys.readouterr().err
