#!/usr/bin/env python3
"""Transfer table of `ehactl diagnose` on the UTFSM MTS records (DIAGNOSIS.md "Transfer"):
fit on one segment or record, predict another it never saw, per channel against the ARX
baseline fitted on the same fitting data.

Segments of each raw chirp file (1 kHz, decimated to 500 Hz as scripts/convert_measured.py
does; the same scalings and assumptions): `low` = 5–15 s (the shipped 0.4–2 Hz part) and
`high` = 15–25 s (the next, faster part of the same sweep). Pairs: low → high and high → low
of each current, and 0 A ↔ 1 A on the low segment (the yield force changes with the current,
so that pair measures what a current-independent law cannot carry over).

Usage: python3 scripts/eval_transfer.py DIR_WITH_0A_1A_TXT [--out out/transfer]
  (DIR: the raw files of the public repository DanielMaurelE/vRTHS_AMBC_MRdamper,
  Cap6_ModeloActuador/Preprocesamiento/Datos/; tests/data/measured/utfsm_mts/README_source.md)
Writes OUT/table.md and OUT/table.json; prints the table.
"""
import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

from convert_measured import mts_columns, write  # same directory: the same conversion

REPO = pathlib.Path(__file__).resolve().parents[1]
BIN = os.environ.get("EHACTL_BIN", "ehactl")
CONFIG = REPO / "configs" / "utfsm_mts_mrdamper.toml"
SEGMENTS = {"low": (5.0, 15.0), "high": (15.0, 25.0)}


def segment(src: pathlib.Path, t0: float, t1: float, dst: pathlib.Path) -> None:
    write(dst, mts_columns(src, t0, t1))


def diagnose(fit: pathlib.Path, val: pathlib.Path) -> dict:
    t = time.monotonic()
    r = subprocess.run(
        [BIN, "diagnose", "--config", str(CONFIG), "--data", str(fit), "--validate", str(val), "--json"],
        capture_output=True, text=True, check=False,
    )
    if r.returncode != 0:
        sys.exit(f"diagnose {fit.name} → {val.name} failed: {r.stderr}")
    d = json.loads(r.stdout)
    d["_wall_s"] = time.monotonic() - t
    return d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("raw_dir", type=pathlib.Path)
    ap.add_argument("--out", type=pathlib.Path, default=REPO / "out" / "transfer")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    files = {}
    for cur in ("0A", "1A"):
        for seg, (t0, t1) in SEGMENTS.items():
            p = a.out / f"{cur}_{seg}.csv"
            segment(a.raw_dir / f"{cur}.txt", t0, t1, p)
            files[(cur, seg)] = p
    pairs = [
        (("0A", "low"), ("0A", "high")),
        (("0A", "high"), ("0A", "low")),
        (("1A", "low"), ("1A", "high")),
        (("1A", "high"), ("1A", "low")),
        (("0A", "low"), ("1A", "low")),
        (("1A", "low"), ("0A", "low")),
    ]
    rows = []
    for fit, val in pairs:
        d = diagnose(files[fit], files[val])
        gb = d.get("greybox") or {}
        ext = d["nrmse_extended"]["channels"]
        if gb.get("accepted"):
            ext = gb["nrmse_validation"]["channels"]
        for ch in sorted(d["nrmse_nominal"]["channels"]):
            rows.append({
                "fit": "_".join(fit), "predict": "_".join(val), "channel": ch,
                "nominal": d["nrmse_nominal"]["channels"][ch],
                "extended": ext[ch],
                "arx": d["nrmse_baseline"]["channels"].get(ch),
                "cause": d["cause"],
                "terms": [(t["name"], t["value"], t["unit"]) for t in gb.get("terms", [])],
                "wall_s": d["_wall_s"],
            })
        print(f"{'_'.join(fit)} → {'_'.join(val)}: {d['cause']} ({d['_wall_s']:.0f} s)", file=sys.stderr)
    (a.out / "table.json").write_text(json.dumps(rows, indent=1))
    lines = ["| fit on | predict | channel | nominal | extended | ARX | extended / nominal | extended / ARX |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['fit']} | {r['predict']} | {r['channel']} | {r['nominal']:.3f} | {r['extended']:.3f} | "
            f"{r['arx']:.3f} | {r['extended'] / r['nominal']:.2f} | {r['extended'] / r['arx']:.2f} |"
        )
    (a.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
