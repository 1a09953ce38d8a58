//! The camera's own noise beyond [`crate::Noise`]: spatially correlated range errors,
//! a range-dependent σ, wiggling, multipath bands and flying pixels at depth edges.
//!
//! Every option is off in [`CameraNoise::default`], and a frame with every option off is
//! bit-identical to the frame [`crate::simulate`] gives (the same seeded streams, drawn
//! in the same order); each option that draws random numbers draws them from its own
//! stream ([`crate::noise::Stream`]) of (seed, trial, sweep index), so turning one on
//! leaves the other draws, and the determinism per (seed, trial, sweep index) and for
//! any thread count, as they were.
//!
//! Ranges are along each pixel's unit ray in the SCS (X forward, Y right, Z up), in
//! metres; pixel (u, v) has u to the right and v downwards.
//!
//! The error-model facts and their sources are collected in
//! /work/shared/notes/field-notes.md ("ToF error models"): Lange (2000, eq. 4.17) for the
//! random error, the wiggling (cyclic) error, multipath and flying pixels. Amplitude-
//! dependent σ, the physical wiggling at L/4 and a phasor multipath model live in
//! [`crate::ToFPhysics`]; far outliers in [`crate::Noise::far_outlier_fraction`].

use std::f64::consts::TAU;

use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::error::{Rule, SimError, first_broken};
use crate::frame::FrameSeed;
use crate::noise::{Noise, NoiseModel, Stream, stream};

/// The largest correlation length accepted (pixels): the kernel then spans 2·256 + 1
/// taps and one 640×480 field costs about 0.3 G multiply-adds.
pub const MAX_CORRELATION_PX: f64 = 64.0;

/// The largest exponent of the range-dependent σ: 2 is the ambient-limited case; 4 leaves
/// room for a steeper empirical fit.
pub const MAX_SIGMA_RANGE_EXPONENT: f64 = 4.0;

/// The camera's noise options (module doc). Plain data; [`CameraNoise::validate`]
/// checks them. The default turns every option off.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraNoise {
    /// Correlation length ℓ (pixels) of the random range error, in
    /// [0, [`MAX_CORRELATION_PX`]]; 0 (the default) draws it independently per pixel.
    ///
    /// Model: an i.i.d. N(0, 1) field z over the pixel grid, padded by R = ⌈4ℓ⌉ pixels on
    /// every side (so the image's edges are like its centre), is smoothed by the separable
    /// Gaussian kernel k_j = exp(−j²/(2ℓ²)), |j| ≤ R, along rows and then columns and
    /// divided by Σ_j k_j²; each pixel's ε then has variance exactly 1, and the error is σ·ε
    /// (σ that of the pixel: `Noise::sigma`, σ(r) below, or σ(A) of the physical model).
    /// The correlation of two pixels' errors Δu columns and Δv rows apart is
    /// ρ(Δu, Δv) = c(Δu)·c(Δv), c(d) = Σ_j k_j k_{j+d} / Σ_j k_j² ([`correlation`]),
    /// ≈ exp(−(Δu² + Δv²)/(4ℓ²)) for ℓ ≳ 1 (a Gaussian of standard deviation ℓ√2 in
    /// pixels), 0 beyond 2R. Why: on-camera filtering and the pixel's own footprint make
    /// ToF errors spatially correlated (field notes, "Correlated errors"). Only with the
    /// `range` noise model.
    pub correlation_length_px: f64,
    /// The exponent p of a range-dependent σ for the plain model (`physics: None`):
    /// σ(r) = `Noise::sigma` · (r / r0)^p at true range r, p in
    /// [0, [`MAX_SIGMA_RANGE_EXPONENT`]]; 0 (the default) keeps σ constant. Lange (2000,
    /// eq. 4.17; field notes) gives σ ∝ √B / A with amplitude A ∝ ρ·cos θ / r²: when the
    /// signal's own shot noise dominates (B ≈ A) σ ∝ 1/√A ∝ r, p = 1; when ambient light
    /// or dark current dominates (B constant) σ ∝ 1/A ∝ r², p = 2 (both at a fixed
    /// incidence θ). The physical model ([`crate::ToFPhysics`]) sets σ from each pixel's
    /// amplitude instead, so p must be 0 with it.
    pub sigma_range_exponent: f64,
    /// The reference range r0 (m) at which σ(r) = `Noise::sigma`; finite, > 0. 1 m by
    /// default.
    pub sigma_reference_range_m: f64,
    /// A wiggling (cyclic) range error, `None` by default.
    pub wiggle: Option<Wiggle>,
    /// Multipath bands: a ray whose true range lies in a band's [near, far] reads long by
    /// its `extra_m` (the extras of overlapping bands add up). Empty by default.
    pub multipath_bands: Vec<MultipathBand>,
    /// Flying pixels at depth edges, `None` by default.
    pub flying_pixels: Option<FlyingPixels>,
}

