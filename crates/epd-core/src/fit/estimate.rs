//! The estimators C-EPD, RU-EPD and ML-EPD: one call from a point cloud to a canonical
//! β with its status, fit quality and 1-σ uncertainty.

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

use crate::check::{
    Diagnostics, FitStatus, Implausible, MAX_ASSESSED, MIN_UNCERTAINTY_DOF, assess,
};
use crate::cloud::{CleanWeighted, check_ranges, clean, clean_weighted, far, usable};
use crate::error::EpdError;
pub use crate::fit::bound::{
    cramer_rao_bound, cramer_rao_bound_weighted, rms_range_residual, rms_range_residual_of,
};
pub use crate::fit::covariance::{AXIAL_CELLS, AxisCov, CLOCK_SECTORS};
pub(crate) use crate::fit::covariance::{CELL_EDGE_POINTS, SliceShift, uncertainty, wall_cells};
use crate::fit::form::{
    DIAMETER_SHIFT_FRACTION, FORM_AXIAL_CELLS, FORM_POINTS, FormMisfit, WallCells,
    normal_upper_quantile,
};
pub use crate::fit::options::{EstimateOptions, LossScale, Method};
use crate::init::{MAX_SAMPLE, initial_guess};
use crate::lm::{LmReport, NormalEquations, minimize};
use crate::loss::Loss;
use crate::params::{N_PARAMS, Params};
use crate::points::{Mask, Points};
use crate::problem::PipeFit;
use crate::residual::{Geometry, Residual};
use crate::symmetry::{Applied, canonical_form, canonicalize};
use crate::uncertainty::{SharedOffset, slice_offset_scores};

/// A 1-σ standard deviation per parameter of eq. (2) (m, rad); `None` where the data do
/// not determine the parameter (e.g. the roll of a circular pipe).
pub type Sigmas = [Option<f64>; N_PARAMS];

/// The result of one estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// The method used.
    pub method: Method,
    /// The estimated β in canonical form (README, Conventions: Dmax ≥ Dmin, roll in
    /// [−90°, 90°)).
    pub params: Params,
    /// The solver's starting point: the data-only start, or the one given
    /// ([`EstimateOptions::with_start`]).
    pub initial: Params,
    /// Why the final solver stage stopped, overruled by `implausible` when the result
    /// disagrees with the data (see [`crate::check`]).
    pub status: FitStatus,
    /// How the result agrees with the points; `None` when it left the model.
    pub diagnostics: Option<Diagnostics>,
    /// Solver iterations over all stages.
    pub iterations: usize,
    /// Final cost over all points: F(β) of eq. (4), or Σ 2ρ(rᵢ) under a robust loss
    /// (residual units squared).
    pub cost: f64,
    /// √(Σ rᵢ²/N): the RMS residual, whatever the loss (m for RU-EPD and ML-EPD,
    /// dimensionless for C-EPD; of the scaled residuals sᵢrᵢ for
    /// [`estimate_weighted`]); under a robust loss taken over at most 16 384 evenly
    /// strided points.
    pub rms_residual: f64,
    /// Points used.
    pub n_points: usize,
    /// Points dropped (non-finite or at the origin; for [`estimate_weighted`] also those
    /// whose σᵢ is not finite or not > 0).
    pub n_dropped: usize,
    /// Usable points left out by the range gate (0 without one).
    pub n_out_of_gate: usize,
    /// The loss as applied, its scale in the method's residual units.
    pub loss: Loss,
    /// 1-σ of each parameter, for every loss the cluster-robust sandwich
    /// c·H⁻¹·B·H⁻¹ with H = Σ w_H JᵢJᵢᵀ (the loss's exact curvature w_H, negative past
    /// a redescending loss's knee: [`crate::problem::Curvature`]), B = Σ_g s_g s_gᵀ the spread of the scores
    /// s_g = Σ_{i∈g} w_g(rᵢ)rᵢJᵢ of the wall's cells g ([`AXIAL_CELLS`] × [`CLOCK_SECTORS`])
    /// and c = G/(G − 1)·(N − 1)/(N − p) (p the fitted parameters: 7, or 5 with the
    /// diameters held); σ̂²·(JᵀJ)⁻¹ when there are too few cells. With weights, of the
    /// scaled rᵢ and Jᵢ. `None` for held diameters.
    pub sigma: Sigmas,
    /// Whether the wall's axial slices differ more than their cells do (Welch's test,
    /// `WallCells::shared_along_axis`, at `form::SHARED_ERROR_ALPHA`): errors shared along
    /// the pipe, or a wall that departs from the straight model somewhere along it (the
    /// survey then also looks from the near section: `segment::segment`).
    pub shared_along_axis: bool,
    /// Whether the roll is determined: the ovality is significant (Dmax − Dmin above
    /// three of its standard deviations) and the roll's 1-σ is below 45°.
    pub roll_determined: bool,
    /// The covariance (m²) of (Dmax, Dmin), from the same sandwich as `sigma` (without
    /// their correlation when the full covariance is undetermined); `None` for held
    /// diameters.
    pub diameter_cov: Option<[[f64; 2]; 2]>,
    /// The covariance of where the fitted axis lies across the pipe, as a function of the
    /// distance along it ([`AxisCov`]); `None` without a full covariance.
    pub axis_cov: Option<AxisCov>,
}

