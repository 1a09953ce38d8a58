//! `epd estimate BAG` and `epd topics BAG` on MCAP files written by the `mcap` crate's own
//! writer (the Python tests use `rosbags`, a writer of another project): one result per
//! PointCloud2 message of the topic, the same estimate as the same points in a file,
//! the frame from `frame_id`, the topic chosen or asked for, `--frame flu`.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

/// A little-endian CDR PointCloud2 of `points` as FLOAT64 x, y, z (24-byte points).
fn cloud_cdr(points: &[[f64; 3]], sec: i32, frame_id: &str) -> Vec<u8> {
    let mut b = vec![0u8, 1, 0, 0];
    let align = |b: &mut Vec<u8>| {
        while !(b.len() - 4).is_multiple_of(4) {
            b.push(0);
        }
    };
    let u32 = |b: &mut Vec<u8>, v: u32| {
        align(b);
        b.extend_from_slice(&v.to_le_bytes());
    };
    let string = |b: &mut Vec<u8>, s: &str| {
        u32(b, s.len() as u32 + 1);
        b.extend_from_slice(s.as_bytes());
        b.push(0);
    };
    u32(&mut b, sec as u32);
    u32(&mut b, 7);
    string(&mut b, frame_id);
    u32(&mut b, 1);
    u32(&mut b, points.len() as u32);
    u32(&mut b, 3);
    for (i, name) in ["x", "y", "z"].iter().enumerate() {
        string(&mut b, name);
        u32(&mut b, 8 * i as u32);
        b.push(8);
        u32(&mut b, 1);
    }
    b.push(0);
    u32(&mut b, 24);
    u32(&mut b, 24 * points.len() as u32);
    u32(&mut b, 24 * points.len() as u32);
    b.extend(points.iter().flatten().flat_map(|v| v.to_le_bytes()));
    b.push(1);
    b
}

/// An MCAP file of `clouds` on `/cam/points` (each: points, stamp sec, frame_id), a
/// message on `/imu` between each, and `extra` more PointCloud2 topics.
fn write_bag(path: &Path, clouds: &[(Vec<[f64; 3]>, i32, &str)], extra: &[&str]) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::Writer::new(f).unwrap();
    let s = w
        .add_schema("sensor_msgs/msg/PointCloud2", "ros2msg", b"")
        .unwrap();
    let imu_s = w.add_schema("sensor_msgs/msg/Imu", "ros2msg", b"").unwrap();
    let none = BTreeMap::new();
    let cam = w.add_channel(s, "/cam/points", "cdr", &none).unwrap();
    let imu = w.add_channel(imu_s, "/imu", "cdr", &none).unwrap();
    for t in extra {
        w.add_channel(s, t, "cdr", &none).unwrap();
    }
    for (k, (pts, sec, frame)) in clouds.iter().enumerate() {
        for (ch, data) in [
            (imu, vec![0u8, 1, 0, 0]),
            (cam, cloud_cdr(pts, *sec, frame)),
        ] {
            let h = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: k as u32,
                log_time: k as u64,
                publish_time: k as u64,
            };
            w.write_to_known_channel(&h, &data).unwrap();
        }
    }
    w.finish().unwrap();
}

fn json_lines(out: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// The points of a frame in a camera's optical frame.
fn optical(p: &[[f64; 3]]) -> Vec<[f64; 3]> {
    p.iter().map(|&[x, y, z]| [y, -z, x]).collect()
}

fn csv(dir: &Path, name: &str, pts: &[[f64; 3]]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, common::xyz(pts)).unwrap();
    p
}

/// Each message's estimate equals that of its points as a file (to 1e-6 mm and degrees),
/// in order, with its stamp and frame id; `*_optical_frame` read as the optical frame.
#[test]
fn a_bag_gives_the_estimates_of_its_points() {
    let dir = common::temp_dir("bag-estimates");
    let frames: Vec<Vec<[f64; 3]>> = (0..3).map(|k| common::frame(k, 3000).measured).collect();
    let bag = dir.as_path().join("run.mcap");
    let clouds: Vec<(Vec<[f64; 3]>, i32, &str)> = frames
        .iter()
        .enumerate()
        .map(|(k, p)| (optical(p), 100 + k as i32, "cam_optical_frame"))
        .collect();
    write_bag(&bag, &clouds, &[]);
    let out = epd()
        .args(["estimate", "--format", "json", "-q"])
        .arg(&bag)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{:?}: {}{}",
        out.status,
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    let rows = json_lines(&out.stdout);
    assert_eq!(rows.len(), 3);
    let files: Vec<PathBuf> = frames
        .iter()
        .enumerate()
        .map(|(k, p)| csv(dir.as_path(), &format!("f{k}.csv"), p))
        .collect();
    let out = epd()
        .args(["estimate", "--format", "json", "-q"])
        .args(&files)
        .output()
        .unwrap();
    let want = json_lines(&out.stdout);
    for (k, (r, w)) in rows.iter().zip(&want).enumerate() {
        assert_eq!(r["stamp_ns"], (100 + k as i64) * 1_000_000_000 + 7);
        assert_eq!(r["frame_id"], "cam_optical_frame");
        assert!(w["stamp_ns"].is_null() && w["frame_id"].is_null());
        assert_eq!(r["status"], "converged");
        for key in common::PARAM_KEYS {
            let (a, b) = (r[key].as_f64().unwrap(), w[key].as_f64().unwrap());
            assert!((a - b).abs() <= 1e-6, "{k} {key}: {a} vs {b}");
        }
    }
    // `epd topics`: every topic with its type and count.
    let out = epd().arg("topics").arg(&bag).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    assert!(
        text.contains("/cam/points  sensor_msgs/msg/PointCloud2         3"),
        "{text}"
    );
    assert!(
        text.contains("/imu         sensor_msgs/msg/Imu                 3"),
        "{text}"
    );
}

