"""`epd estimate FILES --format json` with its defaults on frames of a tee ahead that share
no code with tof-sim or epd (issue 23's second, independent geometry, as
`test_independent_bends.py` for the elbow): a numpy ray caster of its own, exact.

The main pipe is a round cylinder of inner diameter D along +X of the pipe frame (PCS),
without end. The branch is a perpendicular round cylinder of diameter D_b ∈ [0.5·D, D]
whose axis leaves the main axis at x = x0 + D_b/2 toward the clock direction
u = (0, cos φ_b, sin φ_b) (any side), and runs outward without end: its opening in the
main pipe's wall starts at x0 along the axis. The inside is the union of the two
cylinders' interiors (the branch taken only on its outward half, s = (p − c)·u ≥ 0).

Each ray of a pinhole camera (`test_independent_frames.rays`, SPEC.md eq. 3 for the pose)
starts inside the main pipe and leaves it at t₁, the larger root of the main cylinder's
quadratic. If that exit point lies inside the branch (within D_b/2 of its axis, s > 0),
the ray goes on in the branch and leaves the union at t₂, the larger root of the branch
cylinder's quadratic: a line meets a convex set in one interval, so past t₁ it is never
inside the main pipe again, and past t₂ never inside the branch (its s = 0 disc lies
inside the main pipe, since D_b ≤ D). Ranges beyond 6 m are dropped, and range noise
N(0, σ²) is added along the ray. Nothing here is tof-sim's mesh.

Measured and printed per distance: how many frames read `tee_ahead` with
`straight_until_m` within 5 cm of x0 (the opening's near edge). What does not hold is
recorded as xfail with the measured figures; that no frame with a tee ahead is answered
far off is asserted.
"""

import math

import numpy as np
import pytest

from casting import DIAMETER_M, FRAMES, answered_far_off, draw_pose, estimate_frames, read_ahead
from test_independent_frames import MAX_RANGE_M, SIGMA_M, rays, rot

BRANCH_SHARE = (0.5, 1.0)  # D_b / D, drawn per frame


def larger_root(qa, qb, qc):
    """The larger root of qa·t² + qb·t + qc = 0 per element (NaN when none or qa ≈ 0)."""
    disc = qb * qb - 4 * qa * qc
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-qb + np.sqrt(disc)) / (2 * qa)
    return np.where((disc >= 0) & (qa > 1e-12), t, np.nan)


def tee_ranges(origin, e, x0, diameter, branch_d, phi_b):
    """Exact range along each unit PCS direction e (n, 3) from `origin` (inside the main
    pipe) to where the ray leaves the union of the main pipe and the branch."""
    a2 = (diameter / 2) ** 2
    # Main cylinder: (oy + t·ey)² + (oz + t·ez)² = a².
    qa = e[:, 1] ** 2 + e[:, 2] ** 2
    qb = 2 * (origin[1] * e[:, 1] + origin[2] * e[:, 2])
    qc = origin[1] ** 2 + origin[2] ** 2 - a2
    t1 = larger_root(qa, qb, qc)
    # Branch cylinder: axis through c along u, radius D_b/2.
    u = np.array([0.0, math.cos(phi_b), math.sin(phi_b)])
    c = np.array([x0 + branch_d / 2, 0.0, 0.0])
    q0 = origin - c
    q_perp = q0 - (q0 @ u) * u
    e_perp = e - np.outer(e @ u, u)
    ba = np.einsum("ij,ij->i", e_perp, e_perp)
    bb = 2 * (e_perp @ q_perp)
    bc = q_perp @ q_perp - (branch_d / 2) ** 2
    t2 = larger_root(ba, bb, bc)
    # Whether the exit from the main pipe opens into the branch.
    p1 = origin + e * t1[:, None]
    r1 = p1 - c
    s1 = r1 @ u
    off = r1 - np.outer(s1, u)
    into_branch = (s1 > 0) & (np.einsum("ij,ij->i", off, off) < (branch_d / 2) ** 2)
    # A ray along the branch's axis never leaves it (t₂ NaN): no return.
    return np.where(into_branch, t2, t1)


