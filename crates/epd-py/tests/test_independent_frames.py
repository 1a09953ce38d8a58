"""`epd estimate FILES --format json` with its defaults on frames of our own making that
share no code with tof-sim or epd: a numpy ray caster of the pipe written from
SPEC.md (eq. 3: x_P = Rz(yaw)·Ry(pitch)·Rx(roll)·x_S + [0, δy, δz]; the wall
y²/(Dmax/2)² + z²/(Dmin/2)² = 1), a pinhole camera of its own (160 × 120, 69° × 51°,
the sensor frame: X along the optical axis, Y left, Z up), pipe sizes, ovalities and
poses off the paper's grid, and range-error models of its own: independent,
spatially correlated (a 2-pixel Gaussian blur of the noise image, rescaled to σ), a
multipath band (every range in 1–2 m read 2.5σ long), range noise growing as r²
(σ(r) = S0_M·(r / 1 m)², as a phase camera's does with falling return power) and far
outliers (independent noise, then OUTLIER_SHARE of the pixels read anywhere in
OUTLIER_RANGE_M). `frame` and `run` take the camera's size (W × H by default; the
survey's false alarms at 320 × 240 are checked in `test_straight_false_alarms.py`).
Frames are written as binary little-endian PLY (float32 x y z), as checks outside the
project write them.

What is checked is issue 22's goals on frames we did not make with tof-sim:
- coverage of the ±1.96σ̂ interval for Dmax and Dmin (independent and correlated noise):
  over n frames the covered count is binomial; at the nominal 0.95 the observed share has
  standard error √(0.95·0.05/n) (0.0154 at n = 200), and the test fails below
  0.95 − 4 SE = 0.888: a true coverage of 0.95 fails with probability < 10⁻⁴, one of
  0.85 passes with probability < 10⁻².
- no frame answered `converged` more than max(5σ̂, 0.5 mm) off, under every model
  (multipath included): with an honest 1-σ, P(|z| > 5) is below 10⁻⁴ per diameter even
  for Student's t with 10 degrees of freedom, so one such frame in 200 is a failure.

And issue 23's goal that ≤ 1 % of straight frames read as a bend or a tee (correlated
noise included): the count read otherwise is binomial; the test fails above 0.01 + 4 SE
= 0.038 (8 or more of 200), which a true rate of 1 % reaches with probability 0.001 and
one of 5 % with probability 0.79 (binomial tails, exact); the measured counts are printed.
"""

import json
import math
import subprocess

import numpy as np
import pytest

FRAMES = 200
SIGMA_M = 0.02
W, H = 160, 120
FOV_DEG = (69.0, 51.0)
MAX_RANGE_M = 6.0
S0_M = 0.02  # range-squared model: σ(r) = S0_M·(r / 1 m)², 20 mm at 1 m
OUTLIER_SHARE = 0.05  # outliers model: the share of pixels read anywhere in OUTLIER_RANGE_M
OUTLIER_RANGE_M = (0.3, 6.0)
MODELS = ("independent", "correlated", "multipath", "range_squared", "outliers")


def rot(roll, pitch, yaw):
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rays(w=W, h=H):
    """Unit sensing directions of the pinhole camera (w × h pixels, FOV_DEG) in the sensor
    frame, (h, w, 3)."""
    fx = (w / 2) / math.tan(math.radians(FOV_DEG[0] / 2))
    fy = (h / 2) / math.tan(math.radians(FOV_DEG[1] / 2))
    u = (np.arange(w) + 0.5 - w / 2) / fx
    v = -(np.arange(h) + 0.5 - h / 2) / fy
    uu, vv = np.meshgrid(u, v)
    d = np.stack([np.ones_like(uu), -uu, vv], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def blur(img, px):
    """A separable Gaussian blur of standard deviation `px` pixels (edges reflected)."""
    r = int(math.ceil(3 * px))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / px) ** 2)
    k /= k.sum()
    pad = np.pad(img, r, mode="reflect")
    rows = np.apply_along_axis(lambda a: np.convolve(a, k, mode="valid"), 1, pad)
    return np.apply_along_axis(lambda a: np.convolve(a, k, mode="valid"), 0, rows)


