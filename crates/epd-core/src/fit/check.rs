//! Whether a fitted β is consistent with the points it was fitted to.
//!
//! A solver's convergence test says only that the cost stopped falling. C-EPD's cost
//! (eq. 6) is scaled by the model's own size, so it falls towards zero along a family
//! of ever larger ellipses whose edge passes by the points: on tilted, noisy clouds the
//! solver can walk off to diameters of 10⁹ mm and stop there "converged". Other fits
//! settle in a wrong basin (a wrong tilt with a wrong diameter). Neither may be reported
//! as a result. [`assess`] measures, on a subsample of the points, what any fitted pipe
//! must satisfy, and [`Diagnostics::verdict`] turns the measures into a verdict:
//!
//! - the sensor lies inside the fitted pipe and the pipe runs ahead of it (the angle
//!   between the pipe axis and the sensor's X axis below [`MAX_TILT_DEG`]);
//! - the cloud's extent across the fitted axis matches the fitted diameters: a camera
//!   inside a pipe sees the wall all round, so the span of the points' PCS y (z)
//!   coordinates, between their 1 % and 99 % quantiles, lies within
//!   [[`MIN_SPAN_RATIO`], [`MAX_SPAN_RATIO`]] of Dmax (Dmin), widened by the noise;
//! - the points' displacements across the axis, r_d (RU-EPD's residual: the range error
//!   projected on the cross-section, m), have a robust scale 1.4826·median|r_d| below
//!   [`MAX_NOISE_TO_RADIUS`] of the mean radius: a pipe whose cross-section is blurred by
//!   more than that is not measured by the frame. Range noise along rays that graze the
//!   wall moves the points mostly along the axis: the range residuals' own scale s says
//!   nothing about the cross-section there (an 8" pipe under σ = 0.05 m of range noise
//!   has s = 0.54 radius and a cross-section scatter of about a fifth of it);
//! - no region of the wall is systematically missed: around the axis, in
//!   [`SECTORS`] sectors, the median range residual of each sector stays within
//!   [`MAX_SECTOR_MEDIAN`]·s + [`SECTOR_SAMPLING`]·s/√n (n the sector's points). A fit with a wrong tilt
//!   or in a wrong basin leaves whole sectors on one side of the wall.

use crate::fit::form::FormMisfit;
use crate::lm::{Convergence, DegenerateReason, Status};
use crate::params::Params;
use crate::residual::{Geometry, Residual};

/// Largest angle between the pipe axis and the sensor's optical (X) axis for a camera
/// looking along a pipe (deg). A plausibility bound, not a statistic: a robot's camera
/// looks along the pipe (the paper's poses tilt at most 7°: pitch and yaw within ±5°);
/// at 60° the axis runs across the view and the far wall, which fixes the axis, is out
/// of a 69° × 51° field of view, so such a fit stands on the near wall alone.
pub const MAX_TILT_DEG: f64 = 60.0;
/// Smallest ratio of the cloud's lateral span (1st to 99th percentile across the axis)
/// to the fitted diameter: a wall seen from inside spans its whole diameter on both
/// cross-section axes unless half of it is out of view; a fitted diameter twice the
/// points' extent is extrapolated, not measured.
pub const MIN_SPAN_RATIO: f64 = 0.5;
/// Largest ratio of the cloud's lateral span to the fitted diameter (plus
/// [`SPAN_NOISE_ALLOWANCE`]·s/D): points 50 % beyond the wall are not of this pipe.
pub const MAX_SPAN_RATIO: f64 = 1.5;
/// How far noise of scale s widens the 1st–99th percentile span, in units of s: each end
/// moves out by up to z₀.₉₉ = 2.33 s, so 4.65 s at both ends, and 8 s leaves 3.3 s for
/// the percentiles' own sampling error.
pub const SPAN_NOISE_ALLOWANCE: f64 = 8.0;
/// Largest robust scale of the points' displacements across the axis (the range
/// residuals projected on the cross-section, [`Residual::ErrorBased`]), as a fraction of
/// the mean radius: with a cross-section scatter of half the radius the wall's points
/// fill the whole cross-section (±2 scales span two radii), so the points no longer show
/// where the wall is. A plausibility bound, not a statistic: a real camera in a pipe is
/// ten to a hundred times below it. The range residuals' scale would not do: range noise
/// on rays that graze the wall displaces the points along the axis, not across it.
pub const MAX_NOISE_TO_RADIUS: f64 = 0.5;
/// Angular sectors around the axis for the lack-of-fit test: a wrong tilt or basin
/// leaves a side of the wall off the fit, a half or a quarter of it; eight sectors of
/// 45° resolve a quarter, and leave each sector 512 of the 4096 points assessed (see
/// `MAX_ASSESSED`).
pub const SECTORS: usize = 8;
/// Largest |median residual| of a sector, in units of s (beyond the sampling term): a
/// whole sector one noise scale off the wall is a wrong tilt or basin, not noise.
pub const MAX_SECTOR_MEDIAN: f64 = 1.0;
/// The sector median's sampling allowance, in standard errors: the median of n
/// independent residuals of scale s has standard error √(π/2)·s/√n = 1.2533·s/√n, and the
/// allowance [`SECTOR_SAMPLING`]·s/√n = 5·s/√n is 5/1.2533 = 3.99 of them — a one-sided
/// false alarm of 3.3·10⁻⁵ per sector, 2.6·10⁻⁴ per frame over [`SECTORS`] sectors, for
/// independent noise.
pub const SECTOR_SAMPLING: f64 = 5.0;
/// Fewest points a sector needs to be tested: at n = 32 the median's standard error is
/// 1.2533/√32 = 0.22 s, so a misfit of [`MAX_SECTOR_MEDIAN`] = 1 s is 4.5 standard
/// errors; fewer points (the far wall seen edge-on) cannot resolve it.
pub const MIN_SECTOR_POINTS: usize = 32;

