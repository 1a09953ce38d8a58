"""Issue 23's goal on straight frames of our own numpy caster (`test_independent_frames`,
none of it tof-sim's or epd's): ≤ 1 % of straight-pipe frames read as anything but
`straight` by `epd estimate FILES --format json` with its defaults, under every range-error
model of that caster (independent, correlated, multipath, range noise growing as r², 5 %
far outliers) and at two camera sizes, 160 × 120 and 320 × 240 (the same 69° × 51° field
of view; the correlated model's blur stays 2 pixels, so at 320 × 240 it is half as wide in
angle). And that none of those frames is answered `converged` more than max(5σ̂, 0.5 mm)
off (issue 22's bound, `test_independent_frames.score`).

The count read otherwise over n frames is binomial; the test fails above
MISREAD_CEILING = 0.01 + 4·√(0.01·0.99/n) of n (0.038 at n = 200: 8 or more of 200), which a
true rate of 1 % reaches with probability 0.001 and one of 5 % with probability 0.79
(binomial tails, computed exactly). One frame answered far off fails the test: with an
honest 1-σ, P(|z| > 5) < 10⁻⁴ per diameter.

200 frames of one (model, size) take a few seconds (`epd` reads and fits ~20 000 points at
160 × 120 and ~76 000 at 320 × 240), so the tests run them all. The figures are measured
with `python test_straight_false_alarms.py` (EPD_BIN or target/release/epd), which prints
the table for the seeds of the tests and for a second set of seeds.
"""

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from test_independent_frames import FRAMES, MODELS, estimate_files, frame, run, score, write_ply

SIZES = ((160, 120), (320, 240))
MISREAD_CEILING = 0.01 + 4 * math.sqrt(0.01 * 0.99 / FRAMES)


def seed(model, size, offset=0):
    """The seed of one (model, size): distinct from each other and from the seeds
    22–25 and 31 of `test_independent_frames`."""
    return 100 + 10 * MODELS.index(model) + SIZES.index(size) + offset


def survey(epd_bin, tmp_path, model, size, offset=0):
    """FRAMES straight frames of `model` at `size`, estimated: (answered count, the
    files read as another geometry with the geometry, the answers far off)."""
    rows, truth = run(epd_bin, tmp_path, model, seed(model, size, offset), FRAMES, *size)
    converged, _, far = score(rows, truth)
    misread = [(r["file"], r["geometry"]) for r in rows if r["geometry"] != "straight"]
    return converged, misread, far


# Measured (`python test_straight_false_alarms.py`, epd of main in the eighth session,
# the dev build; 200 frames per row; read otherwise / answered far off / answered, for the
# tests' seeds and then seeds + 1000):
#   independent   160x120  0, 0 / 0, 0 / 200, 200    320x240  0, 0 / 0, 0 / 200, 200
#   correlated    160x120  0, 0 / 0, 0 / 200, 196    320x240  0, 0 / 0, 0 / 200, 200
#   multipath     160x120  2, 1 / 0, 0 /  50,  36    320x240  3, 1 / 0, 0 /  91,  75
#   range_squared 160x120  0, 0 / 0, 0 / 200, 200    320x240  0, 0 / 0, 0 / 200, 200
#   outliers      160x120  0, 0 / 0, 0 / 200, 199    320x240  0, 0 / 0, 0 / 200, 200
# Every frame read otherwise read `tee_ahead`, each where the multipath band begins (about
# 1 m ahead). Every count is under the ceiling (7.6 of 200), so no misread is xfail;
# multipath's 7 of 800 (0.88 % ± 0.33 %) is within the 1 % goal. Before the survey kept
# the verdict of the straight pipe refitted before a departure that then vanished
# (`epd_core::scene::segment`, `refine`), multipath read 18 of 800 (2.3 %) and correlated
# noise 6 of 800: the fit on every point, pulled off the pipe by the band, had been kept.
# Measured again on 2026-12-06 at 3b06fb1 (the release build, after the survey weighs a
# straight pipe seen through a ring of range error, `epd_core::scene::segment`,
# `ring_refit`): every model and size reads otherwise 0 of 200 for both seed sets, except
# multipath 320x240 at the second set, 1 of 200 (`tee_ahead`); none answered far off; the
# multipath frames answered 49, 36 at 160x120 and 130, 119 at 320x240 (50, 36 and 91, 75
# above), the others as above.
# What does not hold is recorded here as xfail with its figures, not loosened.
MISREAD_NOT_MET = {}
FAR_NOT_MET = {}

