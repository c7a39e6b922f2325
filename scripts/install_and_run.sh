#!/usr/bin/env bash
# Install what ehactl needs and run the main job: a closed-loop run of the default config
# (seed 004 force loop) against the simulated plant, logged to out/sahu2022_force.mcap.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo >/dev/null || { echo "error: cargo (Rust toolchain) not found; install it from rustup first" >&2; exit 1; }
cargo build --release -p ehactl-cli
python3 -m pip install --quiet -r tests/python/requirements.txt || echo "warning: Python packages not installed (only needed for tests and plots)" >&2
exec ./target/release/ehactl run configs/sahu2022_force.toml "$@"