def tee_frame(rng, x0, diameter, w=None, h=None):
    """One frame: (points (n, 3) float32 in the sensor frame, D_b, φ_b)."""
    roll, pitch, yaw, origin, phi_b = draw_pose(rng, diameter)
    branch_d = rng.uniform(*BRANCH_SHARE) * diameter
    d_s = (rays() if w is None else rays(w, h)).reshape(-1, 3)
    e = d_s @ rot(roll, pitch, yaw).T  # directions in the PCS
    t = tee_ranges(origin, e, x0, diameter, branch_d, phi_b)
    keep = np.isfinite(t) & (t > 0) & (t <= MAX_RANGE_M)
    measured = t[keep] + rng.normal(0.0, SIGMA_M, size=int(keep.sum()))
    return (d_s[keep] * measured[:, None]).astype(np.float32), branch_d, phi_b


def test_the_caster_is_exact():
    """The caster against hand-worked rays: along the axis past the opening, straight
    into the branch along its axis, and across the main pipe away from the branch."""
    d, db, x0 = 0.5, 0.3, 1.0
    origin = np.zeros(3)
    up = math.pi / 2  # branch toward +Z
    e = np.array(
        [
            [0.0, 0.0, 1.0],  # up at x = 0: the main wall at 0.25 m
            [0.0, 0.0, -1.0],  # down: the main wall
            [1.0, 0.0, 0.0],  # along the axis: no wall (NaN)
        ]
    )
    t = tee_ranges(origin, e, x0, d, db, up)
    assert abs(t[0] - 0.25) < 1e-12 and abs(t[1] - 0.25) < 1e-12
    assert np.isnan(t[2])
    # From the branch axis's foot, up the branch: never leaves (NaN). Tilted by α from
    # it toward +X: at 20° it crosses the main wall (z = d/2) at x − (x0 + db/2) =
    # (d/2)·tan α = 0.091 < db/2, inside the opening, and leaves the branch's far wall
    # where x − (x0 + db/2) = db/2: t = (db/2)/sin α. At 45° the crossing is at 0.25 >
    # db/2, past the opening: the main wall, t = (d/2)/cos α.
    o2 = np.array([x0 + db / 2, 0.0, 0.0])
    a20, a45 = math.radians(20.0), math.radians(45.0)
    e2 = np.array(
        [
            [0.0, 0.0, 1.0],
            [math.sin(a20), 0.0, math.cos(a20)],
            [math.sin(a45), 0.0, math.cos(a45)],
        ]
    )
    t2 = tee_ranges(o2, e2, x0, d, db, up)
    assert np.isnan(t2[0])
    assert abs(t2[1] - db / 2 / math.sin(a20)) < 1e-12
    assert abs(t2[2] - d / 2 / math.cos(a45)) < 1e-12
    # The branch on the other side (toward −Z): up meets the main wall, down never
    # leaves.
    t_other = tee_ranges(o2, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]), x0, d, db, -up)
    assert abs(t_other[0] - d / 2) < 1e-12 and np.isnan(t_other[1])
    # Across the opening's near edge: a ray from the origin to (x0 − 1 mm, 0, 0.25)
    # hits the main wall; to (x0 + 1 mm, 0, 0.25) goes into the branch and on to its far
    # wall (x = x0 + db): further.
    before = np.array([x0 - 1e-3, 0.0, 0.25])
    after = np.array([x0 + 1e-3, 0.0, 0.25])
    dirs = np.array([before / np.linalg.norm(before), after / np.linalg.norm(after)])
    t3 = tee_ranges(origin, dirs, x0, d, db, up)
    assert abs(t3[0] - np.linalg.norm(before)) < 1e-12
    far = (x0 + db) / dirs[1, 0]
    assert abs(t3[1] - far) < 1e-9