/// An inlier's range residual is within this many robust scales s of the wall: for
/// normal noise |z| ≤ 3.29 holds for 99.9 % of the points, so the spans of the inliers are
/// those of the wall, and a far outlier (a return from anywhere along its ray) is left
/// out unless it falls within 3.29 s of the wall.
pub const INLIER_SCALES: f64 = 3.29;

/// At most this many points (evenly strided) are assessed: the statistics above then
/// cost O(4096) whatever the frame, and their standard errors are those of 4096 points
/// (a sector of 512 points resolves 1.2533·5/√512 = 0.28 s).
pub(crate) const MAX_ASSESSED: usize = 4096;

/// Measures of how a fitted β agrees with its points (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diagnostics {
    /// Angle between the fitted pipe axis and the sensor's X axis (rad).
    pub tilt: f64,
    /// Span of the points' PCS y between the 1 % and 99 % quantiles, over Dmax.
    pub span_ratio_major: f64,
    /// The same for z over Dmin.
    pub span_ratio_minor: f64,
    /// Robust scale of the range residuals, 1.4826·median|r_m| (m).
    pub residual_scale: f64,
    /// Robust scale of the displacements across the axis, 1.4826·median|r_d| (m): the
    /// range residuals projected on the cross-section ([`Residual::ErrorBased`]).
    pub cross_section_scale: f64,
    /// Largest |median range residual| of a sector, minus the sampling term 5·s/√n,
    /// in units of s.
    pub sector_misfit: f64,
    /// Points assessed.
    pub n_assessed: usize,
    /// The [`SECTORS`] sectors around the axis holding at least [`MIN_SECTOR_POINTS`] of
    /// the points assessed: all of them for a camera that sees the wall all round.
    pub sectors_seen: usize,
}

