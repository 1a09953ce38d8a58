//! One simulated frame: ray casting, depth errors, range filter and subsampling.

use epd_core::Params;
use nalgebra::Vector3;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::camera::{CameraNoise, correlated_field};
use crate::error::SimError;
use crate::noise::{Noise, NoiseModel, Stream, stream};
use crate::physics::ToFPhysics;
use crate::pipeline::Part;
use crate::scene::Scene;
use crate::sensor::{Pinhole, Sensor};

/// Which random streams a frame uses: a frame is a pure function of these and the
/// configuration (README, Conventions).
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
///
/// With a physical sensor model ([`Noise::physics`]), invalid pixels (too dark,
/// saturated, or no wall within reach) are kept as cameras write them: measured point
/// [0, 0, 0], intensity 0, σ NaN, whatever the sensor's range filter; their `exact` is
/// the wall point, or NaN when the ray meets no wall. [`Frame::retain_valid`] drops them.
/// The frame's `PartialEq` sees NaN ≠ NaN: compare frames bit by bit.
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
    /// Intensity of each point in camera counts (`ToFPhysics::intensity_scale` ·
    /// measured amplitude, multipath included); 0 for invalid pixels. NaN for every point
    /// of the plain model (`physics: None`), which has no amplitude.
    pub intensity: Vec<f32>,
    /// The true standard deviation σ (m) of the random range error drawn for each point:
    /// σ(A) of the physical model, the constant `Noise::sigma` of the plain one (the
    /// total rms for the isotropic model), or its σ(r) with a range exponent
    /// ([`CameraNoise::sigma_range_exponent`]); NaN for invalid pixels.
    pub sigma: Vec<f64>,
    /// What each point's ray hit, for a scene with labels ([`Scene::pipeline`]): the
    /// segment and the kind of wall of the exact point; `None` for a pixel whose ray met
    /// no wall (only invalid pixels of the physical model). Empty for scenes without
    /// labels, so their frames are as before; otherwise aligned with the other lists
    /// (kept so by [`Frame::retain_valid`] and the subsampling).
    pub part: Vec<Option<Part>>,
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
            intensity: Vec::new(),
            sigma: Vec::new(),
            part: Vec::new(),
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

    /// Whether point i is a valid depth: invalid pixels of the physical model are written
    /// as the point [0, 0, 0].
    pub fn is_valid(&self, i: usize) -> bool {
        self.measured[i] != [0.0; 3]
    }

    /// Drop the invalid points ([`Frame::is_valid`]), keeping the others in order.
    pub fn retain_valid(&mut self) {
        let mut k = 0;
        for i in 0..self.measured.len() {
            if self.is_valid(i) {
                self.move_point(i, k);
                k += 1;
            }
        }
        self.truncate(k);
    }

    /// Copy point `from` over point `to`, in every list.
    fn move_point(&mut self, from: usize, to: usize) {
        self.measured[to] = self.measured[from];
        self.exact[to] = self.exact[from];
        self.pixels[to] = self.pixels[from];
        self.directions[to] = self.directions[from];
        self.intensity[to] = self.intensity[from];
        self.sigma[to] = self.sigma[from];
        if !self.part.is_empty() {
            self.part[to] = self.part[from];
        }
    }

    /// Keep the first `n` points, in every list.
    fn truncate(&mut self, n: usize) {
        self.measured.truncate(n);
        self.exact.truncate(n);
        self.pixels.truncate(n);
        self.directions.truncate(n);
        self.intensity.truncate(n);
        self.sigma.truncate(n);
        self.part.truncate(n);
    }
}

