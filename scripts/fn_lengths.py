#!/usr/bin/env python3
"""Lists the Rust functions longer than N lines (default 100) in non-test code.

Scans `crates/*/src` and `crates/*/examples` (never a `tests/` directory) and prints one line
per function over the limit, `path:line name length`, longest first. A function's length runs
from its `fn` line to the line of its matching closing brace, both counted. The scan reads
tokens, not text: braces inside strings (normal, byte, raw `r#"…"#`), char literals (`'{'`) and
comments (line, nested block) do not count, and a lifetime (`'a`) is not a char literal.
Left out: modules and items under `#[cfg(test)]` (an inline `mod tests { … }` as well as a
`mod tests;` file), files starting with `#![cfg(test)]`, and `macro_rules!` bodies (a macro is
not a function; neither is the block of a macro invocation such as `components! { … }`, whose
length is never counted, though a function defined inside one is). Closures are not listed.

Usage: `python3 scripts/fn_lengths.py [--max N] [--all] [PATH …]` (paths: files or folders;
default the crates above). `--all` lists every function with its length. Exit status 1 when
any function is longer than the limit, 0 otherwise.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MAX = 100


@dataclass
class Tok:
    """One token: an identifier or number (`kind` "id"), a literal ("lit"), or a punctuation
    character or `->` / `::` ("p")."""

    kind: str
    text: str
    line: int


def _skip_block_comment(src: str, i: int, line: int) -> tuple[int, int]:
    """From just after `/*`: returns the index after the matching `*/` and the line there."""
    depth = 1
    n = len(src)
    while i < n and depth:
        if src.startswith("/*", i):
            depth += 1
            i += 2
        elif src.startswith("*/", i):
            depth -= 1
            i += 2
        else:
            if src[i] == "\n":
                line += 1
            i += 1
    return i, line


def _skip_quoted(src: str, i: int, line: int) -> tuple[int, int]:
    """From just after an opening `"`: the index after the closing quote (escapes honoured)."""
    n = len(src)
    while i < n:
        c = src[i]
        if c == "\\":
            if i + 1 < n and src[i + 1] == "\n":
                line += 1
            i += 2
            continue
        if c == "\n":
            line += 1
        i += 1
        if c == '"':
            break
    return i, line


def _skip_raw(src: str, i: int, line: int, hashes: int) -> tuple[int, int]:
    """From just after `r#…#"`: the index after the closing `"#…#`."""
    end = '"' + "#" * hashes
    j = src.find(end, i)
    j = len(src) if j < 0 else j + len(end)
    return j, line + src.count("\n", i, j)


def _raw_string_at(src: str, i: int) -> int | None:
    """The number of `#` when `src[i:]` starts a raw string (`r"`, `r#"`, `br"`, `cr#"`)."""
    j = i
    if src[j] in "bc" and j + 1 < len(src) and src[j + 1] == "r":
        j += 1
    if src[j] != "r":
        return None
    j += 1
    hashes = 0
    while j < len(src) and src[j] == "#":
        hashes += 1
        j += 1
    if j < len(src) and src[j] == '"':
        return hashes
    return None


def _char_literal_end(src: str, i: int) -> int | None:
    """At a `'`: the index after the char literal that starts here, None for a lifetime."""
    n = len(src)
    if i + 1 < n and src[i + 1] == "\\":
        j = i + 2
        if j < n and src[j] == "u" and j + 1 < n and src[j + 1] == "{":
            j = src.find("}", j) + 1
        else:
            j += 1
        while j < n and src[j] != "'":
            j += 1
        return j + 1
    if i + 2 < n and src[i + 2] == "'":
        return i + 3
    return None


def tokenize(src: str) -> list[Tok]:
    """Splits Rust source into tokens, dropping comments and reducing literals to "lit"."""
    toks: list[Tok] = []
    i, line, n = 0, 1, len(src)
    while i < n:
        c = src[i]
        if c == "\n":
            line += 1
            i += 1
        elif c.isspace():
            i += 1
        elif src.startswith("//", i):
            j = src.find("\n", i)
            i = n if j < 0 else j
        elif src.startswith("/*", i):
            i, line = _skip_block_comment(src, i + 2, line)
        elif c == '"':
            start = line
            i, line = _skip_quoted(src, i + 1, line)
            toks.append(Tok("lit", '""', start))
        elif c in "brc" and _raw_string_at(src, i) is not None:
            hashes = _raw_string_at(src, i)
            start = line
            i, line = _skip_raw(src, src.index('"', i) + 1, line, hashes)
            toks.append(Tok("lit", 'r""', start))
        elif c in "bc" and i + 1 < n and src[i + 1] == '"':
            start = line
            i, line = _skip_quoted(src, i + 2, line)
            toks.append(Tok("lit", 'b""', start))
        elif c == "b" and i + 1 < n and src[i + 1] == "'":
            end = _char_literal_end(src, i + 1)
            i = end if end is not None else i + 2
            toks.append(Tok("lit", "b''", line))
        elif c == "'":
            end = _char_literal_end(src, i)
            if end is None:  # a lifetime or a label: `'a`, `'static`, `'outer:`
                j = i + 1
                while j < n and (src[j].isalnum() or src[j] == "_"):
                    j += 1
                toks.append(Tok("life", src[i:j], line))
                i = j
            else:
                toks.append(Tok("lit", "''", line))
                i = end
        elif c.isalnum() or c == "_":
            j = i
            while j < n and (src[j].isalnum() or src[j] == "_"):
                j += 1
            if src.startswith("r#", i) and j == i + 1:  # raw identifier r#type
                j = i + 2
                while j < n and (src[j].isalnum() or src[j] == "_"):
                    j += 1
            toks.append(Tok("id", src[i:j], line))
            i = j
        elif src.startswith("->", i) or src.startswith("::", i) or src.startswith("=>", i):
            toks.append(Tok("p", src[i : i + 2], line))
            i += 2
        else:
            toks.append(Tok("p", c, line))
            i += 1
    return toks


def _match(toks: list[Tok], i: int) -> int:
    """At an opening `{`, `(` or `[`: the index of its matching closer (or the last token)."""
    opener = toks[i].text
    closer = {"{": "}", "(": ")", "[": "]"}[opener]
    depth = 0
    for j in range(i, len(toks)):
        t = toks[j]
        if t.kind != "p":
            continue
        if t.text == opener:
            depth += 1
        elif t.text == closer:
            depth -= 1
            if depth == 0:
                return j
    return len(toks) - 1


def _item_end(toks: list[Tok], i: int) -> int:
    """From the start of an item: the index of its last token (its block's `}` or its `;`)."""
    j = i
    while j < len(toks):
        t = toks[j]
        if t.kind == "p" and t.text in "([":
            j = _match(toks, j) + 1
            continue
        if t.kind == "p" and t.text == "{":
            return _match(toks, j)
        if t.kind == "p" and t.text == ";":
            return j
        j += 1
    return len(toks) - 1


def _is_cfg_test(attr: list[Tok]) -> bool:
    """Whether an attribute's tokens (between `[` and `]`) are `cfg(…test…)` without `not`."""
    words = [t.text for t in attr if t.kind == "id"]
    return bool(words) and words[0] == "cfg" and "test" in words and "not" not in words


def _impl_name(toks: list[Tok], i: int, brace: int) -> str:
    """The self type of the `impl` at `i` whose block opens at `brace` (`impl Tr for X` → X)."""
    depth = 0
    words: list[str] = []
    after_for: str | None = None
    for t in toks[i + 1 : brace]:
        if t.kind == "p" and t.text == "<":
            depth += 1
        elif t.kind == "p" and t.text == ">":
            depth -= 1
        elif t.kind == "id" and depth == 0:
            if t.text == "where":
                break
            if t.text == "for":
                after_for = ""
            elif after_for == "":
                after_for = t.text
            elif t.text not in ("dyn", "unsafe", "const", "mut"):
                words.append(t.text)
    if after_for:
        return after_for
    return words[-1] if words else "?"


@dataclass
class Fn:
    """A function found: its file, the line of `fn`, a readable name, its length in lines."""

    path: str
    line: int
    name: str
    length: int


def scan_tokens(toks: list[Tok], path: str) -> tuple[list[Fn], set[str]]:
    """Functions with a body in `toks` (test items left out) and the names of the `mod x;`
    files declared under `#[cfg(test)]`."""
    fns: list[Fn] = []
    test_mods: set[str] = set()
    scopes: list[tuple[int, str]] = []  # (index of the closing brace, name prefix)
    cfg_test = False
    i = 0
    while i < len(toks):
        while scopes and i > scopes[-1][0]:
            scopes.pop()
        t = toks[i]
        if t.kind == "p" and t.text == "#":
            j = i + 1
            if j < len(toks) and toks[j].text == "!":
                j += 1
            if j < len(toks) and toks[j].text == "[":
                end = _match(toks, j)
                if _is_cfg_test(toks[j + 1 : end]):
                    cfg_test = True
                i = end + 1
                continue
        if cfg_test:
            cfg_test = False
            end = _item_end(toks, i)
            words = [x.text for x in toks[i : end + 1] if x.kind == "id"]
            if "mod" in words and toks[end].text == ";":
                test_mods.add(words[words.index("mod") + 1])
            i = end + 1
            continue
        if t.kind == "id" and t.text == "macro_rules" and i + 2 < len(toks):
            j = i + 3  # macro_rules ! name {
            i = (_match(toks, j) + 1) if toks[j].text in "{([" else j
            continue
        if t.kind == "id" and t.text in ("impl", "trait") and _at_item_start(toks, i):
            brace = _body_start(toks, i)
            if brace is not None:
                name = _impl_name(toks, i, brace) if t.text == "impl" else toks[i + 1].text
                prefix = (scopes[-1][1] if scopes else "") + name + "::"
                scopes.append((_match(toks, brace), prefix))
                i = brace + 1
                continue
        if t.kind == "id" and t.text == "fn" and i + 1 < len(toks) and toks[i + 1].kind == "id":
            brace = _body_start(toks, i)
            if brace is not None:
                close = _match(toks, brace)
                prefix = scopes[-1][1] if scopes else ""
                name = prefix + toks[i + 1].text
                fns.append(Fn(path, t.line, name, toks[close].line - t.line + 1))
                scopes.append((close, prefix))
                i = brace + 1
                continue
        i += 1
    return fns, test_mods


def _at_item_start(toks: list[Tok], i: int) -> bool:
    """Whether the keyword at `i` starts an item (not `impl Trait` in a type position)."""
    if i == 0:
        return True
    prev = toks[i - 1]
    return (prev.kind == "p" and prev.text in "{};]") or prev.text in ("unsafe", "pub", ")")


def _body_start(toks: list[Tok], i: int) -> int | None:
    """From an `fn` / `impl` / `trait` keyword: the index of its block's `{`, None when the
    item ends with `;` first (a declaration without a body)."""
    j = i + 1
    while j < len(toks):
        t = toks[j]
        if t.kind == "p" and t.text in "([":
            j = _match(toks, j) + 1
            continue
        if t.kind == "p" and t.text == "{":
            return j
        if t.kind == "p" and t.text == ";":
            return None
        j += 1
    return None


def scan_file(path: Path, rel: str) -> tuple[list[Fn], set[Path]]:
    """The functions of one file and the files of its `#[cfg(test)] mod x;` declarations."""
    src = path.read_text(encoding="utf-8")
    toks = tokenize(src)
    if len(toks) > 3 and toks[0].text == "#" and toks[1].text == "!" and toks[2].text == "[":
        if _is_cfg_test(toks[3 : _match(toks, 2)]):
            return [], set()
    fns, mods = scan_tokens(toks, rel)
    base = path.parent if path.name in ("mod.rs", "lib.rs", "main.rs") else path.with_suffix("")
    skipped: set[Path] = set()
    for m in mods:
        skipped.add(base / f"{m}.rs")
        skipped.add(base / m / "mod.rs")
    return fns, skipped


def rust_files(paths: list[Path]) -> list[Path]:
    """Every `.rs` file under the given files or folders, no `tests/` directory, sorted."""
    out: list[Path] = []
    for p in paths:
        found = [p] if p.is_file() else sorted(p.rglob("*.rs"))
        out.extend(f for f in found if "tests" not in f.relative_to(p.parent).parts[:-1])
    return sorted(set(out))


def scan(paths: list[Path]) -> list[Fn]:
    """Every function with a body in the non-test code under `paths`."""
    files = rust_files(paths)
    skipped: set[Path] = set()
    found: list[Fn] = []
    for f in files:
        rel = str(f.relative_to(ROOT)) if f.is_relative_to(ROOT) else str(f)
        fns, skip = scan_file(f, rel)
        skipped |= {s.resolve() for s in skip}
        found.extend(fns)
    drop = {str(s.relative_to(ROOT)) if s.is_relative_to(ROOT) else str(s) for s in skipped}
    return [fn for fn in found if fn.path not in drop]


def default_paths() -> list[Path]:
    """`crates/*/src` and `crates/*/examples`."""
    crates = sorted((ROOT / "crates").iterdir())
    return [c / d for c in crates for d in ("src", "examples") if (c / d).is_dir()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max", type=int, default=DEFAULT_MAX, help="longest allowed (lines)")
    ap.add_argument("--all", action="store_true", help="list every function")
    ap.add_argument("paths", nargs="*", type=Path, help="files or folders (default: crates)")
    args = ap.parse_args(argv)
    paths = [p.resolve() for p in args.paths] or default_paths()
    fns = scan(paths)
    over = [f for f in fns if f.length > args.max]
    shown = fns if args.all else over
    for f in sorted(shown, key=lambda f: (-f.length, f.path, f.line)):
        print(f"{f.path}:{f.line} {f.name} {f.length}")
    if not args.all:
        print(f"{len(over)} of {len(fns)} functions over {args.max} lines", file=sys.stderr)
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
