#!/usr/bin/env python3
"""Does the workspace have Rust doc tests? Exit 0 (and list them) if a doc comment (`///` or
`//!`) of a Rust file under crates/, bindings/ or tests/ opens a code block that rustdoc runs
as a test: a fence with no info string or one naming rust, should_panic, no_run,
compile_fail or edition20xx (rustdoc book, "Documentation tests"); exit 1 if none does.
scripts/test_all.sh runs `cargo test --doc` only then: rustdoc costs CPU per crate even
where it finds nothing to run."""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
FENCE = re.compile(r"^\s*//[/!]\s?\s*(```+|~~~+)\s*([^`]*)$")
TESTED = {"", "rust", "should_panic", "no_run", "compile_fail"}


def runs_as_test(info: str) -> bool:
    """Whether a fence's info string makes rustdoc compile the block as a test."""
    words = [w for w in re.split(r"[,\s]+", info.strip()) if w]
    if not words:
        return True
    if "ignore" in words:
        return False
    return all(w in TESTED or re.fullmatch(r"edition20\d\d", w) for w in words)


def doc_tests(root: pathlib.Path) -> list[str]:
    """`path:line` of every doc-test block under the Rust source trees of `root`."""
    found = []
    for top in ("crates", "bindings", "tests"):
        for path in sorted((root / top).rglob("*.rs")):
            if "target" in path.parts:
                continue
            open_fence = None
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                m = FENCE.match(line)
                if not m:
                    continue
                if open_fence is None:
                    open_fence = m.group(1)
                    if runs_as_test(m.group(2)):
                        found.append(f"{path.relative_to(root)}:{n}")
                elif m.group(1).startswith(open_fence[0]) and not m.group(2).strip():
                    open_fence = None
    return found


if __name__ == "__main__":
    hits = doc_tests(ROOT)
    for h in hits:
        print(f"   doc test: {h}")
    sys.exit(0 if hits else 1)
