"""The crate layers of ARCHITECTURE.md, read from the dependency graph cargo itself resolves
(`cargo metadata`, normal dependencies only, transitively): the control laws compile no
hardware, plant or logging crate and no TOML parser; the config, the diagnosis and the analysis do not compile
the CANopen master; the logger does not compile the plant or the Hal; the Hal contract is
bare (no plant, no logger), so the CANopen backend compiles no physics and no MCAP writer,
the config no logger and the diagnosis no Hal; the diagnosis' evaluation harness
(ehactl-ident-eval) is compiled by none of the CLI, the Python bindings and the diagnosis.
No TOML parser below the config: the plant, the Hal, the logger and the CANopen backend
compile none (the serde error mapping is crates/config/src/tree.rs). One queue type for what
may be lost: the bounded lossy hand-overs between threads are `ehactl_types::queue::LossyQueue`
(crates/types/src/queue.rs); no source file writes its own drop-and-count queue.

EHACTL_ROOT selects another checkout (default: this repository).
"""
import json
import os
import pathlib
import re
import subprocess

import pytest

ROOT = pathlib.Path(os.environ.get("EHACTL_ROOT", pathlib.Path(__file__).resolve().parents[2]))


@pytest.fixture(scope="module")
def deps():
    # The graph of the host only: what this machine compiles. Without `--filter-platform`
    # cargo wants every target's crates (android, windows) in the local registry, which a
    # fresh machine that only built for its host does not have offline.
    host = subprocess.run(["rustc", "-vV"], capture_output=True, text=True, check=True).stdout
    triple = next(line.split()[1] for line in host.splitlines() if line.startswith("host:"))
    out = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--offline", "--filter-platform", triple],
        cwd=ROOT, capture_output=True, text=True, check=True,
    ).stdout
    meta = json.loads(out)
    name = {p["id"]: p["name"] for p in meta["packages"]}
    graph = {}
    for node in meta["resolve"]["nodes"]:
        normal = {name[d["pkg"]] for d in node["deps"]
                  if any(k["kind"] is None for k in d["dep_kinds"])}
        graph.setdefault(name[node["id"]], set()).update(normal)
    return graph


def closure(graph, crate):
    """Every crate `crate` compiles (normal dependencies, transitively)."""
    seen, todo = set(), [crate]
    while todo:
        for d in graph[todo.pop()]:
            if d not in seen:
                seen.add(d)
                todo.append(d)
    return seen


def test_control_laws_compile_no_io_and_no_plant(deps):
    got = closure(deps, "ehactl-control")
    assert not got & {"ehactl-hal", "ehactl-plant", "ehactl-log", "ehactl-canopen",
                      "mcap", "lz4", "zstd", "nalgebra"}, sorted(got)
    assert "ehactl-types" in got


def test_control_laws_compile_no_toml_parser(deps):
    # The registry's checks on a parsed TOML tree belong to the loader (crates/config/src/tree.rs);
    # the control laws declare parameters through ehactl-types, which parses nothing.
    got = closure(deps, "ehactl-control")
    assert not {d for d in got if d == "toml" or d.startswith("toml_")}, sorted(got)
    assert "serde" in got


@pytest.mark.parametrize("crate", ["ehactl-types", "ehactl-plant", "ehactl-hal", "ehactl-log",
                                   "ehactl-canopen"])
def test_no_toml_parser_below_the_config(deps, crate):
    # The plant reads its sections through serde only; mapping a TOML parser's errors onto
    # registry paths (`from_serde`) is the loader's (crates/config/src/tree.rs).
    got = closure(deps, crate)
    assert not {d for d in got if d == "toml" or d.startswith("toml_")}, sorted(got)
    assert "ehactl-types" in got or crate == "ehactl-types", sorted(got)
    assert "toml" in closure(deps, "ehactl-config")


