#!/usr/bin/env bash
# Cross-build the ehactl binary for embedded Linux controllers (DEPLOY.md, "Build"):
#   aarch64-unknown-linux-gnu      64-bit ARM (Raspberry Pi 4/5 64-bit OS, i.MX8, Jetson)
#   armv7-unknown-linux-gnueabihf  32-bit ARM with hard float (BeagleBone, Pi 32-bit OS)
# and for aarch64 the FMU library (target/aarch64-unknown-linux-gnu/release/libehactl_fmu.so)
# with the native FMI host example beside it (release/examples/fmu_host).
# The Rust std for each target comes from rustup; the linker is Zig (PyPI `ziglang`)
# driven by `cargo-zigbuild` (PyPI), so no system cross-gcc is needed; both go into the active
# virtual environment, else into .venv-test/ (created if missing), never the user's Python. Binaries link
# against glibc GLIBC (default 2.31 = Debian 11 / Ubuntu 20.04 or newer on the board).
# Usage: scripts/cross_build.sh [TARGET ...]   (default: both targets)
# Env: GLIBC=2.31, EHACTL_REQUIRE_CROSS=1 to fail (not skip) when the toolchain is missing,
#      CROSS_PRUNE=1 to delete the target's intermediate build files (deps, build scripts,
#      fingerprints; ≈ 0.5 GB per target) once the binary is checked — the binary stays at
#      target/TARGET/release/ehactl (CI sets it: its disk is small; a rebuild then starts cold);
#      EHACTL_SKIP_LOG=FILE: a skip appends its reason there (test_all.sh lists them at its end);
#      CROSS_SETUP_ONLY=1 to install the toolchain (rustup targets, Zig, cargo-zigbuild) and stop,
#      status 3 if it skipped (test_all.sh: before the build, both in the background);
#      CARGO_TARGET_DIR=DIR builds there (default target/): the binaries are DIR/TARGET/release/ehactl;
#      CROSS_DIAGNOSIS=1 builds the full binary (with `diagnose` / `predict`) instead of the
#      controller build (`--no-default-features`, DEPLOY.md §2).
# The controller build leaves the diagnosis crate out (no plotting, FFT or MCAP reading on the
# board); for armv7 that crate is still type-checked (`cargo-zigbuild check`), so code that
# assumes a 64-bit usize fails here as before, at a fraction of a code-generation's cost.
set -euo pipefail
cd "$(dirname "$0")/.."
GLIBC="${GLIBC:-2.31}"
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf)

skip() {
  if [ "${EHACTL_REQUIRE_CROSS:-0}" = 1 ]; then
    echo "cross_build: FAILED: $*" >&2
    exit 1
  fi
  echo "cross_build: SKIPPED: $* (set EHACTL_REQUIRE_CROSS=1 to make this an error)" >&2
  [ -z "${EHACTL_SKIP_LOG:-}" ] || echo "ARM cross-builds (scripts/cross_build.sh): $*" >>"$EHACTL_SKIP_LOG"
  # CROSS_SETUP_ONLY: status 3 tells the caller there is nothing to build (the skip is logged).
  [ "${CROSS_SETUP_ONLY:-0}" != 1 ] || exit 3
  exit 0
}

command -v rustup >/dev/null || skip "rustup not found: the target std libraries come from rustup"
for t in "${targets[@]}"; do
  rustup target add "$t" >/dev/null 2>&1 || skip "rustup target add $t failed (no access to static.rust-lang.org?)"
done
if [ -z "${VIRTUAL_ENV:-}" ]; then
  # Not inside a virtual environment: use the test suite's (.venv-test, as scripts/test_all.sh)
  # so that Zig and cargo-zigbuild never go into the user's own Python.
  venv="${EHACTL_TEST_VENV:-$PWD/.venv-test}"
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv" || skip "python3 -m venv $venv failed (Debian: python3-venv)"
  export VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH"