# Measured (`pytest -s test_independent_tees.py`, 8 frames per distance, 160 × 120
# pixels, D_b ∈ [0.5, 1]·D, any side): 0.75, 1.0, 1.5 and 2.0 m 8 of 8 `tee_ahead`, the
# opening within −13 … +15 mm; 3.0 m 4 of 8 (3 `straight`, converged; one `tee_ahead` 67 mm
# late). 3 of 8 (5 `straight`) before the opening test pooled two neighbouring sectors
# (`epd_core::scene::sparse::WINDOW_SECTORS`): an opening straddling a sector boundary split
# its exceedances between the two. Before the opening
# test of the sparse cells (`epd_core::scene::sparse`) 1.5, 2.0 and 3.0 m were 0 of 8: the
# opening holds too few of this camera's points for the medians' tests, as the elbow's in
# `test_independent_bends.py`. The same caster at 640 × 480 pixels: 6 of 6 at 1.5 and
# 3.0 m (asserted below). Issue 23's goal is not met on this geometry at 160 × 120 at
# 3 m; the misses are recorded as xfail rather than loosened.
NOT_MET = {
    3.0: "issue 23: 4 of 8 at 160 x 120 (3 straight, 1 tee 67 mm late)",
}


def run_tees(epd_bin, tmp_path, ahead, w=None, h=None, frames=FRAMES):
    rng = np.random.default_rng(2300 + int(ahead * 100))
    cast = [tee_frame(rng, ahead, DIAMETER_M, w, h) for _ in range(frames)]
    drawn = [(round(b / DIAMETER_M, 2), round(math.degrees(phi))) for _, b, phi in cast]
    return estimate_frames(epd_bin, tmp_path, "tee", [pts for pts, _, _ in cast]), drawn


def assert_all_read_right(rows, drawn, ahead, label):
    """Every frame reads `tee_ahead` within 5 cm (`casting.read_ahead`); prints what each
    read."""
    right = read_ahead(rows, "tee_ahead", ahead)
    seen = [
        (r["status"], r["geometry"], r["straight_until_m"], b)
        for r, b in zip(rows, drawn)
    ]
    print(f"{label}: {len(right)} of {len(rows)} tee_ahead within 5 cm;", seen)
    assert len(right) == len(rows), seen


@pytest.mark.parametrize(
    "ahead",
    [
        pytest.param(a, marks=pytest.mark.xfail(reason=NOT_MET[a])) if a in NOT_MET else a
        for a in (0.75, 1.0, 1.5, 2.0, 3.0)
    ],
)
def test_a_tee_ahead_is_read_as_a_tee(epd_bin, tmp_path, ahead):
    """A branch of 0.5–1·D whose opening starts `ahead` metres in front of the sensor:
    every one of 8 frames reads `tee_ahead` with the straight section's end within 5 cm
    of the opening's near edge. With a true rate of 99 % all 8 read right with
    probability 0.92; a rate of 70 % passes with probability 0.06."""
    rows, drawn = run_tees(epd_bin, tmp_path, ahead)
    assert_all_read_right(rows, drawn, ahead, f"{ahead} m")


FULL_FRAMES = 6


@pytest.mark.parametrize("ahead", [1.5, 3.0])
def test_a_tee_ahead_is_read_as_a_tee_in_full_frames(epd_bin, tmp_path, ahead):
    """The same at 640 × 480 pixels (a Helios2's frame), where the opening holds enough
    points: every one of 6 frames reads `tee_ahead` within 5 cm. A true rate of 99 %
    passes with probability 0.94, one of 70 % with probability 0.12."""
    rows, drawn = run_tees(epd_bin, tmp_path, ahead, 640, 480, frames=FULL_FRAMES)
    assert_all_read_right(rows, drawn, ahead, f"{ahead} m, 640 x 480")


@pytest.mark.parametrize("ahead", [0.75, 1.5, 3.0])
def test_no_frame_with_a_tee_ahead_is_answered_far_off(epd_bin, tmp_path, ahead):
    """Whatever geometry it reads, a frame answered `converged` with diameters gives the
    straight pipe's within max(5σ̂, 0.5 mm) (issue 22's bound, as for the bends)."""
    rows, _ = run_tees(epd_bin, tmp_path, ahead)
    far = answered_far_off(rows, DIAMETER_M)
    assert not far, far
