"""ROS 2 bags written by a writer this project did not write (`rosbags`, MCAP storage) are
read by `epd estimate BAG --topic T`: one result per `sensor_msgs/msg/PointCloud2` message,
in order, with its `stamp_ns` and `frame_id`, and the same estimate as the same points
given as a PLY file. Organised and unorganised clouds, big-endian CDR and data, padded
points and rows, FLOAT32/FLOAT64/UINT16 fields, a second topic interleaved, a truncated
file, the bag's folder and its `.mcap` file.

The bags' messages are serialised by `rosbags.typesys` (`serialize_cdr`, little- and
big-endian); the point data inside each message (`data`, laid out by `fields`,
`point_step`, `row_step` and `is_bigendian`) is packed here with numpy, as a camera
driver packs it.
"""

import json

import numpy as np
import pytest

import epd
from conftest import run_epd

# Not skipped without it: `pip install rosbags` (.ci/python-tests.sh does).
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_HUMBLE)
PointCloud2 = TS.types["sensor_msgs/msg/PointCloud2"]
PointField = TS.types["sensor_msgs/msg/PointField"]
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]
Imu = TS.types["sensor_msgs/msg/Imu"]
PC2 = "sensor_msgs/msg/PointCloud2"

TOPIC = "/helios/points"
# Keys whose values differ between a bag's message and the same points in a PLY file.
NOT_COMPARED = ("file", "elapsed_ms", "read_ms", "stamp_ns", "frame_id")
# sensor_msgs/PointField datatypes.
FLOAT32, FLOAT64, UINT16 = 7, 8, 4
DTYPES = {FLOAT32: "f4", FLOAT64: "f8", UINT16: "u2"}


def frames(n, points=6000, sensor="plain"):
    """`n` simulated frames (sensor frame, metres): (points, properties) each."""
    out = []
    for k in range(n):
        pts, _truth, props = epd.simulate(
            seed=21, trial=k, points=points, sensor=sensor, return_properties=True
        )
        out.append((pts, props))
    return out


def to_optical(p):
    """Sensor frame (X forward, Y right, Z up) → optical (X right, Y down, Z forward)."""
    return np.stack([p[:, 1], -p[:, 2], p[:, 0]], axis=1)


def cloud_msg(xyz, stamp_ns, frame_id, *, extra=None, ftype=FLOAT32, big=False,
              height=1, point_step=None, row_pad=0):
    """A PointCloud2 of `xyz` (N×3) in `ftype`, `extra` {name: (values, datatype)} after
    x, y, z; each point padded to `point_step` bytes and each row by `row_pad` bytes."""
    n = len(xyz)
    assert n % height == 0
    width = n // height
    end = ">" if big else "<"
    fields, names, offset = [], [], 0
    for name, dt in [("x", ftype), ("y", ftype), ("z", ftype)] + [
        (k, v[1]) for k, v in (extra or {}).items()
    ]:
        size = np.dtype(DTYPES[dt]).itemsize
        fields.append(PointField(name=name, offset=offset, datatype=dt, count=1))
        names.append((name, end + DTYPES[dt], offset))
        offset += size
    step = point_step or offset
    rec = np.dtype({"names": [a for a, _, _ in names], "formats": [b for _, b, _ in names],
                    "offsets": [c for _, _, c in names], "itemsize": step})
    arr = np.zeros(n, dtype=rec)
    for i, a in enumerate("xyz"):
        arr[a] = xyz[:, i]
    for k, (v, _) in (extra or {}).items():
        arr[k] = v
    rows = arr.tobytes()
    row_bytes = width * step
    data = b"".join(
        rows[r * row_bytes:(r + 1) * row_bytes] + b"\xee" * row_pad for r in range(height)
    )
    return PointCloud2(
        header=Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
                      frame_id=frame_id),
        height=height, width=width, fields=fields, is_bigendian=big,
        point_step=step, row_step=row_bytes + row_pad,
        data=np.frombuffer(data, dtype=np.uint8), is_dense=False,
    )


