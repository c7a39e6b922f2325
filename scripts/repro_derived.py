#!/usr/bin/env python3
"""Derived numbers quoted in REPRODUCTION.md that no ehactl command prints.

Each sub-command recomputes its figures from the seed papers' printed values alone, without
the ehactl binary, so they are an independent check of what the docs say:

  eq17   Sahu 2022 eq. 17 with Table 1 (converged values) in the paper's continuous PI loop
         (K_P 0.57, I 386.24, load-cell gain 0.5097 mV/N): gain and phase crossovers, margins,
         closed-loop -3 dB bandwidth; Merritt's soft-load quantities (omega_h, delta_h, the
         slow pole) that show why eq. 17 does not describe Table 1's stiff load.
  refit  the K_Ct / K_Qv refit: the exact blocked-actuator model (chamber compliance V_t/4beta,
         mass M, damping C, load-cell spring K_L, Table 1's valve) fitted to eq. 17's
         valve-to-force response over 1-300 Hz; largest remaining error in dB and degrees.
  eq20   Sahu 2022 eq. 20 (valve flow curve of fig. 5) at the 785 N operating point against the
         refit K_Qv and Table 1's K_Qv (assumes fig. 5 is at full 10 V opening and P_d is the
         drop per metering edge: neither is stated).
  woods  Sirohi 2003 eq. 12: Woods' approximation of the Bessel ratio against the exact
         B_r = 2 J1(k)/(k J0(k)) (mpmath, independent of ehactl's continued fraction) at
         001's tube (1/8 in x 0.028 in, 2 cSt) and 350 Hz, i.e. omega/omega_v ~ 105.

Usage: python3 scripts/repro_derived.py [eq17|refit|eq20|woods|all] [--json]
Needs numpy; `woods` also mpmath (both in tests/python/requirements.txt).
"""
import argparse
import json
import math
import sys

import numpy as np

# Sahu 2022 Table 1 (converged values) and section 6.1.
M, A_P, V_T, BETA = 0.893, 2.364e-4, 2.364e-6, 1.75e9
K_QV, K_L, C_V, K_CT = 3.33e-3, 4.83e8, 10.587, 1.51e-10
W_NV, ZETA = 1507.9, 0.59
G_VN, K_P, I_GAIN = 0.5097e-3, 0.57, 386.24


def valve(s):
    """004 eq. 1 without K_v (K_Qv = K_v K_Q already holds it)."""
    return 1.0 / (s**2 / W_NV**2 + 2 * ZETA / W_NV * s + 1)


def eq17(s, kqv=K_QV, kct=K_CT):
    """004 eq. 17: F_p/v, Merritt's factorisation with omega_h and delta_h of Table 1."""
    wh = math.sqrt(4 * BETA * A_P**2 / (M * V_T))
    dh = kct / A_P * math.sqrt(BETA * M / V_T) + C_V / (4 * A_P) * math.sqrt(V_T / (BETA * M))
    return (kqv / A_P) * (M * s**2 + C_V * s + K_L) * valve(s) / (
        (s**2 / wh**2 + 2 * dh / wh * s + 1) * (s + kct * K_L / A_P**2))


def exact(s, kqv, kct):
    """Exact linear blocked actuator: (V_t/4beta) p_L' = K_Qv v - A_p x' - K_Ct p_L,
    M x'' = A_p p_L - C x' - K_L x, F = K_L x (Merritt ch. 6 without the soft-load step)."""
    return K_L * A_P * kqv * valve(s) / ((V_T / (4 * BETA) * s + kct) * (M * s**2 + C_V * s + K_L) + A_P**2 * s)


def crossing(f, y, level):
    """First f where y crosses `level` (log-linear interpolation on a dense grid)."""
    for i in range(1, len(f)):
        if (y[i - 1] - level) * (y[i] - level) <= 0 and y[i - 1] != y[i]:
            t = (level - y[i - 1]) / (y[i] - y[i - 1])
            return math.exp(math.log(f[i - 1]) + t * (math.log(f[i]) - math.log(f[i - 1])))
    return None