impl Estimate {
    /// The mean diameter (Dmax + Dmin)/2 (m): what a near-round pipe is measured by, free
    /// of the order Dmax ≥ Dmin imposes.
    pub fn d_mean(&self) -> f64 {
        0.5 * (self.params.d_max + self.params.d_min)
    }

    /// The 1-σ of [`d_mean`](Self::d_mean) (m): √(c₀₀ + c₁₁ + 2c₀₁)/2.
    pub fn sigma_d_mean(&self) -> Option<f64> {
        let c = self.diameter_cov?;
        Some((0.25 * (c[0][0] + c[1][1] + 2.0 * c[0][1])).max(0.0).sqrt())
    }

    /// The ovality (Dmax − Dmin)/Dmean (the simulator's and API 5L's out-of-roundness
    /// over the mean diameter; dimensionless).
    pub fn ovality(&self) -> f64 {
        (self.params.d_max - self.params.d_min) / self.d_mean()
    }

    /// The 1-σ of [`ovality`](Self::ovality), by the delta method on (Dmax, Dmin).
    pub fn sigma_ovality(&self) -> Option<f64> {
        let c = self.diameter_cov?;
        let (a, b, m) = (self.params.d_max, self.params.d_min, self.d_mean());
        let ga = 1.0 / m - (a - b) / (2.0 * m * m);
        let gb = -1.0 / m - (a - b) / (2.0 * m * m);
        Some(
            (ga * ga * c[0][0] + gb * gb * c[1][1] + 2.0 * ga * gb * c[0][1])
                .max(0.0)
                .sqrt(),
        )
    }
}

/// Estimate β from measured points (SCS, m) with `method`.
///
/// Non-finite points and points at the origin are dropped and counted; points farther
/// than [`MAX_POINT_RANGE_M`](crate::cloud::MAX_POINT_RANGE_M) from the sensor are an
/// error ([`EpdError::FarPoints`]). The fit starts
/// from [`initial_guess`] (or from [`EstimateOptions::with_start`]'s β, without the
/// subsample stage); with more than `stage_points` points it first converges on a
/// strided subsample, then iterates on all points. ML-EPD starts from the RU-EPD
/// estimate: its cost has poles where the model axis crosses a measured ray, and started
/// cold it can settle in a wrong basin. With a range gate
/// ([`EstimateOptions::with_range_gate`]) the points are selected by their model range.
/// With held diameters ([`EstimateOptions::with_fixed_diameters`]) only the pose is
/// fitted. The status is `converged` only when the result is also consistent with the
/// points ([`crate::check`]).
pub fn estimate(
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
) -> Result<Estimate, EpdError> {
    check_ranges(points)?;
    let cloud = clean(points);
    let view = View {
        points: Points::all(&cloud.points),
        scales: None,
    };
    estimate_view(view, cloud.dropped, method, options)
}

/// [`estimate`] of the points of `points` that `mask` keeps, read in place: the result
/// of [`estimate`] on their copy, to the bit (the fit reads them in the same order, in
/// the same chunks; [`crate::points`]), without the copy's 24 bytes per kept point — a
/// refit of the straight pipe before a bend holds one bit per point of the frame
/// beside it (issue 27). A mask made for a slice of another length is an
/// [`EpdError::InvalidOption`].
pub fn estimate_masked(
    points: &[[f64; 3]],
    mask: &Mask,
    method: Method,
    options: &EstimateOptions,
) -> Result<Estimate, EpdError> {
    let kept = Points::masked(points, mask).ok_or_else(|| {
        EpdError::InvalidOption(format!(
            "a mask for another number of points than the {} given",
            points.len()
        ))
    })?;
    if kept.iter().any(|p| !usable(p) || far(p)) {
        // Points to drop or to refuse: the copy's path, whose counts and error name the
        // points by their place among the kept ones.
        let copy: Vec<[f64; 3]> = kept.iter().copied().collect();
        return estimate(&copy, method, options);
    }
    let view = View {
        points: kept,
        scales: None,
    };
    estimate_view(view, 0, method, options)
}

