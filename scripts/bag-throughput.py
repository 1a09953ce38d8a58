#!/usr/bin/env python3
"""Throughput and peak memory of `epd estimate BAG` on a long ROS 2 bag.

Writes a bag of MESSAGES `sensor_msgs/msg/PointCloud2` messages (MCAP storage, written by
`rosbags`) from DISTINCT simulated 640×480 Helios2 frames (float32 x, y, z and intensity
in the camera's optical frame, `frame_id` helios_optical_frame, cycled), then runs

    /usr/bin/time -v EPD estimate BAG --topic /helios/points --format csv -o /dev/null -q
        --threads THREADS

and prints messages per second (wall time) and the peak resident memory, with the bag's
size for scale. Needs `rosbags`, and the `epd` Python package for the frames, or
`--ply-dir DIR`: the frames of `epd simulate --out DIR --sensor helios2 --precision f32`
(binary PLY, x y z in the sensor frame and intensity; read with `plyfile`).

    python3 scripts/bag-throughput.py EPD_BIN [--messages 300] [--distinct 10]
        [--threads 2] [--points N] [--dir DIR] [--ply-dir DIR]
"""

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore


def frame(a, k):
    """Frame k: its points (N × 3, sensor frame: X forward, Y right, Z up) and intensity."""
    if a.ply_dir is None:
        import epd
        pts, _, props = epd.simulate(seed=5, trial=k, sensor="helios2", points=a.points,
                                     return_properties=True)
        return pts, props
    from plyfile import PlyData
    files = sorted(Path(a.ply_dir).glob("*.ply"))
    v = PlyData.read(str(files[k % len(files)]))["vertex"]
    pts = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    idx = np.flatnonzero(np.isfinite(pts).all(axis=1) & (np.abs(pts).sum(axis=1) > 0))
    if a.points is not None and a.points < len(idx):
        # An even subsample over the whole image.
        idx = idx[np.linspace(0, len(idx) - 1, a.points).astype(int)]
    names = {p.name for p in v.properties}
    props = {"intensity": np.asarray(v["intensity"])[idx]} if "intensity" in names else {}
    return pts[idx], props


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("epd_bin")
    ap.add_argument("--messages", type=int, default=300)
    ap.add_argument("--distinct", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--points", type=int, default=None, help="subsample (default: all)")
    ap.add_argument("--dir", default=None)
    ap.add_argument("--ply-dir", default=None, help="frames from `epd simulate` PLY files")
    a = ap.parse_args()

    ts = get_typestore(Stores.ROS2_HUMBLE)
    pc2 = ts.types["sensor_msgs/msg/PointCloud2"]
    field = ts.types["sensor_msgs/msg/PointField"]
    header = ts.types["std_msgs/msg/Header"]
    stamp = ts.types["builtin_interfaces/msg/Time"]

    blobs = []
    names = ["x", "y", "z"]
    for k in range(a.distinct):
        pts, props = frame(a, k)
        # Intensity when the frames carry it (a PLY of clean tof-sim frames does not).
        names = ["x", "y", "z"] + sorted(props)
        rec = np.zeros(len(pts), dtype=[(n, "<f4") for n in names])
        # Optical frame: X right, Y down, Z forward.
        rec["x"], rec["y"], rec["z"] = pts[:, 1], -pts[:, 2], pts[:, 0]
        for n, values in props.items():
            rec[n] = values
        blobs.append(np.frombuffer(rec.tobytes(), dtype=np.uint8))
    step = 4 * len(names)
    fields = [field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(names)]

    work = Path(a.dir or tempfile.mkdtemp(prefix="epd-bag-"))
    bag = work / "run"
    t0 = time.time()
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/helios/points", pc2.__msgtype__, typestore=ts)
        for i in range(a.messages):
            data = blobs[i % a.distinct]
            n = len(data) // step
            t = 1_700_000_000 * 10**9 + i * 33_333_333
            msg = pc2(header=header(stamp=stamp(sec=t // 10**9, nanosec=t % 10**9),
                                    frame_id="helios_optical_frame"),
                      height=1, width=n, fields=fields, is_bigendian=False, point_step=step,
                      row_step=step * n, data=data, is_dense=False)
            w.write(conn, t, ts.serialize_cdr(msg, pc2.__msgtype__))
    size = sum(f.stat().st_size for f in bag.glob("*.mcap"))
    print(f"bag: {a.messages} messages of {len(blobs[0]) // step} points, "
          f"{size / 2**20:.0f} MiB, written in {time.time() - t0:.1f} s ({bag})")

    cmd = ["/usr/bin/time", "-v", a.epd_bin, "estimate", str(bag), "--topic",
           "/helios/points", "--format", "csv", "-o", "/dev/null", "-q",
           "--threads", str(a.threads)]
    print("$", " ".join(cmd))
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", p.stderr)
    h, m, s = wall.groups()
    secs = int(h or 0) * 3600 + int(m) * 60 + float(s)
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr).group(1))
    print(f"exit {p.returncode}; wall {secs:.1f} s: {a.messages / secs:.1f} messages/s; "
          f"peak RSS {rss / 1024:.0f} MiB ({rss * 1024 / size:.3f} of the bag's size)")
    return 0 if p.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
