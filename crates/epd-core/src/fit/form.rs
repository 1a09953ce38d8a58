//! A test that the model fits: does any region of the wall lie off the fitted elliptic
//! cylinder by more than the scatter of its own points?
//!
//! The wall is cut into the cells of the cluster-robust covariance
//! ([`crate::problem::Cells`], by where each sensing line meets the fitted wall, so a
//! point's own noise does not choose its cell). In each cell g of n_g points, m_g is the
//! median range residual (robust to a minority of stray returns) and s_g = 1.4826·MAD its
//! points' robust scatter. The form tolerance is twice the frame's noise scale,
//! τ = [`FORM_TOLERANCE_SCALES`]·1.4826·median|r| over all points: a camera's own smooth
//! systematic errors left after its depth table (wiggling of a few mm under σ of 1–3 cm)
//! stay within it; a floor layer, debris, a fitting or multipath that lengthens a band of
//! ranges by a few noise scales do not.
//! The median of n points of scale s has standard error √(π/2)·s/√n, so the cell's
//! statistic is
//!
//!   z_g = (|m_g| − τ) / (1.2533·s_g/√n_g),
//!
//! and the frame fails when max_g z_g exceeds z*, the two-sided normal quantile at the
//! level [`LACK_OF_FIT_ALPHA`] shared by the G cells (Bonferroni: 1 − α/(2G)). With the
//! model exact, |m_g| ≪ τ and z_g is far below zero, so the false-alarm rate is at
//! most α whatever the correlation of the noise within a cell (which widens the median's
//! spread by a few times at most, against a margin of √n_g/1.2533 ≫ z*).

use crate::fit::student::f_upper_quantile;
use crate::params::Params;
use crate::problem::{Cells, for_each_range_and_cell};
use crate::residual::Geometry;

/// The level of the form test per frame: at most one frame in a thousand whose wall is
/// an elliptic cylinder is flagged.
pub const LACK_OF_FIT_ALPHA: f64 = 1e-3;

/// The least tolerance, as a fraction of Dmax + Dmin: 10⁷ times the rounding of the
/// geometry in f64 and far below any physical form deviation (0.5 nm on a 20" pipe), so
/// noise-free clouds are not failed for their rounding.
pub const NOISE_FREE_FLOOR: f64 = 1e-9;

/// Axial bins of the form test's cells (of equal point counts, times the 12 clock
/// sectors of the covariance's cells): twice the covariance's, so that a band of the wall
/// a tenth of the points long (multipath over a metre of range, a deposit, a dent) fills
/// whole cells rather than half of one.
pub const FORM_AXIAL_CELLS: usize = 16;

/// The form tolerance in units of the frame's noise scale: a region is off the model
/// when its median lies more than twice the noise scale from the fitted wall. Measured
/// (`epd estimate --calibration` on three frames of `epd simulate --sensor helios2`, a
/// table from six rig frames of a 484 mm pipe; their diameters within 2.1 mm of the
/// truth): at one noise scale every frame was refused for regions near the far edge of
/// the table's range lying 1.3–2.4 noise scales off — good frames refused; at two, with
/// the residuals in units of each point's σᵢ from the table, they pass. A 10 cm floor
/// deposit (5 noise scales) is caught at two; multipath lengthening a band by 2.5 noise
/// scales is not (docs/trust.md, "The form test"): its effect on the estimate is carried
/// by the 1-σ instead, through the test for errors shared along the axis
/// ([`WallCells::shared_along_axis`]).
pub const FORM_TOLERANCE_SCALES: f64 = 2.0;

