#!/usr/bin/env python3
"""SciPy baseline for the sahu2022_force closed loop (BENCHMARKS.md, "Plant integration: accuracy against cost per rig").

The same plant and controller as ehactl's Rust code for configs/sahu2022_force.toml, written
the way a user would write it without ehactl: one ODE right-hand side, and a loop over the
5 kHz control periods that samples the force, runs the PI and integrates one 200 µs period
with ``scipy.integrate.solve_ivp`` while holding the valve command (sample and hold).

Model (SI units; same equations and parameters as crates/plant for this config):
  state y = [s, ṡ, p_A, p_B, x, v]
  spool    s̈ = ω²(u/u_fs − s) − 2ζω ṡ                                  (004 eq. 1)
  edges    o₊ = max(s − s₀, 0), o₋ = max(s₀ − s, 0)   (zero offset s₀, zero lap)
           Q(o, Δp) = k·o·Δp/(Δp² + Δp_l²)^¼, k = Q_rated/√Δp_rated   (K_q law, regularised
           to laminar below Δp_l = 20 kPa exactly as crates/plant/src/valve.rs)
           Q_A = Q(o₊, p_s − p_A) − Q(o₋, p_A − p_T),  Q_B = Q(o₋, p_s − p_B) − Q(o₊, p_B − p_T)
  chambers V_A = V_A0 + A_A·x̄, V_B = V_B0 + A_B·(stroke − x̄), x̄ = clamp(x, 0, stroke)
           ṗ_A = β/V_A·(Q_A − A_A v − K_in(p_A − p_B))
           ṗ_B = β/V_B·(Q_B + A_B v + K_in(p_A − p_B))
  piston   m v̇ = p_A A_A − p_B A_B − K_L (x − x_c) − c v,  ẋ = v  (no friction in this config)
  force    F = K_L (x − x_c)  (the load cell; noise and tones off, see below)
  PI       e = g·(r − F), u = K_P·e + I_acc, I_acc += K_P·I·T_s·e with clamping anti-windup,
           u clamped to ±10 V                                     (crates/control/src/pi.rs)
  setpoint 785 N reached by a ramp over 50 ms, then + 196 N · sin(log chirp 1→300 Hz over 3 s)

Not modelled because they never act in this run: the cavitation floor (pressures stay above
7.9 MPa, see the Rust reference ladder) and the supervisor trips.

Sensor noise and the 225/420 Hz tones are disabled here and in the Rust runs it is compared
with (the Rust bench's ``noise-free`` variant).

Accuracy is measured against the Rust high-accuracy reference trace written by
``cargo bench -p ehactl-tests --bench plant_accuracy -- sahu2022_force`` to
target/bench/sahu_reference_noisefree.csv (exponential Euler at 2816 substeps):
NRMSE = RMS(F − F_ref) / (max F_ref − min F_ref) over the control instants of the window.

By default each (method, rtol) runs the whole 3 s from t = 0, like the Rust runs, so nothing is
extrapolated. Shorter windows (``--horizon``, wall time then extrapolated linearly and said so)
are available: ``start`` (from t = 0, the same initial state as the Rust runs, accuracy
compared with the Rust traces over the same window) and ``end`` (the last part of the 1–300 Hz
chirp, started from the reference state, to check that the cost per simulated second does not
depend on where the window lies).

The script then matches accuracies: for every Rust substep count in
target/bench/sahu_rust_timing_noisefree.csv it finds the cheapest SciPy run (over the methods and
tolerances tried) whose NRMSE is at least as good over the same window, and prints the ratio of
wall time per simulated second, SciPy / Rust.

Usage:
  pip install -r bench/requirements.txt
  cargo bench -p ehactl-tests --bench plant_accuracy -- sahu2022_force   # writes target/bench/sahu_*.csv
  python bench/scipy_baseline.py                            # defaults below
  python bench/scipy_baseline.py --methods LSODA,BDF --rtols 1e-4,1e-6 --horizon 0.3 --windows start,end
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import scipy
from scipy.integrate import solve_ivp
from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------------------------
# Parameters (read from the rig config; defaults as in crates/plant/src/params.rs)
# --------------------------------------------------------------------------------------------
def load_params(path: Path) -> dict:
    c = tomllib.loads(path.read_text())
    v, cyl, mech, eff = c["valve"], c["cylinder"], c["mechanics"], c["effects"]
    assert v["flow_form"] == "kq"
    assert "friction" not in eff, "this script has no friction model"
    vd = eff["valve_dynamics"]
    assert vd["order"] == 2
    pi = c["control"]["pi"]
    sp = c["setpoint"]
    assert sp["kind"] == "static_dynamic" and sp.get("sweep") == "log"
    return dict(
        beta=c["fluid"]["bulk_modulus"],
        ps=c["supply"]["pressure"],
        pt=c["supply"].get("tank_pressure", 0.0),
        u_fs=v["command_full_scale"],
        k=v["rated_flow"] / math.sqrt(v["rated_pressure_drop"]),
        dp_lam=v.get("laminar_pressure", 2.0e4),
        s0=eff["valve_deadband"]["zero_offset"],
        wn=vd["natural_frequency"],
        zeta=vd["damping_ratio"],
        k_in=eff["internal_leakage"]["coefficient"],
        a_a=cyl["area_a"],
        a_b=cyl["area_b"],
        v_a0=cyl["dead_volume_a"],
        v_b0=cyl["dead_volume_b"],
        stroke=cyl["stroke"],
        x0=cyl.get("initial_position", 0.0),
        m=mech["mass"],
        c=mech.get("damping", 0.0),
        k_l=mech["load_stiffness"],
        x_c=mech.get("load_contact_position", 0.0),
        kp=pi["kp"],
        ki=pi["integral"],
        g=pi["error_scale"],
        u_min=pi.get("u_min", -10.0),
        u_max=pi.get("u_max", 10.0),
        u_sup=c["supervisor"].get("max_command", 10.0),
        sp_offset=sp["offset"],
        sp_amp=sp["amplitude"],
        sp_ramp=sp["ramp_time"],
        sp_f0=sp["f0"],
        sp_f1=sp["f1"],
        sp_dur=sp["duration"],
        sp_start=sp.get("start", 0.0),
        dt=1.0 / c["run"]["control_rate_hz"],
    )


def make_rhs(P: dict):
    beta, ps, pt, u_fs, k = P["beta"], P["ps"], P["pt"], P["u_fs"], P["k"]
    dpl2 = P["dp_lam"] ** 2
    s0, wn, zeta, k_in = P["s0"], P["wn"], P["zeta"], P["k_in"]
    a_a, a_b, v_a0, v_b0, stroke = P["a_a"], P["a_b"], P["v_a0"], P["v_b0"], P["stroke"]
    m, c, k_l, x_c = P["m"], P["c"], P["k_l"], P["x_c"]
    w2, two_zw = wn * wn, 2.0 * zeta * wn

    def q(o, dp):  # regularised K_q edge law
        return k * o * dp / (dp * dp + dpl2) ** 0.25 if o > 0.0 else 0.0

    def rhs(t, y, u):
        s, sd, pa, pb, x, v = y
        se = s - s0
        o_pos = se if se > 0.0 else 0.0
        o_neg = -se if se < 0.0 else 0.0
        qa = q(o_pos, ps - pa) - q(o_neg, pa - pt)
        qb = q(o_neg, ps - pb) - q(o_pos, pb - pt)
        xc = min(max(x, 0.0), stroke)
        va = v_a0 + a_a * xc
        vb = v_b0 + a_b * (stroke - xc)
        qin = k_in * (pa - pb)
        return np.array(
            [
                sd,
                w2 * (u / u_fs - s) - two_zw * sd,
                beta / va * (qa - a_a * v - qin),
                beta / vb * (qb + a_b * v + qin),
                v,
                (pa * a_a - pb * a_b - k_l * (x - x_c) - c * v) / m,
            ]
        )

    return rhs


def setpoint(P: dict, t: float) -> float:
    if t < P["sp_ramp"]:
        return P["sp_offset"] / max(P["sp_ramp"], 1e-12) * max(t, 0.0)
    td = t - max(P["sp_ramp"], P["sp_start"])
    if td < 0.0:
        return P["sp_offset"]
    t_end = max(P["sp_dur"], 1e-12)
    tt = min(td, t_end)
    r = math.log(P["sp_f1"] / P["sp_f0"]) / t_end
    ph = 2.0 * math.pi * P["sp_f0"] * math.expm1(r * tt) / r
    if td > t_end:
        ph += 2.0 * math.pi * P["sp_f0"] * math.exp(r * tt) * (td - t_end)
    return P["sp_offset"] + P["sp_amp"] * math.sin(ph)


def initial_state(P: dict) -> np.ndarray:
    # 003 eq. 14 force balance at rest with no external force (as Plant::initialize).
    f0 = P["k_l"] * (P["x0"] - P["x_c"])
    alpha = P["a_b"] / P["a_a"]
    p_l = f0 / P["a_a"]
    a3 = alpha**3
    span = P["ps"] - P["pt"]
    pa = P["pt"] + (a3 * span + p_l) / (1.0 + a3)
    pb = P["pt"] + alpha * alpha * (span - p_l) / (1.0 + a3)
    return np.array([0.0, 0.0, pa, pb, P["x0"], 0.0])


# --------------------------------------------------------------------------------------------
# The closed loop: sample, PI, hold the command over one period with solve_ivp
# --------------------------------------------------------------------------------------------
def closed_loop(P, rhs, k0, n, y0, integ0, method, rtol, atol, progress=True):
    dt = P["dt"]
    kp, ki, g = P["kp"], P["ki"], P["g"]
    u_min, u_max, u_sup = P["u_min"], P["u_max"], P["u_sup"]
    y = np.array(y0, dtype=float)
    integ = integ0
    forces = np.empty(n)
    nfev = 0
    t_wall0 = time.perf_counter()
    for i in tqdm(range(n), desc=f"{method} rtol={rtol:g}", disable=not progress, leave=False):
        k = k0 + i
        t = k * dt
        f = P["k_l"] * (y[4] - P["x_c"])  # load cell, noise-free
        forces[i] = f
        # PI, ideal form, backward-Euler integral, clamping anti-windup (pi.rs)
        ev = g * (setpoint(P, t) - f)
        p = kp * ev
        di = kp * ki * dt * ev
        trial = integ + di
        u_trial = p + trial
        u_sat = min(max(u_trial, u_min), u_max)
        if u_trial == u_sat or (u_trial > u_max and di < 0.0) or (u_trial < u_min and di > 0.0):
            integ = trial
        u = min(max(p + integ, u_min), u_max)
        u = min(max(u, -u_sup), u_sup)  # supervisor command limit
        sol = solve_ivp(rhs, (t, t + dt), y, method=method, rtol=rtol, atol=atol, args=(u,))
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            # A loose explicit run can blow up (RK45 at rtol 0.1 on this stiff plant): report
            # it as a failed row instead of aborting the whole table.
            raise SolverFailure(t, sol.message if not sol.success else "non-finite state")
        nfev += sol.nfev
        y = sol.y[:, -1]
    wall = time.perf_counter() - t_wall0
    return forces, wall, nfev


class SolverFailure(RuntimeError):
    def __init__(self, t, message):
        super().__init__(f"solve_ivp failed at t = {t:.4f} s: {message}")
        self.t = t
        self.message = message


def read_csv(path: Path) -> dict:
    a = np.genfromtxt(path, delimiter=",", names=True)
    return {key: np.asarray(a[key], dtype=float) for key in a.dtype.names}


def nrmse(f, ref):
    return math.sqrt(float(np.mean((f - ref) ** 2))) / float(ref.max() - ref.min())


def equal_accuracy(results, rust_timing, rust, ref_f, n):
    """Cheapest SciPy run at least as accurate as each Rust setting, over the same window."""
    if rust_timing is None:
        print("\n(no target/bench/sahu_rust_timing_noisefree.csv: run the Rust bench first for the ratio table)")
        return
    sc = [r for r in results if r["window"] == "start" and not r.get("failed")]
    print("\n### Equal accuracy: Rust (noise-free, median thread CPU time) vs the cheapest SciPy run "
          "(median process CPU time) with NRMSE ≤ Rust's over the same window\n")
    print("| Rust setting | Rust NRMSE | Rust × real time (CPU) | cheapest SciPy run at ≤ that NRMSE | its NRMSE "
          "| SciPy × real time (CPU) | Rust faster by |")
    print("|---|---:|---:|---|---:|---:|---:|")
    for rt in rust_timing:
        key = f"{rt['method']}_s{rt['substeps']}"
        rust_per_s = rt["median_cpu_s"] / rt["duration_s"]
        e_r = nrmse(rust[key]["rod_force"][:n], ref_f) if key in rust else float("nan")
        ok = [r for r in sc if r["nrmse"] <= e_r]
        if ok:
            b = min(ok, key=lambda r: r["cpu_s"] / r["horizon_s"])
            sp = b["cpu_s"] / b["horizon_s"]
            print(f"| {rt['method']} {rt['substeps']} | {100 * e_r:.4f} % | {1 / rust_per_s:.0f}× | {b['method']} "
                  f"rtol {b['rtol']:g} | {100 * b['nrmse']:.4f} % | {1 / sp:.3f}× | {sp / rust_per_s:,.0f}× |")
        else:
            print(f"| {rt['method']} {rt['substeps']} | {100 * e_r:.4f} % | {1 / rust_per_s:.0f}× "
                  f"| none of the runs tried | – | – | – |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs/sahu2022_force.toml"))
    ap.add_argument("--bench-dir", default=str(ROOT / "target/bench"),
                    help="where `cargo bench -p ehactl-tests --bench plant_accuracy -- sahu2022_force` wrote "
                         "sahu_reference_noisefree.csv, sahu_<method>_s<N>_noisefree.csv and sahu_rust_timing_noisefree.csv")
    ap.add_argument("--methods", default="LSODA,BDF,Radau,RK45")
    ap.add_argument("--rtols", default="1e-1,1e-2,1e-3,1e-4,1e-5,1e-6")
    ap.add_argument("--horizon", type=float, default=3.0, help="simulated seconds per window (3 s = the whole run)")
    ap.add_argument("--windows", default="start",
                    help="start (from t = 0) and/or end (last part of the chirp, from the reference state)")
    ap.add_argument("--reps", type=int, default=1, help="timed repetitions per (method, rtol, window); median reported")
    ap.add_argument("--full-duration", type=float, default=3.0, help="simulated time the cost is extrapolated to (s)")
    ap.add_argument("--json", default=str(ROOT / "target/bench/scipy_baseline.json"))
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args()

    P = load_params(Path(args.config))
    rhs = make_rhs(P)
    bench = Path(args.bench_dir)
    ref = read_csv(bench / "sahu_reference_noisefree.csv")
    rust = {}
    tpath = bench / "sahu_rust_timing_noisefree.csv"
    rust_timing = None
    if tpath.exists():
        import csv
        with open(tpath) as fh:
            rust_timing = [dict(method=r["method"], substeps=int(r["substeps"]), duration_s=float(r["duration_s"]),
                                median_wall_s=float(r["median_wall_s"]), median_cpu_s=float(r["median_cpu_s"]))
                           for r in csv.DictReader(fh)]
    for fn in sorted(bench.glob("sahu_*_s*_noisefree.csv")):
        rust[fn.name[len("sahu_"):-len("_noisefree.csv")]] = read_csv(fn)
    dt = P["dt"]
    n = int(round(args.horizon / dt))
    n_total = len(ref["t"])
    # Per-component absolute tolerance: rtol × a typical magnitude of each state
    # (spool fraction, spool rate 1/s, Pa, Pa, m, m/s); a scalar atol cannot serve states
    # that span 1e-6 m to 1e7 Pa.
    scale = np.array([1e-2, 10.0, 1e7, 1e7, 1e-6, 1e-3])

    print(f"# SciPy baseline: python {platform.python_version()}, numpy {np.__version__}, "
          f"scipy {scipy.__version__}, {platform.processor() or platform.machine()}")
    print(f"# window {args.horizon} s = {n} control periods; cost extrapolated ×{args.full_duration / args.horizon:g} "
          f"to {args.full_duration} s; atol = rtol × {scale.tolist()}")
    results = []
    windows = [w for w in args.windows.split(",") if w]
    for w in windows:
        if w == "start":
            k0 = 0
            y0 = initial_state(P)
            integ0 = 0.0
        elif w == "end":
            k0 = n_total - n
            if k0 <= 0:
                raise SystemExit("the `end` window needs --horizon shorter than the reference run")
            y0 = np.array([ref[key][k0] for key in ("spool", "spool_velocity", "p_a", "p_b", "x", "v")])
            integ0 = float(ref["i_term"][k0 - 1])
        else:
            raise SystemExit(f"unknown window {w!r}")
        ref_f = ref["rod_force"][k0:k0 + n]
        print(f"\n## window `{w}`: t = {k0 * dt:.3f} … {(k0 + n) * dt:.3f} s, "
              f"reference range {ref_f.max() - ref_f.min():.1f} N")
        if w == "start":
            print("\nRust (same window, from t = 0), NRMSE vs reference:")
            for key, tr in sorted(rust.items()):
                print(f"  {key}: {100 * nrmse(tr['rod_force'][:n], ref_f):.4f} %")
        rich_f = ref["rod_force_richardson"][k0:k0 + n] if "rod_force_richardson" in ref else ref_f
        print("\n| method | rtol | median wall (s) | s per simulated s | × real time | RHS evals / period "
              "| NRMSE vs reference run | NRMSE vs Richardson-extrapolated reference |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for method in args.methods.split(","):
            for rtol in [float(r) for r in args.rtols.split(",")]:
                walls, cpus = [], []
                try:
                    for _ in range(args.reps):
                        c0 = time.process_time()
                        f, wall, nfev = closed_loop(P, rhs, k0, n, y0, integ0, method, rtol, rtol * scale,
                                                    progress=not args.no_progress)
                        cpus.append(time.process_time() - c0)
                        walls.append(wall)
                except SolverFailure as err:
                    results.append(dict(window=w, method=method, rtol=rtol, failed=True, t_fail=err.t,
                                        message=str(err.message)))
                    print(f"| {method} | {rtol:g} | failed at t = {err.t:.4f} s ({err.message}) | | | | | |",
                          flush=True)
                    continue
                wall = float(np.median(walls))
                e = nrmse(f, ref_f)
                e_rich = nrmse(f, rich_f)
                per_s = wall / (n * dt)
                row = dict(window=w, method=method, rtol=rtol, wall_s=wall, walls_s=walls, horizon_s=n * dt,
                           cpu_s=float(np.median(cpus)), cpu_speed_x_realtime=n * dt / float(np.median(cpus)),
                           wall_per_sim_s=per_s, speed_x_realtime=1.0 / per_s, nfev_per_period=nfev / n,
                           nrmse=e, nrmse_richardson=e_rich)
                results.append(row)
                print(f"| {method} | {rtol:g} | {wall:.2f} | {per_s:.1f} | {1.0 / per_s:.3f}× | {nfev / n:.1f} | "
                      f"{100 * e:.4f} % | {100 * e_rich:.5f} % |", flush=True)
        if w == "start":
            equal_accuracy(results, rust_timing, rust, ref_f, n)
    out = dict(python=platform.python_version(), numpy=np.__version__, scipy=scipy.__version__,
               horizon_s=n * dt, atol_scale=scale.tolist(), results=results,
               rust_start_window_nrmse={k: nrmse(tr["rod_force"][:n], ref["rod_force"][:n]) for k, tr in rust.items()},
               loadavg=os.getloadavg(),
               argv=sys.argv)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1))
    print(f"\n(results in {os.path.relpath(args.json)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
