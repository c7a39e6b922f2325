#!/usr/bin/env python3
"""Figures of REPRODUCTION.md, regenerated from the ehactl binary.

- docs/repro/004_closed_loop_bode.png: Sahu 2022's force loop (K_P 0.57, I 386.24, 5 kHz):
  the nonlinear plant measured by `ehactl sweep` (785 N + 196 N stepped sine), the sampled
  linearisation of `ehactl analyze`, and the paper's eq. 17 evaluated with Table 1.
- docs/repro/004_open_loop_bode.png: valve command -> force, open loop (`ehactl sweep --open-loop`).
- docs/repro/003_rigid_vs_flexible.png: Dindorf 2022 figures 13-16 redone: PD positioning to 0.6 m
  under the 21.8 Hz force, rigid (255 kg on the rod) vs flexible (SDD to the 250 kg load).

Usage: python3 scripts/repro_plots.py [--ehactl target/release/ehactl] [--out DIR | --docs]

Writes to out/repro/ by default; --docs refreshes the tracked figures in docs/repro/ (the names
above) that REPRODUCTION.md and the README show.
"""
import argparse
import json
import pathlib
import shutil
import subprocess
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

try:
    import ehactl  # noqa: E402  (the log reader of the Python bindings: ehactl.read_mcap)
except ImportError as e:  # pragma: no cover
    raise SystemExit(f"{e}: install the Python bindings first: python3 -m pip install ./bindings/python")


