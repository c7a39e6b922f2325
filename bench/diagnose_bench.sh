#!/usr/bin/env bash
# Benchmark of `ehactl diagnose` : 10 s of 5 kHz data (50 000 samples, 4 channels)
# with a hidden effect, every catalogue candidate fitted (2 worker threads), wall time of the
# whole command measured RUNS times; prints each time and the median.
# Usage: bench/diagnose_bench.sh [RUNS=3] [EFFECT=friction]
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS="${1:-3}"
EFFECT="${2:-friction}"
cargo build --release -p ehactl-cli -p ehactl-ident-eval --examples --bins >/dev/null
DIR="$(mktemp -d)"
./target/release/examples/make_csv 77 10 5000 "$DIR/data.csv" "$EFFECT"
echo "data: $(($(wc -l < "$DIR/data.csv") - 1)) samples at 5 kHz, hidden: $EFFECT, nproc $(nproc), load $(cut -d' ' -f1-3 /proc/loadavg)"
times=()
for i in $(seq "$RUNS"); do
  s=$(date +%s.%N)
  ./target/release/ehactl diagnose --config "$DIR/data.csv.nominal.toml" --data "$DIR/data.csv" --json > "$DIR/out$i.json"
  e=$(date +%s.%N)
  t=$(python3 -c "print(f'{$e - $s:.1f}')")
  cause=$(python3 -c "import json;d=json.load(open('$DIR/out$i.json'));print(d['cause'], round(d['gain']*100,1))")
  echo "run $i: ${t} s (cause, gain %: $cause)"
  times+=("$t")
done
python3 -c "import statistics,sys; print('median', statistics.median(map(float, sys.argv[1:])), 's')" "${times[@]}"
rm -rf "$DIR"
