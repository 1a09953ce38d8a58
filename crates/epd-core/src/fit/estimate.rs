//! The estimators C-EPD, RU-EPD and ML-EPD: one call from a point cloud to a canonical
//! β with its status, fit quality and 1-σ uncertainty.

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

use crate::check::{Diagnostics, FitStatus, Implausible, MIN_UNCERTAINTY_DOF, assess};
use crate::cloud::{CleanWeighted, check_ranges, clean, clean_weighted};
use crate::error::EpdError;
use crate::fit::form::{
    DIAMETER_SHIFT_FRACTION, FORM_AXIAL_CELLS, FORM_POINTS, FormMisfit, WallCells,
    normal_upper_quantile,
};
pub use crate::fit::options::{EstimateOptions, LossScale, Method};
use crate::init::initial_guess;
use crate::lm::{LmReport, NormalEquations, minimize};
use crate::loss::Loss;
use crate::params::{N_PARAMS, Params};
use crate::problem::{Cells, PipeFit, wall_point_pcs};
use crate::residual::{Geometry, Residual};
use crate::symmetry::{canonical_form, canonicalize};
use crate::uncertainty::{
    Mat7, SharedOffset, SliceCheck, covariance, jackknife_covariance, roll_is_determined,
    shared_offset_cov, slice_check, slice_offset_scores, slice_shift,
};

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
    /// c·H⁻¹·B·H⁻¹ with H = Σ w_H JᵢJᵢᵀ, B = Σ_g s_g s_gᵀ the spread of the scores
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
        points: &cloud.points,
        scales: None,
    };
    estimate_view(view, cloud.dropped, method, options)
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
        points: &cloud.points,
        scales: Some(&scales),
    };
    estimate_view(view, cloud.dropped, method, options)
}

/// The usable pairs of `points` and `sigma` and their scales sᵢ = σ̃/σᵢ with σ̃ the
/// median of the kept σᵢ (of an even subsample of at most `TYPICAL_SIGMA_POINTS` of
/// them: σ̃ only sets the units of the scaled residuals), returned beside them.
fn weighted_cloud(points: &[[f64; 3]], sigma: &[f64]) -> (CleanWeighted, Vec<f64>, f64) {
    let cloud = clean_weighted(points, sigma);
    let stride = cloud.sigma.len().div_ceil(TYPICAL_SIGMA_POINTS).max(1);
    let mut sorted: Vec<f64> = cloud.sigma.iter().step_by(stride).copied().collect();
    let typical = crate::check::quantile(&mut sorted, 0.5);
    let scales = cloud.sigma.par_iter().map(|s| typical / s).collect();
    (cloud, scales, typical)
}

/// Points (SCS, m; finite, non-zero) with their optional scales sᵢ (one per point).
#[derive(Clone, Copy, Debug)]
struct View<'a> {
    points: &'a [[f64; 3]],
    scales: Option<&'a [f64]>,
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
            points: &self.points,
            scales: self.scales.as_deref(),
        }
    }
}

impl<'a> View<'a> {
    fn len(&self) -> usize {
        self.points.len()
    }

    /// The scale of point `i` (1 without scales).
    fn scale(&self, i: usize) -> f64 {
        self.scales.map_or(1.0, |s| s[i])
    }

