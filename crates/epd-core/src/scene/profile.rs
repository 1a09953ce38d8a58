//! The departure profile: how the points of a frame depart from a straight fit, slice
//! by slice along its axis, and the tests that say when a slice departs at the survey's
//! false-alarm rate ([`SURVEY_FALSE_ALARM`]). [`crate::segment`] reads it to find where
//! the straight pipe ends and what lies beyond.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::estimate::Estimate;
use crate::params::Params;
use crate::points::Points;
use crate::residual::Geometry;
use crate::segment::SegmentOptions;

/// One slice of the departure profile (PCS of the straight fit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Slice {
    /// Axial coordinate of the slice's near edge (m).
    pub start_m: f64,
    /// Points in the slice.
    pub n_points: usize,
    /// Sectors with enough points.
    pub n_sectors: usize,
    /// Mean radial deviation c₀ (m).
    pub widening_m: f64,
    /// The least mean deviation of the wall's halves (m): over the `sectors` rotations
    /// of a half of the circumference (⌊sectors/2⌋ consecutive sectors, at least half of
    /// them with medians), the least mean of the sector medians. A branch opening or a
    /// bend moves at most half the wall outward (a branch is no wider than the main pipe,
    /// so its opening spans at most half the circumference seen from the axis; a bend
    /// moves the other half inward), so a slice whose every half lies outside the wall
    /// shows neither: the wall reads wider all around (a range bias over a band of
    /// ranges, as multipath gives, or a wider pipe). NaN without such a half.
    pub least_half_m: f64,
    /// Variance of `least_half_m` (m²): the medians' variances summed over its sectors
    /// and divided by their count squared, scaled by κ̂ (`calibrate_tests`).
    pub least_half_var_m2: f64,
    /// Lateral shift (c₁, c₂) (m), toward +Y and +Z of the PCS.
    pub shift_m: [f64; 2],
    /// Standard error of the shift's length (m).
    pub shift_se_m: f64,
    /// Median deviation of the sector opposite the shift (m), NaN without points.
    pub opposite_m: f64,
    /// The largest outward excess of one sector's median over the slice's harmonic fit
    /// c₀ + c₁cos ψ + c₂sin ψ (m), NaN without a fit: a branch opening lets the rays
    /// that cross it run on to the branch's far wall, so its one or two sectors lie far
    /// outside the wall while the rest of the slice stays on it, a local bump that the
    /// first harmonic, weighted by the sectors' precisions, hardly follows.
    pub bump_m: f64,
    /// Standard error of `bump_m` (the sector median's and the fit's there) (m).
    pub bump_se_m: f64,
    /// Polar angle ψ of the bump's sector centre, from +Y toward +Z (rad).
    pub bump_psi: f64,
    /// Whether the bump's sector had a usable median in the slice before: the wall was
    /// in view on that side before the bump. When it was not, an opening may begin
    /// where the view does not reach, and the points before the bump may hold some of
    /// it.
    pub bump_follows_wall: bool,
    /// How much more the sectors' medians scatter about the harmonic fit than their
    /// variances for independent points say: med_k[e_k²/(v_k(1 − h_k))]/med(χ²₁), with e_k
    /// = m_k − c₀ − c₁cos ψ_k − c₂sin ψ_k, v_k = (π/2)σ_k²/n_k and h_k sector k's leverage
    /// in the fit; ≈ 1 for independent points. A median, so that the one or two sectors of
    /// a branch opening do not inflate it. NaN without a fit.
    pub variance_ratio: f64,
    /// The harmonic fit's degrees of freedom: usable sectors − 3.
    pub misfit_dof: usize,
    /// Covariance of the shift ĉ = (c₁, c₂) (m²: var c₁, cov, var c₂): from the medians'
    /// independent-point variances, then (`calibrate_tests`) scaled by κ̂ and added the
    /// straight fit's own uncertainty of where its axis lies at this slice ([`AxisSigma`]).
    pub shift_cov_m2: [f64; 3],
    /// The variance scale κ̂ applied to this slice's standard errors and `shift_f`
    /// (`calibrate_tests`); 1 before.
    pub variance_scale: f64,
    /// The shift's test statistic, F = ĉᵀ Cov(ĉ)⁻¹ ĉ / 2 for ĉ = (c₁, c₂), with Cov(ĉ) scaled
    /// by the profile's variance scale κ̂ (`calibrate_tests`): F(2, ν) distributed for a straight pipe
    /// (NaN without a fit).
    pub shift_f: f64,
    /// The profile's critical values, copied in every slice: `shift_f` beyond
    /// `critical_f`, or `bump_m / bump_se_m` beyond `critical_t`, is a departure at the
    /// survey's false-alarm rate ([`SURVEY_FALSE_ALARM`]).
    pub critical_f: f64,
    /// See `critical_f`.
    pub critical_t: f64,
    /// The slice's departure p-value, adjusted as the critical values are
    /// (`departure_p`): the least of 2n·P(F(2, ν̂) > `shift_f`) and
    /// 2n·K·P(t(ν̂) > `bump_m`/`bump_se_m`) (n slices tested, K sectors), at most 1. A
    /// slice departs only when it is below [`SURVEY_FALSE_ALARM`] (and its shift or bump
    /// exceeds `min_shift_m`). NaN for a slice not tested (fewer than six sectors).
    pub departure_p: f64,
    /// The opening test's least p-value over the slice's cells too sparse for the
    /// medians' tests (all of them in a slice with fewer than six sectors), adjusted over
    /// every cell tested in the frame ([`crate::scene::sparse`]); the slice opens below
    /// [`crate::scene::sparse::OPENING_FALSE_ALARM`]. NaN when not tested.
    pub opening_p: f64,
    /// The polar angle ψ of the sector centre where `opening_p` was found (rad), NaN
    /// without it.
    pub opening_psi: f64,
}

