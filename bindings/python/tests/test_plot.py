"""ehactl.plot writes real PNG figures (matplotlib)."""

from __future__ import annotations

import numpy as np
import pytest

import ehactl
from ehactl import tune

pytest.importorskip("matplotlib")


def _is_png(p):
    return p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000


def test_step_and_bode_pngs(force_cfg, tmp_path):
    from ehactl import plot

    runs = ehactl.run_many({"control.pi.kp": [0.4, 0.57]}, base=force_cfg, duration=0.05, setpoint=785.0)
    fig = plot.step(runs, labels=["0.4", "0.57"], path=tmp_path / "step.png")
    assert _is_png(tmp_path / "step.png")
    assert len(fig.axes) == 2
    fr = tune.frequency_response(force_cfg, f_hz=np.geomspace(20, 1000, 8))
    plot.bode(fr, path=tmp_path / "bode.png")
    plot.bode([fr, fr.with_gains(force_cfg, {"control.pi.kp": 0.4})], which="closed", path=tmp_path / "closed.png")
    plot.tracking(runs[0], path=tmp_path / "track.png")
    for n in ("bode.png", "closed.png", "track.png"):
        assert _is_png(tmp_path / n)
