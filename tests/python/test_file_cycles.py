"""scripts/file_cycles.py on small trees written here: the circles it must find (direct,
through a third file, through a `use crate::{...}` group, a `super::` path, a lazy Python
import) and the references it must not count (doc comments, a file's own `mod tests`, an
`if TYPE_CHECKING:` import)."""

import importlib.util
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "file_cycles.py"


def _load():
    spec = importlib.util.spec_from_file_location("file_cycles", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


fc = _load()


def _tree(root: pathlib.Path, files: dict) -> pathlib.Path:
    for name, text in files.items():
        p = root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root


def test_rust_circles_direct_grouped_and_through_a_third_file(tmp_path):
    src = _tree(tmp_path / "src", {
        "lib.rs": "pub mod a;\npub mod b;\npub mod c;\npub mod d;\npub mod e;\n",
        "a.rs": "use crate::{frame::X, b::Y};\n",
        "b.rs": "pub fn f() { super::a::g(); }\n",
        "c.rs": "use crate::d::Z;\n",
        "d.rs": "use crate::e::W;\n",
        "e.rs": "use crate::c;\n",
        "frame.rs": "",
    })
    g = fc.rust_graph(src)
    assert g["a.rs"] == {"b.rs", "frame.rs"}
    assert g["b.rs"] == {"a.rs"}
    assert sorted(fc.cycles(g)) == [["a.rs", "b.rs"], ["c.rs", "d.rs", "e.rs"]]


def test_rust_doc_links_and_own_tests_are_no_edges(tmp_path):
    src = _tree(tmp_path / "src", {
        "lib.rs": "pub mod a;\npub mod b;\n",
        "a.rs": "//! See [`crate::b`].\n/* crate::b::X */\nuse crate::b::X;\n",
        "b.rs": "/// Used by [`crate::a`].\npub struct X;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n",
    })
    g = fc.rust_graph(src)
    assert g["a.rs"] == {"b.rs"} and g["b.rs"] == set()
    assert fc.cycles(g) == []


def test_python_lazy_imports_count_type_checking_ones_do_not(tmp_path):
    pkg = _tree(tmp_path / "pkg", {
        "__init__.py": "",
        "a.py": "from . import b\n",
        "b.py": "def f():\n    from .a import thing\n",
        "c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import T\nfrom pkg.b import f\n",
    })
    g = fc.python_graph(pkg)
    assert g["b.py"] == {"a.py"} and g["c.py"] == {"b.py"}
    assert fc.cycles(g) == [["a.py", "b.py"]]


def test_the_repository_has_no_file_level_circles():
    out = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "circle between" not in out.stdout and "(allowed)" not in out.stdout, out.stdout