/// The sectors with medians a slice needs for its shift and bump to be tested: six, twice
/// the three coefficients of the harmonic fit c₀ + c₁cos ψ + c₂sin ψ, so that its misfit
/// keeps ν = 6 − 3 = 3 degrees of freedom, the fewest for which Student's t (the bump's
/// statistic, and the shift's F(2, ν) denominator) has a finite variance ν/(ν − 2), and
/// the slice's variance ratio is a median of at least six ratios. With fewer, the critical
/// values grow without bound (t₀.₉₉₉₉₉(ν = 1) ≈ 3·10⁴) and a slice seen on one side only
/// carries no test.
pub const MIN_SECTORS_TESTED: usize = 6;

impl Slice {
    /// The shift's length (m).
    pub fn shift(&self) -> f64 {
        self.shift_m[0].hypot(self.shift_m[1])
    }

    /// The shift's direction in the cross-section: the angle from +Y toward +Z (rad).
    pub fn direction(&self) -> f64 {
        self.shift_m[1].atan2(self.shift_m[0])
    }

    /// Whether the shift is significant under `o`.
    pub fn shifts(&self, o: &SegmentOptions) -> bool {
        let s = self.shift();
        self.n_sectors >= MIN_SECTORS_TESTED && s > o.min_shift_m && self.shift_f > self.critical_f
    }

    /// Whether one sector's outward bump is significant under `o` (same thresholds as
    /// the shift).
    pub fn bumps(&self, o: &SegmentOptions) -> bool {
        let b = self.bump_m;
        self.n_sectors >= MIN_SECTORS_TESTED
            && b > o.min_shift_m
            && b > self.critical_t * self.bump_se_m
    }

    /// Whether the slice's cells too sparse for the medians show an opening's
    /// exceedances ([`crate::scene::sparse`]).
    pub fn opens(&self) -> bool {
        self.opening_p < crate::scene::sparse::OPENING_FALSE_ALARM
    }

    /// Whether the slice departs from the straight pipe: a significant shift or bump, or
    /// an opening in its sparse cells.
    pub fn departs(&self, o: &SegmentOptions) -> bool {
        self.shifts(o) || self.bumps(o) || self.opens()
    }

    /// The side of the wall a departure without a shift lies on: the bump's sector
    /// centre when the bump is significant, else the opening's when the slice opens,
    /// else the bump's (rad; NaN without either).
    pub fn side(&self) -> f64 {
        if self.side_is_opening() {
            self.opening_psi
        } else {
            self.bump_psi
        }
    }

    /// Whether [`Slice::side`] is the opening's: the slice opens and its bump is not
    /// significant.
    pub(crate) fn side_is_opening(&self) -> bool {
        let bumps = self.n_sectors >= MIN_SECTORS_TESTED
            && self.bump_m > 0.0
            && self.bump_m > self.critical_t * self.bump_se_m;
        !bumps && self.opens()
    }

    /// A slice at `start_m` with no points: nothing fitted, nothing tested.
    pub fn empty(start_m: f64) -> Self {
        Self {
            start_m,
            n_points: 0,
            n_sectors: 0,
            widening_m: f64::NAN,
            least_half_m: f64::NAN,
            least_half_var_m2: f64::NAN,
            shift_m: [f64::NAN; 2],
            shift_se_m: f64::NAN,
            opposite_m: f64::NAN,
            bump_m: f64::NAN,
            bump_se_m: f64::NAN,
            bump_psi: f64::NAN,
            bump_follows_wall: false,
            variance_ratio: f64::NAN,
            misfit_dof: 0,
            shift_cov_m2: [f64::NAN; 3],
            variance_scale: 1.0,
            shift_f: f64::NAN,
            critical_f: f64::INFINITY,
            critical_t: f64::INFINITY,
            departure_p: f64::NAN,
            opening_p: f64::NAN,
            opening_psi: f64::NAN,
        }
    }
}

/// Where a measured point's ray meets the wall of `beta` and how far the point lies off
/// it, normal to the wall: (x, d, ψ) with x the axial coordinate and ψ the polar angle
/// (from +Y toward +Z) of the *model* wall point t·x̂ (t the line parameter of eq. 21,
/// the ray's crossing of the wall), and d = (1 − t)·‖x̂‖·|n·u| the range error along the
/// ray (ML-EPD's residual) times the cosine of the incidence (n the wall's normal, u the
/// ray). Binning by the model point rather than the measured one keeps the range noise
/// out of the binning: a measured point moves along its ray, toward the sensor when its
/// noise is negative, and near the edge of the view the first slices would collect the
/// short ones.
pub(crate) fn deviation(geom: &Geometry, p: &[f64; 3]) -> Option<(f64, f64, f64)> {
    axial_deviation(geom.wall_deviation(p))
}

/// (x, d, ψ) of [`deviation`] from [`Geometry::wall_deviation`]'s (x, Y, Z, d), if finite.
fn axial_deviation([x, y, z, d]: [f64; 4]) -> Option<(f64, f64, f64)> {
    let out = (x, d, z.atan2(y));
    (out.0.is_finite() && out.1.is_finite() && out.2.is_finite()).then_some(out)
}

/// The clock sector of a wall point: k = ⌊ψ·s/2π⌋ with ψ = atan2(Z, Y) taken in [0, 2π)
/// (from +Y toward +Z), s sectors. When s is a multiple of 4 the point is turned into its
/// quadrant q (by the signs of Y and Z), where its angle α ∈ [0, π/2) has passed the
/// boundary a_j = j·2π/s when Z'·cos a_j − Y'·sin a_j ≥ 0, so k = q·s/4 + (boundaries
/// passed) without a transcendental function per point; otherwise, and for a point not
/// finite, by `atan2`. The two agree except within rounding (10⁻¹⁵ rad) of a boundary
/// (tested).
#[derive(Clone, Debug)]
struct ClockSectors {
    sectors: usize,
    /// s/4 when the sectors divide the quadrants, else 0.
    per_quadrant: usize,
    /// (cos a_j, sin a_j) of a quadrant's inner boundaries.
    bounds: Vec<(f64, f64)>,
}