/// At most this many points (evenly strided) are tested: 65 536 points put about 340 in
/// each of the form test's 192 cells ([`FORM_AXIAL_CELLS`] × 12 sectors), whose median
/// then has a standard error of 1.2533/√340 = 0.07 of the noise — a region off by 1.3
/// times the noise is found — and the test holds 12 B per point tested (a residual and its
/// cell while they are gathered), 0.75 MB whatever the frame.
///
/// Why 2¹⁶ and not 2¹⁵: the test for errors shared along the axis
/// ([`WallCells::shared_along_axis`]) compares slice means whose standard errors shrink as
/// 1/√n, so its F grows as n where the estimate's 1-σ shrinks as 1/√N over all N points.
/// A band of multipath in the far slices, where few points carry much of the
/// information on the diameters, moved them by 4–7σ̂ while the test, at 2¹⁵ points,
/// missed it (tof-sim's 8" frames with rays of 1–2 m read 5 cm long:
/// `EPD_OD_IN=8.625 EPD_WALL_MM=8.18 cargo run --release -p epd-frame --example coverage --
/// 100 multipath`, Welch F 3.8 against a critical 4.3 on one frame; 1 of 100 beyond
/// max(5σ̂, 0.5 mm), coverage 0.90). At 2¹⁶ its F doubles: 0 of 100, coverage
/// 0.96/0.96/0.98; the 20" frames of every other model of the example unchanged within
/// one frame of 40. The test then cost 4.5 ms at 10⁵ points against 1.8 ms at 2¹⁵
/// (`cargo bench -p epd-core -- parts`); with its residuals, wall points and cells in
/// AVX2 registers ([`crate::problem::for_each_range_and_cell`]) it costs 1.8 ms on 2¹⁶
/// (docs/benchmarks.md).
pub const FORM_POINTS: usize = 65_536;

/// A cell holding less than 1/[`SLIVER_FRACTION`] of its share N/G of the points is not
/// tested: the cells are cut to hold equal shares, so such a cell is a sliver at the edge
/// of the view whose points come from a few patches of pixels; correlated as one, its
/// median spreads like one point's error, not like s/√n.
pub const SLIVER_FRACTION: usize = 4;

/// Fewest points a cell needs to be tested: with n = 32 the median's standard error is
/// 1.2533/√32 = 0.22 of the cell's scatter, so a region off by twice its scatter is
/// 4.5 standard errors beyond the tolerance.
pub const MIN_CELL_POINTS: usize = 32;

/// Where the wall departs from the fitted model most, when it does beyond tolerance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FormMisfit {
    /// Distance along the pipe axis from the sensor of the region's centre (m, PCS x).
    pub x_m: f64,
    /// Its clock angle around the pipe axis (deg, PCS: 0 along +Z, the minor axis; 90
    /// along +Y, the major axis).
    pub clock_deg: f64,
    /// Its median range residual (m; positive: the points lie beyond the fitted wall).
    pub offset_m: f64,
    /// The tolerance it exceeds: [`FORM_TOLERANCE_SCALES`] times the frame's noise scale (m).
    pub tolerance_m: f64,
    /// The statistic z_g against the critical value.
    pub z: f64,
    /// The critical value z*.
    pub critical: f64,
    /// Whether the region is a whole slice of the wall (every clock angle at `x_m`;
    /// [`WallCells::misfit_slices`]) rather than one cell; `clock_deg` is then NaN.
    pub all_around: bool,
    /// For slices: the largest change of Dmax or Dmin (m) when the failing slices are
    /// left out of the fit; NaN for a cell.
    pub diameter_shift_m: f64,
}

impl std::fmt::Display for FormMisfit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let side = if self.offset_m > 0.0 {
            "beyond"
        } else {
            "inside"
        };
        if self.all_around {
            return write!(
                f,
                "the wall {:.2} m ahead lies {:.1} mm {} the fitted pipe all around, more than \
                 the tolerance of {:.1} mm for a whole slice (the frame's noise scale; z = {:.1} > \
                 {:.1}), and leaving such slices out moves the diameters by {:.1} mm: the \
                 camera's ranges there are off by an error shared along the pipe (multipath, \
                 a calibration error) or the pipe's size changes",
                self.x_m,
                self.offset_m.abs() * 1e3,
                side,
                self.tolerance_m * 1e3,
                self.z,
                self.critical,
                self.diameter_shift_m * 1e3
            );
        }
        write!(
            f,
            "the wall {:.2} m ahead at clock {:.0}° lies {:.1} mm {} the fitted pipe, more than \
             the tolerance of {:.1} mm (twice the frame's noise scale; z = {:.1} > {:.1}): the pipe is not an \
             elliptic cylinder there (debris, a deposit, a dent, a fitting) or the camera's \
             error is systematic there (multipath)",
            self.x_m,
            self.clock_deg,
            self.offset_m.abs() * 1e3,
            side,
            self.tolerance_m * 1e3,
            self.z,
            self.critical
        )
    }
}