fi
if ! command -v cargo-zigbuild >/dev/null || ! python3 -m ziglang version >/dev/null 2>&1; then
  echo "== installing Zig (PyPI ziglang) and cargo-zigbuild into $VIRTUAL_ENV: the cross linker"
  python3 -m pip install --quiet ziglang cargo-zigbuild || skip "pip install ziglang cargo-zigbuild failed"
fi
command -v cargo-zigbuild >/dev/null || skip "cargo-zigbuild not on PATH after pip install"
[ "${CROSS_SETUP_ONLY:-0}" != 1 ] || exit 0
tdir="${CARGO_TARGET_DIR:-target}"

# One cargo invocation for all targets: cargo schedules their crates together (a core left
# idle by one target's long crate compiles the other's), and the build scripts and proc macros,
# which run on this machine, are compiled once for all of them.
target_args=()
for t in "${targets[@]}"; do target_args+=(--target "$t.$GLIBC"); done
features=(--no-default-features)
what="controller build, no diagnosis"
if [ "${CROSS_DIAGNOSIS:-0}" = 1 ]; then features=(); what="full build, with the diagnosis"; fi
echo "== cross-building ehactl for ${targets[*]} (glibc $GLIBC; $what)"
cargo zigbuild --release -p ehactl-cli "${features[@]}" "${target_args[@]}"
# The FMU library for the board (`ehactl export-fmu --aarch64-binary`, docs/fmu.md) and the
# native FMI host that runs it under QEMU (crates/fmu/examples/fmu_host.rs, scripts/qemu_run.sh):
# aarch64 only, the platform FMUs name (FMI 3.0's `aarch64-linux`).
for t in "${targets[@]}"; do
  case "$t" in
    aarch64-*)
      echo "== cross-building the FMU library and its native host for $t"
      cargo zigbuild --release -p ehactl-fmu --lib --example fmu_host --target "$t.$GLIBC" ;;
  esac
done
if [ "${CROSS_DIAGNOSIS:-0}" != 1 ]; then
  for t in "${targets[@]}"; do
    case "$t" in
      armv7-*)
        echo "== type-checking the diagnosis crate (ehactl-ident) for $t (32-bit usize)"
        # `cargo-zigbuild check`, not `cargo zigbuild check` (no such cargo subcommand form).
        cargo-zigbuild check --release -p ehactl-ident --target "$t.$GLIBC" ;;
    esac
  done
fi
for t in "${targets[@]}"; do
  bin="$tdir/$t/release/ehactl"
  # Check the result is an ELF executable for the right machine (e_machine field).
  python3 - "$bin" "$t" <<'PY'
import struct, sys
path, target = sys.argv[1], sys.argv[2]
raw = open(path, "rb").read(64)
assert raw[:4] == b"\x7fELF", f"{path}: not an ELF file"
machine = struct.unpack_from("<H", raw, 18)[0]
want = {"aarch64": (0xB7, 2), "armv7": (0x28, 1)}[target.split("-")[0]]
assert (machine, raw[4]) == want, f"{path}: e_machine {machine:#x}, class {raw[4]}, expected {want}"
print(f"{path}: ELF {'64' if raw[4] == 2 else '32'}-bit, e_machine {machine:#x} ({target}) ok")
PY
  if [ "${CROSS_PRUNE:-0}" = 1 ]; then
    rm -rf "$tdir/$t/release/deps" "$tdir/$t/release/build" "$tdir/$t/release/.fingerprint" \
      "$tdir/$t/release/incremental"
  fi
done
# A build directory of its own (test_all.sh: target/cross) also holds the cross-build's host
# tools (build scripts, proc macros) in DIR/release: pruned too. Never the repository's
# target/release, which the native build and the tests use.
if [ "${CROSS_PRUNE:-0}" = 1 ] && [ "$(realpath -m "$tdir")" != "$(realpath -m target)" ]; then
  rm -rf "$tdir/release"
fi
