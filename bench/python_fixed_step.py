#!/usr/bin/env python3
"""Plain-Python fixed-step loop of ehactl's `linear_exact` scheme on sahu2022_force.

The "what a user would write" baseline next to ``bench/scipy_baseline.py``: the same plant,
PI and setpoint as ``bench/scipy_baseline.py`` (noise and tones off), integrated with the SAME
scheme as crates/plant/src/exact.rs + model.rs ``advance_substep_linear``:

  spool     exact zero-order-hold transition of the 2nd-order spool over h and h/2;
  valve     K_q edge flows at the mid-step spool position, linearised in the port pressure,
            evaluated at the step-mean pressures of the exact linear solution;
  chambers  z = (p_A, p_B, x, v) advanced by z ← Φ z + Γ w, w = (Q_A, Q_B, 0, 1), Φ, Γ and the
            step means from one expm of the augmented matrix (scipy.linalg.expm), recomputed when
            β/V of a chamber drifts by more than 1e-3 (as REDISCRETISE_TOL);

with the per-step arithmetic in plain Python floats (no NumPy in the loop: on 4-element
vectors NumPy's call overhead is larger than the arithmetic). Same algorithm and substeps as the
Rust run, so the same accuracy: the script checks that by the NRMSE of its force against the
Rust reference, and against the Rust trace of the same setting (≈ 1e-12 %: round-off).

Usage (after ``cargo bench -p ehactl-tests --bench plant_accuracy -- sahu2022_force``, which
writes target/bench/sahu_reference_noisefree.csv and the Rust trace/timing files):

  python3 bench/python_fixed_step.py --substeps 2 --reps 3
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np
from scipy.linalg import expm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scipy_baseline import ROOT, initial_state, load_params, nrmse, read_csv, setpoint  # noqa: E402

TOL = 1e-3


def spool_maps(P, h):
    w, z = P["wn"], P["zeta"]
    m = np.zeros((3, 3))
    m[0, 1] = 1.0
    m[1, 0] = -w * w
    m[1, 1] = -2.0 * z * w
    m[1, 2] = w * w
    e = expm(m * h)
    return e[:2, :2].tolist(), e[:2, 2].tolist()


def linear_maps(P, h, ca, cb):
    """Φ (4×4), Γ (4×4), and rows p_A, p_B of the step means (Ψ/h, Λ/h)."""
    a_a, a_b, k_in, m, c, k_l, x_c = P["a_a"], P["a_b"], P["k_in"], P["m"], P["c"], P["k_l"], P["x_c"]
    A = np.zeros((4, 4))
    B = np.zeros((4, 4))
    A[0, 0], A[0, 1], A[0, 3], B[0, 0] = -ca * k_in, ca * k_in, -ca * a_a, ca
    A[1, 0], A[1, 1], A[1, 3], B[1, 1] = cb * k_in, -cb * k_in, cb * a_b, cb
    A[2, 3] = 1.0
    A[3, 0], A[3, 1], A[3, 2], A[3, 3] = a_a / m, -a_b / m, -k_l / m, -c / m
    B[3, 2], B[3, 3] = -1.0 / m, k_l * x_c / m
    M = np.zeros((12, 12))
    M[:4, :4] = A * h
    M[:4, 4:8] = B * h
    M[8:12, :4] = np.eye(4) * h
    # Scale pressures to MPa and positions to µm so that expm sees a balanced matrix.
    d = np.array([1e6, 1e6, 1e-6, 1e-3, 1e-6, 1e-6, 1.0, 1.0, 1e6, 1e6, 1e-6, 1e-3])
    E = expm(M * d[None, :] / d[:, None]) * d[:, None] / d[None, :]
    phi = E[:4, :4].tolist()
    gam = E[:4, 4:8].tolist()
    psi = (E[8:10, :4] / h).tolist()
    lam = (E[8:10, 4:8] / h).tolist()
    return phi, gam, psi, lam


def run(P, n_cycles, substeps):
    dt = P["dt"]
    h = dt / substeps
    ps, pt, u_fs, k = P["ps"], P["pt"], P["u_fs"], P["k"]
    dpl2 = P["dp_lam"] ** 2
    s0 = P["s0"]
    a_a, a_b, v_a0, v_b0, stroke, beta = P["a_a"], P["a_b"], P["v_a0"], P["v_b0"], P["stroke"], P["beta"]
    k_l, x_c = P["k_l"], P["x_c"]
    kp, ki, g = P["kp"], P["ki"], P["g"]
    u_min, u_max, u_sup = P["u_min"], P["u_max"], P["u_sup"]
    (f00, f01), (f10, f11) = spool_maps(P, h)[0]
    g0, g1 = spool_maps(P, h)[1]
    (hf00, hf01), (hf10, hf11) = spool_maps(P, 0.5 * h)[0]
    hg0, hg1 = spool_maps(P, 0.5 * h)[1]

    def edge(o, dp):
        if o <= 0.0:
            return 0.0, 0.0
        s2 = dp * dp + dpl2
        gg = 1.0 / math.sqrt(math.sqrt(s2))
        return k * o * dp * gg, k * o * gg * (0.5 * dp * dp + dpl2) / s2

    y = initial_state(P).tolist()
    s, sd, pa, pb, x, v = y
    x0c = min(max(x, 0.0), stroke)
    ca_used = beta / (v_a0 + a_a * x0c)
    cb_used = beta / (v_b0 + a_b * (stroke - x0c))
    phi, gam, psi, lam = linear_maps(P, h, ca_used, cb_used)
    n_disc = 1
    integ = 0.0
    forces = [0.0] * n_cycles
    for i in range(n_cycles):
        t = i * dt
        f = k_l * (x - x_c)
        forces[i] = f
        ev = g * (setpoint(P, t) - f)
        p = kp * ev
        di = kp * ki * dt * ev
        trial = integ + di
        u_trial = p + trial
        u_sat = min(max(u_trial, u_min), u_max)
        if u_trial == u_sat or (u_trial > u_max and di < 0.0) or (u_trial < u_min and di > 0.0):
            integ = trial
        u = min(max(p + integ, u_min), u_max)
        u = min(max(u, -u_sup), u_sup)
        target = u / u_fs
        for _ in range(substeps):
            sm = hf00 * s + hf01 * sd + hg0 * target
            s, sd = f00 * s + f01 * sd + g0 * target, f10 * s + f11 * sd + g1 * target
            se = sm - s0
            o_pos = se if se > 0.0 else 0.0
            o_neg = -se if se < 0.0 else 0.0
            xc = min(max(x, 0.0), stroke)
            ca = beta / (v_a0 + a_a * xc)
            cb = beta / (v_b0 + a_b * (stroke - xc))
            if abs(ca - ca_used) > TOL * ca_used or abs(cb - cb_used) > TOL * cb_used:
                ca_used, cb_used = ca, cb
                phi, gam, psi, lam = linear_maps(P, h, ca, cb)
                n_disc += 1
            qi, dqi = edge(o_pos, ps - pa)
            qo, dqo = edge(o_neg, pa - pt)
            qa, dqa = qi - qo, -dqi - dqo
            qi, dqi = edge(o_neg, ps - pb)
            qo, dqo = edge(o_pos, pb - pt)
            qb, dqb = qi - qo, -dqi - dqo
            z = (pa, pb, x, v)
            w = (qa, qb, 0.0, 1.0)
            pm_a = sum(psi[0][j] * z[j] for j in range(4)) + sum(lam[0][j] * w[j] for j in range(4))
            pm_b = sum(psi[1][j] * z[j] for j in range(4)) + sum(lam[1][j] * w[j] for j in range(4))
            qa = qa + dqa * (pm_a - pa) / (1.0 - dqa * lam[0][0])
            qb = qb + dqb * (pm_b - pb) / (1.0 - dqb * lam[1][1])
            w = (qa, qb, 0.0, 1.0)
            pa, pb, x, v = (
                sum(phi[r][j] * z[j] for j in range(4)) + sum(gam[r][j] * w[j] for j in range(4))
                for r in range(4)
            )
    return np.array(forces), n_disc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs/sahu2022_force.toml"))
    ap.add_argument("--bench-dir", default=str(ROOT / "target/bench"))
    ap.add_argument("--substeps", default="1,2", help="comma-separated substep counts")
    ap.add_argument("--horizon", type=float, default=3.0, help="simulated s (from t = 0)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--json", default=str(ROOT / "target/bench/python_fixed_step.json"))
    args = ap.parse_args()
    P = load_params(Path(args.config))
    bench = Path(args.bench_dir)
    ref = read_csv(bench / "sahu_reference_noisefree.csv")
    n = int(round(args.horizon / P["dt"]))
    ref_f = ref["rod_force"][:n]
    print(f"# plain-Python fixed-step linear_exact: python {platform.python_version()}, "
          f"numpy {np.__version__}; load average {os.getloadavg()}")
    print("| substeps | NRMSE vs reference | NRMSE vs Rust trace (same setting) | median wall (s) "
          "| median process CPU (s) | × real time (CPU) | discretisations |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    rows = []
    for ns in [int(v) for v in args.substeps.split(",") if v]:
        walls, cpus = [], []
        for _ in range(args.reps):
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            t0 = time.perf_counter()
            f, nd = run(P, n, ns)
            walls.append(time.perf_counter() - t0)
            r1 = resource.getrusage(resource.RUSAGE_SELF)
            cpus.append((r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
        rust_path = bench / f"sahu_linear_exact_s{ns}_noisefree.csv"
        e_rust = nrmse(f, read_csv(rust_path)["rod_force"][:n]) if rust_path.exists() else float("nan")
        e = nrmse(f, ref_f)
        row = dict(substeps=ns, nrmse=e, nrmse_vs_rust=e_rust, wall_s=float(np.median(walls)),
                   cpu_s=float(np.median(cpus)), horizon_s=n * P["dt"], discretisations=nd)
        rows.append(row)
        print(f"| {ns} | {100 * e:.4f} % | {100 * e_rust:.1e} % | {row['wall_s']:.2f} | {row['cpu_s']:.2f} "
              f"| {row['horizon_s'] / row['cpu_s']:.2f}× | {nd} |", flush=True)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(dict(results=rows, argv=sys.argv, loadavg=os.getloadavg()), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
