#!/usr/bin/env python3
"""Sizing figures as inspection tools state them (API 1163, POF 100: a tolerance at a
certainty, e.g. "±1 % of OD at 80 % confidence"), from a run's `trials.csv`.

    python3 scripts/ili-figures.py results/noise_models [results/contamination ...]

For each swept value and method, over its converged trials: the 80th percentile of |error|
of Dmax, Dmin and the mean diameter, in mm and as % of the nominal OD (the scenario's
`[pipe] nominal_od_in`), and how often the reported 1-σ's 80 % interval (±1.2816σ̂) held
the error of Dmax and Dmin (0.80 for an honest 1-σ). Prints a Markdown table. Needs only
the standard library.
"""
import csv
import math
import sys
import tomllib
from pathlib import Path

Z80 = 1.2816  # two-sided 80 % normal quantile


def p80(v):
    """The 80th percentile (linear interpolation between order statistics)."""
    v = sorted(v)
    if not v:
        return math.nan
    h = 0.8 * (len(v) - 1)
    lo = int(h)
    return v[lo] + (h - lo) * (v[min(lo + 1, len(v) - 1)] - v[lo])


def main(dirs):
    print("| run | value | method | converged | Dmax p80 mm (% OD) | Dmin p80 mm (% OD) | Dmean p80 mm (% OD) | ±1.28σ̂ held Dmax / Dmin |")
    print("|---|---|---|---|---|---|---|---|")
    for d in map(Path, dirs):
        scenario = tomllib.loads((d / "scenario.toml").read_text())
        od_mm = scenario["pipe"]["nominal_od_in"] * 25.4
        groups = {}
        with open(d / "trials.csv", newline="") as f:
            for r in csv.DictReader(f):
                if r["status"] != "converged" or not r["err_dmax_mm"]:
                    continue
                groups.setdefault((r["sweep_value"], r["method"]), []).append(r)
        for (value, method), rows in groups.items():
            cells = []
            for key in ("err_dmax_mm", "err_dmin_mm", "err_dmean_mm"):
                q = p80([abs(float(r[key])) for r in rows])
                cells.append(f"{q:.3f} ({100 * q / od_mm:.4f} %)")
            held = []
            for key, s in (("err_dmax_mm", "sigma_dmax_mm"), ("err_dmin_mm", "sigma_dmin_mm")):
                ok = [abs(float(r[key])) <= Z80 * float(r[s]) for r in rows if r[s]]
                held.append(f"{sum(ok) / len(ok):.2f}" if ok else "—")
            print(f"| {d.name} | {value} | {method} | {len(rows)} | {' | '.join(cells)} | {' / '.join(held)} |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