/// Why an estimate is not believed although the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum Implausible {
    /// A parameter is not finite, a diameter not positive, or the sensor lies outside
    /// the fitted pipe.
    OutsideModel,
    /// The pipe axis is not ahead of the sensor (tilt in rad).
    AxisNotAhead {
        /// The angle between the fitted axis and the sensor's X axis (rad).
        tilt: f64,
    },
    /// Too little of the wall is in view to measure the pipe: the points lie in some of
    /// the sectors around the axis only, and span less than [`MIN_SPAN_RATIO`] of a
    /// fitted diameter across it, which is then extrapolated, not measured.
    PartialView {
        /// 0 for Dmax, 1 for Dmin.
        axis: usize,
        /// The fitted diameter (m).
        diameter: f64,
        /// The points' span across the axis along that diameter (m).
        span: f64,
        /// The sectors holding points ([`Diagnostics::sectors_seen`]).
        sectors_seen: usize,
    },
    /// The fitted diameter does not match the cloud's extent across the axis.
    DiameterVsExtent {
        /// 0 for Dmax, 1 for Dmin.
        axis: usize,
        /// The fitted diameter (m).
        diameter: f64,
        /// The cloud's span (m).
        span: f64,
    },
    /// The points' scatter across the axis is too large for the fitted radius to be
    /// measured.
    NoiseVsRadius {
        /// Robust scale of the displacements across the axis (m)
        /// ([`Diagnostics::cross_section_scale`]).
        scale: f64,
        /// Mean fitted radius (m).
        radius: f64,
    },
    /// A region of the wall lies systematically off the fitted surface.
    LackOfFit {
        /// The worst sector's excess |median| in units of the residual scale.
        misfit: f64,
    },
    /// Too few points for a 1-σ: their residual degrees of freedom ν = N − p are below
    /// [`MIN_UNCERTAINTY_DOF`].
    TooFewForUncertainty {
        /// Points used.
        points: usize,
        /// ν = points − free parameters.
        dof: usize,
    },
}

/// The fewest residual degrees of freedom ν = N − p with which an estimate is given a
/// 1-σ, and so answered: the error of a least-squares estimate over its estimated σ is
/// Student's t with ν degrees of freedom, which has a finite variance only for ν ≥ 3
/// (Var = ν/(ν − 2)); below, a reported σ is no scale of the error at all. Measured
/// (`cargo run --release -p epd-frame --example small_clouds`, 300 random subsets of
/// full frames per size): at N = 9 (ν = 2) 13 converged answers were more than 5σ̂ off,
/// even with the small-sample factor; at N = 10 (ν = 3), 2 (0.7 %).
pub const MIN_UNCERTAINTY_DOF: usize = 3;

impl std::fmt::Display for Implausible {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Implausible::OutsideModel => f.write_str(
                "the fit left the model (non-finite or non-positive diameters, or the sensor outside the fitted pipe)",
            ),
            Implausible::AxisNotAhead { tilt } => write!(
                f,
                "the fitted pipe axis is {:.1}° from the sensor's X axis (more than {MAX_TILT_DEG}°): \
                 the camera does not look along this pipe, or the cloud's axes are not the sensor \
                 frame's (X forward): a camera's optical frame has Z forward, and a cloud already in \
                 the sensor frame must not be converted from it",
                tilt.to_degrees()
            ),
            Implausible::PartialView {
                axis,
                diameter,
                span,
                sectors_seen,
            } => write!(
                f,
                "too little of the wall is in view to measure the pipe: the points lie in \
                 {sectors_seen} of the {SECTORS} sectors around the axis and span {:.1} mm \
                 across it, under half the fitted {} {:.1} mm, which is extrapolated (a \
                 partial view: a fitting close ahead, an obstruction, the sensor near the \
                 wall); a frame with more of the wall in view measures it",
                span * 1e3,
                if axis == 0 { "Dmax" } else { "Dmin" },
                diameter * 1e3,
            ),
            Implausible::DiameterVsExtent {
                axis,
                diameter,
                span,
            } => write!(
                f,
                "the fitted {} {:.1} mm does not match the cloud's extent across the axis ({:.1} mm): \
                 the fit diverged",
                if axis == 0 { "Dmax" } else { "Dmin" },
                diameter * 1e3,
                span * 1e3
            ),
            Implausible::NoiseVsRadius { scale, radius } => write!(
                f,
                "the points scatter by {:.1} mm across the pipe about the fitted wall, more than half \
                 its radius ({:.1} mm): the diameters are not determined",
                scale * 1e3,
                radius * 1e3
            ),
            Implausible::LackOfFit { misfit } => write!(
                f,
                "a region of the wall lies systematically off the fitted surface (sector median {:.1} noise \
                 scales beyond tolerance): the fit settled in a wrong pose",
                misfit
            ),
            Implausible::TooFewForUncertainty { points, dof } => write!(
                f,
                "{points} points leave {dof} degrees of freedom beyond the fitted parameters: a 1-σ needs \
                 at least {MIN_UNCERTAINTY_DOF} (below, the error over its estimated σ has no variance); \
                 give more points"
            ),
        }
    }
}