/// [`estimate`] with a range-noise standard deviation σᵢ (m) per point: the
/// heteroscedastic weighted fit.
///
/// Each residual rᵢ and its gradient gᵢ enter eq. (4) as sᵢ·rᵢ and sᵢ·gᵢ with
/// sᵢ = σ̃/σᵢ, σ̃ the median σᵢ of the points used, so F = Σ (sᵢrᵢ)² keeps the residual
/// units (m for RU/ML-EPD) and a robust loss's scale keeps its meaning. For ML-EPD,
/// whose residual is the range error along the ray, this is the maximum likelihood
/// under independent N(0, σᵢ²) range noise; RU-EPD and C-EPD weight their own residuals
/// the same way. The weights travel with the points through the cleaning, the range
/// gate, the subsample stage, the data-scaled loss (1.4826·median|sᵢrᵢ|) and the
/// covariance: σ̂²·(J̃ᵀJ̃)⁻¹ with J̃ the scaled Jacobian and σ̂² = F̃/(N − p), p the
/// fitted parameters (the plausibility check of [`crate::check`] is unweighted).
/// Equal σᵢ give exactly [`estimate`]'s result.
///
/// Points whose σᵢ is not finite or not > 0 are dropped with the point and counted in
/// `n_dropped`. `sigma.len() != points.len()` is an [`EpdError::InvalidOption`].
pub fn estimate_weighted(
    points: &[[f64; 3]],
    sigma: &[f64],
    method: Method,
    options: &EstimateOptions,
) -> Result<Estimate, EpdError> {
    if sigma.len() != points.len() {
        return Err(EpdError::InvalidOption(format!(
            "{} range standard deviations for {} points: need one per point",
            sigma.len(),
            points.len()
        )));
    }
    check_ranges(points)?;
    let (cloud, scales, _) = weighted_cloud(points, sigma);
    let view = View {
        points: Points::all(&cloud.points),
        scales: Some(&scales),
    };
    estimate_view(view, cloud.dropped, method, options)
}

/// The usable pairs of `points` and `sigma` and their scales sᵢ = σ̃/σᵢ with σ̃ the
/// median of the kept σᵢ (of an even subsample of at most `TYPICAL_SIGMA_POINTS` of
/// them: σ̃ only sets the units of the scaled residuals), returned beside them.
pub(crate) fn weighted_cloud(points: &[[f64; 3]], sigma: &[f64]) -> (CleanWeighted, Vec<f64>, f64) {
    let cloud = clean_weighted(points, sigma);
    let stride = cloud.sigma.len().div_ceil(TYPICAL_SIGMA_POINTS).max(1);
    let mut sorted: Vec<f64> = cloud.sigma.iter().step_by(stride).copied().collect();
    let typical = crate::check::quantile(&mut sorted, 0.5);
    let scales = cloud.sigma.par_iter().map(|s| typical / s).collect();
    (cloud, scales, typical)
}

/// Points (SCS, m; finite, non-zero), read in place ([`Points`]: all of a slice or those a
/// mask keeps), with their optional scales sᵢ (one per point read, in the points' numbering).
#[derive(Clone, Copy, Debug)]
pub(crate) struct View<'a> {
    pub(crate) points: Points<'a>,
    pub(crate) scales: Option<&'a [f64]>,
}

/// Most σᵢ of the median σ̃ in [`weighted_cloud`].
const TYPICAL_SIGMA_POINTS: usize = 1 << 16;

/// Points of the first fit of a range gate (see [`estimate_view`]).
const GATE_PROBE_POINTS: usize = 32_768;

/// An owned selection of a [`View`], kept aligned.
#[derive(Clone, Debug)]
struct Selection {
    points: Vec<[f64; 3]>,
    scales: Option<Vec<f64>>,
}

impl Selection {
    fn view(&self) -> View<'_> {
        View {
            points: Points::all(&self.points),
            scales: self.scales.as_deref(),
        }
    }
}

impl<'a> View<'a> {
    pub(crate) fn len(&self) -> usize {
        self.points.len()
    }

    /// The scale of point `i` (1 without scales).
    pub(crate) fn scale(&self, i: usize) -> f64 {
        self.scales.map_or(1.0, |s| s[i])
    }

