//! Depth calibration by lookup table (the paper's §4.2, its ref. 27).
//!
//! A ToF camera's systematic range error (wiggling, an amplitude-dependent offset,
//! multipath) depends mostly on the measured range r and the return's intensity I. In a
//! pipe of known diameter the pose of each frame is fitted with the diameters held at
//! their known values; every point then gives one observation of the error along its
//! sensing line,
//!
//!   δᵢ = ‖x̂ᵢ‖ − t(x̂ᵢ)·‖x̂ᵢ‖  (measured range − model range, m),
//!
//! with t the line parameter of eq. (21) at the fitted β ([`offsets`]). A [`DepthTable`]
//! stores, per (range × log-intensity) bin, the robust mean of δ over many frames (the
//! random error averages out) and its robust spread (the random error's σ there).
//! [`DepthTable::correct`] moves each measured point of a new frame along its own ray by
//! −T(r, I), interpolated between bin centres.
//!
//! Binning uses the *model* range of each observation: binned by measured range, a
//! bin would collect the points whose noise pushed them in, and store that noise's
//! conditional mean along with the systematic error. A new frame has no model: its
//! correction solves ρ + T(ρ, I) = r for the wall range ρ of each measured range r.

use crate::error::EpdError;
use crate::estimate::{Estimate, EstimateOptions, Method, estimate};
use crate::params::Params;
use crate::residual::Geometry;
use rayon::prelude::*;

/// One observation of the systematic range error: a point of a calibration frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Range where the point's sensing line meets the known wall (m).
    pub model_range_m: f64,
    /// The point's intensity (camera units).
    pub intensity: f64,
    /// Measured range − model range (m): positive when the camera reads long.
    pub offset_m: f64,
}

/// The observations of one calibration frame: every finite, non-zero point with a finite
/// positive intensity whose model range at `beta` (the frame's fit with the diameters
/// held at the known values) lies in `gate` (m).
pub fn offsets(
    points: &[[f64; 3]],
    intensity: &[f64],
    beta: &Params,
    gate: (f64, f64),
) -> Result<Vec<Observation>, EpdError> {
    if points.len() != intensity.len() {
        return Err(EpdError::InvalidOption(format!(
            "{} points but {} intensities: one intensity per point is needed",
            points.len(),
            intensity.len()
        )));
    }
    let geom = Geometry::new(beta).ok_or_else(|| {
        EpdError::InvalidOption("the fitted β puts the sensor outside the pipe".into())
    })?;
    Ok(points
        .iter()
        .zip(intensity)
        .filter(|(p, i)| usable(p) && i.is_finite() && **i > 0.0)
        .filter_map(|(p, &i)| {
            let r = norm(p);
            let model = geom.line_parameter(p) * r;
            ((gate.0..=gate.1).contains(&model) && model.is_finite()).then_some(Observation {
                model_range_m: model,
                intensity: i,
                offset_m: r - model,
            })
        })
        .collect())
}

/// One calibration frame: measured points (SCS, m; invalid pixels as zeros) and their
/// intensities.
#[derive(Clone, Copy, Debug)]
pub struct CalibrationFrame<'a> {
    /// Measured points.
    pub points: &'a [[f64; 3]],
    /// One intensity per point.
    pub intensity: &'a [f64],
}

/// How a table is made from calibration frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationSettings {
    /// The known (Dmax, Dmin) of the calibration pipe (m).
    pub known: (f64, f64),
    /// Range gate on the model range (m): the points used.
    pub gate: (f64, f64),
    /// Range × intensity bins.
    pub bins: (usize, usize),
    /// Least observations of a filled bin.
    pub min_count: usize,
    /// Passes of the alternating refinement (≥ 1; see [`calibrate`]).
    pub passes: usize,
}

/// A depth table with the frames' fitted poses.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The table.
    pub table: DepthTable,
    /// Per frame: its fit with the diameters held, or why it failed (the frame is then
    /// left out).
    pub fits: Vec<Result<Estimate, EpdError>>,
    /// Observations behind the table.
    pub n_observations: usize,
}

