"""epd.estimate returns the keys and values of `epd estimate --format json`, to the last
bit (timings aside), for a path and for the same points given as an array."""

import json

import numpy as np
import pytest

import epd
from conftest import assert_same_report, cli_json, same_value

# (CLI flags, the same as keyword arguments)
OPTIONS = [
    ([], {}),
    (["--method", "ru-epd"], {"method": "ru-epd"}),
    (["--method", "c-epd"], {"method": "c-epd"}),
    (["--loss", "huber", "--loss-scale", "0.02"], {"loss": "huber", "loss_scale": 0.02}),
    (["--loss", "none"], {"loss": None}),
    (["--min-range", "0.6", "--max-range", "2.5"], {"min_range": 0.6, "max_range": 2.5}),
    (["--nominal-od-in", "20"], {"nominal_od_in": 20.0}),
]


@pytest.mark.parametrize("flags,kwargs", OPTIONS, ids=[" ".join(f) or "defaults" for f, _ in OPTIONS])
def test_path_and_array_match_the_cli(epd_bin, frames, flags, kwargs):
    for f in frames[:2]:
        cli = cli_json(epd_bin, f, *flags)
        assert cli["status"] == "converged", cli
        by_path = epd.estimate(f, **kwargs)
        assert_same_report(by_path, cli)
        points, _ = epd.read(f)
        by_array = epd.estimate(points, **kwargs)
        assert by_array["file"] is None
        assert_same_report(by_array, cli, skip=("file", "elapsed_ms", "read_ms"))
        assert by_path["file"] == str(f)


def test_a_str_path_is_reported_as_given(epd_bin, frames):
    f = str(frames[0])
    assert epd.estimate(f)["file"] == f == cli_json(epd_bin, f)["file"]


def test_units_and_frame_match_the_cli(epd_bin, frames, tmp_path):
    """Millimetres in the optical frame, as the Helios2 SDK writes them (a CSV file)."""
    points, _ = epd.read(frames[0])
    # sensor (X fwd, Y right, Z up) → optical (X right, Y down, Z fwd), in mm
    optical_mm = np.column_stack([points[:, 1], -points[:, 2], points[:, 0]]) * 1e3
    csv = tmp_path / "optical_mm.csv"
    np.savetxt(csv, optical_mm, delimiter=",", fmt="%.17g", header="x,y,z", comments="")
    cli = cli_json(epd_bin, csv, "--units", "mm", "--frame", "optical")
    assert cli["status"] == "converged", cli
    assert_same_report(epd.estimate(csv, units="mm", frame="optical"), cli)
    from_file, _ = epd.read(csv)
    assert np.array_equal(from_file, optical_mm)
    by_array = epd.estimate(optical_mm, units="mm", frame="optical")
    assert_same_report(by_array, cli, skip=("file", "elapsed_ms", "read_ms"))


@pytest.mark.parametrize("unweighted", [False, True])
def test_calibration_matches_the_cli(epd_bin, helios_frames, unweighted):
    plys, table = helios_frames
    f = plys[3]
    flags = ["--calibration", table] + (["--unweighted"] if unweighted else [])
    cli = cli_json(epd_bin, f, *flags)
    assert cli["status"] == "converged", cli
    assert cli["n_calibrated"] > 0 and cli["weighted"] is (not unweighted)
    assert_same_report(epd.estimate(f, calibration=table, unweighted=unweighted), cli)
    points, props = epd.read(f)
    by_array = epd.estimate(
        points, calibration=str(table), intensity=props["intensity"], unweighted=unweighted
    )
    assert_same_report(by_array, cli, skip=("file", "elapsed_ms", "read_ms"))


def test_helios2_frame_without_calibration_matches_the_cli(epd_bin, helios_frames):
    """Invalid pixels (zeros) are dropped and counted the same way."""
    f = helios_frames[0][0]
    cli = cli_json(epd_bin, f)
    assert cli["n_dropped"] > 0
    assert_same_report(epd.estimate(f), cli)


def test_sigma_weights_the_fit(frames):
    points, _ = epd.read(frames[0])
    plain = epd.estimate(points)
    same = epd.estimate(points, sigma=np.full(len(points), 0.03))
    assert same["weighted"] is True and plain["weighted"] is False
    # Equal weights leave the fit where it was (up to rounding).
    assert abs(same["d_max_mm"] - plain["d_max_mm"]) < 1e-6
    uneven = np.where(np.arange(len(points)) % 2 == 0, 0.01, 0.5)
    assert not same_value(epd.estimate(points, sigma=uneven)["d_max_mm"], plain["d_max_mm"])


def test_the_cli_json_is_what_the_dict_dumps(epd_bin, frames):
    """json.loads of the tool's line gives the same Python types (int, float, bool, None;
    a whole float such as `508` reads as an int)."""
    cli = cli_json(epd_bin, frames[0], "--nominal-od-in", "20")
    py = epd.estimate(frames[0], nominal_od_in=20.0)
    for k in py:
        if type(py[k]) is float and type(cli[k]) is int:
            assert float(cli[k]) == py[k], k
        else:
            assert type(py[k]) is type(cli[k]), k
    assert type(py["nominal_od_mm"]) is float and type(py["n_read"]) is int
    json.dumps(py)  # a valid JSON document