impl ClockSectors {
    fn new(sectors: usize) -> Self {
        let per_quadrant = if sectors.is_multiple_of(4) {
            sectors / 4
        } else {
            0
        };
        let bounds = (1..per_quadrant)
            .map(|j| {
                let a = j as f64 * std::f64::consts::TAU / sectors as f64;
                (a.cos(), a.sin())
            })
            .collect();
        Self {
            sectors,
            per_quadrant,
            bounds,
        }
    }

    /// The sector of the wall point (Y, Z) (neither NaN).
    #[inline]
    fn of(&self, y: f64, z: f64) -> usize {
        let s = self.sectors;
        if self.per_quadrant == 0 || !(y.is_finite() && z.is_finite()) {
            let tau = std::f64::consts::TAU;
            return ((z.atan2(y).rem_euclid(tau) / tau * s as f64) as usize).min(s - 1);
        }
        // Quadrants of ψ in [0, 2π): 0 [0, π/2), 1 [π/2, π), 2 [π, 3π/2), 3 [3π/2, 2π);
        // (Y', Z') is the point turned back by q·π/2.
        let (q, yy, zz) = if z >= 0.0 && y > 0.0 {
            (0, y, z)
        } else if y <= 0.0 && z > 0.0 {
            (1, z, -y)
        } else if y < 0.0 {
            (2, -y, -z)
        } else if z < 0.0 {
            (3, -z, y)
        } else {
            // The axis itself (Y = Z = 0): atan2 decides by the zeros' signs.
            let tau = std::f64::consts::TAU;
            return ((z.atan2(y).rem_euclid(tau) / tau * s as f64) as usize).min(s - 1);
        };
        let passed = self
            .bounds
            .iter()
            .filter(|&&(c, sn)| zz * c - yy * sn >= 0.0)
            .count();
        q * self.per_quadrant + passed
    }
}

/// The departure profile of `points` (SCS, clean) against the straight fit `beta`, whose
/// axis is uncertain by `axis` (empty when β leaves the model).
pub fn profile(
    points: &[[f64; 3]],
    beta: &Params,
    axis: &AxisSigma,
    o: &SegmentOptions,
) -> Vec<Slice> {
    profile_of(Points::all(points), beta, axis, o)
}

/// [`profile`] of points read in place (all of a slice or those a mask keeps; the same
/// profile as of their copy: the chunks are cut by their numbering).
pub fn profile_of(
    points: Points<'_>,
    beta: &Params,
    axis: &AxisSigma,
    o: &SegmentOptions,
) -> Vec<Slice> {
    let n = points.len();
    let Some(geom) = Geometry::new(beta) else {
        return Vec::new();
    };
    // On all cores; each cell keeps its points in their order (the batches are binned in
    // order), so the profile is the same whatever the thread count. A stop request skips
    // the remaining chunks and the checkpoint after each pass unwinds (`crate::cancel`).
    let watch = crate::cancel::watch();
    let ns = o.sectors;
    let clock = ClockSectors::new(ns);
    // Pass 1: the axial extent of the counted points, which places the slices.
    // Also how many of them lie at x ≥ 0: those that pass 2 bins (x ≥ x_min = max(the
    // least x, 0) holds for every point at x ≥ 0 when the least x is ≥ 0, and selects
    // them when it is not).
    let chunk_of = |k: usize| points.range(k * PROFILE_CHUNK..((k + 1) * PROFILE_CHUNK).min(n));
    let (x_min, x_max, n_binned) = (0..n.div_ceil(PROFILE_CHUNK))
        .into_par_iter()
        .map(|k| {
            let (mut lo, mut hi, mut n) = (f64::INFINITY, f64::NEG_INFINITY, 0usize);
            if !watch.stopped() {
                for_each_counted(&geom, &chunk_of(k), |w| {
                    (lo, hi, n) = (lo.min(w[0]), hi.max(w[0]), n + usize::from(w[0] >= 0.0));
                });
            }
            (lo, hi, n)
        })
        .reduce(
            || (f64::INFINITY, f64::NEG_INFINITY, 0),
            |a, b| (a.0.min(b.0), a.1.max(b.1), a.2 + b.2),
        );
    crate::cancel::checkpoint();
    let x_min = x_min.max(0.0);
    if !(x_max > x_min) {
        return Vec::new();
    }
    let n_slices = (((x_max - x_min) / o.slice_m).ceil() as usize).clamp(1, 100_000);
    // Pass 2: each point's deviation into its cell, batch by batch.
    let mut store = CellStore::new(n_slices * ns, n_binned);
    let chunks = n.div_ceil(PROFILE_CHUNK);
    for first in (0..chunks).step_by(PROFILE_BATCH_CHUNKS) {
        // A cell's index fits 32 bits: at most 100 000 slices of at most 360 sectors
        // (`SegmentOptions::validate`).
        let binned: Vec<Vec<(u32, f32)>> = (first..(first + PROFILE_BATCH_CHUNKS).min(chunks))
            .into_par_iter()
            .map(|k| {
                let chunk = chunk_of(k);
                let mut pairs = Vec::with_capacity(chunk.len());
                if !watch.stopped() {
                    for_each_counted(&geom, &chunk, |[x, y, z, d]| {
                        if x >= x_min {
                            let i = (((x - x_min) / o.slice_m) as usize).min(n_slices - 1);
                            pairs.push(((i * ns + clock.of(y, z)) as u32, d as f32));
                        }
                    });
                }
                pairs
            })
            .collect();
        crate::cancel::checkpoint();
        for (c, d) in binned.into_iter().flatten() {
            store.push(c as usize, d);
        }
    }
    let store = store.into_contiguous();
    let cells: Vec<&[f32]> = (0..n_slices * ns).map(|c| store.cell(c)).collect();
    let tau = std::f64::consts::TAU;
    // Each slice's statistics on its own, on all cores.
    let mut slices: Vec<Slice> = cells
        .par_chunks(ns)
        .enumerate()
        .map(|(i, sectors)| slice_stats(sectors, x_min + i as f64 * o.slice_m, o))
        .collect();
    let law = calibrate_tests(&mut slices, ns, axis, o.slice_m);
    crate::scene::sparse::test_openings(&mut slices, &cells, o, &law);
    for (i, s) in slices.iter_mut().enumerate().skip(1) {
        // The wall in view before the departure's side: a median there in the slice
        // before, or, for an opening in sparse cells, any point there within the longest
        // window the opening test pools (a sparse slice's cell may hold none by chance).
        let (psi, needed, back) = if s.side_is_opening() {
            let longest = crate::scene::sparse::WINDOW_SLICES.iter().max().copied();
            (s.opening_psi, 1, longest.unwrap_or(1))
        } else {
            (s.bump_psi, o.min_points, 1)
        };
        if psi.is_finite() {
            let k = ((psi / tau * ns as f64) as usize).min(ns - 1);
            s.bump_follows_wall = (i.saturating_sub(back)..i)
                .map(|j| cells[j * ns + k].len())
                .sum::<usize>()
                >= needed;
        }
    }
    slices
}