impl Default for CameraNoise {
    fn default() -> Self {
        Self {
            correlation_length_px: 0.0,
            sigma_range_exponent: 0.0,
            sigma_reference_range_m: 1.0,
            wiggle: None,
            multipath_bands: Vec::new(),
            flying_pixels: None,
        }
    }
}

/// The wiggling error w(r) = a·sin(2π r / P + φ) (m) added to the range at true range r
/// (m). It comes from the modulation's harmonics aliased by the phase sampling; tens of
/// mm peak to peak at tens of MHz before calibration, its period a fraction of the
/// unambiguous range L = c/(2 f_mod) (field notes, "Wiggling (cyclic) error"; L/4 for
/// 4-phase sampling of odd harmonics, as in [`crate::ToFPhysics::wiggle_period`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wiggle {
    /// Amplitude a (m), finite, ≥ 0.
    pub amplitude_m: f64,
    /// Period P (m) in range, finite, > 0 (1.5 m = L/4 of the Helios2's 6 m mode).
    pub period_m: f64,
    /// Phase φ (rad), finite; ignored with `random_phase`.
    pub phase_rad: f64,
    /// Draw φ ~ U[0, 2π) once per frame (from the stream (seed, trial, sweep index,
    /// wiggle)) instead of `phase_rad`: a camera whose calibration leaves a residual of
    /// unknown phase.
    pub random_phase: bool,
}

impl Wiggle {
    /// A 6 mm, L/4 = 1.5 m wiggle of phase 0, as the physical model's default residual
    /// ([`crate::ToFPhysics::helios2`]).
    pub fn helios2() -> Self {
        Self {
            amplitude_m: 0.006,
            period_m: 1.5,
            phase_rad: 0.0,
            random_phase: false,
        }
    }

    /// w(r) = a·sin(2π r / P + φ) at range `range` (m) with phase `phase` (rad).
    pub fn at(&self, range: f64, phase: f64) -> f64 {
        self.amplitude_m * (TAU * range / self.period_m + phase).sin()
    }
}

/// One multipath band: every ray whose true range r lies in [`near_m`, `far_m`] reads
/// `extra_m` long. Multipath always lengthens the range and is worst in concave scenes
/// such as a pipe's inside; no published pipe figure exists, so its size is a parameter
/// (field notes, "Multipath interference"). A band is the simplest such model: the
/// stretch of wall whose indirect light arrives with about the same extra path. (The
/// phasor sum of [`crate::ToFPhysics::multipath`] is the smooth model.)
///
/// [`near_m`]: MultipathBand::near_m
/// [`far_m`]: MultipathBand::far_m
/// [`extra_m`]: MultipathBand::extra_m
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultipathBand {
    /// The band's nearest true range (m), finite, ≥ 0.
    pub near_m: f64,
    /// Its farthest true range (m), finite, > `near_m`.
    pub far_m: f64,
    /// The range added Δ (m), finite, ≥ 0 (multipath never shortens a range).
    pub extra_m: f64,
}