/// The status of an estimate: the solver's reason to stop, overruled by [`Implausible`]
/// when the result disagrees with the data. Only [`FitStatus::Converged`] is a result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FitStatus {
    /// A convergence test held and the result is consistent with the data.
    Converged(Convergence),
    /// The iteration limit was reached first.
    IterationLimit,
    /// The solver found no usable step.
    Degenerate(DegenerateReason),
    /// The solver stopped, but the result disagrees with the data.
    Implausible(Implausible),
    /// The fit is consistent, but a region of the wall lies off the model beyond its
    /// tolerance ([`crate::fit::form::form_test`]): the diameters are not those of an
    /// elliptic cylinder seen whole.
    LackOfFit(FormMisfit),
}

impl FitStatus {
    /// The solver's status, unless the diagnostics overrule it.
    pub fn from_solver(status: Status, implausible: Option<Implausible>) -> Self {
        match (implausible, status) {
            (Some(i), _) => FitStatus::Implausible(i),
            (None, Status::Converged(c)) => FitStatus::Converged(c),
            (None, Status::IterationLimit) => FitStatus::IterationLimit,
            (None, Status::Degenerate(d)) => FitStatus::Degenerate(d),
        }
    }

    /// Which of the five statuses this is, without its reason: what files write.
    pub fn outcome(&self) -> FitOutcome {
        match self {
            FitStatus::Converged(_) => FitOutcome::Converged,
            FitStatus::IterationLimit => FitOutcome::IterationLimit,
            FitStatus::Degenerate(_) => FitOutcome::Degenerate,
            FitStatus::Implausible(_) => FitOutcome::Implausible,
            FitStatus::LackOfFit(_) => FitOutcome::LackOfFit,
        }
    }

    /// A short machine-readable name: [`FitOutcome::name`] of [`outcome`](Self::outcome).
    pub fn name(&self) -> &'static str {
        self.outcome().name()
    }

    /// The reason in words, for reports.
    pub fn reason(&self) -> String {
        match self {
            FitStatus::Converged(c) => Status::Converged(*c).reason().into(),
            FitStatus::IterationLimit => Status::IterationLimit.reason().into(),
            FitStatus::Degenerate(d) => Status::Degenerate(*d).reason().into(),
            FitStatus::Implausible(i) => i.to_string(),
            FitStatus::LackOfFit(m) => m.to_string(),
        }
    }

    /// Whether the estimate is a result: converged and consistent with the data.
    pub fn is_converged(&self) -> bool {
        matches!(self, FitStatus::Converged(_))
    }
}

/// A [`FitStatus`] without its reason: the value of a `status` column or key
/// (`converged`, `iteration_limit`, `degenerate`, `implausible`, `lack_of_fit`), with the feature
/// `serde` serialised as exactly those names. Only [`FitOutcome::Converged`] is a result.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "snake_case")
)]
pub enum FitOutcome {
    /// A convergence test held and the result is consistent with the data.
    Converged,
    /// The iteration limit was reached first.
    IterationLimit,
    /// The solver found no usable step.
    Degenerate,
    /// The solver stopped, but the result disagrees with the data.
    Implausible,
    /// A region of the wall lies off the fitted model beyond tolerance.
    LackOfFit,
}

impl FitOutcome {
    /// Every outcome, in the order above.
    pub const ALL: [FitOutcome; 5] = [
        FitOutcome::Converged,
        FitOutcome::IterationLimit,
        FitOutcome::Degenerate,
        FitOutcome::Implausible,
        FitOutcome::LackOfFit,
    ];

    /// The name written in files: the variant in snake case (the same as serde's).
    pub fn name(self) -> &'static str {
        match self {
            FitOutcome::Converged => "converged",
            FitOutcome::IterationLimit => "iteration_limit",
            FitOutcome::Degenerate => "degenerate",
            FitOutcome::Implausible => "implausible",
            FitOutcome::LackOfFit => "lack_of_fit",
        }
    }
}