/// The (x, Y, Z, d) of the points of `chunk` (SCS, m) that the profile counts, handed to
/// `f` in order: x, d and ψ finite (as `deviation` keeps them). Nothing is held: writing
/// every point's deviation to a buffer and reading it back cost more than computing it.
fn for_each_counted(geom: &Geometry, chunk: &[[f64; 3]], mut f: impl FnMut([f64; 4])) {
    geom.for_each_wall_deviation(chunk, |w| {
        let [x, y, z, d] = w;
        if x.is_finite() && d.is_finite() && !(y.is_nan() || z.is_nan()) {
            f(w);
        }
    });
}

/// Deviations per block of [`CellStore`]: 64 (256 B), so that the cells' slack, at most
/// one block each, stays small whatever the points (0.4 MB for 120 slices of 12 sectors).
const CELL_BLOCK: usize = 64;

/// The profile's deviations, cell by cell, held once (issue 27: the survey's memory beside
/// its input). While [`profile`] bins them, each cell fills blocks of [`CELL_BLOCK`] taken
/// in turn from one buffer, which is sized once for every deviation and every cell's
/// last block, so nothing is ever reallocated or copied (cells grown by doubling held up
/// to twice their deviations); then the blocks are permuted in place so that each cell's
/// lie together and in order ([`CellStore::into_contiguous`]).
struct CellStore {
    /// The blocks, in the order they were taken.
    data: Vec<f32>,
    /// Each cell's blocks, in order.
    blocks: Vec<Vec<u32>>,
    /// Each cell's deviations.
    len: Vec<usize>,
    /// Where each cell's last block starts in `data`.
    tail: Vec<usize>,
}

impl CellStore {
    /// Room for `n` deviations in `cells` cells: at most ⌈n/64⌉ full blocks and one part
    /// block for each cell that holds any (at most n of them).
    fn new(cells: usize, n: usize) -> Self {
        let blocks = n.div_ceil(CELL_BLOCK) + cells.min(n);
        Self {
            data: Vec::with_capacity(blocks * CELL_BLOCK),
            blocks: vec![Vec::new(); cells],
            len: vec![0; cells],
            tail: vec![0; cells],
        }
    }

    fn push(&mut self, c: usize, d: f32) {
        let k = self.len[c] % CELL_BLOCK;
        if k == 0 {
            let b = self.data.len() / CELL_BLOCK;
            self.blocks[c].push(b as u32);
            self.tail[c] = b * CELL_BLOCK;
            self.data.resize(self.data.len() + CELL_BLOCK, 0.0);
        }
        self.data[self.tail[c] + k] = d;
        self.len[c] += 1;
    }

    /// The blocks permuted in place, cell after cell, each cell's in its order (its part
    /// block last), by following the permutation's cycles with one block's copy.
    fn into_contiguous(mut self) -> Cells {
        let n_blocks = self.data.len() / CELL_BLOCK;
        // Where each block goes, and where each cell starts.
        let mut dest = vec![0u32; n_blocks];
        let mut start = Vec::with_capacity(self.len.len());
        let mut next = 0u32;
        for list in &self.blocks {
            start.push(next as usize * CELL_BLOCK);
            for &b in list {
                dest[b as usize] = next;
                next += 1;
            }
        }
        self.blocks = Vec::new();
        let mut held = [0.0f32; CELL_BLOCK];
        for b in 0..n_blocks {
            // Move the block at b to its place, bringing the one there to b, until b
            // holds its own.
            while dest[b] as usize != b {
                let to = dest[b] as usize;
                let (lo, hi) = (b.min(to), b.max(to));
                let (head, tail) = self.data.split_at_mut(hi * CELL_BLOCK);
                held.copy_from_slice(&head[lo * CELL_BLOCK..(lo + 1) * CELL_BLOCK]);
                head[lo * CELL_BLOCK..(lo + 1) * CELL_BLOCK].copy_from_slice(&tail[..CELL_BLOCK]);
                tail[..CELL_BLOCK].copy_from_slice(&held);
                dest.swap(b, to);
            }
        }
        Cells {
            data: self.data,
            start,
            len: self.len,
        }
    }
}

/// The profile's deviations with each cell's together ([`CellStore::into_contiguous`]).
struct Cells {
    data: Vec<f32>,
    start: Vec<usize>,
    len: Vec<usize>,
}

