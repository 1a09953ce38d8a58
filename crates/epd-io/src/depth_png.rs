//! A frame's depth image, drawn with plotters as the harness's figures are: each pixel
//! coloured by its measured range ‖x‖ (SCS, m) on the viridis map (near dark violet, far
//! yellow; no return or an invalid pixel, stored as zeros, black), with a colour bar in
//! metres on the right — the paper's Fig. 10.

use std::io::Write;
use std::path::Path;

use plotters::prelude::*;

use crate::WriteError;
use crate::cloud::SensorCloud;
use crate::font::{FONT, register_font};

/// Width of the colour bar and its labels (px).
const BAR_WIDTH: u32 = 110;
/// Smallest image height, so that the bar keeps room for its labels (px).
const MIN_HEIGHT: u32 = 160;

fn draw_err(e: impl std::fmt::Display) -> WriteError {
    WriteError::Draw {
        what: "the depth image".into(),
        message: e.to_string(),
    }
}

/// The RGB pixels (row-major, 3 bytes a pixel) and the size of `frame`'s depth image;
/// ranges above `max_range` (m) take the top colour.
pub fn render(
    frame: &SensorCloud<'_>,
    max_range: f64,
) -> Result<(Vec<u8>, (u32, u32)), WriteError> {
    register_font().map_err(draw_err)?;
    let [iw, ih] = frame.image_size;
    let size = (iw + BAR_WIDTH, ih.max(MIN_HEIGHT));
    let mut buf = vec![0u8; 3 * size.0 as usize * size.1 as usize];
    let top = if max_range > 0.0 { max_range } else { 1.0 };
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&BLACK).map_err(draw_err)?;
        let (image, bar) = root.split_horizontally(iw);
        for (p, px) in frame.points.iter().zip(frame.pixels) {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if r == 0.0 || !r.is_finite() {
                continue; // an invalid pixel, written as zeros
            }
            let c = ViridisRGB.get_color_normalized(r.min(top), 0.0, top);
            image
                .draw_pixel((px[0] as i32, px[1] as i32), &c)
                .map_err(draw_err)?;
        }
        let white = TextStyle::from((FONT, 14).into_font()).color(&WHITE);
        let mut chart = ChartBuilder::on(&bar)
            .margin(10)
            .set_label_area_size(LabelAreaPosition::Right, 70)
            .build_cartesian_2d(0.0..1.0, 0.0..top)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_labels(5)
            .y_label_formatter(&|v| format!("{v:.1}"))
            .y_label_style(white.clone())
            .y_desc("range (m)")
            .axis_desc_style(white)
            .axis_style(WHITE)
            .draw()
            .map_err(draw_err)?;
        const BANDS: usize = 256;
        chart
            .draw_series((0..BANDS).map(|k| {
                let (lo, hi) = (k as f64 / BANDS as f64, (k + 1) as f64 / BANDS as f64);
                let c = ViridisRGB.get_color_normalized(lo + 0.5 / BANDS as f64, 0.0, 1.0);
                Rectangle::new([(0.0, lo * top), (1.0, hi * top)], c.filled())
            }))
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok((buf, size))
}

/// RGB pixels as a PNG (8 bits a channel).
pub fn encode_rgb<W: Write>(w: W, rgb: &[u8], size: (u32, u32)) -> Result<(), WriteError> {
    let io = |e: png::EncodingError| WriteError::io("a PNG image", std::io::Error::other(e));
    let mut enc = png::Encoder::new(w, size.0, size.1);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(io)?;
    writer.write_image_data(rgb).map_err(io)?;
    writer.finish().map_err(io)
}

/// `frame`'s depth image (see [`render`]) as a PNG.
pub fn write<W: Write>(w: W, frame: &SensorCloud<'_>, max_range: f64) -> Result<(), WriteError> {
    let (rgb, size) = render(frame, max_range)?;
    encode_rgb(w, &rgb, size)
}

/// [`write()`] into a file, written whole ([`crate::atomic::write_file_atomic`]).
pub fn save(path: &Path, frame: &SensorCloud<'_>, max_range: f64) -> Result<(), WriteError> {
    let mut png = Vec::new();
    write(&mut png, frame, max_range)?;
    crate::atomic::write_bytes_atomic(path, &png)
}
