"""What `ehactl predict` and a campaign (`ehactl diagnose --data R1 --data R2 …`) refuse before
they score anything: a dependence on an operating input that pushes a parameter out of its
range, a constant channel, a record that is not one operating point, an ehactl log of another
rig, one recording given twice; and how they share an output directory (a lock, their own
names in messages, `prediction.json` = `--json`). Records: the repository's real MTS chirps
(tests/data/measured/utfsm_mts/, 500 Hz, a `current` column) and copies of them changed here."""
import csv
import fcntl
import json
import os
import pathlib
import subprocess

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
CONFIG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"
A0, A1 = MTS / "0A_5to15s.csv", MTS / "1A_5to15s.csv"


def ehactl(*args, timeout=600):
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def rows(src):
    with open(src, newline="") as f:
        return list(csv.reader(f))


def write(dst, table, **kw):
    with open(dst, "w", newline="", **kw) as f:
        csv.writer(f).writerows(table)
    return dst


def with_column(src, dst, name, values):
    """`src` with column `name` set to `values` (one per data row)."""
    t = rows(src)
    j = t[0].index(name)
    for row, v in zip(t[1:], values):
        row[j] = repr(float(v))
    return write(dst, t)


def config_with(tmp_path, extra):
    p = tmp_path / "model.toml"
    p.write_text(CONFIG.read_text() + "\n" + extra)
    return p


def one_error(r):
    assert r.stdout == "", r.stdout
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, r.stderr
    return lines[0]


# A dependence on an operating input checked at the record's operating point.

def test_a_dependence_that_makes_the_mass_negative_is_refused(tmp_path):
    # mass 10 kg at 0 A, −100 kg/A: −90 kg at the 1 A record.
    cfg = config_with(tmp_path, '[inputs.current.linear]\n"mechanics.mass" = -100.0\n')
    assert ehactl("check-config", cfg).returncode == 0  # the file itself is in range
    for args in (["predict", "--config", cfg, "--data", A1, "--imposed-motion"],
                 ["diagnose", "--config", cfg, "--data", A0, "--data", A1]):
        r = ehactl(*args)
        assert r.returncode == 2, (args, r)
        line = one_error(r)
        assert "inputs.current = 1 A" in line and "`mechanics.mass` becomes -90 kg" in line, line
        assert "out of range" in line and "> 0" in line, line


def test_a_negative_pre_yield_travel_is_refused(tmp_path):
    cfg = config_with(tmp_path, '[inputs.current.linear]\n"effects.polynomial_force.dahl_travel" = -1.0\n')
    r = ehactl("predict", "--config", cfg, "--data", A1, "--imposed-motion")
    assert r.returncode == 2, r
    assert "effects.polynomial_force.dahl_travel" in r.stderr and "out of range" in r.stderr, r.stderr


# A constant channel cannot be scored.

def test_a_constant_force_is_refused_by_predict_and_a_campaign(tmp_path):
    n = len(rows(A0)) - 1
    flat = with_column(A0, tmp_path / "flat.csv", "force", [120.0] * n)
    r = ehactl("predict", "--config", CONFIG, "--data", flat, "--imposed-motion", "--json")
    assert r.returncode == 2, r
    line = one_error(r)
    assert str(flat) in line and "column `force` is constant" in line and "standard deviation 0.000e0 N" in line, line
    assert "cannot be scored" in line, line
    r = ehactl("diagnose", "--config", CONFIG, "--data", flat, "--data", A1, "--json")
    assert r.returncode == 2, r
    line = one_error(r)
    assert str(flat) in line and "column `force` is constant" in line, line


def test_a_constant_channel_beside_others_is_left_out_of_the_score_with_a_warning(tmp_path):
    # Closed-loop replay of the MTS chirp scores x and force; with the force constant only x
    # is scored, and said so.
    n = len(rows(A0)) - 1
    flat = with_column(A0, tmp_path / "flat.csv", "force", [120.0] * n)
    r = ehactl("predict", "--config", CONFIG, "--data", flat, "--json")
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    assert j["replay"] == "closed_loop" and set(j["nrmse"]["channels"]) == {"x"}, j
    assert j["nrmse"]["overall"] == j["nrmse"]["channels"]["x"] > 0
    w = [x for x in j["warnings"] if "column `force` is constant" in x]
    assert len(w) == 1 and str(flat) in w[0] and "left out of the NRMSE" in w[0], j["warnings"]
    # The same record with the force varying: x scores the same, the force is scored too.
    r = ehactl("predict", "--config", CONFIG, "--data", A0, "--json")
    both = json.loads(r.stdout)["nrmse"]["channels"]
    assert set(both) == {"x", "force"} and both["x"] == j["nrmse"]["channels"]["x"]