impl Cells {
    /// Cell `c`'s deviations, in the order they were binned.
    fn cell(&self, c: usize) -> &[f32] {
        &self.data[self.start[c]..self.start[c] + self.len[c]]
    }
}

/// Points per parallel job of [`profile`]'s pass over the points: large enough that a
/// job's cost (about 0.1 ms) dwarfs rayon's scheduling, small enough that a 20 000-point
/// frame still splits over a few cores and that a stop request waits at most one job.
const PROFILE_CHUNK: usize = 4096;

/// Jobs of [`profile`]'s second pass binned together: the (cell, deviation) pairs of one
/// batch, 8 bytes a point, are all that is held beside the cells (0.5 MiB for 16 jobs),
/// and 16 jobs keep every core of a small machine busy between two binnings.
const PROFILE_BATCH_CHUNKS: usize = 16;

/// The survey's false-alarm rate: the probability that a straight pipe's frame has a
/// departing slice (a shift or a bump), split equally between the two tests and, by
/// Bonferroni, over the slices and sectors tested, so that it holds whatever the
/// dependence between slices (adjacent slices share the correlated part of the noise).
/// 10⁻³ per frame keeps the issue's ≤ 1 % of straight frames read as a bend or a tee
/// with a margin of 10 for what the Gaussian model of the medians does not capture.
pub const SURVEY_FALSE_ALARM: f64 = 1e-3;

/// The median of χ² with one degree of freedom, (Φ⁻¹(0.75))² (Abramowitz & Stegun
/// 26.2): the scale of [`Slice::variance_ratio`].
pub(crate) const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_8;

/// Share of the residual degrees of freedom that the pooled variance law keeps: the
/// median of squared normal residuals as a scale estimate has an asymptotic efficiency
/// of 0.37 (the MAD's), the median-based line through the slices' ratios 2/π more:
/// 0.37·2/π ≈ 0.236.
pub(crate) const ROBUST_DOF_SHARE: f64 = 0.37 * 2.0 / std::f64::consts::PI;

/// Scale the medians' variances by what the sectors' scatter about their harmonic fits
/// shows, and set the critical values of the shift and bump tests.
///
/// **Why.** v_k = (π/2)σ_k²/n_k holds for independent points; a camera's range errors are
/// correlated between neighbouring pixels (on-camera filtering, flying-pixel smoothing:
/// issue 22 measured err/σ̂ spreads of 5–7 under a 2-pixel correlation), which makes a
/// sector's median as uncertain as that of n_k/DEFF points. The sectors of one slice lie
/// 30° apart on the wall, far further than any such correlation, so their residuals about
/// the harmonic fit are independent with variances κ·v_k(1 − h_k), and each slice's
/// [`Slice::variance_ratio`] estimates κ there.
///
/// **The law of κ.** The design effect of a cluster grows with the points it holds until
/// it spans many correlation areas: κ = 1 for independent points, ∝ n̄ when a sector lies
/// within one correlated patch (n̄ = points per sector). Measured in one frame of 2-pixel
/// correlated noise: ratios of about 60 in the near slices (≈ 150 points per sector), 3 in
/// the far ones (≈ 20). So κ_i = exp(a)·n̄_i^b, the line log r_i = a + b·log n̄_i fitted
/// by Theil–Sen (the median of pairwise slopes, clamped to b ∈ [0, 1], then the median
/// intercept): robust to the departing slices (a bend's distorted cross-section, a tee's
/// bumps) while fewer than about 29 % of the slices depart, and for a frame mostly in a
/// bend its shifts are many times any noise.
///
/// **Critical values.** With Cov(ĉ) scaled by κ̂_i, the shift's F = ĉᵀCov⁻¹ĉ/2 is F(2, ν̂)
/// distributed for a straight pipe, ν̂ = [`ROBUST_DOF_SHARE`]·Σν_i − 2 (the residual
/// degrees of freedom of the tested slices, less the law's two); one sector's excess over
/// the fit in units of its scaled standard error is t(ν̂). Each test gets half of
/// [`SURVEY_FALSE_ALARM`], divided among the n slices tested (and the sectors for the
/// bump, which takes the largest of them).
///
/// Returns the law κ(n) ([`crate::scene::sparse::DesignEffect`]) for the sparse slices'
/// opening test; independent points when no slice was tested.
pub(crate) fn calibrate_tests(
    slices: &mut [Slice],
    sectors: usize,
    axis: &AxisSigma,
    slice_m: f64,
) -> crate::scene::sparse::DesignEffect {
    // (ln n̄, ln r, ν) of each tested slice.
    let tested: Vec<(f64, f64, f64)> = slices
        .iter()
        .filter(|s| s.n_sectors >= MIN_SECTORS_TESTED && s.variance_ratio > 0.0 && s.misfit_dof > 0)
        .map(|s| {
            let per_sector = s.n_points as f64 / s.n_sectors as f64;
            (per_sector.ln(), s.variance_ratio.ln(), s.misfit_dof as f64)
        })
        .collect();
    if tested.is_empty() {
        return crate::scene::sparse::DesignEffect::INDEPENDENT;
    }
    let mut slopes: Vec<f64> = Vec::new();
    for (i, a) in tested.iter().enumerate() {
        for b in &tested[i + 1..] {
            let dx = b.0 - a.0;
            if dx.abs() > 1e-9 {
                slopes.push((b.1 - a.1) / dx);
            }
        }
    }
    let b = median(&mut slopes).unwrap_or(0.0).clamp(0.0, 1.0);
    let mut intercepts: Vec<f64> = tested.iter().map(|&(x, y, _)| y - b * x).collect();
    let a = median(&mut intercepts).unwrap_or(0.0);
    let dof = (ROBUST_DOF_SHARE * tested.iter().map(|t| t.2).sum::<f64>() - 2.0).max(1.0);
    let (critical_f, critical_t) = critical_values(tested.len(), dof, sectors);
    let kappas: Vec<f64> = slices
        .iter()
        .map(|s| {
            let per_sector = (s.n_points as f64 / s.n_sectors.max(1) as f64).max(1.0);
            (a + b * per_sector.ln()).exp().max(f64::MIN_POSITIVE)
        })
        .collect();
    for (s, kappa) in slices.iter_mut().zip(kappas) {
        let [vy, vz] = axis.lateral_variance(s.start_m + 0.5 * slice_m);
        let c = s.shift_cov_m2;
        s.shift_cov_m2 = [kappa * c[0] + vy, kappa * c[1], kappa * c[2] + vz];
        s.shift_se_m = shift_se(s.shift_m, s.shift_cov_m2);
        s.shift_f = shift_f(s.shift_m, s.shift_cov_m2);
        s.bump_se_m *= kappa.sqrt();
        s.least_half_var_m2 *= kappa;
        s.variance_scale = kappa;
        s.critical_f = critical_f;
        s.critical_t = critical_t;
        s.departure_p = departure_p(s, tested.len(), dof, sectors);
    }
    crate::scene::sparse::DesignEffect { a, b }
}