def ehactl_json(exe, *args):
    out = subprocess.run([exe, *args, "--json"], check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def eq17_closed_loop(f):
    """Sahu 2022 eq. 17 with Table 1's converged values, ideal PI on load-cell volts."""
    M, A, Vt, beta = 0.893, 2.364e-4, 2.364e-6, 1.75e9
    KQv, KL, C, KCt = 3.33e-3, 4.83e8, 10.587, 1.51e-10
    wnv, z, g, kp, ki = 1507.9, 0.59, 0.5097e-3, 0.57, 386.24
    wh = np.sqrt(4 * beta * A**2 / (M * Vt))
    dh = KCt / A * np.sqrt(beta * M / Vt) + C / (4 * A) * np.sqrt(Vt / (beta * M))
    s = 2j * np.pi * f
    G = (KQv / A) * (M * s**2 + C * s + KL) / (
        (s**2 / wnv**2 + 2 * z / wnv * s + 1) * (s**2 / wh**2 + 2 * dh / wh * s + 1)
        * (s + KCt * KL / A**2))
    L = kp * (1 + ki / s) * g * G
    return L / (1 + L), G


def bode(ax_m, ax_p, f, h_db, ph, **kw):
    ax_m.semilogx(f, h_db, **kw)
    ax_p.semilogx(f, ph, **kw)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    built = ROOT / "target" / "release" / "ehactl"
    # the workspace build, else the installed binary (scripts/install_and_run.sh)
    ap.add_argument("--ehactl", default=str(built) if built.exists() else (shutil.which("ehactl") or str(built)))
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "repro", help="output directory (default out/repro)")
    ap.add_argument("--docs", action="store_true", help="refresh the tracked figures in docs/repro/ instead")
    a = ap.parse_args()
    if a.docs:
        a.out = ROOT / "docs" / "repro"
    a.out.mkdir(parents=True, exist_ok=True)
    exe = a.ehactl
    cfg = str(ROOT / "configs" / "sahu2022_force.toml")
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="ehactl_repro_"))

    an = ehactl_json(exe, "analyze", cfg)
    sw = ehactl_json(exe, "sweep", cfg, "--from", "1", "--to", "300", "--points", "30",
                     "--out", str(tmp / "sweep.mcap"))
    lin = an["loop_response"]
    fl = np.array([p["f_hz"] for p in lin])
    fig, (am, apz) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    f17 = np.logspace(0, np.log10(2400), 400)
    T17, G17 = eq17_closed_loop(f17)
    bode(am, apz, f17, 20 * np.log10(abs(T17)), np.unwrap(np.angle(T17)) * 180 / np.pi,
         label="paper eq. 17 + Table 1 (continuous)", color="0.6", lw=2)
    bode(am, apz, fl, [p["closed_mag_db"] for p in lin],
         np.unwrap(np.radians([p["closed_phase_deg"] for p in lin])) * 180 / np.pi,
         label="ehactl analyze: sampled linearisation (5 kHz ZOH)", color="C0")
    fs = np.array([p["f_hz"] for p in sw["points"]])
    bode(am, apz, fs, [p["mag_db"] for p in sw["points"]], [p["phase_deg"] for p in sw["points"]],
         label="ehactl sweep: nonlinear plant, 785 N ± 196 N", color="C3", marker="o", ls="none", ms=4)
    am.axhline(-3, color="k", lw=0.5, ls=":")
    bw = sw.get("bandwidth_hz")
    am.set_title(f"Sahu 2022 force loop, K_P 0.57, I 386.24 s⁻¹: closed loop F/F_ref "
                 f"(sweep −3 dB at {bw:.0f} Hz)" if bw else "Sahu 2022 closed loop")
    am.set_ylabel("|T| [dB]")
    apz.set_ylabel("∠T [°]")
    apz.set_xlabel("frequency [Hz]")
    am.set_xlim(1, 2400)
    am.set_ylim(-30, 6)
    apz.set_ylim(-360, 10)
    for ax in (am, apz):
        ax.grid(True, which="both", lw=0.3)
    am.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out / "004_closed_loop_bode.png", dpi=130)
    plt.close(fig)

    swo = ehactl_json(exe, "sweep", cfg, "--open-loop", "--amplitude", "0.0376", "--from", "1",
                      "--to", "300", "--points", "25", "--out", str(tmp / "sweep_open.mcap"))
    fig, (am, apz) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    bode(am, apz, f17, 20 * np.log10(abs(G17)), np.unwrap(np.angle(G17)) * 180 / np.pi,
         label="paper eq. 17 + Table 1", color="0.6", lw=2)
    fo = np.array([p["f_hz"] for p in swo["points"]])
    bode(am, apz, fo, [p["mag_db"] for p in swo["points"]], [p["phase_deg"] for p in swo["points"]],
         label="ehactl sweep --open-loop (nonlinear plant)", color="C3", marker="o", ls="none", ms=4)
    am.set_title(f"Sahu 2022 open loop, valve command → force (−3 dB at {swo['bandwidth_hz']:.0f} Hz)")
    am.set_ylabel("|F/u| [dB N/V]")
    apz.set_ylabel("phase [°]")
    apz.set_xlabel("frequency [Hz]")
    for ax in (am, apz):
        ax.grid(True, which="both", lw=0.3)
    am.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out / "004_open_loop_bode.png", dpi=130)
    plt.close(fig)

    runs = {}
    for name in ("dindorf2022_boom_rigid", "dindorf2022_boom"):
        path = tmp / f"{name}.mcap"
        subprocess.run([exe, "run", str(ROOT / "configs" / f"{name}.toml"), "--out", str(path),
                        "--json"], check=True, capture_output=True)
        runs[name] = ehactl.read_mcap(path)
    fig, ax = plt.subplots(4, 2, figsize=(12, 10), sharex="col")
    for col, (t0, t1) in enumerate([(0.0, 3.0), (2.5, 2.7)]):
        for name, color, label in (("dindorf2022_boom_rigid", "C2", "rigid (m_y + m_L on the rod)"),
                                   ("dindorf2022_boom", "C3", "flexible (SDD k_m 5.0e4, d_m 1.5e4)")):
            p = runs[name]["plant"]
            t = p["t"]
            m = (t >= t0) & (t <= t1)
            ax[0, col].plot(t[m], p["x"][m], color=color, lw=0.8, label=label)
            ax[1, col].plot(t[m], p["v"][m], color=color, lw=0.8)
            ax[2, col].plot(t[m], (p["p_a"][m] - p["p_b"][m]) / 1e5, color=color, lw=0.8)
            ax[3, col].plot(t[m], p["x_load"][m], color=color, lw=0.8)
        ax[0, col].set_ylabel("piston y [m]")
        ax[1, col].set_ylabel("piston v_y [m/s]")
        ax[2, col].set_ylabel("p_L = p₁ − p₂ [bar]")
        ax[3, col].set_ylabel("load x [m]")
        ax[3, col].set_xlabel("t [s]")
        for r in ax[:, col]:
            r.grid(True, lw=0.3)
    ax[0, 0].legend(fontsize=8)
    ax[0, 0].set_title("Dindorf 2022: PD to y_set = 0.6 m, F₀ 2500 N + 1000 N at 21.8 Hz")
    ax[0, 1].set_title("zoom 2.5–2.7 s (steady vibration)")
    fig.tight_layout()
    fig.savefig(a.out / "003_rigid_vs_flexible.png", dpi=120)
    plt.close(fig)
    print(f"wrote {a.out}/004_closed_loop_bode.png, 004_open_loop_bode.png, 003_rigid_vs_flexible.png")


if __name__ == "__main__":
    main()