    /// The points for which `keep` holds, with their scales, in their order (the
    /// test runs on all cores).
    fn select(&self, keep: impl Fn(&[f64; 3]) -> bool + Sync) -> Selection {
        let (idx, picked): (Vec<usize>, Vec<[f64; 3]>) = match self.points.as_slice() {
            Some(all) => {
                let idx: Vec<usize> = (0..all.len())
                    .into_par_iter()
                    .filter(|&i| keep(&all[i]))
                    .collect();
                let picked = idx.par_iter().map(|&i| all[i]).collect();
                (idx, picked)
            }
            None => self
                .points
                .iter()
                .enumerate()
                .filter(|(_, p)| keep(p))
                .map(|(i, p)| (i, *p))
                .unzip(),
        };
        Selection {
            points: picked,
            scales: self.scales.map(|s| idx.par_iter().map(|&i| s[i]).collect()),
        }
    }

    /// Every `stride`-th point from the first, with its scale.
    fn strided(&self, stride: usize) -> Selection {
        Selection {
            points: self.points.iter().step_by(stride).copied().collect(),
            scales: self
                .scales
                .map(|s| s.iter().step_by(stride).copied().collect()),
        }
    }

    /// Eq. (4) over these points with `kind`, scaled.
    pub(crate) fn fit(&self, kind: Residual) -> PipeFit<'a> {
        PipeFit::over(self.points, kind).with_scales(self.scales)
    }
}

/// [`estimate`] on clean points with optional scales: the range gate, then the fit.
fn estimate_view(
    cloud: View<'_>,
    n_dropped: usize,
    method: Method,
    options: &EstimateOptions,
) -> Result<Estimate, EpdError> {
    gated(cloud, n_dropped, method, options, |kept, gated, start| {
        fit_cloud(kept, n_dropped, gated, method, options, start)
    })
}

/// β from measured points (SCS, m) as [`estimate`] finds it — the same cleaning, range
/// gate, start and solver stages, the same β to the bit — without what only its 1-σ and
/// its status need: the cluster-robust covariance, the form test that the model fits,
/// and the normal equations at a canonical form the solver did not end in. For a fit
/// whose only use is its β, a step toward another fit (a depth table's incidence rounds
/// take each round's pose to look up the next correction). Its status is the solver's,
/// overruled by the plausibility check ([`crate::check`]); never `lack_of_fit`, which
/// only the form test finds.
pub fn fit_pose(
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
) -> Result<PoseFit, EpdError> {
    check_ranges(points)?;
    let cloud = clean(points);
    let view = View {
        points: Points::all(&cloud.points),
        scales: None,
    };
    let dropped = cloud.dropped;
    gated(view, dropped, method, options, |kept, _, start| {
        let s = solve_cloud(kept, dropped, method, options, start)?;
        Ok(PoseFit {
            params: s.canonical,
            status: FitStatus::from_solver(s.rep.status, s.implausible),
            iterations: s.iterations,
            n_points: kept.len(),
        })
    })
}

/// What [`fit_pose`] returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseFit {
    /// β in canonical form, as [`Estimate::params`].
    pub params: Params,
    /// Why the solver stopped, overruled when the result is implausible.
    pub status: FitStatus,
    /// Solver iterations over all stages.
    pub iterations: usize,
    /// Points used (after the cleaning and the range gate).
    pub n_points: usize,
}

impl PoseFit {
    /// The mean diameter (Dmax + Dmin)/2 (m).
    pub fn d_mean(&self) -> f64 {
        0.5 * (self.params.d_max + self.params.d_min)
    }
}