/// A slice's departure p-value with the Bonferroni split of [`critical_values`] (each of
/// the two tests gets half the false-alarm rate, divided among the `tested` slices, the
/// bump's also among the `sectors`): min(1, 2n·P(F(2, ν) > F), 2n·K·P(t(ν) > b/se_b)).
/// It lies below [`SURVEY_FALSE_ALARM`] exactly when the shift's F exceeds `critical_f`
/// or the bump's t exceeds `critical_t`. NaN for a slice with fewer than [`MIN_SECTORS_TESTED`] sectors,
/// which the survey does not test.
fn departure_p(s: &Slice, tested: usize, dof: f64, sectors: usize) -> f64 {
    if s.n_sectors < MIN_SECTORS_TESTED {
        return f64::NAN;
    }
    let n = 2.0 * tested.max(1) as f64;
    let p_shift = n * crate::fit::student::f_upper_tail(s.shift_f, 2.0, dof);
    let t = s.bump_m / s.bump_se_m;
    let p_bump = if t > 0.0 {
        n * sectors as f64 * crate::fit::student::student_t_upper_tail(t, dof)
    } else {
        1.0
    };
    // A NaN statistic (no fit) is no evidence.
    [p_shift, p_bump]
        .into_iter()
        .filter(|p| !p.is_nan())
        .fold(1.0, f64::min)
}

/// The evidence of a departure in a profile: −log₁₀ of its least [`Slice::departure_p`],
/// 0 when no slice was tested. A straight pipe's frame reaches −log₁₀
/// [`SURVEY_FALSE_ALARM`] (3) with probability at most [`SURVEY_FALSE_ALARM`] under the
/// profile's Gaussian model of the medians; a p-value below the smallest positive double
/// counts as that (evidence ≈ 307.7).
pub fn departure_evidence(profile: &[Slice]) -> f64 {
    let p = profile
        .iter()
        .map(|s| s.departure_p)
        .filter(|p| !p.is_nan())
        .fold(1.0, f64::min);
    // 0 − log₁₀ p, not −log₁₀ p: a p of 1 gives +0, not −0 (which JSON prints as "-0").
    0.0 - p.max(f64::MIN_POSITIVE).log10()
}

/// The median of `v` (reordered), `None` when empty.
pub(crate) fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let mid = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[mid]
    } else {
        0.5 * (v[mid - 1] + v[mid])
    })
}

/// F = ĉᵀC⁻¹ĉ/2 for a shift ĉ with covariance C = [c₁₁, c₁₂, c₂₂] (NaN when C is singular).
pub(crate) fn shift_f(shift: [f64; 2], cov: [f64; 3]) -> f64 {
    let c = nalgebra::Matrix2::new(cov[0], cov[1], cov[1], cov[2]);
    c.try_inverse().map_or(f64::NAN, |info| {
        let v = nalgebra::Vector2::new(shift[0], shift[1]);
        0.5 * (v.transpose() * info * v)[0]
    })
}

/// The standard error of a shift's length: along its direction (the mean of the two
/// variances when the shift is zero).
pub(crate) fn shift_se(shift: [f64; 2], cov: [f64; 3]) -> f64 {
    let len = shift[0].hypot(shift[1]);
    if len > 0.0 {
        let (u, v) = (shift[0] / len, shift[1] / len);
        (u * u * cov[0] + 2.0 * u * v * cov[1] + v * v * cov[2]).sqrt()
    } else {
        (0.5 * (cov[0] + cov[2])).sqrt()
    }
}

/// The straight fit's 1-σ of where its axis lies (from its reported uncertainty): the
/// offsets δy, δz (m) and the tilts yaw, pitch (rad) of eq. (3).
///
/// A slice's shift is measured against the fitted axis, so the fit's own error at the
/// slice, δ + x·θ to first order (yaw turns the axis toward ±Y of the PCS, pitch toward
/// ∓Z), reads as a shift there. Where the fit hardly depends on the slice (the far slices
/// of a frame, which hold few of its points) the two errors are independent and their
/// variances add: σ_y²(x) = σ_δy² + x²σ_yaw², σ_z²(x) = σ_δz² + x²σ_pitch² (covariances
/// between offset and tilt left out). Where the fit is pinned by the slice, this overstates
/// the shift's variance, which only makes the test more conservative there. Under 2-pixel
/// correlated noise the reported tilts' 1-σ are 0.1–0.5°, 5–12 mm at 1.4 m: the size of
/// the far slices' shifts that were read as a tee without this term.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisSigma {
    /// 1-σ of δy (m).
    pub dy: f64,
    /// 1-σ of δz (m).
    pub dz: f64,
    /// 1-σ of yaw (rad).
    pub yaw: f64,
    /// 1-σ of pitch (rad).
    pub pitch: f64,
    /// The axis's lateral covariance from the estimate's full covariance
    /// ([`crate::estimate::AxisCov`]); when given, it replaces the four 1-σ above.
    pub cov: Option<crate::estimate::AxisCov>,
}

