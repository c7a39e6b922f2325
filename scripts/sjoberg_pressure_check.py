#!/usr/bin/env python3
"""What the Sjöberg actuator's pressure error is made of (DIAGNOSIS.md, "Sjöberg et al. 1995
robot-arm actuator"): measured from the data alone and from the traces `ehactl diagnose` writes.

Record: tests/data/measured/sjoberg/actuator.csv (valve opening u, oil pressure p and the
undocumented third signal x, see README_source.md there); the estimation half (samples
0–511) is what the diagnosis fits, the validation half (512–1023) is held out. p is in the
record's units (the config reads it as p_a = 5 MPa − 1 MPa·p).

Prints
1. data only, estimation half: the quasi-static pressure map per direction (22-sample moving
   averages, one ringing period) and the knee where it levels off, per direction, by least
   squares with the knee scanned;
2. data only, whole record: which signal the pressure follows — the first difference of x (a
   velocity, if x is a position) or x itself — and the ratio of the speeds per direction, at
   small openings and where they level off;
3. data only: a Hammerstein model fitted on the estimation half — the one-sided input map of
   point 1 (knees and the positive side's slope ratio scanned) followed by a linear ARX(2,3,1)
   with a constant, chosen by the free-run error on the estimation half — its pole pair
   (frequency, damping ratio) and its held-out NRMSE, against the plain linear ARX;
4. if a diagnose output directory is given (`--out DIR` of
   `ehactl diagnose --config configs/sjoberg1995_actuator.toml
   --data tests/data/measured/sjoberg/estimation.csv
   --validate tests/data/measured/sjoberg/validation.csv`): the held-out error of the
   final model (the traces' `ext_p_a`: catalogue effects plus any accepted grey-box terms)
   split into level offset, gain, lag, frequency bands and direction of the opening; and
   whether the model's pressure follows its own position or its velocity.

Usage: python3 scripts/sjoberg_pressure_check.py [DIAGNOSE_OUT_DIR]
"""
import pathlib
import sys

import numpy as np

SJ = pathlib.Path(__file__).resolve().parents[1] / "tests" / "data" / "measured" / "sjoberg"
DT = 0.01  # s, the config's assumed sample period (the source states none)
W = 22  # samples: one period of the pressure ringing


def smooth(s):
    return np.convolve(s, np.ones(W) / W, "same")


def knee(us, ps, side):
    """Knee k (units of u) of ps ≈ a·clip(us, side) + b·(other side) + c, scanned on 0.01."""
    best = None
    for k in np.arange(0.1, 1.5, 0.01):
        if side < 0:
            cols = [np.minimum(np.maximum(us, -k), 0), np.maximum(us, 0)]
        else:
            cols = [np.maximum(np.minimum(us, k), 0), np.minimum(us, 0)]
        a = np.column_stack(cols + [np.ones_like(us)])
        c, *_ = np.linalg.lstsq(a, ps, rcond=None)
        s = float(np.sum((a @ c - ps) ** 2))
        if best is None or s < best[0]:
            best = (s, k, c[0])
    return best[1], best[2]


def best_lag_corr(a, b, lags=range(-15, 16)):
    """(lag, r) maximising |corr(a[t], b[t + lag])|."""
    a, b = a - a.mean(), b - b.mean()
    m = max(abs(k) for k in lags)
    out = []
    for k in lags:
        out.append((k, float(np.corrcoef(a[m:-m], np.roll(b, -k)[m:-m])[0, 1])))
    return max(out, key=lambda t: abs(t[1]))


