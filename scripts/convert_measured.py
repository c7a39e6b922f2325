#!/usr/bin/env python3
"""Convert the measured records in tests/data/measured/ to the CSV format of docs/design.md
(t, u, outputs in SI) for `ehactl diagnose`. Every scaling below is an ASSUMPTION (the
sources give no units); it is repeated in the rig configs under configs/.

Sjöberg et al. 1995 robot-arm actuator (actuator.csv: k, u, p, x):
  t   = k · 0.01 s            (sample period not published; assumed 10 ms, see configs/sjoberg1995_actuator.toml)
  u   = valve opening as is   (read as V with command_full_scale = 2: |u| ≤ 1.46 is 73 % opening)
  p_a = 5 MPa − 1 MPa · p     (p is zero-mean and scaled; read as chamber-A pressure around half of a
                               10 MPa supply, 1 unit = 1 MPa, sign chosen so that opening towards A raises p_a)
  x   = not used (undocumented)
Usage: python3 scripts/convert_measured.py [DIR_WITH_MTS_TXT]
Writes sjoberg/estimation.csv (samples 0–511) and sjoberg/validation.csv (512–1023), the split of the literature.

UTFSM MTS press (0A.txt/1A.txt, 1 kHz, CHANNEL0 x_m ×10 mm, CHANNEL1 F ×9806.65 N, CHANNEL2 x_ref ×10 mm):
  u = K_p · (x_ref − x_m) with K_p = 2000 V/m (10 V at 5 mm error): the valve command of the MTS's
      proportional displacement loop, reconstructed because the file holds no valve signal (assumed P-only loop)
  x = 0.05 m + x_m, ref = 0.05 m + x_ref (mid-stroke offset, m)
  force = 9806.65 N/V · CHANNEL1 − F_rest: the load-cell force on the rod in N, with the scale of the
      source's own Preprocesamiento/sincronize.m ("Fuerza medida en N"); F_rest is the mean of the first
      4000 samples (4 s at rest before either sweep starts: 0A.txt starts moving near sample 7700,
      1A.txt near 5300), the zeroing at rest that sincronize.m also does (it subtracts a rest mean).
      Sign: positive when the damper pushes against +x (it correlates positively with the
      velocity, r = 0.70 at 0 A, 0.80 at 1 A), which is the plant's rod-force convention.
  Segment 5–15 s of each file (the sweep's slow start, 2 mm amplitude) decimated to 500 Hz
  (every second sample, as in the earlier conversion, so x and ref are unchanged): the README's
  campaign fits these. The rest of the sweep, 15–30 s, 30–45 s and 45 s to the end (1–20 Hz, the
  amplitude falling to 0.9 mm), is converted the same way for the hold-out by frequency
  (tests/python/test_campaign_holdout.py).
Usage for the MTS part: python3 scripts/convert_measured.py MTS_DIR
  (MTS_DIR: a directory holding 0A.txt and 1A.txt from Cap6_ModeloActuador/Preprocesamiento/Datos/
  of https://github.com/DanielMaurelE/vRTHS_AMBC_MRdamper, commit d412cae0)
Source files: 0A.txt sha256 7ac3fd85ba301805323fc8f20a967ff3e989babcbcd9719b9bf5aa9d734168d1,
              1A.txt sha256 5c25dcda73680c3c793157edfc2c37411a7c5e264ce1b4c28fe227bf5f03ce1a.
"""
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1] / "tests" / "data" / "measured"


def write(path, cols):
    names = list(cols)
    data = np.column_stack([cols[n] for n in names])
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.9g")


def sjoberg():
    d = np.genfromtxt(ROOT / "sjoberg" / "actuator.csv", delimiter=",", names=True)
    t = d["k"] * 0.01
    u = d["u"]
    pa = 5.0e6 - 1.0e6 * d["p"]
    for name, sl in (("estimation", slice(0, 512)), ("validation", slice(512, 1024))):
        write(ROOT / "sjoberg" / f"{name}.csv", {"t": t[sl] - t[sl][0], "u": u[sl], "p_a": pa[sl]})


def mts_columns(src, t0=5.0, t1=15.0):
    """Columns (t, u, x, ref, force; SI) of the t0–t1 s segment of a raw MTS file (t1 None: to
    the file's end), decimated to 500 Hz, with the scalings and assumptions of the module doc."""
    d = np.genfromtxt(src, delimiter=",", skip_header=7, usecols=(2, 3, 4))
    xm = d[:, 0] * 10e-3
    f = d[:, 1] * 9806.65
    xr = d[:, 2] * 10e-3
    f = f - f[:4000].mean()  # load-cell zero at rest (see the module doc)
    end = len(xm) if t1 is None else int(round(t1 * 1000))
    sl = slice(int(round(t0 * 1000)), end, 2)
    t = np.arange(len(xm))[sl] * 1e-3
    return {"t": t - t[0], "u": 2000.0 * (xr[sl] - xm[sl]), "x": 0.05 + xm[sl], "ref": 0.05 + xr[sl], "force": f[sl]}


def coil_current(name):
    """The MR damper's coil current (A) of a test, from its file name (`0A`, `1A`): the
    campaign's operating input, a `current` column (configs/utfsm_mts_mrdamper.toml declares it)."""
    return float(name.rstrip("A"))


# Segments of each MTS file (start s, end s or None for the file's end, file-name tag): the
# fitting segment of the README's campaign first, then the rest of the sweep (held out).
MTS_SEGMENTS = [(5.0, 15.0, "5to15s"), (15.0, 30.0, "15to30s"), (30.0, 45.0, "30to45s"), (45.0, None, "45toEnd")]


def mts(name, src_dir):
    """The raw DAQ files (4 MB each) are not in the repo; pass their directory."""
    src = pathlib.Path(src_dir) / f"{name}.txt"
    if not src.exists():
        print(f"skip MTS {name}: {src} not found", file=sys.stderr)
        return
    for t0, t1, tag in MTS_SEGMENTS:
        cols = mts_columns(src, t0, t1)
        cols["current"] = np.full(len(cols["t"]), coil_current(name))
        write(ROOT / "utfsm_mts" / f"{name}_{tag}.csv", cols)


if __name__ == "__main__":
    sjoberg()
    if len(sys.argv) > 1:  # directory holding the UTFSM 0A.txt / 1A.txt
        mts("0A", sys.argv[1])
        mts("1A", sys.argv[1])
    print("converted", file=sys.stderr)
