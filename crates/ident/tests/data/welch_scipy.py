#!/usr/bin/env python3
"""Reference spectra for ehactl-ident's Welch PSD (crates/ident/src/analysis.rs tests), made
by scipy.signal.welch: Hann window (periodic), 50 % overlap, mean removed per segment,
one-sided density (unit²/Hz). Regenerate: python3 crates/ident/tests/data/welch_scipy.py

The test signal is computed from the same formula in the Rust test (integers for the
pseudo-noise so both sides build identical samples up to sin/cos rounding)."""
import json
from pathlib import Path

import numpy as np
import scipy
from scipy.signal import welch


def signal(n: int, dt: float) -> np.ndarray:
    i = np.arange(n)
    t = i * dt
    noise = ((i * 7919) % 101) / 101.0 - 0.5
    return np.sin(2 * np.pi * 50.0 * t) + 0.5 * np.sin(2 * np.pi * 173.3 * t + 1.0) + 0.2 * noise + 0.7


cases = []
for n, dt, seg in [(1000, 1e-3, 300), (3000, 2e-4, 1024), (777, 1.0, 97)]:
    f, p = welch(signal(n, dt), fs=1.0 / dt, window="hann", nperseg=seg, noverlap=seg // 2,
                 detrend="constant", scaling="density", return_onesided=True, average="mean")
    cases.append({"n": n, "dt": dt, "seg": seg, "f": f.tolist(), "psd": p.tolist()})
out = Path(__file__).with_name("welch_scipy.json")
out.write_text(json.dumps({"scipy": scipy.__version__, "cases": cases}))
print(f"wrote {out}")
