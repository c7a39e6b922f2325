"""The README is true when followed line by line: every shell command of its ```sh blocks and
every ```python block (and those of docs/python.md, where the Python reference moved) runs
from the repository root as written and exits 0, and the warnings they print are the ones
the text explains.

Not run here, with the reason: the two commands that install (scripts/install_and_run.sh,
which is what put the package this test imports in place) and run this suite
(scripts/test_all.sh, which contains this test). Python blocks need the bindings: skipped
without them unless EHACTL_REQUIRE_BINDINGS is set (scripts/test_all.sh sets it)."""

from __future__ import annotations

import os
import re
import resource
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from simrig import require_bindings
from test_mcap_roundtrip import ehactl_bin

REPO = Path(__file__).resolve().parents[2]
NOT_RUN = {
    "bash scripts/install_and_run.sh": "installs ehactl (how the bindings under test got here)",
    "bash scripts/test_all.sh": "the suite this test is part of",
}


def blocks(path: Path, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", path.read_text(), re.S | re.M)


def shell_commands(path: Path) -> list[str]:
    cmds = []
    for b in blocks(path, "sh"):
        for line in b.splitlines():
            cmd = re.sub(r"\s+#.*$", "", line).strip()
            if cmd:
                cmds.append(cmd)
    return cmds


README_SH = shell_commands(REPO / "README.md")


def test_the_readme_has_what_this_test_runs():
    assert set(NOT_RUN) <= set(README_SH), README_SH
    assert any(c.startswith("ehactl diagnose") for c in README_SH)
    assert len(blocks(REPO / "README.md", "python")) == 1


@pytest.mark.parametrize("cmd", [c for c in README_SH if c not in NOT_RUN])
def test_readme_shell_command(cmd):
    argv = shlex.split(cmd)
    if argv[0] == "ehactl":
        argv[0] = str(ehactl_bin())
    elif argv[0] == "python3":
        argv[0] = sys.executable
    else:
        pytest.fail(f"README command this test does not know how to run: {cmd}")
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
    r = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=1200)
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - cpu0
    assert r.returncode == 0, f"{cmd}\n{r.stderr[-3000:]}"
    assert "panicked" not in r.stderr
    if argv[1:2] == ["diagnose"] and argv.count("--data") > 1:
        # a campaign (DIAGNOSIS.md "Campaigns"): its cause names the current dependence
        assert re.search(r"Cause: load-side .* N/A·current", r.stdout), r.stdout[-3000:]
        assert (REPO / "out" / "campaign" / "extended.toml").is_file()
    elif argv[1:2] == ["diagnose"]:
        # the README prepares the reader for this answer on the real MR-damper record
        cause = re.search(r"cause\s+(load-side yield force [\d.]+ N) \(Dahl ", r.stdout)
        assert cause, r.stdout[-3000:]
        # and for these figures of the run (README.md, "Diagnosis" in the tour)
        readme = " ".join((REPO / "README.md").read_text().split())
        ext = float(re.search(r"extended (\d\.\d+)", r.stdout).group(1))
        arx = float(re.search(r"ARX baseline held-out NRMSE (\d\.\d+)", r.stdout).group(1))
        floor = float(re.search(r"`force` ([\d.]+)× floor", r.stdout).group(1))
        report = (REPO / "out" / "diag" / "report.md").read_text().split("## Grey-box extension", 1)[1]
        grey = float(re.search(r"\| \*\*overall\*\* \| \*\*[\d.]+\*\* \| \*\*([\d.]+)\*\* \|", report).group(1))
        for phrase in (f"≈ {floor:.0f}× the noise floor", f"(held-out NRMSE {ext:.2f})",
                       f"ARX model ({arx:.2f})", f"a yield force on the rod, brings it to {grey:.2f}",
                       f"`{cause.group(1)}`"):
            assert phrase in readme, f"README.md should say: {phrase}"
        # the CPU time the README states for this command, within a factor of 2 of this run's
        # (user CPU barely depends on the load, unlike wall time)
        stated = float(re.search(r"About ([\d.]+) s of user CPU time", readme).group(1))
        assert stated / 2 <= cpu <= stated * 2, \
            f"README.md says about {stated} s of user CPU time for diagnose; this run took {cpu:.1f} s"


def test_readme_states_measured_figures_only():
    """No test counts (the suite prints them at its end: they change with every test added),
    and every duration the README gives for the two scripts comes with the date and the load
    average it was measured at."""
    readme = " ".join((REPO / "README.md").read_text().split())
    counts = re.findall(r"\b\d[\d ]* (?:Rust|Python)(?: and [^.]*?)? tests\b", readme)
    assert not counts, f"README.md states test counts {counts}: the suite prints them"
    how_long = re.search(r"How long[,:](.*?)## ", readme).group(1)
    assert re.search(r"\d+ min", how_long), how_long
    assert re.search(r"measured 20\d\d-\d\d-\d\d", how_long), how_long
    assert "load average" in how_long, how_long


def run_python(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    require_bindings()
    script = tmp_path / "snippet.py"
    script.write_text(code)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    r = subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True,
                       timeout=1800, env=env)
    assert r.returncode == 0, f"{code}\n---\n{r.stderr[-3000:]}"
    return r


def test_readme_python_block(tmp_path):
    (code,) = blocks(REPO / "README.md", "python")
    r = run_python(code, tmp_path)
    assert "warn" not in r.stderr.lower(), r.stderr  # nothing the README would have to explain
    out = r.stdout.splitlines()
    assert out[0].startswith("N "), r.stdout  # res.unit and the largest force error


@pytest.mark.parametrize("i", range(len(blocks(REPO / "docs" / "python.md", "python"))))
def test_python_doc_block(i, tmp_path):
    code = blocks(REPO / "docs" / "python.md", "python")[i]
    r = run_python(code, tmp_path)
    # The only warning these print is the one docs/python.md explains next to the call.
    for line in r.stderr.splitlines():
        if "warn" in line.lower():
            assert "replay integration error on" in line, r.stderr