/// Several PointCloud2 topics and no --topic, a --topic of another type, a --topic for
/// files only: usage errors (exit 2) naming what to choose.
#[test]
fn the_topic_is_chosen_or_asked_for() {
    let dir = common::temp_dir("bag-topic");
    let pts = common::frame(1, 2000).measured;
    let bag = dir.as_path().join("two.mcap");
    write_bag(&bag, &[(pts.clone(), 1, "base_link")], &["/lidar/points"]);
    let run = |args: &[&str]| {
        let out = epd().args(args).output().unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let b = bag.to_str().unwrap();
    let (code, err) = run(&["estimate", "-q", b]);
    assert_eq!(code, Some(2));
    assert!(
        err.contains("2 PointCloud2 topics: /cam/points, /lidar/points; choose one with --topic"),
        "{err}"
    );
    let (code, err) = run(&["estimate", "-q", b, "--topic", "/imu"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("sensor_msgs/msg/Imu"), "{err}");
    let (code, _) = run(&["estimate", "-q", b, "--topic", "/cam/points"]);
    assert_eq!(code, Some(0));
    let f = csv(dir.as_path(), "f.csv", &pts);
    let (code, err) = run(&[
        "estimate",
        "-q",
        f.to_str().unwrap(),
        "--topic",
        "/cam/points",
    ]);
    assert_eq!(code, Some(2));
    assert!(err.contains("no input is one"), "{err}");
}

/// A topic that holds no message is a failure that says so, in `estimate` and `profile`
/// (they had exited 0 with nothing written and nothing said); a bag cut short is named
/// as such.
#[test]
fn an_empty_topic_is_a_failure_that_says_so() {
    let dir = common::temp_dir("bag-empty-topic");
    let pts = common::frame(1, 2000).measured;
    let bag = dir.as_path().join("two.mcap");
    write_bag(&bag, &[(pts, 1, "base_link")], &["/lidar/points"]);
    let out = epd()
        .arg("estimate")
        .arg(&bag)
        .args(["--topic", "/lidar/points"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("topic `/lidar/points` holds no message"),
        "{err}"
    );
    let out = epd()
        .arg("profile")
        .arg(&bag)
        .args(["--topic", "/lidar/points", "--out"])
        .arg(dir.as_path().join("profile"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("no frame to profile"), "{err}");
    // A bag cut before its first chunk ends: the damage is named (exit 1), not a usage
    // error saying the bag has no point-cloud topic (exit 2).
    let bytes = std::fs::read(&bag).unwrap();
    let cut = dir.as_path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let out = epd().arg("estimate").arg(&cut).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("truncated"), "{err}");
}

/// `--frame flu` is `--frame body`: a cloud in the ROS body frame gives the pose of the
/// same cloud in the sensor frame; read as the sensor frame, yaw and δy change sign.
#[test]
fn frame_flu_is_the_body_frame() {
    let dir = common::temp_dir("bag-flu");
    let pts = common::frame(3, 3000).measured;
    let flu: Vec<[f64; 3]> = pts.iter().map(|&[x, y, z]| [x, -y, z]).collect();
    let sensor = csv(dir.as_path(), "s.csv", &pts);
    let body = csv(dir.as_path(), "b.csv", &flu);
    let get = |f: &Path, frame: &str| {
        let out = epd()
            .args(["estimate", "--format", "json", "-q", "--frame", frame])
            .arg(f)
            .output()
            .unwrap();
        json_lines(&out.stdout).remove(0)
    };
    let want = get(&sensor, "sensor");
    for name in ["flu", "body", "ros-body"] {
        let got = get(&body, name);
        for key in ["d_max_mm", "yaw_deg", "dy_mm"] {
            assert_eq!(got[key], want[key], "{name} {key}");
        }
    }
    let mirrored = get(&body, "sensor");
    let yaw = mirrored["yaw_deg"].as_f64().unwrap();
    assert!((yaw + want["yaw_deg"].as_f64().unwrap()).abs() < 1e-6);
}
