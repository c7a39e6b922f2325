#!/usr/bin/env bash
# Run the cross-built ehactl (scripts/cross_build.sh) under QEMU user-mode emulation and check
# that it gives the same run as the native build (DEPLOY.md, "Check the cross-built binary").
#   aarch64-unknown-linux-gnu      qemu-aarch64 -L /usr/aarch64-linux-gnu   (libc6-arm64-cross)
#   armv7-unknown-linux-gnueabihf  qemu-arm     -L /usr/arm-linux-gnueabihf (libc6-armhf-cross)
# QEMU and the target's glibc come from Debian's packages (qemu-user, libc6-*-cross,
# libgcc-s1-*-cross), installed with apt-get if missing and allowed: EHACTL_APT=1, or a yes
# to the question asked when run from a terminal; otherwise the step is skipped (EHACTL_APT=0
# or EHACTL_NO_APT=1: skip without asking). No binfmt registration is needed because qemu is
# called directly.
# The check: the shipped rig config (configs/sahu2022_force.toml, simulated time, its full
# 3.05 s) run natively (target/release/ehactl) and emulated; the summaries must agree
# (cycles, trip, records written exactly; rms/max errors to 1e-9 relative) and so must the
# two MCAP logs, read with the official Python `mcap` reader: every /control and /plant field
# of every cycle within 1e-9 of that field's range over the run (max |value|) + 1e-12
# absolute — the only allowed difference is the last bits of libm (expm1, sin, log) and FMA
# contraction on the other architecture, which the closed loop carries along. The scale is
# the field's range, not the single value: a rounding difference in a sum is relative to the
# operands, so a value crossing zero (a control error) keeps an absolute difference of the
# order of 1e-12 of its range (seen on armv7: 5e-12 on an error of 4.5e-3 with range ≈ 1e2).
# For aarch64 it then runs the FMU's aarch64 binary under QEMU with a native FMI host
# (fmu_check below; crates/fmu/examples/fmu_host.rs).
# Prints the emulated loop's time per cycle (an upper-bound sanity figure, not a board figure).
# Usage: scripts/qemu_run.sh [TARGET ...]   (default: aarch64-unknown-linux-gnu)
# Env: EHACTL_REQUIRE_QEMU=1 to fail (not skip) when qemu or the binary is missing;
#      QEMU_DURATION to shorten the run (s); EHACTL_SKIP_LOG=FILE: a skip appends its reason
#      there (scripts/test_all.sh lists them at its end); CARGO_TARGET_DIR=DIR where
#      cross_build.sh built (default target/): the ARM binaries are DIR/TARGET/release/ehactl;
#      QEMU_INSTALL_ONLY=1 to install the missing packages (as allowed above) and stop, status 1
#      if that was refused or failed (scripts/test_all.sh: in the background, early);
#      CROSS_DIAGNOSIS=1 when cross_build.sh built the full binary (else the controller build
#      must refuse `diagnose` with exit 2).
set -euo pipefail
cd "$(dirname "$0")/.."
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(aarch64-unknown-linux-gnu)
config=configs/sahu2022_force.toml
native=target/release/ehactl

skip() {
  # QEMU_INSTALL_ONLY: the caller runs the real step later and logs the skip then.
  [ "${QEMU_INSTALL_ONLY:-0}" != 1 ] || { echo "qemu_run: install step: $*" >&2; exit 1; }
  if [ "${EHACTL_REQUIRE_QEMU:-0}" = 1 ]; then
    echo "qemu_run: FAILED: $*" >&2
    exit 1
  fi
  echo "qemu_run: SKIPPED: $* (set EHACTL_REQUIRE_QEMU=1 to make this an error)" >&2
  [ -z "${EHACTL_SKIP_LOG:-}" ] || echo "QEMU runs of the ARM binaries (scripts/qemu_run.sh): $*" >>"$EHACTL_SKIP_LOG"
  exit 0
}

pkgs=(qemu-user)
for t in "${targets[@]}"; do
  case "$t" in
    aarch64-*) pkgs+=(libc6-arm64-cross libgcc-s1-arm64-cross) ;;
    armv7-*) pkgs+=(libc6-armhf-cross libgcc-s1-armhf-cross) ;;
    *) echo "qemu_run: unknown target $t" >&2; exit 2 ;;
  esac
