#!/usr/bin/env bash
# Run the whole test suite (what CI runs, .ci/run): formatting and lints, Rust unit +
# integration tests, the aarch64/armv7 cross-builds run under QEMU, Python lint (ruff) and
# the Python tests (MCAP read back by the official Python reader and by @mcap/core under
# Node.js, CLI behaviour, CAN end to end, the Python bindings, the README's examples).
#
# It does not touch your Python: every Python package (test tools, the bindings, Zig and
# cargo-zigbuild for the cross-builds) goes into a virtual environment it creates,
# .venv-test/ in the repository (EHACTL_TEST_VENV=DIR to choose another), reused on the
# next run. System packages it needs are listed first; the only ones it installs itself
# (apt-get, with sudo -n when not root) are those of the QEMU step, and EHACTL_NO_APT=1
# skips that step instead. The quick tier for the edit-test loop: scripts/test_fast.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
# Disk use of the build directory and free space, printed between steps: a CI run once
# failed with "No space left on device" in the cross-builds.
disk() { echo "   disk: target $(du -sh target 2>/dev/null | cut -f1), free $(df -h . | awk 'NR==2 {print $4}')"; }

echo "== what this needs"
command -v cargo >/dev/null || { echo "error: cargo not found: install Rust with rustup (https://rustup.rs)" >&2; exit 1; }
command -v cc >/dev/null || echo "   warning: no C compiler (cc) found: the LZ4 library of the logger needs one (Debian: build-essential)" >&2
command -v python3 >/dev/null || { echo "error: python3 not found: install Python >= 3.9 (Debian: python3 python3-venv)" >&2; exit 1; }
python3 -c 'import sys; sys.exit(sys.version_info < (3, 9))' || { echo "error: $(python3 --version) is older than 3.9" >&2; exit 1; }
echo "   Rust: $(cargo --version); Python: $(python3 --version)"
if command -v node >/dev/null && command -v npm >/dev/null; then
  echo "   Node.js $(node --version): the MCAP cross-check with @mcap/core runs"
else
  echo "   Node.js/npm not found: the @mcap/core cross-check is skipped (Debian: nodejs npm)"
fi
qemu_pkgs=(qemu-user libc6-arm64-cross libgcc-s1-arm64-cross libc6-armhf-cross libgcc-s1-armhf-cross)
missing=()
if command -v dpkg-query >/dev/null; then
  for p in "${qemu_pkgs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
fi
if [ "${EHACTL_NO_APT:-0}" = 1 ]; then
  echo "   EHACTL_NO_APT=1: nothing is installed with apt-get; the QEMU step is skipped"
elif [ ${#missing[@]} -gt 0 ]; then
  echo "   to run the ARM cross-builds under emulation the QEMU step will apt-get install: ${missing[*]}"
  echo "   (EHACTL_NO_APT=1 skips that step instead)"
else
  echo "   system packages for the QEMU step: present"
fi

VENV="${EHACTL_TEST_VENV:-$PWD/.venv-test}"
echo "== Python virtual environment $VENV"
if [ ! -x "$VENV/bin/python" ]; then
  if ! python3 -m venv "$VENV" 2>/tmp/ehactl_venv_err.$$; then
    cat /tmp/ehactl_venv_err.$$ >&2
    rm -rf "$VENV"
    if [ "${EHACTL_NO_APT:-0}" != 1 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
      echo "   python3 -m venv needs the venv module (ensurepip): apt-get install python3-venv"
      { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends python3-venv >/dev/null; } \
        || { echo "error: apt-get install python3-venv failed" >&2; exit 1; }
      python3 -m venv "$VENV"
    else
      echo "error: python3 -m venv failed; install the venv module (Debian/Ubuntu: python3-venv)" >&2
      exit 1
    fi
  fi
  rm -f /tmp/ehactl_venv_err.$$
fi
PY="$VENV/bin/python"
# Everything below (and the scripts it calls: cross_build.sh, qemu_run.sh, the tests'
# subprocesses) finds this environment's python3, pip and console scripts first.
export VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH"
"$PY" -m pip install --quiet --upgrade pip

echo "== formatting and lints (rustfmt, clippy with warnings as errors)"
rustup component add rustfmt clippy >/dev/null 2>&1 || true
cargo fmt --all --check
cargo clippy --release --workspace --all-targets -- -D warnings
echo "== building (release)"
cargo build --release --workspace --all-targets
disk
echo "== SocketCAN transport (feature build; this machine has no AF_CAN, so only compiled)"
cargo build --release -p ehactl-canopen --features socketcan
echo "== Rust tests"
# Property tests (proptest) run a fixed seed here so that a CI result is reproducible; without
# the variable every developer run draws new cases, and the long random runs are in
# BENCHMARKS.md ("Fuzzed parsers").
PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-20261123}" cargo test --release --workspace
disk
echo "== cross-build for aarch64 and armv7 (DEPLOY.md; Zig and cargo-zigbuild into $VENV; skipped with a message if the toolchain cannot be installed)"
CROSS_PRUNE=1 scripts/cross_build.sh aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf
disk
echo "== Python test dependencies and lint (into $VENV)"
# both lists now: tests/python also runs the docs' Python snippets (pandas, Dask, tqdm)
"$PY" -m pip install --quiet -r tests/python/requirements.txt -r bindings/python/requirements-test.txt
"$PY" -m ruff check
if command -v npm >/dev/null; then
  (cd tests/node && { [ -d node_modules ] || npm ci --no-audit --no-fund --silent; })
fi
if [ "${EHACTL_NO_APT:-0}" = 1 ] && [ ${#missing[@]} -gt 0 ]; then
  echo "== QEMU step skipped (EHACTL_NO_APT=1 and missing: ${missing[*]})"
else
  echo "== cross-built binaries run under qemu user-mode emulation (apt: ${qemu_pkgs[*]}; same run as native)"
  scripts/qemu_run.sh aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf
fi
echo "== Python bindings (pyo3 + maturin) with the simulated CANopen devices (python -m ehactl.devices): build, install into $VENV"
"$PY" -m pip install --quiet "./bindings/python[devices]"
echo "== Python tests"
EHACTL_BIN="$PWD/target/release/ehactl" EHACTL_REQUIRE_BINDINGS=1 "$PY" -m pytest tests/python -q
echo "== Python bindings: type check (mypy --strict, config in bindings/python/pyproject.toml)"
(cd bindings/python && "$PY" -m mypy)
echo "== Python bindings (pyo3 + maturin): tests"
EHACTL_BIN="$PWD/target/release/ehactl" PY="$PY" bash -c 'cd bindings/python && "$PY" -m pytest tests -q'
disk
