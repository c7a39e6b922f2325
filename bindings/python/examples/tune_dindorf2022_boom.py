#!/usr/bin/env python3
"""Tune the Dindorf 2022 boom PD position loop (configs/dindorf2022_boom.toml) and compare the
positioning and vibration under the 21.8 Hz excitation force with the config's gains.

    python3 bindings/python/examples/tune_dindorf2022_boom.py [--out out/tune_dindorf2022]

(b) is the paper's own method (003 §5: critical gain K_Pcr and period T_pcr, here with the
Ziegler–Nichols PD rule K_P = 0.8 K_Pcr, T_D = T_pcr/8); (a) and (c) for comparison.
Scored on the ground-truth piston position x: step 0 → 0.6 m, vibration over the second
half of the 3 s run (RMS, peak to peak, 21.8 Hz amplitude) and the final position error.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import ehactl
from ehactl import plot, tune

REPO = Path(__file__).resolve().parents[3]
KEYS = ("itae", "overshoot_pct", "settling_time", "vibration_rms", "vibration_p2p", "tone_amplitude", "position_error")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--config", default=str(REPO / "configs" / "dindorf2022_boom.toml"))
    ap.add_argument("--out", default=str(REPO / "out" / "tune_dindorf2022"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = ehactl.Config.load(args.config)
    res = {
        "(b) critical gain (003), Ziegler–Nichols PD": tune.critical_gain(cfg, "zn"),
        "(a) model-based PM 60°": tune.model_based(cfg, 60.0),
        "(c) ITAE optimisation": tune.optimize(cfg, "itae"),
    }
    b = res["(b) critical gain (003), Ziegler–Nichols PD"]
    print(f"K_Pcr = {b.details['K_Pcr']:.1f} V/m, T_pcr = {b.details['T_pcr'] * 1e3:.2f} ms ({b.details['f_cr_hz']:.1f} Hz)")
    rows = {"config gains": {**b.baseline_gains, **b.baseline}}
    for k, r in res.items():
        rows[k] = {**r.gains, **r.metrics}
    print(f"{'gains':44s} {'K_P V/m':>8s} {'T_D ms':>7s} " + " ".join(f"{k:>14s}" for k in KEYS))
    for k, r in rows.items():
        print(f"{k:44s} {r['control.pd.kp']:8.1f} {r['control.pd.td'] * 1e3:7.3f} " + " ".join(f"{r[m]:14.4g}" for m in KEYS))
    runs = ehactl.run_many([cfg] + [r.config for r in res.values()])
    plot.step(runs, labels=["config gains"] + list(res), title="Dindorf 2022 boom: 0 → 0.6 m under the 21.8 Hz force (piston x)",
              path=out / "step.png")
    plot.step(runs, labels=["config gains"] + list(res), t_range=(1.5, 3.0),
              title="Dindorf 2022 boom: steady state under the 21.8 Hz force", path=out / "steady.png")
    for i, r in enumerate(res.values()):
        r.write_config(out / f"tuned_{i}_{r.method}.toml")
    (out / "summary.json").write_text(json.dumps({"K_Pcr": b.details["K_Pcr"], "T_pcr": b.details["T_pcr"], "rows": rows}, indent=2, default=float))
    print(f"figures, tuned configs and summary.json in {out}")


if __name__ == "__main__":
    main()
