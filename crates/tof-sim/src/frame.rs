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

struct Hit {
    pixel: [u32; 2],
    dir: Vector3<f64>,
    exact: Vector3<f64>,
    measured: Vector3<f64>,
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
    sensor.validate()?;
    noise.validate()?;
    // Cast far enough that noise may bring a point back into range.
    let cast_limit = sensor.max_range * 2.0 + 10.0 * noise.sigma + 1.0;
    let rows: Vec<Vec<Hit>> = (0..sensor.height)
        .into_par_iter()
        .map(|v| {
            let mut rng = stream(
                seeds.seed,
                seeds.trial,
                seeds.sweep_index,
                Stream::Row,
                v as u64,
            );
            let mut out = Vec::new();
            for u in 0..sensor.width {
                let dir = sensor.ray_direction(u, v);
                let Some(range) = scene.cast(&dir, cast_limit) else {
                    continue;
                };
                let exact = dir * range;
                // Depth bias and outliers act on the range along the ray.
                let mut r = range + noise.bias_b0 + noise.bias_b1 * range;
                if noise.outlier_fraction > 0.0 && rng.random::<f64>() < noise.outlier_fraction {
                    r = range * rng.random_range(0.5..1.5);
                }
                let measured = match noise.model {
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
                            for k in 0..3 {
                                let n: f64 = StandardNormal.sample(&mut rng);
                                e[k] = s * n;
                            }
                        }
                        dir * r + e
                    }
                };
                let m = measured.norm();
                if m >= sensor.min_range && m <= sensor.max_range {
                    out.push(Hit {
                        pixel: [u, v],
                        dir,
                        exact,
                        measured,
                    });
                }
            }
            out
        })
        .collect();
    let mut hits: Vec<Hit> = rows.into_iter().flatten().collect();
    if let Subsample::Points(n) = subsample
        && n < hits.len()
    {
        let mut rng = stream(
            seeds.seed,
            seeds.trial,
            seeds.sweep_index,
            Stream::Subsample,
            0,
        );
        let mut idx: Vec<usize> = (0..hits.len()).collect();
        for i in 0..n {
            let j = rng.random_range(i..idx.len());
            idx.swap(i, j);
        }
        idx.truncate(n);
        idx.sort_unstable();
        let mut keep = vec![false; hits.len()];
        for i in idx {
            keep[i] = true;
        }
        let mut k = keep.into_iter();
        hits.retain(|_| k.next().unwrap_or(false));
    }
    let arr = |v: &Vector3<f64>| [v.x, v.y, v.z];
    Ok(Frame {
        measured: hits.iter().map(|h| arr(&h.measured)).collect(),
        exact: hits.iter().map(|h| arr(&h.exact)).collect(),
        pixels: hits.iter().map(|h| h.pixel).collect(),
        directions: hits.iter().map(|h| arr(&h.dir)).collect(),
        truth: *scene.truth(),
        image_size: [sensor.width, sensor.height],
    })
}
