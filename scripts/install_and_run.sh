#!/usr/bin/env bash
# Install ehactl and run the main job:
#   1. the `ehactl` binary with `cargo install --path crates/cli --locked` (into
#      $CARGO_HOME/bin, normally ~/.cargo/bin, which rustup puts on PATH);
#   2. the Python package `ehactl` with the extras a user needs (pandas, matplotlib, tqdm,
#      Dask distributed; python-can and canopen for the simulated CAN devices) —
#      `pip install "./bindings/python[all,devices]"`, a pyo3 extension built by maturin;
#   3. a closed-loop run of the default config (Sahu 2022 force loop) against the simulated
#      plant, logged to out/sahu2022_force.mcap. Extra arguments go to `ehactl run`.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo >/dev/null || { echo "error: cargo (Rust toolchain) not found; install it from rustup first" >&2; exit 1; }
command -v python3 >/dev/null || { echo "error: python3 not found; install Python >= 3.9 first" >&2; exit 1; }
echo "== installing the ehactl binary (cargo install --path crates/cli --locked)"
cargo install --quiet --path crates/cli --locked
bin_dir="${CARGO_INSTALL_ROOT:-${CARGO_HOME:-$HOME/.cargo}}/bin"
echo "== installing the Python package ehactl with its extras (pip install './bindings/python[all,devices]')"
python3 -m pip install --quiet "./bindings/python[all,devices]"
if [ "$(command -v ehactl || true)" != "$bin_dir/ehactl" ]; then
  echo "note: $bin_dir is not first on PATH; add it, e.g. to ~/.bashrc:" >&2
  echo "      export PATH=\"$bin_dir:\$PATH\"" >&2
fi
echo "== $bin_dir/ehactl run configs/sahu2022_force.toml $*"
exec "$bin_dir/ehactl" run configs/sahu2022_force.toml "$@"
