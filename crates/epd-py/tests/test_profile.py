"""`epd profile BAG --topic T --out DIR` on a bag written by `rosbags` (a writer this project
did not write) of a known pipe, and `epd estimate FILE --export-fit OUT.ply` / `epd view`:

- profile.csv has a row per message in order, with the message's stamp, the time since the
  first message, the distance from `--speed` or from an odometry topic's path length, and
  the mean diameter and ovality within their 1-σ of the truth;
- `--shard K/N` outputs concatenate into the whole run's table;
- the exported PLY (read here by a reader of its own, numpy only, and by `plyfile`) holds the points with a
  `residual_mm` equal to their range error to the fitted wall, computed here from the
  reported fit, and mesh vertices on that wall to 1e-6.

The clouds are drawn here with numpy from a known elliptic pipe and pose (not by epd).
"""

import csv
import io
import json
import math

import numpy as np
import pytest

from conftest import run_epd

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
PC2 = "sensor_msgs/msg/PointCloud2"
ODOM = "nav_msgs/msg/Odometry"
TOPIC = "/helios/points"

# The known pipe (m) and the noise along the rays (m).
D_MAX, D_MIN = 0.50, 0.48
SIGMA = 0.004


def rotation(roll, pitch, yaw):
    """R = Rz(yaw)·Ry(pitch)·Rx(roll): sensor frame → pipe frame (eq. 3)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def pipe_frame(seed, n=8000):
    """Points (sensor frame, m) on the known pipe seen from a pose, with range noise."""
    rng = np.random.default_rng(seed)
    r = rotation(0.2, 0.01 * seed, -0.02, )
    dy, dz = 0.01, -0.015
    x = rng.uniform(0.4, 2.5, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    wall = np.stack([x, 0.5 * D_MAX * np.cos(phi), 0.5 * D_MIN * np.sin(phi)], axis=1)
    p = (wall - np.array([0, dy, dz])) @ r  # Rᵀ·(w − δ), row by row
    rng_ = np.linalg.norm(p, axis=1)
    return p * ((rng_ + rng.normal(0, SIGMA, n)) / rng_)[:, None]


def cloud_msg(xyz, stamp_ns, frame_id="helios_link"):
    """An unorganised float32 PointCloud2 of `xyz`."""
    F = T["sensor_msgs/msg/PointField"]
    data = np.asarray(xyz, dtype="<f4").tobytes()
    return T[PC2](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9,
                                                   nanosec=stamp_ns % 10**9),
            frame_id=frame_id),
        height=1, width=len(xyz),
        fields=[F(name=a, offset=4 * i, datatype=7, count=1) for i, a in enumerate("xyz")],
        is_bigendian=False, point_step=12, row_step=12 * len(xyz),
        data=np.frombuffer(data, dtype=np.uint8), is_dense=True,
    )


def odom_msg(stamp_ns, x, y):
    """A nav_msgs/msg/Odometry at (x, y, 0)."""
    V = T["geometry_msgs/msg/Vector3"]
    return T[ODOM](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9,
                                                   nanosec=stamp_ns % 10**9),
            frame_id="odom"),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
            covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=V(x=0.0, y=0.0, z=0.0),
                                               angular=V(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36)),
    )


T0 = 1_700_000_000 * 10**9
N_MESSAGES = 6
PERIOD_NS = 100_000_000  # 10 Hz


def odometry_path(t_s):
    """The robot's path: 1 m/s along x for 0.24 s, then along y (a turn at an odometry
    stamp): (x, y)."""
    if t_s <= 0.24:
        return t_s, 0.0
    return 0.24, t_s - 0.24


@pytest.fixture(scope="module")
def run_bag(tmp_path_factory):
    """A bag of 6 clouds at 10 Hz interleaved with odometry at 50 Hz."""
    path = tmp_path_factory.mktemp("run") / "run"
    messages = []
    for k in range(N_MESSAGES):
        stamp = T0 + k * PERIOD_NS
        messages.append((stamp, TOPIC, PC2, cloud_msg(pipe_frame(k), stamp)))
    for j in range(0, 30):
        stamp = T0 + j * 20_000_000
        messages.append((stamp, "/odom", ODOM, odom_msg(stamp, *odometry_path(j * 0.02))))
    messages.sort(key=lambda m: m[0])
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for stamp, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=TS)
            w.write(conns[topic], stamp, TS.serialize_cdr(msg, msgtype))
    return path


def read_csv(path):
    return list(csv.DictReader(io.StringIO(path.read_text())))


def test_profile_columns_against_the_truth(epd_bin, run_bag, tmp_path):
    out = tmp_path / "speed"
    run_epd(epd_bin, "profile", run_bag, "--topic", TOPIC, "--out", out, "--speed", "0.5", "-q")
    rows = read_csv(out / "profile.csv")
    assert (out / "profile.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [int(r["frame"]) for r in rows] == list(range(N_MESSAGES))
    assert [int(r["message_index"]) for r in rows] == list(range(N_MESSAGES))
    d_true = 0.5 * (D_MAX + D_MIN) * 1e3
    ovality_true = 100 * (D_MAX - D_MIN) / (0.5 * (D_MAX + D_MIN))
    for k, r in enumerate(rows):
        assert int(r["stamp_ns"]) == T0 + k * PERIOD_NS
        assert float(r["time_s"]) == pytest.approx(k * 0.1, abs=1e-9)
        assert float(r["distance_m"]) == pytest.approx(0.5 * k * 0.1, abs=1e-9)
        assert r["status"] == "converged" and r["flagged"] == "false", r
        assert r["geometry"] == "straight"
        # Within 4 of their 1-σ (and the 1-σ not absurdly large) of the known pipe.
        s = float(r["sigma_d_mean_mm"])
        assert 0 < s < 1.0
        assert abs(float(r["d_mean_mm"]) - d_true) < 4 * s + 0.05, r
        so = float(r["sigma_ovality_pct"])
        assert abs(float(r["ovality_pct"]) - ovality_true) < 4 * so + 0.01, r
        assert float(r["d_max_mm"]) == pytest.approx(
            float(r["d_mean_mm"]) * (1 + float(r["ovality_pct"]) / 200), rel=1e-9)


def test_profile_distance_from_odometry_is_the_path_length(epd_bin, run_bag, tmp_path):
    out = tmp_path / "odom"
    run_epd(epd_bin, "profile", run_bag, "--topic", TOPIC, "--out", out,
            "--odometry-topic", "/odom", "-q")
    rows = read_csv(out / "profile.csv")
    for k, r in enumerate(rows):
        t = k * 0.1
        # The path length: 1 m/s all along (the turn at 0.24 s does not shorten it);
        # the last cloud (0.5 s) is within the odometry's 0…0.58 s.
        assert float(r["distance_m"]) == pytest.approx(t, abs=1e-9), r
    # Not the displacement: at 0.5 s the robot is √(0.24² + 0.26²) = 0.354 m from the start.
    assert float(rows[5]["distance_m"]) > 0.45


def test_profile_shards_concatenate_into_the_run(epd_bin, run_bag, tmp_path):
    whole = tmp_path / "whole"
    run_epd(epd_bin, "profile", run_bag, "--out", whole, "-q")
    parts = []
    for k in (1, 2, 3):
        d = tmp_path / f"shard{k}"
        run_epd(epd_bin, "profile", run_bag, "--out", d, "--shard", f"{k}/3", "-q")
        parts.append((d / "profile.csv").read_text())
    assert "".join(parts) == (whole / "profile.csv").read_text()
    assert parts[1].count("\n") == 2 and not parts[1].startswith("frame,")


def test_profile_usage_errors(epd_bin, run_bag, tmp_path):
    p = run_epd(epd_bin, "profile", run_bag, "--out", tmp_path / "x", "--speed", "-1",
                check=False)
    assert p.returncode == 2 and "--speed" in p.stderr
    p = run_epd(epd_bin, "profile", run_bag, "--out", tmp_path / "x",
                "--odometry-topic", TOPIC, check=False)
    assert p.returncode == 2 and "nav_msgs/msg/Odometry" in p.stderr


def read_ply(path):
    """A binary little-endian PLY read with numpy from its header: {element: records}."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode().splitlines()
    assert header[1] == "format binary_little_endian 1.0"
    types = {"double": "<f8", "float": "<f4", "uchar": "u1", "int": "<i4"}
    elements, comments = [], [l for l in header if l.startswith("comment")]
    for line in header:
        w = line.split()
        if w[0] == "element":
            elements.append([w[1], int(w[2]), []])
        elif w[0] == "property":
            elements[-1][2].append(w[1:])
    out, at = {}, end
    for name, n, props in elements:
        if props[0][0] == "list":
            # Faces: a uchar count (3), three ints, then the scalar properties.
            assert props[0][1:3] == ["uchar", "int"]
            dt = np.dtype([("n", "u1"), ("v", "<i4", 3)] + [(p[1], types[p[0]]) for p in props[1:]])
        else:
            dt = np.dtype([(p[1], types[p[0]]) for p in props])
        out[name] = np.frombuffer(raw, dtype=dt, count=n, offset=at)
        at += n * dt.itemsize
    assert at == len(raw)
    return out, comments


