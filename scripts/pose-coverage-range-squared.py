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
# The caster's frame under range noise growing as r², with its pose.
def frame(rng, w, h):
    pts, d_max, d_min, (roll, pitch, yaw, dy, dz) = T.frame(
        rng, "range_squared", w, h, with_pose=True
    )
    # canonical: roll in [-90, 90): a 180° turn flips pitch, yaw, dy, dz
    if not (-math.pi / 2 <= roll < math.pi / 2):
        roll -= math.copysign(math.pi, roll); pitch, yaw, dy, dz = -pitch, -yaw, -dy, -dz
    return pts, dict(pitch_deg=math.degrees(pitch), yaw_deg=math.degrees(yaw), dy_mm=dy*1e3, dz_mm=dz*1e3, d_max_mm=d_max*1e3, d_min_mm=d_min*1e3)
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
