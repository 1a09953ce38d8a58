//! A Helios2 frame in a 20" pipe ahead of a 90° long-radius elbow turning right, written
//! as a labelled PLY, and the share of each part of the pipeline among the valid points
//! as the sensor approaches the bend.
//!
//! ```text
//! cargo run --release -p tof-sim --example bend_demo -- [--out /tmp/bend-demo.ply] [--bend-at 1.0]
//! ```
//! The pipe is the paper's (20", 12 mm wall, 2 % ovality: Dmax 488.8 mm, Dmin 479.2 mm);
//! the elbow's centreline radius is 1.5 × 20" = 762 mm and its tube diameter the mean
//! inner diameter; the sensor sits on the axis with zero roll, pitch and yaw, so "right"
//! is +Y in both frames. The PLY (binary, float coordinates, with `intensity`, `segment`
//! and `part`) is the frame with the bend `--bend-at` metres ahead under the physical
//! Helios2 model ([`tof_sim::ToFPhysics::helios2`]), invalid pixels included as zeros.
//! Then, for the bend 6, 3, 1 and 0.5 m ahead, the share of points per part: of the valid
//! points of the physical model, and of the noise-free points within the 6 m range.

use std::collections::BTreeMap;
use std::f64::consts::FRAC_PI_2;
use std::path::PathBuf;
use std::time::Instant;

use epd_core::Params;
use epd_io::ply::{PlyFormat, PlyPrecision, save as save_ply};
use tof_sim::{
    FrameSeed, MeshResolution, Noise, Part, Pipe, Pipeline, Scene, Segment, Sensor, Subsample,
    ToFPhysics, simulate,
};

/// The frame in the demo pipe with the bend `bend_at` metres ahead.
fn scene(bend_at: f64) -> anyhow::Result<(Scene, Pipeline)> {
    let pipe = Pipe::paper_20in();
    let p = Pipeline::with_one_bend(
        pipe.d_max(),
        pipe.d_min(),
        -1.0,
        bend_at,
        Segment::Bend {
            radius: 1.5 * 20.0 * tof_sim::pipe::INCH,
            angle: FRAC_PI_2,
            direction: 0.0,
        },
        6.0,
    );
    let truth = Params {
        d_max: p.d_max,
        d_min: p.d_min,
        roll: 0.0,
        pitch: 0.0,
        yaw: 0.0,
        dy: 0.0,
        dz: 0.0,
    };
    Ok((Scene::pipeline(&truth, &p, &MeshResolution::default())?, p))
}

/// "segment 0 straight 81.2 %, …" over the points of `parts` that `keep` accepts.
fn shares(parts: &[Option<Part>], keep: impl Fn(usize) -> bool) -> String {
    let mut n = BTreeMap::new();
    let mut total = 0usize;
    for (i, p) in parts.iter().enumerate() {
        if keep(i) {
            *n.entry(*p).or_insert(0usize) += 1;
            total += 1;
        }
    }
    let list: Vec<String> = n
        .iter()
        .map(|(p, k)| {
            let name = p.map_or("no wall".to_string(), |p| {
                format!("segment {} {:?}", p.segment, p.kind)
            });
            format!("{name} {:.1} %", 100.0 * *k as f64 / total.max(1) as f64)
        })
        .collect();
    format!("{total} points: {}", list.join(", "))
}

fn main() -> anyhow::Result<()> {
    let mut out = PathBuf::from("/tmp/bend-demo.ply");
    let mut bend_at = 1.0;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match (a.as_str(), args.next()) {
            ("--out", Some(v)) => out = PathBuf::from(v),
            ("--bend-at", Some(v)) => bend_at = v.parse()?,
            _ => anyhow::bail!("usage: bend_demo [--out FILE.ply] [--bend-at METRES]"),
        }
    }
    let sensor = Sensor::helios2();
    let physical = Noise {
        physics: Some(ToFPhysics::helios2()),
        ..Noise::range(0.0)
    };
    let t0 = Instant::now();
    let (sc, p) = scene(bend_at)?;
    let build = t0.elapsed();
    let t0 = Instant::now();
    let frame = simulate(
        &sensor,
        &sc,
        &physical,
        Subsample::All,
        FrameSeed::default(),
    )?;
    let cast = t0.elapsed();
    save_ply(
        &out,
        &frame.cloud(),
        PlyFormat::BinaryLittleEndian,
        PlyPrecision::F32,
    )?;
    let triangles = p.mesh(&MeshResolution::default())?.labels.len();
    println!(
        "wrote {} ({} pixels); mesh {triangles} triangles built in {build:.2?}, frame cast in {cast:.2?}",
        out.display(),
        frame.len()
    );
    for d in [6.0, 3.0, 1.0, 0.5] {
        let (sc, p) = scene(d)?;
        let f = simulate(
            &sensor,
            &sc,
            &physical,
            Subsample::All,
            FrameSeed::default(),
        )?;
        let g = simulate(
            &sensor,
            &sc,
            &Noise::none(),
            Subsample::All,
            FrameSeed::default(),
        )?;
        println!(
            "bend {d} m ahead (straight until x = {:?} m)\n  physical model, valid: {}\n  noise-free, within 6 m: {}",
            p.straight_until(),
            shares(&f.part, |i| f.is_valid(i)),
            shares(&g.part, |_| true)
        );
    }
    Ok(())
}
