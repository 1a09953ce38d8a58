"""Issue 23's scene judgement OFF the grid it was checked on (scripts/approach-grid-numpy.py:
8", 20", 42" pipes, sigma 0.01 / 0.05 m, x0 = 0.5, 1, 2, 3 m, 320 x 240): frames drawn at
random from the independent numpy casters of crates/epd-py/tests and read by
`epd estimate FILE --format json --threads 1` (its defaults otherwise).

What it measures, per frame: whether `geometry` is right (`bend_ahead` for the elbows,
`tee_ahead` for the tee, `straight` for the straight pipe), whether `straight_until_m` is
within 5 cm of the feature's start x0, and whether its 1-sigma (`sigma_straight_until_m`)
covers the error (|err| <= 1.96 sigma). Issue 23's goal: geometry right in >= 99 % of
frames 0.5-3 m before an elbow or a tee, sigma 0.01-0.05 m, 8"-42" pipes; <= 1 % of
straight frames read as a bend or a tee; the start within 5 cm with its 1-sigma covering
in >= 90 %.

The draw of frame k (k = 0, 1, ...), seed SEED0 + k (recorded per frame):
- fitting FITTINGS[k % 6] and pipe size SIZES[(k // 6) % 6] (stratified: every block of 36
  frames holds each fitting x size once), the camera 224 x 172 (a smaller ToF camera, the
  casters' 69 x 51 deg field of view) in one frame of each fitting and of each size per
  block of 36 (when (k // 36) % 6 == (k % 6 + (k // 6) % 6) % 6), else 320 x 240;
- from numpy.random.default_rng(seed), in this order: sigma ~ U[0.01, 0.05] m, x0 ~
  U[0.5, 3.0] m (the elbow's or the tee opening's start ahead along the axis), for the
  straight pipe the noise model (`independent` with probability 2/3, else `correlated`,
  `test_independent_frames.frame`), then the caster's own draws (the camera's pose, the
  feature's clock direction, the tee's branch diameter) from the same generator.
Fittings: elbow (R = 1.5 D, 90 deg), elbow_r1 (R = 1.0 D, 90 deg), elbow_45 (R = 1.5 D,
45 deg), elbow_oval (R = 1.5 D, 90 deg, 4 % ovality flattened in the bend's plane;
`test_independent_bends.bend_frame`), tee (`test_independent_tees.tee_frame`, branch
0.5-1 D, any side) and straight (`test_independent_frames.frame`: its own wall 6-15 mm and
ovality 1-4 %, so its truth is the Dmax/Dmin it returns). Sizes off the grid: nominal 10",
12", 16", 24", 30", 36", standard-weight walls, inner diameter = OD - 2 wall.
Noise: the casters read the module global `SIGMA_M` (set as approach-grid-numpy.py's
`set_sigma` does); the straight caster takes `sigma=`.

Usage (from the repository's root; EPD_BIN overrides the binary, default target/release/epd):
  python3 scripts/offgrid-numpy.py run [--frames N] [--first K] [--only tee,straight]
      [--out /tmp/offgrid/results.jsonl]
      [--miss /tmp/offgrid/miss] [--work /tmp/offgrid/frames]
  python3 scripts/offgrid-numpy.py table [--out /tmp/offgrid/results.jsonl]
  python3 scripts/offgrid-numpy.py cast K [--to DIR]   # writes frame K's PLY and truth again
  python3 scripts/offgrid-numpy.py opening [--out /tmp/offgrid/results.jsonl] [--frames N]
`opening` casts every tee frame k < N (2160 by default) again and measures what its opening
gives a reader at best: the rays that leave the main pipe through the opening read long by
t - t1 (t1 where the main cylinder alone would end them, t where the caster does), and
z_open = sqrt(sum((t - t1)^2) / sigma^2) over those rays is the log-likelihood ratio's
scale of an oracle that knows which rays they are and by how much (no reader that must
find them among all points, at a stated false-alarm rate, does better). It prints, per
bin of z_open, the frames and how many --out reads right.
`run` casts and estimates frames K .. N-1 (K = 0 by default) one at a time (one caster, one `epd --threads 1`
at a time) and appends one JSON line per frame to --out; frames already there are skipped,
so a run can be resumed. The PLY and a truth JSON of every frame whose geometry is wrong
are kept in --miss; the others are deleted.

Written by a helper session on 2026-12-07.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "crates" / "epd-py" / "tests"))

import test_independent_bends as tb  # noqa: E402
import test_independent_frames as tf  # noqa: E402
import test_independent_tees as tt  # noqa: E402
from casting import draw_pose  # noqa: E402

EPD = Path(os.environ.get("EPD_BIN", ROOT / "target" / "release" / "epd"))
SEED0 = 20261207000
IN = 0.0254
# nominal size: (outside diameter in, standard-weight wall in)
SIZES = {
    "10in": (10.75, 0.365),
    "12in": (12.75, 0.375),
    "16in": (16.0, 0.375),
    "24in": (24.0, 0.375),
    "30in": (30.0, 0.375),
    "36in": (36.0, 0.375),
}
FITTINGS = ("elbow", "elbow_r1", "elbow_45", "elbow_oval", "tee", "straight")
# elbow variants: (bend radius / D, bend angle in degrees, ovality)
ELBOWS = {"elbow": (1.5, 90.0, 0.0), "elbow_r1": (1.0, 90.0, 0.0), "elbow_45": (1.5, 45.0, 0.0),
          "elbow_oval": (1.5, 90.0, 0.04)}
CAMERAS = {"320x240": (320, 240), "224x172": (224, 172)}
BINS = ((0.5, 1.0), (1.0, 2.0), (2.0, 3.0))
KEYS = ("geometry", "status", "straight_until_m", "sigma_straight_until_m", "bend_radius_mm",
        "sigma_bend_radius_mm", "bend_angle_deg", "sigma_bend_angle_deg", "d_max_mm",
        "d_min_mm", "sigma_d_max_mm", "sigma_d_min_mm", "n_points", "elapsed_ms")


def set_sigma(sigma):
    tb.SIGMA_M = sigma
    tt.SIGMA_M = sigma


def plan(k):
    """Frame k's stratified cells: (fitting, size, camera)."""
    fi, si, block = k % 6, (k // 6) % 6, k // 36
    camera = "224x172" if block % 6 == (fi + si) % 6 else "320x240"
    return FITTINGS[fi], list(SIZES)[si], camera


def peek_pose(rng, d):
    """The pose `draw_pose` will draw next from `rng`, without advancing it."""
    g = np.random.Generator(np.random.PCG64())
    g.bit_generator.state = rng.bit_generator.state
    roll, pitch, yaw, origin, phi_b = draw_pose(g, d)
    return dict(roll_deg=round(math.degrees(roll), 2), pitch_deg=round(math.degrees(pitch), 3),
                yaw_deg=round(math.degrees(yaw), 3), dy_mm=round(origin[1] * 1e3, 2),
                dz_mm=round(origin[2] * 1e3, 2), phi_b_deg=round(math.degrees(phi_b), 1))


def draw(k):
    """Frame k: (points (n, 3) float32 in the sensor frame, its truth)."""
    fitting, size, camera = plan(k)
    seed = SEED0 + k
    rng = np.random.default_rng(seed)
    od_in, wall_in = SIZES[size]
    d = (od_in - 2 * wall_in) * IN
    w, h = CAMERAS[camera]
    sigma = float(rng.uniform(0.01, 0.05))
    x0 = float(rng.uniform(0.5, 3.0))
    truth = dict(k=k, seed=seed, fitting=fitting, size=size, od_in=od_in, wall_in=wall_in,
                 camera=camera, sigma=round(sigma, 5))
    if fitting == "straight":
        model = "independent" if rng.random() < 2 / 3 else "correlated"
        pts, d_max, d_min, (roll, pitch, yaw, dy, dz) = tf.frame(
            rng, model, w, h, od_in=od_in, sigma=sigma, with_pose=True)
        truth.update(x0=None, model=model, d_m=round((d_max + d_min) / 2, 5),
                     d_max_true_mm=round(d_max * 1e3, 2), d_min_true_mm=round(d_min * 1e3, 2),
                     roll_deg=round(math.degrees(roll), 2), pitch_deg=round(math.degrees(pitch), 3),
                     yaw_deg=round(math.degrees(yaw), 3), dy_mm=round(dy * 1e3, 2),
                     dz_mm=round(dz * 1e3, 2), want="straight")
        return pts, truth
    set_sigma(sigma)
    assert tb.SIGMA_M == sigma and tt.SIGMA_M == sigma
    truth.update(x0=round(x0, 4), model="independent", d_m=round(d, 5), **peek_pose(rng, d))
    if fitting in ELBOWS:
        r_d, angle, ovality = ELBOWS[fitting]
        pts = tb.bend_frame(rng, x0, d, r_d * d, math.radians(angle), w, h, ovality=ovality)
        truth.update(bend_radius_true_mm=round(r_d * d * 1e3, 2), bend_angle_true_deg=angle,
                     ovality=ovality, want="bend_ahead")
    else:
        pts, bd, _phi = tt.tee_frame(rng, x0, d, w, h)
        truth.update(branch_share=round(bd / d, 3), want="tee_ahead")
    # x0 rounded for the record; the frame was cast with the unrounded value
    truth["x0_exact"] = x0
    return pts, truth


def estimate(path):
    t0 = time.time()
    p = subprocess.run([str(EPD), "estimate", str(path), "--format", "json", "--threads", "1"],
                       capture_output=True, text=True)
    wall = time.time() - t0
    rows = [json.loads(line) for line in p.stdout.splitlines() if line.strip()]
    if p.returncode not in (0, 1) or len(rows) != 1:
        return dict(status="error", geometry=None, error=p.stderr[-500:], rc=p.returncode), wall
    r = rows[0]
    out = {key: r.get(key) for key in KEYS}
    if p.stderr.strip():
        out["stderr"] = p.stderr.strip()[-300:]
    return out, wall


def score(rec):
    rec["geom_right"] = rec["geometry"] == rec["want"]
    x0, su, s = rec.get("x0_exact"), rec.get("straight_until_m"), rec.get("sigma_straight_until_m")
    ahead = x0 is not None and rec["geom_right"] and su is not None
    rec["start_err_m"] = round(su - x0, 4) if ahead else None
    rec["within_5cm"] = bool(ahead and abs(su - x0) <= 0.05)
    rec["covers"] = bool(abs(su - x0) <= 1.96 * s) if ahead and s else None


def load(out_path):
    if not Path(out_path).exists():
        return []
    return [json.loads(line) for line in open(out_path) if line.strip()]


def run(a):
    done = {r["k"] for r in load(a.out)}
    work, miss = Path(a.work), Path(a.miss)
    work.mkdir(parents=True, exist_ok=True)
    miss.mkdir(parents=True, exist_ok=True)
    t_start = time.time()
    only = set(a.only.split(",")) if a.only else None
    todo = [k for k in range(a.first, a.frames)
            if k not in done and (only is None or plan(k)[0] in only)]
    print(f"{len(done)} frames done, {len(todo)} to do; binary {EPD}", flush=True)
    for i, k in enumerate(todo):
        t0 = time.time()
        pts, truth = draw(k)
        t_cast = time.time() - t0
        name = f"{k:04d}_{truth['fitting']}_{truth['size']}_{truth['camera']}"
        ply = work / f"{name}.ply"
        tf.write_ply(ply, pts)
        ans, t_est = estimate(ply)
        rec = dict(truth, n_cast=len(pts), **ans, cast_s=round(t_cast, 2), epd_wall_s=round(t_est, 3))
        score(rec)
        if rec["geom_right"]:
            ply.unlink()
        else:
            ply.replace(miss / ply.name)
            (miss / f"{name}.json").write_text(json.dumps(rec, indent=1) + "\n")
        with open(a.out, "a") as f:
            f.write(json.dumps(rec) + "\n")
        x0 = f"{rec['x0']:.3f}" if rec["x0"] is not None else "  -  "
        su = rec["straight_until_m"]
        print(f"[{i + 1}/{len(todo)} {time.time() - t_start:6.0f}s] k {k} {rec['fitting']} {rec['size']} "
              f"{rec['camera']} s {rec['sigma']:.3f} x0 {x0}: {rec['status']} {rec['geometry']} "
              f"su {su if su is None else round(su, 3)} {'OK' if rec['geom_right'] else 'MISS'} "
              f"cast {t_cast:.1f}s epd {t_est:.2f}s", flush=True)


def frac(n, m):
    return f"{n}/{m}" if m else "—"


def row_stats(rs):
    ahead = [r for r in rs if r["want"] != "straight"]
    right = [r for r in ahead if r["geom_right"]]
    w5 = [r for r in right if r["within_5cm"]]
    cov = [r for r in right if r["covers"] is not None]
    cov5 = [r for r in w5 if r["covers"] is not None]
    return [len(rs), frac(sum(r["geom_right"] for r in rs), len(rs)),
            frac(len(w5), len(right)) if ahead else "—",
            frac(sum(r["covers"] for r in cov), len(cov)) if ahead else "—",
            frac(sum(r["covers"] for r in cov5), len(cov5)) if ahead else "—"]


HEAD = ["n", "geometry right", "start ≤ 5 cm (of right)", "±1.96σ covers (of right with σ)",
        "±1.96σ covers (of ≤ 5 cm with σ)"]


def print_table(title, first, rows):
    print(f"\n{title}\n")
    print("| " + " | ".join(first + HEAD) + " |")
    print("|" + "---|" * (len(first) + len(HEAD)))
    for key, rs in rows:
        print("| " + " | ".join([str(x) for x in key] + [str(x) for x in row_stats(rs)]) + " |")


def binom(n, m):
    p = n / m
    se = math.sqrt(p * (1 - p) / m)
    extra = f"; none missed: 95 % upper bound on the miss rate {3 / m:.4f}" if n == m else ""
    return f"{n}/{m} = {p:.4f} ± {se:.4f} (binomial SE){extra}"


def table(a):
    recs = load(a.out)
    if not recs:
        print("no results")
        return
    sizes = list(SIZES)
    rows = []
    for f in FITTINGS:
        for s in sizes:
            rs = [r for r in recs if r["fitting"] == f and r["size"] == s]
            if rs:
                rows.append(((f, s), rs))
        rs = [r for r in recs if r["fitting"] == f]
        if rs:
            rows.append(((f, "all"), rs))
    print_table("Per fitting × size", ["fitting", "size"], rows)
    rows = []
    for f in FITTINGS[:-1]:
        for lo, hi in BINS:
            rs = [r for r in recs if r["fitting"] == f and lo <= r["x0"] < hi + (hi == 3.0)]
            if rs:
                rows.append(((f, f"{lo}–{hi}"), rs))
    for lo, hi in BINS:
        rs = [r for r in recs if r["want"] != "straight" and lo <= r["x0"] < hi + (hi == 3.0)]
        if rs:
            rows.append((("all but straight", f"{lo}–{hi}"), rs))
    print_table("Per fitting × distance x0 (m)", ["fitting", "x0 m"], rows)
    rows = []
    for cam in CAMERAS:
        for group, sel in (("ahead", lambda r: r["want"] != "straight"), ("straight", lambda r: r["want"] == "straight")):
            rs = [r for r in recs if r["camera"] == cam and sel(r)]
            if rs:
                rows.append(((cam, group), rs))
    for lo, hi in ((0.01, 0.02), (0.02, 0.03), (0.03, 0.04), (0.04, 0.05)):
        for group, sel in (("ahead", lambda r: r["want"] != "straight"), ("straight", lambda r: r["want"] == "straight")):
            rs = [r for r in recs if lo <= r["sigma"] < hi + 1e-9 * (hi == 0.05) and sel(r)]
            if rs:
                rows.append(((f"σ {lo}–{hi} m", group), rs))
    print_table("Per camera and per σ bin", ["cell", "frames"], rows)
    ahead = [r for r in recs if r["want"] != "straight"]
    straight = [r for r in recs if r["want"] == "straight"]
    print("\nOverall geometry right:")
    print(f"- all frames: {binom(sum(r['geom_right'] for r in recs), len(recs))}")
    if ahead:
        print(f"- elbow or tee ahead: {binom(sum(r['geom_right'] for r in ahead), len(ahead))}")
        right = [r for r in ahead if r["geom_right"]]
        w5 = sum(r["within_5cm"] for r in right)
        print(f"- start within 5 cm, of the right ones: {binom(w5, len(right))}" if right else "")
        cov = [r for r in right if r["covers"] is not None]
        if cov:
            print(f"- ±1.96σ covers the start's error, of the right ones with σ: {binom(sum(r['covers'] for r in cov), len(cov))}")
    if straight:
        fa = sum(not r["geom_right"] for r in straight)
        print(f"- straight read as another geometry: {fa}/{len(straight)} = {fa / len(straight):.4f} ± "
              f"{math.sqrt(fa / len(straight) * (1 - fa / len(straight)) / len(straight)):.4f}")
    print("\nMisreads (geometry wrong):\n")
    print("| fitting | size | σ m | x0 m | camera | k | seed | geometry | status | straight_until_m |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in sorted((r for r in recs if not r["geom_right"]), key=lambda r: (FITTINGS.index(r["fitting"]), r["k"])):
        su = r.get("straight_until_m")
        print(f"| {r['fitting']} | {r['size']} | {r['sigma']:.3f} | {r['x0'] if r['x0'] is not None else '—'} | "
              f"{r['camera']} | {r['k']} | {r['seed']} | {r['geometry']} | {r['status']} | "
              f"{'—' if su is None else f'{su:.3f}'} |")
    off = [r for r in ahead if r["geom_right"] and not r["within_5cm"]]
    if off:
        print("\nGeometry right, start more than 5 cm off:\n")
        print("| fitting | size | σ m | x0 m | camera | k | straight_until_m | error m | σ m |")
        print("|---|---|---|---|---|---|---|---|---|")
        for r in sorted(off, key=lambda r: (FITTINGS.index(r["fitting"]), r["k"])):
            s = r.get("sigma_straight_until_m")
            print(f"| {r['fitting']} | {r['size']} | {r['sigma']:.3f} | {r['x0']} | {r['camera']} | {r['k']} | "
                  f"{r['straight_until_m']} | {r['start_err_m']:+.3f} | {'—' if s is None else f'{s:.3f}'} |")
    t = [r["cast_s"] for r in recs]
    e = [r["epd_wall_s"] for r in recs]
    print(f"\n{len(recs)} frames; cast {sum(t):.0f} s in all (max {max(t):.1f} s), epd {sum(e):.0f} s "
          f"(median {np.median(e):.2f} s, max {max(e):.2f} s)")


def cast(a):
    pts, truth = draw(a.k)
    to = Path(a.to)
    to.mkdir(parents=True, exist_ok=True)
    name = f"{a.k:04d}_{truth['fitting']}_{truth['size']}_{truth['camera']}"
    tf.write_ply(to / f"{name}.ply", pts)
    (to / f"{name}.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(to / f"{name}.ply")


def opening(a):
    """Per tee frame: the rays through the opening and z_open (see the module doc),
    joined with --out's verdicts, printed by bin of z_open."""
    seen = {}
    original = tt.tee_ranges

    def recorded(origin, e, x0, diameter, branch_d, phi_b):
        t = original(origin, e, x0, diameter, branch_d, phi_b)
        # Where the main cylinder alone ends each ray (the caster's own quadratic).
        qa = e[:, 1] ** 2 + e[:, 2] ** 2
        qb = 2 * (origin[1] * e[:, 1] + origin[2] * e[:, 2])
        qc = origin[1] ** 2 + origin[2] ** 2 - (diameter / 2) ** 2
        t1 = tt.larger_root(qa, qb, qc)
        kept = np.isfinite(t) & (t > 0) & (t <= tt.MAX_RANGE_M)
        seen["excess"] = (t - t1)[kept]
        return t

    tt.tee_ranges = recorded
    try:
        verdicts = {}
        if Path(a.out).exists():
            for line in Path(a.out).read_text().splitlines():
                r = json.loads(line)
                verdicts[r["k"]] = r
        rows = []
        for k in range(a.frames):
            if plan(k)[0] != "tee":
                continue
            _, truth = draw(k)
            through = seen["excess"][seen["excess"] > 0.0]
            z = float(np.sqrt(np.sum((through / truth["sigma"]) ** 2)))
            rows.append((z, through.size, truth, verdicts.get(k)))
    finally:
        tt.tee_ranges = original
    print("| z_open | tee frames | rays through the opening (median) | read tee_ahead | misread |")
    print("|---|---|---|---|---|")
    edges = (0, 12, 20, 40, 80, math.inf)
    for lo, hi in zip(edges, edges[1:]):
        sel = [r for r in rows if lo <= r[0] < hi]
        if not sel:
            continue
        read = [r for r in sel if r[3] is not None]
        right = sum(bool(r[3].get("geom_right")) for r in read)
        n_rays = sorted(r[1] for r in sel)[len(sel) // 2]
        print(f"| {lo}–{hi} | {len(sel)} | {n_rays} | {right}/{len(read)} | {len(read) - right} |")


def main():
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="mode", required=True)
    r = sub.add_parser("run")
    r.add_argument("--frames", type=int, default=324, help="frames k < N")
    r.add_argument("--first", type=int, default=0, help="frames k >= K only (an extension)")
    r.add_argument("--only", default="", help="these fittings only, e.g. tee,straight")
    r.add_argument("--work", default="/tmp/offgrid/frames")
    r.add_argument("--miss", default="/tmp/offgrid/miss")
    t = sub.add_parser("table")
    c = sub.add_parser("cast")
    c.add_argument("k", type=int)
    c.add_argument("--to", default="/tmp/offgrid/cast")
    o = sub.add_parser("opening")
    o.add_argument("--frames", type=int, default=2160, help="tee frames k < N")
    for p in (r, t, o):
        p.add_argument("--out", default="/tmp/offgrid/results.jsonl")
    a = ap.parse_args()
    {"run": run, "table": table, "cast": cast, "opening": opening}[a.mode](a)


if __name__ == "__main__":
    main()
