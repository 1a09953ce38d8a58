#!/usr/bin/env python3
"""Coverage of `epd estimate`'s ±1.96σ̂ for the diameters and the pose under range noise
growing as r², on frames of the independent numpy ray caster of
crates/epd-py/tests/test_independent_frames.py (same draws as its `frame`, the pose
returned too and put in canonical form: roll in [−90°, 90°), a 180° turn flipping pitch,
yaw, δy, δz). Usage: pose-coverage-range-squared.py W H FRAMES EPD_BIN (writes the frames
to /tmp/indep; needs numpy)."""
import os
os.makedirs('/tmp/indep', exist_ok=True)
import sys, json, math, subprocess
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'crates', 'epd-py', 'tests'))
import numpy as np
import test_independent_frames as T
# Same draws as T.frame, returning the pose too.
def frame(rng, w, h):
    od = rng.uniform(14.0, 32.0) * 25.4e-3
    inner = od - 2 * rng.uniform(0.006, 0.015)
    ovality = rng.uniform(0.01, 0.04)
    d_max, d_min = inner * (1 + ovality / 2), inner * (1 - ovality / 2)
    roll = rng.uniform(-math.pi, math.pi)
    pitch, yaw = np.radians(rng.uniform(-6.0, 6.0, size=2))
    dy, dz = rng.uniform(-0.05, 0.05, size=2) * inner / 0.5
    d_s = T.rays(w, h)
    e = d_s @ T.rot(roll, pitch, yaw).T
    a2, b2 = (d_max / 2) ** 2, (d_min / 2) ** 2
    qa = e[..., 1] ** 2 / a2 + e[..., 2] ** 2 / b2
    qb = 2 * (dy * e[..., 1] / a2 + dz * e[..., 2] / b2)
    qc = dy * dy / a2 + dz * dz / b2 - 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-qb + np.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)
    noise = rng.normal(0.0, T.SIGMA_M, size=t.shape) * (T.S0_M / T.SIGMA_M) * t**2
    keep = np.isfinite(t) & (t <= T.MAX_RANGE_M)
    pts = (d_s * (t + noise)[..., None])[keep]
    # canonical: roll in [-90, 90): a 180° turn flips pitch, yaw, dy, dz
    if not (-math.pi / 2 <= roll < math.pi / 2):
        roll -= math.copysign(math.pi, roll); pitch, yaw, dy, dz = -pitch, -yaw, -dy, -dz
    return pts.astype(np.float32), dict(pitch_deg=math.degrees(pitch), yaw_deg=math.degrees(yaw), dy_mm=dy*1e3, dz_mm=dz*1e3, d_max_mm=d_max*1e3, d_min_mm=d_min*1e3)
w, h, n = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
rng = np.random.default_rng(2026)
paths, truth = [], {}
for k in range(n):
    pts, tr = frame(rng, w, h)
    p = f'/tmp/indep/f{w}_{k:03d}.ply'; T.write_ply(p, pts); paths.append(p); truth[p] = tr
out = subprocess.run([sys.argv[4], 'estimate', *paths, '--format', 'json'], capture_output=True, text=True).stdout
cov = {k: [0, 0] for k in ['d_max_mm','d_min_mm','pitch_deg','yaw_deg','dy_mm','dz_mm']}
for line in out.splitlines():
    d = json.loads(line)
    if d['status'] != 'converged': continue
    for k in cov:
        s = d.get('sigma_' + k)
        if s is None: continue
        cov[k][1] += 1; cov[k][0] += abs(d[k] - truth[d['file']][k]) <= 1.96 * s
print(w, h, {k: f'{c}/{m}' for k, (c, m) in cov.items()})