def frame(rng, model, w=W, h=H, od_in=None, sigma=SIGMA_M, with_pose=False):
    """One frame of a `w` × `h` camera under the range-error `model` (one of MODELS) of
    scale `sigma` (m): (points (n, 3) float32 in the sensor frame, Dmax, Dmin in m), and
    with `with_pose` the true pose too, (roll, pitch, yaw in rad, δy, δz in m). The
    pipe's outside diameter is drawn in 14–32" unless `od_in` gives it (inches). The draws of the first
    three models are those they had before the others were added (same seed, same frame
    at W × H)."""
    assert model in MODELS, model
    od = (rng.uniform(14.0, 32.0) if od_in is None else od_in) * 25.4e-3
    inner = od - 2 * rng.uniform(0.006, 0.015)
    ovality = rng.uniform(0.01, 0.04)
    d_max, d_min = inner * (1 + ovality / 2), inner * (1 - ovality / 2)
    roll = rng.uniform(-math.pi, math.pi)
    pitch, yaw = np.radians(rng.uniform(-6.0, 6.0, size=2))
    dy, dz = rng.uniform(-0.05, 0.05, size=2) * inner / 0.5
    d_s = rays(w, h)
    e = d_s @ rot(roll, pitch, yaw).T  # directions in the PCS
    a2, b2 = (d_max / 2) ** 2, (d_min / 2) ** 2
    qa = e[..., 1] ** 2 / a2 + e[..., 2] ** 2 / b2
    qb = 2 * (dy * e[..., 1] / a2 + dz * e[..., 2] / b2)
    qc = dy * dy / a2 + dz * dz / b2 - 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-qb + np.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)
    noise = rng.normal(0.0, sigma, size=t.shape)
    if model == "correlated":
        noise = blur(noise, 2.0)
        noise *= sigma / noise.std()
    if model == "range_squared":
        noise *= (S0_M / sigma) * t**2  # NaN where the ray misses: dropped below
    measured = t + noise
    if model == "multipath":
        measured = measured + np.where((t >= 1.0) & (t <= 2.0), 2.5 * sigma, 0.0)
    if model == "outliers":
        wild = rng.random(t.shape) < OUTLIER_SHARE
        measured = np.where(wild, rng.uniform(*OUTLIER_RANGE_M, size=t.shape), measured)
    keep = np.isfinite(t) & (t <= MAX_RANGE_M)
    pts = (d_s * measured[..., None])[keep]
    if with_pose:
        return pts.astype(np.float32), d_max, d_min, (roll, pitch, yaw, dy, dz)
    return pts.astype(np.float32), d_max, d_min


def write_ply(path, pts):
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(pts)}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.ascontiguousarray(pts, dtype="<f4").tobytes())


def run(
    epd_bin, tmp_path, model, seed, frames=FRAMES, w=W, h=H, args=(), od_in=None, sigma=SIGMA_M
):
    """`frames` frames of a `w` × `h` camera under `model` of scale `sigma` (pipes of
    `od_in` inches outside when given), drawn from `seed`, written to `tmp_path` and estimated (with the
    defaults and `args`): (one result per frame, {file: (Dmax, Dmin) in mm})."""
    rng = np.random.default_rng(seed)
    truth = {}
    paths = []
    for k in range(frames):
        pts, d_max, d_min = frame(rng, model, w, h, od_in, sigma)
        p = tmp_path / f"{model}_{w}x{h}_{k:03d}.ply"
        write_ply(p, pts)
        truth[str(p)] = (d_max * 1e3, d_min * 1e3)
        paths.append(str(p))
    return estimate_files(epd_bin, paths, args), truth


def estimate_files(epd_bin, paths, args=()):
    """`epd estimate PATHS --format json` with the defaults and `args`: one result per
    file."""
    out = subprocess.run(
        [str(epd_bin), "estimate", *paths, "--format", "json", *args],
        capture_output=True,
        text=True,
    )
    # Exit 1: some file was not answered `converged` (named on stderr); 2 or more: usage.
    assert out.returncode in (0, 1), out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines() if line.strip()]
    assert len(rows) == len(paths)
    return rows


def score(rows, truth):
    converged, covered, far = 0, [0, 0], []
    for r in rows:
        # Not answered: refused, or converged without diameters (the survey saw a bend
        # or a tee and withheld them).
        if r["status"] != "converged" or r["d_max_mm"] is None:
            continue
        converged += 1
        for i, key in enumerate(("d_max_mm", "d_min_mm")):
            err = r[key] - truth[r["file"]][i]
            s = r["sigma_" + key]
            covered[i] += abs(err) <= 1.96 * s
            if abs(err) > max(5 * s, 0.5):
                far.append((r["file"], key, err, s))
    return converged, covered, far


COVERAGE_FLOOR = 0.95 - 4 * math.sqrt(0.95 * 0.05 / FRAMES)


# Measured with the survey's variance law and the fitted axis's 1-σ (issue 23; `epd
# estimate FILES --format json` with the defaults, 200 frames per model): independent
# 0.920/0.905 and 0 of 200 misread; correlated 0.919/0.904 and 3 of 200 misread as a tee
# (0 of 200 with seed 31; 0 of each before the axis's lateral covariance, whose one-by-one
# predecessor was too wide on round pipes). Multipath (seed 24): 40 of 200 answered, coverage 0.925/0.900, none
# far off, since the 1-σ carries the covariance of the range error the slices share
# (`add_shared_offsets` in epd-core); 3 of 200 were far off before it (seed 25: 39
# answered, 0.897/0.974, none far off). At 448cd07 (the survey's rings and near windows
# of 2026-12-06): multipath (seed 24) 47 of 200 answered, coverage 0.915/0.894, none far
# off.