/// The upper α quantile of the standard normal, z with P(Z > z) = α, for 0 < α < 0.5 (the
/// tail of Abramowitz & Stegun 26.2.23, refined by two Newton steps on erfc: accurate to
/// 1e-9 for α ≥ 1e-15).
pub fn normal_upper_quantile(alpha: f64) -> f64 {
    let t = (-2.0 * alpha.ln()).sqrt();
    let mut z = t
        - (2.515517 + 0.802853 * t + 0.010328 * t * t)
            / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t * t * t);
    for _ in 0..2 {
        let tail = 0.5 * erfc(z / std::f64::consts::SQRT_2);
        let density = (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
        z += (tail - alpha) / density;
    }
    z
}

/// The complementary error function (Numerical Recipes' erfcc, fractional error < 1.2e-7,
/// then good enough for the Newton steps of [`normal_upper_quantile`] to converge on it).
pub(crate) fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.26551223
            + t * (1.00002368
                + t * (0.37409196
                    + t * (0.09678418
                        + t * (-0.18628806
                            + t * (0.27886807
                                + t * (-1.13520398
                                    + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277)))))))))
            .exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// One cell of the form test: its tested points' median range residual, their robust
/// scatter, the count, and the sums that place its centre.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CellMedian {
    /// Index in [`Cells`] (axial bin · sectors + sector).
    pub id: usize,
    /// Points tested in the cell.
    pub n: usize,
    /// Median range residual m_g (m, scaled by sᵢ when weighted).
    pub median: f64,
    /// 1.4826·MAD of the cell's residuals about m_g (m).
    pub scale: f64,
    /// Mean axial distance of the cell's wall points (m, PCS x).
    pub x_m: f64,
    /// Clock angle of the cell's centre (deg, as [`FormMisfit::clock_deg`]).
    pub clock_deg: f64,
}

/// One slice of the wall along the axis ([`WallCells::slice_means`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SliceMean {
    /// Its axial bin.
    pub bin: usize,
    /// ȳ_k, the mean of its cells' medians (m).
    pub mean: f64,
    /// s_k²/n_k, the variance of ȳ_k from its cells' spread (m²).
    pub var_mean: f64,
}

/// The wall's cells as the form test sees them: each tested cell's median and scatter,
/// and the frame's noise scale.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WallCells {
    /// The cells holding enough points to be tested (see [`MIN_CELL_POINTS`],
    /// [`SLIVER_FRACTION`]), in cell order.
    pub cells: Vec<CellMedian>,
    /// Clock sectors per axial bin.
    pub sectors: usize,
    /// The frame's noise scale: 1.4826·median|rᵢ| over every tested point (m), at least
    /// [`NOISE_FREE_FLOOR`]·(Dmax + Dmin).
    pub noise_scale: f64,
}

