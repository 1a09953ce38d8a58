#!/usr/bin/env python3
"""The tables of docs/bends-and-tees.md "What the survey reads" from a run's files.

- From `results/straight_false_alarm/summary.csv` (one row per pipe and noise model,
  `geometry_frames` and `false_alarms`): the false alarms per noise model (over the
  pipe sizes), per pipe size and over every frame, each with its rate, binomial standard
  error √(p̂(1 − p̂)/n) and one-sided 95 % Clopper–Pearson upper bound (the p at which
  P(X ≤ k | n, p) = 0.05), as bench-harness computes them per row. The swept values'
  labels are `"<pipe> / <model>"`.
- From `results/{elbow_approach,tee_pass}/confusion.csv` and the false-alarm run: the
  confusion matrix, true scene × reported geometry, by distance.

Python 3.9+, standard library only:

    python3 scripts/geometry-tables.py [RESULTS_DIR]
"""

from __future__ import annotations

import csv
import math
import sys
from collections import defaultdict
from pathlib import Path

GEOMETRIES = ["straight", "bend_ahead", "tee_ahead", "in_bend"]


def binomial_cdf(k: int, n: int, p: float) -> float:
    """P(X ≤ k), X ~ Binomial(n, p), summed in log space."""
    if p <= 0.0:
        return 1.0
    if p >= 1.0:
        return 1.0 if k >= n else 0.0
    log_term = n * math.log1p(-p)
    terms = [log_term]
    for j in range(min(k, n)):
        log_term += math.log((n - j) / (j + 1)) + math.log(p / (1 - p))
        terms.append(log_term)
    top = max(terms)
    return min(1.0, math.exp(top) * sum(math.exp(t - top) for t in terms))


def upper95(k: int, n: int) -> float:
    """The one-sided 95 % Clopper–Pearson upper bound on a rate after k in n."""
    if k >= n:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if binomial_cdf(k, n, mid) > 0.05:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def rate_cells(k: int, n: int) -> str:
    p = k / n
    se = math.sqrt(p * (1 - p) / n)
    return f"{k} / {n} | {100 * p:.2f} % | {100 * se:.2f} % | {100 * upper95(k, n):.2f} %"


def false_alarm_tables(results: Path) -> tuple[dict, str]:
    path = results / "straight_false_alarm" / "summary.csv"
    by_value = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row["geometry_frames"] == "":
                continue
            by_value[row["sweep_value"]] = (int(row["false_alarms"]), int(row["geometry_frames"]))
    models, pipes = defaultdict(lambda: [0, 0]), defaultdict(lambda: [0, 0])
    for value, (k, n) in by_value.items():
        pipe, model = value.split(" / ", 1)
        for d, key in ((models, model), (pipes, pipe)):
            d[key][0] += k
            d[key][1] += n
    out = ["| noise model | read otherwise | rate | SE | upper 95 % |", "|---|---:|---:|---:|---:|"]
    out += [f"| {m} | {rate_cells(k, n)} |" for m, (k, n) in models.items()]
    out += ["", "| pipe | read otherwise | rate | SE | upper 95 % |", "|---|---:|---:|---:|---:|"]
    out += [f"| {p} | {rate_cells(k, n)} |" for p, (k, n) in pipes.items()]
    k = sum(v[0] for v in by_value.values())
    n = sum(v[1] for v in by_value.values())
    no_mp = [(kk, nn) for v, (kk, nn) in by_value.items() if "multipath" not in v]
    k2, n2 = sum(x[0] for x in no_mp), sum(x[1] for x in no_mp)
    out += [
        "",
        "| frames | read otherwise | rate | SE | upper 95 % |",
        "|---|---:|---:|---:|---:|",
        f"| all | {rate_cells(k, n)} |",
        f"| all but multipath | {rate_cells(k2, n2)} |",
    ]
    return by_value, "\n".join(out)


def read_trials_geometry(results: Path) -> dict:
    counts = defaultdict(int)
    with open(results / "straight_false_alarm" / "trials.csv", newline="") as f:
        for row in csv.DictReader(f):
            counts[row["geometry"] or "error"] += 1
    return counts


def confusion_table(results: Path) -> str:
    rows = defaultdict(lambda: defaultdict(int))
    order = []
    for run in ("elbow_approach", "tee_pass"):
        with open(results / run / "confusion.csv", newline="") as f:
            for r in csv.DictReader(f):
                key = (r["true_scene"], float(r["distance_m"]))
                if key not in rows:
                    order.append(key)
                rows[key][r["geometry"]] += int(r["count"])
    straight = read_trials_geometry(results)
    head = "| true scene | ahead | " + " | ".join(f"`{g}`" for g in GEOMETRIES) + " | no answer |"
    out = [head, "|---|---:|" + "---:|" * (len(GEOMETRIES) + 1)]
    for scene, d in order:
        cells = [str(rows[(scene, d)][g]) for g in GEOMETRIES]
        out.append(f"| {scene} | {d:g} m | " + " | ".join(cells) + " | — |")
    cells = [str(straight.get(g, 0)) for g in GEOMETRIES]
    out.append(
        "| straight (8\", 20\", 42\", 9 noise models) | — | "
        + " | ".join(cells)
        + f" | {straight.get('error', 0)} |"
    )
    return "\n".join(out)


def main() -> None:
    results = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "results"
    _, tables = false_alarm_tables(results)
    print(tables)
    print()
    print(confusion_table(results))


if __name__ == "__main__":
    main()