/// The outliers and the random error of one point: `r` is the range with its systematic
/// errors, `sigma` the standard deviation of the random error (`Noise::sigma` or σ(A) of
/// the physical model). Draws, in this order: the outlier test (and its range), the far
/// outlier test (and its range), the Gaussian error(s) — of which the range model takes
/// `field` instead when given (the pixel's correlated ε, [`correlated_field`]).
#[inline]
fn displace(
    noise: &Noise,
    sigma: f64,
    dir: &Vector3<f64>,
    range: f64,
    mut r: f64,
    field: Option<f64>,
    rng: &mut rand_pcg::Pcg64,
) -> Vector3<f64> {
    if noise.outlier_fraction > 0.0 && rng.random::<f64>() < noise.outlier_fraction {
        r = range * rng.random_range(0.5..1.5);
    }
    if noise.far_outlier_fraction > 0.0 && rng.random::<f64>() < noise.far_outlier_fraction {
        r = rng.random_range(0.1..6.0);
    }
    match noise.model {
        NoiseModel::Range => {
            let e: f64 = match field {
                Some(e) => e,
                None if sigma > 0.0 => StandardNormal.sample(rng),
                None => 0.0,
            };
            dir * (r + sigma * e)
        }
        NoiseModel::Isotropic => {
            let s = sigma / 3f64.sqrt();
            let mut e = Vector3::zeros();
            if sigma > 0.0 {
                for c in 0..3 {
                    let n: f64 = StandardNormal.sample(rng);
                    e[c] = s * n;
                }
            }
            dir * r + e
        }
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

/// [`simulate`] with the camera's own noise options ([`CameraNoise`]): correlated range
/// errors, a range-dependent σ, wiggling, multipath bands, flying pixels. With
/// `CameraNoise::default()` the frame is bit-identical to [`simulate`]'s.
pub fn simulate_with(
    sensor: &Sensor,
    scene: &Scene,
    noise: &Noise,
    camera: &CameraNoise,
    subsample: Subsample,
    seeds: FrameSeed,
) -> Result<Frame, SimError> {
    let mut frame = Frame::empty();
    simulate_into_with(sensor, scene, noise, camera, subsample, seeds, &mut frame)?;
    Ok(frame)
}

/// [`simulate`] into an existing frame, reusing its buffers: after the first frame of a
/// given size no memory is allocated (fresh pages cost more than the ray casting here).
///
/// Every image row draws its depth errors from its own stream (seed, trial, sweep
/// index, row), so the frame does not depend on the number of threads. The subsample is
/// Knuth's selection sampling (Algorithm S): N distinct points, uniformly, kept in pixel
/// order, from the stream (seed, trial, sweep index, subsample).
///
/// With a physical model ([`ToFPhysics`]) each pixel goes: true range r and incidence
/// cos θ (ray cast with the wall normal) → direct amplitude A = ρ cos θ/r² → multipath
/// phasor sum (range shift, measured amplitude A_m) → invalid if A_m is outside
/// [min_amplitude, saturation_amplitude] (written as zeros, kept, no random draw) →
/// r + wiggle(r) + offset(A_m) + multipath shift → outliers → + σ(A_m)·ε from the row's
/// stream → range filter. Without it, the plain model: r + b0 + b1·r → outliers →
/// + σ·ε → range filter.
///
/// For a scene with labels ([`Scene::is_labeled`]: a pipeline) every ray is cast with
/// [`Scene::cast_labeled`] and the hit part goes to [`Frame::part`]; otherwise the casts
/// are as they always were and `part` is left empty.
///
/// A scene's contamination ([`Scene::with_contamination`]) changes the casts; a pixel
/// whose hit lies outside its view sector ([`Scene::in_view`]) is dropped by the plain
/// model, and is invalid (zeros, its exact point kept, no random draw) under the
/// physical one.
pub fn simulate_into(
    sensor: &Sensor,
    scene: &Scene,
    noise: &Noise,
    subsample: Subsample,
    seeds: FrameSeed,
    frame: &mut Frame,
) -> Result<(), SimError> {
    simulate_into_with(
        sensor,
        scene,
        noise,
        &CameraNoise::default(),
        subsample,
        seeds,
        frame,
    )
}

/// [`simulate_into`] with the camera's own noise ([`CameraNoise`]). Per pixel, with r
/// the true range of its ray and r_s the range it sees (r, or the mixed range of a flying
/// pixel, which then stands for r in every model below): the plain model reads
/// r_s + b0 + b1·r_s + wiggle(r_s) + bands(r_s), then the outliers, then adds σ(r_s)·ε;
/// the physical one r_s plus its own systematic errors plus wiggle(r_s) and bands(r_s),
/// then the outliers, then σ(A)·ε. ε is the pixel's value of the correlated field
/// ([`correlated_field`], streams (seed, trial, sweep index, field, padded row)) when
/// ℓ > 0, else the row stream's draw as before. The flying-pixel draws take the stream
/// (seed, trial, sweep index, flying, row) and the random wiggle phase (seed, trial,
/// sweep index, wiggle), so each option leaves the other draws as they were.
pub fn simulate_into_with(
    sensor: &Sensor,
    scene: &Scene,
    noise: &Noise,
    camera: &CameraNoise,
    subsample: Subsample,
    seeds: FrameSeed,
    frame: &mut Frame,
) -> Result<(), SimError> {
    sensor.validate()?;
    noise.validate()?;
    camera.validate(noise)?;
    // Cast far enough that noise may bring a point back into range; with the physical
    // model, also as far as a pixel may be valid.
    // (With a range exponent, σ as at twice the range; a wiggle may shorten ranges by
    // its amplitude.)
    let cast_limit = match &noise.physics {
        None => {
            let sigma = camera.sigma_at(noise.sigma, sensor.max_range * 2.0 + 1.0);
            let wiggle = camera.wiggle.map_or(0.0, |w| w.amplitude_m);
            sensor.max_range * 2.0 + 10.0 * sigma + 1.0 + wiggle
        }
        Some(p) => (sensor.max_range * 2.0 + 1.0).max(p.max_valid_range()),
    };
    let w = sensor.width as usize;
    let pinhole = sensor.rays();
    let random_error = noise.sigma > 0.0 || noise.physics.is_some();
    let field = (camera.correlation_length_px > 0.0 && random_error).then(|| {
        correlated_field(
            w,
            sensor.height as usize,
            camera.correlation_length_px,
            seeds,
        )
    });
    let flying = camera
        .flying_pixels
        .filter(|f| f.probability > 0.0)
        .map(|f| {
            let ranges = true_ranges(sensor, &pinhole, scene, cast_limit);
            let partners = f.edge_partners(&ranges, w);
            Flying {
                probability: f.probability,
                ranges,
                partners,
            }
        });
    let labeled = scene.is_labeled();
    frame.resize_for(sensor.pixel_count(), labeled);
    let job = RowJob {
        sensor,
        pinhole,
        scene,
        noise,
        cast_limit,
        seeds,
        camera: (!camera.is_off()).then(|| CameraJob {
            noise: camera,
            wiggle_phase: camera.wiggle_phase(seeds),
            field: field.as_deref(),
            flying: flying.as_ref(),
        }),
    };
    let row =
        |v: usize, bufs: RowBuffers, part: Option<&mut [Option<Part>]>| job.run(v, bufs, part);
    let rows = frame
        .measured
        .par_chunks_mut(w)
        .zip(frame.exact.par_chunks_mut(w))
        .zip(frame.pixels.par_chunks_mut(w))
        .zip(frame.directions.par_chunks_mut(w))
        .zip(frame.intensity.par_chunks_mut(w))
        .zip(frame.sigma.par_chunks_mut(w))
        .map(
            |(((((meas, exact), pixels), dirs), inten), sig)| RowBuffers {
                meas,
                exact,
                pixels,
                dirs,
                inten,
                sig,
            },
        );
    let counts: Vec<usize> = if labeled {
        rows.zip(frame.part.par_chunks_mut(w))
            .enumerate()
            .map(|(v, (bufs, part))| row(v, bufs, Some(part)))
            .collect()
    } else {
        rows.enumerate()
            .map(|(v, bufs)| row(v, bufs, None))
            .collect()
    };
    let total = frame.close_row_gaps(&counts, w, labeled);
    let keep_n = match subsample {
        Subsample::Points(n) if n < total => {
            let mut rng = stream(
                seeds.seed,
                seeds.trial,
                seeds.sweep_index,
                Stream::Subsample,
                0,
            );
            frame.select_sampling(total, n, &mut rng)
        }
        _ => total,
    };
    frame.truncate(keep_n);
    frame.truth = *scene.truth();
    frame.image_size = [sensor.width, sensor.height];
    Ok(())
}

/// The true range (m) of every pixel's ray, row-major, NaN where it meets nothing
/// within `cast_limit` or its hit is out of view: the image the depth edges are found in.
fn true_ranges(sensor: &Sensor, pinhole: &Pinhole, scene: &Scene, cast_limit: f64) -> Vec<f64> {
    let w = sensor.width as usize;
    let mut ranges = vec![f64::NAN; sensor.pixel_count()];
    ranges.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, r) in row.iter_mut().enumerate() {
            let dir = pinhole.direction(u as u32, v as u32);
            if let Some(t) = scene.cast(&dir, cast_limit)
                && scene.in_view(&dir, t)
            {
                *r = t;
            }
        }
    });
    ranges
}

