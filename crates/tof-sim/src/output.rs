//! Writing frames: PLY (ASCII or binary little-endian), CSV, and a depth-image PNG with
//! a colour scale bar (its digits drawn from a built-in bitmap font: no system fonts).

use std::io::Write;
use std::path::Path;

use crate::error::SimError;
use crate::frame::Frame;
use crate::pipeline::PartKind;

/// PLY encodings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyFormat {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
}

/// Scalar type of the coordinates in a PLY file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyPrecision {
    /// `float` (32-bit).
    F32,
    /// `double` (64-bit).
    F64,
}

/// Write `frame`'s measured points (SCS, m) with their pixel (u, v) as PLY, plus a
/// `property float intensity` (camera counts) after v when the frame has any finite
/// intensity (the physical sensor model; the plain model's intensities are NaN and are
/// not written). Invalid pixels are written as they are held: x = y = z = 0, intensity 0.
///
/// A frame with labels ([`Frame::part`], a pipeline scene) gets two more properties at
/// the end, `property ushort segment` (the index in `Pipeline::segments`) and
/// `property uchar part` (the [`part_code`]: 0 no wall, 1 straight, 2 bend, 3 branch),
/// described in a header comment. Frames without labels are written as before.
pub fn write_ply<W: Write>(
    w: &mut W,
    frame: &Frame,
    format: PlyFormat,
    precision: PlyPrecision,
) -> std::io::Result<()> {
    let fmt = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
    };
    let ty = match precision {
        PlyPrecision::F32 => "float",
        PlyPrecision::F64 => "double",
    };
    let t = &frame.truth;
    let with_intensity = frame.intensity.len() == frame.measured.len()
        && frame.intensity.iter().any(|i| i.is_finite());
    let with_part = !frame.part.is_empty() && frame.part.len() == frame.measured.len();
    write!(
        w,
        "ply\nformat {fmt} 1.0\ncomment tof-sim frame: measured points in the sensor frame (m; X forward, Y right, Z up)\n\
         comment truth d_max_m {} d_min_m {} roll_rad {} pitch_rad {} yaw_rad {} dy_m {} dz_m {}\n\
         {}element vertex {}\nproperty {ty} x\nproperty {ty} y\nproperty {ty} z\nproperty uint u\nproperty uint v\n{}{}end_header\n",
        t.d_max,
        t.d_min,
        t.roll,
        t.pitch,
        t.yaw,
        t.dy,
        t.dz,
        if with_part {
            "comment part: what the pixel's ray hit, 0 no wall, 1 straight, 2 bend, 3 branch; segment: its index in the pipeline\n"
        } else {
            ""
        },
        frame.measured.len(),
        if with_intensity {
            "property float intensity\n"
        } else {
            ""
        },
        if with_part {
            "property ushort segment\nproperty uchar part\n"
        } else {
            ""
        }
    )?;
    for (i, (p, px)) in frame.measured.iter().zip(&frame.pixels).enumerate() {
        match (format, precision) {
            (PlyFormat::Ascii, PlyPrecision::F64) => {
                write!(w, "{} {} {} {} {}", p[0], p[1], p[2], px[0], px[1])?
            }
            (PlyFormat::Ascii, PlyPrecision::F32) => write!(
                w,
                "{} {} {} {} {}",
                p[0] as f32, p[1] as f32, p[2] as f32, px[0], px[1]
            )?,
            (PlyFormat::BinaryLittleEndian, prec) => {
                for c in p {
                    match prec {
                        PlyPrecision::F64 => w.write_all(&c.to_le_bytes())?,
                        PlyPrecision::F32 => w.write_all(&(*c as f32).to_le_bytes())?,
                    }
                }
                w.write_all(&px[0].to_le_bytes())?;
                w.write_all(&px[1].to_le_bytes())?;
            }
        }
        match format {
            PlyFormat::Ascii if with_intensity => write!(w, " {}", frame.intensity[i])?,
            PlyFormat::Ascii => {}
            PlyFormat::BinaryLittleEndian if with_intensity => {
                w.write_all(&frame.intensity[i].to_le_bytes())?
            }
            PlyFormat::BinaryLittleEndian => {}
        }
        if with_part {
            let (segment, code) = frame.part[i].map_or((0, 0), |p| (p.segment, part_code(p.kind)));
            match format {
                PlyFormat::Ascii => write!(w, " {segment} {code}")?,
                PlyFormat::BinaryLittleEndian => {
                    w.write_all(&segment.to_le_bytes())?;
                    w.write_all(&[code])?;
                }
            }
        }
        if format == PlyFormat::Ascii {
            writeln!(w)?;
        }
    }
    Ok(())
}

/// The PLY code of a part kind: 1 straight, 2 bend, 3 branch (0 is "no wall").
pub fn part_code(kind: PartKind) -> u8 {
    match kind {
        PartKind::Straight => 1,
        PartKind::Bend => 2,
        PartKind::Branch => 3,
    }
}

