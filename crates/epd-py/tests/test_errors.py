"""Errors are Python exceptions with the `epd` tool's messages: OSError (with its errno)
for a file that cannot be opened, ValueError for bad arguments and unusable clouds."""

import numpy as np
import pytest

import epd
from conftest import cli_json, cli_usage_error


def test_missing_file(epd_bin, tmp_path):
    f = tmp_path / "missing.ply"
    cli = cli_json(epd_bin, f)
    assert cli["status"] == "error"
    with pytest.raises(FileNotFoundError) as e:
        epd.estimate(f)
    assert e.value.strerror == cli["error"]
    assert e.value.filename == str(f)
    with pytest.raises(FileNotFoundError) as e:
        epd.read(f)
    assert e.value.strerror == cli["error"]


def test_directory(epd_bin, tmp_path):
    cli = cli_json(epd_bin, tmp_path)
    with pytest.raises(IsADirectoryError) as e:
        epd.estimate(tmp_path)
    assert str(e.value) == cli["error"]


def test_unreadable_contents(epd_bin, tmp_path):
    f = tmp_path / "bad.ply"
    f.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nend_header\n")
    cli = cli_json(epd_bin, f)
    with pytest.raises(ValueError) as e:
        epd.estimate(f)
    assert str(e.value) == cli["error"]
    with pytest.raises(ValueError) as e:
        epd.read(f)
    assert str(e.value) == cli["error"]


def test_too_few_points(epd_bin, tmp_path):
    pts = np.array([[1.0, 0.1, 0.2], [1.2, -0.2, 0.1], [1.5, 0.2, -0.2]])
    f = tmp_path / "three.csv"
    np.savetxt(f, pts, delimiter=",", fmt="%.17g")
    cli = cli_json(epd_bin, f)
    assert cli["status"] == "error"
    with pytest.raises(ValueError) as e:
        epd.estimate(f)
    assert str(e.value) == cli["error"]
    with pytest.raises(ValueError) as e:
        epd.estimate(pts)
    assert str(e.value) == cli["error"]


def test_millimetres_read_as_metres(epd_bin, frames):
    points, _ = epd.read(frames[0])
    cli = cli_json(epd_bin, frames[0], "--units", "mm")
    with pytest.raises(ValueError) as e:
        epd.estimate(points, units="mm")
    # The tool's message, in Python's terms.
    assert "drop --units mm" in cli["error"]
    assert str(e.value) == cli["error"].replace("--units mm", 'units="mm"')
    assert 'drop units="mm"' in str(e.value)


def test_open3d_like_objects_and_object_arrays(frames):
    """An object holding its points in `.points` (an Open3D PointCloud) is read as
    `np.asarray(obj.points)`; an object array says how to get numbers out of one."""
    points, _ = epd.read(frames[0])

    class Vector3dVector:  # what open3d.utility.Vector3dVector gives numpy
        def __init__(self, a):
            self.a = a

        def __array__(self, dtype=None, copy=None):
            return self.a

    class PointCloud:  # open3d.geometry.PointCloud: no array protocol of its own
        def __init__(self, a):
            self.points = Vector3dVector(a)

    want = epd.estimate(points)
    got = epd.estimate(PointCloud(points))
    assert got["d_max_mm"] == want["d_max_mm"] and got["yaw_deg"] == want["yaw_deg"]
    with pytest.raises(ValueError, match=r"numpy\.asarray\(pcd\.points\)"):
        epd.estimate(np.array([object()] * 3, dtype=object).reshape(1, 3))


def test_signature_shows_the_defaults():
    """help(epd.estimate) shows the defaults as Python values, not Ellipsis."""
    import inspect

    sig = inspect.signature(epd.estimate)
    assert sig.parameters["loss"].default == "cauchy"
    assert sig.parameters["frame"].default == "sensor"
    assert "Ellipsis" not in str(sig)
    assert "d_max_mm" in epd.estimate.__doc__ and "stamp_ns" in epd.estimate.__doc__


def test_status_reasons_are_in_a_users_words():
    """A converged fit's status_reason names no solver setting (stat_tol, ftol, …)."""
    points, _ = epd.simulate(seed=3, points=20000)
    r = epd.estimate(points)
    assert r["status"] == "converged"
    for internal in ("stat_tol", "ftol", "xtol", "gtol"):
        assert internal not in r["status_reason"], r["status_reason"]