/// The flying pixels of a frame: who may fly, across which edge.
struct Flying {
    probability: f64,
    /// [`true_ranges`].
    ranges: Vec<f64>,
    /// [`crate::FlyingPixels::edge_partners`] of `ranges`.
    partners: Vec<Option<usize>>,
}

/// What the camera's options share over a frame.
struct CameraJob<'a> {
    noise: &'a CameraNoise,
    /// The frame's wiggle phase (rad).
    wiggle_phase: f64,
    /// The correlated ε of every pixel, row-major (ℓ > 0 and a random error).
    field: Option<&'a [f64]>,
    flying: Option<&'a Flying>,
}

/// What the camera adds to one pixel.
struct PixelCamera<'a> {
    noise: &'a CameraNoise,
    wiggle_phase: f64,
    /// The pixel's correlated ε.
    field: Option<f64>,
    /// The range a flying pixel sees instead of its ray's.
    flown: Option<f64>,
}

impl PixelCamera<'_> {
    /// The range the pixel sees: its flown range, or the true one.
    fn seen(cam: Option<&Self>, range: f64) -> f64 {
        cam.and_then(|c| c.flown).unwrap_or(range)
    }

    /// `r` plus the wiggle and the multipath bands at the seen range `seen`.
    fn systematic(cam: Option<&Self>, seen: f64, r: f64) -> f64 {
        match cam {
            Some(c) if c.noise.has_systematic() => r + c.noise.systematic(seen, c.wiggle_phase),
            _ => r,
        }
    }
}

