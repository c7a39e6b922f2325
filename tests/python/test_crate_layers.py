"""The crate layers of ARCHITECTURE.md, read from the dependency graph cargo itself resolves
(`cargo metadata`, normal dependencies only, transitively): the control laws compile no
hardware, plant or logging crate and no TOML parser; the config, the diagnosis and the analysis do not compile
the CANopen master; the logger does not compile the plant or the Hal; the Hal contract is
bare (no plant, no logger), so the CANopen backend compiles no physics and no MCAP writer,
the config no logger and the diagnosis no Hal; the diagnosis' evaluation harness
(ehactl-ident-eval) is compiled by none of the CLI, the Python bindings and the diagnosis.

EHACTL_ROOT selects another checkout (default: this repository).
"""
import json
import os
import pathlib
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
