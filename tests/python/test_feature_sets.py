"""One compilation for the CLI, the Python extension and the workspace: `cargo build -p
ehactl-cli` (scripts/install_and_run.sh, scripts/test_fast.sh), maturin's build of
bindings/python and `cargo build --workspace` (scripts/test_all.sh) must resolve the same
features for every package they share, or each command recompiles the plant and every crate
above it (crates/feature-unify/Cargo.toml says how they are kept equal). Read from `cargo tree`,
no compilation.

EHACTL_ROOT selects another checkout (default: this repository).
"""
import os
import pathlib
import shutil
import subprocess

import pytest

ROOT = pathlib.Path(os.environ.get("EHACTL_ROOT", pathlib.Path(__file__).resolve().parents[2]))

pytestmark = pytest.mark.skipif(shutil.which("cargo") is None, reason="needs cargo")


def feature_sets(*select):
    """{package: {feature set, ...}} of the normal and build graph (a package built for the
    host and for the target may appear with two sets)."""
    out = subprocess.run(
        ["cargo", "tree", "--offline", *select, "-e", "normal,build", "--prefix", "none",
         "-f", "{p}|{f}"],
        cwd=ROOT, capture_output=True, text=True, check=True,
    ).stdout
    sets = {}
    for line in out.splitlines():
        if "|" not in line:
            continue
        pkg, feats = line.split("|", 1)
        pkg = pkg.split(" (")[0]  # drop "(/path)" and "(proc-macro)"
        sets.setdefault(pkg, set()).add(feats.replace(" (*)", "").strip())
    return sets


def differences(a, b):
    return {p: (sorted(a[p]), sorted(b[p])) for p in a.keys() & b.keys() if a[p] != b[p]}


@pytest.fixture(scope="module")
def resolved():
    return {
        "cli": feature_sets("-p", "ehactl-cli"),
        "bindings": feature_sets("-p", "ehactl-python"),
        "workspace": feature_sets("--workspace"),
    }


@pytest.mark.parametrize("a,b", [("cli", "bindings"), ("cli", "workspace"),
                                 ("bindings", "workspace")])
def test_shared_packages_have_one_feature_set(resolved, a, b):
    assert differences(resolved[a], resolved[b]) == {}
