"""Figures quoted in docs/python.md are the ones the tuning examples print today.

Runs bindings/python/examples/tune_sahu2022_force.py and tune_dindorf2022_boom.py (≈ 30 s
together) into a temporary directory, formats the numbers of their summary.json the way
docs/python.md quotes them, and checks that each quoted phrase is in the document. When an
example's result changes on purpose, the failure prints the phrase to paste."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from simrig import require_bindings

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "python.md"
EXAMPLES = REPO / "bindings" / "python" / "examples"


def run_example(name: str, out: Path) -> dict:
    require_bindings()
    r = subprocess.run([sys.executable, str(EXAMPLES / name), "--out", str(out)], cwd=REPO,
                       capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads((out / "summary.json").read_text())


def check_phrases(phrases: list[str]) -> None:
    text = " ".join(DOC.read_text().split())  # line breaks of the paragraph do not matter
    missing = [p for p in phrases if p not in text]
    assert not missing, "docs/python.md does not say (the example prints this now):\n" + "\n".join(missing)


@pytest.fixture(scope="module")
def sahu(tmp_path_factory):
    return run_example("tune_sahu2022_force.py", tmp_path_factory.mktemp("sahu"))


def test_sahu2022_tuning_figures_are_current(sahu):
    rows = {r["gains"]: r for r in sahu["rows"]}

    def row(prefix: str) -> dict:
        (r,) = [v for k, v in rows.items() if k.startswith(prefix)]
        return r

    lin = row("(a) model-based PM 60°, max K_I, linearised")
    itae = row("(c) ITAE optimisation")
    sweep = row("(c) sweep RMS optimisation")
    p057, p04 = row("paper K_P 0.57"), row("paper K_P 0.4")
    check_phrases([
        f"linearised Sahu 2022 loop is K_P {lin['kp']:.3f}, I {lin['integral_per_s']:.0f} 1/s",
        f"lands on K_P {itae['kp']:.3f}, I {itae['integral_per_s']:.0f} 1/s",
        f"(ITAE {itae['itae_Ns2']:.5f} N·s² vs {p057['itae_Ns2']:.5f} for K_P 0.57)",
        f"gives {sweep['sweep_rms_error_N']:.1f} N vs {p04['sweep_rms_error_N']:.1f} N (K_P 0.4) "
        f"and {p057['sweep_rms_error_N']:.1f} N (K_P 0.57)",
    ])


def test_dindorf2022_tuning_figures_are_current(tmp_path):
    s = run_example("tune_dindorf2022_boom.py", tmp_path)
    base = s["rows"]["config gains"]
    (zn,) = [v for k, v in s["rows"].items() if k.startswith("(b) critical gain")]
    assert zn["vibration_rms"] < 1e-9, zn  # the document says "no piston vibration"
    check_phrases([
        f"critical-gain PD (K_Pcr {s['K_Pcr']:.0f} V/m, T_pcr {s['T_pcr'] * 1e3:.0f} ms → "
        f"K_P {zn['control.pd.kp']:.0f} V/m, T_D {zn['control.pd.td'] * 1e3:.1f} ms)",
        f"holds 0.6 m to {abs(zn['position_error']) * 1e3:.2f} mm with no piston vibration",
        f"against {abs(base['position_error']) * 1e3:.1f} mm and {base['vibration_rms'] * 1e6:.1f} µm RMS "
        f"for the config's K_P {base['control.pd.kp']:.0f} V/m",
    ])
