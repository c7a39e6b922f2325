#!/usr/bin/env python3
"""Figure of the Cristofori 2015 crane cycle with counterbalance valves (REPRODUCTION.md, "Cristofori 2015 —
crane cycle with counterbalance valves"): docs/repro/002_cycle.png from
docs/repro/data/002_cycle.csv, which `cargo run --release -p ehactl-analysis --example
repro_002_cycle_csv -- docs/repro/data` writes (run here if the CSV is absent or --regen).

Panels: valve command and piston position with the phases of 002's test cycles; chamber and
valve-port pressures of both sides (the CBVs' effect); CBV poppet openings; the bulk modulus of
both chambers relative to beta(100 bar) (002 eq. 35-36, fig. 19); true piston velocity and the
port-pressure estimate of 002 eq. 31/32 switched as 002 does.

Usage: python3 scripts/repro_002_cycle_plot.py [--regen] [--out DIR | --docs]

Reads the tracked docs/repro/data/002_cycle.csv and writes the PNG to out/repro/ by default;
--docs refreshes the tracked files in docs/repro/ instead; --regen alone writes a fresh CSV
to out/repro/data.
"""
import argparse
import csv
import pathlib
import subprocess

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
PHASES = ["raise", "stop after raise", "lower", "stop after lowering"]
COLORS = ["#d8ecd8", "#eeeeee", "#f3dcdc", "#eeeeee"]


def load(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def shade(ax, t, ph):
    start = 0
    for i in range(1, len(t) + 1):
        if i == len(t) or ph[i] != ph[start]:
            ax.axvspan(t[start], t[i - 1], color=COLORS[int(ph[start])], lw=0)
            start = i


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--regen", action="store_true", help="rerun the Rust example first")
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "repro", help="output directory (default out/repro)")
    ap.add_argument("--docs", action="store_true", help="refresh the tracked files in docs/repro/ instead")
    a = ap.parse_args()
    if a.docs:
        a.out = ROOT / "docs" / "repro"
    data = a.out / "data" if (a.docs or a.regen) else ROOT / "docs" / "repro" / "data"
    csv_path = data / "002_cycle.csv"
    if a.regen or not csv_path.exists():
        subprocess.run(["cargo", "run", "--release", "-p", "ehactl-analysis", "--example",
                        "repro_002_cycle_csv", "--", str(data)], check=True, cwd=ROOT)
    d = load(csv_path)
    t, ph = d["t_s"], d["phase"]
    fig, ax = plt.subplots(5, 1, figsize=(10, 13), sharex=True)
    for x in ax:
        shade(x, t, ph)
    ax[0].plot(t, d["command_v"], "k", label="valve command (V)")
    ax0 = ax[0].twinx()
    ax0.plot(t, d["x_m"], "C0", label="piston position (m)")
    ax[0].set_ylabel("command (V)")
    ax0.set_ylabel("x (m)", color="C0")
    for k, name in enumerate(PHASES):
        idx = np.flatnonzero(ph == k)
        if len(idx) and k in (0, 1, 2):
            ax[0].text(t[idx[len(idx) // 2]], 10.5, name, ha="center", fontsize=8)
    ax[0].set_ylim(-10, 12)
    ax[0].set_title("Cristofori 2015 crane cycle, configs/cristofori2015_crane_cycle.toml (100 kN, CBVs on both lines)")
    ax[1].plot(t, d["p_chamber_a_pa"] / 1e6, "C3", label="chamber A (piston side)")
    ax[1].plot(t, d["p_port_a_pa"] / 1e6, "C3--", label="valve port A")
    ax[1].plot(t, d["p_chamber_b_pa"] / 1e6, "C0", label="chamber B (rod side)")
    ax[1].plot(t, d["p_port_b_pa"] / 1e6, "C0--", label="valve port B")
    ax[1].plot(t, d["p_supply_pa"] / 1e6, "0.5", lw=0.8, label="supply (P port)")
    ax[1].set_ylabel("pressure (MPa)")
    ax[1].legend(fontsize=8, ncol=3, loc="upper right")
    ax[2].plot(t, d["cbv_opening_a"], "C3", label="CBV A (holds the load)")
    ax[2].plot(t, d["cbv_opening_b"], "C0", label="CBV B")
    ax[2].set_ylabel("poppet opening (-)")
    ax[2].legend(fontsize=8, loc="upper right")
    b100 = np.interp(10e6, d["p_chamber_a_pa"][np.argsort(d["p_chamber_a_pa"])],
                     d["beta_a_pa"][np.argsort(d["p_chamber_a_pa"])])
    ax[3].plot(t, 100 * (d["beta_a_pa"] / b100 - 1), "C3", label="chamber A")
    ax[3].plot(t, 100 * (d["beta_b_pa"] / b100 - 1), "C0", label="chamber B")
    ax[3].set_ylabel("β / β(100 bar) − 1 (%)")
    ax[3].legend(fontsize=8, loc="upper right")
    ax[4].plot(t, d["v_true_m_s"], "k", label="true piston velocity")
    ax[4].plot(t, d["v_est_m_s"], "C1--", label="estimate from port pressures (eq. 31/32, switched)")
    ax[4].set_ylabel("velocity (m/s)")
    ax[4].set_xlabel("t (s)")
    ax[4].legend(fontsize=8, loc="lower left")
    for x in ax:
        x.grid(alpha=0.3)
    fig.tight_layout()
    a.out.mkdir(parents=True, exist_ok=True)
    out = a.out / "002_cycle.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