/// The depth table of frames recorded in a pipe of known diameter.
///
/// The systematic error and the pose are found together: a frame's pose, fitted with
/// the diameters held, absorbs the part of the error that looks like a pose change (a
/// range error larger on one side shifts δy, δz), and the table built on that pose
/// inherits the pose's error. So the fit alternates, like the joint least squares of
/// one table and one pose per frame: pass 1 fits each frame's pose on its measured
/// points and builds the table from their offsets (measured − model range); each
/// further pass fits the poses again on the points corrected by the current table and
/// rebuilds the table from the raw points' offsets to the new poses. The table's
/// bins span the observations of the first pass (range clipped to the gate).
/// Frames whose fit does not converge are left out; fails when none is left.
pub fn calibrate(
    frames: &[CalibrationFrame<'_>],
    settings: &CalibrationSettings,
    options: &EstimateOptions,
) -> Result<Calibration, EpdError> {
    let (d_max, d_min) = settings.known;
    let (lo, hi) = settings.gate;
    let options = options
        .with_fixed_diameters(d_max, d_min)?
        .with_range_gate(lo, hi)?;
    let mut table: Option<DepthTable> = None;
    let mut bins: Option<TableBins> = None;
    let mut last = None;
    for _ in 0..settings.passes.max(1) {
        let per_frame: Vec<Result<(Estimate, Vec<Observation>), EpdError>> = frames
            .par_iter()
            .with_max_len(1)
            .map(|f| {
                let corrected;
                let pts = match &table {
                    None => f.points,
                    Some(t) => {
                        let mut c = f.points.to_vec();
                        t.correct(&mut c, f.intensity)?;
                        corrected = c;
                        &corrected
                    }
                };
                let est = estimate(pts, Method::MlEpd, &options)?;
                if !est.status.is_converged() {
                    return Err(EpdError::Degenerate(format!(
                        "the pose fit with the known diameters ended {}: {}",
                        est.status.name(),
                        est.status.reason()
                    )));
                }
                let obs = offsets(f.points, f.intensity, &est.params, settings.gate)?;
                Ok((est, obs))
            })
            .collect();
        let obs: Vec<Observation> = per_frame
            .iter()
            .filter_map(|r| r.as_ref().ok())
            .flat_map(|(_, o)| o.iter().copied())
            .collect();
        if obs.is_empty() {
            let why = per_frame
                .iter()
                .find_map(|r| r.as_ref().err().map(|e| e.to_string()))
                .unwrap_or_else(|| "no point lies in the range gate".into());
            return Err(EpdError::InvalidOption(format!(
                "no calibration frame could be used: {why}"
            )));
        }
        let b = match bins {
            Some(b) => b,
            None => {
                let mut b = TableBins::spanning(&obs, settings.bins.0, settings.bins.1)?;
                b.range.lo = b.range.lo.max(lo);
                b.range.hi = b.range.hi.min(hi);
                if !(b.range.hi > b.range.lo) {
                    (b.range.lo, b.range.hi) = (lo, hi);
                }
                b.min_count = settings.min_count.max(1);
                bins = Some(b);
                b
            }
        };
        table = Some(DepthTable::build(&obs, &b)?);
        last = Some((per_frame, obs.len()));
    }
    let (Some(table), Some((per_frame, n_observations))) = (table, last) else {
        return Err(EpdError::InvalidOption("no calibration pass ran".into()));
    };
    Ok(Calibration {
        table,
        fits: per_frame.into_iter().map(|r| r.map(|(e, _)| e)).collect(),
        n_observations,
    })
}

/// An axis of the table: `n` equal bins over [lo, hi] of a coordinate (the range in m,
/// or the natural log of the intensity).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    /// Lower edge of the first bin.
    pub lo: f64,
    /// Upper edge of the last bin.
    pub hi: f64,
    /// Number of bins (≥ 1).
    pub n: usize,
}

impl Axis {
    fn validate(&self, name: &str) -> Result<(), EpdError> {
        if !(self.lo.is_finite() && self.hi.is_finite() && self.hi > self.lo && self.n >= 1) {
            return Err(EpdError::InvalidOption(format!(
                "{name} axis [{}, {}] with {} bins: need finite lo < hi and at least one bin",
                self.lo, self.hi, self.n
            )));
        }
        Ok(())
    }

    fn width(&self) -> f64 {
        (self.hi - self.lo) / self.n as f64
    }

    /// The bin holding x (clamped to the axis).
    fn bin(&self, x: f64) -> usize {
        let k = ((x - self.lo) / self.width()).floor();
        if k.is_nan() || k < 0.0 {
            0
        } else {
            (k as usize).min(self.n - 1)
        }
    }

    /// The two bins whose centres bracket x and the weight of the second: linear
    /// interpolation between centres, constant beyond the outer centres.
    fn bracket(&self, x: f64) -> (usize, usize, f64) {
        let f = (x - self.lo) / self.width() - 0.5;
        let last = (self.n - 1) as f64;
        if f.is_nan() || f <= 0.0 {
            return (0, 0, 0.0);
        }
        if f >= last {
            return (self.n - 1, self.n - 1, 0.0);
        }
        // f ∈ (0, n − 1): truncation is the floor (and no libm call).
        let k = f as usize;
        (k, k + 1, f - k as f64)
    }
}

/// The bins of a table to be built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableBins {
    /// Measured range (m).
    pub range: Axis,
    /// Natural log of the intensity.
    pub log_intensity: Axis,
    /// Bins with fewer observations are empty (filled from a neighbour, see
    /// [`DepthTable::build`]).
    pub min_count: usize,
}

