"""Cross-check ehactl MCAP logs with the official TypeScript reader (@mcap/core) under Node.

Skipped only when `node` is not installed. Installs tests/node's locked dependencies
(`npm ci`) when tests/node/node_modules is missing.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from ehactl_mcap import read_run

REPO = Path(__file__).resolve().parents[2]
NODE_DIR = REPO / "tests" / "node"
FORCE_CONFIG = REPO / "configs" / "sahu2022_force.toml"
RATE_HZ = 5000.0
DURATION = 0.3

pytestmark = pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")


@pytest.fixture(scope="module")
def node_ready() -> str:
    node = shutil.which("node")
    assert node is not None
    if not (NODE_DIR / "node_modules" / "@mcap" / "core").is_dir():
        npm = shutil.which("npm")
        assert npm is not None, "node is installed but npm is not: cannot install tests/node dependencies"
        cmd = [npm, "ci"] if (NODE_DIR / "package-lock.json").is_file() else [npm, "install"]
        proc = subprocess.run(
            cmd + ["--no-audit", "--no-fund"], cwd=NODE_DIR, capture_output=True, text=True, timeout=600
        )
        assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}"
    return node


def ehactl_bin() -> Path:
    path = Path(os.environ.get("EHACTL_BIN", REPO / "target" / "release" / "ehactl"))
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.fail(
            f"ehactl binary not found at {path}: build it with "
            "`cargo build --release -p ehactl-cli` or set EHACTL_BIN"
        )
    return path


def run_node(node: str, mcap: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [node, str(NODE_DIR / "read_mcap.mjs"), str(mcap)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.fixture(scope="module")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("node") / "sahu2022_force.mcap"
    proc = subprocess.run(
        [str(ehactl_bin()), "run", str(FORCE_CONFIG), "--duration", repr(DURATION), "--out", str(out), "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return out, json.loads(proc.stdout)


def test_node_reader_agrees(node_ready: str, short_run: tuple[Path, dict]) -> None:
    out, js = short_run
    cycles = js["cycles"]
    assert cycles == round(DURATION * RATE_HZ)

    proc = run_node(node_ready, out)
    assert proc.returncode == 0, f"read_mcap.mjs exit {proc.returncode}\nstdout: {proc.stdout}\nstderr: {proc.stderr}"
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stdout
    res = json.loads(lines[0])

    assert res["errors"] == []
    assert res["contiguous"] is True
    assert res["topics"]["/control"] == cycles
    assert res["topics"]["/plant"] == cycles
    assert res["stream_topics"] == res["topics"]
    assert res["first_cycle"] == 0 and res["last_cycle"] == cycles - 1
    assert res["crc"]["data_section_ok"] is True

    run = read_run(out)
    assert res["topics"] == run["message_counts"]
    assert res["first_t"] == run["control"]["t"][0]
    assert res["last_t"] == run["control"]["t"][-1]
    for key in ("setpoint", "feedback", "command", "p_a", "p_b", "spool"):
        assert res["last_control"][key] == run["control"][key][-1], key
    assert res["crc"]["summary"] == run["crcs"]["summary"]
    assert res["crc"]["data_section"] == run["crcs"]["data_section"]
    assert res["crc"]["chunks"] == run["crcs"]["chunk"]


def test_node_reader_rejects_corrupt_chunk(node_ready: str, short_run: tuple[Path, dict], tmp_path: Path) -> None:
    out, _ = short_run
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    ci = max(summary.chunk_indexes, key=lambda c: c.compressed_size)
    raw = bytearray(out.read_bytes())
    raw[ci.chunk_start_offset + ci.chunk_length - ci.compressed_size // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    proc = run_node(node_ready, bad)
    assert proc.returncode != 0, f"corrupt file accepted:\n{proc.stdout}"

    # a flipped bit in the chunk's stored CRC: decompression succeeds, only the CRC check can fail
    raw = bytearray(out.read_bytes())
    raw[ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8] ^= 0x01
    bad_crc = tmp_path / "bad_crc.mcap"
    bad_crc.write_bytes(bytes(raw))
    proc = run_node(node_ready, bad_crc)
    assert proc.returncode != 0, f"corrupt chunk CRC accepted:\n{proc.stdout}"
    assert "Incorrect chunk CRC" in proc.stderr, proc.stderr