impl AxisSigma {
    /// From an estimate: its axis's lateral covariance ([`Estimate::axis_cov`]), else its
    /// reported 1-σ (a parameter without one counts as known). A near-round pipe's roll is
    /// nearly undetermined, and its reported pitch, yaw and offsets carry the turn of the
    /// cross-section's labels that leaves the axis in place (a round 20" pipe: pitch and
    /// yaw 2°, δz 44 mm reported, which would hide a 5 cm shift 1.5 m ahead); the
    /// covariance does not. A fit the form test refused (`lack_of_fit`) has a 1-σ that
    /// measures its misfit rather than its noise: its axis counts as known, so that the
    /// profile shows the misfit.
    pub fn of(e: &Estimate) -> Self {
        if matches!(e.status, crate::check::FitStatus::LackOfFit(_)) {
            return Self::default();
        }
        let s = |i: usize| e.sigma[i].filter(|v| v.is_finite()).unwrap_or(0.0);
        // Params order: d_max, d_min, roll, pitch, yaw, dy, dz.
        Self {
            pitch: s(3),
            yaw: s(4),
            dy: s(5),
            dz: s(6),
            cov: e.axis_cov,
        }
    }

    /// The variances of the axis's lateral position at axial distance x (m²): toward +Y
    /// and toward +Z of the PCS.
    pub fn lateral_variance(&self, x: f64) -> [f64; 2] {
        if let Some(c) = &self.cov {
            return c.lateral_variance(x);
        }
        [
            self.dy * self.dy + (x * self.yaw).powi(2),
            self.dz * self.dz + (x * self.pitch).powi(2),
        ]
    }
}

/// The shift's critical F and the bump's critical t for `tested` slices of `sectors`
/// sectors, the variance scale estimated with `dof` degrees of freedom
/// ([`calibrate_tests`]).
pub(crate) fn critical_values(tested: usize, dof: f64, sectors: usize) -> (f64, f64) {
    let alpha = 0.5 * SURVEY_FALSE_ALARM / tested.max(1) as f64;
    (
        crate::fit::student::f_upper_quantile(alpha, 2.0, dof),
        crate::fit::student::student_t_quantile(1.0 - alpha / sectors as f64, dof),
    )
}

/// One slice's statistics from its sectors' deviations (m, held in 32 bits: a relative
/// rounding of 6·10⁻⁸, 10⁻⁹ m on a 2 cm deviation, far below any camera's range noise,
/// which halves the survey's memory per point; the statistics are taken in 64 bits).
pub(crate) fn slice_stats<C: AsRef<[f32]>>(
    sectors: &[C],
    start_m: f64,
    o: &SegmentOptions,
) -> Slice {
    let ns = sectors.len();
    let tau = std::f64::consts::TAU;
    let n_points = sectors.iter().map(|c| c.as_ref().len()).sum();
    // (ψ, median, variance of the median) per usable sector.
    let mut meds: Vec<(f64, f64, f64)> = Vec::new();
    let mut by_sector = vec![f64::NAN; ns];
    let mut var_by_sector = vec![f64::NAN; ns];
    let (mut v, mut dev): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    for (k, cell) in sectors.iter().enumerate() {
        let cell = cell.as_ref();
        if cell.len() < o.min_points {
            continue;
        }
        v.clear();
        v.extend(cell.iter().map(|&d| f64::from(d)));
        let n = v.len() as f64;
        let (m, s) = crate::loss::median_and_mad_sigma_in(&mut v, &mut dev);
        // Var(median) ≈ (π/2)·σ²/n, floored so that a noise-free slice is not infinitely
        // certain.
        let var = (std::f64::consts::FRAC_PI_2 * s * s / n).max(1e-12);
        let psi = (k as f64 + 0.5) / ns as f64 * tau;
        meds.push((psi, m, var));
        by_sector[k] = m;
        var_by_sector[k] = var;
    }
    let mut out = Slice {
        n_points,
        n_sectors: meds.len(),
        ..Slice::empty(start_m)
    };
    if meds.len() < 3 {
        return out;
    }
    // Weighted least squares m_k ≈ c₀ + c₁cos ψ + c₂sin ψ.
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    for &(psi, m, var) in &meds {
        let row = Vector3::new(1.0, psi.cos(), psi.sin());
        a += row * row.transpose() / var;
        rhs += row * m / var;
    }
    let Some(inv) = a.try_inverse() else {
        return out;
    };
    let c = inv * rhs;
    out.widening_m = c[0];
    out.shift_m = [c[1], c[2]];
    out.shift_cov_m2 = [inv[(1, 1)], inv[(1, 2)], inv[(2, 2)]];
    out.shift_se_m = shift_se(out.shift_m, out.shift_cov_m2);
    out.shift_f = shift_f(out.shift_m, out.shift_cov_m2);
    out.misfit_dof = meds.len() - 3;
    let mut ratios: Vec<f64> = Vec::with_capacity(meds.len());
    // The sector furthest outside the harmonic fit, in units of its standard error.
    let mut best = f64::NEG_INFINITY;
    for &(psi, m, var) in &meds {
        let row = Vector3::new(1.0, psi.cos(), psi.sin());
        let excess = m - row.dot(&c);
        let leverage = (row.transpose() * inv * row)[0] / var;
        ratios.push(excess * excess / (var * (1.0 - leverage).max(f64::EPSILON)));
        let se = (var + (row.transpose() * inv * row)[0].max(0.0)).sqrt();
        if excess / se > best {
            best = excess / se;
            (out.bump_m, out.bump_se_m, out.bump_psi) = (excess, se, psi);
        }
    }
    if out.misfit_dof > 0 {
        out.variance_ratio = median(&mut ratios).unwrap_or(f64::NAN) / CHI2_1_MEDIAN;
    }
    (out.least_half_m, out.least_half_var_m2) = least_half(&by_sector, &var_by_sector);
    let dir = c[2].atan2(c[1]);
    let opp = ((dir + std::f64::consts::PI).rem_euclid(tau) / tau * ns as f64) as usize % ns;
    out.opposite_m = by_sector[opp];
    out
}

