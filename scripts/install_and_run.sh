#!/usr/bin/env bash
# Install ehactl and run the main job:
#   1. the `ehactl` binary with `cargo install --path crates/cli --locked --target-dir target`
#      (into $CARGO_HOME/bin, normally ~/.cargo/bin, which rustup puts on PATH). The build goes
#      to the repository's target/ (or $CARGO_TARGET_DIR), not to a temporary directory, so
#      that step 2 reuses it;
#   1b. the FMU library `libehactl_fmu.so` that `ehactl export-fmu` packs into every FMU
#      (`cargo build --release -p ehactl-fmu`, same target/), copied to ../lib/ehactl/ from
#      that bin directory, where `ehactl export-fmu` looks for it (docs/fmu.md);
#   2. the Python package `ehactl` with the extras a user needs (pandas, matplotlib, tqdm,
#      Dask distributed; python-can and canopen for the simulated CAN devices) —
#      `pip install -v "./bindings/python[all,devices]"`, a pyo3 extension built by maturin in
#      the same target/ with the same features (crates/feature-unify), so it compiles only the
#      extension's own crates (pyo3, numpy, the bindings) —
#      into the virtual environment you have active, else into .venv/ in the repository
#      (created if missing, reused otherwise; `source .venv/bin/activate` to use it), never
#      into the system's Python;
#   3. a closed-loop run of the default config (the Sahu 2022 force loop) against the
#      simulated plant, logged to out/sahu2022_force.mcap. Extra arguments go to `ehactl run`.
# Cargo and pip print their own progress (no --quiet): `pip -v` shows maturin's cargo lines.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo >/dev/null || { echo "error: cargo (Rust toolchain) not found; install it from rustup first" >&2; exit 1; }
command -v python3 >/dev/null || { echo "error: python3 not found; install Python >= 3.9 first" >&2; exit 1; }
python3 -c 'import sys; sys.exit(sys.version_info < (3, 9))' || { echo "error: $(python3 --version) is older than 3.9" >&2; exit 1; }
target_dir="${CARGO_TARGET_DIR:-$PWD/target}"
echo "== building and installing the ehactl binary (cargo install --path crates/cli --locked --target-dir $target_dir)"
cargo install --path crates/cli --locked --target-dir "$target_dir"
bin_dir="${CARGO_INSTALL_ROOT:-${CARGO_HOME:-$HOME/.cargo}}/bin"
echo "== building the FMU library (cargo build --release --locked -p ehactl-fmu --target-dir $target_dir) for ehactl export-fmu"
cargo build --release --locked -p ehactl-fmu --target-dir "$target_dir"
mkdir -p "$bin_dir/../lib/ehactl"
cp "$target_dir/release/libehactl_fmu.so" "$bin_dir/../lib/ehactl/libehactl_fmu.so"
if [ -n "${VIRTUAL_ENV:-}" ]; then
  venv="$VIRTUAL_ENV"
  echo "== using the active virtual environment $venv"
else
  venv="$PWD/.venv"
  if [ ! -x "$venv/bin/python" ]; then
    echo "== creating the virtual environment $venv (python3 -m venv)"
    python3 -m venv "$venv" || { echo "error: python3 -m venv failed; install the venv module (Debian/Ubuntu: python3-venv)" >&2; exit 1; }
  fi
fi
echo "== installing the Python package ehactl with its extras into $venv (pip install -v './bindings/python[all,devices]'; maturin builds the extension in $target_dir, reusing the build above)"
CARGO_TARGET_DIR="$target_dir" "$venv/bin/python" -m pip install -v "./bindings/python[all,devices]"
if [ "$(command -v ehactl || true)" != "$bin_dir/ehactl" ]; then
  echo "note: $bin_dir is not first on PATH; add it, e.g. to ~/.bashrc:" >&2
  echo "      export PATH=\"$bin_dir:\$PATH\"" >&2
fi
[ "${VIRTUAL_ENV:-}" = "$venv" ] || echo "note: the Python package is in $venv: 'source $venv/bin/activate' to import ehactl" >&2
echo "== $bin_dir/ehactl run configs/sahu2022_force.toml $*"
exec "$bin_dir/ehactl" run configs/sahu2022_force.toml "$@"