def cmd_eq17():
    f = np.logspace(-1, 4, 400001)
    s = 2j * np.pi * f
    L = K_P * (1 + I_GAIN / s) * G_VN * eq17(s)
    mag = 20 * np.log10(abs(L))
    ph = np.unwrap(np.angle(L)) * 180 / np.pi
    gc = crossing(f, mag, 0.0)
    pm = 180 + np.interp(math.log(gc), np.log(f), ph)
    pc = crossing(f, ph, -180.0)
    gm = -np.interp(math.log(pc), np.log(f), mag)
    T = L / (1 + L)
    bw = crossing(f, 20 * np.log10(abs(T)) - 20 * np.log10(abs(T[0])), -3.0)
    wh = math.sqrt(4 * BETA * A_P**2 / (M * V_T))
    dh = K_CT / A_P * math.sqrt(BETA * M / V_T) + C_V / (4 * A_P) * math.sqrt(V_T / (BETA * M))
    # Real roots of s^2/wh^2 + 2 dh s/wh + 1 (dh > 1: two real poles).
    r = np.roots([1 / wh**2, 2 * dh / wh, 1.0])
    out = {
        "gain_crossover_hz": gc, "phase_margin_deg": pm,
        "phase_crossover_hz": pc, "gain_margin_db": gm,
        "closed_loop_bandwidth_hz": bw,
        "hydraulic_stiffness_N_per_m": 4 * BETA * A_P**2 / V_T,
        "omega_h_rad_s": wh, "delta_h": dh,
        "hydraulic_factor_poles_rad_s": sorted(float(abs(x)) for x in r),
        "free_mass_pole_Ap2_over_KCt_M_rad_s": A_P**2 / (K_CT * M),
        "static_gain_N_per_V": K_QV * A_P / K_CT,
    }
    print("Sahu 2022 eq. 17 with Table 1, continuous PI loop (K_P 0.57, I 386.24, 0.5097 mV/N):")
    print(f"  gain crossover {gc:.1f} Hz, phase margin {pm:.1f} deg")
    print(f"  phase crossover {pc:.1f} Hz, gain margin {gm:.2f} dB")
    print(f"  closed-loop -3 dB bandwidth {bw:.0f} Hz")
    print(f"  hydraulic stiffness 4 beta A_p^2/V_t = {out['hydraulic_stiffness_N_per_m']:.3e} N/m "
          f"(K_L = {K_L:.3e} N/m, ratio {K_L / out['hydraulic_stiffness_N_per_m']:.2f})")
    print(f"  omega_h {wh:.0f} rad/s, delta_h {dh:.1f}; hydraulic factor poles "
          f"{out['hydraulic_factor_poles_rad_s'][0]:.0f} and {out['hydraulic_factor_poles_rad_s'][1]:.3e} rad/s; "
          f"A_p^2/(K_Ct M) = {out['free_mass_pole_Ap2_over_KCt_M_rad_s']:.0f} rad/s "
          f"({out['free_mass_pole_Ap2_over_KCt_M_rad_s'] / (2 * math.pi):.1f} Hz)")
    print(f"  static gain K_Qv A_p/K_Ct = {out['static_gain_N_per_V']:.1f} N/V")
    return out