impl TableBins {
    /// Bins spanning the observations: the range and the log-intensity from their 0.1 %
    /// to 99.9 % quantiles, `n_range` × `n_intensity` bins, at least 30 observations
    /// each.
    pub fn spanning(
        obs: &[Observation],
        n_range: usize,
        n_intensity: usize,
    ) -> Result<Self, EpdError> {
        if obs.is_empty() {
            return Err(EpdError::InvalidOption(
                "no calibration observations: no point of the frames lies in the range gate".into(),
            ));
        }
        let stride = obs.len().div_ceil(200_000).max(1);
        let mut r: Vec<f64> = obs
            .iter()
            .step_by(stride)
            .map(|o| o.model_range_m)
            .collect();
        let mut li: Vec<f64> = obs
            .iter()
            .step_by(stride)
            .map(|o| o.intensity.ln())
            .collect();
        let span = |v: &mut Vec<f64>| {
            let lo = crate::check::quantile(v, 0.001);
            let hi = crate::check::quantile(v, 0.999);
            if hi > lo {
                (lo, hi)
            } else {
                (lo - 0.5, lo + 0.5)
            }
        };
        let (r0, r1) = span(&mut r);
        let (i0, i1) = span(&mut li);
        Ok(Self {
            range: Axis {
                lo: r0,
                hi: r1,
                n: n_range,
            },
            log_intensity: Axis {
                lo: i0,
                hi: i1,
                n: n_intensity,
            },
            min_count: 30,
        })
    }
}

/// A lookup table of the systematic range error over measured range × log-intensity.
/// Bins are stored row by row: bin (i, j) of range bin i and intensity bin j is entry
/// `i·n_intensity + j`.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthTable {
    /// The range axis (m).
    pub range: Axis,
    /// The log-intensity axis.
    pub log_intensity: Axis,
    /// Robust mean of measured − model range per bin (m); an empty bin holds its
    /// nearest filled bin's value.
    pub offset_m: Vec<f64>,
    /// Robust spread 1.4826·MAD of the offsets per bin (m): the random range error's σ
    /// there; an empty bin holds its nearest filled bin's value.
    pub spread_m: Vec<f64>,
    /// Observations behind each bin (below `min_count` the bin counts as empty: 0).
    pub count: Vec<u64>,
}

/// The offsets of the usable observations (finite, intensity > 0, inside both axes) by
/// bin: bin k = range bin × log-intensity bins + log-intensity bin.
fn bin_offsets(obs: &[Observation], bins: &TableBins, cells: usize) -> Vec<Vec<f64>> {
    let ni = bins.log_intensity.n;
    let mut per_bin: Vec<Vec<f64>> = vec![Vec::new(); cells];
    for o in obs {
        if !(o.model_range_m.is_finite()
            && o.offset_m.is_finite()
            && o.intensity.is_finite()
            && o.intensity > 0.0)
        {
            continue;
        }
        let (lo, hi) = (bins.range.lo, bins.range.hi);
        let li = o.intensity.ln();
        if !(lo..=hi).contains(&o.model_range_m)
            || !(bins.log_intensity.lo..=bins.log_intensity.hi).contains(&li)
        {
            continue;
        }
        let k = bins.range.bin(o.model_range_m) * ni + bins.log_intensity.bin(li);
        per_bin[k].push(o.offset_m);
    }
    per_bin
}

impl DepthTable {
    /// The table from calibration observations.
    ///
    /// Per bin (by model range and log-intensity): the median m and MAD of the offsets,
    /// then the mean of the offsets within m ± 4·1.4826·MAD (a clipped mean: as
    /// efficient as the mean for Gaussian noise, deaf to flying pixels). A bin with
    /// fewer than `min_count` observations is empty and takes the values of the nearest
    /// filled bin of its range row (ties to the lower intensity); a row without any
    /// filled bin takes the nearest filled row (ties to the lower range). The table is
    /// then defined everywhere and never extrapolates a trend it has not seen; the
    /// range, which sets the wiggling, is never mixed up. Fails when no bin is filled.
    pub fn build(obs: &[Observation], bins: &TableBins) -> Result<Self, EpdError> {
        bins.range.validate("range")?;
        bins.log_intensity.validate("log-intensity")?;
        let (nr, ni) = (bins.range.n, bins.log_intensity.n);
        let cells = nr
            .checked_mul(ni)
            .filter(|&c| c <= 1 << 20)
            .ok_or_else(|| {
                EpdError::InvalidOption(format!("{nr} × {ni} bins: at most 2²⁰ bins"))
            })?;
        let mut table = Self {
            range: bins.range,
            log_intensity: bins.log_intensity,
            offset_m: vec![f64::NAN; cells],
            spread_m: vec![f64::NAN; cells],
            count: vec![0u64; cells],
        };
        for (k, v) in bin_offsets(obs, bins, cells).iter_mut().enumerate() {
            if v.len() < bins.min_count.max(1) {
                continue;
            }
            let (mean, spread) = clipped_mean(v);
            if !(spread > 0.0) {
                // All offsets alike: too few distinct points to know the noise there.
                continue;
            }
            table.offset_m[k] = mean;
            table.spread_m[k] = spread;
            table.count[k] = v.len() as u64;
        }
        let Some(first_filled) = table.count.iter().position(|&c| c > 0) else {
            return Err(EpdError::InvalidOption(format!(
                "no bin of the depth table holds {} observations with a spread: record more \
                 frames or use fewer bins",
                bins.min_count.max(1)
            )));
        };
        table.fill_empty_bins(first_filled);
        Ok(table)
    }