CASES = [(m, s) for m in MODELS for s in SIZES]


def case_id(case):
    """The test id of a (model, (w, h)) case: `model-WxH`."""
    return f"{case[0]}-{case[1][0]}x{case[1][1]}"


@pytest.fixture(scope="module")
def surveyed(epd_bin, tmp_path_factory):
    """Each (model, size) surveyed once for both tests."""
    done = {}

    def get(model, size):
        if (model, size) not in done:
            d = tmp_path_factory.mktemp(case_id((model, size)))
            done[model, size] = survey(epd_bin, d, model, size)
        return done[model, size]

    return get


def marked(cases, not_met):
    """The cases as pytest params, those in `not_met` strict xfail with its reason."""
    return [
        pytest.param(*c, id=case_id(c), marks=pytest.mark.xfail(reason=not_met[c], strict=True))
        if c in not_met
        else pytest.param(*c, id=case_id(c))
        for c in cases
    ]


@pytest.mark.parametrize("model, size", marked(CASES, MISREAD_NOT_MET))
def test_straight_frames_read_straight(surveyed, model, size):
    converged, misread, _ = surveyed(model, size)
    name = case_id((model, size))
    print(f"{name}: {len(misread)} of {FRAMES} read otherwise, {converged} answered")
    assert len(misread) <= MISREAD_CEILING * FRAMES, (
        f"{name}: {len(misread)} of {FRAMES} straight frames read otherwise: {misread[:5]}"
    )


@pytest.mark.parametrize("model, size", marked(CASES, FAR_NOT_MET))
def test_no_straight_frame_answered_far_off(surveyed, model, size):
    converged, _, far = surveyed(model, size)
    print(f"{case_id((model, size))}: {len(far)} far off of {converged} answered")
    assert not far, f"{case_id((model, size))}: {len(far)} answered far off: {far[:5]}"



def test_a_step_of_the_wall_is_no_bend(epd_bin, tmp_path):
    """Two multipath frames at 320 × 240 (frame 150 of the tests' seed 121, frame 133 of
    seed 1121): the band's edge, where ranges become 2.5σ long, is a step of the wall. When
    the fit with a bend's end was first tried for any outlet that lowers the cost
    (2026-12-08, `epd_core::bend::end_scan`), both read `bend_ahead`: a bend of 0.12 ±
    0.10° and 0.09 ± 0.11° (R 62 and 53 m), its end "seen" by the 1-σ of its points alone.
    A bend must have turned by more than 3.09 of its whole 1-σ (`bend::has_turned`); both
    read `straight` again, as they did before."""
    paths = []
    for seed, k in ((121, 150), (1121, 133)):
        rng = np.random.default_rng(seed)
        for _ in range(k):
            frame(rng, "multipath", 320, 240)
        pts, _, _ = frame(rng, "multipath", 320, 240)
        p = tmp_path / f"multipath_{seed}_{k}.ply"
        write_ply(p, pts)
        paths.append(str(p))
    rows = estimate_files(epd_bin, paths)
    seen = [(r["geometry"], r["bend_radius_mm"], r["bend_angle_deg"]) for r in rows]
    assert all(r["geometry"] == "straight" for r in rows), seen

def main():
    """`python test_straight_false_alarms.py [SEED_OFFSET…]` (default 0 1000: the tests'
    seeds and a second set) prints the table: per model × size × seed, the count of FRAMES
    read otherwise (and what they read), the far-off count, the answered count, seconds."""
    from conftest import find_epd_bin

    epd_bin = find_epd_bin()
    offsets = [int(a) for a in sys.argv[1:]] or [0, 1000]
    ceiling = MISREAD_CEILING * FRAMES
    print(f"epd: {epd_bin}; {FRAMES} frames per row; misread ceiling {ceiling:.2f}")
    print("model          size     seed  misread  (geometries)           far  answered  s")
    for off in offsets:
        for model in MODELS:
            for size in SIZES:
                with tempfile.TemporaryDirectory() as d:
                    t0 = time.time()
                    converged, misread, far = survey(epd_bin, Path(d), model, size, off)
                    dt = time.time() - t0
                kinds = {}
                for _, g in misread:
                    kinds[g] = kinds.get(g, 0) + 1
                print(
                    f"{model:14s} {size[0]}x{size[1]:<4d} {seed(model, size, off):5d}"
                    f"  {len(misread):3d}/{FRAMES}  {str(kinds):22s} {len(far):3d}"
                    f"  {converged:8d}  {dt:.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
