//! One simulated frame: ray casting, depth errors, range filter and subsampling.

use epd_core::Params;
use nalgebra::Vector3;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::error::SimError;
use crate::noise::{Noise, NoiseModel, Stream, stream};
use crate::scene::Scene;
use crate::sensor::Sensor;

/// Which random streams a frame uses: a frame is a pure function of these and the
/// configuration (SPEC §5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct FrameSeed {
    /// The scenario seed.
    pub seed: u64,
    /// The trial (pose) index.
    pub trial: u64,
    /// The index of the swept value.
    pub sweep_index: u64,
}

/// A simulated frame. All vectors are in the SCS (m); entry i of each list belongs to
/// the same pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Measured points x̂ (with depth errors).
    pub measured: Vec<[f64; 3]>,
    /// The exact wall points x where each pixel's ray meets the wall.
    pub exact: Vec<[f64; 3]>,
    /// Pixel (u, v) of each point, u to the right, v downwards.
    pub pixels: Vec<[u32; 2]>,
    /// Unit ray direction of each point's pixel.
    pub directions: Vec<[f64; 3]>,
    /// The true β.
    pub truth: Params,
    /// Image size (W, H) the pixels index.
    pub image_size: [u32; 2],
}

/// How many points of a frame to keep after the range filter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Subsample {
    /// Every point within range.
    #[default]
    All,
    /// N distinct points drawn uniformly (all of them if fewer are in range).
    Points(usize),
}

impl Frame {
    /// A frame with no points, whose buffers [`simulate_into`] fills (and reuses).
    pub fn empty() -> Self {
        Self {
            measured: Vec::new(),
            exact: Vec::new(),
            pixels: Vec::new(),
            directions: Vec::new(),
            truth: Params {
                d_max: 0.0,
                d_min: 0.0,
                roll: 0.0,
                pitch: 0.0,
                yaw: 0.0,
                dy: 0.0,
                dz: 0.0,
            },
            image_size: [0, 0],
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.measured.len()
    }

    /// Whether the frame holds no point.
    pub fn is_empty(&self) -> bool {
        self.measured.is_empty()
    }
}

/// Simulate one frame of `sensor` looking at `scene`, with `noise`, keeping the points
/// whose measured range lies in [min_range, max_range], then subsampling.
pub fn simulate(
    sensor: &Sensor,
    scene: &Scene,
    noise: &Noise,
    subsample: Subsample,
    seeds: FrameSeed,
) -> Result<Frame, SimError> {
    let mut frame = Frame::empty();
    simulate_into(sensor, scene, noise, subsample, seeds, &mut frame)?;
    Ok(frame)
}

/// [`simulate`] into an existing frame, reusing its buffers: after the first frame of a
/// given size no memory is allocated (fresh pages cost more than the ray casting here).
///
/// Every image row draws its depth errors from its own stream (seed, trial, sweep
/// index, row), so the frame does not depend on the number of threads. The subsample is
/// Knuth's selection sampling (Algorithm S): N distinct points, uniformly, kept in pixel
/// order, from the stream (seed, trial, sweep index, subsample).
pub fn simulate_into(
    sensor: &Sensor,
    scene: &Scene,
    noise: &Noise,
    subsample: Subsample,
    seeds: FrameSeed,
    frame: &mut Frame,
) -> Result<(), SimError> {
    sensor.validate()?;
    noise.validate()?;
    // Cast far enough that noise may bring a point back into range.
    let cast_limit = sensor.max_range * 2.0 + 10.0 * noise.sigma + 1.0;
    let pinhole = sensor.rays();
    let w = sensor.width as usize;
    let n_pix = sensor.pixel_count();
    frame.measured.resize(n_pix, [0.0; 3]);
    frame.exact.resize(n_pix, [0.0; 3]);
    frame.pixels.resize(n_pix, [0; 2]);
    frame.directions.resize(n_pix, [0.0; 3]);
    // Each row writes its in-range points at the start of its own slice of the buffers.
    let counts: Vec<usize> = frame
        .measured
        .par_chunks_mut(w)
        .zip(frame.exact.par_chunks_mut(w))
        .zip(frame.pixels.par_chunks_mut(w))
        .zip(frame.directions.par_chunks_mut(w))
        .enumerate()
        .map(|(v, (((meas, exact), pixels), dirs))| {
            let v = v as u32;
            let mut rng = stream(
                seeds.seed,
                seeds.trial,
                seeds.sweep_index,
                Stream::Row,
                v as u64,
            );
            let mut k = 0;
            for u in 0..sensor.width {
                let dir = pinhole.direction(u, v);
                let Some(range) = scene.cast(&dir, cast_limit) else {
                    continue;
                };
                let x = dir * range;
                // Depth bias and outliers act on the range along the ray.
                let mut r = range + noise.bias_b0 + noise.bias_b1 * range;
                if noise.outlier_fraction > 0.0 && rng.random::<f64>() < noise.outlier_fraction {
                    r = range * rng.random_range(0.5..1.5);
                }
                if noise.far_outlier_fraction > 0.0
                    && rng.random::<f64>() < noise.far_outlier_fraction
                {
                    r = rng.random_range(0.1..6.0);
                }
                let m = match noise.model {
                    NoiseModel::Range => {
                        let e: f64 = if noise.sigma > 0.0 {
                            StandardNormal.sample(&mut rng)
                        } else {
                            0.0
                        };
                        dir * (r + noise.sigma * e)
                    }
                    NoiseModel::Isotropic => {
                        let s = noise.sigma / 3f64.sqrt();
                        let mut e = Vector3::zeros();
                        if noise.sigma > 0.0 {
                            for c in 0..3 {
                                let n: f64 = StandardNormal.sample(&mut rng);
                                e[c] = s * n;
                            }
                        }
                        dir * r + e
                    }
                };
                let mr = m.norm();
                if mr >= sensor.min_range && mr <= sensor.max_range {
                    meas[k] = [m.x, m.y, m.z];
                    exact[k] = [x.x, x.y, x.z];
                    pixels[k] = [u, v];
                    dirs[k] = [dir.x, dir.y, dir.z];
                    k += 1;
                }
            }
            k
        })
        .collect();
    // Close the gaps between rows, in place.
    let mut at = 0;
    for (v, &k) in counts.iter().enumerate() {
        let from = v * w;
        if from != at {
            frame.measured.copy_within(from..from + k, at);
            frame.exact.copy_within(from..from + k, at);
            frame.pixels.copy_within(from..from + k, at);
            frame.directions.copy_within(from..from + k, at);
        }
        at += k;
    }
    let total = at;
    let mut keep_n = total;
    if let Subsample::Points(n) = subsample
        && n < total
    {
        let mut rng = stream(
            seeds.seed,
            seeds.trial,
            seeds.sweep_index,
            Stream::Subsample,
            0,
        );
        let mut chosen = 0;
        for i in 0..total {
            // Keep item i with probability (still needed)/(still available).
            if (rng.random::<f64>() * (total - i) as f64) < (n - chosen) as f64 {
                frame.measured[chosen] = frame.measured[i];
                frame.exact[chosen] = frame.exact[i];
                frame.pixels[chosen] = frame.pixels[i];
                frame.directions[chosen] = frame.directions[i];
                chosen += 1;
                if chosen == n {
                    break;
                }
            }
        }
        keep_n = chosen;
    }
    frame.measured.truncate(keep_n);
    frame.exact.truncate(keep_n);
    frame.pixels.truncate(keep_n);
    frame.directions.truncate(keep_n);
    frame.truth = *scene.truth();
    frame.image_size = [sensor.width, sensor.height];
    Ok(())
}
