"""epd.simulate makes the frames `epd simulate` writes (points to the bit, the ground
truth with the same keys and values), and epd.read reads them back."""

import json

import numpy as np
import pytest

import epd
from conftest import run_epd, same_value


@pytest.mark.parametrize(
    "flags,kwargs",
    [
        (["--points", "5000"], {"points": 5000}),
        (
            ["--points", "4000", "--sigma", "0.01", "--od-in", "16", "--ovality", "0.05",
             "--wall-mm", "9", "--outliers", "0.02", "--noise", "isotropic"],
            {"points": 4000, "sigma": 0.01, "od_in": 16.0, "ovality": 0.05, "wall_mm": 9.0,
             "outliers": 0.02, "noise": "isotropic"},
        ),
        (["--points", "6000", "--sensor", "helios2"], {"points": 6000, "sensor": "helios2"}),
        (["--points", "5000", "--bend-at", "1.5"], {"points": 5000, "bend_at": 1.5}),
        (["--points", "5000", "--tee-at", "1.2"], {"points": 5000, "tee_at": 1.2}),
    ],
    ids=["plain", "options", "helios2", "bend", "tee"],
)
def test_frames_match_the_cli(epd_bin, tmp_path, flags, kwargs):
    run_epd(epd_bin, "simulate", "--out", tmp_path, "--frames", 2, "--seed", 9, *flags)
    for k in range(2):
        ply = tmp_path / f"frame_{k:04d}.ply"
        truth_cli = json.loads((tmp_path / f"frame_{k:04d}.json").read_text())
        points, truth, props = epd.simulate(seed=9, trial=k, return_properties=True, **kwargs)
        assert points.dtype == np.float64 and points.shape == (truth["n_points"], 3)
        assert points.flags.c_contiguous and points.flags.writeable
        assert list(truth) == list(truth_cli)
        assert all(same_value(truth[key], truth_cli[key]) for key in truth), (truth, truth_cli)
        from_file, props_file = epd.read(ply)
        # Bit for bit, NaN included (the PLY is written in double precision).
        assert from_file.tobytes() == points.tobytes()
        assert sorted(props) == sorted(props_file)
        for name in props:
            assert props[name].tobytes() == props_file[name].tobytes(), name
        two = epd.simulate(seed=9, trial=k, **kwargs)
        assert two[0].tobytes() == points.tobytes()


def test_given_pose_is_the_truth_and_is_found():
    points, truth = epd.simulate(
        points=50_000, seed=2, roll_deg=30.0, pitch_deg=2.0, yaw_deg=-1.5, dy_mm=10.0,
        dz_mm=-20.0, sigma=0.01,
    )
    assert (truth["roll_deg"], truth["pitch_deg"], truth["yaw_deg"]) == pytest.approx(
        (30.0, 2.0, -1.5)
    )
    assert (truth["dy_mm"], truth["dz_mm"]) == pytest.approx((10.0, -20.0))
    est = epd.estimate(points)
    assert est["status"] == "converged"
    assert est["d_max_mm"] == pytest.approx(truth["d_max_mm"], abs=1.0)
    assert est["pitch_deg"] == pytest.approx(truth["pitch_deg"], abs=0.2)
    assert est["dz_mm"] == pytest.approx(truth["dz_mm"], abs=3.0)


def test_read_gives_other_properties(tmp_path):
    f = tmp_path / "c.csv"
    f.write_text("x,y,z,intensity,confidence\n1,0.1,0.2,50,3\n2,-0.2,0.1,60,4\n")
    points, props = epd.read(f)
    assert points.tolist() == [[1.0, 0.1, 0.2], [2.0, -0.2, 0.1]]
    assert list(props) == ["intensity", "confidence"]
    assert props["intensity"].tolist() == [50.0, 60.0]
    assert props["confidence"].dtype == np.float64


@pytest.mark.parametrize("kwargs,layout", [({"bend_at": 1.5}, "bend_ahead"),
                                           ({"tee_at": 1.2}, "tee_ahead")])
def test_bends_and_tees_ahead_are_found_where_simulated(kwargs, layout):
    """A frame with a bend (tee) M ahead: the truth says so, and the survey finds it there
    (the straight section's end within 5 cm, as docs/bends-and-tees.md reports at 1-2 m)."""
    at = next(iter(kwargs.values()))
    points, truth = epd.simulate(seed=4, sigma=0.005, **kwargs)
    assert truth["geometry"] == layout and truth["straight_until_m"] == at
    r = epd.estimate(points)
    assert r["geometry"] == layout, r
    assert abs(r["straight_until_m"] - at) < 0.05, r
    with pytest.raises(ValueError, match="bend_at and tee_at"):
        epd.simulate(bend_at=1.0, tee_at=1.0)
    with pytest.raises(ValueError, match=r"bend_at = -1 m"):
        epd.simulate(bend_at=-1.0)


def test_simulate_signature_shows_the_defaults():
    import inspect

    sig = inspect.signature(epd.simulate)
    assert "Ellipsis" not in str(sig)
    assert sig.parameters["bend_at"].default is None
    assert sig.parameters["od_in"].default == 20.0
    for key in ("d_max_mm", "straight_until_m", "n_points"):
        assert key in epd.simulate.__doc__
