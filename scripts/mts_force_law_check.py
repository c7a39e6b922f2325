#!/usr/bin/env python3
"""Equation-error check of two MR-damper force laws on the UTFSM MTS records (DIAGNOSIS.md,
"Why the law costs the 1 A position").

The measured load-cell force is regressed on [v, s, 1] on the first 70 % of a record (the
diagnosis's fitting part) and scored on the last 30 % (held out), with v the central
difference of the position after a 9-sample moving average (as in
tests/python/test_diagnose_greybox.py) and s either
- the rate-only yield law of the grey-box library, tanh(v/v_y), v_y scanned, or
- Dahl's model, a one-state law with pre-yield elasticity (Dahl, "A solid friction model",
  Aerospace Corp. TOR-0158(3107-18)-1, 1968; viscous + Dahl for an MR damper: Ikhouane &
  Dyke, Smart Mater. Struct. 16(3):605–616, 2007): dz/dt = σ·(v − |v|·z), σ (1/m) scanned,
  z integrated exactly for a velocity held over each sample.
Prints the held-out NRMSE of the force (rms residual / std) of the best scan point of each.

Usage: python3 scripts/mts_force_law_check.py
"""
import pathlib

import numpy as np

MTS = pathlib.Path(__file__).resolve().parents[1] / "tests" / "data" / "measured" / "utfsm_mts"


def dahl_state(v, dt, sigma):
    """Dahl state z (-) for velocity v (m/s) sampled at dt (s), σ in 1/m, z(0) = 0."""
    z = np.zeros(len(v))
    for k in range(1, len(v)):
        a = sigma * abs(v[k - 1]) * dt
        zinf = np.sign(v[k - 1])
        z[k] = zinf + (z[k - 1] - zinf) * np.exp(-a)
    return z


def main():
    for rec in ("0A", "1A"):
        f = np.genfromtxt(MTS / f"{rec}_5to15s.csv", delimiter=",", names=True)
        n = int(round(0.7 * len(f)))
        dt = f["t"][1] - f["t"][0]
        xs = np.convolve(f["x"], np.ones(9) / 9, "same")
        v = np.gradient(xs, dt)
        force = f["force"]
        fit, held = slice(10, n), slice(n, len(f) - 10)  # edges of the moving average dropped

        def score(s):
            a = np.column_stack([v, s, np.ones(len(v))])
            c, *_ = np.linalg.lstsq(a[fit], force[fit], rcond=None)
            r = force[held] - a[held] @ c
            return np.sqrt(np.mean(r**2)) / force[held].std()

        tanh = min((score(np.tanh(v / vy)), vy) for vy in np.geomspace(1e-4, 2e-2, 40))
        dahl = min((score(dahl_state(v, dt, s)), s) for s in np.geomspace(10.0, 1e5, 40))
        print(f"{rec}: held-out force NRMSE, rate-only tanh(v/v_y) {tanh[0]:.3f} (v_y = {tanh[1]:.2e} m/s), "
              f"Dahl {dahl[0]:.3f} (sigma = {dahl[1]:.3g} 1/m, pre-yield travel 1/sigma = {1e3 / dahl[1]:.2f} mm)")


if __name__ == "__main__":
    main()