    /// The points for which `keep` holds, with their scales, in their order (the
    /// test runs on all cores).
    fn select(&self, keep: impl Fn(&[f64; 3]) -> bool + Sync) -> Selection {
        let idx: Vec<usize> = (0..self.len())
            .into_par_iter()
            .filter(|&i| keep(&self.points[i]))
            .collect();
        Selection {
            points: idx.par_iter().map(|&i| self.points[i]).collect(),
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
    fn fit(&self, kind: Residual) -> PipeFit<'a> {
        PipeFit::new(self.points, kind).with_scales(self.scales)
    }
}

/// [`estimate`] on clean points with optional scales: the range gate, then the fit.
fn estimate_view(
    cloud: View<'_>,
    n_dropped: usize,
    method: Method,
    options: &EstimateOptions,
) -> Result<Estimate, EpdError> {
    let Some((lo, hi)) = options.range_gate else {
        return fit_cloud(cloud, n_dropped, 0, method, options, options.held_start());
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
    let first = fit_cloud(
        probe.view(),
        n_dropped,
        0,
        method,
        options,
        options.held_start(),
    )?;
    let geom = Geometry::new(&first.params).ok_or_else(|| {
        EpdError::Degenerate("the first fit of the range gate left the model".into())
    })?;
    // The model range of a ray: the wall point x0 + t(x̂ − x0) is t·‖p‖ from the sensor.
    let kept = cloud.select(|p| (lo..=hi).contains(&(geom.line_parameter(p) * range(p))));
    let gated = cloud.len() - kept.points.len();
    fit_cloud(
        kept.view(),
        n_dropped,
        gated,
        method,
        options,
        Some(first.params),
    )
}

/// The points (SCS, m; finite, non-zero) whose ray meets the wall of β at a range in
/// [lo, hi] (m): the model range of a ray, t·‖p‖ with t the line parameter of eq. (21),
/// does not depend on the point's own range noise. Empty when β leaves the model.
pub fn gate_by_model_range(points: &[[f64; 3]], beta: &Params, lo: f64, hi: f64) -> Vec<[f64; 3]> {
    let Some(geom) = Geometry::new(beta) else {
        return Vec::new();
    };
    points
        .iter()
        .filter(|p| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            (lo..=hi).contains(&(geom.line_parameter(p) * r))
        })
        .copied()
        .collect()
}

/// [`crate::loss::mad_sigma`] (1.4826·median|sᵢrᵢ|) of `kind`'s (scaled) residuals of
/// `pts` at `x`, or `None` outside the model.
fn residual_scale(pts: View<'_>, kind: Residual, x: &SVector<f64, N_PARAMS>) -> Option<f64> {
    let geom = Geometry::new(&Params::from_array((*x).into()))?;
    let stride = pts.len().div_ceil(8192).max(1);
    let mut r: Vec<f64> = (0..pts.len())
        .step_by(stride)
        .map(|i| (pts.scale(i) * geom.residual(kind, &pts.points[i])).abs())
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
        None => cold_start(cloud.points, options)?,
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
    let kind = method.residual();
    let fit = problem(cloud, kind, loss, fixed);
    let (canonical, eq) = canonical_equations(&Params::from_array(x.into()), &rep, &fit, options);
    let form_cells = wall_cells(cloud.points, &canonical, FORM_AXIAL_CELLS);
    let wall = WallCells::gather(cloud.points, cloud.scales, &canonical, &form_cells);
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
    let (diagnostics, implausible) = match assess(stage_pts.points, &canonical) {
        Ok(d) => (Some(d), d.verdict(&canonical)),
        Err(i) => (None, Some(i)),
    };
    let dof = n.saturating_sub(fixed.iter().filter(|&&f| !f).count());
    let implausible = implausible
        .or((dof < MIN_UNCERTAINTY_DOF)
            .then_some(Implausible::TooFewForUncertainty { points: n, dof }));
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

/// The 1-σ of the canonical estimate, for every loss the cluster-robust sandwich over the
/// wall's cells ([`cluster_sandwich_uncertainty`]): it holds when the errors are
/// correlated within a cell (a camera's filtering, neighbouring pixels), when their
/// variance changes across the frame, and when a part of the wall deviates from the model
/// (its cells' scores then spread). Roll's is withheld when roll is undetermined
/// ([`roll_is_determined`]). Every 1-σ carries the small-sample factor of its degrees of
/// freedom ([`small_sample_factor`]). Also whether it is, and the raw cost Σ rᵢ² without the loss
/// (for [`Estimate::rms_residual`]). `eq` (the normal equations at the estimate) is the
/// fallback when the sandwich cannot be formed. When the wall's slices along the axis
/// differ more than their cells do (`shared_along_axis`,
/// [`WallCells::shared_along_axis`]), the errors are shared by each slice's cells and
/// the cells are not independent: the covariance of the slices' shared offsets is added
/// ([`add_shared_offsets`]; `shared_offset` is `Some` exactly then), and each parameter
/// whose slice jackknife is larger still by the F test of [`slice_check`] takes that
/// 1-σ ([`take_shared_errors`]).
#[allow(clippy::too_many_arguments)]
fn uncertainty(
    cloud: View<'_>,
    kind: Residual,
    loss: Loss,
    fixed: [bool; N_PARAMS],
    canonical: &Params,
    eq: &NormalEquations<N_PARAMS>,
    options: &EstimateOptions,
    shared_offset: Option<&SharedOffset>,
    off: &[usize],
) -> FitUncertainty {
    let n_free = fixed.iter().filter(|&&f| !f).count();
    let residual_dof = cloud.len().saturating_sub(n_free).max(1);
    let (mut sigma, mut cov, raw_cost, dof, slices, shift, bread) =
        match cluster_sandwich_uncertainty(cloud, kind, loss, fixed, canonical, n_free, off) {
            Some(c) => (
                c.sigma,
                c.cov,
                c.raw_cost,
                (c.clusters - 1).min(residual_dof),
                c.slices,
                c.shift,
                c.bread,
            ),
            None => {
                let (s, c) = covariance(eq, eq.cost / residual_dof as f64);
                (s, c, eq.cost, residual_dof, None, None, eq.jtj)
            }
        };
    let k = small_sample_factor(dof);
    for s in sigma.iter_mut().flatten() {
        *s *= k;
    }
    if let Some(c) = cov.as_mut() {
        *c *= k * k;
    }
    if let Some(so) = shared_offset {
        add_shared_offsets(&mut sigma, cov.as_mut(), &bread, so);
    }
    if let Some(check) = slices.filter(|_| shared_offset.is_some()) {
        take_shared_errors(&mut sigma, cov.as_mut(), &check);
    }
    let roll_determined = roll_is_determined(
        canonical,
        &sigma,
        cov.as_ref(),
        options.fixed_diameters.is_some(),
    );
    if !roll_determined {
        sigma[2] = None;
    }
    let diameter_cov = match (&cov, sigma[0], sigma[1]) {
        (Some(c), _, _) => Some([[c[(0, 0)], c[(0, 1)]], [c[(1, 0)], c[(1, 1)]]]),
        (None, Some(a), Some(b)) => Some([[a * a, 0.0], [0.0, b * b]]),
        _ => None,
    };
    let axis_cov = cov.as_ref().and_then(|c| AxisCov::of(canonical, c));
    (
        sigma,
        diameter_cov,
        roll_determined,
        raw_cost,
        shift,
        axis_cov,
    )
}

/// Where the fitted axis lies across the pipe, with its uncertainty: the axis's lateral
/// displacement at PCS distance x, in the PCS of the estimate (toward +Y and +Z), is
/// (A + x·B)·Δβ to first order for an error Δβ of the parameters, so its covariance is
/// P + x(Q + Qᵀ) + x²R with P = AΣAᵀ, Q = AΣBᵀ, R = BΣBᵀ (Σ the estimate's covariance).
/// A and B are taken by central differences of the axis of β + Δβ mapped into the PCS of
/// β. Unlike the reported 1-σ of pitch, yaw and the offsets taken one by one, this holds
/// for a near-round pipe, whose roll is nearly undetermined: turning the roll while the
/// other angles and offsets compensate leaves the axis where it is (A and B have no
/// component along that turn), where their 1-σ taken one by one carry it in full (a round
/// 20" pipe: pitch and yaw 2°, δz 44 mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisCov {
    /// P (m²).
    pub at_sensor: [[f64; 2]; 2],
    /// Q (m²/m).
    pub cross: [[f64; 2]; 2],
    /// R (m²/m²).
    pub slope: [[f64; 2]; 2],
}

impl AxisCov {
    /// The variances (m²) of the axis's lateral position at distance `x` (m) toward +Y and
    /// +Z of the PCS.
    pub fn lateral_variance(&self, x: f64) -> [f64; 2] {
        std::array::from_fn(|i| {
            (self.at_sensor[i][i] + 2.0 * x * self.cross[i][i] + x * x * self.slope[i][i]).max(0.0)
        })
    }