/// The range gate ([`EstimateOptions::with_range_gate`]) of clean points, then `fit` of
/// the points kept, given how many the gate left out and the start: without a gate every
/// point and the options' held start.
fn gated<T>(
    cloud: View<'_>,
    n_dropped: usize,
    method: Method,
    options: &EstimateOptions,
    fit: impl FnOnce(View<'_>, usize, Option<Params>) -> Result<T, EpdError>,
) -> Result<T, EpdError> {
    let Some((lo, hi)) = options.range_gate else {
        return fit(cloud, 0, options.held_start());
    };
    let range = |p: &[f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    // The first fit only chooses the points and the start of the final one: the points
    // of an even subsample (at most GATE_PROBE_POINTS of the cloud) whose measured range
    // is in the gate do (its parameters are within a few of the final fit's standard
    // deviations, far below the gate's resolution).
    let stride = cloud.len().div_ceil(GATE_PROBE_POINTS).max(1);
    let in_gate = |p: &[f64; 3]| (lo..=hi).contains(&range(p));
    let probe = if stride > 1 {
        cloud.strided(stride).view().select(in_gate)
    } else {
        cloud.select(in_gate)
    };
    let first = solve_cloud(
        probe.view(),
        n_dropped,
        method,
        options,
        options.held_start(),
    )?;
    let geom = Geometry::new(&first.canonical).ok_or_else(|| {
        EpdError::Degenerate("the first fit of the range gate left the model".into())
    })?;
    // The model range of a ray: the wall point x0 + t(x̂ − x0) is t·‖p‖ from the sensor.
    let kept = cloud.select(|p| (lo..=hi).contains(&(geom.line_parameter(p) * range(p))));
    let gated = cloud.len() - kept.points.len();
    fit(kept.view(), gated, Some(first.canonical))
}

/// The points (SCS, m; finite, non-zero) whose ray meets the wall of β at a range in
/// [lo, hi] (m): the model range of a ray, t·‖p‖ with t the line parameter of eq. (21),
/// does not depend on the point's own range noise. Empty when β leaves the model.
pub fn gate_by_model_range(points: &[[f64; 3]], beta: &Params, lo: f64, hi: f64) -> Vec<[f64; 3]> {
    let Some(in_gate) = model_range_gate(beta, lo, hi) else {
        return Vec::new();
    };
    points.iter().filter(|p| in_gate(p)).copied().collect()
}

/// The test of [`gate_by_model_range`] for one point: whether its ray meets the wall of
/// β at a range in [lo, hi] (m). `None` when β leaves the model.
pub fn model_range_gate(beta: &Params, lo: f64, hi: f64) -> Option<impl Fn(&[f64; 3]) -> bool> {
    let geom = Geometry::new(beta)?;
    Some(move |p: &[f64; 3]| {
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        (lo..=hi).contains(&(geom.line_parameter(p) * r))
    })
}

/// [`crate::loss::mad_sigma`] (1.4826·median|sᵢrᵢ|) of `kind`'s (scaled) residuals of
/// `pts` at `x`, or `None` outside the model.
fn residual_scale(pts: View<'_>, kind: Residual, x: &SVector<f64, N_PARAMS>) -> Option<f64> {
    let geom = Geometry::new(&Params::from_array((*x).into()))?;
    let stride = pts.len().div_ceil(8192).max(1);
    let mut r: Vec<f64> = pts
        .points
        .iter()
        .enumerate()
        .step_by(stride)
        .map(|(i, p)| (pts.scale(i) * geom.residual(kind, p)).abs())
        .collect();
    let s = crate::loss::mad_sigma(&mut r);
    (s > 0.0 && s.is_finite()).then_some(s)
}

/// The fit of clean points (with their scales, if any), from the initial guess or from
/// `start`: the solver's stages ([`solve_stages`]), the canonical form and its normal
/// equations ([`canonical_equations`]), the 1-σ ([`uncertainty`]), then the check
/// against the points ([`assess`]).
fn fit_cloud(
    cloud: View<'_>,
    n_dropped: usize,
    n_out_of_gate: usize,
    method: Method,
    options: &EstimateOptions,
    start: Option<Params>,
) -> Result<Estimate, EpdError> {
    let Solved {
        fitted,
        rep,
        canonical: _,
        iterations,
        loss,
        init,
        diagnostics,
        implausible,
    } = solve_cloud(cloud, n_dropped, method, options, start)?;
    let n = cloud.len();
    let fixed = options.fixed_mask();
    let kind = method.residual();
    let fit = problem(cloud, kind, loss, fixed);
    let (canonical, eq) = canonical_equations(&fitted, &rep, &fit, options);
    let form_cells = wall_cells(
        &cloud.points.sample(CELL_EDGE_POINTS),
        &canonical,
        FORM_AXIAL_CELLS,
    );
    let wall = WallCells::gather(
        &cloud.points.sample(FORM_POINTS),
        cloud.scales,
        &canonical,
        &form_cells,
    );
    let shared = wall
        .as_ref()
        .and_then(WallCells::shared_along_axis)
        .unwrap_or(false);
    // With an error shared along the pipe, its variance between slices and what each
    // slice's offset does to β (see `uncertainty`).
    let shared_offset = if shared {
        wall.as_ref().and_then(|w| {
            let scores = slice_offset_scores(
                cloud.points,
                cloud.scales,
                kind,
                loss,
                fixed,
                &canonical,
                &form_cells,
                FORM_POINTS,
            )?;
            Some(SharedOffset {
                means: w.slice_means(),
                scores,
            })
        })
    } else {
        None
    };
    // Slices of the wall off the fitted pipe all around (in the form test's 16 axial
    // bins), as bins of the covariance's 8 (each covariance bin is two form bins: both
    // grids' edges are the same quantiles of the same points).
    let misfit_slices = wall
        .as_ref()
        .map(WallCells::misfit_slices)
        .unwrap_or_default();
    let mut off: Vec<usize> = misfit_slices
        .iter()
        .map(|(k, _)| k / (FORM_AXIAL_CELLS / AXIAL_CELLS))
        .collect();
    off.sort_unstable();
    off.dedup();
    let (sigma, diameter_cov, roll_determined, raw_cost, shift, axis_cov) = uncertainty(
        cloud,
        kind,
        loss,
        fixed,
        &canonical,
        &eq,
        options,
        shared_offset.as_ref(),
        &off,
    );
    let mut status = FitStatus::from_solver(rep.status, implausible);
    if status.is_converged()
        && let Some(misfit) = wall
            .as_ref()
            .and_then(WallCells::form_test)
            .or_else(|| shared_misfit(&canonical, misfit_slices.first(), shift))
    {
        status = FitStatus::LackOfFit(misfit);
    }
    Ok(Estimate {
        method,
        params: canonical,
        initial: init,
        status,
        diagnostics,
        iterations,
        cost: eq.cost,
        rms_residual: (raw_cost / n as f64).sqrt(),
        n_points: n,
        n_dropped,
        n_out_of_gate,
        loss,
        sigma,
        shared_along_axis: shared,
        roll_determined,
        diameter_cov,
        axis_cov,
    })
}

/// What the solver's stages reached on a cloud ([`solve_cloud`]), before the 1-σ and the
/// form test: β as the solver left it and in canonical form, and the plausibility check
/// of [`assess`] on the stage points (with too few degrees of freedom for a 1-σ).
struct Solved {
    fitted: Params,
    canonical: Params,
    rep: LmReport<N_PARAMS>,
    iterations: usize,
    loss: Loss,
    init: Params,
    diagnostics: Option<Diagnostics>,
    implausible: Option<Implausible>,
}

/// The solver's part of [`fit_cloud`]: the start (cold or `start`), the stages
/// ([`Stages::solve`]), the canonical form, the plausibility check.
fn solve_cloud(
    cloud: View<'_>,
    n_dropped: usize,
    method: Method,
    options: &EstimateOptions,
    start: Option<Params>,
) -> Result<Solved, EpdError> {
    let n = cloud.len();
    if n < N_PARAMS {
        return Err(EpdError::TooFewPoints {
            usable: n,
            dropped: n_dropped,
            needed: N_PARAMS,
        });
    }
    let fixed = options.fixed_mask();
    let init = match start {
        Some(p) => p,
        None => cold_start(&cloud.points.sample(MAX_SAMPLE), options)?,
    };
    let sub: Selection;
    let stage_pts: View<'_> = if options.stage_points > 0 && n > 2 * options.stage_points {
        let stride = n / options.stage_points;
        sub = cloud.strided(stride);
        sub.view()
    } else {
        cloud
    };
    let stages = Stages {
        cloud,
        stage_pts,
        method,
        options,
        fixed,
        init: &init,
    };
    let (x, rep, iterations, loss) = stages.solve(start.is_some())?;
    let fitted = Params::from_array(x.into());
    let canonical = canonical_params(&fitted, options).0;
    let (diagnostics, implausible) =
        match assess(&stage_pts.points.sample(MAX_ASSESSED), &canonical) {
            Ok(d) => (Some(d), d.verdict(&canonical)),
            Err(i) => (None, Some(i)),
        };
    // Too few residual degrees of freedom for a 1-σ: implausible whether or not one is
    // computed (`fit_pose` reports the status `estimate` would).
    let dof = n.saturating_sub(fixed.iter().filter(|&&f| !f).count());
    let implausible = implausible
        .or((dof < MIN_UNCERTAINTY_DOF)
            .then_some(Implausible::TooFewForUncertainty { points: n, dof }));
    Ok(Solved {
        fitted,
        canonical,
        rep,
        iterations,
        loss,
        init,
        diagnostics,
        implausible,
    })
}

/// The level of the test whether slices found off the wall move the diameters
/// (`shared_misfit`): it is asked only of frames whose slices already failed the slice
/// form test at [`crate::fit::form::LACK_OF_FIT_ALPHA`], so a frame whose errors are independent is refused
/// by it at a rate below 10⁻³ whatever this level; this level is the rate at which a frame
/// with a real but harmless shared error (a depth table's residual at the nearest ranges)
/// is refused. Measured on 40 numpy frames with a multipath band
/// (`crates/epd-py/tests/test_independent_frames.py`'s generator): leaving the band's
/// slices out moved the diameters by 2–10 mm with a standard deviation of 0.5–3 mm, z of
/// 2–4: at 10⁻³ most were answered; at 5 % most are refused.
pub const SHIFT_TEST_ALPHA: f64 = 0.05;

/// A frame whose slices lie off the fitted pipe all around fails when leaving them out
/// moves Dmax or Dmin by more than [`DIAMETER_SHIFT_FRACTION`] of the mean diameter,
/// beyond noise: (|Δ_j| − τ_D)/sd(Δ_j) above the two-sided normal quantile at
/// [`SHIFT_TEST_ALPHA`] shared by the two diameters. The misfit reported is the worst
/// slice, with the larger of the two shifts.
fn shared_misfit(
    beta: &Params,
    worst: Option<&(usize, FormMisfit)>,
    shift: Option<SliceShift>,
) -> Option<FormMisfit> {
    let (_, misfit) = worst?;
    let (delta, sd) = shift?;
    let tolerance = DIAMETER_SHIFT_FRACTION * 0.5 * (beta.d_max + beta.d_min);
    let critical = normal_upper_quantile(SHIFT_TEST_ALPHA / 4.0);
    let fails = (0..2).any(|j| (delta[j].abs() - tolerance) > critical * sd[j]);
    fails.then(|| FormMisfit {
        diameter_shift_m: delta[0].abs().max(delta[1].abs()),
        ..*misfit
    })
}

/// The data-only start ([`initial_guess`]); with held diameters, the guess in canonical
/// form (its roll names the major axis) with the held diameters.
fn cold_start(points: &[[f64; 3]], options: &EstimateOptions) -> Result<Params, EpdError> {
    Ok(match options.fixed_diameters {
        None => initial_guess(points)?,
        Some((d_max, d_min)) => Params {
            d_max,
            d_min,
            ..canonicalize(&initial_guess(points)?)
        },
    })
}

/// Eq. (4) over `on` with `kind` and `loss`, the held parameters held.
pub(crate) fn problem<'v>(
    on: View<'v>,
    kind: Residual,
    loss: Loss,
    fixed: [bool; N_PARAMS],
) -> PipeFit<'v> {
    on.fit(kind).with_loss(loss).with_fixed(fixed)
}