@pytest.mark.parametrize(
    "flags,kwargs",
    [
        (["--min-range", "2", "--max-range", "1"], {"min_range": 2.0, "max_range": 1.0}),
        (["--min-range", "-1"], {"min_range": -1.0}),
        (["--loss-scale", "0"], {"loss_scale": 0.0}),
        (["--nominal-od-in", "-3"], {"nominal_od_in": -3.0}),
        (["--unweighted"], {"unweighted": True}),
    ],
)
def test_bad_settings(epd_bin, frames, flags, kwargs):
    msg = cli_usage_error(epd_bin, "estimate", *flags, frames[0])
    for points in (frames[0], epd.read(frames[0])[0]):
        with pytest.raises(ValueError) as e:
            epd.estimate(points, **kwargs)
        assert str(e.value) == msg


def test_missing_calibration_table(epd_bin, frames, tmp_path):
    table = tmp_path / "no-table.json"
    msg = cli_usage_error(epd_bin, "estimate", "--calibration", table, frames[0])
    with pytest.raises(FileNotFoundError) as e:
        epd.estimate(frames[0], calibration=table)
    assert e.value.strerror == msg


def test_damaged_calibration_table(epd_bin, frames, tmp_path):
    table = tmp_path / "table.json"
    table.write_text('{"format": "something-else"}')
    msg = cli_usage_error(epd_bin, "estimate", "--calibration", table, frames[0])
    with pytest.raises(ValueError) as e:
        epd.estimate(epd.read(frames[0])[0], calibration=table)
    assert str(e.value) == msg


def test_calibration_needs_intensity(epd_bin, frames, helios_frames):
    _, table = helios_frames
    cli = cli_json(epd_bin, frames[0], "--calibration", table)
    with pytest.raises(ValueError) as e:
        epd.estimate(frames[0], calibration=table)
    assert str(e.value) == cli["error"]
    with pytest.raises(ValueError, match="intensity"):
        epd.estimate(epd.read(frames[0])[0], calibration=table)


def test_bad_arrays():
    good = epd.simulate(points=1000)[0]
    with pytest.raises(ValueError, match=r"points: expected an array of shape \(N, 3\), got shape \[1000, 2\]"):
        epd.estimate(good[:, :2])
    with pytest.raises(ValueError, match=r"got shape \[3000\]"):
        epd.estimate(good.ravel())
    with pytest.raises(ValueError, match="not a real number type"):
        epd.estimate(good.astype(np.complex128))
    with pytest.raises(ValueError, match="not a real number type"):
        epd.estimate(good > 0)
    with pytest.raises(ValueError, match="points: not an array of numbers|not a real number type"):
        epd.estimate([["a", "b", "c"]] * 10)
    with pytest.raises(ValueError, match="the array holds no points"):
        epd.estimate(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="per point"):
        epd.estimate(good, sigma=np.ones(10))
    with pytest.raises(ValueError, match=r"sigma: expected an array of shape \(N,\)"):
        epd.estimate(good, sigma=np.ones((1000, 1)))


def test_bad_names():
    good = epd.simulate(points=1000)[0]
    with pytest.raises(ValueError, match="unknown method `x`"):
        epd.estimate(good, method="x")
    with pytest.raises(ValueError, match="units"):
        epd.estimate(good, units="km")
    with pytest.raises(ValueError, match="frame"):
        epd.estimate(good, frame="world")
    with pytest.raises(ValueError, match="unknown loss"):
        epd.estimate(good, loss="l1")
    with pytest.raises(ValueError, match="sensor"):
        epd.simulate(sensor="kinect")
    with pytest.raises(ValueError, match="points=0"):
        epd.simulate(points=0)


def test_bad_simulation_settings(epd_bin, tmp_path):
    msg = cli_usage_error(epd_bin, "simulate", "--out", tmp_path / "x", "--ovality", "-1")
    with pytest.raises(ValueError) as e:
        epd.simulate(ovality=-1.0)
    assert str(e.value) == msg
    with pytest.raises(ValueError, match="outside the pipe"):
        epd.simulate(dy_mm=400.0)
    with pytest.raises(ValueError, match="pitch"):
        epd.simulate(pitch_deg=95.0)