    /// Empty bins: from the nearest filled bin of the same range row (the range sets
    /// the wiggling; in a pipe each range sees a narrow band of intensities), then
    /// whole empty rows from the nearest filled row (`first_filled`: a filled bin).
    fn fill_empty_bins(&mut self, first_filled: usize) {
        let (nr, ni) = (self.range.n, self.log_intensity.n);
        let Self {
            offset_m,
            spread_m,
            count,
            ..
        } = self;
        let row_filled = |i: usize, count: &[u64]| (0..ni).any(|j| count[i * ni + j] > 0);
        for i in 0..nr {
            if !row_filled(i, count) {
                continue;
            }
            for j in 0..ni {
                if count[i * ni + j] > 0 {
                    continue;
                }
                let near = (0..ni)
                    .filter(|&f| count[i * ni + f] > 0)
                    .min_by_key(|&f| (f.abs_diff(j), f))
                    .unwrap_or(j);
                offset_m[i * ni + j] = offset_m[i * ni + near];
                spread_m[i * ni + j] = spread_m[i * ni + near];
            }
        }
        let rows: Vec<usize> = (0..nr).filter(|&i| row_filled(i, count)).collect();
        for i in 0..nr {
            if row_filled(i, count) {
                continue;
            }
            let near = rows
                .iter()
                .copied()
                .min_by_key(|&f| (f.abs_diff(i), f))
                .unwrap_or(first_filled / ni);
            for j in 0..ni {
                offset_m[i * ni + j] = offset_m[near * ni + j];
                spread_m[i * ni + j] = spread_m[near * ni + j];
            }
        }
    }

    /// Check a table read from elsewhere: axes valid, one finite value per bin.
    pub fn validate(&self) -> Result<(), EpdError> {
        self.range.validate("range")?;
        self.log_intensity.validate("log-intensity")?;
        let cells = self.range.n.checked_mul(self.log_intensity.n);
        let ok = |len: usize| Some(len) == cells;
        if !(ok(self.offset_m.len()) && ok(self.spread_m.len()) && ok(self.count.len())) {
            return Err(EpdError::InvalidOption(format!(
                "depth table: {} × {} bins but {} offsets, {} spreads and {} counts",
                self.range.n,
                self.log_intensity.n,
                self.offset_m.len(),
                self.spread_m.len(),
                self.count.len()
            )));
        }
        if !(self.range.lo >= 0.0 && self.range.hi <= MAX_TABLE_RANGE_M) {
            return Err(EpdError::InvalidOption(format!(
                "depth table: range axis [{}, {}] m: a ToF camera's ranges lie in [0, {MAX_TABLE_RANGE_M}] m",
                self.range.lo, self.range.hi
            )));
        }
        if !(self.log_intensity.hi - self.log_intensity.lo <= 100.0) {
            return Err(EpdError::InvalidOption(format!(
                "depth table: log-intensity axis [{}, {}] spans more than e^100",
                self.log_intensity.lo, self.log_intensity.hi
            )));
        }
        if let Some(k) = self
            .offset_m
            .iter()
            .position(|v| !(v.is_finite() && v.abs() <= MAX_OFFSET_M))
        {
            return Err(EpdError::InvalidOption(format!(
                "depth table: offset {} mm of bin {k} is not a depth error (at most ±{} mm)",
                self.offset_m[k] * 1e3,
                MAX_OFFSET_M * 1e3
            )));
        }
        if let Some(k) = self
            .spread_m
            .iter()
            .position(|v| !(v.is_finite() && *v > 0.0 && *v <= MAX_OFFSET_M))
        {
            return Err(EpdError::InvalidOption(format!(
                "depth table: spread {} mm of bin {k} is not a random error's σ (need > 0 and \
                 at most {} mm)",
                self.spread_m[k] * 1e3,
                MAX_OFFSET_M * 1e3
            )));
        }
        Ok(())
    }

    /// Bilinear interpolation of `values` between bin centres at (range, log-intensity);
    /// constant beyond the outer centres.
    fn interpolate(&self, values: &[f64], range_m: f64, log_intensity: f64) -> f64 {
        let (i0, i1, fi) = self.range.bracket(range_m);
        let (j0, j1, fj) = self.log_intensity.bracket(log_intensity);
        let ni = self.log_intensity.n;
        let at = |i: usize, j: usize| values[i * ni + j];
        let a = at(i0, j0) * (1.0 - fj) + at(i0, j1) * fj;
        let b = at(i1, j0) * (1.0 - fj) + at(i1, j1) * fj;
        a * (1.0 - fi) + b * fi
    }

    /// Whether the table observed the measured range r (m) and intensity I: (r, ln I)
    /// inside both axes, in a bin that held observations. Elsewhere its offset is a
    /// neighbouring bin's (see [`DepthTable::build`]): a guess for returns the rig never
    /// showed, such as a bend's wall beyond the rig's ranges or brighter at the same range.
    pub fn covers(&self, range_m: f64, intensity: f64) -> bool {
        let li = log_of(intensity);
        let inside = (self.range.lo..=self.range.hi).contains(&range_m)
            && (self.log_intensity.lo..=self.log_intensity.hi).contains(&li);
        inside
            && self
                .count
                .get(self.range.bin(range_m) * self.log_intensity.n + self.log_intensity.bin(li))
                .is_some_and(|&c| c > 0)
    }

    /// The systematic range error T(r, I) at measured range r (m) and intensity I (camera units).
    /// A non-positive or non-finite intensity reads as the lowest intensity bin.
    pub fn offset_at(&self, range_m: f64, intensity: f64) -> f64 {
        self.interpolate(&self.offset_m, range_m, log_of(intensity))
    }