def write_bag(path, messages, *, big=False):
    """A rosbag2 folder (MCAP storage) of `messages`: (topic, msgtype, stamp_ns, msg)."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for topic, msgtype, stamp, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=TS)
            w.write(conns[topic], stamp, TS.serialize_cdr(msg, msgtype, little_endian=not big))
    return path


def write_ply(path, xyz, props=None):
    """A binary little-endian PLY of `xyz` (double) and `props` {name: values} (float)."""
    props = props or {}
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(xyz)}",
            "property double x", "property double y", "property double z"]
    head += [f"property double {k}" for k in props]
    rec = np.zeros(len(xyz), dtype=[(c, "<f8") for c in ["x", "y", "z", *props]])
    for i, a in enumerate("xyz"):
        rec[a] = xyz[:, i]
    for k, v in props.items():
        rec[k] = v
    path.write_bytes(("\n".join(head) + "\nend_header\n").encode() + rec.tobytes())
    return path


def estimate_lines(epd_bin, *args):
    """The JSON objects of `epd estimate --format json -q ARGS…`, and the process."""
    p = run_epd(epd_bin, "estimate", "--format", "json", "-q", *args, check=False)
    return [json.loads(ln) for ln in p.stdout.splitlines() if ln.strip()], p


def assert_same_estimate(bag_row, ply_row):
    """The same keys, the same values (numbers to 1e-6 of their unit: mm, degrees)."""
    assert list(bag_row) == list(ply_row)
    assert bag_row["status"] == "converged", bag_row
    for k, v in ply_row.items():
        if k in NOT_COMPARED:
            continue
        w = bag_row[k]
        if isinstance(v, float) or isinstance(w, float):
            assert w is not None and abs(w - v) <= 1e-6, (k, w, v)
        else:
            assert w == v, (k, w, v)


STAMP0 = 1_700_000_000_123_456_789
DT = 33_333_333


def test_unorganised_optical_float32_equals_ply(epd_bin, tmp_path):
    """Unorganised float32 clouds in a camera's optical frame (read as such from their
    `frame_id`), with intensity: each message's estimate equals that of its points as PLY
    (the same float32 values, in the sensor frame), stamps and frame ids kept in order."""
    fr = frames(3, sensor="helios2")
    msgs, plys = [], []
    for k, (pts, props) in enumerate(fr):
        p32 = pts.astype(np.float32)
        inten = props["intensity"].astype(np.float32)
        msgs.append((TOPIC, PC2, STAMP0 + k * DT, cloud_msg(
            to_optical(p32.astype(np.float64)).astype(np.float32), STAMP0 + k * DT,
            "helios_optical_frame", extra={"intensity": (inten, FLOAT32)})))
        plys.append(write_ply(tmp_path / f"f{k}.ply", p32.astype(np.float64),
                              {"intensity": inten.astype(np.float64)}))
    bag = write_bag(tmp_path / "run", msgs)
    mcap = next(bag.glob("*.mcap"))
    for source in (bag, mcap):
        rows, p = estimate_lines(epd_bin, source, "--topic", TOPIC)
        assert p.returncode == 0, p.stderr
        assert [r["stamp_ns"] for r in rows] == [STAMP0 + k * DT for k in range(3)]
        assert all(r["frame_id"] == "helios_optical_frame" for r in rows)
        assert all(r["file"] == str(source) for r in rows)
        ply_rows, _ = estimate_lines(epd_bin, *plys)
        for r, q in zip(rows, ply_rows):
            assert q["stamp_ns"] is None and q["frame_id"] is None
            assert_same_estimate(r, q)
    # An explicit --frame wins over the frame id: read as the sensor frame, the optical
    # points are not a pipe along X and the estimate differs.
    rows, _ = estimate_lines(epd_bin, bag, "--frame", "sensor")
    assert rows[0]["d_max_mm"] != ply_rows[0]["d_max_mm"]


def test_organised_big_endian_padded_equals_ply(epd_bin, tmp_path):
    """An organised cloud (60 rows × 100 columns) in big-endian CDR with big-endian data
    (`is_bigendian`), FLOAT64 coordinates and a UINT16 intensity, points padded to 40 bytes
    and rows by 24 bytes: the same estimates as the PLY of the same points, in order."""
    fr = frames(2, points=6000)
    msgs, plys = [], []
    for k, (pts, _props) in enumerate(fr):
        inten = (np.arange(len(pts)) % 4000).astype(np.uint16)
        msgs.append((TOPIC, PC2, STAMP0 + k * DT, cloud_msg(
            pts, STAMP0 + k * DT, "helios_link", extra={"intensity": (inten, UINT16)},
            ftype=FLOAT64, big=True, height=60, point_step=40, row_pad=24)))
        plys.append(write_ply(tmp_path / f"f{k}.ply", pts, {"intensity": inten}))
    bag = write_bag(tmp_path / "run", msgs, big=True)
    rows, p = estimate_lines(epd_bin, bag, "--topic", TOPIC, "--frame", "sensor")
    assert p.returncode == 0, p.stderr
    ply_rows, _ = estimate_lines(epd_bin, *plys)
    assert len(rows) == 2
    for r, q in zip(rows, ply_rows):
        assert_same_estimate(r, q)
    assert [r["frame_id"] for r in rows] == ["helios_link"] * 2


def test_body_frame_flu(epd_bin, tmp_path):
    """A cloud in the ROS body frame (X forward, Y left, Z up) read with `--frame flu`
    (an alias of `body`) gives the pose of the sensor-frame PLY; read as `sensor` the pose
    is mirrored (yaw and δy change sign)."""
    (pts, _), = frames(1)
    flu = pts * np.array([1.0, -1.0, 1.0])
    bag = write_bag(tmp_path / "run", [(TOPIC, PC2, STAMP0, cloud_msg(flu, STAMP0, "base_link",
                                                                      ftype=FLOAT64))])
    ply = write_ply(tmp_path / "f.ply", pts)
    (q,), _ = estimate_lines(epd_bin, ply)
    for name in ("flu", "body"):
        (r,), _ = estimate_lines(epd_bin, bag, "--frame", name)
        assert_same_estimate(r, q)
    (m,), _ = estimate_lines(epd_bin, bag)
    assert abs(m["yaw_deg"] + q["yaw_deg"]) < 1e-6 and abs(m["dy_mm"] + q["dy_mm"]) < 1e-6


def test_interleaved_topics(epd_bin, tmp_path):
    """A second PointCloud2 topic and an IMU topic interleaved with the camera's: only the
    topic asked for is read; without --topic the choice is a usage error naming both;
    `epd topics` lists every topic with its type and count."""
    fr = frames(3)
    msgs = []
    imu = Imu(header=Header(stamp=Time(sec=1, nanosec=0), frame_id="imu"),
              orientation=TS.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
              orientation_covariance=np.zeros(9), angular_velocity=TS.types[
                  "geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
              angular_velocity_covariance=np.zeros(9), linear_acceleration=TS.types[
                  "geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.8),
              linear_acceleration_covariance=np.zeros(9))
    for k, (pts, _) in enumerate(fr):
        t = STAMP0 + k * DT
        msgs.append(("/other/points", PC2, t, cloud_msg(pts[:500] * 3.0, t + 1, "other")))
        msgs.append((TOPIC, PC2, t + 5, cloud_msg(pts, t, "helios_link")))
        msgs.append(("/imu", "sensor_msgs/msg/Imu", t + 7, imu))
    bag = write_bag(tmp_path / "run", msgs)
    rows, p = estimate_lines(epd_bin, bag, "--topic", TOPIC)
    assert p.returncode == 0, p.stderr
    assert [r["stamp_ns"] for r in rows] == [STAMP0 + k * DT for k in range(3)]
    plys = [write_ply(tmp_path / f"f{k}.ply", pts.astype(np.float32).astype(np.float64))
            for k, (pts, _) in enumerate(fr)]
    ply_rows, _ = estimate_lines(epd_bin, *plys)
    for r, q in zip(rows, ply_rows):
        assert_same_estimate(r, q)
    p = run_epd(epd_bin, "estimate", "-q", bag, check=False)
    assert p.returncode == 2 and "/helios/points" in p.stderr and "/other/points" in p.stderr
    p = run_epd(epd_bin, "estimate", "-q", bag, "--topic", "/imu", check=False)
    assert p.returncode == 2 and "sensor_msgs/msg/Imu" in p.stderr
    listing = run_epd(epd_bin, "topics", bag).stdout
    lines = {ln.split()[0]: ln.split()[1:] for ln in listing.splitlines()[2:]}
    assert lines == {"/helios/points": [PC2, "3"], "/imu": ["sensor_msgs/msg/Imu", "3"],
                     "/other/points": [PC2, "3"]}


def test_truncated_bag_keeps_what_it_read(epd_bin, tmp_path):
    """A bag cut short in the middle of a message (a recording that died): the messages
    before the cut are reported as in the whole bag, then an error row naming the byte
    offset; exit code 1."""
    fr = frames(8, points=20000)
    msgs = [(TOPIC, PC2, STAMP0 + k * DT, cloud_msg(pts, STAMP0 + k * DT, "helios_link"))
            for k, (pts, _) in enumerate(fr)]
    bag = write_bag(tmp_path / "run", msgs)
    mcap = next(bag.glob("*.mcap"))
    whole, p = estimate_lines(epd_bin, mcap)
    assert p.returncode == 0 and len(whole) == 8
    data = mcap.read_bytes()
    # 20 000 points × 12 bytes per message: cut in the middle of the sixth.
    cut = data.index(b"helios_link", 0)
    for _ in range(5):
        cut = data.index(b"helios_link", cut + 1)
    cut += 100_000
    short = tmp_path / "short.mcap"
    short.write_bytes(data[:cut])
    rows, p = estimate_lines(epd_bin, short)
    assert p.returncode == 1
    assert len(rows) == 6, [r["error"] for r in rows]
    for r, w in zip(rows[:5], whole[:5]):
        assert_same_estimate(r, w)
        assert r["stamp_ns"] == w["stamp_ns"]
    last = rows[5]
    assert last["status"] == "error" and last["stamp_ns"] is None
    assert f"byte {cut}" in last["error"] and "truncated" in last["error"], last["error"]
    assert "5 messages" in last["error"]
    assert f"byte {cut}" in run_epd(epd_bin, "estimate", short, check=False).stderr
    t = run_epd(epd_bin, "topics", short, check=False)
    assert t.returncode == 1 and "5" in t.stdout and f"byte {cut}" in t.stderr


def test_files_have_null_stamps_and_text_names_the_message(epd_bin, tmp_path):
    """A file's report has `stamp_ns` and `frame_id` null, in JSON and CSV (the same
    columns for files and bags); the text output names a message by topic and index."""
    (pts, _), = frames(1)
    ply = write_ply(tmp_path / "f.ply", pts)
    bag = write_bag(tmp_path / "run", [(TOPIC, PC2, STAMP0, cloud_msg(pts, STAMP0, "x"))])
    csv = run_epd(epd_bin, "estimate", "--format", "csv", "-q", ply, bag).stdout.splitlines()
    head = csv[0].split(",")
    assert head[-2:] == ["stamp_ns", "frame_id"]
    assert csv[1].endswith(",,") and csv[2].endswith(f",{STAMP0},x")
    text = run_epd(epd_bin, "estimate", "-q", bag).stdout
    assert text.startswith(f"{bag} {TOPIC} #0: ml-epd converged"), text


def test_read_bag_yields_the_messages(epd_bin, tmp_path):
    """`epd.read_bag(path, topic)` yields `(stamp_ns, points, properties)` per message of
    the topic, as stored (optical-frame points stay optical), the other topic skipped;
    `frame_id` is the last message's; a truncated bag raises after the messages before
    the cut, naming the byte offset."""
    fr = frames(3, sensor="helios2")
    msgs = []
    for k, (pts, props) in enumerate(fr):
        t = STAMP0 + k * DT
        opt = to_optical(pts.astype(np.float32).astype(np.float64)).astype(np.float32)
        msgs.append((TOPIC, PC2, t, cloud_msg(
            opt, t, "helios_optical_frame",
            extra={"intensity": (props["intensity"].astype(np.float32), FLOAT32)})))
        msgs.append(("/other/points", PC2, t + 1, cloud_msg(pts[:100], t, "other")))
    bag = write_bag(tmp_path / "run", msgs)
    it = epd.read_bag(bag, TOPIC)
    assert it.frame_id is None
    got = list(it)
    assert [s for s, _, _ in got] == [STAMP0 + k * DT for k in range(3)]
    assert it.frame_id == "helios_optical_frame"
    for (s, pts, props), (want, wprops) in zip(got, fr):
        assert pts.dtype == np.float64 and pts.shape == want.shape
        w = to_optical(want.astype(np.float32).astype(np.float64)).astype(np.float32)
        assert np.array_equal(pts, w.astype(np.float64), equal_nan=True)
        assert list(props) == ["intensity"]
        assert np.array_equal(props["intensity"],
                              wprops["intensity"].astype(np.float32).astype(np.float64))
        # The same estimate as the tool's, given the frame the tool took from frame_id.
    r = epd.estimate(got[0][1], frame="optical")
    (row, *_), _ = estimate_lines(epd_bin, bag, "--topic", TOPIC)
    assert abs(r["d_max_mm"] - row["d_max_mm"]) <= 1e-6
    with pytest.raises(ValueError, match="PointCloud2 topics: /helios/points, /other/points"):
        epd.read_bag(bag)
    with pytest.raises(OSError):
        epd.read_bag(tmp_path / "missing.mcap")
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    cut = data.index(b"helios_optical_frame", data.index(b"helios_optical_frame") + 1) + 5000
    short = tmp_path / "short.mcap"
    short.write_bytes(data[:cut])
    it = epd.read_bag(short, TOPIC)
    assert next(it)[0] == STAMP0
    with pytest.raises(ValueError, match=f"byte {cut}"):
        next(it)