/// The least mean of the sector medians `by_sector` over the rotations of a half of the
/// circumference, and its variance from `var_by_sector` ([`Slice::least_half_m`]); NaN
/// without a half of which at least half the sectors have medians.
fn least_half(by_sector: &[f64], var_by_sector: &[f64]) -> (f64, f64) {
    let ns = by_sector.len();
    let half = ns / 2;
    let mut least = (f64::NAN, f64::NAN);
    for k0 in 0..ns {
        let (mut sum, mut var, mut n) = (0.0, 0.0, 0usize);
        for k in (k0..k0 + half).map(|k| k % ns) {
            if by_sector[k].is_finite() {
                sum += by_sector[k];
                var += var_by_sector[k];
                n += 1;
            }
        }
        if n == 0 || 2 * n < half {
            continue;
        }
        let mean = sum / n as f64;
        let var = var / (n * n) as f64;
        if !(mean >= least.0) {
            least = (mean, var);
        }
    }
    least
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A half of the wall out reads no widening of its least half; the whole wall out
    /// reads it, with the variance of a mean of the half's medians; sectors without
    /// medians are left out of their half's mean.
    #[test]
    fn the_least_half_is_out_only_when_the_whole_wall_is() {
        let var = vec![1e-6; 12];
        let half_out: Vec<f64> = (0..12).map(|k| if k < 6 { 0.02 } else { 0.0 }).collect();
        assert_eq!(least_half(&half_out, &var).0, 0.0);
        let all_out = vec![0.02; 12];
        let (m, v) = least_half(&all_out, &var);
        assert!((m - 0.02).abs() < 1e-15 && (v - 1e-6 / 6.0).abs() < 1e-18);
        // A tube shifted sideways (a bend): one half out, the other in.
        let bent: Vec<f64> = (0..12)
            .map(|k| 0.02 * ((k as f64 + 0.5) / 12.0 * std::f64::consts::TAU).cos())
            .collect();
        assert!(least_half(&bent, &var).0 < -0.01);
        // Sectors without medians: a half needs three of its six.
        let mut sparse = vec![f64::NAN; 12];
        sparse[0] = 0.01;
        assert!(least_half(&sparse, &var).0.is_nan());
        for k in [0, 1, 2] {
            sparse[k] = 0.01;
        }
        let (m, v) = least_half(&sparse, &var);
        assert!((m - 0.01).abs() < 1e-15 && (v - 1e-6 / 3.0).abs() < 1e-18);
    }

    /// Cells filled block by block, interleaved at random, read back each its deviations
    /// in order once made contiguous, on either side of a block's edge; the store never
    /// outgrows the room it took at the start.
    #[test]
    fn a_cell_store_keeps_each_cells_deviations_in_order() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move |m: usize| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % m as u64) as usize
        };
        for (cells, n) in [
            (1, 0),
            (1, 1),
            (3, CELL_BLOCK),
            (7, 3 * CELL_BLOCK + 5),
            (40, 5000),
        ] {
            let mut store = CellStore::new(cells, n);
            let room = store.data.capacity();
            let mut want = vec![Vec::new(); cells];
            for k in 0..n {
                let c = next(cells);
                let d = k as f32 * 0.25 - 7.0;
                store.push(c, d);
                want[c].push(d);
            }
            assert_eq!(store.data.capacity(), room, "the store grew");
            let got = store.into_contiguous();
            for (c, w) in want.iter().enumerate() {
                assert_eq!(
                    got.cell(c),
                    w.as_slice(),
                    "cell {c} of {cells}, {n} deviations"
                );
            }
        }
    }

    /// The clock sector by comparisons against its definition with `atan2`, for sector
    /// counts that divide the quadrants (the comparisons) and that do not (the fallback),
    /// on random points, on the axes and at signed zeros; points within 1e-12 rad of a
    /// boundary are skipped (there the two may round differently).
    #[test]
    fn clock_sector_matches_the_atan2_definition() {
        let tau = std::f64::consts::TAU;
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for s in [1usize, 3, 4, 8, 12, 16, 36] {
            let clock = ClockSectors::new(s);
            let by_atan2 = |y: f64, z: f64| {
                ((z.atan2(y).rem_euclid(tau) / tau * s as f64) as usize).min(s - 1)
            };
            let mut pts: Vec<(f64, f64)> = (0..20_000).map(|_| (next(), next())).collect();
            pts.extend([
                (1.0, 0.0),
                (1.0, -0.0),
                (0.0, 1.0),
                (-0.0, 1.0),
                (-1.0, 0.0),
                (-1.0, -0.0),
                (0.0, -1.0),
                (-0.0, -1.0),
                (0.0, 0.0),
                (-0.0, -0.0),
            ]);
            for (y, z) in pts {
                let psi = z.atan2(y).rem_euclid(tau);
                let edge = (psi / tau * s as f64).round() * tau / s as f64;
                if (psi - edge).abs() < 1e-12 && y != 0.0 && z != 0.0 {
                    continue;
                }
                assert_eq!(clock.of(y, z), by_atan2(y, z), "s = {s}, ({y}, {z})");
            }
        }
    }
}
