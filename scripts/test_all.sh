#!/usr/bin/env bash
# Run the whole test suite (what CI runs, .ci/run): formatting and lints, Rust unit +
# integration tests, the aarch64/armv7 cross-builds run under QEMU, Python lint (ruff) and
# the Python tests (MCAP read back by the official Python reader and by @mcap/core under
# Node.js, CLI behaviour, CAN end to end, the Python bindings, the README's examples).
#
# It does not touch your Python: every Python package (test tools, the bindings, Zig and
# cargo-zigbuild for the cross-builds) goes into a virtual environment it creates,
# .venv-test/ in the repository (EHACTL_TEST_VENV=DIR to choose another), reused on the
# next run. Outside the repository it adds the two rustup targets of the cross-builds and
# the caches of Zig, cargo-zigbuild, npm and matplotlib (README, "What the scripts install").
# System packages it needs are listed first. It installs system packages (apt-get, with
# sudo -n when not root: those of the QEMU step, and python3-venv if missing) only with
# consent: EHACTL_APT=1, or a yes to the question it asks at the start when run from a
# terminal; otherwise that step is skipped, and the suite's last lines say so. Everything
# it skipped is listed at its very end, with the reason. One build serves every step: the
# CLI, the tests and the bindings resolve the same features (crates/feature-unify).
# The quick tier for the edit-test loop: scripts/test_fast.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$(date +%s)
# Steps that could not run append "step: reason" here (cross_build.sh and qemu_run.sh too);
# the exit trap prints them last, in capitals, whether the suite passed or failed.
EHACTL_SKIP_LOG="$(mktemp)"
counts="$(mktemp)"
export EHACTL_SKIP_LOG
skipped() { echo "$*" >>"$EHACTL_SKIP_LOG"; echo "   SKIPPED: $*"; }
finish() {
  rc=$?
  echo
  if [ $rc = 0 ]; then
    echo "== the whole suite passed in $(( $(date +%s) - t0 )) s"
  else
    echo "== the suite FAILED (exit $rc) after $(( $(date +%s) - t0 )) s"
  fi
  [ ! -s "$counts" ] || sed 's/^/   /' "$counts"
  if [ -s "$EHACTL_SKIP_LOG" ]; then
    echo "################################################################################"
    echo "## NOT EVERYTHING WAS CHECKED: these steps were SKIPPED"
    sed 's/^/##   /' "$EHACTL_SKIP_LOG"
    echo "################################################################################"
  fi
  rm -f "$EHACTL_SKIP_LOG" "$counts" "$counts".*
}
trap finish EXIT
# A step's heading with the time since the start, so that a run shows where its minutes go.
step() { echo "== [$(( $(date +%s) - t0 )) s] $*"; }
# Disk use of the build directory and free space, printed between steps: a CI run once
# failed with "No space left on device" in the cross-builds.
disk() { echo "   disk: target $(du -sh target 2>/dev/null | cut -f1), free $(df -h . | awk 'NR==2 {print $4}')"; }