    /// The random range error's σ at measured range r (m) and intensity I (camera units).
    pub fn sigma_at(&self, range_m: f64, intensity: f64) -> f64 {
        self.interpolate(&self.spread_m, range_m, log_of(intensity))
    }

    /// The range ρ whose systematic error brings it to the measured range r:
    /// ρ + T(ρ, I) = r, by the fixed-point iteration ρ ← r − T(ρ, I) from ρ = r (the
    /// table is indexed by the wall's range, and |∂T/∂ρ| ≪ 1, so a few steps converge:
    /// the error shrinks by |∂T/∂ρ| per step; the iteration stops when a step moves ρ
    /// by less than 10 µm, after at most eight steps).
    pub fn true_range(&self, range_m: f64, intensity: f64) -> f64 {
        self.true_range_log(range_m, log_of(intensity))
    }

    fn true_range_log(&self, range_m: f64, li: f64) -> f64 {
        let mut rho = range_m - self.interpolate(&self.offset_m, range_m, li);
        for _ in 0..7 {
            let next = range_m - self.interpolate(&self.offset_m, rho, li);
            let done = (next - rho).abs() < 1e-5;
            rho = next;
            if done {
                break;
            }
        }
        rho
    }

    /// Move each measured point (SCS, m) along its own sensing line to the range ρ that
    /// the table's systematic error carries to its measured range r
    /// ([`true_range`](Self::true_range)): x̂ ← x̂·ρ/r. Looking the offset up at r
    /// itself would read the table a whole offset (centimetres) away from where it was
    /// measured. Zero and non-finite points (invalid pixels) are left as they are. A
    /// valid point that cannot be corrected — its intensity is not a finite number > 0
    /// (cameras write 0 for invalid pixels), or the correction would carry it through
    /// the sensor — becomes NaN, so the estimators drop and count it: an uncorrected
    /// point among corrected ones is a biased one. Returns how many points were moved.
    pub fn correct(&self, points: &mut [[f64; 3]], intensity: &[f64]) -> Result<usize, EpdError> {
        if points.len() != intensity.len() {
            return Err(EpdError::InvalidOption(format!(
                "{} points but {} intensities: one intensity per point is needed",
                points.len(),
                intensity.len()
            )));
        }
        Ok(self.apply(points, intensity, None))
    }

    /// [`correct`](Self::correct) the points and return each one's σ from the table's
    /// spread at its corrected range and intensity (NaN for invalid points): the
    /// per-point scales of a weighted fit, in the same pass.
    pub fn correct_with_sigmas(
        &self,
        points: &mut [[f64; 3]],
        intensity: &[f64],
    ) -> Result<(usize, Vec<f64>), EpdError> {
        if points.len() != intensity.len() {
            return Err(EpdError::InvalidOption(format!(
                "{} points but {} intensities: one intensity per point is needed",
                points.len(),
                intensity.len()
            )));
        }
        let mut sigma = vec![f64::NAN; points.len()];
        let moved = self.apply(points, intensity, Some(&mut sigma));
        Ok((moved, sigma))
    }

    /// The correction of equal-length slices, with the σ of each point when asked.
    fn apply(
        &self,
        points: &mut [[f64; 3]],
        intensity: &[f64],
        sigma: Option<&mut [f64]>,
    ) -> usize {
        const CHUNK: usize = 4096;
        let inverse = self.inverse();
        let one = |ps: &mut [[f64; 3]], is: &[f64], mut ss: Option<&mut [f64]>| {
            let mut moved = 0;
            for (k, (p, &i)) in ps.iter_mut().zip(is).enumerate() {
                if !usable(p) {
                    continue;
                }
                let r = norm(p);
                let li = (i > 0.0 && i.is_finite()).then(|| i.ln());
                let f = li.map_or(f64::NAN, |li| inverse.true_range(r, li) / r);
                let (Some(li), true) = (li, f > 0.0 && f.is_finite()) else {
                    // No intensity to look up, or a correction through the sensor: the
                    // point cannot be corrected, and an uncorrected point is biased.
                    *p = [f64::NAN; 3];
                    continue;
                };
                *p = [p[0] * f, p[1] * f, p[2] * f];
                moved += 1;
                if let Some(s) = ss.as_deref_mut() {
                    s[k] = self.interpolate(&self.spread_m, r * f, li);
                }
            }
            moved
        };
        match sigma {
            None => points
                .par_chunks_mut(CHUNK)
                .zip(intensity.par_chunks(CHUNK))
                .map(|(ps, is)| one(ps, is, None))
                .sum(),
            Some(sigma) => points
                .par_chunks_mut(CHUNK)
                .zip(intensity.par_chunks(CHUNK))
                .zip(sigma.par_chunks_mut(CHUNK))
                .map(|((ps, is), ss)| one(ps, is, Some(ss)))
                .sum(),
        }
    }

