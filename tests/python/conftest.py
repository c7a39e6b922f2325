"""Fixtures shared by the modules of tests/python.

`diagnosis`: one `ehactl diagnose` per distinct command line in a test session. The
real-data diagnoses (the UTFSM MTS records) take about 20 s of CPU each, and several modules
check different properties of the same diagnosis (the grey-box law, the ARX baseline, the
campaign against each record's own diagnosis); they share one run instead of repeating it.
"""

import json
import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))


@pytest.fixture(scope="session")
def diagnosis(tmp_path_factory):
    """`run(*args)` → (the `--json` summary, the output directory) of
    `ehactl diagnose ARGS --out DIR --json`, run once per distinct ARGS (compared as strings)
    in the session and asserted to succeed. The directory is shared: read it, never write it."""
    done = {}

    def run(*args, timeout=1800):
        key = tuple(str(a) for a in args)
        if key not in done:
            out = tmp_path_factory.mktemp("diagnosis") / "out"
            r = subprocess.run([BIN, "diagnose", *key, "--out", str(out), "--json"],
                               capture_output=True, text=True, timeout=timeout)
            assert r.returncode == 0, r.stderr
            done[key] = (json.loads(r.stdout), out)
        return done[key]

    return run