done
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  command -v apt-get >/dev/null || skip "apt-get not found to install ${missing[*]}"
  sudo=""
  [ "$(id -u)" = 0 ] || sudo="sudo -n"
  allowed="${EHACTL_APT:-}"
  [ "${EHACTL_NO_APT:-0}" != 1 ] || allowed=0
  if [ -z "$allowed" ] && [ -t 0 ] && [ -t 1 ]; then
    read -r -p "qemu_run: install ${missing[*]} with ${sudo:+sudo }apt-get? [y/N] " answer
    case "$answer" in y|Y|yes) allowed=1 ;; esac
  fi
  [ "$allowed" = 1 ] || skip "missing system packages ${missing[*]}; not installed without consent (EHACTL_APT=1 installs them with apt-get)"
  echo "== installing ${missing[*]} (apt-get): QEMU and the ARM C libraries the emulated binaries load"
  { $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq \
      --no-install-recommends "${missing[@]}" >/dev/null; } || skip "apt-get install ${missing[*]} failed"
fi
[ "${QEMU_INSTALL_ONLY:-0}" != 1 ] || exit 0
[ -x "$native" ] || skip "$native not built (cargo build --release -p ehactl-cli)"

# The aarch64 FMU (docs/fmu.md): the closed-loop FMU of $config with the aarch64 library
# (cross_build.sh) run for 1 s by the native FMI host (crates/fmu/examples/fmu_host.rs), built
# for aarch64 too, under QEMU; its outputs after 1 s must equal the x86-64 host's run of the
# linux64 binary of the same FMU to 1e-9 relative (libm's last bits, as above).
fmu_check() {
  local t=$1 qemu=$2 sysroot=$3 d="${CARGO_TARGET_DIR:-target}/$1/release"
  local host_native=target/release/examples/fmu_host
  [ -f "$d/libehactl_fmu.so" ] && [ -x "$d/examples/fmu_host" ] || skip "$d/libehactl_fmu.so or examples/fmu_host not built (scripts/cross_build.sh $t)"
  [ -x "$host_native" ] || skip "$host_native not built (cargo build --release -p ehactl-fmu --example fmu_host)"
  "$native" export-fmu "$config" --closed-loop --out "$out/rig.fmu" --aarch64-binary "$d/libehactl_fmu.so" >/dev/null
  python3 -m zipfile -e "$out/rig.fmu" "$out/rig"
  "$host_native" "$out/rig" --seconds 1 >"$out/fmu_native.json"
  "$qemu" -L "$sysroot" "$d/examples/fmu_host" "$out/rig" --seconds 1 >"$out/fmu_$t.json"
  python3 - "$out/fmu_native.json" "$out/fmu_$t.json" "$t" <<'PY'
import json, math, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
t = sys.argv[3]
assert (a["platform"], b["platform"]) == ("linux64", "aarch64-linux"), (a["platform"], b["platform"])
assert a["steps"] == b["steps"] == 5000
for k in ("x", "v", "p_a", "p_b", "force_measured", "force_load"):
    assert math.isclose(a[k], b[k], rel_tol=1e-9, abs_tol=1e-12), f"{t}: FMU output {k}: linux64 {a[k]!r}, aarch64 {b[k]!r}"
print(f"{t}: the FMU's aarch64 binary under QEMU, 1 s of the closed loop by the native FMI host: "
      f"outputs equal the linux64 binary's (force {b['force_measured']:.6g} N); "
      f"EMULATED {b['median_s_per_step'] * 1e6:.1f} us per fmi2DoStep (native {a['median_s_per_step'] * 1e6:.2f})")
PY
}

out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
dur=()
[ -z "${QEMU_DURATION:-}" ] || dur=(--duration "$QEMU_DURATION")
"$native" run "$config" "${dur[@]}" --out "$out/native.mcap" --json >"$out/native.json"

