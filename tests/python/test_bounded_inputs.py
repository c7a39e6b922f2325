"""Input files the user names are read bounded: a FIFO, /dev/zero or a directory as the
config, an EDS / DCF file (`canopen.valve_eds` / `canopen.transducer_eds`) or `diagnose
--data` is refused at once with exit 2 and one message naming the file (before, a FIFO
blocked for ever and /dev/zero grew memory until the allocator failed), and `ehactl
check-config` loads and checks the EDS / DCF files that `ehactl run --hal canopen` will use
(before, it said ok for missing, malformed or wrong files).

Every command runs under a 2 GB address-space limit and a timeout, so a regression fails
here instead of taking the machine's memory or hanging the suite."""
import os
import pathlib
import resource
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
BOOM = REPO / "configs" / "dindorf2022_boom.toml"
RIG = REPO / "configs" / "diagnose_testrig.toml"
LIMIT = 2 << 30


def _limit():
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


def run(*args, timeout=30):
    return subprocess.run([BIN, *args], capture_output=True, text=True, timeout=timeout,
                          preexec_fn=_limit)


def one_line(stderr):
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert "panicked" not in stderr
    return lines[0]


def special(tmp_path, kind):
    """A path of `kind`: fifo, zero (/dev/zero), dir."""
    if kind == "fifo":
        p = tmp_path / f"pipe_{kind}"
        os.mkfifo(p)
        return str(p)
    if kind == "zero":
        return "/dev/zero"
    p = tmp_path / "a_dir"
    p.mkdir(exist_ok=True)
    return str(p)


WHAT = {"fifo": "FIFO", "zero": "character device", "dir": "directory"}


@pytest.mark.parametrize("kind", ["fifo", "zero", "dir"])
def test_config_that_is_no_regular_file_is_refused_at_once(tmp_path, kind):
    path = special(tmp_path, kind)
    for cmd in (["check-config", path], ["run", path, "--out", str(tmp_path / "x.mcap")],
                ["diagnose", "--config", path, "--data", str(tmp_path / "d.csv"),
                 "--out", str(tmp_path / "diag")]):
        r = run(*cmd)
        assert r.returncode == 2, (cmd, r)
        line = one_line(r.stderr)
        assert path in line and WHAT[kind] in line and "regular file" in line, line


def test_config_larger_than_its_limit_is_refused(tmp_path):
    cfg = tmp_path / "huge.toml"
    cfg.write_text(BOOM.read_text() + "\n" + ("# padding " + "x" * 90 + "\n") * 180_000)
    assert cfg.stat().st_size > 16 << 20
    r = run("check-config", str(cfg))
    assert r.returncode == 2, r
    line = one_line(r.stderr)
    assert str(cfg) in line and "16 MB limit" in line and "config" in line, line


def eds_config(tmp_path, field, value):
    cfg = tmp_path / f"can_{field}.toml"
    cfg.write_text(BOOM.read_text() + f'\n[canopen]\n{field} = "{value}"\n')
    return cfg


BAD_EDS = {
    "missing": (lambda d: str(d / "nowhere.eds"), "cannot read"),
    "malformed": (lambda d: _write(d / "bad.eds", "[1000]\nParameterName=Device type\n"
                                   "ObjectType=0x7\nDataType=0x0007\nAccessType=maybe\n"),
                  "AccessType"),
    "passwd": (lambda d: "/etc/passwd", "no object sections"),
    "fifo": (lambda d: special(d, "fifo"), "FIFO"),
    "zero": (lambda d: "/dev/zero", "character device"),
    "dir": (lambda d: special(d, "dir"), "directory"),
}


def _write(p, text):
    p.write_text(text)
    return str(p)


@pytest.mark.parametrize("field", ["valve_eds", "transducer_eds"])
@pytest.mark.parametrize("case", sorted(BAD_EDS))
def test_check_config_refuses_the_eds_files_run_refuses(tmp_path, field, case):
    make, why = BAD_EDS[case]
    path = make(tmp_path)
    cfg = eds_config(tmp_path, field, path)
    r = run("check-config", str(cfg))
    assert r.returncode == 2, r
    line = one_line(r.stderr)
    assert f"canopen.{field}" in line and path in line and why in line, line
    assert r.stdout == ""
    # run --hal canopen refuses the same config before the bus is opened or the log created
    out = tmp_path / "x.mcap"
    r = run("run", str(cfg), "--hal", "canopen", "--bus", "socketcand://127.0.0.1:9/can0",
            "--out", str(out))
    assert r.returncode == 2, r
    line = one_line(r.stderr)
    assert f"canopen.{field}" in line and path in line, line
    assert not out.exists()


def test_check_config_checks_good_eds_files(tmp_path):
    eds = REPO / "configs" / "eds"
    cfg = tmp_path / "can.toml"
    cfg.write_text(BOOM.read_text() + f'\n[canopen]\nvalve_eds = "{eds / "ehactl_valve_408.eds"}"\n'
                   f'transducer_eds = "{eds / "ehactl_transducer_406.eds"}"\n')
    r = run("check-config", str(cfg))
    assert r.returncode == 0, r
    assert "ok" in r.stdout and "ehactl_valve_408.eds" in r.stdout, r.stdout
    # the transducer's file given as the valve's: a CiA 406 file for the CiA 408 device
    cfg.write_text(BOOM.read_text() + f'\n[canopen]\nvalve_eds = "{eds / "ehactl_transducer_406.eds"}"\n')
    r = run("check-config", str(cfg))
    assert r.returncode == 2 and "no CiA 408" in one_line(r.stderr), r


@pytest.mark.parametrize("kind", ["fifo", "zero", "dir"])
@pytest.mark.parametrize("ext", ["csv", "mcap"])
def test_diagnose_data_that_is_no_regular_file_is_refused_at_once(tmp_path, kind, ext):
    if kind == "zero":
        path = str(tmp_path / f"zero.{ext}")
        os.symlink("/dev/zero", path)
    elif kind == "fifo":
        path = str(tmp_path / f"pipe.{ext}")
        os.mkfifo(path)
    else:
        path = str(tmp_path / f"dir.{ext}")
        os.mkdir(path)
    # --validate after a good --data file (the measured Sjöberg record and its config)
    sj = REPO / "tests" / "data" / "measured" / "sjoberg" / "estimation.csv"
    for args in (["--config", str(RIG), "--data", path],
                 ["--config", str(REPO / "configs" / "sjoberg1995_actuator.toml"),
                  "--data", str(sj), "--validate", path]):
        r = run("diagnose", *args, "--out", str(tmp_path / "diag"))
        assert r.returncode == 2, (args, r)
        line = one_line(r.stderr)
        assert path in line and WHAT[kind] in line and "regular file" in line, line