/// What every image row of a frame shares.
struct RowJob<'a> {
    sensor: &'a Sensor,
    pinhole: Pinhole,
    scene: &'a Scene,
    noise: &'a Noise,
    cast_limit: f64,
    seeds: FrameSeed,
    /// `None` when every camera option is off: the frame as [`simulate_into`] gave it.
    camera: Option<CameraJob<'a>>,
}

impl RowJob<'_> {
    /// Image row `v`: writes its in-range points at the start of its own slice of the
    /// buffers (and of `part`, for a labelled scene) and returns their number. Its
    /// random draws come from its own stream (seed, trial, sweep index, row).
    fn run(&self, v: usize, bufs: RowBuffers, mut part: Option<&mut [Option<Part>]>) -> usize {
        let RowBuffers {
            meas,
            exact,
            pixels,
            dirs,
            inten,
            sig,
        } = bufs;
        let (sensor, seeds) = (self.sensor, self.seeds);
        let v = v as u32;
        let mut rng = stream(
            seeds.seed,
            seeds.trial,
            seeds.sweep_index,
            Stream::Row,
            v as u64,
        );
        let mut flying_rng = self.camera.as_ref().and_then(|c| c.flying).map(|_| {
            stream(
                seeds.seed,
                seeds.trial,
                seeds.sweep_index,
                Stream::Flying,
                v as u64,
            )
        });
        let w = sensor.width as usize;
        let mut k = 0;
        for u in 0..sensor.width {
            let dir = self.pinhole.direction(u, v);
            let i = v as usize * w + u as usize;
            let cam = self.camera.as_ref().map(|c| PixelCamera {
                noise: c.noise,
                wiggle_phase: c.wiggle_phase,
                field: c.field.map(|f| f[i]),
                flown: match (c.flying, flying_rng.as_mut()) {
                    (Some(f), Some(rng)) => fly(f, i, rng),
                    _ => None,
                },
            });
            let Some(px) = sample_pixel(
                self.scene,
                self.noise,
                cam.as_ref(),
                &dir,
                self.cast_limit,
                &mut rng,
            ) else {
                continue;
            };
            let keep = match &px.measured {
                // Invalid pixels are kept as zeros, whatever the range filter.
                None => true,
                Some(m) => {
                    let mr = m.norm();
                    mr >= sensor.min_range && mr <= sensor.max_range
                }
            };
            if keep {
                let (m, x) = (px.measured.unwrap_or_else(Vector3::zeros), px.exact);
                meas[k] = [m.x, m.y, m.z];
                exact[k] = [x.x, x.y, x.z];
                pixels[k] = [u, v];
                dirs[k] = [dir.x, dir.y, dir.z];
                inten[k] = px.intensity;
                sig[k] = px.sigma;
                if let Some(part) = part.as_deref_mut() {
                    part[k] = px.part;
                }
                k += 1;
            }
        }
        k
    }
}

