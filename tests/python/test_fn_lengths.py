"""scripts/fn_lengths.py: the counter on synthetic snippets whose lengths are known by
construction (braces in strings, raw strings, chars and comments; lifetimes; test modules,
`macro_rules!` bodies, `tests/` folders left out), then the rule on the workspace: no function
outside tests longer than 100 lines (ARCHITECTURE.md: functions fit on a screen)."""

import importlib.util
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "fn_lengths.py"


def _load():
    spec = importlib.util.spec_from_file_location("fn_lengths", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["fn_lengths"] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


fl = _load()

# Each function's length is the number of lines of its text below, counted by Python's
# splitlines, not by the scanner: `tricky` holds every kind of brace the scanner must ignore.
TRICKY = '''fn tricky<'a>(s: &'a str) -> usize {
    let open = "{ {{ \\" {";
    let raw = r#"}" } "# ;
    let raw2 = r##"}"# }"##;
    let bytes = b"}}";
    let c = '{';
    let e = '\\'';
    let u = '\\u{7d}';
    let b = b'}';
    // } a line comment with a brace
    /* } a block /* nested } */ comment } */
    let label: &'static str = "x";
    'outer: loop { break 'outer; }
    open.len() + raw.len() + raw2.len() + bytes.len() + label.len() + (c as usize)
        + (e as usize) + (u as usize) + (b as usize)
}'''

SHORT = """fn short() -> u8 {
    1
}"""

IMPL = """impl<T: Fn(u8) -> u8> Wrap<T> {
    pub fn call(&self) -> u8 {
        (self.0)(2)
    }
}"""

TESTS = """#[cfg(test)]
mod tests {
    fn inside_tests() {
        let _ = "{";
    }
}"""

MACRO = """macro_rules! make {
    ($n:ident) => {
        fn $n() {}
    };
}"""

TRAIT = """trait T {
    fn declared(&self) -> u8;
    fn defaulted(&self) -> u8 {
        3
    }
}"""


def _lines(text: str) -> int:
    return len(text.splitlines())


def _scan(tmp_path, files: dict) -> dict:
    for name, text in files.items():
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return {f.name: f for f in fl.scan([tmp_path / "src"])}


def test_counts_with_braces_in_strings_chars_comments(tmp_path):
    src = "\n\n".join([SHORT, TRICKY, IMPL, TESTS, MACRO, TRAIT]) + "\n"
    fns = _scan(tmp_path, {"src/lib.rs": src})
    assert fns["short"].length == _lines(SHORT) == 3
    assert fns["short"].line == 1
    assert fns["tricky"].length == _lines(TRICKY)
    assert fns["tricky"].line == _lines(SHORT) + 2
    assert fns["Wrap::call"].length == 3
    assert fns["T::defaulted"].length == 3
    # Left out: a declaration without a body, test code, a macro's template.
    assert not {"T::declared", "inside_tests", "make", "$n"} & fns.keys()
    assert set(fns) == {"short", "tricky", "Wrap::call", "T::defaulted"}


def test_test_module_files_and_tests_folders_are_left_out(tmp_path):
    fns = _scan(tmp_path, {
        "src/lib.rs": "#[cfg(test)]\nmod tests;\nmod kept;\n",
        "src/tests.rs": "fn in_test_file() {\n}\n",
        "src/kept.rs": "fn kept() {\n}\n",
        "src/tests/helper.rs": "fn in_tests_dir() {\n}\n",
        "src/only_test.rs": "#![cfg(test)]\nfn in_cfg_test_file() {\n}\n",
    })
    assert set(fns) == {"kept"}


def test_limit_and_exit_status(tmp_path):
    body = "\n".join(f"    let x{i} = {i};" for i in range(100))
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "lib.rs").write_text(f"fn long() {{\n{body}\n}}\nfn ok() {{}}\n")
    run = [sys.executable, str(SCRIPT), str(tmp_path / "src")]
    over = subprocess.run(run, capture_output=True, text=True)
    assert over.returncode == 1
    assert over.stdout.strip().endswith("src/lib.rs:1 long 102")
    fine = subprocess.run(run + ["--max", "102"], capture_output=True, text=True)
    assert (fine.returncode, fine.stdout) == (0, "")


def test_no_function_over_100_lines_outside_tests():
    fns = fl.scan(fl.default_paths())
    # The scan must see the workspace (a wrong root would pass vacuously).
    assert len(fns) > 1000
    over = sorted(
        f"{f.path}:{f.line} {f.name} {f.length}"
        for f in fns
        if f.length > 100
    )
    assert over == [], "functions over 100 lines:\n" + "\n".join(over)