impl WallCells {
    /// The residuals of `points` (SCS, m) at β gathered by `cells` (see the module doc),
    /// each range residual multiplied by its point's scale sᵢ = σ̃/σᵢ when the fit is
    /// weighted (`scales`, one per point): a weighted fit's model says the points' noise
    /// differs, and a region is then judged in units of its own points' σᵢ. `None` when
    /// β is outside the model or no cell holds enough points.
    pub fn gather(
        points: &[[f64; 3]],
        scales: Option<&[f64]>,
        beta: &Params,
        cells: &Cells,
    ) -> Option<Self> {
        let geom = Geometry::new(beta)?;
        let g = cells.len();
        let indexer = cells.indexer();
        // On at most FORM_POINTS evenly strided points, in one pass: each point's cell and
        // residual (and the sums of each cell's axial distances and clock-angle sines and
        // cosines), then the residuals grouped by cell in one buffer, in their order
        // (a counting sort). At most FORM_POINTS of each are held, 12 B a point beside
        // the grouped residuals' 8 B (1.31 MB at 2¹⁶: the estimate's largest part,
        // `tests/memory.rs`); a second pass over the points to write the residuals
        // instead cost 0.7 ms a full frame.
        let stride = points.len().div_ceil(FORM_POINTS).max(1);
        let scale_of = |i: usize| scales.and_then(|s| s.get(i)).copied().unwrap_or(1.0);
        let mut cell_of: Vec<u32> = Vec::with_capacity(points.len().div_ceil(stride));
        let mut value_of: Vec<f64> = Vec::with_capacity(points.len().div_ceil(stride));
        let mut counts = vec![0usize; g];
        let mut centre = vec![[0.0f64; 3]; g];
        for_each_range_and_cell(&geom, &indexer, points, stride, |i, r, c, [x, y, z]| {
            let value = scale_of(i) * r;
            if !value.is_finite() {
                return;
            }
            // Cells number far below 2³² (axial bins × sectors of a few hundred at most).
            cell_of.push(u32::try_from(c).unwrap_or(u32::MAX));
            value_of.push(value);
            counts[c] += 1;
            // sin and cos of the clock angle atan2(y, z); ρ by a plain square root, not
            // `hypot` (which guards against overflow, impossible for a wall point, at a
            // quarter of the whole test's time).
            let rho = (y * y + z * z).sqrt();
            centre[c][0] += x;
            if rho > 0.0 {
                centre[c][1] += y / rho;
                centre[c][2] += z / rho;
            }
        });
        let n_all: usize = counts.iter().sum();
        let min_points = MIN_CELL_POINTS.max(n_all / (SLIVER_FRACTION * g));
        if !counts.iter().any(|&n| n >= min_points) {
            return None;
        }
        let mut start = Vec::with_capacity(g + 1);
        start.push(0usize);
        for n in &counts {
            start.push(start[start.len() - 1] + n);
        }
        let mut residuals = vec![0.0f64; n_all];
        let mut fill = start.clone();
        for (&c, &value) in cell_of.iter().zip(&value_of) {
            if let Some(slot) = fill.get_mut(c as usize) {
                residuals[*slot] = value;
                *slot += 1;
            }
        }
        drop((cell_of, value_of));
        let mut tested = Vec::new();
        let mut dev = Vec::new();
        for (id, c) in centre.iter().enumerate() {
            let cell = &mut residuals[start[id]..start[id + 1]];
            let n = cell.len();
            if n < min_points {
                continue;
            }
            let median = crate::fit::check::quantile(cell, 0.5);
            dev.clear();
            dev.extend(cell.iter().map(|v| (v - median).abs()));
            tested.push(CellMedian {
                id,
                n,
                median,
                scale: crate::loss::mad_sigma(&mut dev),
                x_m: c[0] / n as f64,
                clock_deg: c[1].atan2(c[2]).to_degrees().rem_euclid(360.0),
            });
        }
        // The frame's noise scale: the robust scale of every residual (a median, the same
        // whatever the order the cells' medians left them in), with a floor for
        // noise-free clouds, whose residuals are rounding (~1e-16 relative): 1e-9 of the
        // diameter, far below any physical form deviation.
        for r in &mut residuals {
            *r = r.abs();
        }
        let noise_scale = crate::loss::mad_sigma(&mut residuals)
            .max(NOISE_FREE_FLOOR * (beta.d_max + beta.d_min));
        Some(WallCells {
            cells: tested,
            sectors: cells.sectors.max(1),
            noise_scale,
        })
    }

    /// The form test (see the module doc): `Some` misfit when a region lies off the
    /// fitted wall beyond the tolerance [`FORM_TOLERANCE_SCALES`]·noise scale at the level
    /// [`LACK_OF_FIT_ALPHA`], `None` when none does.
    pub fn form_test(&self) -> Option<FormMisfit> {
        let tolerance = FORM_TOLERANCE_SCALES * self.noise_scale;
        let critical = normal_upper_quantile(LACK_OF_FIT_ALPHA / (2.0 * self.cells.len() as f64));
        let mut worst: Option<FormMisfit> = None;
        for c in &self.cells {
            if !(c.scale > 0.0) {
                continue;
            }
            let z =
                (c.median.abs() - tolerance) / (MEDIAN_SE_FACTOR * c.scale / (c.n as f64).sqrt());
            if z > critical && worst.is_none_or(|w| z > w.z) {
                worst = Some(FormMisfit {
                    x_m: c.x_m,
                    clock_deg: c.clock_deg,
                    offset_m: c.median,
                    tolerance_m: tolerance,
                    z,
                    critical,
                    all_around: false,
                    diameter_shift_m: f64::NAN,
                });
            }
        }
        worst
    }