impl Frame {
    /// Every list sized for `n_pix` pixels (`part` only for a labelled scene, emptied
    /// otherwise), keeping the buffers' capacity.
    fn resize_for(&mut self, n_pix: usize, labeled: bool) {
        self.measured.resize(n_pix, [0.0; 3]);
        self.exact.resize(n_pix, [0.0; 3]);
        self.pixels.resize(n_pix, [0; 2]);
        self.directions.resize(n_pix, [0.0; 3]);
        self.intensity.resize(n_pix, 0.0);
        self.sigma.resize(n_pix, 0.0);
        if labeled {
            self.part.resize(n_pix, None);
        } else {
            self.part.clear();
        }
    }

    /// Close the gaps between rows of `w` pixels, in place: row v kept its `counts[v]`
    /// points at the start of its slice. Returns the number of points.
    fn close_row_gaps(&mut self, counts: &[usize], w: usize, labeled: bool) -> usize {
        let mut at = 0;
        for (v, &k) in counts.iter().enumerate() {
            let from = v * w;
            if from != at {
                self.measured.copy_within(from..from + k, at);
                self.exact.copy_within(from..from + k, at);
                self.pixels.copy_within(from..from + k, at);
                self.directions.copy_within(from..from + k, at);
                self.intensity.copy_within(from..from + k, at);
                self.sigma.copy_within(from..from + k, at);
                if labeled {
                    self.part.copy_within(from..from + k, at);
                }
            }
            at += k;
        }
        at
    }

    /// Knuth's selection sampling (Algorithm S) of `n` < `total` of the first `total`
    /// points, uniformly, moved to the front in their order. Returns the number kept.
    fn select_sampling(&mut self, total: usize, n: usize, rng: &mut rand_pcg::Pcg64) -> usize {
        let mut chosen = 0;
        for i in 0..total {
            // Keep item i with probability (still needed)/(still available).
            if (rng.random::<f64>() * (total - i) as f64) < (n - chosen) as f64 {
                self.move_point(i, chosen);
                chosen += 1;
                if chosen == n {
                    break;
                }
            }
        }
        chosen
    }
}

/// What one pixel measured (see [`simulate_into`]).
struct PixelSample {
    /// The measured point; `None` for an invalid pixel of the physical model.
    measured: Option<Vector3<f64>>,
    /// The exact wall point (NaN where the physical model's ray meets no wall).
    exact: Vector3<f64>,
    /// The intensity (NaN without the physical model).
    intensity: f32,
    /// σ of the random range error.
    sigma: f64,
    /// The part hit, for a labelled scene.
    part: Option<Part>,
}