def test_a_force_constant_over_the_held_out_part_only_is_refused(tmp_path):
    f = [float(r[4]) for r in rows(A0)[1:]]
    n = len(f)
    cut = round(0.7 * n)
    held = with_column(A0, tmp_path / "held.csv", "force", f[:cut] + [f[cut]] * (n - cut))
    r = ehactl("predict", "--config", CONFIG, "--data", held, "--imposed-motion", "--held-out")
    assert r.returncode == 2, r
    assert f"samples {cut}..{n}" in r.stderr and "constant" in r.stderr, r.stderr
    # The whole record varies: scored whole, it is predicted.
    r = ehactl("predict", "--config", CONFIG, "--data", held, "--imposed-motion", "--json")
    assert r.returncode == 0, r.stderr


# One record, one operating point.

def test_an_input_that_varies_within_a_record_is_refused(tmp_path):
    n = len(rows(A1)) - 1
    steps = with_column(A1, tmp_path / "steps.csv", "current", [3 * k // n for k in range(n)])
    for args in (["predict", "--config", CONFIG, "--data", steps, "--imposed-motion"],
                 ["diagnose", "--config", CONFIG, "--data", A0, "--data", steps]):
        r = ehactl(*args)
        assert r.returncode == 2, (args, r)
        line = one_error(r)
        assert str(steps) in line and "`current` varies within the record: 0 … 2 A" in line, line
        assert "one operating point per record" in line, line


def test_a_measured_input_with_noise_is_one_operating_point(tmp_path):
    # A measured coil current at 0 A with 10 mA of white noise (a fixed seed): its spread is
    # noise, not a second operating point (no level to compare it with at 0 A).
    import numpy as np

    n = len(rows(A0)) - 1
    noisy = with_column(A0, tmp_path / "noisy.csv", "current",
                        0.01 * np.random.default_rng(7).standard_normal(n))
    r = ehactl("predict", "--config", CONFIG, "--data", noisy, "--imposed-motion", "--json")
    assert r.returncode == 0, r.stderr
    assert abs(json.loads(r.stdout)["operating_point"]["current"]) < 0.01


def test_a_missing_input_is_warned_about_by_predict_and_a_campaign(tmp_path):
    t = rows(A1)
    j = t[0].index("current")
    bare = write(tmp_path / "bare.csv", [r[:j] + r[j + 1:] for r in t])
    want = f"{bare}: no `current` column; taken at the config's operating point 0 A"
    r = ehactl("predict", "--config", CONFIG, "--data", bare, "--imposed-motion", "--json")
    assert r.returncode == 0, r.stderr
    assert want in json.loads(r.stdout)["warnings"]
    assert f"ehactl: warning: {want}" in r.stderr.splitlines(), r.stderr
    r = ehactl("diagnose", "--config", CONFIG, "--data", A0, "--data", bare, "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["warnings"].count(want) == 1


# A log of another rig.

def test_a_log_of_another_rig_is_refused_by_predict_and_a_campaign(tmp_path):
    log = tmp_path / "sahu.mcap"
    r = ehactl("run", REPO / "configs" / "sahu2022_force.toml", "--duration", "0.2", "--out", log)
    assert r.returncode == 0, r.stderr
    for args in (["predict", "--config", CONFIG, "--data", log],
                 ["diagnose", "--config", CONFIG, "--data", A0, "--data", log]):
        r = ehactl(*args)
        assert r.returncode == 2, (args, r)
        line = one_error(r)
        assert str(log) in line and "logged with a config that differs from --config" in line, line
        assert "cylinder.area_a: logged" in line, line


# One recording given twice.

def test_a_copy_of_a_record_is_not_another_recording(tmp_path):
    copy = tmp_path / "copy.csv"
    copy.write_bytes(A0.read_bytes())
    # The same samples with a byte-order mark, CRLF line ends and `;` as separator.
    bom = write(tmp_path / "bom.csv", rows(A0), encoding="utf-8-sig")
    bom.write_bytes(bom.read_bytes().replace(b"\r\n", b"\n").replace(b"\n", b"\r\n").replace(b",", b";"))
    for other in (copy, bom):
        r = ehactl("diagnose", "--config", CONFIG, "--data", A0, "--data", A1, "--data", other)
        assert r.returncode == 2, r
        line = one_error(r)
        assert f"{A0} and {other} hold the same samples" in line, line
        assert "must be another recording" in line, line


# The output directory.

def test_an_output_directory_held_by_another_ehactl_is_refused(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what a running ehactl holds
        for args in (["predict", "--config", CONFIG, "--data", A1, "--imposed-motion"],
                     ["diagnose", "--config", CONFIG, "--data", A0, "--data", A1]):
            r = ehactl(*args, "--out", out)
            assert r.returncode == 1, (args, r)
            line = one_error(r)
            assert f"--out {out}: another running ehactl" in line, line
        assert list(out.iterdir()) == []
    finally:
        os.close(fd)
    r = ehactl("predict", "--config", CONFIG, "--data", A1, "--imposed-motion", "--out", out)
    assert r.returncode == 0, r.stderr
    assert (out / "prediction.json").is_file()


def test_a_refused_record_leaves_no_new_output_directory(tmp_path):
    n = len(rows(A0)) - 1
    flat = with_column(A0, tmp_path / "flat.csv", "force", [120.0] * n)
    out = tmp_path / "new"
    r = ehactl("predict", "--config", CONFIG, "--data", flat, "--imposed-motion", "--out", out)
    assert r.returncode == 2 and not out.exists(), r


def test_predict_names_itself_in_its_messages(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    r = ehactl("predict", "--config", CONFIG, "--data", A1, "--imposed-motion", "--out", out)
    assert r.returncode == 2, r
    line = one_error(r)
    assert "ehactl predict writes only" in line and "diagnose" not in line, line
    d = tmp_path / "d"
    d.mkdir()
    (d / "prediction.json").symlink_to(A1)
    r = ehactl("predict", "--config", CONFIG, "--data", A1, "--imposed-motion", "--out", d)
    assert r.returncode == 2, r
    line = one_error(r)
    assert "predict never writes over its inputs" in line and "diagnose" not in line, line


def test_prediction_json_is_the_json_object(tmp_path):
    out = tmp_path / "p"
    for data in ([A1], [A0, A1]):
        args = [a for d in data for a in ("--data", d)]
        r = ehactl("predict", "--config", CONFIG, *args, "--imposed-motion", "--out", out, "--json")
        assert r.returncode == 0, r.stderr
        printed = json.loads(r.stdout)
        assert json.loads((out / "prediction.json").read_text()) == printed
        assert printed["config"] == str(CONFIG) and "warnings" in printed
        assert str(out / "prediction.json") in printed["files"]


def test_predict_without_data_is_refused():
    r = ehactl("predict", "--config", CONFIG)
    assert r.returncode == 2 and "--data" in r.stderr, r


def test_predict_data_messages_do_not_name_diagnose(tmp_path):
    t = rows(A1)
    t[0].append("note")
    for row in t[1:]:
        row.append("ok")
    noted = write(tmp_path / "noted.csv", t)
    r = ehactl("predict", "--config", CONFIG, "--data", noted, "--imposed-motion")
    assert r.returncode == 0, r.stderr
    assert "text columns not used by ehactl" in r.stderr and "diagnose" not in r.stderr, r.stderr
    t = rows(A1)
    t[100][0] = repr(float(t[100][0]) + 0.0005)  # one time stamp 0.5 ms late at 500 Hz
    jitter = write(tmp_path / "jitter.csv", t)
    r = ehactl("predict", "--config", CONFIG, "--data", jitter, "--imposed-motion")
    assert r.returncode == 2, r
    line = one_error(r)
    assert "sampling is not uniform" in line and "diagnose" not in line, line
