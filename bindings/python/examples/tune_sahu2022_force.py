#!/usr/bin/env python3
"""Tune the Sahu 2022 force loop (configs/sahu2022_force.toml) end to end and save figures.

    python3 bindings/python/examples/tune_sahu2022_force.py [--out out/tune_sahu2022]

Steps, all on the compiled nonlinear plant of ehactl (the one the 5 kHz loop runs):
1. measure the loop frequency response with the paper's model-based gains (K_P 0.57,
   I 386.24 1/s) and its margins (004 §6.1: PM 60° at the 99.63 Hz gain crossover, GM
   10.8 dB at 262.6 Hz — labels as corrected in REPRODUCTION.md);
2. tune three ways: (a) model-based for 60° phase margin with the largest integral gain,
   on the linearised loop (ehactl-analysis) and on the measured response,
   (b) critical gain + Ziegler–Nichols / Tyreus–Luyben rules,
   (c) ITAE optimisation of a 0 → 785 N step with ≤ 5 % overshoot and ≤ 1 % command
   saturation while settling, and RMS-error optimisation of the paper's sweep with the
   same step limits;
3. score every gain set against the paper's hand gains (K_P 0.4 and 0.57) on the step
   (ITAE, overshoot, settling) and on the paper's tracking task (785 N static + ±196 N,
   1–300 Hz log sweep: RMS force error) and write figures, a JSON summary and the tuned
   configs to --out.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

import ehactl
from ehactl import plot, tune

REPO = Path(__file__).resolve().parents[3]


def tracking_rms(results, t_from: float) -> list[float]:
    """RMS of setpoint − true rod force after t_from (s), per run (N)."""
    out = []
    for r in results:
        m = r.t >= t_from
        out.append(float(np.sqrt(np.mean((r.setpoint[m] - r.rod_force[m]) ** 2))) if r.ok else math.inf)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--config", default=str(REPO / "configs" / "sahu2022_force.toml"))
    ap.add_argument("--out", default=str(REPO / "out" / "tune_sahu2022"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    cfg = ehactl.Config.load(args.config)
    test = tune.StepTest.default(cfg)  # 0 → 785 N at 10 ms, 0.1 s, scored on rod_force
    print(f"step test: {test}")

    # 1. loop response with the paper's model-based gains
    fr = tune.frequency_response(cfg, progress=True)
    m0 = fr.margins()
    print("loop with K_P 0.57, I 386.24:", {k: round(v, 2) for k, v in m0.items()})

    # 2. tuning
    results: dict[str, tune.TuneResult] = {}
    results["(a) model-based PM 60°, max K_I, linearised"] = tune.model_based(cfg, 60.0, test=test)
    results["(a) model-based PM 60°, max K_I, measured"] = tune.model_based(cfg, 60.0, fr=fr, test=test)
    results["(b) critical gain, Ziegler–Nichols"] = tune.critical_gain(cfg, "zn", test=test)
    results["(b) critical gain, Tyreus–Luyben"] = tune.critical_gain(cfg, "tyreus_luyben", test=test)
    results["(c) ITAE optimisation"] = tune.optimize(cfg, "itae", test=test, progress=True)
    results["(c) sweep RMS optimisation, step OS ≤ 5 %"] = tune.optimize(
        cfg, "rms_error", test=tune.TrackingTest.default(cfg), constraint_test=test, progress=True
    )

    # 3. score: paper hand gains and every tuned set, step and sweep tracking
    sets = {
        "paper K_P 0.57 (model-based, 004 §6.1)": {"control.pi.kp": 0.57, "control.pi.integral": 386.24},
        "paper K_P 0.4 (experiment, 004 §6.2)": {"control.pi.kp": 0.4, "control.pi.integral": 386.24},
    }
    sets.update({k: r.gains for k, r in results.items()})
    names = list(sets)
    step_m = tune.evaluate(cfg, [sets[n] for n in names], test)
    sweep = ehactl.run_many([cfg.with_values(sets[n]) for n in names], fields=["t", "setpoint", "rod_force", "u"])
    t_dyn = float(cfg["setpoint.ramp_time"])
    sweep_rms = tracking_rms(sweep, t_dyn)
    frs = [fr.with_gains(cfg, sets[n]) for n in names]

    rows = []
    for n, sm, sr, f in zip(names, step_m, sweep_rms, frs):
        mg = f.margins()
        rows.append(
            {
                "gains": n,
                "kp": sets[n]["control.pi.kp"],
                "integral_per_s": sets[n]["control.pi.integral"],
                "itae_Ns2": sm["itae"],
                "overshoot_pct": sm["overshoot_pct"],
                "settling_time_s": sm["settling_time"],
                "rise_time_s": sm["rise_time"],
                "sweep_rms_error_N": sr,
                "phase_margin_deg": mg["phase_margin_deg"],
                "gain_margin_db": mg["gain_margin_db"],
                "crossover_hz": mg["crossover_hz"],
                "bandwidth_hz": mg["bandwidth_hz"],
            }
        )
    hdr = f"{'gains':44s} {'K_P':>8s} {'I 1/s':>8s} {'ITAE N·s²':>10s} {'OS %':>6s} {'t_s ms':>7s} {'sweep RMS N':>11s} {'PM °':>6s} {'GM dB':>6s} {'f_c Hz':>7s} {'BW Hz':>6s}"
    print(hdr)
    for r in rows:
        print(
            f"{r['gains']:44s} {r['kp']:8.4g} {r['integral_per_s']:8.4g} {r['itae_Ns2']:10.4g} {r['overshoot_pct']:6.2f} "
            f"{r['settling_time_s'] * 1e3:7.2f} {r['sweep_rms_error_N']:11.3f} {r['phase_margin_deg']:6.1f} {r['gain_margin_db']:6.1f} "
            f"{r['crossover_hz']:7.1f} {r['bandwidth_hz']:6.1f}"
        )

    # figures
    best = results["(c) ITAE optimisation"]
    mb = results["(a) model-based PM 60°, max K_I, linearised"]
    step_runs = ehactl.run_many(
        [cfg.with_values(sets[n]) for n in names[:2]] + [best.config, mb.config],
        duration=test.duration,
        setpoint=test.setpoint(),
    )
    plot.step(step_runs, labels=names[:2] + ["(c) ITAE optimisation", "(a) model-based"], t_range=(0.0, 0.05),
              title="Sahu 2022 force loop: 0 → 785 N step (true rod force)", path=out / "step.png")
    plot.bode([frs[0], frs[1], frs[names.index("(c) ITAE optimisation")], frs[2]],
              labels=["K_P 0.57", "K_P 0.4", "(c) ITAE", "(a) model-based"], which="loop",
              title="Sahu 2022 loop L = C·P (P measured on the nonlinear plant)", path=out / "bode_loop.png")
    plot.bode(fr, which="plant", title="Sahu 2022 plant P = F/u (stepped sine, nonlinear plant)", path=out / "bode_plant.png")
    sweep_best = names.index("(c) sweep RMS optimisation, step OS ≤ 5 %")
    plot.tracking(sweep[sweep_best], signal="rod_force",
                  title="(c) sweep-tuned gains on the 785 N ± 196 N, 1–300 Hz sweep", path=out / "sweep_tuned.png")
    plot.bode([frs[0], frs[1], frs[sweep_best]], labels=["K_P 0.57", "K_P 0.4", "(c) sweep-tuned"], which="closed",
              title="Sahu 2022 closed loop F/F_ref (from the measured plant)", path=out / "bode_closed.png")
    plot.tracking(sweep[0], signal="rod_force", title="K_P 0.57 on the 785 N ± 196 N, 1–300 Hz sweep",
                  path=out / "sweep_paper.png")

    for i, (k, r) in enumerate(results.items()):
        r.write_config(out / f"tuned_{i}_{r.method}.toml")
    summary = {
        "config": args.config,
        "step_test": test.__dict__,
        "baseline_loop_margins": m0,
        "critical_gain": {k: results["(b) critical gain, Ziegler–Nichols"].details[k] for k in ("K_Pcr", "T_pcr", "f_cr_hz")},
        "rows": rows,
        "tuned_configs": {f"tuned_{i}_{r.method}.toml": k for i, (k, r) in enumerate(results.items())},
        "wall_time_s": time.perf_counter() - t_start,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    print(f"figures, tuned configs and summary.json in {out} ({summary['wall_time_s']:.1f} s)")


if __name__ == "__main__":
    main()
