#!/usr/bin/env python3
"""PNG plots of the Sirohi 2003 and Cristofori 2015 reproductions (REPRODUCTION.md, Sirohi 2003 and Cristofori 2015).

Usage (from the repo root):
    python3 scripts/repro_001_002_plots.py [--data DIR] [--out DIR | --docs] [--regen]

Reads the tracked CSVs in docs/repro/data and writes the PNGs to out/repro/ by default; --docs
refreshes the tracked PNGs (and, with --regen, CSVs) in docs/repro/ instead; --regen alone
writes fresh CSVs to out/repro/data.

The CSVs come from the Rust example
    cargo run --release -p ehactl-analysis --example repro_001_002_csv -- docs/repro/data
which this script runs itself when a CSV is missing or --regen is given.
"""
import argparse
import csv
import pathlib
import subprocess
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent
FILES = ["001_tube_lengths.csv", "001_viscosity.csv", "001_segments.csv", "002_motion.csv"]
PSI = 6894.757


def load(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    head = rows[0]
    data = np.array(rows[1:], dtype=float)
    return {h: data[:, i] for i, h in enumerate(head)}


def plot_tm(d, keys, labels, title, out):
    fig, (ax1, ax2, ax3) = plt.subplots(3, 1, figsize=(7.5, 9), sharex=True)
    f = d["f_hz"]
    for k, lab in zip(keys, labels):
        ax1.loglog(f, d[f"{k}_x_mag_m_per_v"] * 1e6, label=lab)
        ax2.semilogx(f, d[f"{k}_x_phase_deg"], label=lab)
        ax3.loglog(f, d[f"{k}_pc_mag_pa_per_v"] / PSI, label=lab)
    ax1.set_ylabel("|x_o / V| (µm/V)")
    ax2.set_ylabel("phase (deg)")
    ax3.set_ylabel("|P_c / V| (psi/V)")
    ax3.set_xlabel("frequency (Hz)")
    for a in (ax1, ax2, ax3):
        a.grid(True, which="both", alpha=0.3)
        a.axvspan(50, 1000, color="0.9", zorder=0)
    ax1.legend()
    ax1.set_title(title)
    fig.text(0.01, 0.005, "shaded: 001's measured band 50 Hz – 1 kHz", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def plot_segments(d, out):
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    f = d["f_hz"]
    for ax, tube in zip(axes, ["4.5", "11.5"]):
        ax.loglog(f, d[f"tm_{tube}in"], "k", lw=2.5, label="001 transfer matrix (eq. 1–22)")
        for n in [2, 8, 32]:
            ax.loglog(f, d[f"plant_{tube}in_n{n}"], lw=1,
                      label=f"plant lumped line, unsteady friction, {n} segments")
        ax.loglog(f, d[f"plant_{tube}in_n64_steady"], "--", lw=1,
                  label="plant lumped line, steady friction, 64 segments")
        ax.set_title(f"{tube} in tube, 2 cSt")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("gain / gain at 20 Hz")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_xlim(100, 1500)
    axes[0].legend(fontsize=8)
    fig.suptitle("001: plant R-L-C line (linearised, unsteady vs steady friction) vs transfer matrix")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def plot_motion(d, out):
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    t = d["t_s"]
    ax1.plot(t, d["v_est_noisy_m_s"], color="0.75", lw=0.8, label="eq. 31, port noise 0.2 bar")
    ax1.plot(t, d["v_est_full_line_m_s"], color="tab:orange", lw=0.8, label="eq. 31, full R-L-C line")
    ax1.plot(t, d["v_est_m_s"], color="tab:blue", lw=1.2, label="eq. 31, resistive line (002)")
    ax1.plot(t, d["v_true_m_s"], "k--", lw=1.2, label="plant (true)")
    ax1.set_ylabel("piston velocity (m/s)")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ax1.set_title("002: piston velocity from valve-port pressures, crane config")
    ax2.plot(t, d["p_port_a_pa"] / 1e6, label="port A (valve side of line)")
    ax2.plot(t, d["p_chamber_a_pa"] / 1e6, label="chamber A")
    ax2.plot(t, d["p_port_b_pa"] / 1e6, label="port B")
    ax2.plot(t, d["p_chamber_b_pa"] / 1e6, label="chamber B")
    ax2.set_ylabel("pressure (MPa)")
    ax2.set_xlabel("time (s)")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="CSV directory (default docs/repro/data; out/repro/data with --regen)")
    ap.add_argument("--out", default=str(ROOT / "out/repro"), help="PNG directory (default out/repro)")
    ap.add_argument("--docs", action="store_true", help="refresh the tracked files in docs/repro/ instead")
    ap.add_argument("--regen", action="store_true", help="rerun the Rust example first")
    a = ap.parse_args()
    if a.docs:
        a.out = str(ROOT / "docs/repro")
    if a.data is None:
        a.data = str(ROOT / "docs/repro/data") if a.docs or not a.regen else str(pathlib.Path(a.out) / "data")
    data, out = pathlib.Path(a.data), pathlib.Path(a.out)
    if a.regen or not all((data / f).exists() for f in FILES):
        cmd = ["cargo", "run", "--release", "-p", "ehactl-analysis", "--example",
               "repro_001_002_csv", "--", str(data)]
        print("running:", " ".join(cmd), file=sys.stderr)
        subprocess.run(cmd, cwd=ROOT, check=True)
    out.mkdir(parents=True, exist_ok=True)
    d = load(data / "001_tube_lengths.csv")
    plot_tm(d, ["l0in", "l4.5in", "l11.5in"], ["tube 0 in", "tube 4.5 in", "tube 11.5 in"],
            "001 transfer-matrix model, ν = 2 cSt (cf. 001 fig. 8)", out / "001_tube_lengths.png")
    d = load(data / "001_viscosity.csv")
    plot_tm(d, ["nu2cst", "nu20cst", "nu200cst"], ["2 cSt", "20 cSt", "200 cSt"],
            "001 transfer-matrix model, tube 4.5 in (cf. 001 fig. 9)", out / "001_viscosity.png")
    plot_segments(load(data / "001_segments.csv"), out / "001_segments.png")
    plot_motion(load(data / "002_motion.csv"), out / "002_motion.png")
    for p in ["001_tube_lengths", "001_viscosity", "001_segments", "002_motion"]:
        print(out / f"{p}.png")


if __name__ == "__main__":
    main()