    /// The form test of whole slices: each axial bin k's offset ȳ_k, the mean of its n_k ≥ 2
    /// tested cells' medians, with standard error s_k/√n_k from their spread (so noise
    /// correlated within a cell or growing with range is in it), against the tolerance
    /// [`SLICE_TOLERANCE_SCALES`]·noise scale:
    ///
    ///   z_k = (|ȳ_k| − τ_s) / (s_k/√n_k),
    ///
    /// failing when z_k exceeds the two-sided normal quantile at [`LACK_OF_FIT_ALPHA`]
    /// shared by the K slices (Bonferroni). Every failing slice, worst first, as (axial bin,
    /// misfit); none when fewer than [`MIN_SLICES`] slices are tested. Whether the frame
    /// is refused for them is decided by what they do to the diameters (the estimator's
    /// `slice_shift`): a depth table may leave the nearest ranges a few mm off under a
    /// noise of 3 mm without moving the diameters.
    pub fn misfit_slices(&self) -> Vec<(usize, FormMisfit)> {
        let slices = self.slices();
        if slices.len() < MIN_SLICES {
            return Vec::new();
        }
        let tolerance = SLICE_TOLERANCE_SCALES * self.noise_scale;
        let critical = normal_upper_quantile(LACK_OF_FIT_ALPHA / (2.0 * slices.len() as f64));
        let mut found: Vec<(usize, FormMisfit)> = Vec::new();
        for s in &slices {
            let n = s.len() as f64;
            let mean = s.iter().map(|c| c.median).sum::<f64>() / n;
            let var = s.iter().map(|c| (c.median - mean).powi(2)).sum::<f64>() / (n - 1.0);
            if !(var > 0.0) {
                continue;
            }
            let z = (mean.abs() - tolerance) / (var / n).sqrt();
            if z > critical {
                found.push((
                    s[0].id / self.sectors,
                    FormMisfit {
                        x_m: s.iter().map(|c| c.x_m).sum::<f64>() / n,
                        clock_deg: f64::NAN,
                        offset_m: mean,
                        tolerance_m: tolerance,
                        z,
                        critical,
                        all_around: true,
                        diameter_shift_m: f64::NAN,
                    },
                ));
            }
        }
        found.sort_by(|a, b| b.1.z.total_cmp(&a.1.z));
        found
    }

    /// The tested cells grouped by axial bin, slices of fewer than two cells left out.
    fn slices(&self) -> Vec<Vec<CellMedian>> {
        let mut slices: Vec<Vec<CellMedian>> = Vec::new();
        let mut last = usize::MAX;
        for c in &self.cells {
            let k = c.id / self.sectors;
            if k != last {
                slices.push(Vec::new());
                last = k;
            }
            if let Some(s) = slices.last_mut() {
                s.push(*c);
            }
        }
        slices.retain(|s| s.len() >= 2);
        slices
    }

    /// Whether the cells' medians differ between slices along the axis more than within
    /// them: Welch's one-way analysis of variance (Welch 1951, Biometrika 38:330) of the
    /// cell medians grouped by axial bin, each slice k holding n_k ≥ 2 tested cells with
    /// mean ȳ_k and variance s_k² of its medians, weights w_k = n_k/s_k²:
    ///
    ///   F = [Σ w_k(ȳ_k − ȳ_w)²/(K − 1)] / [1 + 2(K − 2)/(K² − 1)·Λ],
    ///   Λ = Σ (1 − w_k/W)²/(n_k − 1),  ν₁ = K − 1,  ν₂ = (K² − 1)/(3Λ),
    ///
    /// with W = Σ w_k and ȳ_w = Σ w_k ȳ_k/W; `true` when F exceeds the upper
    /// [`SHARED_ERROR_ALPHA`] quantile of F(ν₁, ν₂). The within-slice spread is that of the
    /// cells' own medians, so noise correlated within a cell (which widens each median's
    /// spread) and noise whose σ changes with range (each slice its own s_k²) do not raise
    /// F; a range error shared by a slice's clock sectors — multipath over a band of
    /// ranges, a wiggle of the phase unwrapping, a range offset left by a calibration —
    /// moves whole slices and does. `None` with fewer than [`MIN_SLICES`] slices of two
    /// or more cells, or a slice whose medians do not spread.
    pub fn shared_along_axis(&self) -> Option<bool> {
        let (f, nu1, nu2) = self.welch_f()?;
        Some(f > f_upper_quantile(SHARED_ERROR_ALPHA, nu1, nu2))
    }

