#!/usr/bin/env python3
"""List file-level import circles (file A uses B while B, directly or through others, uses A).

Rust: inside each crate under crates/ and bindings/python/src, an edge A -> B for every
`crate::B` path (also in `use crate::{B, ...}` groups) and every `super::B` in A outside
comments; a `#[cfg(test)]` module is left out (test scaffolding: a unit test may use a
sibling to build its input, as Cargo's graph leaves dev-dependencies out of a crate's).
Python: inside the `ehactl` package (bindings/python/python/ehactl), an edge for every
relative or absolute import of a sibling module, also inside functions (a lazy import is
still a circle) but not under `if TYPE_CHECKING:` (no import at run time).

Cycles are the strongly connected components with more than one file (Tarjan). Prints each
with the edges that close it and exits 1 if there is one, 0 otherwise. Run by
scripts/test_fast.sh; `--crate NAME` checks one crate (directory name under crates/).
`--allow a.rs,b.rs` accepts a known circle of exactly these files (in whichever crate it is)
without failing; an allowance that matches no circle any more is reported, so that it is
removed once the circle is broken.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
Graph = dict[str, set[str]]


def _strip_comments(text: str) -> str:
    """Drop `//` comment lines and block comments (doc links are no imports)."""
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join(ln for ln in text.splitlines() if not ln.lstrip().startswith("//"))


def _strip_test_modules(text: str) -> str:
    """Drop every `#[cfg(test)] mod NAME { ... }` block (brace-matched)."""
    out, pos = [], 0
    for m in re.finditer(r"#\[cfg\(test\)\]\s*(?:pub(?:\([a-z]+\))?\s+)?mod\s+\w+\s*\{", text):
        if m.start() < pos:
            continue
        depth, i = 0, m.end() - 1
        while i < len(text):
            if text[i] == "{":
                depth += 1
            elif text[i] == "}":
                depth -= 1
                if depth == 0:
                    break
            i += 1
        out.append(text[pos:m.start()])
        pos = i + 1
    out.append(text[pos:])
    return "".join(out)


def _group_names(text: str, start: int) -> list[str]:
    """Top-level names of the `{...}` group that opens at `start`."""
    depth, name, names = 0, "", []
    for ch in text[start:]:
        if ch == "{":
            depth += 1
            if depth == 1:
                continue
        elif ch == "}":
            depth -= 1
            if depth == 0:
                names.append(name)
                break
        if depth == 1 and ch == ",":
            names.append(name)
            name = ""
        elif depth == 1:
            name += ch
    return [n.strip().split("::")[0].strip() for n in names if n.strip()]


def rust_graph(src: Path) -> Graph:
    """Edges between the module files of one crate's `src` directory."""
    files = {p: p.relative_to(src) for p in src.rglob("*.rs")}

    def module_of(rel: Path) -> tuple[str, ...]:
        parts = list(rel.with_suffix("").parts)
        if parts[-1] in ("lib", "main", "mod"):
            parts = parts[:-1]
        return tuple(parts)

    by_module = {module_of(rel): str(rel) for rel in files.values()}
    graph: Graph = {str(rel): set() for rel in files.values()}
    for p, rel in files.items():
        me = module_of(rel)
        text = _strip_test_modules(_strip_comments(p.read_text(encoding="utf-8")))
        for m in re.finditer(r"\b(crate|super)::", text):
            base: tuple[str, ...] = () if m.group(1) == "crate" else me[:-1]
            rest = text[m.end():]
            if rest.startswith("{"):
                heads = [[n] for n in _group_names(text, m.end())]
            else:
                heads = [re.match(r"[A-Za-z_0-9:]*", rest).group(0).split("::")]  # type: ignore[union-attr]
            for head in heads:
                # the longest module path that is a file of this crate
                target = None
                for k in range(len(head), 0, -1):
                    cand = base + tuple(head[:k])
                    if cand in by_module:
                        target = by_module[cand]
                        break
                if target is not None and target != str(rel):
                    graph[str(rel)].add(target)
    return graph


def python_graph(pkg: Path) -> Graph:
    """Edges between the modules of a Python package (relative and absolute imports)."""
    name = pkg.name
    files = {p: p.relative_to(pkg) for p in pkg.rglob("*.py")}

    def module_of(rel: Path) -> tuple[str, ...]:
        parts = list(rel.with_suffix("").parts)
        return tuple(parts[:-1]) if parts[-1] == "__init__" else tuple(parts)

    by_module = {module_of(rel): str(rel) for rel in files.values()}
    graph: Graph = {str(rel): set() for rel in files.values()}
    for p, rel in files.items():
        me = module_of(rel)
        pkg_of_me = me if rel.name == "__init__.py" else me[:-1]
        tree = ast.parse(p.read_text(encoding="utf-8"))
        skip: set[int] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                skip.update(id(n) for b in node.body for n in ast.walk(b))
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            targets: list[tuple[str, ...]] = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg_of_me[: len(pkg_of_me) - (node.level - 1)]
                    mod = tuple(node.module.split(".")) if node.module else ()
                elif node.module and node.module.split(".")[0] == name:
                    base, mod = (), tuple(node.module.split(".")[1:])
                else:
                    continue
                targets += [base + mod + (a.name,) for a in node.names]
                targets.append(base + mod)
            elif isinstance(node, ast.Import):
                targets += [
                    tuple(a.name.split(".")[1:]) for a in node.names if a.name.split(".")[0] == name
                ]
            for t in targets:
                target = by_module.get(t)
                if target is not None and target != str(rel) and t != ():
                    graph[str(rel)].add(target)
    return graph


def cycles(graph: Graph) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--crate", action="append", help="only this crate (directory under crates/)")
    ap.add_argument("--skip", action="append", default=[], help="crate directory to leave out")
    ap.add_argument("--allow", action="append", default=[], help="known circle: comma-separated file paths")
    args = ap.parse_args()
    units: list[tuple[str, Graph]] = []
    for src in sorted(ROOT.glob("crates/*/src")):
        crate = src.parent.name
        if (args.crate and crate not in args.crate) or crate in args.skip:
            continue
        units.append((f"crates/{crate}/src", rust_graph(src)))
    if not args.crate:
        units.append(("bindings/python/src", rust_graph(ROOT / "bindings/python/src")))
        pkg = ROOT / "bindings/python/python/ehactl"
        units.append(("bindings/python/python/ehactl", python_graph(pkg)))
    allowed = {frozenset(a.split(",")): a for a in args.allow}
    used: set[frozenset[str]] = set()
    found = 0
    for where, g in units:
        for comp in cycles(g):
            inside = set(comp)
            edges = [f"{a} -> {b}" for a in comp for b in sorted(g[a]) if b in inside]
            known = frozenset(comp) in allowed
            if known:
                used.add(frozenset(comp))
            else:
                found += 1
            tag = "known import circle (allowed)" if known else "import circle"
            print(f"{where}: {tag} between {', '.join(comp)}:\n    " + "\n    ".join(edges))
    for a, text in allowed.items():
        if a not in used:
            print(f"note: the allowed circle {text} is gone; remove its --allow")
    if found:
        print(f"{found} file-level import circle(s); move the shared part where both can use it one way")
        return 1
    print(f"no new file-level import circles ({sum(len(g) for _, g in units)} files checked)")
    return 0

if __name__ == "__main__":
    sys.exit(main())
