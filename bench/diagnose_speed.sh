#!/usr/bin/env bash
# Speed of `ehactl diagnose` (BENCHMARKS.md): a 4 s record at 2 kHz, 12 candidates, one
# hidden effect per case; each case run with 1 worker thread (A) and with all cores (B),
# interleaved A/B, REPS times. Prints per run wall time, process CPU time (user+sys) and the
# load average before the run; then the medians per configuration. Not a test.
# Usage: bench/diagnose_speed.sh [REPS=3] [EFFECTS="friction valve_deadband line_dynamics"]
# EFFECTS may name independent-generator cases, e.g. "indep:lugre"; SESSION=1 in the
# environment runs with the options of `ehactl diagnose` (see the example's doc).
set -euo pipefail
cd "$(dirname "$0")/.."
REPS="${1:-3}"
EFFECTS="${2:-friction valve_deadband line_dynamics}"
cargo build --release -p ehactl-ident-eval --example diagnose_speed >/dev/null 2>&1
BIN=./target/release/examples/diagnose_speed
OUT="$(mktemp)"
echo "nproc $(nproc); $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
for r in $(seq "$REPS"); do
  for e in $EFFECTS; do
    for th in 1 0; do
      load=$(cut -d' ' -f1 /proc/loadavg)
      line=$(RAYON_NUM_THREADS=$([ "$th" = 1 ] && echo 1 || nproc) "$BIN" $((100 + r)) "$e" "$th")
      echo "load $load | $line" | tee -a "$OUT"
    done
  done
done
python3 - "$OUT" <<'PY'
import re, statistics, sys
rows = [l for l in open(sys.argv[1])]
for th in ("1", "0"):
    sel = [l for l in rows if f"threads {th}:" in l]
    w = [float(re.search(r"wall ([\d.]+)", l).group(1)) for l in sel]
    c = [float(re.search(r"cpu ([\d.]+)", l).group(1)) for l in sel]
    ld = [float(l.split()[1]) for l in sel]
    print(f"threads {'1' if th == '1' else 'all'}: {len(sel)} runs, median wall {statistics.median(w):.2f} s, "
          f"median cpu {statistics.median(c):.2f} s, median cpu/wall {statistics.median([a / b for a, b in zip(c, w)]):.2f}, "
          f"median load {statistics.median(ld):.1f}")
PY
rm -f "$OUT"
