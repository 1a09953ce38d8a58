"""`max_points=` and `sampling=` are `epd estimate --max-points N --sampling METHOD`: the
same points chosen (the choice is seeded), so the same report to the last bit (timings
aside), with the number fitted in `n_sampled`; bad values raise ValueError."""

import pytest

import epd
from conftest import assert_same_report, cli_json, cli_usage_error


@pytest.mark.parametrize("method", ["informed", "stratified", "uniform"])
def test_max_points_matches_the_cli(epd_bin, frames, method):
    f = frames[0]
    cli = cli_json(epd_bin, f, "--max-points", "5000", "--sampling", method)
    assert cli["status"] == "converged", cli
    assert cli["n_sampled"] == 5000 and cli["sampling"] == method
    by_path = epd.estimate(f, max_points=5000, sampling=method)
    assert_same_report(by_path, cli)
    points, _ = epd.read(f)
    by_array = epd.estimate(points, max_points=5000, sampling=method)
    assert_same_report(by_array, cli, skip=("file", "elapsed_ms", "read_ms"))


def test_without_max_points_every_point_is_fitted(frames):
    r = epd.estimate(frames[0])
    assert r["n_sampled"] is None and r["sampling"] is None
    # More points asked for than the frame has: the frame is used whole.
    r = epd.estimate(frames[0], max_points=10**6)
    assert r["n_sampled"] is None


def test_bad_max_points(epd_bin, frames):
    msg = cli_usage_error(epd_bin, "estimate", "--max-points", "999", frames[0])
    with pytest.raises(ValueError) as e:
        epd.estimate(frames[0], max_points=999)
    assert str(e.value) == msg and "at least 1000" in msg
    with pytest.raises(ValueError, match="at least 1000"):
        epd.estimate(frames[0], max_points=-5)
    with pytest.raises(ValueError, match="uniform, stratified, informed"):
        epd.estimate(frames[0], max_points=5000, sampling="best")


def test_a_choice_measured_again_is_the_same_from_an_array(epd_bin, tmp_path):
    """A frame whose informed choice disagrees with its pilot and is measured again on a
    uniform sample (`epd_frame::sampling::Witness`; a 320 × 240 frame with a multipath
    band from the independent numpy caster, seed 121, frame 3): the array path
    (`epd.estimate(points, max_points=…)`, the choice made in memory) gives the file
    path's report (`epd estimate --max-points`, the choice read from the file's records),
    `sampling` included."""
    import numpy as np

    from test_independent_frames import frame, write_ply

    rng = np.random.default_rng(121)
    for _ in range(4):
        pts, _, _ = frame(rng, "multipath", 320, 240)
    path = tmp_path / "multipath_3.ply"
    write_ply(path, pts)
    cli = cli_json(epd_bin, path, "--max-points", "20000")
    assert cli["sampling"] == "uniform", cli
    points, _ = epd.read(path)
    by_array = epd.estimate(points, max_points=20000)
    assert_same_report(by_array, cli, skip=("file", "elapsed_ms", "read_ms"))
