//! Points and independent writers of PCD and XYZ for the reader tests; epd-cli's and
//! tof-sim's tests include this file too, so it uses nothing of epd-io (nor of any
//! simulator).
#![allow(dead_code)]

/// A round pipe of radius 0.25 m seen from its axis by a pinhole camera of 64 × 48
/// pixels over 69° × 51°, looking along the axis: the first `n` pixels' wall points
/// (SCS, m: X forward, Y right, Z up) and their pixels (u, v), computed here in closed
/// form (the ray t·d meets y² + z² = R² at t = R/√(d_y² + d_z²)), independently of any
/// simulator; at most 64 × 48 points.
pub fn wall_points(n: usize) -> (Vec<[f64; 3]>, Vec<[u32; 2]>) {
    const R: f64 = 0.25;
    let (w, h) = (64u32, 48u32);
    let fx = (w as f64 / 2.0) / (69f64.to_radians() / 2.0).tan();
    let fy = (h as f64 / 2.0) / (51f64.to_radians() / 2.0).tan();
    let mut points = Vec::new();
    let mut pixels = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let d = [
                1.0,
                (u as f64 + 0.5 - w as f64 / 2.0) / fx,
                -(v as f64 + 0.5 - h as f64 / 2.0) / fy,
            ];
            let t = R / (d[1] * d[1] + d[2] * d[2]).sqrt();
            points.push([t * d[0], t * d[1], t * d[2]]);
            pixels.push([u, v]);
        }
    }
    points.truncate(n);
    pixels.truncate(n);
    (points, pixels)
}

/// A PCD file of `points` plus an `intensity` field.
/// `data`: ascii, binary or binary_compressed (LZF with literal runs only, which is valid LZF).
pub fn pcd(points: &[[f64; 3]], data: &str) -> Vec<u8> {
    let n = points.len();
    let mut out = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 4\nTYPE F F F F\n\
         COUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    .into_bytes();
    let intensity = |i: usize| (i % 100) as f32;
    match data {
        "ascii" => {
            for (i, p) in points.iter().enumerate() {
                out.extend(format!("{} {} {} {}\n", p[0], p[1], p[2], intensity(i)).bytes());
            }
        }
        "binary" => {
            for (i, p) in points.iter().enumerate() {
                for c in p {
                    out.extend(c.to_le_bytes());
                }
                out.extend(intensity(i).to_le_bytes());
            }
        }
        _ => {
            // Field-major raw data, then LZF literal runs of ≤ 32 bytes.
            let mut raw = Vec::new();
            for k in 0..3 {
                for p in points {
                    raw.extend(p[k].to_le_bytes());
                }
            }
            for i in 0..n {
                raw.extend(intensity(i).to_le_bytes());
            }
            let mut comp = Vec::new();
            for chunk in raw.chunks(32) {
                comp.push((chunk.len() - 1) as u8);
                comp.extend_from_slice(chunk);
            }
            out.extend((comp.len() as u32).to_le_bytes());
            out.extend((raw.len() as u32).to_le_bytes());
            out.extend(comp);
        }
    }
    out
}

/// Whitespace-separated XYZ text, no header.
pub fn xyz(points: &[[f64; 3]]) -> Vec<u8> {
    let mut s = String::new();
    for p in points {
        s.push_str(&format!("{}\t{} {}\n", p[0], p[1], p[2]));
    }
    s.into_bytes()
}

#[path = "temp_dir.rs"]
mod temp;
#[allow(unused_imports)]
pub use temp::{TempDir, temp_dir};