/// The solver's stages of one fit: eq. (4) minimised by [`minimize`] on the stage
/// points (a strided subsample of a large cloud, or all of it), then on all points.
struct Stages<'v, 'o> {
    /// All points.
    cloud: View<'v>,
    /// The points of the first stage.
    stage_pts: View<'v>,
    method: Method,
    options: &'o EstimateOptions,
    fixed: [bool; N_PARAMS],
    /// The starting point.
    init: &'o Params,
}

impl Stages<'_, '_> {
    /// The loss in the units of `kind`'s residual: r_c ≈ 2δ/R for a radial error δ at
    /// mean radius R = (Dmax + Dmin)/4 of the start (eq. 6's residual); the range units
    /// of RU-EPD and ML-EPD as given.
    fn fixed_loss(&self, kind: Residual) -> Loss {
        match kind {
            Residual::Canonical => self
                .options
                .loss
                .scaled(8.0 / (self.init.d_max + self.init.d_min)),
            _ => self.options.loss,
        }
    }

    /// Whether the loss is scaled to the data ([`LossScale::Auto`] under a robust loss).
    fn auto(&self) -> bool {
        self.options.loss != Loss::Squared && self.options.loss_scale == LossScale::Auto
    }

    /// The loss scaled to the stage points' residuals at x (falls back to the fixed
    /// scale).
    fn loss_at(&self, kind: Residual, x: &SVector<f64, N_PARAMS>) -> Loss {
        let fixed = self.fixed_loss(kind);
        if !self.auto() {
            return fixed;
        }
        residual_scale(self.stage_pts, kind, x)
            .map(|s| fixed.with_scale(fixed.k95() * s))
            .unwrap_or(fixed)
    }