def data_only():
    d = np.genfromtxt(SJ / "actuator.csv", delimiter=",", names=True)
    u, p, x = d["u"], d["p"], d["x"]
    print("1. Quasi-static pressure map, estimation half (22-sample moving averages):")
    us, ps = smooth(u)[11:501], smooth(p)[11:501]
    for lo in np.arange(-1.3, 1.3, 0.2):
        m = (us >= lo) & (us < lo + 0.2)
        if m.sum() > 5:
            print(f"   u in [{lo:+.1f}, {lo + 0.2:+.1f}): n = {m.sum():3d}, mean p = {ps[m].mean():+.2f}")
    kn, gn = knee(us, ps, -1)
    kp, gp = knee(us, ps, +1)
    print(f"   knee for u < 0: {kn:.2f} units of u (slope below it {gn:+.2f} p/u); "
          f"for u > 0: {kp:.2f} (slope {gp:+.2f} p/u); |u| reaches {-u[:512].min():.2f} and {u[:512].max():.2f}")
    print("   -> the pressure levels off for negative openings (≈ +1.2) but keeps growing for positive ones")
    dx = np.gradient(x)
    print("2. What the pressure follows (whole record; x undocumented, read as a position):")
    for name, s in (("dx (velocity)", dx), ("x (position)", x), ("u (opening)", u)):
        k, r = best_lag_corr(p, s)
        print(f"   corr(p, {name}) = {r:+.2f} at a lag of {k:+d} samples")
    vs, us_all = smooth(dx), smooth(u)
    small = [vs[(us_all > lo) & (us_all < hi)].mean() / us_all[(us_all > lo) & (us_all < hi)].mean()
             for lo, hi in ((0.1, 0.3), (-0.3, -0.1))]
    sat = [vs[us_all > 0.9].mean(), vs[us_all < -0.9].mean()]
    print(f"   speed per opening at 0.1 < |u| < 0.3: u > 0 {small[0]:+.4f}, u < 0 {small[1]:+.4f} "
          f"(ratio {small[0] / small[1]:.2f}; √2 = 1.41)")
    print(f"   speed where it levels off (|u| > 0.9): u > 0 {sat[0]:+.4f}, u < 0 {sat[1]:+.4f} "
          f"(ratio {abs(sat[0] / sat[1]):.2f})")
    a = np.column_stack([np.maximum(vs, 0), np.minimum(vs, 0), np.ones_like(vs)])[11:-11]
    c, *_ = np.linalg.lstsq(a, smooth(p)[11:-11], rcond=None)
    print(f"   quasi-static p ≈ {c[0]:.0f}·dx⁺ + {c[1]:.0f}·dx⁻ {c[2]:+.2f}: pressure ∝ speed in both directions")
    print("   -> the speed, and with it the pressure, is one-sided: a symmetric valve on a single-rod")
    print("      cylinder of area ratio 1/2 gives a speed ratio of 2 where the flow is limited and √2")
    print("      at small openings (no load); a hypothesis only: x and the cylinder are undocumented")


def arx_fit(u, y, na, nb, nk):
    """Least squares ARX with a constant (Ljung 1999, eq. 4.7)."""
    lag = max(na, nk + nb - 1)
    phi = np.array([[-y[k - 1 - i] for i in range(na)] + [u[k - nk - j] for j in range(nb)] + [1.0]
                    for k in range(lag, len(u))])
    th, *_ = np.linalg.lstsq(phi, y[lag:], rcond=None)
    return th[:na], th[na:na + nb], th[-1]


def arx_sim(a, b, c, u, y0, nk):
    """Free run from the first measured samples."""
    na, nb = len(a), len(b)
    lag = max(na, nk + nb - 1)
    y = list(y0[:lag])
    for k in range(lag, len(u)):
        y.append(c - sum(a[i] * y[k - 1 - i] for i in range(na)) + sum(b[j] * u[max(k - nk - j, 0)] for j in range(nb)))
    return np.array(y)


def nrmse(y, yh):
    return float(np.sqrt(np.mean((y - yh) ** 2)) / y.std())


