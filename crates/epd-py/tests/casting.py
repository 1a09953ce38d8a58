"""What the ray casters of an elbow and of a tee ahead (`test_independent_bends.py`,
`test_independent_tees.py`) share, none of it tof-sim's or epd's: the pipe, the camera's
random pose in it and the feature's clock direction, the frames written and estimated by
`epd`, and the checks of what the answers read."""

import math

import numpy as np

from test_independent_frames import estimate_files, write_ply

DIAMETER_M = 20 * 0.0254 - 2 * 0.0127  # a 20" pipe, 12.7 mm wall: 482.6 mm inside
FRAMES = 8  # frames per distance


def draw_pose(rng, diameter):
    """The camera's random pose in a round pipe of inner `diameter` (m) and the clock
    direction φ_b of the feature ahead: (roll, pitch, yaw, the sensor's position [0, δy,
    δz] in the PCS, φ_b). Roll anywhere, pitch and yaw within ±4°, δy and δz within ±4 cm
    in a 0.5 m pipe (scaled with the diameter), φ_b anywhere."""
    roll = rng.uniform(-math.pi, math.pi)
    pitch, yaw = np.radians(rng.uniform(-4.0, 4.0, size=2))
    dy, dz = rng.uniform(-0.04, 0.04, size=2) * diameter / 0.5
    phi_b = rng.uniform(0.0, 2 * math.pi)
    return roll, pitch, yaw, np.array([0.0, dy, dz]), phi_b


def estimate_frames(epd_bin, tmp_path, name, frames):
    """Each of `frames` (points (n, 3) in the sensor frame) written as
    `tmp_path/{name}_{k}.ply` and estimated by `epd estimate` with its defaults: one
    result per frame."""
    paths = []
    for k, pts in enumerate(frames):
        p = tmp_path / f"{name}_{k}.ply"
        write_ply(p, pts)
        paths.append(str(p))
    return estimate_files(epd_bin, paths)


def read_ahead(rows, geometry, ahead):
    """The results that read `geometry` with the straight section's end within 5 cm of
    `ahead` (m)."""
    return [
        r
        for r in rows
        if r["geometry"] == geometry
        and r["straight_until_m"] is not None
        and abs(r["straight_until_m"] - ahead) <= 0.05
    ]


def answered_far_off(rows, diameter_m):
    """The results answered `converged` with diameters of which one is more than
    max(5σ̂, 0.5 mm) from the straight pipe's `diameter_m` (issue 22's bound: with an
    honest 1-σ, P(|z| > 5) < 10⁻⁴ per diameter): (file, key, error mm, σ̂ mm, geometry)."""
    far = []
    for r in rows:
        if r["status"] != "converged" or r["d_max_mm"] is None:
            continue
        for key in ("d_max_mm", "d_min_mm"):
            err = r[key] - diameter_m * 1e3
            s = r["sigma_" + key]
            if abs(err) > max(5 * s, 0.5):
                far.append((r["file"], key, err, s, r["geometry"]))
    return far