step "what this needs"
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
# May this run install system packages with apt-get? EHACTL_APT=1 yes, EHACTL_APT=0 (or the
# older EHACTL_NO_APT=1) no; unset: ask when run from a terminal, else no. CI says yes
# (.ci/run: the project's own machine).
apt_ok() {
  case "${EHACTL_APT:-}" in
    1) return 0 ;;
    0) return 1 ;;
  esac
  [ "${EHACTL_NO_APT:-0}" != 1 ] || return 1
  [ -t 0 ] && [ -t 1 ] || return 1
  local answer
  read -r -p "   install them now with apt-get$([ "$(id -u)" = 0 ] || echo " (sudo)")? [y/N] " answer
  [ "$answer" = y ] || [ "$answer" = Y ] || [ "$answer" = yes ]
}
if [ ${#missing[@]} -gt 0 ]; then
  echo "   the QEMU step (ARM cross-builds run under emulation) needs, from apt-get: ${missing[*]}"
  if apt_ok; then
    EHACTL_APT=1
    echo "   EHACTL_APT=1: the QEMU step installs them"
  else
    EHACTL_APT=0
    echo "   not installing them (EHACTL_APT=1 allows it): the QEMU step will be skipped"
  fi
else
  echo "   system packages for the QEMU step: present"
  EHACTL_APT="${EHACTL_APT:-0}"
fi
export EHACTL_APT

VENV="${EHACTL_TEST_VENV:-$PWD/.venv-test}"
step "Python virtual environment $VENV"
if [ ! -x "$VENV/bin/python" ]; then
  if ! python3 -m venv "$VENV" 2>/tmp/ehactl_venv_err.$$; then
    cat /tmp/ehactl_venv_err.$$ >&2
    rm -rf "$VENV"
    if [ "$EHACTL_APT" = 1 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
      echo "   python3 -m venv needs the venv module (ensurepip): apt-get install python3-venv"
      { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends python3-venv >/dev/null; } \
        || { echo "error: apt-get install python3-venv failed" >&2; exit 1; }
      python3 -m venv "$VENV"
    else
      echo "error: python3 -m venv failed; install the venv module (Debian/Ubuntu: python3-venv; as root with EHACTL_APT=1 the suite installs it)" >&2
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

step "formatting and lints (rustfmt, clippy with warnings as errors)"
rustup component add rustfmt clippy >/dev/null 2>&1 || true
cargo fmt --all --check
cargo clippy --release --workspace --all-targets -- -D warnings
# The SocketCAN transport (this machine has no AF_CAN, so it is only compiled): checked by
# clippy with the feature on, over the whole workspace so that every other crate keeps its
# features and the check reuses the step above (a `-p ehactl-canopen` build recompiled the
# plant and the logger with another feature set).
step "SocketCAN transport (clippy with --features ehactl-canopen/socketcan)"
cargo clippy --release --workspace --all-targets --features ehactl-canopen/socketcan -- -D warnings
step "building (release): every target once; the tests, the QEMU step and the bindings reuse it"
# The Python extension's crate is built once, by maturin below (its pyo3 build script depends
# on maturin's environment, so a cargo build of it here would be redone there); clippy above
# checked it, and it has no Rust tests.
cargo build --release --workspace --exclude ehactl-python --all-targets
disk
step "Rust tests"
# Property tests (proptest) run a fixed seed here so that a CI result is reproducible; without
# the variable every developer run draws new cases, and the long random runs are in
# BENCHMARKS.md ("Fuzzed parsers").
PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-20261123}" cargo test --release --workspace --exclude ehactl-python 2>&1 | tee "$counts.rust"
awk '/^test result:/ {p += $4; f += $6; i += $8; n++} END {printf "Rust: %d tests passed, %d ignored (%d test binaries and doc-test runs)\n", p, i, n}' "$counts.rust" >>"$counts"
rm -f "$counts.rust"
disk
step "cross-build for aarch64 and armv7 (DEPLOY.md; Zig and cargo-zigbuild into $VENV; skipped with a message if the toolchain cannot be installed)"
CROSS_PRUNE=1 scripts/cross_build.sh aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf
disk
step "Python test dependencies and lint (into $VENV)"
# both lists now: tests/python also runs the docs' Python snippets (pandas, Dask, tqdm)
"$PY" -m pip install --quiet -r tests/python/requirements.txt -r bindings/python/requirements-test.txt
"$PY" -m ruff check
if command -v npm >/dev/null; then
  (cd tests/node && { [ -d node_modules ] || npm ci --no-audit --no-fund --silent; })
fi
step "cross-built binaries run under qemu user-mode emulation (apt: ${qemu_pkgs[*]}; same run as native)"
scripts/qemu_run.sh aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf
step "Python bindings (pyo3 + maturin) with the simulated CANopen devices (python -m ehactl.devices): build, install into $VENV"
"$PY" -m pip install --quiet "./bindings/python[devices]"
step "Python tests"
EHACTL_BIN="$PWD/target/release/ehactl" EHACTL_REQUIRE_BINDINGS=1 "$PY" -m pytest tests/python -q -rs 2>&1 | tee "$counts.py"
echo "Python (tests/python): $(tail -n 1 "$counts.py" | tr -d '=')" >>"$counts"
step "Python bindings: type check (mypy --strict, config in bindings/python/pyproject.toml)"
(cd bindings/python && "$PY" -m mypy)
step "Python bindings (pyo3 + maturin): tests"
EHACTL_BIN="$PWD/target/release/ehactl" PY="$PY" bash -c 'cd bindings/python && "$PY" -m pytest tests -q -rs' 2>&1 | tee "$counts.py"
echo "Python (bindings/python/tests): $(tail -n 1 "$counts.py" | tr -d '=')" >>"$counts"
rm -f "$counts.py"
disk