/// Flying pixels: a pixel whose footprint straddles a depth edge mixes the returns of the
/// foreground and the background and reads a range between them (field notes: "Flying
/// pixels at depth edges"; the Helios2's own filter drops pixels that jump by more than
/// 20 mm from their neighbours).
///
/// Model. A *depth edge* lies between 4-neighbours p and n (true ranges r_p, r_n, from
/// the noise-free cast of the scene) when the jump J = |r_n − r_p| exceeds both
/// `edge_jump_m` and `edge_ratio` times each of the steps on either side along the same
/// line, |r_p − r_{p−δ}| and |r_{n+δ} − r_n| (δ = n − p; a missing pixel counts 0). A
/// smooth wall, even at grazing incidence where neighbours' ranges differ by centimetres,
/// has steps that change slowly, and a crease (the floor meeting the wall) has a jump
/// no larger than the steeper side's steps: neither is an edge; an occluding contour,
/// whose jump is many steps, is. (A foreground one pixel thick has jumps on both sides
/// and is not found. Within a pixel or two of a straight pipe's vanishing point, at tens
/// of metres, ranges grow like 1/angle and steps by up to 3× a pixel: a few edges there,
/// 12 in a 640×480 frame from the axis, far beyond any camera's range.) A pixel with
/// edges to several neighbours takes the largest jump's.
/// Each edge pixel flies with probability `probability`; one that flies reads the range
/// r_p + α·(r_n − r_p), α ~ U[0, ½): the fraction of its footprint on the other side of
/// the edge for an edge uniformly placed within it, mixed linearly (equal amplitudes and
/// a small phase difference). The draws come from the stream (seed, trial, sweep index,
/// flying, row). Its exact point stays the centre ray's hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlyingPixels {
    /// The probability that a pixel at a depth edge flies, in [0, 1].
    pub probability: f64,
    /// The smallest jump (m) that makes an edge, finite, ≥ 0; 0.02 m in
    /// [`FlyingPixels::new`] (the Helios2 vendor example's flying-pixel filter
    /// threshold, field notes).
    pub edge_jump_m: f64,
    /// How many times the steps on either side the jump must exceed, finite, ≥ 1; 3 in
    /// [`FlyingPixels::new`] (a smooth surface's neighbouring steps differ by a few per
    /// cent, a crease's by the ratio of its two slopes, an occlusion's by orders of
    /// magnitude; assumed).
    pub edge_ratio: f64,
}

impl FlyingPixels {
    /// Edge pixels fly with `probability`; the edge thresholds at their documented
    /// values (`edge_jump_m` 0.02 m, `edge_ratio` 3).
    pub fn new(probability: f64) -> Self {
        Self {
            probability,
            edge_jump_m: 0.02,
            edge_ratio: 3.0,
        }
    }
}

/// The four neighbours' offsets (du, dv).
const NEIGHBOURS: [(isize, isize); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];

impl FlyingPixels {
    /// The depth-edge partner of every pixel of a row-major range image of width
    /// `width` (m; NaN where there is no range): the index of the neighbour across the
    /// largest edge (see the type's doc), or `None`.
    pub fn edge_partners(&self, ranges: &[f64], width: usize) -> Vec<Option<usize>> {
        let height = ranges.len().checked_div(width).unwrap_or(0);
        (0..width * height)
            .into_par_iter()
            .map(|i| self.partner(ranges, width, height, i))
            .collect()
    }

    /// [`FlyingPixels::edge_partners`] of pixel `i`.
    fn partner(&self, ranges: &[f64], w: usize, h: usize, i: usize) -> Option<usize> {
        let (u, v) = ((i % w) as isize, (i / w) as isize);
        let at = |du: isize, dv: isize| -> Option<(usize, f64)> {
            let (x, y) = (u + du, v + dv);
            if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
                return None;
            }
            let j = y as usize * w + x as usize;
            ranges[j].is_finite().then(|| (j, ranges[j]))
        };
        let rp = ranges[i];
        if !rp.is_finite() {
            return None;
        }
        let mut best: Option<(usize, f64)> = None;
        for (du, dv) in NEIGHBOURS {
            let Some((j, rn)) = at(du, dv) else {
                continue;
            };
            let jump = (rn - rp).abs();
            let before = at(-du, -dv).map_or(0.0, |(_, r)| (rp - r).abs());
            let after = at(2 * du, 2 * dv).map_or(0.0, |(_, r)| (r - rn).abs());
            if jump > self.edge_jump_m
                && jump > self.edge_ratio * before.max(after)
                && best.is_none_or(|(_, b)| jump > b)
            {
                best = Some((j, jump));
            }
        }
        best.map(|(j, _)| j)
    }
}