def range_residual_mm(p, est):
    """The range error (mm) of points `p` (sensor frame, m) to the elliptic cylinder of a
    JSON estimate: the ray from the sensor through p meets y²/a² + z²/b² = 1 in the pipe
    frame at t·p; residual = (1 − t)·‖p‖."""
    r = rotation(*(math.radians(est[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg")))
    a, b = est["d_max_mm"] / 2e3, est["d_min_mm"] / 2e3
    y0, z0 = est["dy_mm"] / 1e3, est["dz_mm"] / 1e3
    q = p @ r.T
    u, v = q[:, 1], q[:, 2]
    A = (u / a) ** 2 + (v / b) ** 2
    B = y0 * u / a**2 + z0 * v / b**2
    C = (y0 / a) ** 2 + (z0 / b) ** 2 - 1
    t = (-B + np.sqrt(B * B - A * C)) / A
    return (1 - t) * np.linalg.norm(p, axis=1) * 1e3


def test_export_fit_residuals_and_wall(epd_bin, tmp_path):
    pts = pipe_frame(3)
    xyz = tmp_path / "frame.xyz"
    np.savetxt(xyz, pts, fmt="%.17g")
    ply = tmp_path / "fit.ply"
    p = run_epd(epd_bin, "estimate", xyz, "--format", "json", "--export-fit", ply)
    est = json.loads(p.stdout)
    assert est["status"] == "converged"
    ply_data, comments = read_ply(ply)
    v, f = ply_data["vertex"], ply_data["face"]
    points = v[v["mesh"] == 0]
    mesh = v[v["mesh"] == 1]
    assert len(points) == len(pts) and len(mesh) > 0 and len(f) > 0
    xyz_back = np.stack([points[c] for c in "xyz"], axis=1)
    np.testing.assert_allclose(xyz_back, pts, atol=1e-12)
    # The residual property is the range error to the reported fit (float32: 1e-3 mm).
    np.testing.assert_allclose(points["residual_mm"], range_residual_mm(xyz_back, est),
                               atol=2e-3)
    # Their spread is the noise drawn.
    assert np.std(points["residual_mm"]) == pytest.approx(SIGMA * 1e3, rel=0.1)
    # The mesh vertices lie on the fitted wall to 1e-6.
    m = np.stack([mesh[c] for c in "xyz"], axis=1)
    r = rotation(*(math.radians(est[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg")))
    w = m @ r.T + np.array([0, est["dy_mm"], est["dz_mm"]]) / 1e3
    on = (w[:, 1] / (est["d_max_mm"] / 2e3)) ** 2 + (w[:, 2] / (est["d_min_mm"] / 2e3)) ** 2
    np.testing.assert_allclose(np.sqrt(on), 1.0, atol=1e-6)
    # Every triangle's indices name mesh vertices.
    assert (f["n"] == 3).all()
    assert f["v"].min() >= len(points) and f["v"].max() < len(v)
    assert any("d_max_mm" in c for c in comments)


def test_export_fit_reads_in_plyfile(epd_bin, tmp_path):
    """The export read by `plyfile` (a PLY reader this project did not write, as viewers
    parse the format): the same points, residuals and triangles as our own reader sees,
    each triangle's three vertices on the fitted wall."""
    plyfile = pytest.importorskip("plyfile")
    pts = pipe_frame(6)
    xyz = tmp_path / "frame.xyz"
    np.savetxt(xyz, pts, fmt="%.17g")
    ply = tmp_path / "fit.ply"
    est = json.loads(run_epd(epd_bin, "estimate", xyz, "--format", "json",
                             "--export-fit", ply).stdout)
    data = plyfile.PlyData.read(str(ply))
    v, f = data["vertex"].data, data["face"].data
    assert {"x", "y", "z", "residual_mm", "mesh"} <= set(v.dtype.names)
    points = v[v["mesh"] == 0]
    np.testing.assert_allclose(np.stack([points[c] for c in "xyz"], axis=1), pts, atol=1e-12)
    np.testing.assert_allclose(points["residual_mm"],
                               range_residual_mm(np.stack([points[c] for c in "xyz"], axis=1),
                                                 est), atol=2e-3)
    tri = np.stack(f["vertex_indices"])
    assert tri.shape == (len(f), 3) and len(f) > 0
    ours = read_ply(ply)[0]["face"]["v"]
    np.testing.assert_array_equal(tri, ours)
    assert (v["mesh"][tri] == 1).all()
    m = np.stack([v[c][tri.ravel()] for c in "xyz"], axis=1)
    r = rotation(*(math.radians(est[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg")))
    w = m @ r.T + np.array([0, est["dy_mm"], est["dz_mm"]]) / 1e3
    on = (w[:, 1] / (est["d_max_mm"] / 2e3)) ** 2 + (w[:, 2] / (est["d_min_mm"] / 2e3)) ** 2
    np.testing.assert_allclose(np.sqrt(on), 1.0, atol=1e-6)


def test_export_fit_in_millimetres_lies_over_the_file(epd_bin, tmp_path):
    """In the file's own unit and frame (optical, mm): the points are written back as read."""
    pts = pipe_frame(4)
    optical_mm = np.stack([pts[:, 1], -pts[:, 2], pts[:, 0]], axis=1) * 1e3
    xyz = tmp_path / "frame.xyz"
    np.savetxt(xyz, optical_mm, fmt="%.17g")
    ply = tmp_path / "fit.ply"
    run_epd(epd_bin, "estimate", xyz, "--units", "mm", "--frame", "optical",
            "--export-fit", ply, "-q")
    v = read_ply(ply)[0]["vertex"]
    points = v[v["mesh"] == 0]
    np.testing.assert_allclose(np.stack([points[c] for c in "xyz"], axis=1), optical_mm,
                               atol=1e-9)


def test_view_draws_a_png(epd_bin, tmp_path):
    xyz = tmp_path / "frame.xyz"
    np.savetxt(xyz, pipe_frame(5), fmt="%.17g")
    out = tmp_path / "frame.png"
    run_epd(epd_bin, "view", xyz, "--out", out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    p = run_epd(epd_bin, "view", xyz, "--out", out, "--limit-mm", "0", check=False)
    assert p.returncode == 2


def test_profile_of_a_truncated_bag_keeps_what_was_read(epd_bin, run_bag, tmp_path):
    """A recording cut short: a row per message before the damage, then a row with status
    `error` naming the byte offset; exit 1."""
    mcap = next(run_bag.glob("*.mcap"))
    cut = tmp_path / "cut.mcap"
    raw = mcap.read_bytes()
    cut.write_bytes(raw[: int(len(raw) * 0.6)])
    out = tmp_path / "cut"
    p = run_epd(epd_bin, "profile", cut, "--topic", TOPIC, "--out", out, "-q", check=False)
    assert p.returncode == 1
    rows = read_csv(out / "profile.csv")
    assert 1 <= len(rows) < N_MESSAGES
    assert [int(r["frame"]) for r in rows] == list(range(len(rows)))
    assert all(r["status"] == "converged" for r in rows[:-1])
    assert rows[-1]["status"] == "error" and "byte" in rows[-1]["reason"], rows[-1]
    assert rows[-1]["flagged"] == "true"


def test_profile_values_are_those_of_estimate(epd_bin, run_bag, tmp_path):
    """Each row's values are `epd estimate`'s for the same message (one measurement)."""
    out = tmp_path / "p"
    run_epd(epd_bin, "profile", run_bag, "--out", out, "-q")
    rows = read_csv(out / "profile.csv")
    p = run_epd(epd_bin, "estimate", run_bag, "--format", "json", "-q")
    est = [json.loads(l) for l in p.stdout.splitlines()]
    assert len(est) == len(rows)
    for r, e in zip(rows, est):
        assert int(r["stamp_ns"]) == e["stamp_ns"]
        for k in ("d_mean_mm", "sigma_d_mean_mm", "ovality_pct", "d_max_mm", "d_min_mm"):
            assert float(r[k]) == e[k], k