    /// [`true_range`](Self::true_range) tabulated once for a whole frame: at
    /// INVERSE_STEPS nodes per range bin over the measured ranges the table can produce,
    /// for each intensity bin centre; a point then costs one bilinear interpolation.
    fn inverse(&self) -> Inverse {
        let ni = self.log_intensity.n;
        let (tmin, tmax) = self
            .offset_m
            .iter()
            .fold((0.0f64, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
        let w = self.range.width();
        let lo = self.range.lo + tmin - w;
        let hi = self.range.hi + tmax + w;
        let nodes = ((hi - lo) / w * INVERSE_STEPS as f64).ceil();
        let n = if nodes.is_finite() {
            (nodes.max(1.0) as usize).min(MAX_INVERSE_NODES) + 1
        } else {
            MAX_INVERSE_NODES + 1
        };
        let step = (hi - lo) / (n - 1) as f64;
        let li_w = self.log_intensity.width();
        let mut rho = Vec::with_capacity(n * ni);
        for k in 0..n {
            let m = lo + k as f64 * step;
            for j in 0..ni {
                let li = self.log_intensity.lo + (j as f64 + 0.5) * li_w;
                rho.push(self.true_range_log(m, li));
            }
        }
        Inverse {
            lo,
            step,
            n,
            log_intensity: self.log_intensity,
            rho,
        }
    }

    /// The random range error's σ of each point (m) from the table (NaN for invalid
    /// points): the per-point scale of a weighted fit.
    pub fn sigmas(&self, points: &[[f64; 3]], intensity: &[f64]) -> Vec<f64> {
        points
            .par_iter()
            .zip(intensity.par_iter())
            .map(|(p, &i)| {
                if usable(p) {
                    self.sigma_at(norm(p), i)
                } else {
                    f64::NAN
                }
            })
            .collect()
    }
}

/// The clipped mean of `v` (mean within median ± 4·1.4826·MAD) and 1.4826·MAD. `v` is
/// reordered.
fn clipped_mean(v: &mut [f64]) -> (f64, f64) {
    let (med, spread) = crate::loss::median_and_mad_sigma(v);
    let cut = 4.0 * spread;
    let (mut s, mut n) = (0.0, 0usize);
    for &x in v.iter() {
        if (x - med).abs() <= cut {
            s += x;
            n += 1;
        }
    }
    if n == 0 {
        (med, spread)
    } else {
        (s / n as f64, spread)
    }
}

/// The largest systematic error a table may hold (m): a ToF camera's depth errors are
/// millimetres to centimetres; a larger offset is a damaged or foreign table.
pub const MAX_OFFSET_M: f64 = 0.5;

/// The longest range a table may cover (m).
pub const MAX_TABLE_RANGE_M: f64 = 100.0;

/// Most nodes of the tabulated inverse.
const MAX_INVERSE_NODES: usize = 1 << 16;

/// Nodes per range bin of the tabulated inverse (see [`DepthTable::correct`]).
const INVERSE_STEPS: usize = 8;

/// The wall range ρ as a function of (measured range, log-intensity), tabulated: nodes
/// every `step` metres from `lo`, columns at the table's intensity bin centres.
struct Inverse {
    lo: f64,
    step: f64,
    n: usize,
    log_intensity: Axis,
    rho: Vec<f64>,
}

impl Inverse {
    /// ρ at measured range r and log-intensity li: linear between range nodes and
    /// between intensity centres (constant beyond the outer ones); beyond the nodes, ρ
    /// is r minus the outermost node's offset.
    fn true_range(&self, r: f64, li: f64) -> f64 {
        let (j0, j1, fj) = self.log_intensity.bracket(li);
        let ni = self.log_intensity.n;
        let at = |k: usize| {
            let a = self.rho[k * ni + j0];
            let b = self.rho[k * ni + j1];
            a + (b - a) * fj
        };
        let f = (r - self.lo) / self.step;
        if f.is_nan() || f <= 0.0 {
            return r - (self.lo - at(0));
        }
        let last = (self.n - 1) as f64;
        if f >= last {
            return r - (self.lo + last * self.step - at(self.n - 1));
        }
        // f ∈ (0, n − 1): truncation is the floor.
        let k = f as usize;
        let (a, b) = (at(k), at(k + 1));
        a + (b - a) * (f - k as f64)
    }
}

/// ln(I), or −∞ (the lowest bin) for a non-positive or non-finite intensity.
fn log_of(intensity: f64) -> f64 {
    if intensity > 0.0 && intensity.is_finite() {
        intensity.ln()
    } else {
        f64::NEG_INFINITY
    }
}

fn usable(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0)
}

fn norm(p: &[f64; 3]) -> f64 {
    (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bins(nr: usize, ni: usize) -> TableBins {
        TableBins {
            range: Axis {
                lo: 0.5,
                hi: 2.0,
                n: nr,
            },
            log_intensity: Axis {
                lo: 0.0,
                hi: 6.0,
                n: ni,
            },
            min_count: 10,
        }
    }

    /// A smooth known error: the table reproduces it at the bin centres exactly and in
    /// between to the interpolation error of a linear function (zero).
    #[test]
    fn linear_error_is_reproduced_everywhere() {
        let f = |r: f64, li: f64| 0.004 * r - 0.001 * li + 0.002;
        let mut obs = vec![];
        for a in 0..300 {
            for b in 0..60 {
                let r = 0.5 + 1.5 * (a as f64 + 0.5) / 300.0;
                let li = 6.0 * (b as f64 + 0.5) / 60.0;
                obs.push(Observation {
                    model_range_m: r,
                    intensity: li.exp(),
                    offset_m: f(r, li),
                });
            }
        }
        let t = DepthTable::build(&obs, &bins(15, 6)).unwrap();
        assert!(t.count.iter().all(|&c| c > 0));
        // Within the outer centres the bilinear interpolation of a linear function is
        // exact up to the mean within a bin (also exact: the bins sample it evenly).
        for (r, li) in [(0.6, 0.6), (1.23, 2.7), (1.9, 5.4)] {
            let got = t.offset_at(r, f64::exp(li));
            assert!(
                (got - f(r, li)).abs() < 1e-9,
                "{r} {li}: {got} vs {}",
                f(r, li)
            );
        }
        // Beyond the outer centres the table is constant.
        assert_eq!(t.offset_at(0.1, 1.0), t.offset_at(0.5, 1.0));
        assert_eq!(t.offset_at(9.0, 1e9), t.offset_at(2.0, 6f64.exp()));
    }

    #[test]
    fn robust_mean_ignores_flying_pixels_and_spread_is_sigma() {
        // Deterministic "noise": a symmetric comb of ±σ·z values, plus 5 % gross errors.
        let mut v: Vec<f64> = (0..2000)
            .map(|k| {
                let z = (k as f64 + 0.5) / 2000.0;
                0.003 + 0.01 * inverse_normal(z)
            })
            .collect();
        v.extend(std::iter::repeat_n(1.0, 100));
        let (m, s) = clipped_mean(&mut v);
        assert!((m - 0.003).abs() < 2e-4, "{m}");
        // The MAD is not deaf to 5 % one-sided contamination: its median moves into the
        // tail, ≈ +6 % here (without the gross errors it is exact to 0.2 %).
        assert!((s - 0.01).abs() < 8e-4, "{s}");
        let mut clean: Vec<f64> = v[..].iter().copied().filter(|x| *x < 0.5).collect();
        let (_, s0) = clipped_mean(&mut clean);
        assert!((s0 - 0.01).abs() < 2e-5, "{s0}");
    }

    /// Acklam-free inverse normal by bisection of erf (test only).
    fn inverse_normal(p: f64) -> f64 {
        let cdf = |x: f64| 0.5 * (1.0 + erf(x / std::f64::consts::SQRT_2));
        let (mut lo, mut hi) = (-10.0, 10.0);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if cdf(mid) < p { lo = mid } else { hi = mid }
        }
        0.5 * (lo + hi)
    }

    fn erf(x: f64) -> f64 {
        // Abramowitz & Stegun 7.1.26 is too coarse for a test oracle; integrate instead.
        let n = 2000;
        let h = x / n as f64;
        let f = |t: f64| (-t * t).exp();
        let mut s = f(0.0) + f(x);
        for k in 1..n {
            s += f(k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
        }
        s * h / 3.0 * 2.0 / std::f64::consts::PI.sqrt()
    }

    #[test]
    fn empty_bins_take_the_nearest_filled_bin() {
        // Observations only in range bin 0 (intensity bin 0) and range bin 3 (bin 1).
        let mut obs = vec![];
        for k in 0..20 {
            // ± 1 mm of noise about the bin's offset.
            let e = if k % 2 == 0 { 0.001 } else { -0.001 };
            obs.push(Observation {
                model_range_m: 0.6,
                intensity: 1.5,
                offset_m: 0.01 + e,
            });
            obs.push(Observation {
                model_range_m: 1.9,
                intensity: 3f64.exp(),
                offset_m: -0.02 + e,
            });
        }
        let t = DepthTable::build(&obs, &bins(4, 2)).unwrap();
        assert_eq!(t.count, vec![20, 0, 0, 0, 0, 0, 0, 20]);
        // Row 0: bin (0, 1) from (0, 0); row 3: (3, 0) from (3, 1); the empty rows 1
        // and 2 from their nearest filled rows, 0 and 3.
        let (a, b) = (t.offset_m[0], t.offset_m[7]);
        assert!((a - 0.01).abs() < 1e-12 && (b + 0.02).abs() < 1e-12);
        assert_eq!(&t.offset_m[..4], &[a, a, a, a]);
        assert_eq!(&t.offset_m[4..], &[b, b, b, b]);
        assert!(t.validate().is_ok());
        // Only the observed bins are covered; filled ones and points off the axes are not.
        assert!(t.covers(0.6, 1.5) && t.covers(1.9, 3f64.exp()));
        assert!(!t.covers(0.6, 3f64.exp()) && !t.covers(1.0, 1.5));
        assert!(!t.covers(2.1, 3f64.exp()) && !t.covers(0.6, 1e4) && !t.covers(0.6, 0.0));
        // No observation at all: refused with a reason.
        let e = DepthTable::build(&[], &bins(4, 2)).unwrap_err().to_string();
        assert!(e.contains("no bin"), "{e}");
    }

    #[test]
    fn correction_moves_points_along_their_ray() {
        let obs: Vec<Observation> = (0..100)
            .map(|k| Observation {
                model_range_m: 0.5 + 1.5 * k as f64 / 100.0,
                intensity: 10.0,
                offset_m: 0.02 + if k % 2 == 0 { 0.001 } else { -0.001 },
            })
            .collect();
        let b = TableBins {
            min_count: 1,
            ..bins(1, 1)
        };
        let t = DepthTable::build(&obs, &b).unwrap();
        let mut pts = [[1.0, 0.2, -0.1], [0.0, 0.0, 0.0], [f64::NAN, 1.0, 1.0]];
        let before = pts;
        let mut again = pts;
        let moved = t.correct(&mut pts, &[10.0, 10.0, 10.0]).unwrap();
        assert_eq!(moved, 1);
        let (m2, sig) = t.correct_with_sigmas(&mut again, &[10.0; 3]).unwrap();
        assert_eq!(m2, 1);
        assert_eq!(again[0], pts[0]);
        assert_eq!(sig[0], t.sigma_at(norm(&pts[0]), 10.0));
        assert!(sig[1].is_nan() && sig[2].is_nan());
        let r0 = norm(&before[0]);
        assert!((norm(&pts[0]) - (r0 - 0.02)).abs() < 1e-12);
        assert!((t.true_range(1.3, 10.0) - 1.28).abs() < 1e-12);
        // Without a usable intensity a valid point cannot be corrected: it becomes NaN.
        let mut q = [[1.0, 0.2, -0.1], [1.0, 0.1, 0.1]];
        assert_eq!(t.correct(&mut q, &[0.0, f64::NAN]).unwrap(), 0);
        assert!(q.iter().all(|p| p[0].is_nan()));
        // Same direction.
        let c = (0..3).map(|k| pts[0][k] * before[0][k]).sum::<f64>() / (norm(&pts[0]) * r0);
        assert!((c - 1.0).abs() < 1e-12);
        assert_eq!(pts[1], [0.0; 3]);
        assert!(pts[2][0].is_nan());
        assert!(t.correct(&mut pts, &[1.0]).is_err());
    }

    /// The tabulated inverse that `correct` uses agrees with the fixed-point solution
    /// of ρ + T(ρ, I) = r to 20 µm on a table with wiggles and an intensity trend.
    #[test]
    fn tabulated_inverse_matches_the_fixed_point() {
        let f = |r: f64, li: f64| 0.03 + 0.02 * r + 0.006 * (4.19 * r).sin() - 0.003 * li;
        let mut obs = vec![];
        for a in 0..600 {
            for b in 0..40 {
                let r = 0.5 + 1.5 * (a as f64 + 0.5) / 600.0;
                let li = 1.0 + 6.0 * (b as f64 + 0.5) / 40.0;
                obs.push(Observation {
                    model_range_m: r,
                    intensity: li.exp(),
                    offset_m: f(r, li),
                });
            }
        }
        let b = TableBins {
            range: Axis {
                lo: 0.5,
                hi: 2.0,
                n: 30,
            },
            log_intensity: Axis {
                lo: 1.0,
                hi: 7.0,
                n: 12,
            },
            min_count: 10,
        };
        let t = DepthTable::build(&obs, &b).unwrap();
        let inv = t.inverse();
        let mut worst: f64 = 0.0;
        for k in 0..5000 {
            let r = 0.3 + 2.2 * (k as f64 * 0.618_034).fract();
            let li = 0.5 + 7.0 * (k as f64 * 0.414_214).fract();
            let exact = t.true_range(r, li.exp());
            // The fixed point holds to its own tolerance.
            assert!((exact + t.offset_at(exact, li.exp()) - r).abs() < 2e-5);
            worst = worst.max((inv.true_range(r, li) - exact).abs());
        }
        assert!(worst < 2e-5, "{worst}");
    }

    #[test]
    fn corrupt_tables_are_refused() {
        let obs: Vec<Observation> = (0..100)
            .map(|k| Observation {
                model_range_m: 0.5 + 1.5 * k as f64 / 100.0,
                intensity: 10.0,
                offset_m: if k % 2 == 0 { 0.001 } else { -0.001 },
            })
            .collect();
        let mut t = DepthTable::build(
            &obs,
            &TableBins {
                min_count: 1,
                ..bins(2, 1)
            },
        )
        .unwrap();
        t.offset_m.pop();
        assert!(t.validate().unwrap_err().to_string().contains("offsets"));
        t.offset_m.push(f64::NAN);
        assert!(
            t.validate()
                .unwrap_err()
                .to_string()
                .contains("not a depth error")
        );
        *t.offset_m.last_mut().unwrap() = 1e300;
        assert!(
            t.validate()
                .unwrap_err()
                .to_string()
                .contains("not a depth error")
        );
        *t.offset_m.last_mut().unwrap() = 0.0;
        t.spread_m[0] = 0.0;
        assert!(t.validate().unwrap_err().to_string().contains("spread"));
        t.spread_m[0] = 0.01;
        t.range.lo = -5.0;
        assert!(t.validate().unwrap_err().to_string().contains("range axis"));
        t.range.lo = 0.5;
        t.log_intensity.hi = 1e308;
        assert!(
            t.validate()
                .unwrap_err()
                .to_string()
                .contains("log-intensity")
        );
    }
}
