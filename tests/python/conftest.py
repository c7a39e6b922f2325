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


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist with `--dist loadgroup` (scripts/test_fast.sh runs `-n 2`): each
    module's tests on one worker, so that its module-scoped fixtures run once; and every
    module that asks for the session's `diagnosis` (directly or through a fixture of its own)
    on one worker together, so that each distinct diagnosis runs once, as without xdist.
    Without xdist the marks change nothing."""
    if getattr(config.option, "dist", "no") == "no":
        return
    shared = {item.module.__name__ for item in items if "diagnosis" in item.fixturenames}
    for item in items:
        name = item.module.__name__
        item.add_marker(pytest.mark.xdist_group("diagnosis" if name in shared else name))
