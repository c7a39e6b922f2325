"""One `fmi2DoStep` of one control period of ehactl's closed-loop FMU, called from a native
host (crates/fmu/examples/fmu_host.rs: dlopen, C calls, the outputs read after every step),
against one cycle of `ehactl run` (its `--json` summary's loop wall time / cycles), on the
same config: configs/sahu2022_force.toml, its full 3.05 s, the FMU on the config's setpoint
(`setpoint_from_config`) so that both run the same experiment. Runs alternate, REPS each;
prints medians and minima in µs and the ratio FMU / run.

    python3 bench/fmu_step.py [REPS] [BIN_DIR]     # defaults: 11, target/release

BIN_DIR holds `ehactl`, `libehactl_fmu.so` and `examples/fmu_host`
(`cargo build --release -p ehactl-cli -p ehactl-fmu && cargo build --release -p ehactl-fmu
--example fmu_host`: a build of the example alone does not refresh the library). `ehactl run`'s
cycle includes handing each record to the MCAP logger thread; the FMU logs nothing.
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import zipfile

REPS = int(sys.argv[1]) if len(sys.argv) > 1 else 11
BIN = sys.argv[2] if len(sys.argv) > 2 else "target/release"
CONFIG = "configs/sahu2022_force.toml"


def main():
    with tempfile.TemporaryDirectory() as d:
        fmu = os.path.join(d, "rig.fmu")
        subprocess.run([f"{BIN}/ehactl", "export-fmu", CONFIG, "--closed-loop", "--out", fmu],
                       check=True, capture_output=True)
        zipfile.ZipFile(fmu).extractall(os.path.join(d, "rig"))
        step, cycle = [], []
        for _ in range(REPS):
            r = subprocess.run([f"{BIN}/examples/fmu_host", os.path.join(d, "rig"), "--seconds", "3.05"],
                               check=True, capture_output=True, text=True)
            step.append(json.loads(r.stdout)["median_s_per_step"] * 1e6)
            r = subprocess.run([f"{BIN}/ehactl", "run", CONFIG, "--out", os.path.join(d, "run.mcap"), "--json"],
                               check=True, capture_output=True, text=True)
            s = json.loads(r.stdout)
            cycle.append(s["wall_time_s"] / s["cycles"] * 1e6)
    ms, mc = statistics.median(step), statistics.median(cycle)
    print(f"FMU fmi2DoStep (one 0.2 ms period, native host): median {ms:.3f} us, min {min(step):.3f} us")
    print(f"ehactl run cycle:                               median {mc:.3f} us, min {min(cycle):.3f} us")
    print(f"ratio FMU / run: medians {ms / mc:.2f}, minima {min(step) / min(cycle):.2f} ({REPS} alternate runs each)")


if __name__ == "__main__":
    main()