impl CameraNoise {
    /// Check every field, and that they suit `noise`; the error names the first bad one.
    pub fn validate(&self, noise: &Noise) -> Result<(), SimError> {
        use Rule::{Finite, Holds, NonNegative, Positive};
        let (ell, p) = (self.correlation_length_px, self.sigma_range_exponent);
        let checks = [
            (
                "noise.correlation_length_px",
                ell,
                Holds(
                    ell.is_finite() && (0.0..=MAX_CORRELATION_PX).contains(&ell),
                    "must lie in [0, 64] pixels",
                ),
            ),
            (
                "noise.correlation_length_px",
                ell,
                Holds(
                    ell == 0.0 || noise.model == NoiseModel::Range,
                    "needs the range noise model (noise.model = \"range\")",
                ),
            ),
            (
                "noise.sigma_range_exponent",
                p,
                Holds(
                    p.is_finite() && (0.0..=MAX_SIGMA_RANGE_EXPONENT).contains(&p),
                    "must lie in [0, 4]",
                ),
            ),
            (
                "noise.sigma_range_exponent",
                p,
                Holds(
                    p == 0.0 || noise.physics.is_none(),
                    "must be 0 with the physical sensor model, whose σ follows the amplitude",
                ),
            ),
            (
                "noise.sigma_reference_range_m",
                self.sigma_reference_range_m,
                Positive,
            ),
        ];
        if let Some((k, v, r)) = first_broken(checks) {
            return Err(SimError::invalid(k, v, r.reason()));
        }
        if let Some(w) = &self.wiggle {
            let checks = [
                ("noise.wiggle.amplitude_m", w.amplitude_m, NonNegative),
                ("noise.wiggle.period_m", w.period_m, Positive),
                ("noise.wiggle.phase_rad", w.phase_rad, Finite),
            ];
            if let Some((k, v, r)) = first_broken(checks) {
                return Err(SimError::invalid(k, v, r.reason()));
            }
        }
        for (i, b) in self.multipath_bands.iter().enumerate() {
            let checks = [
                ("noise.multipath_bands.near_m", b.near_m, NonNegative),
                (
                    "noise.multipath_bands.far_m",
                    b.far_m,
                    Holds(
                        b.far_m.is_finite() && b.far_m > b.near_m,
                        "must be finite and greater than the band's near_m",
                    ),
                ),
                ("noise.multipath_bands.extra_m", b.extra_m, NonNegative),
            ];
            if let Some((k, v, r)) = first_broken(checks) {
                return Err(SimError::invalid(k, format!("{v} (band {i})"), r.reason()));
            }
        }
        if let Some(f) = &self.flying_pixels {
            let checks = [
                (
                    "noise.flying_pixels.probability",
                    f.probability,
                    Holds((0.0..=1.0).contains(&f.probability), "must lie in [0, 1]"),
                ),
                (
                    "noise.flying_pixels.edge_jump_m",
                    f.edge_jump_m,
                    NonNegative,
                ),
                (
                    "noise.flying_pixels.edge_ratio",
                    f.edge_ratio,
                    Holds(
                        f.edge_ratio.is_finite() && f.edge_ratio >= 1.0,
                        "must be finite and ≥ 1",
                    ),
                ),
            ];
            if let Some((k, v, r)) = first_broken(checks) {
                return Err(SimError::invalid(k, v, r.reason()));
            }
        }
        Ok(())
    }

    /// Whether any option is on (a frame then takes the camera's code paths).
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }

    /// σ(r) = `sigma` · (r / r0)^p (m) at true range `range` (m); exactly `sigma` for
    /// p = 0.
    pub fn sigma_at(&self, sigma: f64, range: f64) -> f64 {
        if self.sigma_range_exponent == 0.0 {
            sigma
        } else {
            sigma * (range / self.sigma_reference_range_m).powf(self.sigma_range_exponent)
        }
    }

    /// The sum of the multipath bands' extras (m) at true range `range` (m).
    pub fn multipath_extra(&self, range: f64) -> f64 {
        self.multipath_bands
            .iter()
            .filter(|b| (b.near_m..=b.far_m).contains(&range))
            .map(|b| b.extra_m)
            .sum()
    }

    /// The deterministic range error (m) at true range `range` (m): the wiggle (of
    /// phase `wiggle_phase`, rad) plus the multipath extras.
    pub fn systematic(&self, range: f64, wiggle_phase: f64) -> f64 {
        let w = self.wiggle.map_or(0.0, |w| w.at(range, wiggle_phase));
        w + self.multipath_extra(range)
    }

    /// Whether [`CameraNoise::systematic`] can be non-zero.
    pub(crate) fn has_systematic(&self) -> bool {
        self.wiggle.is_some() || !self.multipath_bands.is_empty()
    }

    /// The wiggle's phase (rad) in the frame of `seeds`: `phase_rad`, or U[0, 2π) from
    /// the stream (seed, trial, sweep index, wiggle) with `random_phase`. 0 without a
    /// wiggle.
    pub fn wiggle_phase(&self, seeds: FrameSeed) -> f64 {
        match &self.wiggle {
            None => 0.0,
            Some(w) if w.random_phase => {
                let mut rng = stream(
                    seeds.seed,
                    seeds.trial,
                    seeds.sweep_index,
                    Stream::Wiggle,
                    0,
                );
                rng.random_range(0.0..TAU)
            }
            Some(w) => w.phase_rad,
        }
    }
}