/// Write `frame`'s measured points as CSV: a header `x,y,z`, then one point per line (m, SCS).
pub fn write_csv<W: Write>(w: &mut W, frame: &Frame) -> std::io::Result<()> {
    writeln!(w, "x,y,z")?;
    for p in &frame.measured {
        writeln!(w, "{},{},{}", p[0], p[1], p[2])?;
    }
    Ok(())
}

/// Write a file whole: into a temporary file beside it, then renamed over it.
pub fn write_file_atomic(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<(), SimError> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // An exclusively created temporary file with an unpredictable name (never a planted
    // link), renamed over `path` once written and synced; removed on any error.
    let run = || -> std::io::Result<()> {
        let mut builder = tempfile::Builder::new();
        builder.prefix(".tof-sim-");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            builder.permissions(std::fs::Permissions::from_mode(0o644));
        }
        let tmp = builder.tempfile_in(dir)?;
        let mut f = std::io::BufWriter::new(tmp.reopen()?);
        write(&mut f)?;
        f.flush()?;
        f.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        tmp.persist(path).map_err(|e| e.error)?;
        Ok(())
    };
    run().map_err(|e| SimError::io(path.display().to_string(), e))
}

/// A jet-like colour map: dark blue (0) → cyan → yellow → dark red (1).
pub fn colormap(x: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 6] = [
        [0.0, 0.0, 0.5],
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 1.0],
        [1.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.5, 0.0, 0.0],
    ];
    let x = x.clamp(0.0, 1.0) * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let mut c = [0u8; 3];
    for k in 0..3 {
        c[k] = ((STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f) * 255.0).round() as u8;
    }
    c
}

/// A 3×5 bitmap font for the scale bar: rows top to bottom, 3 bits each (MSB left).
fn glyph(ch: char) -> Option<[u8; 5]> {
    Some(match ch {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        'm' => [0, 0, 7, 7, 5],
        ' ' => [0, 0, 0, 0, 0],
        _ => return None,
    })
}

/// An RGB canvas.
struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn set(&mut self, x: usize, y: usize, c: [u8; 3]) {
        if x < self.w && y < self.h {
            let i = 3 * (y * self.w + x);
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }

    fn text(&mut self, x: usize, y: usize, s: &str, scale: usize, c: [u8; 3]) {
        for (n, ch) in s.chars().enumerate() {
            let Some(g) = glyph(ch) else { continue };
            for (row, bits) in g.iter().enumerate() {
                for col in 0..3 {
                    if bits & (4 >> col) != 0 {
                        for dy in 0..scale {
                            for dx in 0..scale {
                                self.set(x + (n * 4 + col) * scale + dx, y + row * scale + dy, c);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Render the measured ranges of `frame` as a depth image (near = blue, far = red,
/// no return or invalid pixel = black) with a vertical colour scale bar labelled in metres on the right,
/// as the paper's Fig. 10. `max_range` sets the top of the scale.
pub fn depth_png<W: Write>(w: W, frame: &Frame, max_range: f64) -> Result<(), SimError> {
    let [iw, ih] = frame.image_size.map(|v| v as usize);
    let bar = 90;
    let mut c = Canvas {
        w: iw + bar,
        h: ih.max(120),
        px: vec![0; 3 * (iw + bar) * ih.max(120)],
    };
    for (p, px) in frame.measured.iter().zip(&frame.pixels) {
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        if r == 0.0 {
            continue; // an invalid pixel, written as zeros
        }
        c.set(px[0] as usize, px[1] as usize, colormap(r / max_range));
    }
    // The scale bar: 16 px wide, from max_range (top) to 0 (bottom), with 5 labels.
    let (top, bottom) = (10usize, c.h - 10);
    let x0 = iw + 10;
    for y in top..bottom {
        let f = 1.0 - (y - top) as f64 / (bottom - top - 1) as f64;
        for x in x0..x0 + 16 {
            c.set(x, y, colormap(f));
        }
    }
    let white = [255, 255, 255];
    for k in 0..=4 {
        let f = k as f64 / 4.0;
        let y = bottom - 1 - (f * (bottom - top - 1) as f64) as usize;
        for x in x0 + 16..x0 + 22 {
            c.set(x, y, white);
        }
        let label = format!("{:.1} m", f * max_range);
        c.text(x0 + 24, y.saturating_sub(5), &label, 2, white);
    }
    let mut enc = png::Encoder::new(w, c.w as u32, c.h as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let io = |e: png::EncodingError| SimError::io("depth PNG", std::io::Error::other(e));
    let mut writer = enc.write_header().map_err(io)?;
    writer.write_image_data(&c.px).map_err(io)?;
    writer.finish().map_err(io)
}

/// [`write_ply`] into a file, written whole.
pub fn save_ply(
    path: &Path,
    frame: &Frame,
    format: PlyFormat,
    precision: PlyPrecision,
) -> Result<(), SimError> {
    write_file_atomic(path, |w| write_ply(w, frame, format, precision))
}

/// [`depth_png`] into a file, written whole.
pub fn save_depth_png(path: &Path, frame: &Frame, max_range: f64) -> Result<(), SimError> {
    write_file_atomic(path, |w| {
        depth_png(w, frame, max_range).map_err(|e| std::io::Error::other(e.to_string()))
    })
}