def nelder_mead(fun, x0, step=0.1, iters=2000, tol=1e-12):
    """Plain Nelder-Mead (numpy only, so the script needs no scipy)."""
    n = len(x0)
    pts = [np.array(x0, float)] + [np.array(x0, float) + step * np.eye(n)[i] for i in range(n)]
    vals = [fun(p) for p in pts]
    for _ in range(iters):
        order = np.argsort(vals)
        pts = [pts[i] for i in order]
        vals = [vals[i] for i in order]
        if abs(vals[-1] - vals[0]) < tol:
            break
        c = sum(pts[:-1]) / n
        xr = c + (c - pts[-1])
        fr = fun(xr)
        if fr < vals[0]:
            xe = c + 2 * (c - pts[-1])
            fe = fun(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = c + 0.5 * (pts[-1] - c)
            fc = fun(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                pts = [pts[0] + 0.5 * (p - pts[0]) for p in pts]
                vals = [fun(p) for p in pts]
    i = int(np.argmin(vals))
    return pts[i], vals[i]


def cmd_refit():
    f = np.logspace(0, math.log10(300), 300)
    s = 2j * np.pi * f
    ref = eq17(s)

    def err(kqv, kct):
        r = exact(s, kqv, kct) / ref
        return 20 * np.log10(abs(r)), np.angle(r) * 180 / np.pi

    def cost(z):
        db, deg = err(math.exp(z[0]), math.exp(z[1]))
        return float(np.mean(db**2) + np.mean((deg / 10.0) ** 2))  # 1 dB ~ 10 deg

    z, _ = nelder_mead(cost, [math.log(4e-6), math.log(2e-13)])
    kqv, kct = math.exp(z[0]), math.exp(z[1])
    db, deg = err(kqv, kct)
    # Literal Table 1 in the exact model, for contrast.
    db_lit, deg_lit = err(K_QV, K_CT)
    out = {
        "K_Qv_m3_s_V": kqv, "K_Ct_m3_s_Pa": kct,
        "max_abs_error_db": float(max(abs(db))), "max_abs_error_deg": float(max(abs(deg))),
        "static_gain_N_per_V": kqv * A_P / kct,
        "dominant_pole_rad_s": kct / (V_T / (4 * BETA) + A_P**2 / K_L),
        "table1_literal_max_error_db": float(max(abs(db_lit))),
    }
    print("Sahu 2022: exact blocked-actuator model fitted to eq. 17 (Table 1) over 1-300 Hz:")
    print(f"  K_Qv = {kqv:.4g} m^3/s/V, K_Ct = {kct:.4g} m^3/(s Pa)")
    print(f"  largest error {out['max_abs_error_db']:.3f} dB, {out['max_abs_error_deg']:.3f} deg")
    print(f"  static gain K_Qv A_p/K_Ct = {out['static_gain_N_per_V']:.1f} N/V; dominant pole "
          f"K_Ct/(V_t/4beta + A_p^2/K_L) = {out['dominant_pole_rad_s']:.0f} rad/s")
    print(f"  (Table 1 literally in the exact model: up to {out['table1_literal_max_error_db']:.1f} dB off eq. 17)")
    return out


def cmd_eq20(kqv_refit=4.129e-6):
    p_l = 785.0 / A_P  # Pa, load pressure holding 785 N
    p_d = (20e6 - p_l) / 2  # Pa per edge, 20 MPa supply (004 section 5.2)
    q = 1.4075e-4 * (p_d / 1e6) ** 0.4667  # m^3/s, 004 eq. 20 (P_d in MPa)
    kqv_curve = q / 10.0  # m^3/s/V at 10 V
    out = {"load_pressure_Pa": p_l, "edge_drop_Pa": p_d, "flow_m3_s": q,
           "K_Qv_curve_m3_s_V": kqv_curve, "curve_over_refit": kqv_curve / kqv_refit,
           "table1_over_curve": K_QV / kqv_curve}
    print(f"Sahu 2022 eq. 20 at 785 N: p_L {p_l / 1e6:.2f} MPa, {p_d / 1e6:.2f} MPa per edge, Q {q:.3e} m^3/s")
    print(f"  K_Qv from the curve (10 V) {kqv_curve:.3e} m^3/s/V: {out['curve_over_refit']:.1f} x the refit's "
          f"{kqv_refit:.3e}; Table 1's {K_QV:.2e} is {out['table1_over_curve']:.0f} x the curve's")
    return out


def cmd_woods():
    import mpmath

    nu, d, f = 2e-6, 0.125 * 0.0254 - 2 * 0.028 * 0.0254, 350.0
    r = d / 2
    wv = 8 * nu / r**2  # 001 eq. 10 read with the radius (see REPRODUCTION.md, method notes)
    w = 2 * math.pi * f
    dv = mpmath.mpc(0, w / wv)  # D_v = s/omega_v at s = j omega
    k = 1j * mpmath.sqrt(8 * dv)
    br_exact = 2 * mpmath.besselj(1, k) / (k * mpmath.besselj(0, k))
    br_woods = 1 / mpmath.sqrt(1 + 2 * dv)
    fe = 1 / mpmath.sqrt(1 - br_exact)
    fw = 1 / mpmath.sqrt(1 - br_woods)
    re = float(abs(fw.real / fe.real - 1))
    im = float(abs(fw.imag / fe.imag - 1))
    out = {"omega_over_omega_v": w / wv, "tube_id_m": d,
           "factor_exact": [float(fe.real), float(fe.imag)],
           "factor_woods": [float(fw.real), float(fw.imag)],
           "real_part_rel_diff": re, "imag_part_rel_diff": im}
    print(f"Sirohi 2003 eq. 12 at 350 Hz, 2 cSt, ID {d * 1e3:.3f} mm: omega/omega_v = {w / wv:.1f}")
    print(f"  (1 - B_r)^-1/2 exact (mpmath Bessel) {complex(fe):.6f}, Woods {complex(fw):.6f}")
    print(f"  real (inertance) part differs by {100 * re:.4f} %, imaginary (loss) part by {100 * im:.2f} %")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", nargs="?", default="all", choices=["eq17", "refit", "eq20", "woods", "all"])
    ap.add_argument("--json", action="store_true", help="print one JSON object at the end")
    a = ap.parse_args()
    res = {}
    for name, fn in (("eq17", cmd_eq17), ("refit", cmd_refit), ("eq20", cmd_eq20), ("woods", cmd_woods)):
        if a.what in (name, "all"):
            res[name] = fn()
    if a.json:
        json.dump(res, sys.stdout)
        print()


if __name__ == "__main__":
    main()