for t in "${targets[@]}"; do
  case "$t" in
    aarch64-*) qemu=qemu-aarch64; sysroot=/usr/aarch64-linux-gnu ;;
    armv7-*) qemu=qemu-arm; sysroot=/usr/arm-linux-gnueabihf ;;
  esac
  bin="${CARGO_TARGET_DIR:-target}/$t/release/ehactl"
  [ -x "$bin" ] || skip "$bin not built (scripts/cross_build.sh $t)"
  command -v "$qemu" >/dev/null || skip "$qemu not found"
  if [ "${CROSS_DIAGNOSIS:-0}" != 1 ]; then
    # The controller build (cross_build.sh) has no diagnosis: it must say so, exit 2.
    set +e
    msg=$("$qemu" -L "$sysroot" "$bin" diagnose --config "$config" --data none.csv 2>&1)
    rc=$?
    set -e
    [ "$rc" = 2 ] && grep -q "built without the diagnosis" <<<"$msg" || {
      echo "qemu_run: $t: the controller build's \`diagnose\` gave exit $rc: $msg" >&2; exit 1; }
    echo "== $t: controller build, \`diagnose\` refused as documented (exit 2)"
  fi
  echo "== $t under $qemu (user-mode emulation): ehactl run $config ${dur[*]}"
  start=$(date +%s.%N)
  "$qemu" -L "$sysroot" "$bin" run "$config" "${dur[@]}" --out "$out/$t.mcap" --json >"$out/$t.json"
  end=$(date +%s.%N)
  python3 - "$out/native.json" "$out/$t.json" "$out/native.mcap" "$out/$t.mcap" "$t" "$start" "$end" <<'PY'
import json, math, struct, sys
from mcap.reader import make_reader

nat_s, emu_s, nat_m, emu_m, target, t0, t1 = sys.argv[1:]
a, b = json.load(open(nat_s)), json.load(open(emu_s))
for k in ("cycles", "trip", "trip_kind", "interrupted", "substeps", "control_rate_hz"):
    assert a[k] == b[k], f"{target}: summary {k}: native {a[k]!r}, emulated {b[k]!r}"
assert a["log"]["records_written"] == b["log"]["records_written"] == a["cycles"], (a["log"], b["log"])
assert b["log"]["records_dropped"] == 0
for k in ("rms_error", "max_abs_error", "rms_error_settled"):
    assert math.isclose(a[k], b[k], rel_tol=1e-9, abs_tol=1e-12), f"{target}: {k}: native {a[k]!r}, emulated {b[k]!r}"

def fields(path):
    """(topic -> list of float tuples) from the CDR payloads (after the 4-byte header)."""
    out = {"/control": [], "/plant": []}
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(topics=list(out)):
            d = msg.data[4:]
            if ch.topic == "/control":   # uint64 cycle + 16 float64
                out[ch.topic].append(struct.unpack_from("<Q16d", d))
            else:                         # 16 float64 + bool
                out[ch.topic].append(struct.unpack_from("<16d", d))
    return out

fa, fb = fields(nat_m), fields(emu_m)
worst, ndiff = 0.0, 0
for topic in fa:
    assert len(fa[topic]) == len(fb[topic]) == a["cycles"], (topic, len(fa[topic]), len(fb[topic]))
    width = len(fa[topic][0]) if fa[topic] else 0
    # Range of each field over the native run (NaN fields, e.g. open-loop errors, excluded).
    scale = [max((abs(r[j]) for r in fa[topic] if math.isfinite(r[j])), default=0.0)
             for j in range(width)]
    for i, (ra, rb) in enumerate(zip(fa[topic], fb[topic])):
        for j, (x, y) in enumerate(zip(ra, rb)):
            if x == y or (math.isnan(x) and math.isnan(y)):
                continue
            tol = 1e-9 * scale[j] + 1e-12
            assert abs(x - y) <= tol, \
                f"{target}: {topic} record {i} field {j}: native {x!r}, emulated {y!r} (tolerance {tol:.3e} = 1e-9 of the field's range {scale[j]:.3e} + 1e-12)"
            ndiff += 1
            worst = max(worst, abs(x - y) / tol)
cycles = b["cycles"]
print(f"{target}: same run as native ({cycles} cycles; summaries and every /control and /plant "
      f"field agree; {ndiff} values differ in the last bits, the largest at {worst:.1e} of the "
      f"tolerance); rms_error native "
      f"{a['rms_error']!r} emulated {b['rms_error']!r}")
print(f"{target}: EMULATED (qemu user mode on this host, not a board figure): loop "
      f"{b['wall_time_s'] / cycles * 1e6:.1f} us per cycle (native {a['wall_time_s'] / cycles * 1e6:.2f}), "
      f"{b['sim_speed_x_realtime']:.2f}x real time; whole process {float(t1) - float(t0):.2f} s")
PY
  case "$t" in aarch64-*) fmu_check "$t" "$qemu" "$sysroot" ;; esac
done
