"""Shared fixtures for the ehactl Python-binding tests (run: pytest bindings/python/tests)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
CONFIGS = REPO / "configs"


@pytest.fixture
def force_cfg():
    import ehactl

    return ehactl.Config.load(CONFIGS / "sahu2022_force.toml")


@pytest.fixture
def boom_cfg():
    import ehactl

    return ehactl.Config.load(CONFIGS / "dindorf2022_boom.toml")


@pytest.fixture(scope="session")
def delay_diagnosis(tmp_path_factory):
    """A run of the test rig with a hidden 5 ms command delay, logged to MCAP from Python,
    diagnosed against the nominal rig with a report directory and a progress callback (one
    diagnosis shared by the tests that check it: it takes about a minute).

    Returns (mcap path, report directory, DiagnosisResult, progress calls)."""
    import ehactl

    tmp = tmp_path_factory.mktemp("delay")
    truth = tmp / "truth.toml"
    truth.write_text((CONFIGS / "diagnose_testrig.toml").read_text() + "\n[effects.time_delay]\ndelay = 0.005\n")
    mcap = tmp / "rig.mcap"
    ehactl.run(ehactl.Config.load(truth), mcap=mcap)
    calls: list[tuple[int, int]] = []
    rig = ehactl.Config.load(CONFIGS / "diagnose_testrig.toml")
    d = ehactl.diagnose(rig, mcap, out=tmp / "diag", progress=lambda n, m: calls.append((n, m)))
    return mcap, tmp / "diag", d, calls
