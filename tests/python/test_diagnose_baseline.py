"""The ARX baseline of `ehactl diagnose` checked against an independent implementation:
numpy least squares (`numpy.linalg.lstsq`) on the same regressors, a free-run simulation
written here, and the order choice (Akaike's criterion on the free-run error over the fitting
part) recomputed over every order. Data: the Sjöberg actuator record (estimation half fitted,
validation half held out) and the UTFSM MTS 1 A record (last 30 % held out, input `ref`, outputs
`x` and the load-cell `force`)."""
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
SJ = REPO / "tests" / "data" / "measured" / "sjoberg"
MTS = REPO / "tests" / "data" / "measured" / "utfsm_mts"


def diagnose(*args):
    r = subprocess.run([BIN, "diagnose", *args, "--json"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def lstsq_arx(u, y, na, nb, nk, n):
    """Ljung (1999) eq. 4.7 with a constant, least squares on samples 0..n."""
    lag = max(na, nk + nb - 1)
    phi = np.array(
        [[-y[k - 1 - i] for i in range(na)] + [u[k - nk - j] for j in range(nb)] + [1.0] for k in range(lag, n)]
    )
    scale = np.abs(phi).max(axis=0)  # column scaling only: same least-squares solution
    th, *_ = np.linalg.lstsq(phi / scale, np.asarray(y[lag:n]), rcond=None)
    th = th / scale
    return th[:na], th[na : na + nb], th[-1]


def simulate(a, b, c, u, y0, nk):
    na, nb = len(a), len(b)
    lag = max(na, nk + nb - 1)
    y = list(y0[:lag])
    for k in range(lag, len(u)):
        y.append(c - sum(a[i] * y[k - 1 - i] for i in range(na)) + sum(b[j] * u[max(k - nk - j, 0)] for j in range(nb)))
    return np.array(y)


def nrmse(y, yh):
    return float(np.sqrt(np.mean((y - yh) ** 2)) / np.std(y))


def check(d, u_fit, y_fit, u_val, y_val, val_slice, channel=None):
    models = d["baseline"]["models"]
    if channel is None:
        (m,) = models
    else:
        (m,) = [m for m in models if m["channel"] == channel]
    n = len(u_fit)
    # Order choice recomputed independently over every order.
    best = None
    for na in range(1, 5):
        for nb in range(1, 5):
            for nk in range(1, 5):
                a, b, c = lstsq_arx(u_fit, y_fit, na, nb, nk, n)
                e = nrmse(y_fit, simulate(a, b, c, u_fit, y_fit, nk))
                aic = n * np.log(e * e) + 2 * (na + nb + 1)
                if best is None or aic < best[0]:
                    best = (aic, na, nb, nk)
    assert (m["na"], m["nb"], m["nk"]) == best[1:], (m, best)
    a, b, c = lstsq_arx(u_fit, y_fit, m["na"], m["nb"], m["nk"], n)
    np.testing.assert_allclose(m["a"], a, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(m["b"], b, rtol=1e-6)
    assert c == pytest.approx(m["c"], rel=1e-5, abs=1e-9 * np.abs(y_fit).max())
    yh = simulate(a, b, c, u_val, y_val, m["nk"])
    e = nrmse(y_val[val_slice], yh[val_slice])
    if channel is None:
        assert d["nrmse_baseline"]["overall"] == pytest.approx(e, rel=1e-5)
    else:
        assert d["nrmse_baseline"]["channels"][channel] == pytest.approx(e, rel=1e-5)
    return e


def test_arx_baseline_sjoberg_matches_numpy():
    d = diagnose(
        "--config", str(REPO / "configs" / "sjoberg1995_actuator.toml"),
        "--data", str(SJ / "estimation.csv"), "--validate", str(SJ / "validation.csv"),
    )
    est = np.genfromtxt(SJ / "estimation.csv", delimiter=",", names=True)
    val = np.genfromtxt(SJ / "validation.csv", delimiter=",", names=True)
    e = check(d, est["u"], est["p_a"], val["u"], val["p_a"], slice(0, None))
    # A linear ARX on this split lands near 0.6 (ARX(2,2,1) measured 0.635).
    assert 0.5 < e < 0.7, e


def test_arx_baseline_mts_matches_numpy(diagnosis):
    f = MTS / "1A_5to15s.csv"
    d, _ = diagnosis("--config", REPO / "configs" / "utfsm_mts_mrdamper.toml", "--data", f)
    rec = np.genfromtxt(f, delimiter=",", names=True)
    n = len(rec)
    n_fit = int(round(0.7 * n))
    e = check(d, rec["ref"][:n_fit], rec["x"][:n_fit], rec["ref"], rec["x"], slice(n_fit, None), "x")
    assert e < 0.05, e
    # The load-cell force (kept since 2026-11-23): a linear ARX from `ref` cannot follow the
    # MR damper's yield force, so it explains little of it.
    ef = check(d, rec["ref"][:n_fit], rec["force"][:n_fit], rec["ref"], rec["force"], slice(n_fit, None), "force")
    assert 0.5 < ef < 1.0, ef
    assert d["nrmse_baseline"]["overall"] == pytest.approx(np.sqrt((e * e + ef * ef) / 2), rel=1e-5)
