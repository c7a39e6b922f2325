"""scripts/doc_tests.py decides whether the suite runs `cargo test --doc`: it must find every
block rustdoc would run as a test (rustdoc book, "Documentation tests") and no other."""
import importlib.util
import pathlib

REPO = pathlib.Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("doc_tests", REPO / "scripts" / "doc_tests.py")
doc_tests = importlib.util.module_from_spec(spec)
spec.loader.exec_module(doc_tests)


def scan(tmp_path, text):
    src = tmp_path / "crates" / "x" / "src"
    src.mkdir(parents=True)
    (src / "lib.rs").write_text(text, encoding="utf-8")
    return doc_tests.doc_tests(tmp_path)


def test_text_and_toml_blocks_are_not_doc_tests(tmp_path):
    text = "//! ```text\n//! a -> b\n//! ```\n/// ```toml\n/// a = 1\n/// ```\n/// ```ignore\n/// x\n/// ```\n"
    assert scan(tmp_path, text) == []


def test_bare_and_rust_fences_are_doc_tests(tmp_path):
    text = (
        "//! ```\n//! assert!(true);\n//! ```\n"
        "/// ```rust,no_run\n/// f();\n/// ```\n"
        "/// ```should_panic\n/// panic!();\n/// ```\n"
        "// ```\n// a plain comment is not documentation\n// ```\n"
    )
    assert scan(tmp_path, text) == ["crates/x/src/lib.rs:1", "crates/x/src/lib.rs:4", "crates/x/src/lib.rs:7"]

