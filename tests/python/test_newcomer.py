"""A newcomer's rough edges: text output without float noise, open-loop runs
without a NaN error, the control mode spelled as in the config, sweeps logged decimated under
mode-specific default names, exit code 1 documented. Logs are read with the official
``mcap`` reader."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

from mcap.reader import make_reader

from test_mcap_roundtrip import CONFIGS, FORCE_CONFIG, REPO, ehactl_bin

# a float printed with more than 9 significant digits (e.g. 3.0500000000000003)
NOISE = re.compile(r"\d\.\d{9,}|\d{10,}\.\d")


def ehactl(*args: str, cwd: Path = REPO, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([str(ehactl_bin()), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


def summary_of(path: Path) -> dict:
    with open(path, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/summary"]):
            return json.loads(m.data)
    raise AssertionError(f"no /summary in {path}")


def test_run_text_has_no_float_noise(tmp_path):
    r = ehactl("run", str(FORCE_CONFIG), "--out", str(tmp_path / "a.mcap"))
    assert r.returncode == 0, r.stderr
    assert "(3.05 s simulated," in r.stdout, r.stdout
    assert not NOISE.search(r.stdout), r.stdout
    assert re.search(r"rms error\s+\d+(\.\d+)? N \(after start of dynamics: \d+(\.\d+)? N\)", r.stdout), r.stdout


def test_open_loop_run_reports_no_nan_error(tmp_path):
    cfg = CONFIGS / "sirohi2003_circuit.toml"
    r = ehactl("run", str(cfg), "--duration", "0.01", "--out", str(tmp_path / "o.mcap"))
    assert r.returncode == 0, r.stderr
    assert not re.search(r"\bnan\b", r.stdout, re.I), r.stdout
    assert "open loop" in r.stdout, r.stdout
    assert not NOISE.search(r.stdout), r.stdout
    js = json.loads(ehactl("run", str(cfg), "--duration", "0.01", "--out", str(tmp_path / "o2.mcap"), "--json").stdout)
    assert js["error_unit"] == "V" and js["rms_error"] is None


def test_check_config_spells_the_mode_as_in_the_config():
    r = ehactl("check-config", str(CONFIGS / "dindorf2022_boom.toml"))
    assert r.returncode == 0 and "mode position," in r.stdout, r.stdout
    r = ehactl("check-config", str(CONFIGS / "sirohi2003_circuit.toml"))
    assert r.returncode == 0 and "mode open_loop," in r.stdout, r.stdout


def test_sweeps_are_decimated_and_do_not_overwrite_each_other(tmp_path):
    short = ["--points", "3", "--from", "10", "--to", "40", "--periods", "6"]
    closed = ehactl("sweep", str(FORCE_CONFIG), *short, cwd=tmp_path)
    assert closed.returncode == 0, closed.stderr
    opened = ehactl("sweep", str(FORCE_CONFIG), *short, "--open-loop", "--amplitude", "0.04", cwd=tmp_path)
    assert opened.returncode == 0, opened.stderr
    a = tmp_path / "out" / "sahu2022_force_sweep.mcap"
    b = tmp_path / "out" / "sahu2022_force_sweep_open.mcap"
    assert a.exists() and b.exists()
    sa, sb = summary_of(a), summary_of(b)
    assert sa["log_decimation"] == 5 and sb["log_decimation"] == 5
    # one cycle in 5 logged (plus the last), every cycle simulated
    assert sa["records_written"] == -(-sa["cycles"] // 5) + (1 if (sa["cycles"] - 1) % 5 else 0)
    full = ehactl("sweep", str(FORCE_CONFIG), *short, "--log-every", "1", "--out", str(tmp_path / "full.mcap"))
    assert full.returncode == 0, full.stderr
    sf = summary_of(tmp_path / "full.mcap")
    assert sf["records_written"] == sf["cycles"] == sa["cycles"]
    # the estimate does not depend on the log decimation
    assert full.stdout.split("\n", 1)[1].split("mcap:")[0] == closed.stdout.split("\n", 1)[1].split("mcap:")[0]
    assert (tmp_path / "full.mcap").stat().st_size > 3 * a.stat().st_size
    bad = ehactl("sweep", str(FORCE_CONFIG), "--log-every", "0")
    assert bad.returncode == 2 and "--log-every" in bad.stderr


def test_exit_code_1_is_documented_and_used(tmp_path):
    r = ehactl("set", "--socket", str(tmp_path / "none.sock"), "control.pi.kp=0.5")
    assert r.returncode == 1 and "control socket" in r.stderr
    readme = (REPO / "README.md").read_text()
    codes = readme[readme.index("Exit codes:"):][:600]
    assert re.search(r"\b1 [a-z]", codes), codes


def test_missing_config_names_its_path_once(tmp_path):
    missing = tmp_path / "nope.toml"
    for cmd in (["run", str(missing)], ["check-config", str(missing)], ["analyze", str(missing)],
                ["diagnose", "--config", str(missing), "--data", str(REPO / "tests" / "data" / "measured" / "utfsm_mts" / "1A_5to15s.csv")]):
        r = ehactl(*cmd)
        assert r.returncode == 2, (cmd, r.stderr)
        assert "cannot read config file" in r.stderr, r.stderr
        assert r.stderr.count(str(missing)) == 1, r.stderr


def test_check_config_lists_grey_box_terms(tmp_path):
    # a diagnose output (catalogue effects, the identified loop and a grey-box force law) with a
    # grey-box flow law added as a user would write it
    cfg = REPO / "docs" / "diagnosis" / "utfsm_mts_1A" / "extended.toml"
    text = cfg.read_text()
    assert "[effects.polynomial_force]" in text and "[effects.polynomial_flow]" not in text
    flow = "\n[effects.polynomial_flow]\nconstant = 1.0e-7   # m³/s, null-bias flow B → A\n"
    on = tmp_path / "on.toml"
    on.write_text(text + flow)
    r = ehactl("check-config", str(on))
    assert r.returncode == 0, r.stderr
    assert "polynomial_force" in r.stdout and "polynomial_flow" in r.stdout, r.stdout
    off = tmp_path / "off.toml"
    off.write_text(text + flow + "enabled = false\n")
    r = ehactl("check-config", str(off))
    assert r.returncode == 0, r.stderr
    assert "polynomial_force" in r.stdout and "polynomial_flow" not in r.stdout, r.stdout


def test_analyze_text_formats_the_operating_point_with_units():
    r = ehactl("analyze", str(FORCE_CONFIG))
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if "operating point" in ln)
    assert "{" not in line and '"' not in line, line
    assert not NOISE.search(line), line
    for unit in (" N,", " V,", " MPa,"):
        assert unit in line, line
    assert re.search(r"position -?[\d.]+(e-?\d+)? (m|mm|µm)\b", line), line


def test_realtime_overrun_line_reads_as_a_sentence(tmp_path):
    r = ehactl("run", str(FORCE_CONFIG), "--realtime", "--duration", "0.05", "--out", str(tmp_path / "rt.mcap"))
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith("overruns"))
    m = re.search(r"overruns\s+(\d+) of (\d+) cycles: (\d+) ours \(CPU time over the period\), (\d+) thread not running "
                  r"\(late start or preempted\); longest streak (\d+), (\d+) deadlines skipped, policy \w+", line)
    assert m, line
    total, cycles, ours, not_running = (int(m.group(i)) for i in range(1, 5))
    assert total == ours + not_running and cycles > 0, line
