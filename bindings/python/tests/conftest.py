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