impl std::fmt::Display for FitOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Diagnostics {
    /// The first check that fails, or `None` when the fit is consistent with the data.
    pub fn verdict(&self, beta: &Params) -> Option<Implausible> {
        if self.tilt.to_degrees() > MAX_TILT_DEG {
            return Some(Implausible::AxisNotAhead { tilt: self.tilt });
        }
        let s = self.residual_scale;
        let radius = 0.25 * (beta.d_max + beta.d_min);
        for (axis, (ratio, d)) in [
            (self.span_ratio_major, beta.d_max),
            (self.span_ratio_minor, beta.d_min),
        ]
        .into_iter()
        .enumerate()
        {
            let hi = MAX_SPAN_RATIO + SPAN_NOISE_ALLOWANCE * s / d;
            // A span short of the diameter with sectors around the axis empty is a view
            // of part of the wall; with the wall seen all round it is a fit gone off it.
            if ratio < MIN_SPAN_RATIO && self.sectors_seen < SECTORS {
                return Some(Implausible::PartialView {
                    axis,
                    diameter: d,
                    span: ratio * d,
                    sectors_seen: self.sectors_seen,
                });
            }
            if !(ratio >= MIN_SPAN_RATIO && ratio <= hi) {
                return Some(Implausible::DiameterVsExtent {
                    axis,
                    diameter: d,
                    span: ratio * d,
                });
            }
        }
        let cross = self.cross_section_scale;
        if !(cross <= MAX_NOISE_TO_RADIUS * radius) {
            return Some(Implausible::NoiseVsRadius {
                scale: cross,
                radius,
            });
        }
        if !(self.sector_misfit <= MAX_SECTOR_MEDIAN) {
            return Some(Implausible::LackOfFit {
                misfit: self.sector_misfit,
            });
        }
        None
    }
}

/// Measure how β agrees with `points` (SCS, m; finite and non-zero), on at most
/// 4096 evenly strided points. `Err` when β is outside the model.
pub fn assess(points: &[[f64; 3]], beta: &Params) -> Result<Diagnostics, Implausible> {
    let geom = Geometry::new(beta).ok_or(Implausible::OutsideModel)?;
    if points.is_empty() {
        return Err(Implausible::OutsideModel);
    }
    let rot = beta.rotation();
    let m = rot.matrix();
    // The PCS X axis in the SCS is the first row of R; its X component is cos(tilt).
    let tilt = m[(0, 0)].abs().min(1.0).acos();
    let stride = points.len().div_ceil(MAX_ASSESSED).max(1);
    let n = points.len().div_ceil(stride);
    let mut r = Vec::with_capacity(n);
    let mut across = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    let mut zs = Vec::with_capacity(n);
    let mut sector = Vec::with_capacity(n);
    for p in points.iter().step_by(stride) {
        let y = m[(1, 0)] * p[0] + m[(1, 1)] * p[1] + m[(1, 2)] * p[2] + beta.dy;
        let z = m[(2, 0)] * p[0] + m[(2, 1)] * p[1] + m[(2, 2)] * p[2] + beta.dz;
        r.push(geom.residual(Residual::Range, p));
        across.push(geom.residual(Residual::ErrorBased, p).abs());
        ys.push(y);
        zs.push(z);
        sector.push(octant(y, z));
    }
    let mut abs_r: Vec<f64> = r.iter().map(|v| v.abs()).collect();
    let s = crate::loss::mad_sigma(&mut abs_r);
    let cross_section_scale = crate::loss::mad_sigma(&mut across);
    // The spans over the inliers only: far outliers (dust, flying pixels, stray light)
    // lie anywhere along their rays, beyond the wall too, and would widen the span of a
    // good fit.
    let inlier = |k: usize| !(r[k].abs() > INLIER_SCALES * s);
    let mut ys_in: Vec<f64> = (0..r.len()).filter(|&k| inlier(k)).map(|k| ys[k]).collect();
    let mut zs_in: Vec<f64> = (0..r.len()).filter(|&k| inlier(k)).map(|k| zs[k]).collect();
    if ys_in.is_empty() {
        (ys_in, zs_in) = (ys.clone(), zs.clone());
    }
    let span = |v: &mut Vec<f64>| quantile(v, 0.99) - quantile(v, 0.01);
    let span_y = span(&mut ys_in);
    let span_z = span(&mut zs_in);
    // A floor for noise-free clouds, where the medians are rounding (the form test's).
    let s_eff = s.max(crate::fit::form::NOISE_FREE_FLOOR * (beta.d_max + beta.d_min));
    let mut misfit: f64 = 0.0;
    let mut sectors_seen = 0;
    let mut in_sector = Vec::with_capacity(n);
    for k in 0..SECTORS {
        in_sector.clear();
        in_sector.extend(
            r.iter()
                .zip(&sector)
                .filter(|&(_, &sk)| sk == k)
                .map(|(&v, _)| v),
        );
        // Sectors with few points (the far wall seen edge-on) say little.
        if in_sector.len() < MIN_SECTOR_POINTS {
            continue;
        }
        sectors_seen += 1;
        let med = quantile(&mut in_sector, 0.5);
        let sampling = SECTOR_SAMPLING / (in_sector.len() as f64).sqrt();
        misfit = misfit.max(med.abs() / s_eff - sampling);
    }
    Ok(Diagnostics {
        tilt,
        span_ratio_major: span_y / beta.d_max,
        span_ratio_minor: span_z / beta.d_min,
        residual_scale: s,
        cross_section_scale,
        sector_misfit: misfit.max(0.0),
        n_assessed: n,
        sectors_seen,
    })
}