    /// Run the stages from the start (`warm`: a previous fit, so stage 1 and the refit
    /// are skipped). Returns the solution, the last stage's report, the iterations over
    /// all stages and the final loss.
    fn solve(
        &self,
        warm: bool,
    ) -> Result<(SVector<f64, N_PARAMS>, LmReport<N_PARAMS>, usize, Loss), EpdError> {
        let (options, fixed, stage_pts) = (self.options, self.fixed, self.stage_pts);
        let n = self.cloud.len();
        let mut x = SVector::<f64, N_PARAMS>::from(self.init.to_array());
        let mut iterations = 0;
        // Stage 1 (subsample or all): the method's own residual, RU-EPD first for
        // ML-EPD; skipped when starting from a previous fit.
        let mut stage_residuals = vec![];
        if !warm {
            if self.method == Method::MlEpd {
                stage_residuals.push(Residual::ErrorBased);
            }
            stage_residuals.push(self.method.residual());
        }
        let mut last = None;
        for kind in stage_residuals {
            let rep = minimize(
                &problem(stage_pts, kind, self.fixed_loss(kind), fixed),
                x,
                &options.lm,
            );
            iterations += rep.iterations;
            x = rep.x;
            last = Some(rep);
        }
        // With the loss scaled to the data: the scale is taken at the stage-1 fit and
        // the subsample refitted with it (a scale taken at a poor start is too wide),
        // then taken again for the final stage. Starting from a previous fit, no refit.
        let kind = self.method.residual();
        let auto = self.auto();
        // From a fit of a smaller sample ([`EstimateOptions::with_start_fitted_on`]):
        // first on a strided subsample of twice its points.
        if warm && let Some(m) = options.warm_stage_points(n) {
            let sub = self.cloud.strided(n / m);
            let rep = minimize(
                &problem(sub.view(), kind, self.loss_at(kind, &x), fixed),
                x,
                &options.lm,
            );
            iterations += rep.iterations;
            x = rep.x;
        }
        if auto && !warm && stage_pts.len() != n {
            let rep = minimize(
                &problem(stage_pts, kind, self.loss_at(kind, &x), fixed),
                x,
                &options.lm,
            );
            iterations += rep.iterations;
            x = rep.x;
        }
        let loss = self.loss_at(kind, &x);
        // Stage 2: all points (unless stage 1 already fitted them with this loss), from
        // near the minimum (stage 1's, or a previous fit's): with stretched steps, which
        // save passes over every point where the robust loss's curvature is too high.
        if stage_pts.len() != n || last.is_none() || auto {
            let lm = options.lm.with_stretched_steps(true);
            let rep = minimize(&problem(self.cloud, kind, loss, fixed), x, &lm);
            iterations += rep.iterations;
            x = rep.x;
            last = Some(rep);
        }
        let Some(rep) = last else {
            return Err(EpdError::Degenerate("no solver stage ran".into()));
        };
        Ok((x, rep, iterations, loss))
    }
}

