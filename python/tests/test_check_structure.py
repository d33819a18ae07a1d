"""scripts/check_structure.py (the test command's layout check) fails on a module cycle in a Rust crate, on a
long function or file without its `long:` reason, and passes on the same trees without them."""
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("check_structure", ROOT / "scripts" / "check_structure.py")
check_structure = importlib.util.module_from_spec(spec)
spec.loader.exec_module(check_structure)


def run(root: Path, known=None) -> int:
    return check_structure.main([str(root)], known_cycles=known or {})


def write(root: Path, rel: str, text: str) -> Path:
    p = root / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding="utf-8")
    return p


def crate(tmp_path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        write(tmp_path, "runtime/src/" + rel, text)
    return tmp_path


def test_a_tree_without_cycles_passes(tmp_path):
    root = crate(tmp_path, {
        "lib.rs": "pub mod a;\npub mod b;\n",
        "a.rs": "use crate::b::B;\n// crate::a::x in a comment is not a use\npub fn f(_: B) {}\n",
        # a child using its parent, the parent its child: containment, not a cycle
        "b/mod.rs": "mod c;\npub struct B;\npub fn g() { c::h() }\n",
        "b/c.rs": "use super::B;\npub fn h() { let _ = \"crate::a::f\"; }\n",
    })
    assert run(root) == 0


def test_a_sibling_cycle_fails(tmp_path, capsys):
    root = crate(tmp_path, {
        "lib.rs": "pub mod a;\npub mod b;\n",
        "a.rs": "use crate::b::B;\npub struct A;\npub fn f(_: B) {}\n",
        "b/mod.rs": "mod c;\npub struct B;\n",
        # deep in b's subtree, through a brace group: b -> a
        "b/c.rs": "use crate::{a::A, b::B};\npub fn h(_: A, _: B) {}\n",
    })
    assert run(root) == 1
    err = capsys.readouterr().err
    assert "module cycle under the crate root: a -> b -> a" in err
    assert "b::c uses a" in err


def test_a_cycle_through_super_and_inline_modules_fails(tmp_path, capsys):
    root = crate(tmp_path, {
        "lib.rs": "pub mod m;\n",
        "m/mod.rs": "mod x;\nmod y;\n",
        "m/x.rs": "pub fn f() { super::y::g() }\n",
        "m/y.rs": "pub fn g() {}\nmod inner {\n    fn k() { super::super::x::f() }\n}\n",
    })
    assert run(root) == 1
    assert "module cycle under m: x -> y -> x" in capsys.readouterr().err


def test_a_long_function_needs_its_reason(tmp_path, capsys):
    body = "    let _ = 1;\n" * (check_structure.FN_LINES + 5)
    root = crate(tmp_path, {"lib.rs": "pub fn short() {}\n\npub fn big() {\n" + body + "}\n"})
    assert run(root) == 1
    assert "fn big is" in capsys.readouterr().err
    write(root, "runtime/src/lib.rs",
          "pub fn short() {}\n\n// long: one table, row by row\npub fn big() {\n" + body + "}\n")
    assert run(root) == 0


def test_a_long_file_needs_its_reason(tmp_path, capsys):
    text = "pub fn f() {}\n" * (check_structure.FILE_LINES + 1)
    root = crate(tmp_path, {"lib.rs": text})
    assert run(root) == 1
    assert "lines (over" in capsys.readouterr().err
    write(root, "runtime/src/lib.rs", "//! The crate.\n// long: every function of the format in one place\n" + text)
    assert run(root) == 0


def test_a_long_python_function_needs_its_reason(tmp_path, capsys):
    body = "    x = 1\n" * (check_structure.FN_LINES + 2)
    write(tmp_path, "export/big.py", "def big():\n" + body)
    assert run(tmp_path) == 1
    assert "def big is" in capsys.readouterr().err
    write(tmp_path, "export/big.py", "# long: the steps of one export, in order\ndef big():\n" + body)
    assert run(tmp_path) == 0


def test_use_trees_are_expanded():
    assert check_structure.expand_use("crate::{a::{b, c as d}, e::*, self}") == [
        "crate::a::b", "crate::a::c", "crate::e", "crate"]


def test_a_known_cycle_passes_only_while_it_is_that_cycle(tmp_path, capsys):
    files = {
        "lib.rs": "pub mod a;\npub mod b;\npub mod c;\n",
        "a.rs": "use crate::b::B;\npub struct A;\n",
        "b.rs": "use crate::a::A;\npub struct B;\n",
        "c.rs": "pub struct C;\n",
    }
    root = crate(tmp_path, files)
    known = {("runtime/src/lib.rs", ()): {"a", "b"}}
    assert run(root, known) == 0
    # a third module joins the cycle: it fails
    write(root, "runtime/src/c.rs", "use crate::a::A;\npub struct C;\n")
    write(root, "runtime/src/a.rs", "use crate::b::B;\nuse crate::c::C;\npub struct A;\n")
    assert run(root, known) == 1
    assert "module cycle under the crate root" in capsys.readouterr().err
    # the cycle is gone: the entry must go too
    write(root, "runtime/src/a.rs", "pub struct A;\n")
    assert run(root, known) == 1
    assert "no longer the cycle there" in capsys.readouterr().err