@pytest.mark.parametrize(
    "model, seed",
    [
        pytest.param("independent", 22),
        pytest.param("correlated", 23),
    ],
)
def test_coverage_on_frames_of_our_own(epd_bin, tmp_path, model, seed):
    rows, truth = run(epd_bin, tmp_path, model, seed)
    converged, covered, far = score(rows, truth)
    assert converged >= 0.99 * FRAMES - 4 * math.sqrt(FRAMES * 0.01 * 0.99), (
        f"{model}: {converged} of {FRAMES} good frames converged"
    )
    share = [c / converged for c in covered]
    print(f"{model}: {converged} converged, coverage Dmax {share[0]:.3f} Dmin {share[1]:.3f}")
    assert min(share) >= COVERAGE_FLOOR, (
        f"{model}: coverage {share} below {COVERAGE_FLOOR:.3f} over {converged} frames"
    )
    assert not far, f"{model}: converged far off: {far}"
    misread = [r["file"] for r in rows if r["geometry"] != "straight"]
    print(f"{model}: {len(misread)} of {FRAMES} straight frames read as another geometry")
    assert len(misread) <= MISREAD_CEILING * FRAMES, f"{model}: misread {misread}"


MISREAD_CEILING = 0.01 + 4 * math.sqrt(0.01 * 0.99 / FRAMES)


def test_a_small_pipe_under_half_its_radius_of_range_noise_is_measured(epd_bin, tmp_path):
    """An 8" pipe (8.625" outside, radius ≈ 0.1 m) under σ = 0.05 m of independent range
    noise, the noisiest case of issue 23's goal, at 320 × 240: the range residuals'
    scale is half the radius, but range noise on rays that graze the wall moves the
    points along the axis, so the cross-section is well measured. Until the checks judged
    the noise by the points' scatter across the axis (`epd_core::check`), every such
    frame was refused `implausible` ("more than half its radius"). Asked as in
    `test_coverage_on_frames_of_our_own`: converged in ≥ 99 % less 4 standard errors of
    the frames, ±1.96σ̂ covering at the floor there, none answered more than
    max(5σ̂, 0.5 mm) off, and the frames read `straight` but for the 1 % ceiling."""
    rows, truth = run(epd_bin, tmp_path, "independent", 27, w=320, h=240, od_in=8.625, sigma=0.05)
    converged, covered, far = score(rows, truth)
    share = [c / max(converged, 1) for c in covered]
    misread = [r["file"] for r in rows if r["geometry"] != "straight"]
    print(
        f"8 in, σ 0.05 m: {converged} of {FRAMES} converged, coverage Dmax {share[0]:.3f} "
        f"Dmin {share[1]:.3f}, {len(misread)} read as another geometry"
    )
    assert converged >= 0.99 * FRAMES - 4 * math.sqrt(FRAMES * 0.01 * 0.99), converged
    assert min(share) >= COVERAGE_FLOOR, share
    assert not far, f"converged far off: {far[:5]}"
    assert len(misread) <= MISREAD_CEILING * FRAMES, misread


def test_no_multipath_frame_is_answered_far_off(epd_bin, tmp_path):
    rows, truth = run(epd_bin, tmp_path, "multipath", 24)
    converged, covered, far = score(rows, truth)
    print(f"multipath: {converged} converged, covered {covered}")
    assert not far, f"multipath: {len(far)} converged far off: {far[:5]}"


def test_no_multipath_frame_of_a_small_pipe_is_answered_far_off(epd_bin, tmp_path):
    """An 8" pipe (8.625" outside) at 640 × 480: the band's rays of 1–2 m are few but
    carry much of the information on the diameters, and the test for errors shared along
    the axis must find them for the 1-σ to carry the band. With that test on 2¹⁵ points
    (`epd_core::fit::form::FORM_POINTS` before), 2 of these 200 frames were answered
    `converged` 1.1 mm off in Dmax at 5.1 and 5.2σ̂ and ±1.96σ̂ covered 184 of 200; on
    2¹⁶, none, and 200 of 200 (checked: the test fails on the binary with 2¹⁵)."""
    rows, truth = run(epd_bin, tmp_path, "multipath", 6, w=640, h=480, od_in=8.625)
    converged, covered, far = score(rows, truth)
    print(f"multipath, 8 in: {converged} converged, covered {covered}")
    assert not far, f"multipath, 8 in: {len(far)} converged far off: {far[:5]}"


def test_no_multipath_frame_is_answered_far_off_with_max_points(epd_bin, tmp_path):
    """`--max-points 20000` on 320 × 240 frames (76 800 rays; the choice keeps about a
    quarter of the points in range) with a multipath band. The informed choice favours
    the far, grazing rays, where the band sits: its robust fit followed the band's points
    and answered `converged` about 20 mm (8–12σ̂) off in 4 of these 200 frames, where
    the full frame was right. The fit is now checked against the choice's pilot on a
    uniform sample (`epd_frame::sampling::Witness`) and the frame measured again on a
    uniform sample when they disagree; the frames so measured say `sampling: uniform`."""
    rows, truth = run(
        epd_bin, tmp_path, "multipath", 121, w=320, h=240, args=("--max-points", "20000")
    )
    converged, covered, far = score(rows, truth)
    again = sum(r["sampling"] == "uniform" for r in rows)
    print(f"multipath, --max-points 20000: {converged} converged, covered {covered}, {again} measured again")
    assert not far, f"multipath, --max-points 20000: {len(far)} converged far off: {far[:5]}"