/// The 45° sector around the axis of the PCS point (y, z): by the signs of y and z and
/// whether |y| > |z| (the [`SECTORS`] = 8 sectors, without a trigonometric call).
fn octant(y: f64, z: f64) -> usize {
    usize::from(y < 0.0) * 4 + usize::from(z < 0.0) * 2 + usize::from(y.abs() > z.abs())
}

/// The q-quantile of `v` (reordered in place; nearest rank). NaN for an empty slice.
pub(crate) fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let k = ((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1);
    quantile_rank(v, k)
}

/// The `k`-th smallest of `v` (from 0; reordered in place; total order); `k < v.len()`.
pub(crate) fn quantile_rank(v: &mut [f64], k: usize) -> f64 {
    let (_, x, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    *x
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn truth() -> Params {
        Params {
            d_max: 0.49,
            d_min: 0.48,
            roll: 0.4,
            pitch: 0.1,
            yaw: -0.05,
            dy: 0.03,
            dz: -0.02,
        }
    }

    fn cloud(t: &Params) -> Vec<[f64; 3]> {
        (0..4000)
            .map(|i| {
                let phi = i as f64 * 0.7;
                let x = 0.6 + (i % 53) as f64 * 0.1;
                let w = Point3::new(x, 0.5 * t.d_max * phi.cos(), 0.5 * t.d_min * phi.sin());
                let s = t.pcs_to_scs(&w);
                [s.x, s.y, s.z]
            })
            .collect()
    }

    #[test]
    fn the_truth_is_plausible() {
        let t = truth();
        let d = assess(&cloud(&t), &t).unwrap();
        assert!(d.verdict(&t).is_none(), "{d:?}");
        assert!((d.span_ratio_major - 1.0).abs() < 0.01, "{d:?}");
        assert!(d.residual_scale < 1e-9);
    }

    /// The wall of [`cloud`] with normal noise of `sigma` (m), along each point's ray
    /// (`along_ray`) or across the axis (in the PCS y–z plane).
    fn noisy(t: &Params, sigma: f64, along_ray: bool) -> Vec<[f64; 3]> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        cloud(t)
            .into_iter()
            .map(|p| {
                let e: f64 = StandardNormal.sample(&mut rng);
                if along_ray {
                    let range = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    p.map(|c| c * (1.0 + sigma * e / range))
                } else {
                    let e2: f64 = StandardNormal.sample(&mut rng);
                    let w = t.scs_to_pcs(&Point3::new(p[0], p[1], p[2]));
                    let q = t.pcs_to_scs(&Point3::new(w.x, w.y + sigma * e, w.z + sigma * e2));
                    [q.x, q.y, q.z]
                }
            })
            .collect()
    }

    /// Range noise of 0.8 × the radius on rays that graze the wall (points 0.6–5.8 m
    /// ahead of a 0.245 m radius) moves the points along the axis: their scatter across
    /// it is a tenth of the radius or less, and the pipe is measured. The same scale
    /// across the axis blurs the cross-section and is refused.
    #[test]
    fn noise_is_judged_by_its_scatter_across_the_axis() {
        let t = truth();
        let radius = 0.25 * (t.d_max + t.d_min);
        let along = noisy(&t, 0.8 * radius, true);
        let d = assess(&along, &t).unwrap();
        assert!(d.residual_scale > MAX_NOISE_TO_RADIUS * radius, "{d:?}");
        assert!(d.cross_section_scale < 0.1 * radius, "{d:?}");
        assert!(d.verdict(&t).is_none(), "{d:?}");
        let across = noisy(&t, 0.8 * radius, false);
        let d = assess(&across, &t).unwrap();
        assert!(
            matches!(d.verdict(&t), Some(Implausible::NoiseVsRadius { .. })),
            "{d:?}"
        );
    }

    #[test]
    fn a_huge_pipe_is_refused() {
        let t = truth();
        let pts = cloud(&t);
        let big = Params {
            d_max: 1e3,
            d_min: 0.9e3,
            ..t
        };
        let d = assess(&pts, &big).unwrap();
        assert!(
            matches!(d.verdict(&big), Some(Implausible::DiameterVsExtent { .. })),
            "{d:?}"
        );
    }

    /// Points on a 60° arc of the wall only (as a fitting close ahead or an obstruction
    /// leaves in view): refused as a partial view, not as a diverged fit, and a huge pipe
    /// fitted to the wall seen all round is still a diverged fit.
    #[test]
    fn a_partial_view_is_named_as_such() {
        let t = truth();
        let arc: Vec<[f64; 3]> = (0..4000)
            .map(|i| {
                let phi = (i % 60) as f64 * std::f64::consts::PI / 180.0;
                let x = 0.6 + (i % 53) as f64 * 0.1;
                let w = Point3::new(x, 0.5 * t.d_max * phi.cos(), 0.5 * t.d_min * phi.sin());
                let s = t.pcs_to_scs(&w);
                [s.x, s.y, s.z]
            })
            .collect();
        let d = assess(&arc, &t).unwrap();
        assert!(d.sectors_seen <= 2, "{d:?}");
        let v = d.verdict(&t);
        assert!(matches!(v, Some(Implausible::PartialView { .. })), "{v:?}");
        assert!(v.unwrap().to_string().contains("in view"), "{}", v.unwrap());
        assert_eq!(assess(&cloud(&t), &t).unwrap().sectors_seen, SECTORS);
    }

    #[test]
    fn a_wrong_tilt_is_refused() {
        let t = truth();
        let pts = cloud(&t);
        let wrong = Params {
            pitch: t.pitch + 0.15,
            ..t
        };
        let d = assess(&pts, &wrong).unwrap();
        assert!(d.verdict(&wrong).is_some(), "{d:?}");
    }

    #[test]
    fn a_sideways_axis_is_refused() {
        let t = Params {
            yaw: 1.3,
            ..truth()
        };
        let d = assess(&cloud(&t), &t).unwrap();
        assert!(matches!(
            d.verdict(&t),
            Some(Implausible::AxisNotAhead { .. })
        ));
    }

    #[test]
    fn the_outcome_follows_the_solver_unless_overruled() {
        let conv = Status::Converged(Convergence::StepTolerance);
        let cases = [
            (conv, None, FitOutcome::Converged),
            (Status::IterationLimit, None, FitOutcome::IterationLimit),
            (
                Status::Degenerate(DegenerateReason::NoDescent),
                None,
                FitOutcome::Degenerate,
            ),
            (
                conv,
                Some(Implausible::OutsideModel),
                FitOutcome::Implausible,
            ),
        ];
        for (solver, verdict, outcome) in cases {
            let s = FitStatus::from_solver(solver, verdict);
            assert_eq!(s.outcome(), outcome, "{solver:?} {verdict:?}");
            assert_eq!(s.name(), outcome.name());
            assert_eq!(s.is_converged(), outcome == FitOutcome::Converged);
        }
    }

    #[test]
    fn outside_the_model_is_an_error() {
        let t = Params { dy: 0.3, ..truth() };
        assert_eq!(assess(&cloud(&truth()), &t), Err(Implausible::OutsideModel));
    }

    /// The axis message names both ways a cloud's axes go wrong: an optical-frame cloud
    /// not converted, and a sensor-frame cloud converted as if it were one.
    #[test]
    fn the_axis_message_names_both_frame_mistakes() {
        let m = Implausible::AxisNotAhead { tilt: 1.5 }.to_string();
        assert!(m.contains("85.9°"), "{m}");
        assert!(m.contains("optical frame has Z forward"), "{m}");
        assert!(
            m.contains("already in the sensor frame must not be converted"),
            "{m}"
        );
    }
}
