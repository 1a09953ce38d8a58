//! Depth calibration across pipe sizes on frames this test writes itself, with an error
//! model that is not tof-sim's: a checker outside the project writes its own rig and
//! test frames (binary PLY, `x y z` in metres, float `intensity`), so a table must not
//! work only on the simulator it was developed with.
//!
//! The caster: a round straight pipe, the sensor off the axis by up to 25 mm and tilted
//! by up to 2°, a 69° × 51° pinhole camera of 200 × 150 pixels. Its camera differs from
//! tof-sim's Helios2 in every term: intensity I = 700·cos^0.6 θ / r² (not Lambertian),
//! a systematic error 5 mm·sin(2πr/1.1 m + 0.7) (another period and phase) + 12 mm·(1 −
//! cos θ) (an incidence law: grazing returns read long) + 3 mm/m·r (a scale error), no
//! multipath, and Gaussian range noise σ = 2 mm + 4 mm/m²·r²; pixels darker than I = 3
//! are invalid (zeros).

use std::path::{Path, PathBuf};
use std::process::Command;

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

/// SplitMix64: a small generator, so the frames do not depend on any crate's streams.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn uniform(&mut self, a: f64) -> f64 {
        a * (2.0 * self.next() - 1.0)
    }

    fn normal(&mut self) -> f64 {
        let u = self.next().max(1e-300);
        let v = self.next();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// One frame of the caster in a pipe of inner diameter `id_m`, written to `path`.
fn write_frame(path: &Path, id_m: f64, rng: &mut Rng) {
    let r_pipe = id_m / 2.0;
    let (dy, dz) = (rng.uniform(0.025), rng.uniform(0.025));
    let (pitch, yaw) = (
        rng.uniform(2f64.to_radians()),
        rng.uniform(2f64.to_radians()),
    );
    let (w, h) = (200usize, 150usize);
    let (tx, ty) = (
        (69f64.to_radians() / 2.0).tan(),
        (51f64.to_radians() / 2.0).tan(),
    );
    let mut body = Vec::with_capacity(w * h * 16);
    for row in 0..h {
        for col in 0..w {
            let u = tx * (2.0 * (col as f64 + 0.5) / w as f64 - 1.0);
            let v = ty * (1.0 - 2.0 * (row as f64 + 0.5) / h as f64);
            let n = (1.0 + u * u + v * v).sqrt();
            let d = [1.0 / n, u / n, v / n];
            // SCS → PCS: pitch about Y, then yaw about Z.
            let (sp, cp) = pitch.sin_cos();
            let (sy, cy) = yaw.sin_cos();
            let a = [d[0] * cp + d[2] * sp, d[1], -d[0] * sp + d[2] * cp];
            let e = [a[0] * cy - a[1] * sy, a[0] * sy + a[1] * cy, a[2]];
            // (dy + t·e1)² + (dz + t·e2)² = R².
            let qa = e[1] * e[1] + e[2] * e[2];
            let qb = dy * e[1] + dz * e[2];
            let qc = dy * dy + dz * dz - r_pipe * r_pipe;
            let mut out = [0f32; 4];
            if qa > 1e-12 {
                let t = (-qb + (qb * qb - qa * qc).sqrt()) / qa;
                let (wy, wz) = (dy + t * e[1], dz + t * e[2]);
                let cos = ((e[1] * wy + e[2] * wz) / r_pipe).abs();
                let intensity = 700.0 * cos.powf(0.6) / (t * t);
                if intensity >= 3.0 && t < 4.0 {
                    let sys = 0.005 * (std::f64::consts::TAU * t / 1.1 + 0.7).sin()
                        + 0.012 * (1.0 - cos)
                        + 0.003 * t;
                    let sigma = 0.002 + 0.004 * t * t;
                    let m = t + sys + sigma * rng.normal();
                    out = [
                        (d[0] * m) as f32,
                        (d[1] * m) as f32,
                        (d[2] * m) as f32,
                        intensity as f32,
                    ];
                }
            }
            for v in out {
                body.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    let header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
         property float y\nproperty float z\nproperty float intensity\nend_header\n",
        w * h
    );
    let mut bytes = header.into_bytes();
    bytes.extend_from_slice(&body);
    std::fs::write(path, bytes).unwrap();
}

fn frames(dir: &Path, name: &str, id_mm: f64, n: usize, seed: u64) -> Vec<PathBuf> {
    let mut rng = Rng(seed);
    std::fs::create_dir_all(dir.join(name)).unwrap();
    (0..n)
        .map(|k| {
            let p = dir.join(name).join(format!("f{k}.ply"));
            write_frame(&p, id_mm * 1e-3, &mut rng);
            p
        })
        .collect()
}

/// Per frame: (status, mean-diameter error mm, whether the 1-σ of both diameters
/// covers their errors, calibration_outside, status_reason).
fn estimate(files: &[PathBuf], lut: &Path, id_mm: f64) -> Vec<(String, f64, bool, f64, String)> {
    let o = epd()
        .arg("estimate")
        .args(files)
        .args(["--straight-only", "--format", "json", "-q", "--calibration"])
        .arg(lut)
        .output()
        .unwrap();
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| {
            let d: serde_json::Value = serde_json::from_str(l).unwrap();
            let status = d["status"].as_str().unwrap_or("").to_string();
            let reason = d["status_reason"]
                .as_str()
                .or(d["error"].as_str())
                .unwrap_or("")
                .to_string();
            let out = d["calibration_outside"].as_f64().unwrap_or(f64::NAN);
            match (d["d_max_mm"].as_f64(), d["d_min_mm"].as_f64()) {
                (Some(a), Some(b)) => {
                    let (sa, sb) = (
                        d["sigma_d_max_mm"].as_f64().unwrap_or(0.0),
                        d["sigma_d_min_mm"].as_f64().unwrap_or(0.0),
                    );
                    let covered = (a - id_mm).abs() <= sa && (b - id_mm).abs() <= sb;
                    (status, 0.5 * (a + b) - id_mm, covered, out, reason)
                }
                _ => (status, f64::NAN, false, out, reason),
            }
        })
        .collect()
}

fn calibrate(args: &[&std::ffi::OsStr]) {
    let o = epd()
        .arg("calibrate")
        .args(args)
        .arg("-q")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Rigs of 20" and 30" (ID 484 and 738 mm) with `--rigs`, and a 20" rig alone, applied
/// to 24" and 30" frames of the caster: the two-size table's 24" bias, and the one-size
/// table's 1-σ over a size it never saw (or a withheld result, with the reason).
#[test]
fn tables_transfer_across_sizes_on_frames_of_another_error_model() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let rig20 = frames(d, "rig20", 484.0, 4, 1);
    let rig30 = frames(d, "rig30", 738.0, 4, 2);
    let t24 = frames(d, "t24", 585.6, 15, 3);
    let t30 = frames(d, "t30", 738.0, 3, 4);
    let list = |v: &[PathBuf]| {
        v.iter()
            .map(|p| format!("{:?}", p.strip_prefix(d).unwrap().to_str().unwrap()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let toml = format!(
        "[[rig]]\nknown_id_mm = 484\nfiles = [{}]\n\n[[rig]]\nknown_id_mm = 738\nfiles = [{}]\n",
        list(&rig20),
        list(&rig30)
    );
    std::fs::write(d.join("rigs.toml"), toml).unwrap();
    let (lut2, lut1) = (d.join("lut2.json"), d.join("lut1.json"));
    calibrate(&[
        "--rigs".as_ref(),
        d.join("rigs.toml").as_os_str(),
        "--out".as_ref(),
        lut2.as_os_str(),
    ]);
    let mut one: Vec<&std::ffi::OsStr> = rig20.iter().map(|p| p.as_os_str()).collect();
    let os = |s: &'static str| -> &'static std::ffi::OsStr { s.as_ref() };
    one.extend([os("--known-id-mm"), os("484"), os("--out")]);
    one.push(lut1.as_os_str());
    calibrate(&one);
    // The two-size table records both rigs.
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lut2).unwrap()).unwrap();
    assert_eq!(t["version"], 2);
    assert_eq!(t["rigs"].as_array().map(|r| r.len()), Some(2));
    assert!(t["incidence"]["support"].is_array());

    let two_24 = estimate(&t24, &lut2, 585.6);
    let one_24 = estimate(&t24, &lut1, 585.6);
    let one_30 = estimate(&t30, &lut1, 738.0);
    eprintln!("20\"+30\" → 24\": {two_24:?}\n20\" → 24\": {one_24:?}\n20\" → 30\": {one_30:?}");
    let mean = |v: &[(String, f64, bool, f64, String)]| {
        v.iter().map(|r| r.1).sum::<f64>() / v.len() as f64
    };
    assert!(two_24.iter().all(|r| r.0 == "converged"), "{two_24:?}");
    // The issue's goal: |bias| < 0.3 mm with rigs of 20" and 30" on 24" frames of an
    // error model the table was not written for. The 15 frames' errors spread by about
    // 0.025 mm (docs/calibration.md: mean −0.203 mm), so their mean has a standard
    // error of about 0.006 mm against the goal's margin of 0.1 mm.
    assert!(mean(&two_24).abs() < 0.3, "20\"+30\" → 24\": {two_24:?}");
    // A size the one rig never saw: every frame is answered, its 1-σ covers its error,
    // and its status_reason says the pipe lies outside the rig's sizes, or that the
    // frame lies too far outside the table's support to be corrected.
    for r in one_24.iter().chain(&one_30) {
        assert!(r.2, "{r:?}");
        assert!(
            r.4.contains("outside the depth table's rig sizes")
                || r.4.contains("the frame is not corrected"),
            "{r:?}"
        );
    }
}

/// A RIGS.toml that cannot be used is a usage error (exit 2) naming the rig and the key;
/// --rigs with FILE… or --known-id-mm is refused by the parser (exit 2 too).
#[test]
fn a_bad_rigs_file_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (text, says) in [
        (
            "[[rig]]\nknown_id_mm = 0\nfiles = [\"a.ply\"]\n",
            "rig 1: known_id_mm = 0",
        ),
        ("[[rig]]\nfiles = [\"a.ply\"]\n", "known_id_mm"),
        ("rigs = 3\n", "not a rigs file"),
    ] {
        let p = d.join("rigs.toml");
        std::fs::write(&p, text).unwrap();
        let o = epd()
            .args(["calibrate", "--rigs"])
            .arg(&p)
            .args(["--out"])
            .arg(d.join("lut.json"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{text:?}: {err}");
        assert!(err.contains(says), "{text:?}: {err}");
        assert!(!d.join("lut.json").exists());
    }
    let o = epd()
        .args(["calibrate", "x.ply", "--rigs", "r.toml", "--out", "l.json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let o = epd()
        .args(["calibrate", "--rigs"])
        .arg(d.join("missing.toml"))
        .args(["--out", "l.json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot read"));
}
