"""`ehactl params` prints exactly the registry it printed before the tables moved onto the
struct fields (`#[derive(Params)]`): every line of tests/fixtures/ehactl_params.txt, captured
from the binary of main fcc370f (hand-written CONTROL_PARAMS / CANOPEN_PARAMS), in order,
plus the six switches of the rig sections that the hand-written table left out and the
parameters added since (ADDED)."""
import os
import pathlib
import subprocess

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
FIXTURE = REPO / "tests" / "fixtures" / "ehactl_params.txt"


# Lines added on purpose after the fixture: parameters added since (2026-11-26: the line
# scheme and its segment-mode margin; 2026-11-27: the friction variant lugre and the
# line_dynamics variant hose, whose friction.variant description line the fixture carries
# updated; the Dahl term of the grey-box force law; 2026-11-28: the position sensor's velocity
# window of an imposed-motion replay; 2026-12-07: the supervisor's following-error watch and the
# Bouc–Wen exponent of the Dahl term) and
# the rig sections' switches, which the hand-written table left out
# (tests/rust/param_registry.rs checks their entries). In output order.
ADDED = ("effects.friction.bristle_stiffness", "effects.friction.bristle_damping",
         "effects.line_dynamics.variant", "effects.line_dynamics.wall_compliance",
         "effects.line_dynamics.resistance", "effects.polynomial_force.dahl",
         "effects.polynomial_force.dahl_travel", "effects.polynomial_force.dahl_velocity",
         "effects.polynomial_force.dahl_exponent", "sensors.position.velocity_window",
         "integration.max_omega_h_line", "integration.line_method", "control.mode", "setpoint.kind", "setpoint.sweep",
         "supervisor.following_error", "supervisor.following_error_time", "log.compression",
         "realtime.lock_memory", "realtime.overrun_policy")


def test_params_output_is_unchanged_but_for_the_added_switches():
    r = subprocess.run([BIN, "params"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    old = FIXTURE.read_text().splitlines()
    lines = r.stdout.splitlines()
    added = [ln for ln in lines if ln.split(" ", 1)[0] in ADDED]
    assert [ln.split(" ", 1)[0] for ln in added] == list(ADDED)
    new = [ln for ln in lines if ln.split(" ", 1)[0] not in ADDED]
    assert len(old) > 170
    for i, (o, n) in enumerate(zip(old, new)):
        assert o == n, f"line {i + 1}:\n  was {o!r}\n  now {n!r}"
    assert len(new) == len(old)


def test_every_listed_path_is_checked_by_check_config(tmp_path):
    """A listed control/run parameter set out of range is refused by check-config with its
    path and unit (the list is what the loader checks, not a separate text)."""
    base = (REPO / "configs" / "sahu2022_force.toml").read_text()
    assert "control_rate_hz = 5000.0" in base
    cfg = tmp_path / "bad.toml"
    cfg.write_text(base.replace("control_rate_hz = 5000.0", "control_rate_hz = 0.5", 1))
    r = subprocess.run([BIN, "check-config", str(cfg)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r
    line = r.stderr.strip()
    assert "run.control_rate_hz" in line and "Hz" in line and "out of range" in line, line