def hammerstein():
    d = np.genfromtxt(SJ / "actuator.csv", delimiter=",", names=True)
    u, p = d["u"], d["p"]
    ue, pe, uv, pv = u[:512], p[:512], u[512:], p[512:]
    na, nb, nk = 2, 3, 1

    def inmap(s, kn, kp, sp):
        return np.where(s < 0, np.maximum(s, -kn), sp * np.minimum(s, kp))

    best = None
    for kn in np.arange(0.3, 1.5, 0.05):
        for kp in (0.6, 0.8, 1.0, 1.2, 1.5):
            for sp in (1.0, 1.5, 2.0, 2.5):
                w = inmap(ue, kn, kp, sp)
                a, b, c = arx_fit(w, pe, na, nb, nk)
                if np.max(np.abs(np.roots(np.r_[1.0, a]))) >= 1.0:
                    continue
                e = nrmse(pe, arx_sim(a, b, c, w, pe, nk))
                if best is None or e < best[0]:
                    best = (e, kn, kp, sp, a, b, c)
    e, kn, kp, sp, a, b, c = best
    z = np.roots(np.r_[1.0, a])
    s = np.log(z[np.argmax(z.imag)]) / DT
    held = nrmse(pv, arx_sim(a, b, c, inmap(uv, kn, kp, sp), pv, nk))
    al, bl, cl = arx_fit(ue, pe, na, nb, nk)
    lin = nrmse(pv, arx_sim(al, bl, cl, uv, pv, nk))
    print("3. Hammerstein model (one-sided input map, then ARX(2,3,1)), fitted on the estimation half:")
    print(f"   input map: knee {kn:.2f} for u < 0, {kp:.2f} for u > 0, positive slope {sp:.1f}× the negative;"
          f" pole pair {abs(s) / (2 * np.pi):.2f} Hz, ζ = {-s.real / abs(s):.2f}")
    print(f"   NRMSE estimation (free run) {e:.3f}, held out {held:.3f}; the same ARX on u alone: held out {lin:.3f}")
    print("   -> a one-sided static map and one lightly damped mode explain most of the pressure")


def band_shares(r, y):
    f = np.fft.rfftfreq(len(r), DT)
    rp = np.abs(np.fft.rfft(r - r.mean())) ** 2
    yp = np.abs(np.fft.rfft(y - y.mean())) ** 2
    out = []
    for lo, hi in ((0, 1), (1, 2.5), (2.5, 3.5), (3.5, 5.5), (5.5, 50)):
        m = (f >= lo) & (f < hi)
        out.append(f"{lo}–{hi} Hz: {rp[m].sum() / rp.sum():.0%} of the residual, {yp[m].sum() / yp.sum():.0%} of the signal")
    return "; ".join(out)


def traces(out):
    print(f"4. Final model of {out} (the `ext_p_a` traces: catalogue effects plus any accepted grey-box terms):")
    for fname, part in (("traces.csv", "estimation half"), ("validation_traces.csv", "validation half (held out)")):
        t = np.genfromtxt(out / fname, delimiter=",", names=True)
        y = 5.0 - t["meas_p_a"] / 1e6
        yh = 5.0 - t["ext_p_a"] / 1e6
        r = y - yh
        sd = y.std()
        a = np.column_stack([yh, np.ones_like(yh)])
        c, *_ = np.linalg.lstsq(a, y, rcond=None)
        lag = min(range(-8, 9), key=lambda k: np.mean((y[10:-10] - np.roll(yh, k)[10:-10]) ** 2))
        print(f"   {part}: NRMSE {np.sqrt(np.mean(r ** 2)) / sd:.3f}; mean residual {r.mean():+.2f} "
              f"(without it {np.sqrt(np.mean((r - r.mean()) ** 2)) / sd:.3f}); best affine correction "
              f"p ≈ {c[0]:.2f}·model {c[1]:+.2f} -> {np.sqrt(np.mean((y - a @ c) ** 2)) / sd:.3f}; "
              f"best shift {lag:+d} samples; std model/measured {yh.std() / sd:.2f}")
        print(f"      bands: {band_shares(r, y)}")
        for lab, m in (("u > +0.2", t["u"] > 0.2), ("u < −0.2", t["u"] < -0.2)):
            print(f"      {lab}: mean measured {y[m].mean():+.2f}, mean model {yh[m].mean():+.2f}")
        if part.startswith("estimation"):
            v = t["v_model"]
            xm = np.cumsum(v) * DT
            print(f"      corr(model pressure, model position) = {np.corrcoef(yh, xm)[0, 1]:+.2f}, "
                  f"corr(model pressure, model velocity) = {np.corrcoef(yh, v)[0, 1]:+.2f}")


def main():
    data_only()
    hammerstein()
    if len(sys.argv) > 1:
        traces(pathlib.Path(sys.argv[1]))


if __name__ == "__main__":
    main()