    /// The slices of the wall along the axis as the tests see them: per tested slice (an
    /// axial bin with n_k ≥ 2 tested cells, in axial order) its bin, the mean ȳ_k of its
    /// cells' medians and that mean's variance s_k²/n_k from their spread (m and m², in
    /// the units of the medians). `uncertainty::shared_offset_cov` carries the error they
    /// share into the 1-σ.
    pub fn slice_means(&self) -> Vec<SliceMean> {
        self.slices()
            .iter()
            .map(|s| {
                let n = s.len() as f64;
                let mean = s.iter().map(|c| c.median).sum::<f64>() / n;
                let var = s.iter().map(|c| (c.median - mean).powi(2)).sum::<f64>() / (n - 1.0);
                SliceMean {
                    bin: s[0].id / self.sectors,
                    mean,
                    var_mean: var / n,
                }
            })
            .collect()
    }

    /// Welch's F of [`shared_along_axis`](Self::shared_along_axis) and its degrees of
    /// freedom (ν₁, ν₂).
    pub fn welch_f(&self) -> Option<(f64, f64, f64)> {
        let slices: Vec<Vec<f64>> = self
            .slices()
            .iter()
            .map(|s| s.iter().map(|c| c.median).collect())
            .collect();
        let k = slices.len();
        if k < MIN_SLICES {
            return None;
        }
        let mut stats = Vec::with_capacity(k);
        for s in &slices {
            let n = s.len() as f64;
            let mean = s.iter().sum::<f64>() / n;
            let var = s.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
            if !(var > 0.0) {
                return None;
            }
            stats.push((n, mean, n / var));
        }
        let w: f64 = stats.iter().map(|s| s.2).sum();
        let mean_w = stats.iter().map(|s| s.2 * s.1).sum::<f64>() / w;
        let kf = k as f64;
        let between = stats
            .iter()
            .map(|s| s.2 * (s.1 - mean_w).powi(2))
            .sum::<f64>()
            / (kf - 1.0);
        let lambda: f64 = stats
            .iter()
            .map(|s| (1.0 - s.2 / w).powi(2) / (s.0 - 1.0))
            .sum();
        let f = between / (1.0 + 2.0 * (kf - 2.0) / (kf * kf - 1.0) * lambda);
        let nu2 = (kf * kf - 1.0) / (3.0 * lambda);
        Some((f, kf - 1.0, nu2))
    }
}

/// The level of the test for a range error shared along the pipe
/// ([`WallCells::shared_along_axis`]), per frame: at most one frame in a thousand whose
/// errors are independent between cells takes a parameter's 1-σ from the slices of the
/// wall (see `uncertainty::slice_check`, which then decides per parameter).
pub const SHARED_ERROR_ALPHA: f64 = 1e-3;

/// Fewest slices (axial bins with two or more tested cells) for the shared-error test:
/// K − 1 = 3 degrees of freedom between slices at least.
pub const MIN_SLICES: usize = 4;

/// How far leaving out the slices found off the wall may move Dmax or Dmin before the
/// frame is refused, as a fraction of the mean diameter: issue 22's floor of 0.5 mm on a
/// 20" pipe (489 mm inside), scaled with the pipe. Below it a shared range error is
/// answered, its effect carried by the 1-σ of the slices' jackknife.
pub const DIAMETER_SHIFT_FRACTION: f64 = 1e-3;