/// The kernel k_j = exp(−j²/(2ℓ²)), j = −R..=R, R = ⌈4ℓ⌉, of correlation length `ell`
/// (pixels, > 0).
fn kernel(ell: f64) -> Vec<f64> {
    let r = (4.0 * ell).ceil() as isize;
    (-r..=r)
        .map(|j| (-(j * j) as f64 / (2.0 * ell * ell)).exp())
        .collect()
}

/// The correlation c(d) = Σ_j k_j k_{j+d} / Σ_j k_j² along one image axis, `d` pixels
/// apart, of the field of correlation length `ell` ([`CameraNoise::correlation_length_px`]);
/// 1 at d = 0, 0 beyond 2R. The correlation of pixels (Δu, Δv) apart is
/// `correlation(ell, Δu) · correlation(ell, Δv)`; for `ell` = 0 it is 1 at 0, else 0.
pub fn correlation(ell: f64, d: i64) -> f64 {
    if ell <= 0.0 {
        return if d == 0 { 1.0 } else { 0.0 };
    }
    let k = kernel(ell);
    let n = k.len() as i64;
    let norm: f64 = k.iter().map(|x| x * x).sum();
    let s: f64 = (0..n)
        .filter(|&j| (0..n).contains(&(j + d)))
        .map(|j| k[j as usize] * k[(j + d) as usize])
        .sum();
    s / norm
}

