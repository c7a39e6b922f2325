#!/usr/bin/env bash
# Wall-clock jitter benchmark (BENCHMARKS.md): 20 s at 5 kHz per scenario with the sim backend
# paced in real time (idle, idle without busy-wait tail, other core loaded, same core loaded).
# Prints a markdown table; writes bench/results/jitter.json and bench/results/jitter.png.
# Extra arguments go to bench/jitter.py (e.g. --duration 5 --scenarios idle --note "...").
# SCHED_FIFO / mlockall need root or CAP_SYS_NICE + CAP_IPC_LOCK; without them the run
# continues and the table's warnings say what was not applied.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p ehactl-cli
python3 -m pip install --quiet -r tests/python/requirements.txt matplotlib tqdm
python3 bench/jitter.py "$@"
