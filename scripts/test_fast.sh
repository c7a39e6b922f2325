#!/usr/bin/env bash
# The quick test tier for the edit-test loop (the full suite, what CI runs, is
# scripts/test_all.sh). Runs: the check for file-level import circles (scripts/file_cycles.py),
# rustfmt and clippy (warnings as errors), ruff, the API docs (cargo doc, rustdoc warnings as
# errors), the Rust unit and integration tests except the diagnosis' long evaluation tests
# (crates/ident-eval/tests/: the catalogue in hidden_effects.rs and indep_generator.rs,
# false_none.rs, force_loop.rs, …; its data_errors.rs and data_units.rs run), and the Python
# tests that need neither a CAN bus, the diagnosis catalogue nor the compiled Python bindings.
# No cross-builds, no QEMU, no apt-get.
# Python tools go into .venv-test/ (EHACTL_TEST_VENV=DIR to choose another), as in test_all.sh.
# Extra arguments go to every `cargo test`, e.g. `scripts/test_fast.sh -- --test-threads 1`.
# It builds with the `fast` profile (Cargo.toml: release code, incremental) into target/fast/,
# apart from the suite's target/release/: after an edit only what the edit reaches is rebuilt.
# The Python tests run on two pytest-xdist workers beside the API docs and the Rust tests, once
# the CLI and the FMU they drive are built (their output is printed after the Rust tests; the
# tier fails if either fails).
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$(date +%s)

VENV="${EHACTL_TEST_VENV:-$PWD/.venv-test}"
if [ ! -x "$VENV/bin/python" ]; then
  echo "== creating $VENV (python3 -m venv; Debian needs python3-venv)"
  python3 -m venv "$VENV"
fi
PY="$VENV/bin/python"
export VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH"
# Install the test requirements only when one is missing (a re-run needs no network).
if ! "$PY" -c 'import mcap, pytest, xdist, can, canopen, jsonschema, websockets, mpmath, lz4, matplotlib, scipy, fmpy' 2>/dev/null \
    || ! "$PY" -m ruff --version >/dev/null 2>&1; then
  echo "== Python test requirements into $VENV"
  "$PY" -m pip install --quiet -r tests/python/requirements.txt
fi

echo "== file-level import circles (scripts/file_cycles.py)"
"$PY" scripts/file_cycles.py

echo "== formatting and lints"
cargo fmt --all --check
cargo clippy --profile fast --workspace --all-targets -- -D warnings
"$PY" -m ruff check

echo "== the CLI and the FMU, then the Python tests in the background"
# The crates the CLI needs, with the features the Rust tests below build them with
# (crates/feature-unify; tests/python/test_feature_sets.py checks it): the tests reuse them.
cargo build --profile fast -p ehactl-cli -p ehactl-fmu
# Skipped here, run by test_all.sh: CAN end to end (hub, devices, LocalNode), diagnosis on
# generated and real records, the README's examples and the documented tuning figures (need
# the bindings), fault injection. Two workers, each module on one (its fixtures once) and the
# modules sharing a session diagnosis together (tests/python/conftest.py); they run while
# cargo documents and tests below, whose steps leave target/fast/ehactl as it is.
PYTEST_LOG="$(mktemp)"
PYTEST_STATUS=0
EHACTL_BIN="$PWD/target/fast/ehactl" "$PY" -m pytest tests/python -q -n 2 --dist loadgroup \
  --ignore=tests/python/test_canbus_hub.py --ignore=tests/python/test_canopen_e2e.py \
  --ignore=tests/python/test_canopen_localnode.py --ignore=tests/python/test_devices.py \
  --ignore=tests/python/test_diagnose_baseline.py --ignore=tests/python/test_diagnose_cli.py \
  --ignore=tests/python/test_diagnose_greybox.py --ignore=tests/python/test_readme.py \
  --ignore=tests/python/test_doc_figures.py \
  --ignore=tests/python/test_reliability.py --ignore=tests/python/test_can_demo.py \
  > "$PYTEST_LOG" 2>&1 &
PYTEST_PID=$!
# A Rust step that fails ends the script (set -e): the Python tests end with it.
trap '[ -n "${PYTEST_PID:-}" ] && kill "$PYTEST_PID" 2>/dev/null; rm -f "$PYTEST_LOG"' EXIT

echo "== API documentation (cargo doc, rustdoc warnings as errors)"
# As in test_all.sh: broken, private or ambiguous links and stray HTML in doc comments fail.
# 21–26 s after a touch of crates/plant or crates/types, 0.5 s when nothing changed
# (2026-12-03, warm target/fast, another build beside it).
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --profile fast --workspace --no-deps

echo "== Rust tests (without the diagnosis catalogue)"
export PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-20261123}"
# The Python extension's crate has no Rust tests (its tests are pytest files, run by
# test_all.sh after maturin builds it); clippy above checked it.
cargo test --profile fast --workspace --exclude ehactl-ident --exclude ehactl-ident-eval \
  --exclude ehactl-python "$@"
# ehactl-ident's unit tests, the evaluation harness's (crates/ident-eval) and the harness's two
# quick integration tests of the diagnosis. Selected with --workspace (the other crates' unit
# tests run again, a few seconds) so that Cargo resolves the same features as above:
# `-p ehactl-ident-eval` would build every dependency a second time after each change.
cargo test --profile fast --workspace --exclude ehactl-python --lib --test data_errors --test data_units "$@"

echo "== Python tests (no CAN, no diagnosis catalogue, no bindings)"
wait "$PYTEST_PID" || PYTEST_STATUS=1
PYTEST_PID=
cat "$PYTEST_LOG"
[ "$PYTEST_STATUS" = 0 ] || { echo "== Python tests failed"; exit 1; }
echo "== fast tier passed in $(( $(date +%s) - t0 )) s"
