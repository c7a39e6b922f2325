#!/usr/bin/env bash
# Run the whole test suite: Rust unit + integration tests, then the Python tests (MCAP
# read back by the official Python reader and by @mcap/core under Node.js, CLI behaviour).
# Installs what it needs itself.
set -euo pipefail
cd "$(dirname "$0")/.."
# Disk use of the build directory and free space, printed between steps: a CI run once
# failed with "No space left on device" in the cross-builds.
disk() { echo "   disk: target $(du -sh target 2>/dev/null | cut -f1), free $(df -h . | awk 'NR==2 {print $4}')"; }
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
echo "== cross-build for aarch64 and armv7 (DEPLOY.md; skipped with a message if the toolchain cannot be installed)"
CROSS_PRUNE=1 scripts/cross_build.sh aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf
disk
echo "== Python test dependencies"
python3 -m pip install --quiet -r tests/python/requirements.txt
if command -v npm >/dev/null; then
  (cd tests/node && { [ -d node_modules ] || npm ci --no-audit --no-fund --silent; })
fi
echo "== cross-built binaries run under qemu user-mode emulation (apt: qemu-user, libc6-arm64-cross, libc6-armhf-cross; same run as native)"
scripts/qemu_run.sh aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf
echo "== Python bindings for the simulated CANopen devices (python -m ehactl.devices)"
python3 -m pip install --quiet "./bindings/python[devices]"
echo "== Python tests"
EHACTL_BIN="$PWD/target/release/ehactl" EHACTL_REQUIRE_BINDINGS=1 python3 -m pytest tests/python -q
echo "== Python bindings (pyo3 + maturin): build, install, test"
python3 -m pip install --quiet -r bindings/python/requirements-test.txt
python3 -m pip install --quiet ./bindings/python
echo "== Python bindings: type check (mypy --strict, config in bindings/python/pyproject.toml)"
(cd bindings/python && python3 -m mypy)
EHACTL_BIN="$PWD/target/release/ehactl" bash -c 'cd bindings/python && python3 -m pytest tests -q'
disk
