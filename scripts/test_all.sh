#!/usr/bin/env bash
# Run the whole test suite (what CI runs, .ci/run): formatting and lints, the API docs
# (cargo doc, rustdoc warnings as errors), Rust unit + integration tests, the aarch64/armv7
# cross-builds run under QEMU, Python lint (ruff) and the Python tests (MCAP read back by the
# official Python reader and by @mcap/core under Node.js, CLI behaviour, CAN end to end, the
# Python bindings, the README's examples).
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
  # A suite that stops early stops its background cross-build too (its own process group).
  if [ -n "${cross_pid:-}" ] && kill -0 "$cross_pid" 2>/dev/null; then
    kill -- -"$cross_pid" 2>/dev/null || kill "$cross_pid" 2>/dev/null || true
    echo "   (the background cross-build was stopped; its output so far:)"
    sed 's/^/   /' "$cross_log"
  fi
  # The other background jobs: the pip/npm one is stopped; an apt-get one is waited for
  # (stopping apt-get in the middle of an install can leave dpkg half-configured).
  if [ -n "${bg_pid[pydeps]:-}" ]; then
    pkill -P "${bg_pid[pydeps]}" 2>/dev/null || true
    kill "${bg_pid[pydeps]}" 2>/dev/null || true
  fi
  if [ -n "${bg_pid[qemu_apt]:-}" ]; then wait "${bg_pid[qemu_apt]}" 2>/dev/null || true; fi
  rm -f "$EHACTL_SKIP_LOG" "$counts" "$counts".* "${cross_log:-}" "${cross_ready:-}" "${bg_log[@]}"
}
# Steps that only wait for the network (apt-get, pip, npm) run in the background beside the
# builds: `background NAME CMD…` starts one (its output into a file), `await NAME` waits for
# it, prints that output and fails the suite if it failed.
declare -A bg_pid=() bg_log=()
background() {
  local name=$1; shift
  bg_log[$name]="$(mktemp)"
  "$@" >"${bg_log[$name]}" 2>&1 </dev/null &
  bg_pid[$name]=$!
}
await() {
  local name=$1 rc=0
  [ -n "${bg_pid[$name]:-}" ] || return 0
  wait "${bg_pid[$name]}" || rc=$?
  bg_pid[$name]=""
  sed 's/^/   /' "${bg_log[$name]}"
  return $rc
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
# The ARM targets of the cross-builds (and their QEMU runs).
cross_targets=(aarch64-unknown-linux-gnu armv7-unknown-linux-gnueabihf)
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

# The ARM cross-builds (DEPLOY.md) run in the background from here, at the lowest CPU priority
# (nice 19) and in a build directory of their own (target/cross: cargo locks a build
# directory, and the tests use target/release meanwhile): they take the CPU the foreground
# steps leave idle (a test waiting on a subprocess, a single-threaded link) instead of a
# step of their own (5 min 40 s on an idle 2-core machine when they ran alone). Their output
# is printed in one piece when the foreground is done; the QEMU step runs after them.
# rustup is not safe to run twice at once on one toolchain: the foreground's components first.
rustup component add rustfmt clippy >/dev/null 2>&1 || true
cross_log="$(mktemp)"
cross_ready="$cross_log.ready"
export EHACTL_T0="$t0" CROSS_LOG="$cross_log" CROSS_READY="$cross_ready"
# setsid: its own process group, so that a failing suite stops the whole build (exit trap).
own_group=(setsid)
command -v setsid >/dev/null || own_group=()
"${own_group[@]}" bash -c '
  set -uo pipefail
  # setsid made a new session, which Linux schedules as its own group (autogroup) at equal
  # share with the suite: nice 19 would then act only inside it. The group itself goes to 19.
  { [ -w /proc/self/autogroup ] && echo 19 >/proc/self/autogroup; } 2>/dev/null || true
  echo "== [$(( $(date +%s) - EHACTL_T0 )) s] cross-build toolchain (rustup targets; Zig and cargo-zigbuild into $VIRTUAL_ENV)"
  CROSS_SETUP_ONLY=1 scripts/cross_build.sh "$@"; rc=$?
  touch "$CROSS_READY"
  [ $rc = 3 ] && exit 0
  [ $rc = 0 ] || exit $rc
  echo "== [$(( $(date +%s) - EHACTL_T0 )) s] cross-build starts (nice 19, CARGO_TARGET_DIR=target/cross)"
  CARGO_TARGET_DIR=target/cross CROSS_PRUNE=1 nice -n 19 scripts/cross_build.sh "$@" || exit $?
  echo "== [$(( $(date +%s) - EHACTL_T0 )) s] cross-build done"
' cross_build "${cross_targets[@]}" >"$cross_log" 2>&1 </dev/null &
cross_pid=$!
# QEMU and the ARM C libraries (apt-get, when allowed above) are installed now, beside the
# builds; the QEMU step at the end waits for it (and, if it failed, tries once more and says
# what it skipped).
if [ ${#missing[@]} -gt 0 ] && [ "$EHACTL_APT" = 1 ]; then
  step "installing ${missing[*]} with apt-get, in the background"
  background qemu_apt env QEMU_INSTALL_ONLY=1 scripts/qemu_run.sh "${cross_targets[@]}"
fi
# The Python test dependencies (pip, npm) in the background too, once the cross-build's
# toolchain install is done with the environment: never two pip runs in one at once.
python_test_deps() {
  while [ ! -e "$cross_ready" ] && kill -0 "$cross_pid" 2>/dev/null; do sleep 1; done
  # both lists: tests/python also runs the docs' Python snippets (pandas, Dask, tqdm)
  "$PY" -m pip install --quiet -r tests/python/requirements.txt \
    -r bindings/python/requirements-test.txt || return 1
  if command -v npm >/dev/null; then
    (cd tests/node && { [ -d node_modules ] || npm ci --no-audit --no-fund --silent; }) || return 1
  fi
}
background pydeps python_test_deps

step "formatting and lints (rustfmt, clippy with warnings as errors)"
cargo fmt --all --check
cargo clippy --release --workspace --all-targets -- -D warnings
# The SocketCAN transport (this machine has no AF_CAN, so it is only compiled): checked by
# clippy with the feature on, over the whole workspace so that every other crate keeps its
# features and the check reuses the step above (a `-p ehactl-canopen` build recompiled the
# plant and the logger with another feature set).
# The feature changes only the library of ehactl-canopen (crates/canopen/src/socketcan_bus.rs),
# so the libraries are enough (--lib): the crates that use it are checked again against it,
# their tests, examples and benchmarks, which the feature does not change, are not.
step "SocketCAN transport (clippy with --features ehactl-canopen/socketcan)"
cargo clippy --release --workspace --lib --bins --features ehactl-canopen/socketcan -- -D warnings
# Broken links, links from public docs to private items, ambiguous links and stray HTML in doc
# comments fail here. `cargo doc` compiles no machine code: it type-checks the workspace's
# crates again (the dependencies' metadata of the clippy steps is reused) and runs rustdoc on
# them (the binary's with its private items, as cargo does for binaries). The Python
# extension's crate is documented too: that needs no maturin. It took 11 s after
# `touch crates/plant/src/model.rs` and 30 s after a touch of crates/types (2026-12-03, on a
# warm target/release, with another build beside it); 0.3 s when nothing changed.
step "API documentation (cargo doc, rustdoc warnings as errors)"
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --release --workspace --no-deps
step "building (release): the libraries, binaries and tests, once; the tests, the QEMU step and the bindings reuse it"
# The Python extension's crate is built once, by maturin below (its pyo3 build script depends
# on maturin's environment, so a cargo build of it here would be redone there); clippy above
# checked it, and it has no Rust tests. Neither the benchmarks (criterion) nor the examples
# (the evaluations, profilers and figure generators of BENCHMARKS.md, DIAGNOSIS.md and
# REPRODUCTION.md, each documented with its command) are compiled to machine code: clippy
# checked them, and no test runs them. The tests below select the same targets; the doc
# tests run after them when the sources have any (scripts/doc_tests.py finds the Rust code
# blocks of doc comments; today's snippets are all `text` or `toml`).
cargo build --release --workspace --exclude ehactl-python --lib --bins --tests
disk
step "Rust tests"
# Property tests (proptest) run a fixed seed here so that a CI result is reproducible; without
# the variable every developer run draws new cases, and the long random runs are in
# BENCHMARKS.md ("Fuzzed parsers").
PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-20261123}" cargo test --release --workspace --exclude ehactl-python --lib --bins --tests 2>&1 | tee "$counts.rust"
if "$PY" scripts/doc_tests.py; then
  step "Rust doc tests"
  cargo test --release --workspace --exclude ehactl-python --doc 2>&1 | tee -a "$counts.rust"
fi
awk '/^test result:/ {p += $4; f += $6; i += $8; n++} END {printf "Rust: %d tests passed, %d ignored (%d test binaries, doc tests included when there are any)\n", p, i, n}' "$counts.rust" >>"$counts"
rm -f "$counts.rust"
disk
step "Python test dependencies and lint (into $VENV)"
await pydeps || { echo "error: installing the Python test dependencies failed (output above)" >&2; exit 1; }
"$PY" -m ruff check
step "Python bindings (pyo3 + maturin) with the simulated CANopen devices (python -m ehactl.devices): build, install into $VENV"
"$PY" -m pip install --quiet "./bindings/python[devices]"
step "Python tests"
EHACTL_BIN="$PWD/target/release/ehactl" EHACTL_REQUIRE_BINDINGS=1 "$PY" -m pytest tests/python -q -rs --durations=15 2>&1 | tee "$counts.py"
echo "Python (tests/python): $(tail -n 1 "$counts.py" | tr -d '=')" >>"$counts"
step "Python bindings: type check (mypy --strict, config in bindings/python/pyproject.toml)"
(cd bindings/python && "$PY" -m mypy)
step "Python bindings (pyo3 + maturin): tests"
EHACTL_BIN="$PWD/target/release/ehactl" PY="$PY" bash -c 'cd bindings/python && "$PY" -m pytest tests -q -rs' 2>&1 | tee "$counts.py"
echo "Python (bindings/python/tests): $(tail -n 1 "$counts.py" | tr -d '=')" >>"$counts"
rm -f "$counts.py"
step "cross-build for aarch64 and armv7 (DEPLOY.md; in the background since the start; skipped with a message if the toolchain cannot be installed)"
cross_rc=0
wait "$cross_pid" || cross_rc=$?
cross_pid=""
sed 's/^/   /' "$cross_log"
[ $cross_rc = 0 ] || { echo "error: the cross-build failed (exit $cross_rc), its output is above" >&2; exit 1; }
disk
step "cross-built binaries run under qemu user-mode emulation (apt: ${qemu_pkgs[*]}; same run as native)"
await qemu_apt || echo "   the background apt-get install failed (above): the QEMU step tries once more"
# The native FMI host the QEMU step compares the aarch64 FMU with (crates/fmu/examples/fmu_host.rs).
cargo build --release -p ehactl-fmu --example fmu_host
CARGO_TARGET_DIR=target/cross scripts/qemu_run.sh "${cross_targets[@]}"
