"""`ehactl diagnose` end to end: an MCAP written by `ehactl run` from a plant with a hidden
5 ms command delay is diagnosed against the nominal test-bench config (JSON keys, cause,
extended config runnable, report with SVG plots); bad data files exit 2 with one message."""
import json
import os
import pathlib
import xml.etree.ElementTree as ET
import subprocess

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
RIG = REPO / "configs" / "diagnose_testrig.toml"


def run(*args, timeout=600):
    return subprocess.run([BIN, *args], capture_output=True, text=True, timeout=timeout)


def test_diagnose_mcap_names_hidden_delay(tmp_path):
    truth = tmp_path / "truth.toml"
    truth.write_text(RIG.read_text() + "\n[effects.time_delay]\ndelay = 0.005\n")
    mcap = tmp_path / "rig.mcap"
    r = run("run", str(truth), "--out", str(mcap), "--json")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "diag"
    r = run("diagnose", "--config", str(RIG), "--data", str(mcap), "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    for key in ("cause", "causes", "nrmse_nominal", "nrmse_extended", "gain", "candidates", "extended_config", "report"):
        assert key in d, key
    assert d["cause"] == "time_delay", d["summary"]
    assert len(d["candidates"]) == 12
    for c in d["candidates"]:
        for key in ("effect", "params", "nrmse_train", "nrmse_validation", "score", "accepted", "evidence"):
            assert key in c
    assert d["sensor_offsets"] == {}  # the zeros are trusted unless --sensor-offsets
    fitted = d["extended_params"]["effects.time_delay.delay"]
    assert abs(fitted - 0.005) < 0.001, fitted
    assert d["nrmse_extended"]["overall"] < 0.5 * d["nrmse_nominal"]["overall"]
    assert d["gain"] >= 0.5
    # The extended config runs and reproduces the data better than the nominal one.
    r = run("check-config", d["extended_config"])
    assert r.returncode == 0 and "time_delay" in r.stdout, r.stdout + r.stderr
    report = pathlib.Path(d["report"]).read_text()
    assert "Cause: `time_delay`" in report
    # Plots: SVG drawn in Rust (no Python needed), parsed here by the standard XML parser.
    for svg in ("traces.svg", "residual.svg", "residual_state.svg", "frf.svg"):
        root = ET.parse(out / svg).getroot()
        assert root.tag.endswith("svg"), svg
        lines = [e for e in root.iter() if e.tag.endswith("polyline") or e.tag.endswith("path")]
        texts = " ".join((e.text or "") for e in root.iter() if e.tag.endswith("text"))
        assert len(lines) >= 3, (svg, len(lines))
        assert f"]({svg})" in report
        if svg in ("traces.svg", "frf.svg"):
            for name in ("measured", "nominal", "extended"):
                assert name in texts, (svg, name)
    # The circles of the residual-versus-state scatter are data points, not decoration.
    circles = [e for e in ET.parse(out / "residual_state.svg").getroot().iter() if e.tag.endswith("circle")]
    assert len(circles) > 1000, len(circles)
    # Traces file: held-out flag marks the last 30 %.
    tr = np.genfromtxt(out / "traces.csv", delimiter=",", names=True)
    assert abs(tr["held_out"].mean() - 0.3) < 0.01


def write_csv(path, rows, header="t,u,x,p_a,p_b"):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")


def one_line_error(r, *words):
    assert r.returncode == 2, r
    assert r.stdout == ""
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    for w in words:
        assert w in lines[0], lines[0]
    assert "panicked" not in r.stderr


def test_bad_data_files_exit_2(tmp_path):
    good = [[k * 1e-3, 0.1, 0.1, 5e6, 4e6] for k in range(100)]
    nan = [list(r) for r in good]
    nan[40][3] = float("nan")
    write_csv(tmp_path / "nan.csv", nan)
    one_line_error(run("diagnose", "--config", str(RIG), "--data", str(tmp_path / "nan.csv")), "`p_a`", "line 42")
    back = [list(r) for r in good]
    back[50][0] = back[48][0]
    write_csv(tmp_path / "time.csv", back)
    one_line_error(run("diagnose", "--config", str(RIG), "--data", str(tmp_path / "time.csv")), "not increasing", "line 52")
    bar = [[r[0], r[1], r[2], 50.0, 40.0] for r in good]
    write_csv(tmp_path / "bar.csv", bar)
    one_line_error(run("diagnose", "--config", str(RIG), "--data", str(tmp_path / "bar.csv")), "looks like bar")
    write_csv(tmp_path / "nou.csv", [[r[0], r[2]] for r in good], header="t,x")
    one_line_error(run("diagnose", "--config", str(RIG), "--data", str(tmp_path / "nou.csv")), "missing required column `u`")