/// The pixel of ray `dir` (SCS, unit): the ray cast (labelled for a pipeline), then
/// the plain model — r + b0 + b1·r, outliers, + σ·ε — or the physical one
/// ([`physical_point`]), drawing from `rng`. `None` when the plain model's ray meets no
/// wall within `cast_limit`.
#[inline]
fn sample_pixel(
    scene: &Scene,
    noise: &Noise,
    cam: Option<&PixelCamera>,
    dir: &Vector3<f64>,
    cast_limit: f64,
    rng: &mut rand_pcg::Pcg64,
) -> Option<PixelSample> {
    let labeled = scene.is_labeled();
    let mut part = None;
    Some(match &noise.physics {
        None => {
            let range = if labeled {
                scene.cast_labeled(dir, cast_limit).map(|(r, _, p)| {
                    part = Some(p);
                    r
                })
            } else {
                scene.cast(dir, cast_limit)
            }?;
            if !scene.in_view(dir, range) {
                return None;
            }
            // Depth bias and outliers act on the range along the ray (the one the pixel
            // sees: a flying pixel's is not its ray's).
            let seen = PixelCamera::seen(cam, range);
            let r = seen + noise.bias_b0 + noise.bias_b1 * seen;
            let r = PixelCamera::systematic(cam, seen, r);
            let sigma = cam.map_or(noise.sigma, |c| c.noise.sigma_at(noise.sigma, seen));
            let e = cam.and_then(|c| c.field);
            let m = displace(noise, sigma, dir, seen, r, e, rng);
            PixelSample {
                measured: Some(m),
                exact: dir * range,
                intensity: f32::NAN,
                sigma,
                part,
            }
        }
        Some(p) => {
            let hit = if labeled {
                scene.cast_labeled(dir, cast_limit).map(|(r, c, hit_part)| {
                    part = Some(hit_part);
                    (r, c)
                })
            } else {
                scene.cast_with_normal(dir, cast_limit)
            };
            let q = physical_point(p, noise, scene, cam, dir, hit, rng);
            PixelSample {
                measured: q.measured,
                exact: q.exact,
                intensity: (p.intensity_scale * q.amplitude) as f32,
                sigma: q.sigma,
                part,
            }
        }
    })
}

/// Whether pixel `i` flies, and the range it then sees: for an edge pixel, a draw
/// U[0, 1) < p, then α ~ U[0, ½) and r_i + α·(r_partner − r_i) ([`crate::FlyingPixels`]).
fn fly(f: &Flying, i: usize, rng: &mut rand_pcg::Pcg64) -> Option<f64> {
    let j = f.partners[i]?;
    if rng.random::<f64>() >= f.probability {
        return None;
    }
    let alpha = rng.random_range(0.0..0.5);
    let (ri, rj) = (f.ranges[i], f.ranges[j]);
    Some(ri + alpha * (rj - ri))
}

/// One image row's slices of a frame's buffers.
struct RowBuffers<'a> {
    meas: &'a mut [[f64; 3]],
    exact: &'a mut [[f64; 3]],
    pixels: &'a mut [[u32; 2]],
    dirs: &'a mut [[f64; 3]],
    inten: &'a mut [f32],
    sig: &'a mut [f64],
}

/// One pixel under the physical model.
struct PhysicalPixel {
    /// The measured point; `None` if the pixel is invalid.
    measured: Option<Vector3<f64>>,
    /// The exact wall point; NaN if the ray meets no wall.
    exact: Vector3<f64>,
    /// The measured amplitude; 0 if invalid.
    amplitude: f64,
    /// σ of the random range error; NaN if invalid.
    sigma: f64,
}

/// One pixel under the physical model, from its ray cast `hit` (range, cos θ), `None`
/// when the ray meets no wall within reach.
#[inline]
fn physical_point(
    p: &ToFPhysics,
    noise: &Noise,
    scene: &Scene,
    cam: Option<&PixelCamera>,
    dir: &Vector3<f64>,
    hit: Option<(f64, f64)>,
    rng: &mut rand_pcg::Pcg64,
) -> PhysicalPixel {
    let invalid = |exact| PhysicalPixel {
        measured: None,
        exact,
        amplitude: 0.0,
        sigma: f64::NAN,
    };
    let Some((range, cos_incidence)) = hit else {
        return invalid(Vector3::repeat(f64::NAN));
    };
    let x = dir * range;
    if !scene.in_view(dir, range) {
        return invalid(x);
    }
    let a = p.amplitude(range, cos_incidence);
    let (shift, a_m) = p.multipath(range, a);
    if !p.is_valid(a_m) {
        return invalid(x);
    }
    let seen = PixelCamera::seen(cam, range);
    let r = seen + p.wiggle(seen) + p.amplitude_offset(a_m) + shift;
    let r = PixelCamera::systematic(cam, seen, r);
    let s = p.sigma_at(a_m);
    let e = cam.and_then(|c| c.field);
    PhysicalPixel {
        measured: Some(displace(noise, s, dir, seen, r, e, rng)),
        exact: x,
        amplitude: a_m,
        sigma: s,
    }
}