    /// From the estimate `beta` and its covariance `cov`; `None` when β leaves the model.
    fn of(beta: &Params, cov: &Mat7) -> Option<Self> {
        // The axis of β + h·e_j at PCS distance s, in the PCS of β, lateral part.
        let lateral = |j: usize, h: f64, s: f64| -> [f64; 2] {
            let mut a = beta.to_array();
            a[j] += h;
            let moved = Params::from_array(a);
            let q = beta.scs_to_pcs(&moved.pcs_to_scs(&nalgebra::Point3::new(s, 0.0, 0.0)));
            [q.y, q.z]
        };
        let mut a = nalgebra::SMatrix::<f64, 2, N_PARAMS>::zeros();
        let mut b = nalgebra::SMatrix::<f64, 2, N_PARAMS>::zeros();
        for j in 2..N_PARAMS {
            let (p0, m0) = (lateral(j, AXIS_STEP, 0.0), lateral(j, -AXIS_STEP, 0.0));
            let (p1, m1) = (lateral(j, AXIS_STEP, 1.0), lateral(j, -AXIS_STEP, 1.0));
            for i in 0..2 {
                a[(i, j)] = (p0[i] - m0[i]) / (2.0 * AXIS_STEP);
                b[(i, j)] = (p1[i] - m1[i]) / (2.0 * AXIS_STEP) - a[(i, j)];
            }
        }
        let m = |x: nalgebra::SMatrix<f64, 2, 2>| [[x[(0, 0)], x[(0, 1)]], [x[(1, 0)], x[(1, 1)]]];
        let out = Self {
            at_sensor: m(a * cov * a.transpose()),
            cross: m(a * cov * b.transpose()),
            slope: m(b * cov * b.transpose()),
        };
        [out.at_sensor, out.cross, out.slope]
            .iter()
            .flatten()
            .flatten()
            .all(|v| v.is_finite())
            .then_some(out)
    }
}

/// Central-difference step of [`AxisCov::of`] (rad for the angles, m for the offsets):
/// the axis moves linearly in β to 10⁻¹² here, far below any 1-σ.
const AXIS_STEP: f64 = 1e-6;

/// The level of the test whether slices found off the wall move the diameters
/// ([`shared_misfit`]): it is asked only of frames whose slices already failed the slice
/// form test at [`crate::fit::form::LACK_OF_FIT_ALPHA`], so a frame whose errors are independent is refused
/// by it at a rate below 10⁻³ whatever this level; this level is the rate at which a frame
/// with a real but harmless shared error (a depth table's residual at the nearest ranges)
/// is refused. Measured on 40 numpy frames with a multipath band
/// (`crates/epd-py/tests/test_independent_frames.py`'s generator): leaving the band's
/// slices out moved the diameters by 2–10 mm with a standard deviation of 0.5–3 mm, z of
/// 2–4: at 10⁻³ most were answered; at 5 % most are refused.
pub const SHIFT_TEST_ALPHA: f64 = 0.05;

/// What [`uncertainty`] gives: the 1-σ, the diameters' covariance, whether the roll is
/// determined, the raw cost Σ rᵢ², and the change of β without the slices found off the
/// wall.
type FitUncertainty = (
    Sigmas,
    Option<[[f64; 2]; 2]>,
    bool,
    f64,
    Option<SliceShift>,
    Option<AxisCov>,
);

/// The change of β when the slices found off the wall are left out, and its standard
/// deviation per parameter ([`slice_shift`]).
type SliceShift = (SVector<f64, N_PARAMS>, [f64; N_PARAMS]);

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
fn problem<'v>(on: View<'v>, kind: Residual, loss: Loss, fixed: [bool; N_PARAMS]) -> PipeFit<'v> {
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
        // Stage 2: all points (unless stage 1 already fitted them with this loss).
        if stage_pts.len() != n || last.is_none() || auto {
            let rep = minimize(&problem(self.cloud, kind, loss, fixed), x, &options.lm);
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

/// The canonical form of the fitted β (see [`canonical_form`]) and the normal equations
/// of `fit` there: a 180° turn only flips the signs of (pitch, yaw, δy, δz) in the last
/// stage's equations; a 90° turn or the end-for-end turn re-expresses the pose, so the
/// equations are evaluated afresh. Held diameters are restated exactly.
fn canonical_equations(
    fitted: &Params,
    rep: &LmReport<N_PARAMS>,
    fit: &PipeFit<'_>,
    options: &EstimateOptions,
) -> (Params, NormalEquations<N_PARAMS>) {
    let (mut canonical, applied) = canonical_form(fitted);
    if let Some((d_max, d_min)) = options.fixed_diameters {
        // The solver's steps in held diameters are exactly zero, and Dmax ≥ Dmin, so the
        // 90° turn (which swaps them) is never applied and the flip and the end-for-end
        // turn keep them: this only states what already holds bit for bit.
        debug_assert!(!applied.turned && fitted.d_max == d_max && fitted.d_min == d_min);
        canonical.d_max = d_max;
        canonical.d_min = d_min;
    }
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

/// Clock-angle sectors of the cluster-robust cells: 30° each. With
/// [`AXIAL_CELLS`] axial bins that makes G = 96 cells: the cluster-robust variance then
/// has about G − 1 = 95 degrees of freedom, a relative standard error of √(2/95) = 15 %
/// on a variance and 7 % on a 1-σ; and each cell — a 30° arc (0.13 m on a 20" pipe) by
/// an eighth of the points along the axis — is tens to hundreds of pixels across, far
/// larger than the few pixels over which a camera's errors are correlated.
pub const CLOCK_SECTORS: usize = 12;

/// Bins along the axis of the cluster-robust cells, of equal point counts (their edges
/// are quantiles of the points' axial distance at the estimate); see [`CLOCK_SECTORS`].
pub const AXIAL_CELLS: usize = 8;

/// Points (evenly strided) whose axial distances give the cells' edges: the quantiles of
/// 4096 points are within ±0.8 % (one binomial standard error √(q(1−q)/4096) at the
/// median) of the whole frame's, so the cells hold equal counts to that precision.
const CELL_EDGE_POINTS: usize = 4096;

/// The wall's cells at `beta`: `axial` bins of equal counts of `points`
/// (by where their sensing lines meet the wall, [`wall_point_pcs`]) times
/// [`CLOCK_SECTORS`] sectors.
pub(crate) fn wall_cells(points: &[[f64; 3]], beta: &Params, axial: usize) -> Cells {
    let stride = points.len().div_ceil(CELL_EDGE_POINTS).max(1);
    let mut x: Vec<f64> = match Geometry::new(beta) {
        None => Vec::new(),
        Some(geom) => points
            .iter()
            .step_by(stride)
            .map(|p| wall_point_pcs(&geom, p)[0])
            .filter(|v| v.is_finite())
            .collect(),
    };
    x.sort_by(f64::total_cmp);
    let axial_edges = if x.is_empty() {
        Vec::new()
    } else {
        (1..axial)
            .map(|k| x[(k * x.len() / axial).min(x.len() - 1)])
            .collect()
    };
    Cells {
        axial_edges,
        sectors: CLOCK_SECTORS,
    }
}

/// The cluster-robust covariance at the canonical β over every point, the points grouped
/// by the wall's cells ([`wall_cells`]; scores and breads from
/// [`crate::problem::PipeFit::cluster_sandwich_at`]): the cluster jackknife
/// ([`jackknife_covariance`]), which measured on tof-sim's full frames (σ = 20 mm, the
/// paper's poses; `cargo run --release -p epd-frame --example coverage`) gave err/σ̂ a
/// spread of 1.05/1.03 for Dmax/Dmin under independent noise where H⁻¹BH⁻¹ with the
/// G/(G − 1) factor gave 1.24/1.20. `None` when the cells are too few to estimate a
/// spread (G ≤ p free parameters, or N ≤ p) or β is outside the model.
fn cluster_sandwich_uncertainty(
    cloud: View<'_>,
    kind: Residual,
    loss: Loss,
    fixed: [bool; N_PARAMS],
    canonical: &Params,
    n_free: usize,
    off: &[usize],
) -> Option<ClusterUncertainty> {
    let cells = wall_cells(cloud.points, canonical, AXIAL_CELLS);
    let sw = problem(cloud, kind, loss, fixed).cluster_sandwich_at(canonical, &cells)?;
    if sw.clusters <= n_free || cloud.len() <= n_free {
        return None;
    }
    let (s, cov) = jackknife_covariance(&sw.bread, &sw.cells);
    let slices = slice_check(&sw.bread, &sw.meat, &sw.cells, &sw.cell_ids, cells.sectors);
    let shift = slice_shift(
        &sw.bread,
        &sw.meat,
        &sw.cells,
        &sw.cell_ids,
        cells.sectors,
        off,
    );
    Some(ClusterUncertainty {
        sigma: s,
        cov,
        raw_cost: sw.raw_cost,
        clusters: sw.clusters,
        bread: sw.bread,
        slices,
        shift,
    })
}

/// What [`cluster_sandwich_uncertainty`] finds.
struct ClusterUncertainty {
    /// The cell jackknife's 1-σ (no small-sample factor yet).
    sigma: Sigmas,
    /// Its covariance when every parameter is determined.
    cov: Option<Mat7>,
    /// Σ rᵢ² without the loss.
    raw_cost: f64,
    /// Cells holding points (G).
    clusters: usize,
    /// The sandwich's bread H.
    bread: Mat7,
    /// The jackknife over slices along the axis and its test ([`slice_check`]).
    slices: Option<SliceCheck>,
    /// The change of β without the slices found off the wall ([`slice_shift`]).
    shift: Option<SliceShift>,
}

/// Every parameter whose errors the slice test finds shared along the pipe
/// ([`slice_check`]) takes the larger of its two 1-σ: the cells' (as given, with its
/// small-sample factor) and the slices' jackknife times t₀.₉₇₅(ν)/1.96 of the slices'
/// Satterthwaite degrees of freedom ν. The covariance's row and column of such a
/// parameter are scaled by the same ratio (D·C·D with D diagonal: the cells'
/// correlations kept, the matrix still positive semi-definite).
fn take_shared_errors(sigma: &mut Sigmas, mut cov: Option<&mut Mat7>, check: &SliceCheck) {
    for j in (0..N_PARAMS).filter(|&j| check.shared[j]) {
        let Some(cell_sigma) = sigma[j] else { continue };
        let t = crate::fit::student::student_t_quantile(0.975, check.dof[j]);
        let slice_sigma = check.cov[(j, j)].max(0.0).sqrt() * t / Z_975;
        if !(slice_sigma > cell_sigma) || cell_sigma <= 0.0 {
            continue;
        }
        let r = slice_sigma / cell_sigma;
        sigma[j] = Some(slice_sigma);
        if let Some(c) = cov.as_deref_mut() {
            for i in 0..N_PARAMS {
                c[(i, j)] *= r;
                c[(j, i)] *= r;
            }
        }
    }
}

/// Adds the covariance of a range error shared by each slice of the wall
/// ([`shared_offset_cov`], times the small-sample factor² of its degrees of freedom) to
/// the cells' covariance. The cells' jackknife sees a slice's shared error only as a part
/// of each cell's own, as if the S cells of a slice erred independently, which for a
/// parameter that every cell of a slice moves the same way (the mean diameter under a
/// range offset all around) understates its variance up to S-fold. Unlike the slice
/// jackknife of [`take_shared_errors`], the offsets' covariance is pooled over all
/// slices, so its degrees of freedom do not collapse when a few slices (the far wall)
/// carry most of the information on a parameter.
fn add_shared_offsets(sigma: &mut Sigmas, cov: Option<&mut Mat7>, bread: &Mat7, so: &SharedOffset) {
    let Some((v, dof)) = shared_offset_cov(bread, &so.scores, &so.means) else {
        return;
    };
    let t = crate::fit::student::student_t_quantile(0.975, dof.max(1.0));
    let f = if t.is_finite() { t / Z_975 } else { 1.0 };
    let v = v * (f * f);
    for (j, s) in sigma.iter_mut().enumerate() {
        if let Some(s) = s.as_mut() {
            *s = (*s * *s + v[(j, j)].max(0.0)).sqrt();
        }
    }
    if let Some(c) = cov {
        *c += v;
    }
}

/// The 0.975 quantile of the standard normal.
const Z_975: f64 = 1.959_963_984_540_054;

/// The small-sample factor of a 1-σ whose variance was estimated with `dof` degrees of
/// freedom: t₀.₉₇₅(ν)/z₀.₉₇₅, so that ±1.96 reported σ is the exact 95 % interval of
/// Student's t (the standardised error of a normal estimate over an estimated variance
/// with ν degrees of freedom) rather than the normal one, which is too short when ν is
/// small. ν is the smaller of the residual degrees of freedom N − p and, for the cluster
/// jackknife, G − 1 for G clusters (the usual reference for a cluster-robust variance:
/// Cameron & Miller 2015, J. Human Resources 50:317, §VI). 1.013 at G = 96 cells, 1.31
/// at ν = 5, 2.20 at ν = 2 (N = 9 points and seven parameters).
pub(crate) fn small_sample_factor(dof: usize) -> f64 {
    let t = crate::fit::student::student_t_quantile(0.975, dof.max(1) as f64);
    if t.is_finite() { t / Z_975 } else { 1.0 }
}

/// The Cramér–Rao lower bound on the 1-σ of each parameter, for range noise N(0, σ²)
/// along each sensing line: the Fisher information is JᵀJ/σ² with J the Jacobian of the
/// ML-EPD range residual at the true β over the noise-free points (SCS, m). The case
/// σᵢ = σ of [`cramer_rao_bound_weighted`].
pub fn cramer_rao_bound(
    noise_free_points: &[[f64; 3]],
    truth: &Params,
    sigma_range: f64,
) -> Result<Sigmas, EpdError> {
    if !(sigma_range >= 0.0 && sigma_range.is_finite()) {
        return Err(EpdError::InvalidOption(format!(
            "sigma_range = {sigma_range}: must be a finite number ≥ 0"
        )));
    }
    let cloud = clean(noise_free_points);
    let view = View {
        points: &cloud.points,
        scales: None,
    };
    fisher_bound(view, cloud.dropped, truth, sigma_range * sigma_range)
}

/// The Cramér–Rao lower bound on the 1-σ of each parameter for independent range noise
/// N(0, σᵢ²) along each sensing line, σᵢ (m) per point: the Fisher information is
/// Σ gᵢgᵢᵀ/σᵢ² with gᵢ the gradient of the ML-EPD range residual at the true β of the
/// noise-free point i (SCS, m); the bound of [`estimate_weighted`] with ML-EPD.
/// Computed as σ̃²·(Σ sᵢ²gᵢgᵢᵀ)⁻¹ with sᵢ = σ̃/σᵢ, σ̃ the median σᵢ. Points (with their
/// σᵢ) are dropped as in [`estimate_weighted`]; `sigma.len() != points.len()` is an
/// [`EpdError::InvalidOption`].
pub fn cramer_rao_bound_weighted(
    noise_free_points: &[[f64; 3]],
    sigma: &[f64],
    truth: &Params,
) -> Result<Sigmas, EpdError> {
    if sigma.len() != noise_free_points.len() {
        return Err(EpdError::InvalidOption(format!(
            "{} range standard deviations for {} points: need one per point",
            sigma.len(),
            noise_free_points.len()
        )));
    }
    let (cloud, scales, typical) = weighted_cloud(noise_free_points, sigma);
    let view = View {
        points: &cloud.points,
        scales: Some(&scales),
    };
    fisher_bound(view, cloud.dropped, truth, typical * typical)
}

/// σ̃²·(J̃ᵀJ̃)⁻¹ on the determined parameters, J̃ the scaled Jacobian of the range residual
/// of `cloud` at `truth`.
fn fisher_bound(
    cloud: View<'_>,
    n_dropped: usize,
    truth: &Params,
    sigma2: f64,
) -> Result<Sigmas, EpdError> {
    if cloud.len() < N_PARAMS {
        return Err(EpdError::TooFewPoints {
            usable: cloud.len(),
            dropped: n_dropped,
            needed: N_PARAMS,
        });
    }
    let eq = cloud
        .fit(Residual::Range)
        .equations_at(truth)
        .ok_or_else(|| {
            EpdError::InvalidOption("the true β puts the sensor outside the pipe".into())
        })?;
    Ok(covariance(&eq, sigma2).0)
}

/// RMS of the range residual r_m (ML-EPD's residual, m) of measured points (SCS) at β:
/// a fit quality in metres comparable across methods. `None` when no point is usable or
/// β puts the sensor outside the pipe.
pub fn rms_range_residual(points: &[[f64; 3]], beta: &Params) -> Option<f64> {
    let cloud = clean(points);
    if cloud.points.is_empty() {
        return None;
    }
    let eq = PipeFit::new(&cloud.points, Residual::Range).equations_at(beta)?;
    Some((eq.cost / cloud.points.len() as f64).sqrt())
}