/// The unit-variance correlated field ε of a `width` × `height` image (row-major) with
/// correlation length `ell` > 0 pixels ([`CameraNoise::correlation_length_px`]): row r of
/// the padded i.i.d. field comes from the stream (seed, trial, sweep index, field, r),
/// and each output is a fixed-order sum, so the field is the same for any thread count.
pub fn correlated_field(width: usize, height: usize, ell: f64, seeds: FrameSeed) -> Vec<f64> {
    let k = kernel(ell);
    let r = k.len() / 2;
    let (pw, ph) = (width + 2 * r, height + 2 * r);
    let norm: f64 = k.iter().map(|x| x * x).sum();
    // Each padded row drawn and smoothed along u: `width` values per row.
    let mut rows = vec![0.0; width * ph];
    rows.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(row, out)| {
            let mut rng = stream(
                seeds.seed,
                seeds.trial,
                seeds.sweep_index,
                Stream::Field,
                row as u64,
            );
            let z: Vec<f64> = (0..pw).map(|_| StandardNormal.sample(&mut rng)).collect();
            for (u, o) in out.iter_mut().enumerate() {
                *o = k.iter().zip(&z[u..u + k.len()]).map(|(a, b)| a * b).sum();
            }
        });
    // Then along v, and normalised to unit variance.
    let mut field = vec![0.0; width * height];
    field
        .par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(v, out)| {
            for (u, o) in out.iter_mut().enumerate() {
                let s: f64 = k
                    .iter()
                    .enumerate()
                    .map(|(j, a)| a * rows[(v + j) * width + u])
                    .sum();
                *o = s / norm;
            }
        });
    field
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn correlation_is_the_kernel_autocorrelation_and_near_the_continuum() {
        for ell in [0.5, 1.0, 2.0, 5.0] {
            assert!((correlation(ell, 0) - 1.0).abs() < 1e-15);
            let r = (4.0 * ell).ceil() as i64;
            assert_eq!(correlation(ell, 2 * r + 1), 0.0);
            for d in 1..=(3.0 * ell) as i64 {
                let cont = (-(d * d) as f64 / (4.0 * ell * ell)).exp();
                let c = correlation(ell, d);
                assert!((c - correlation(ell, -d)).abs() < 1e-15);
                if ell >= 1.0 {
                    assert!((c - cont).abs() < 2e-3, "ℓ {ell}, d {d}: {c} vs {cont}");
                }
            }
        }
        assert_eq!(correlation(0.0, 0), 1.0);
        assert_eq!(correlation(0.0, 1), 0.0);
    }

    /// The field's variance at the corners and the centre: each pixel's value over 400
    /// seeds has sample variance 1 within 4 standard errors, √(2/399) each.
    #[test]
    fn field_has_unit_variance_everywhere() {
        let n = 400;
        let (w, h) = (9, 7);
        let mut sum2 = vec![0.0; w * h];
        for s in 0..n {
            let f = correlated_field(
                w,
                h,
                1.5,
                FrameSeed {
                    seed: s,
                    trial: 0,
                    sweep_index: 0,
                },
            );
            for (a, x) in sum2.iter_mut().zip(&f) {
                *a += x * x;
            }
        }
        let tol = 4.0 * (2.0 / n as f64).sqrt();
        for i in [0, w - 1, w * h / 2, w * h - 1] {
            let var = sum2[i] / n as f64;
            assert!((var - 1.0).abs() < tol, "pixel {i}: {var}");
        }
    }

    #[test]
    fn edges_are_jumps_not_slopes_or_creases() {
        let fp = FlyingPixels::new(0.5);
        // One row: a grazing wall (steps growing 5 % a pixel), then a crease to a 5×
        // steeper slope: no edge.
        let mut row = vec![1.0];
        for i in 1..40usize {
            let grow = 1.05f64.powi(i as i32);
            let step = if i < 20 { 0.03 * grow } else { 0.15 * grow };
            row.push(row[i - 1] + step);
        }
        assert!(
            fp.edge_partners(&row, row.len())
                .iter()
                .all(Option::is_none)
        );
        // A step from a foreground at 1 m to a background at 3 m: both sides are edges,
        // each the other's partner.
        let step: Vec<f64> = (0..10)
            .map(|i| if i < 5 { 1.0 + 0.001 * i as f64 } else { 3.0 })
            .collect();
        let p = fp.edge_partners(&step, 10);
        assert_eq!(p[4], Some(5));
        assert_eq!(p[5], Some(4));
        assert_eq!(p.iter().filter(|x| x.is_some()).count(), 2);
        // Too small a jump, or a missing neighbour: no edge.
        let small: Vec<f64> = (0..10).map(|i| if i < 5 { 1.0 } else { 1.01 }).collect();
        assert!(fp.edge_partners(&small, 10).iter().all(Option::is_none));
        let gap: Vec<f64> = (0..10)
            .map(|i| if i < 5 { 1.0 } else { f64::NAN })
            .collect();
        assert!(fp.edge_partners(&gap, 10).iter().all(Option::is_none));
        // Columns too: a 2 × 3 image whose lower row is far.
        let img = [1.0, 1.0, 1.0, 2.0, 2.0, 2.0];
        let p = fp.edge_partners(&img, 3);
        assert_eq!(
            p,
            vec![Some(3), Some(4), Some(5), Some(0), Some(1), Some(2)]
        );
    }

    #[test]
    fn sigma_wiggle_and_bands() {
        let c = CameraNoise {
            sigma_range_exponent: 2.0,
            sigma_reference_range_m: 2.0,
            wiggle: Some(Wiggle {
                amplitude_m: 0.01,
                period_m: 1.5,
                phase_rad: 0.3,
                random_phase: false,
            }),
            multipath_bands: vec![
                MultipathBand {
                    near_m: 1.0,
                    far_m: 2.0,
                    extra_m: 0.05,
                },
                MultipathBand {
                    near_m: 1.5,
                    far_m: 3.0,
                    extra_m: 0.01,
                },
            ],
            ..CameraNoise::default()
        };
        assert_eq!(c.sigma_at(0.02, 4.0), 0.08);
        assert_eq!(CameraNoise::default().sigma_at(0.02, 4.0), 0.02);
        assert_eq!(c.multipath_extra(0.99), 0.0);
        assert_eq!(c.multipath_extra(1.0), 0.05);
        assert_eq!(c.multipath_extra(1.7), 0.05 + 0.01);
        assert_eq!(c.multipath_extra(3.0), 0.01);
        let w = 0.01 * (TAU * 1.2 / 1.5 + 0.3).sin();
        assert!((c.systematic(1.2, 0.3) - (w + 0.05)).abs() < 1e-15);
        assert_eq!(c.wiggle_phase(FrameSeed::default()), 0.3);
        let r = CameraNoise {
            wiggle: Some(Wiggle {
                random_phase: true,
                ..Wiggle::helios2()
            }),
            ..CameraNoise::default()
        };
        let s = FrameSeed::default();
        assert_eq!(r.wiggle_phase(s), r.wiggle_phase(s));
        assert_ne!(
            r.wiggle_phase(s),
            r.wiggle_phase(FrameSeed { trial: 1, ..s })
        );
    }

    #[test]
    fn validation_names_the_field() {
        let field = |c: CameraNoise, n: Noise| match c.validate(&n).unwrap_err() {
            SimError::Invalid { field, .. } => field,
            e => panic!("{e}"),
        };
        let n = Noise::range(0.01);
        let d = CameraNoise::default();
        d.validate(&n).unwrap();
        let cases = [
            (
                CameraNoise {
                    correlation_length_px: -1.0,
                    ..d.clone()
                },
                n,
                "noise.correlation_length_px",
            ),
            (
                CameraNoise {
                    correlation_length_px: f64::NAN,
                    ..d.clone()
                },
                n,
                "noise.correlation_length_px",
            ),
            (
                CameraNoise {
                    correlation_length_px: 2.0,
                    ..d.clone()
                },
                Noise {
                    model: NoiseModel::Isotropic,
                    ..n
                },
                "noise.correlation_length_px",
            ),
            (
                CameraNoise {
                    sigma_range_exponent: -0.5,
                    ..d.clone()
                },
                n,
                "noise.sigma_range_exponent",
            ),
            (
                CameraNoise {
                    sigma_range_exponent: 1.0,
                    ..d.clone()
                },
                Noise {
                    physics: Some(crate::ToFPhysics::helios2()),
                    ..n
                },
                "noise.sigma_range_exponent",
            ),
            (
                CameraNoise {
                    sigma_reference_range_m: 0.0,
                    ..d.clone()
                },
                n,
                "noise.sigma_reference_range_m",
            ),
            (
                CameraNoise {
                    wiggle: Some(Wiggle {
                        period_m: 0.0,
                        ..Wiggle::helios2()
                    }),
                    ..d.clone()
                },
                n,
                "noise.wiggle.period_m",
            ),
            (
                CameraNoise {
                    wiggle: Some(Wiggle {
                        amplitude_m: f64::NAN,
                        ..Wiggle::helios2()
                    }),
                    ..d.clone()
                },
                n,
                "noise.wiggle.amplitude_m",
            ),
            (
                CameraNoise {
                    multipath_bands: vec![MultipathBand {
                        near_m: 2.0,
                        far_m: 1.0,
                        extra_m: 0.1,
                    }],
                    ..d.clone()
                },
                n,
                "noise.multipath_bands.far_m",
            ),
            (
                CameraNoise {
                    multipath_bands: vec![MultipathBand {
                        near_m: 1.0,
                        far_m: 2.0,
                        extra_m: -0.1,
                    }],
                    ..d.clone()
                },
                n,
                "noise.multipath_bands.extra_m",
            ),
            (
                CameraNoise {
                    flying_pixels: Some(FlyingPixels {
                        probability: 1.5,
                        ..FlyingPixels::new(0.5)
                    }),
                    ..d.clone()
                },
                n,
                "noise.flying_pixels.probability",
            ),
            (
                CameraNoise {
                    flying_pixels: Some(FlyingPixels {
                        edge_ratio: 0.5,
                        ..FlyingPixels::new(0.5)
                    }),
                    ..d.clone()
                },
                n,
                "noise.flying_pixels.edge_ratio",
            ),
            (
                CameraNoise {
                    flying_pixels: Some(FlyingPixels {
                        edge_jump_m: -1.0,
                        ..FlyingPixels::new(0.5)
                    }),
                    ..d.clone()
                },
                n,
                "noise.flying_pixels.edge_jump_m",
            ),
        ];
        for (c, n, f) in cases {
            assert_eq!(field(c, n), f);
        }
    }
}
