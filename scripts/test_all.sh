#!/usr/bin/env bash
# Run the whole test suite: Rust unit + integration tests, then the Python tests (MCAP
# read back by the official Python reader and by @mcap/core under Node.js, CLI behaviour).
# Installs what it needs itself.
set -euo pipefail
cd "$(dirname "$0")/.."
echo "== building (release)"
cargo build --release --workspace --all-targets
echo "== Rust tests"
cargo test --release --workspace
echo "== Python test dependencies"
python3 -m pip install --quiet -r tests/python/requirements.txt
if command -v npm >/dev/null; then
  (cd tests/node && { [ -d node_modules ] || npm ci --no-audit --no-fund --silent; })
fi
echo "== Python tests"
EHACTL_BIN="$PWD/target/release/ehactl" python3 -m pytest tests/python -q
echo "== Python bindings (pyo3 + maturin): build, install, test"
python3 -m pip install --quiet -r bindings/python/requirements-test.txt
python3 -m pip install --quiet ./bindings/python
EHACTL_BIN="$PWD/target/release/ehactl" bash -c 'cd bindings/python && python3 -m pytest tests -q'
