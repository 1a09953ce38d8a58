//! The 1-σ of a fit: the cluster-robust sandwich over the wall's cells, the slices'
//! jackknife when errors are shared along the pipe, the shared offsets' covariance, the
//! small-sample factor, and the covariance of the pipe's axis. [`crate::estimate()`] calls
//! `uncertainty` once per estimate, at the canonical β.

use nalgebra::SVector;

use crate::estimate::{EstimateOptions, Sigmas, View, problem};
use crate::lm::NormalEquations;
use crate::loss::Loss;
use crate::params::{N_PARAMS, Params};
use crate::problem::{Cells, Curvature, wall_point_pcs};
use crate::residual::{Geometry, Residual};
use crate::uncertainty::{
    Mat7, SharedOffset, SliceCheck, covariance, determined_inverse, jackknife_covariance,
    roll_is_determined, shared_offset_cov, slice_check, slice_shift,
};

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
pub(crate) fn uncertainty(
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
        if let Some(c) = cov.as_ref().filter(|_| !fixed[2]) {
            hold_roll(&mut sigma, canonical, c);
        }
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

/// The 1-σ of pitch, yaw, δy and δz at the reported roll, for a pipe whose roll is
/// undetermined. Turning the PCS about the pipe's axis by φ
/// ([`crate::symmetry::turn_about_axis`]) moves β along v = ∂β/∂φ and leaves a round
/// pipe's wall in place, so the fit's error has a large component along v that only says
/// which roll the fit happened to take. Re-expressed at the reported roll, the error is
/// Δβ' = Δβ − v·Δθx / v_θx, with covariance MΣMᵀ for M = I − v·e_θxᵀ / v_θx: the
/// uncertainty of the pose that goes with the reported roll (zero along v, the
/// diameters' rows unchanged, since v has no diameter component). Taken one by one, Σ's
/// own 1-σ carry the whole turn (a round 20" frame: pitch and yaw 2°, δz 44 mm). v is
/// taken by central differences of step [`AXIS_STEP`] (in closed form v = (0, 0,
/// cos θz / cos θy, −sin θz, cos θz·tan θy, −δz, δy)); v_θx is 1 when pitch and yaw are
/// zero (the turn is then a roll) and never changes sign for a canonical estimate; nothing
/// is changed when |v_θx| falls below 1/2 (|θz| beyond about 60°).
///
/// These 1-σ are conditional on the reported roll: they describe where the axis lies in
/// the PCS of that roll. Against a pose given at another roll — the true roll of an oval
/// pipe whose ovality the frame does not resolve — the pose differs by the turn, which the
/// roll's missing 1-σ says is unknown. Known limit: the shared-error steps before this one
/// ([`add_shared_offsets`], [`take_shared_errors`]) judge and scale Σ before it is held at
/// the roll, so part of the turn's variance can reach the held 1-σ through their scaling
/// (measured: `results/straight_false_alarm`, 8" pipe under a 6 mm wiggle, pitch covered
/// in 33 of 40 frames).
fn hold_roll(sigma: &mut Sigmas, beta: &Params, cov: &Mat7) {
    let at = |phi: f64| {
        SVector::<f64, N_PARAMS>::from(crate::symmetry::turn_about_axis(beta, phi).to_array())
    };
    let mut v = (at(AXIS_STEP) - at(-AXIS_STEP)) / (2.0 * AXIS_STEP);
    v[2] = crate::params::wrap_pi(v[2] * 2.0 * AXIS_STEP) / (2.0 * AXIS_STEP);
    if v[2].abs() < 0.5 || !v.iter().all(|x| x.is_finite()) {
        return;
    }
    let mut m = Mat7::identity();
    for i in 0..N_PARAMS {
        m[(i, 2)] -= v[i] / v[2];
    }
    let held = m * cov * m.transpose();
    for j in 3..N_PARAMS {
        if sigma[j].is_some() {
            sigma[j] = Some(held[(j, j)].max(0.0).sqrt());
        }
    }
}

/// Where the fitted axis lies across the pipe, with its uncertainty: the axis's lateral
/// displacement at PCS distance x, in the PCS of the estimate (toward +Y and +Z), is
/// (A + x·B)·Δβ to first order for an error Δβ of the parameters, so its covariance is
/// P + x(Q + Qᵀ) + x²R with P = AΣAᵀ, Q = AΣBᵀ, R = BΣBᵀ (Σ the estimate's covariance).
/// A and B are taken by central differences of the axis of β + Δβ mapped into the PCS of
/// β. Unlike the 1-σ of pitch, yaw and the offsets taken one by one from Σ, this holds
/// for a near-round pipe, whose roll is nearly undetermined: turning the roll while the
/// other angles and offsets compensate leaves the axis where it is (A and B have no
/// component along that turn), where their 1-σ taken one by one carry it in full (a round
/// 20" pipe: pitch and yaw 2°, δz 44 mm; the reported ones are held at the reported roll,
/// `hold_roll`).
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

/// What [`uncertainty`] gives: the 1-σ, the diameters' covariance, whether the roll is
/// determined, the raw cost Σ rᵢ², and the change of β without the slices found off the
/// wall.
pub(crate) type FitUncertainty = (
    Sigmas,
    Option<[[f64; 2]; 2]>,
    bool,
    f64,
    Option<SliceShift>,
    Option<AxisCov>,
);

/// The change of β when the slices found off the wall are left out, and its standard
/// deviation per parameter ([`slice_shift`]).
pub(crate) type SliceShift = (SVector<f64, N_PARAMS>, [f64; N_PARAMS]);

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
pub(crate) const CELL_EDGE_POINTS: usize = 4096;

/// The wall's cells at `beta`: `axial` bins of equal counts of `points`
/// (by where their sensing lines meet the wall, [`wall_point_pcs`]) times
/// [`CLOCK_SECTORS`] sectors.
pub fn wall_cells(points: &[[f64; 3]], beta: &Params, axial: usize) -> Cells {
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
    let cells = wall_cells(
        &cloud.points.sample(CELL_EDGE_POINTS),
        canonical,
        AXIAL_CELLS,
    );
    // The bread with the loss's exact curvature: residuals past a redescending loss's
    // knee lower it, and the solver's clipped curvature would overstate it — under range
    // noise growing as r² (the far points past the Cauchy knee) the pose's ±1.96σ̂
    // covered 0.745–0.825 of 200 trials with it, 0.95–0.96 with the exact one
    // (`results/noise_models`). Where the exact bread leaves a parameter undetermined
    // that the clipped one determines (F not convex there), the clipped one.
    let fit = problem(cloud, kind, loss, fixed);
    let exact = fit.cluster_sandwich_at(canonical, &cells, Curvature::Exact)?;
    let determined = |b: &Mat7| determined_inverse(b).1.iter().filter(|&&k| k).count();
    let sw = if loss == Loss::Squared
        || determined(&exact.bread) == (0..N_PARAMS).filter(|&i| !fixed[i]).count()
    {
        exact
    } else {
        let clipped = fit.cluster_sandwich_at(canonical, &cells, Curvature::Clipped)?;
        if determined(&clipped.bread) > determined(&exact.bread) {
            clipped
        } else {
            exact
        }
    };
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
