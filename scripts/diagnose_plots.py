#!/usr/bin/env python3
"""Plots for `ehactl diagnose --out DIR` (matplotlib): reads DIR/traces.csv (and
DIR/validation_traces.csv) written by the CLI, writes PNGs into DIR and prints their paths.

- traces.png: measured vs nominal vs extended per channel, held-out part shaded
- residual.png: residual of nominal and extended model over time and its spectrum (Welch)
- residual_state.png: nominal residual against velocity, pressure, command and position
- frf.png: frequency responses u → each channel (H1 estimate) of data, nominal and extended
"""
import sys
from pathlib import Path

import numpy as np
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

UNITS = {"force": "N", "x": "m", "p_a": "Pa", "p_b": "Pa", "x_v": "-"}


def load(path):
    with open(path) as f:
        names = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {n: data[:, i] for i, n in enumerate(names)}


def channels(d):
    return [k[5:] for k in d if k.startswith("meas_")]


def welch(y, fs, nseg):
    nseg = int(min(nseg, len(y)))
    step = nseg // 2
    win = np.hanning(nseg)
    acc = None
    count = 0
    for s in range(0, len(y) - nseg + 1, step):
        seg = (y[s:s + nseg] - np.mean(y[s:s + nseg])) * win
        p = np.abs(np.fft.rfft(seg)) ** 2
        acc = p if acc is None else acc + p
        count += 1
    f = np.fft.rfftfreq(nseg, 1.0 / fs)
    return f, acc / max(count, 1) * 2.0 / (fs * np.sum(win ** 2))


def h1(u, y, fs, nseg):
    nseg = int(min(nseg, len(u)))
    step = nseg // 2
    win = np.hanning(nseg)
    suu = 0
    suy = 0
    for s in range(0, len(u) - nseg + 1, step):
        U = np.fft.rfft((u[s:s + nseg] - np.mean(u[s:s + nseg])) * win)
        Y = np.fft.rfft((y[s:s + nseg] - np.mean(y[s:s + nseg])) * win)
        suu = suu + np.abs(U) ** 2
        suy = suy + np.conj(U) * Y
    return np.fft.rfftfreq(nseg, 1.0 / fs), suy / np.maximum(suu, 1e-300)


def main(out):
    out = Path(out)
    d = load(out / "traces.csv")
    t = d["t"]
    fs = 1.0 / np.median(np.diff(t))
    held = d["held_out"] > 0.5
    chans = channels(d)
    made = []
    nseg = 2 ** int(np.log2(max(64, min(len(t) // 4, 4096))))

    fig, axes = plt.subplots(len(chans) + 1, 1, figsize=(11, 2.2 * (len(chans) + 1)), sharex=True)
    axes[0].plot(t, d["u"], "k", lw=0.8)
    axes[0].set_ylabel("u (V)")
    for ax, c in zip(axes[1:], chans):
        ax.plot(t, d["meas_" + c], "k", lw=0.8, label="measured")
        ax.plot(t, d["nom_" + c], "C0", lw=0.8, label="nominal")
        ax.plot(t, d["ext_" + c], "C3", lw=0.8, ls="--", label="extended")
        ax.set_ylabel(f"{c} ({UNITS.get(c, '')})")
    for ax in axes:
        if held.any():
            ax.axvspan(t[held][0], t[-1], color="0.9", zorder=-1)
    axes[1].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t (s) — shaded: held out")
    fig.tight_layout()
    fig.savefig(out / "traces.png", dpi=110)
    plt.close(fig)
    made.append(out / "traces.png")

    fig, axes = plt.subplots(len(chans), 2, figsize=(12, 2.4 * len(chans)), squeeze=False)
    for i, c in enumerate(chans):
        rn = d["meas_" + c] - d["nom_" + c]
        re = d["meas_" + c] - d["ext_" + c]
        axes[i, 0].plot(t, rn, "C0", lw=0.7, label="nominal")
        axes[i, 0].plot(t, re, "C3", lw=0.7, label="extended")
        axes[i, 0].set_ylabel(f"residual {c} ({UNITS.get(c, '')})")
        for r, col, lab in ((rn, "C0", "nominal"), (re, "C3", "extended")):
            f, p = welch(r, fs, nseg)
            axes[i, 1].semilogy(f[1:], p[1:], col, lw=0.8, label=lab)
        axes[i, 1].set_ylabel("PSD")
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    axes[-1, 1].set_xlabel("f (Hz)")
    fig.tight_layout()
    fig.savefig(out / "residual.png", dpi=110)
    plt.close(fig)
    made.append(out / "residual.png")

    states = [("v_model", "velocity (model) (m/s)"), ("u", "command u (V)")]
    if "meas_p_a" in d:
        states.append(("meas_p_a", "p_a (Pa)"))
    if "meas_x" in d:
        states.append(("meas_x", "position x (m)"))
    fig, axes = plt.subplots(len(chans), len(states), figsize=(3.2 * len(states), 2.4 * len(chans)), squeeze=False)
    for i, c in enumerate(chans):
        rn = d["meas_" + c] - d["nom_" + c]
        for j, (k, lab) in enumerate(states):
            axes[i, j].plot(d[k], rn, ".", ms=1.5, alpha=0.5)
            if i == len(chans) - 1:
                axes[i, j].set_xlabel(lab)
            if j == 0:
                axes[i, j].set_ylabel(f"nominal residual {c}")
    fig.tight_layout()
    fig.savefig(out / "residual_state.png", dpi=110)
    plt.close(fig)
    made.append(out / "residual_state.png")

    fig, axes = plt.subplots(2, len(chans), figsize=(3.6 * len(chans), 5.5), squeeze=False)
    for j, c in enumerate(chans):
        for key, col, lab in (("meas_", "k", "measured"), ("nom_", "C0", "nominal"), ("ext_", "C3", "extended")):
            f, h = h1(d["u"], d[key + c], fs, nseg)
            axes[0, j].loglog(f[1:], np.abs(h[1:]), col, lw=0.8, label=lab)
            axes[1, j].semilogx(f[1:], np.degrees(np.unwrap(np.angle(h[1:]))), col, lw=0.8)
        axes[0, j].set_title(f"u → {c}")
        axes[1, j].set_xlabel("f (Hz)")
    axes[0, 0].set_ylabel("|H| (unit/V)")
    axes[1, 0].set_ylabel("phase (deg)")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "frf.png", dpi=110)
    plt.close(fig)
    made.append(out / "frf.png")

    vpath = out / "validation_traces.csv"
    if vpath.exists():
        v = load(vpath)
        vc = channels(v)
        fig, axes = plt.subplots(len(vc), 1, figsize=(11, 2.2 * len(vc)), sharex=True, squeeze=False)
        for ax, c in zip(axes[:, 0], vc):
            ax.plot(v["t"], v["meas_" + c], "k", lw=0.8, label="measured")
            ax.plot(v["t"], v["nom_" + c], "C0", lw=0.8, label="nominal")
            ax.plot(v["t"], v["ext_" + c], "C3", lw=0.8, ls="--", label="extended")
            ax.set_ylabel(f"{c} ({UNITS.get(c, '')})")
        axes[0, 0].legend(fontsize=8)
        axes[-1, 0].set_xlabel("t (s) — validation file")
        fig.tight_layout()
        fig.savefig(out / "validation.png", dpi=110)
        plt.close(fig)
        made.append(out / "validation.png")

    for m in made:
        print(m)


if __name__ == "__main__":
    main(sys.argv[1])
