//! The depth table: per (range × log-intensity) bin the robust mean of the range error
//! and its spread ([`DepthTable`]), its axes, the correction of a new frame by inverting
//! ρ + T(ρ, I) = r, and the per-point σ it implies.

use rayon::prelude::*;

use super::rig::Observation;
use crate::error::EpdError;

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
    /// `n` bins over [`lo`, `hi`], as given: a table checks its axes when it is built or
    /// read.
    pub const fn new(lo: f64, hi: f64, n: usize) -> Self {
        Self { lo, hi, n }
    }

    pub(super) fn validate(&self, name: &str) -> Result<(), EpdError> {
        if !(self.lo.is_finite() && self.hi.is_finite() && self.hi > self.lo && self.n >= 1) {
            return Err(EpdError::InvalidOption(format!(
                "{name} axis [{}, {}] with {} bins: need finite lo < hi and at least one bin",
                self.lo, self.hi, self.n
            )));
        }
        if self.n > MAX_TABLE_BINS {
            return Err(EpdError::InvalidOption(format!(
                "{name} axis with {} bins: at most {MAX_TABLE_BINS} (2²⁰) bins in a table",
                self.n
            )));
        }
        if !(self.hi - self.lo >= MIN_AXIS_SPAN) {
            return Err(EpdError::InvalidOption(format!(
                "{name} axis [{}, {}] spans {:e}: at least {MIN_AXIS_SPAN} (1 mm of range, a \
                 0.1 % change of intensity)",
                self.lo,
                self.hi,
                self.hi - self.lo
            )));
        }
        Ok(())
    }

    /// Whether x lies on the axis, [lo, hi].
    pub(super) fn holds(&self, x: f64) -> bool {
        (self.lo..=self.hi).contains(&x)
    }

    fn width(&self) -> f64 {
        (self.hi - self.lo) / self.n as f64
    }

    /// The bin holding x (clamped to the axis).
    pub(super) fn bin(&self, x: f64) -> usize {
        let k = (x - self.lo) / self.width();
        if k.is_nan() || k < 0.0 {
            0
        } else {
            // k ≥ 0: truncation is the floor (and no libm call); saturates when huge.
            (k as usize).min(self.n - 1)
        }
    }

    /// The two bins whose centres bracket x and the weight of the second: linear
    /// interpolation between centres, constant beyond the outer centres.
    pub(super) fn bracket(&self, x: f64) -> (usize, usize, f64) {
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
            // Observations closer together than MIN_AXIS_SPAN (the narrowest axis a
            // table may have): an axis of width 1 from them.
            if hi - lo >= MIN_AXIS_SPAN {
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
pub(super) fn bin_offsets(obs: &[Observation], bins: &TableBins, cells: usize) -> Vec<Vec<f64>> {
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
            .filter(|&c| c <= MAX_TABLE_BINS)
            .ok_or_else(|| {
                EpdError::InvalidOption(format!(
                    "{nr} × {ni} bins: at most {MAX_TABLE_BINS} (2²⁰) bins"
                ))
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

    /// For each bin, the filled bin whose values it holds: itself when filled, else the
    /// one `Self::fill_empty_bins` copied (the nearest filled bin of its range row, else
    /// that bin of the nearest filled row); `None` when no bin is filled.
    pub fn source_bins(&self) -> Option<Vec<usize>> {
        let (nr, ni) = (self.range.n, self.log_intensity.n);
        let filled: Vec<bool> = (0..nr * ni)
            .map(|k| self.count.get(k).is_some_and(|&c| c > 0))
            .collect();
        let row_filled: Vec<bool> = (0..nr)
            .map(|i| filled[i * ni..(i + 1) * ni].iter().any(|&f| f))
            .collect();
        let near_row = nearest_true(&row_filled);
        if near_row.iter().all(Option::is_none) {
            return None;
        }
        // Linear in the bins (a crafted table of 2·10⁵ bins takes milliseconds, issue 27):
        // each row's nearest filled bins from two sweeps, not a scan per bin.
        let mut out = Vec::with_capacity(nr * ni);
        for (i, near) in near_row.iter().enumerate() {
            let row = near.unwrap_or(i);
            let in_row = nearest_true(&filled[row * ni..(row + 1) * ni]);
            out.extend(
                in_row
                    .iter()
                    .enumerate()
                    .map(|(j, f)| f.map_or(i * ni + j, |f| row * ni + f)),
            );
        }
        Some(out)
    }

    /// The shared errors of corrected points (SCS, m) and their intensities: per point
    /// the (filled bin, weight × that bin mean's standard error spread/√count in m) of
    /// the 4 bins the bilinear interpolation at its corrected range and intensity reads
    /// (each empty bin standing for the filled bin it copied, [`Self::source_bins`]);
    /// `(u32::MAX, 0)` for the terms of a point that was not corrected. The input of
    /// [`super::shared_error_cov_terms`] with groups the table's bins.
    pub fn shared_error_terms(
        &self,
        points: &[[f64; 3]],
        intensity: &[f64],
    ) -> Vec<[(u32, f64); 4]> {
        let none = [(u32::MAX, 0.0); 4];
        let Some(src) = self.source_bins() else {
            return vec![none; points.len()];
        };
        let ni = self.log_intensity.n;
        let se = |k: usize| {
            let b = src[k];
            let n = self.count[b].max(1) as f64;
            (b as u32, self.spread_m[b] / n.sqrt())
        };
        points
            .par_iter()
            .zip(intensity.par_iter())
            .map(|(p, &i)| {
                if !(usable(p) && i > 0.0 && i.is_finite()) {
                    return none;
                }
                let (i0, i1, fi) = self.range.bracket(norm(p));
                let (j0, j1, fj) = self.log_intensity.bracket(i.ln());
                let mut out = none;
                for (t, (a, b, w)) in [
                    (i0, j0, (1.0 - fi) * (1.0 - fj)),
                    (i0, j1, (1.0 - fi) * fj),
                    (i1, j0, fi * (1.0 - fj)),
                    (i1, j1, fi * fj),
                ]
                .into_iter()
                .enumerate()
                {
                    let (g, e) = se(a * ni + b);
                    out[t] = (g, w * e);
                }
                out
            })
            .collect()
    }

    /// Check a table read from elsewhere: axes valid, one finite value per bin.
    pub fn validate(&self) -> Result<(), EpdError> {
        self.range.validate("range")?;
        self.log_intensity.validate("log-intensity")?;
        let cells = self
            .range
            .n
            .checked_mul(self.log_intensity.n)
            .filter(|&c| c <= MAX_TABLE_BINS);
        let Some(cells) = cells else {
            return Err(EpdError::InvalidOption(format!(
                "depth table: {} × {} bins: at most {MAX_TABLE_BINS} (2²⁰) bins",
                self.range.n, self.log_intensity.n
            )));
        };
        let ok = |len: usize| len == cells;
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

    /// Of the frame's valid points (finite, not all zeros), how many there are and how
    /// many lie within both of the table's axes: their measured range in the range axis
    /// and the log of their intensity in the log-intensity axis. A frame with valid
    /// points none of which lies there is from another camera or rig than the table's.
    /// `intensity` pairs with `points` (the shorter one sets the count).
    pub fn within_axes(&self, points: &[[f64; 3]], intensity: &[f64]) -> (usize, usize) {
        points
            .par_iter()
            .zip(intensity.par_iter())
            .map(|(p, &i)| {
                if !usable(p) {
                    return (0, 0);
                }
                let inside = self.range.holds(norm(p)) && self.log_intensity.holds(log_of(i));
                (1, usize::from(inside))
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
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
        // A table of more bins than the inverse's cells: its spreads on a grid of as
        // many, so that a point's σ is not a cache miss in a table of megabytes.
        let coarse = sigma.is_some().then(|| self.coarse_spreads()).flatten();
        let spreads = coarse.as_ref().unwrap_or(self);
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
                    s[k] = spreads.interpolate(&spreads.spread_m, r * f, li);
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

    /// The table's spreads on a grid of at most [`MAX_INVERSE_CELLS`] bins over the same
    /// axes (at most [`MAX_INVERSE_COLUMNS`] intensity bins), each the table's
    /// interpolated spread at its centre; `None` when the table has no more bins than
    /// that (its own spreads are then used).
    fn coarse_spreads(&self) -> Option<DepthTable> {
        if self.spread_m.len() <= MAX_INVERSE_CELLS {
            return None;
        }
        let ni = self.log_intensity.n.min(MAX_INVERSE_COLUMNS);
        let nr = self.range.n.min(MAX_INVERSE_CELLS / ni);
        let range = Axis {
            n: nr,
            ..self.range
        };
        let log_intensity = Axis {
            n: ni,
            ..self.log_intensity
        };
        let (rw, lw) = (range.width(), log_intensity.width());
        let spread_m = (0..nr * ni)
            .into_par_iter()
            .map(|k| {
                let r = range.lo + ((k / ni) as f64 + 0.5) * rw;
                let li = log_intensity.lo + ((k % ni) as f64 + 0.5) * lw;
                self.interpolate(&self.spread_m, r, li)
            })
            .collect();
        Some(DepthTable {
            range,
            log_intensity,
            offset_m: Vec::new(),
            spread_m,
            count: Vec::new(),
        })
    }

    /// [`true_range`](Self::true_range) tabulated once for a whole frame: at
    /// INVERSE_STEPS nodes per range bin over the measured ranges the table can produce,
    /// for each intensity bin centre; a point then costs one bilinear interpolation.
    /// The grid has at most [`MAX_INVERSE_CELLS`] cells: a finer table is tabulated at
    /// [`MAX_INVERSE_COLUMNS`] intensities evenly over its axis and as many range nodes
    /// as the cells allow (at least 256), so a frame's cost does not grow with the
    /// table's bins.
    pub(super) fn inverse(&self) -> Inverse {
        let columns = Axis {
            n: self.log_intensity.n.min(MAX_INVERSE_COLUMNS),
            ..self.log_intensity
        };
        let (tmin, tmax) = self
            .offset_m
            .iter()
            .fold((0.0f64, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
        let w = self.range.width();
        let lo = self.range.lo + tmin - w;
        let hi = self.range.hi + tmax + w;
        let most = MAX_INVERSE_CELLS / columns.n;
        let nodes = ((hi - lo) / w * INVERSE_STEPS as f64).ceil();
        let n = if nodes.is_finite() {
            (nodes.max(1.0) as usize).min(most - 1) + 1
        } else {
            most
        };
        let step = (hi - lo) / (n - 1) as f64;
        let li_w = columns.width();
        let rho: Vec<f64> = (0..n)
            .into_par_iter()
            .flat_map_iter(|k| {
                let m = lo + k as f64 * step;
                (0..columns.n).map(move |j| {
                    let li = columns.lo + (j as f64 + 0.5) * li_w;
                    self.true_range_log(m, li)
                })
            })
            .collect();
        Inverse {
            lo,
            step,
            n,
            log_intensity: columns,
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

/// Half-width of a bin's inlier band, in spreads (1.4826·MAD): for Gaussian errors the
/// band keeps all but 6·10⁻⁵ of the observations, and a gross error (multipath, a flying
/// pixel) beyond it does not move the bin's mean.
pub(super) const CLIP_SPREADS: f64 = 4.0;

/// The clipped mean of `v` (mean within median ± [`CLIP_SPREADS`]·1.4826·MAD) and
/// 1.4826·MAD. `v` is reordered.
pub(super) fn clipped_mean(v: &mut [f64]) -> (f64, f64) {
    let (med, spread) = crate::loss::median_and_mad_sigma(v);
    let cut = CLIP_SPREADS * spread;
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

/// The most bins (range × intensity) a table may have: 2²⁰, about 3 000 times `epd
/// calibrate`'s default 30 × 12, so a table's values stay within 24 MiB of memory.
/// [`DepthTable::build`] and [`DepthTable::validate`] refuse more, and so does the
/// table file's reader before it allocates anything.
pub const MAX_TABLE_BINS: usize = 1 << 20;

/// The narrowest span of an axis (metres of range, or natural log of intensity): 1 mm
/// of range is a tenth of the best ToF camera's noise σ, and 10⁻³ of log-intensity a
/// 0.1 % change of intensity; a narrower axis cannot have been measured, and bins
/// narrower than it would only slow the correction down.
/// [`TableBins::spanning`] widens a narrower span of observations to one bin of 1.
pub const MIN_AXIS_SPAN: f64 = 1e-3;

/// The most cells (range nodes × intensity columns) of the tabulated inverse that
/// corrects a frame: 2¹⁴. Building it solves the fixed point (2–8 interpolations) per
/// cell, a few ms, a fraction of the correction of a 640 × 480 frame; `epd calibrate`'s
/// default 30 × 12 table needs about 270 × 12 cells. A table that would need more is
/// tabulated on a coarser grid ([`MAX_INVERSE_COLUMNS`] intensities at most, and at
/// least 256 range nodes: a node every 6 mm over a 1.5 m axis, as the default table's
/// 8 nodes a 5 cm bin), so a frame's cost stays about that of a real table whatever the
/// table's bins (`cargo run --release -p epd-frame --example table_cost`).
pub const MAX_INVERSE_CELLS: usize = 1 << 14;

/// The most intensity columns of the tabulated inverse: 64 (a table's default is 12),
/// leaving at least 256 range nodes within [`MAX_INVERSE_CELLS`].
pub const MAX_INVERSE_COLUMNS: usize = 64;

/// Nodes per range bin of the tabulated inverse (see [`DepthTable::correct`]).
const INVERSE_STEPS: usize = 8;

/// The wall range ρ as a function of (measured range, log-intensity), tabulated: nodes
/// every `step` metres from `lo`, columns at the table's intensity bin centres.
pub(super) struct Inverse {
    lo: f64,
    step: f64,
    n: usize,
    log_intensity: Axis,
    pub(super) rho: Vec<f64>,
}

impl Inverse {
    /// ρ at measured range r and log-intensity li: linear between range nodes and
    /// between intensity centres (constant beyond the outer ones); beyond the nodes, ρ
    /// is r minus the outermost node's offset.
    pub(super) fn true_range(&self, r: f64, li: f64) -> f64 {
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
pub(super) fn log_of(intensity: f64) -> f64 {
    if intensity > 0.0 && intensity.is_finite() {
        intensity.ln()
    } else {
        f64::NEG_INFINITY
    }
}

pub(super) fn usable(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0)
}

pub(super) fn norm(p: &[f64; 3]) -> f64 {
    (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
}

/// For each index, the nearest index whose flag is set (ties to the lower one), `None`
/// when none is: two sweeps, O(n).
fn nearest_true(flags: &[bool]) -> Vec<Option<usize>> {
    let n = flags.len();
    let mut before = vec![None; n];
    let mut last = None;
    for (k, &f) in flags.iter().enumerate() {
        if f {
            last = Some(k);
        }
        before[k] = last;
    }
    let mut next = None;
    let mut out = vec![None; n];
    for k in (0..n).rev() {
        if flags[k] {
            next = Some(k);
        }
        out[k] = match (before[k], next) {
            (Some(b), Some(a)) => Some(if k - b <= a - k { b } else { a }),
            (b, a) => b.or(a),
        };
    }
    out
}

#[cfg(test)]
mod nearest_tests {
    use super::nearest_true;

    /// Against the scan it replaces (the nearest set flag, ties to the lower index), on
    /// every pattern of up to 10 flags.
    #[test]
    fn nearest_true_is_the_scan() {
        for n in 0..=10usize {
            for bits in 0u32..(1 << n) {
                let flags: Vec<bool> = (0..n).map(|k| bits >> k & 1 == 1).collect();
                let scan: Vec<Option<usize>> = (0..n)
                    .map(|j| {
                        (0..n)
                            .filter(|&f| flags[f])
                            .min_by_key(|&f| (f.abs_diff(j), f))
                    })
                    .collect();
                assert_eq!(nearest_true(&flags), scan, "{flags:?}");
            }
        }
    }
}