# Files that may name crossbeam's ArrayQueue, and why the queue there is not a lossy one:
# the logger's record and event queues wait for room under the Block policy; the live
# parameters' one-slot hand-over keeps the newest update; the CANopen backend's receive and
# transmit queues trip the run when they overflow.
ARRAY_QUEUE_USERS = {
    "crates/types/src/queue.rs",
    "crates/log/src/logger.rs",
    "crates/runtime/src/live.rs",
    "crates/canopen/src/hal.rs",
}
# A hand-written drop-and-count queue: a push whose failure bumps a `dropped` counter.
HAND_WRITTEN_LOSSY = re.compile(
    r"\.push\([^;]*?\)\.is_err\(\)\s*\{\s*[\w.]*dropped[\w.]*\.fetch_add", re.S)


def rust_sources():
    for top in ("crates", "bindings"):
        for f in sorted((ROOT / top).rglob("*.rs")):
            if "target" not in f.relative_to(ROOT).parts:
                yield f.relative_to(ROOT).as_posix(), f.read_text()


def test_one_lossy_queue_type():
    sources = dict(rust_sources())
    assert "crates/types/src/queue.rs" in sources, sorted(sources)[:5]
    naming = {p for p, text in sources.items() if "ArrayQueue" in text}
    assert naming <= ARRAY_QUEUE_USERS, sorted(naming - ARRAY_QUEUE_USERS)
    hand = {p for p, text in sources.items()
            if p != "crates/types/src/queue.rs" and HAND_WRITTEN_LOSSY.search(text)}
    assert not hand, sorted(hand)
    assert HAND_WRITTEN_LOSSY.search(sources["crates/types/src/queue.rs"])
    for p in ("crates/types/src/frames.rs", "crates/log/src/logger.rs"):
        assert "LossyQueue<" in sources[p], p


@pytest.mark.parametrize("crate", ["ehactl-config", "ehactl-ident", "ehactl-analysis"])
def test_config_readers_do_not_compile_the_canopen_master(deps, crate):
    got = closure(deps, crate)
    assert "ehactl-canopen" not in got and "rust-ini" not in got, sorted(got)


def test_logger_compiles_neither_plant_nor_hal(deps):
    got = closure(deps, "ehactl-log")
    assert not got & {"ehactl-hal", "ehactl-plant", "nalgebra"}, sorted(got)
    assert "mcap" in got


def test_hal_contract_compiles_neither_plant_nor_log(deps):
    got = closure(deps, "ehactl-hal")
    assert not got & {"ehactl-plant", "ehactl-log", "nalgebra", "mcap", "lz4", "zstd"}, \
        sorted(got)
    assert "ehactl-types" in got


def test_canopen_backend_compiles_no_plant_and_no_mcap_writer(deps):
    got = closure(deps, "ehactl-canopen")
    assert not got & {"ehactl-plant", "nalgebra", "ehactl-log", "mcap", "lz4", "zstd"}, \
        sorted(got)
    assert "ehactl-hal" in got


def test_config_compiles_no_logger(deps):
    got = closure(deps, "ehactl-config")
    assert not got & {"ehactl-log", "mcap", "lz4", "zstd", "ehactl-hal"}, sorted(got)


def test_diagnosis_compiles_no_hal(deps):
    got = closure(deps, "ehactl-ident")
    assert "ehactl-hal" not in got, sorted(got)


@pytest.mark.parametrize("crate", ["ehactl-cli", "ehactl-python", "ehactl-ident"])
def test_shipped_crates_do_not_compile_the_evaluation_harness(deps, crate):
    # The diagnosis' evaluation harness (crates/ident-eval: synthetic and independent cases,
    # effect hiding) is dev-only: neither the CLI, the Python bindings (bindings/python) nor
    # the diagnosis library itself compile it.
    assert "ehactl-ident-eval" in deps, sorted(deps)
    got = closure(deps, crate)
    assert "ehactl-ident-eval" not in got, sorted(got)
    assert "ehactl-ident" in got or crate == "ehactl-ident", sorted(got)