/// The form tolerance of a whole slice of the wall ([`WallCells::misfit_slices`]) in units
/// of the frame's noise scale: half the cells' [`FORM_TOLERANCE_SCALES`], since an error
/// that every clock angle at one distance shares moves the fitted diameters where a local
/// one does not. Measured on tof-sim's frames and the numpy frames of
/// `crates/epd-py/tests/test_independent_frames.py` (σ = 20 mm): a range wiggle of 6 mm
/// (0.3 noise scales) leaves slices within 0.3 noise scales and is carried by the 1-σ
/// (the slice jackknife of `uncertainty::slice_check`); a multipath band reading 2.5 noise
/// scales long leaves its slices 1–2 noise scales off and the diameters 2–12 mm off, which
/// no 1-σ estimated from one frame carried (15 of 100 numpy frames beyond 5σ̂).
pub const SLICE_TOLERANCE_SCALES: f64 = 1.0;

/// The standard error of a median of n points of scale s is √(π/2)·s/√n = 1.2533·s/√n.
const MEDIAN_SE_FACTOR: f64 = 1.2533;

/// The form test of `points` against β over `cells` ([`WallCells::gather`], then
/// [`WallCells::form_test`]).
pub fn form_test(
    points: &[[f64; 3]],
    scales: Option<&[f64]>,
    beta: &Params,
    cells: &Cells,
) -> Option<FormMisfit> {
    WallCells::gather(points, scales, beta, cells)?.form_test()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cells of `slices` × 12 sectors whose medians are N(offset_k, s_k²), s_k growing
    /// fivefold along the axis (as a ToF camera's σ does with range).
    fn synthetic(rng: &mut rand_pcg::Pcg64, slices: usize, offset: f64) -> WallCells {
        use rand_distr::{Distribution, StandardNormal};
        let mut cells = Vec::new();
        for k in 0..slices {
            let s = 1.0 + 4.0 * k as f64 / slices as f64;
            let c: f64 = StandardNormal.sample(rng);
            let shift = offset * c;
            for g in 0..12 {
                let z: f64 = StandardNormal.sample(rng);
                cells.push(CellMedian {
                    id: k * 12 + g,
                    n: 100,
                    median: shift + s * z,
                    scale: 1.0,
                    ..CellMedian::default()
                });
            }
        }
        WallCells {
            cells,
            sectors: 12,
            noise_scale: 1.0,
        }
    }

    /// Welch's test keeps its level when the medians' spread differs between slices,
    /// and finds slices shifted by errors they share.
    ///
    /// 2000 frames of 16 slices with independent medians: at the 5 % level the count of
    /// rejections is binomial(2000, 0.05), mean 100, standard deviation 9.7; the test
    /// accepts 100 ± 4·9.7 (61…139). Shifts of one median-noise per slice: rejected at
    /// [`SHARED_ERROR_ALPHA`] in at least 95 of 100 frames.
    #[test]
    fn welch_test_keeps_its_level_and_finds_shared_shifts() {
        use rand::SeedableRng;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let mut rejected = 0;
        for _ in 0..2000 {
            let (f, nu1, nu2) = synthetic(&mut rng, 16, 0.0).welch_f().expect("16 slices");
            rejected += usize::from(f > f_upper_quantile(0.05, nu1, nu2));
        }
        assert!((61..=139).contains(&rejected), "{rejected} of 2000 at 5 %");
        let found = (0..100)
            .filter(|_| synthetic(&mut rng, 16, 3.0).shared_along_axis() == Some(true))
            .count();
        assert!(found >= 95, "{found} of 100 shifted frames found");
        assert_eq!(synthetic(&mut rng, 3, 0.0).shared_along_axis(), None);
    }

    /// The normal quantile against reference values (Abramowitz & Stegun, table 26.1).
    #[test]
    fn normal_quantiles() {
        for (alpha, z) in [
            (0.025, 1.959_963_985),
            (0.005, 2.575_829_304),
            (1e-3, 3.090_232_306),
            (1e-6, 4.753_424_309),
        ] {
            assert!((normal_upper_quantile(alpha) - z).abs() < 1e-6, "{alpha}");
        }
    }
}
