//! A small analytic point-cloud generator for epd-core's tests and benchmarks: pinhole
//! rays (README, Conventions) intersected with the elliptic cylinder in closed form, with optional
//! Gaussian range noise along each ray. Independent of the estimators' code paths except
//! for eq. (3) (`Params::rotation`), which has its own unit tests.
#![allow(dead_code)]

use epd_core::Params;
use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64;

/// A pinhole grid of `w`×`h` pixels over 69°×51°, rays in the SCS (X forward, Y right, Z up).
pub fn rays(w: usize, h: usize) -> Vec<Vector3<f64>> {
    let fx = (w as f64 / 2.0) / (69f64.to_radians() / 2.0).tan();
    let fy = (h as f64 / 2.0) / (51f64.to_radians() / 2.0).tan();
    let mut v = Vec::with_capacity(w * h);
    for row in 0..h {
        for col in 0..w {
            let y = (col as f64 + 0.5 - w as f64 / 2.0) / fx;
            let z = -(row as f64 + 0.5 - h as f64 / 2.0) / fy;
            v.push(Vector3::new(1.0, y, z).normalize());
        }
    }
    v
}

/// Range along the unit ray `d` (SCS) to the wall of the pipe `beta`: the positive root
/// of the quadratic of eq. (5) along the line, written independently of epd-core.
pub fn range_to_wall(beta: &Params, d: &Vector3<f64>) -> Option<f64> {
    let q = beta.dir_scs_to_pcs(d);
    let (a2, b2) = ((beta.d_max / 2.0).powi(2), (beta.d_min / 2.0).powi(2));
    let qa = q.y * q.y / a2 + q.z * q.z / b2;
    let qb = beta.dy * q.y / a2 + beta.dz * q.z / b2;
    let qc = beta.dy * beta.dy / a2 + beta.dz * beta.dz / b2 - 1.0;
    if qa <= 0.0 {
        return None;
    }
    let disc = qb * qb - qa * qc;
    if disc < 0.0 {
        return None;
    }
    let t = (-qb + disc.sqrt()) / qa;
    (t > 0.0).then_some(t)
}

/// A frame of `n` points (or all within `max_range` if `n` is 0): exact wall points hit
/// by the rays of a `w`×`h` grid, displaced by N(0, σ²) along their rays.
pub fn cloud(
    beta: &Params,
    w: usize,
    h: usize,
    max_range: f64,
    sigma: f64,
    n: usize,
    seed: u64,
) -> Vec<[f64; 3]> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let normal = Normal::new(0.0, sigma.max(0.0)).expect("sigma is finite");
    let mut pts: Vec<[f64; 3]> = Vec::new();
    for d in rays(w, h) {
        if let Some(t) = range_to_wall(beta, &d).filter(|&t| t <= max_range) {
            let eps = if sigma > 0.0 {
                normal.sample(&mut rng)
            } else {
                0.0
            };
            let p = d * (t + eps);
            pts.push([p.x, p.y, p.z]);
        }
    }
    if n > 0 && n < pts.len() {
        // Partial Fisher–Yates: n distinct points.
        for i in 0..n {
            let j = rng.random_range(i..pts.len());
            pts.swap(i, j);
        }
        pts.truncate(n);
    }
    pts
}

/// A random pose in the given ranges (angles in degrees, offsets as a fraction of the radius).
pub fn random_params(
    rng: &mut Pcg64,
    id_m: f64,
    ovality: f64,
    tilt_deg: f64,
    offset_frac: f64,
) -> Params {
    let d_max = id_m * (1.0 + ovality / 2.0);
    let d_min = id_m * (1.0 - ovality / 2.0);
    let r = 0.5 * d_min;
    Params {
        d_max,
        d_min,
        roll: rng.random_range(-180.0..180.0f64).to_radians(),
        pitch: rng.random_range(-tilt_deg..tilt_deg).to_radians(),
        yaw: rng.random_range(-tilt_deg..tilt_deg).to_radians(),
        dy: rng.random_range(-offset_frac..offset_frac) * r,
        dz: rng.random_range(-offset_frac..offset_frac) * r,
    }
}

/// Inner diameter (m) of a pipe of nominal outer diameter `od_in` inches and 12 mm wall.
pub fn id_m(od_in: f64) -> f64 {
    od_in * 0.0254 - 2.0 * 0.012
}

pub fn rng(seed: u64) -> Pcg64 {
    Pcg64::seed_from_u64(seed)
}

/// A wall point of `beta` at axial position x and angle φ, in the SCS.
pub fn wall_point(beta: &Params, x: f64, phi: f64) -> [f64; 3] {
    let p = beta.pcs_to_scs(&Point3::new(
        x,
        0.5 * beta.d_max * phi.cos(),
        0.5 * beta.d_min * phi.sin(),
    ));
    [p.x, p.y, p.z]
}

/// One straight frame of a pipe `od_in` inches outside at 320 × 240 within 6 m (a random
/// pose: tilt within ±6°, offsets within a fifth of the radius) with N(0, σ²) range
/// noise, every range within `band` (m) read `bias_m` long (a multipath band).
pub fn banded_frame(
    seed: u64,
    od_in: f64,
    sigma: f64,
    band: (f64, f64),
    bias_m: f64,
) -> Vec<[f64; 3]> {
    let mut rng = rng(seed);
    let truth = random_params(&mut rng, id_m(od_in), 0.02, 6.0, 0.2);
    let normal = Normal::new(0.0, sigma).expect("σ is finite");
    rays(320, 240)
        .iter()
        .filter_map(|d| {
            let t = range_to_wall(&truth, d).filter(|&t| t <= 6.0)?;
            let shift = if (band.0..=band.1).contains(&t) {
                bias_m
            } else {
                0.0
            };
            let r = t + shift + normal.sample(&mut rng);
            Some([d.x * r, d.y * r, d.z * r])
        })
        .collect()
}
