#!/usr/bin/env python3
"""Plot an ehactl MCAP run: setpoint vs feedback, error, command and chamber pressures.

Usage: python scripts/plot_run.py RUN.mcap [-o RUN.png]
"""
import argparse
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

try:
    import ehactl  # noqa: E402  (the log reader of the Python bindings: ehactl.read_mcap)
except ImportError as e:  # pragma: no cover
    raise SystemExit(f"{e}: install the Python bindings first: python3 -m pip install ./bindings/python")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("mcap", type=pathlib.Path)
    ap.add_argument("-o", "--out", type=pathlib.Path)
    a = ap.parse_args()
    run = ehactl.read_mcap(a.mcap)
    c = run["control"]
    p = run.get("plant")
    fig, ax = plt.subplots(4, 1, figsize=(11, 10), sharex=True)
    ax[0].plot(c["t"], c["setpoint"], label="setpoint", lw=0.8)
    ax[0].plot(c["t"], c["feedback"], label="feedback (measured)", lw=0.8)
    ax[0].set_ylabel("controlled variable (N or m)")
    ax[0].legend(loc="upper right")
    ax[1].plot(c["t"], c["error"], lw=0.6)
    ax[1].set_ylabel("error")
    ax[2].plot(c["t"], c["command"], lw=0.6, label="command")
    ax[2].plot(c["t"], c["i_term"], lw=0.6, label="I term")
    ax[2].set_ylabel("V")
    ax[2].legend(loc="upper right")
    if p is not None:
        ax[3].plot(p["t"], p["p_a"] / 1e6, lw=0.6, label="p_a")
        ax[3].plot(p["t"], p["p_b"] / 1e6, lw=0.6, label="p_b")
        ax[3].set_ylabel("MPa")
        ax[3].legend(loc="upper right")
    ax[-1].set_xlabel("t (s)")
    fig.suptitle(str(a.mcap))
    fig.tight_layout()
    out = a.out or a.mcap.with_suffix(".png")
    fig.savefig(out, dpi=110)
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