/// The canonical form of the fitted β ([`canonical_form`]) and the turns applied; held
/// diameters are restated exactly.
fn canonical_params(fitted: &Params, options: &EstimateOptions) -> (Params, Applied) {
    let (mut canonical, applied) = canonical_form(fitted);
    if let Some((d_max, d_min)) = options.fixed_diameters {
        // The solver's steps in held diameters are exactly zero, and Dmax ≥ Dmin, so the
        // 90° turn (which swaps them) is never applied and the flip and the end-for-end
        // turn keep them: this only states what already holds bit for bit.
        debug_assert!(!applied.turned && fitted.d_max == d_max && fitted.d_min == d_min);
        canonical.d_max = d_max;
        canonical.d_min = d_min;
    }
    (canonical, applied)
}

/// The canonical form of the fitted β ([`canonical_params`]) and the normal equations
/// of `fit` there: a 180° turn only flips the signs of (pitch, yaw, δy, δz) in the last
/// stage's equations; a 90° turn or the end-for-end turn re-expresses the pose, so the
/// equations are evaluated afresh.
fn canonical_equations(
    fitted: &Params,
    rep: &LmReport<N_PARAMS>,
    fit: &PipeFit<'_>,
    options: &EstimateOptions,
) -> (Params, NormalEquations<N_PARAMS>) {
    let (canonical, applied) = canonical_params(fitted, options);
    let eq = if applied.turned || applied.reversed {
        fit.equations_at(&canonical).unwrap_or(rep.equations)
    } else {
        let mut e = rep.equations;
        if applied.flipped {
            let s = SVector::<f64, N_PARAMS>::from([1.0, 1.0, 1.0, -1.0, -1.0, -1.0, -1.0]);
            e.jtj = SMatrix::from_fn(|i, j| e.jtj[(i, j)] * s[i] * s[j]);
            e.jtr = e.jtr.component_mul(&s);
        }
        e
    };
    (canonical, eq)
}
