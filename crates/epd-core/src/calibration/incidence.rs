//! The depth table over range × log-intensity × log-cos-incidence ([`IncidenceTable`]):
//! the systematic range error indexed also by the angle between the ray and the wall
//! normal, the support it observed, and each bin mean's standard error.
//!
//! At the same range and intensity the error of a ToF camera may still depend on the
//! incidence (the footprint of the pixel on the wall, multipath from the neighbouring
//! wall): in a pipe the incidence at range r is about R/r, so a table made in one pipe
//! size and applied in another reads its bins along another curve. The table records
//! which bins its rigs observed; a point is corrected only inside that support:
//!
//! - **observed** bins hold at least `min_count` observations;
//! - **bridged** bins are empty bins of a range row inside the bounding box (in
//!   intensity × incidence bins) of that row's observed bins: between two rig sizes. The
//!   offset is a local linear interpolant of the row's observed bins (a weighted plane,
//!   weights 1/d² in bin units, clamped to their range); the spread and the standard
//!   error are their inverse-distance (1/d²) means;
//! - every other bin is **outside**: a point there is not corrected — it is left out
//!   (NaN) and counted (`calibration_outside`), never corrected by an extrapolated value.
//!
//! The incidence axis is ln cos θ: an ln(D₁/D₂) change of pipe size is the same step of
//! ln cos θ at every range (cos θ ≈ R/r for a sensor near the axis).

use rayon::prelude::*;

use super::rig::Observation;
use super::table::{Axis, MAX_OFFSET_M, MAX_TABLE_BINS, MAX_TABLE_RANGE_M, clipped_mean};
use crate::error::EpdError;

/// Where a bin's value comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Support {
    /// No rig showed it, and it lies beyond the observed bins of its range row: a point
    /// there is left uncorrected.
    Outside = 0,
    /// At least `min_count` observations.
    Observed = 1,
    /// Empty, between observed bins of its range row (see the module doc).
    Bridged = 2,
}

impl Support {
    /// From its number in a table file (0, 1, 2).
    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Outside),
            1 => Some(Self::Observed),
            2 => Some(Self::Bridged),
            _ => None,
        }
    }
}

/// One observation with the incidence at its wall point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IncidenceObservation {
    /// Range, intensity and offset.
    pub obs: Observation,
    /// cos θ at the wall point (0, 1].
    pub cos_incidence: f64,
}

/// The bins of an [`IncidenceTable`] to be built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IncidenceBins {
    /// Model range (m).
    pub range: Axis,
    /// ln intensity.
    pub log_intensity: Axis,
    /// ln cos θ.
    pub log_cos_incidence: Axis,
    /// Fewest observations of an observed bin.
    pub min_count: usize,
}

impl IncidenceBins {
    /// Bins spanning the observations (0.1 % to 99.9 % quantiles on each axis; the range
    /// clipped to `gate`).
    pub fn spanning(
        obs: &[IncidenceObservation],
        n: (usize, usize, usize),
        gate: (f64, f64),
        min_count: usize,
    ) -> Result<Self, EpdError> {
        if obs.is_empty() {
            return Err(EpdError::InvalidOption(
                "no calibration observations: no point of the frames lies in the range gate".into(),
            ));
        }
        let stride = obs.len().div_ceil(200_000).max(1);
        let span = |f: &dyn Fn(&IncidenceObservation) -> f64| {
            let mut v: Vec<f64> = obs.iter().step_by(stride).map(f).collect();
            let lo = crate::check::quantile(&mut v, 0.001);
            let hi = crate::check::quantile(&mut v, 0.999);
            if hi - lo >= super::MIN_AXIS_SPAN {
                (lo, hi)
            } else {
                (lo - 0.5, lo + 0.5)
            }
        };
        let (mut r0, mut r1) = span(&|o| o.obs.model_range_m);
        r0 = r0.max(gate.0);
        r1 = r1.min(gate.1);
        if !(r1 - r0 >= super::MIN_AXIS_SPAN) {
            (r0, r1) = gate;
        }
        let (i0, i1) = span(&|o| o.obs.intensity.ln());
        let (c0, c1) = span(&|o| o.cos_incidence.ln());
        Ok(Self {
            range: Axis {
                lo: r0,
                hi: r1,
                n: n.0,
            },
            log_intensity: Axis {
                lo: i0,
                hi: i1,
                n: n.1,
            },
            log_cos_incidence: Axis {
                lo: c0,
                hi: c1.min(0.0).max(c0 + super::MIN_AXIS_SPAN),
                n: n.2,
            },
            min_count: min_count.max(1),
        })
    }
}

/// The systematic range error over model range × ln intensity × ln cos θ, with its
/// support. Bin (i, j, l) is entry `(i·n_intensity + j)·n_incidence + l`.
#[derive(Clone, Debug, PartialEq)]
pub struct IncidenceTable {
    /// Range axis (m).
    pub range: Axis,
    /// ln intensity axis.
    pub log_intensity: Axis,
    /// ln cos θ axis.
    pub log_cos_incidence: Axis,
    /// Mean offset per bin (m), NaN outside the support.
    pub offset_m: Vec<f64>,
    /// Spread 1.4826·MAD per bin (m), NaN outside the support.
    pub spread_m: Vec<f64>,
    /// Standard error of each bin's mean (m): spread/√count for an observed bin, the
    /// inverse-distance mean of the row's observed bins' for a bridged one; NaN outside.
    pub se_m: Vec<f64>,
    /// Observations behind each bin (0 for bridged and outside bins).
    pub count: Vec<u64>,
    /// Where each bin's value comes from.
    pub support: Vec<Support>,
}

/// A point's look-up in an [`IncidenceTable`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lookup {
    /// The interpolated offset (m).
    pub offset_m: f64,
    /// The interpolated spread (m).
    pub spread_m: f64,
    /// The bin holding the point (whose standard error the point shares).
    pub bin: usize,
}

/// The result of correcting a frame with an [`IncidenceTable`].
#[derive(Clone, Debug, PartialEq)]
pub struct Correction {
    /// Points moved.
    pub moved: usize,
    /// Valid points left uncorrected because they lie outside the support.
    pub outside: usize,
    /// Per point: the bin whose offset moved it (`None` for an uncorrected point).
    pub bin: Vec<Option<u32>>,
    /// Per point: the table's spread at the corrected point (m; NaN where uncorrected).
    pub sigma_m: Vec<f64>,
}

impl IncidenceTable {
    /// Bins in all.
    pub fn cells(&self) -> usize {
        self.offset_m.len()
    }

    fn index(&self, i: usize, j: usize, l: usize) -> usize {
        (i * self.log_intensity.n + j) * self.log_cos_incidence.n + l
    }

    /// The table from observations: per bin the clipped mean and the spread (as
    /// [`super::DepthTable::build`]), its standard error spread/√n, then the bridged
    /// bins (module doc). Fails when no bin is observed.
    pub fn build(obs: &[IncidenceObservation], bins: &IncidenceBins) -> Result<Self, EpdError> {
        bins.range.validate("range")?;
        bins.log_intensity.validate("log-intensity")?;
        bins.log_cos_incidence.validate("log-cos-incidence")?;
        let (nr, ni, nc) = (bins.range.n, bins.log_intensity.n, bins.log_cos_incidence.n);
        let cells = nr
            .checked_mul(ni)
            .and_then(|c| c.checked_mul(nc))
            .filter(|&c| c <= MAX_TABLE_BINS)
            .ok_or_else(|| {
                EpdError::InvalidOption(format!(
                    "{nr} × {ni} × {nc} bins: at most {MAX_TABLE_BINS} (2²⁰) bins"
                ))
            })?;
        let mut per_bin: Vec<Vec<f64>> = vec![Vec::new(); cells];
        for o in obs {
            let (r, i, c) = (o.obs.model_range_m, o.obs.intensity, o.cos_incidence);
            if !(r.is_finite() && i > 0.0 && i.is_finite() && c > 0.0 && c <= 1.0) {
                continue;
            }
            let (li, lc) = (i.ln(), c.ln());
            if !(bins.range.holds(r)
                && bins.log_intensity.holds(li)
                && bins.log_cos_incidence.holds(lc))
            {
                continue;
            }
            let k = (bins.range.bin(r) * ni + bins.log_intensity.bin(li)) * nc
                + bins.log_cos_incidence.bin(lc);
            per_bin[k].push(o.obs.offset_m);
        }
        let mut t = Self {
            range: bins.range,
            log_intensity: bins.log_intensity,
            log_cos_incidence: bins.log_cos_incidence,
            offset_m: vec![f64::NAN; cells],
            spread_m: vec![f64::NAN; cells],
            se_m: vec![f64::NAN; cells],
            count: vec![0; cells],
            support: vec![Support::Outside; cells],
        };
        let stats: Vec<Option<(f64, f64, usize)>> = per_bin
            .par_iter_mut()
            .map(|v| {
                if v.len() < bins.min_count {
                    return None;
                }
                let (mean, spread) = clipped_mean(v);
                (spread > 0.0).then_some((mean, spread, v.len()))
            })
            .collect();
        for (k, s) in stats.into_iter().enumerate() {
            if let Some((mean, spread, n)) = s {
                t.offset_m[k] = mean;
                t.spread_m[k] = spread;
                t.se_m[k] = spread / (n as f64).sqrt();
                t.count[k] = n as u64;
                t.support[k] = Support::Observed;
            }
        }
        if !t.support.contains(&Support::Observed) {
            return Err(EpdError::InvalidOption(format!(
                "no bin of the depth table holds {} observations with a spread: record more \
                 frames or use fewer bins",
                bins.min_count
            )));
        }
        t.bridge();
        Ok(t)
    }

    /// The offset of an empty bin (j, l) of range row `i` from the row's observed bins
    /// `seen`: the intercept of the weighted least-squares plane o ≈ c₀ + c₁·Δj + c₂·Δl
    /// over them (weights 1/d², d the distance in bins, as the inverse-distance mean),
    /// a local linear interpolant that reproduces an error linear in ln I and ln cos θ
    /// across the gap between two rig sizes, where the inverse-distance mean flattens
    /// it towards the side with more bins. A pipe's bins at one range lie near a line of
    /// that plane (the intensity follows from range and incidence), so the slope across
    /// the line is held near zero by a ridge of 10⁻⁹ of the slopes' weighted second
    /// moment (a bias of that relative size on a determined slope). The result is
    /// clamped to the observed offsets' range: an interpolant, never an extrapolation.
    fn local_linear(&self, i: usize, seen: &[(usize, usize)], (j, l): (usize, usize)) -> f64 {
        let mut m = [[0.0f64; 3]; 3];
        let mut v = [0.0f64; 3];
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &(a, b) in seen {
            let (dj, dl) = (a as f64 - j as f64, b as f64 - l as f64);
            let w = 1.0 / (dj * dj + dl * dl);
            let o = self.offset_m[self.index(i, a, b)];
            lo = lo.min(o);
            hi = hi.max(o);
            let x = [1.0, dj, dl];
            for r in 0..3 {
                v[r] += w * x[r] * o;
                for c in 0..3 {
                    m[r][c] += w * x[r] * x[c];
                }
            }
        }
        let ridge = 1e-9 * (m[1][1] + m[2][2]);
        m[1][1] += ridge;
        m[2][2] += ridge;
        let mat = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
        let fit = mat
            .cholesky()
            .map(|ch| ch.solve(&nalgebra::Vector3::from(v))[0]);
        match fit {
            Some(o) if o.is_finite() => o.clamp(lo, hi),
            _ => v[0] / m[0][0],
        }
    }

    /// Fill each range row's empty bins inside the bounding box of its observed bins
    /// (module doc).
    fn bridge(&mut self) {
        let (nr, ni, nc) = (self.range.n, self.log_intensity.n, self.log_cos_incidence.n);
        for i in 0..nr {
            let seen: Vec<(usize, usize)> = (0..ni)
                .flat_map(|j| (0..nc).map(move |l| (j, l)))
                .filter(|&(j, l)| self.support[self.index(i, j, l)] == Support::Observed)
                .collect();
            let Some(j0) = seen.iter().map(|s| s.0).min() else {
                continue;
            };
            let j1 = seen.iter().map(|s| s.0).max().unwrap_or(j0);
            let l0 = seen.iter().map(|s| s.1).min().unwrap_or(0);
            let l1 = seen.iter().map(|s| s.1).max().unwrap_or(l0);
            for j in j0..=j1 {
                for l in l0..=l1 {
                    let k = self.index(i, j, l);
                    if self.support[k] == Support::Observed {
                        continue;
                    }
                    let (mut w, mut s, mut e) = (0.0, 0.0, 0.0);
                    for &(a, b) in &seen {
                        let d2 = (a as f64 - j as f64).powi(2) + (b as f64 - l as f64).powi(2);
                        let wk = 1.0 / d2;
                        let src = self.index(i, a, b);
                        w += wk;
                        s += wk * self.spread_m[src];
                        e += wk * self.se_m[src];
                    }
                    self.offset_m[k] = self.local_linear(i, &seen, (j, l));
                    self.spread_m[k] = s / w;
                    self.se_m[k] = e / w;
                    self.support[k] = Support::Bridged;
                }
            }
        }
    }

    /// Check a table read from elsewhere: axes valid, one value per bin, finite offsets
    /// within ±[`MAX_OFFSET_M`] and positive spreads inside the support.
    pub fn validate(&self) -> Result<(), EpdError> {
        self.range.validate("range")?;
        self.log_intensity.validate("log-intensity")?;
        self.log_cos_incidence.validate("log-cos-incidence")?;
        let cells = self
            .range
            .n
            .checked_mul(self.log_intensity.n)
            .and_then(|c| c.checked_mul(self.log_cos_incidence.n))
            .filter(|&c| c <= MAX_TABLE_BINS)
            .ok_or_else(|| {
                EpdError::InvalidOption(format!(
                    "depth table: more than {MAX_TABLE_BINS} (2²⁰) bins"
                ))
            })?;
        let lens = [
            self.offset_m.len(),
            self.spread_m.len(),
            self.se_m.len(),
            self.count.len(),
            self.support.len(),
        ];
        if lens.iter().any(|&n| n != cells) {
            return Err(EpdError::InvalidOption(format!(
                "depth table: {cells} bins but {lens:?} offsets, spreads, standard errors, \
                 counts and support flags"
            )));
        }
        if !(self.range.lo >= 0.0 && self.range.hi <= MAX_TABLE_RANGE_M) {
            return Err(EpdError::InvalidOption(format!(
                "depth table: range axis [{}, {}] m: a ToF camera's ranges lie in [0, \
                 {MAX_TABLE_RANGE_M}] m",
                self.range.lo, self.range.hi
            )));
        }
        if !(self.log_cos_incidence.hi <= 1e-9) {
            return Err(EpdError::InvalidOption(format!(
                "depth table: ln cos θ axis up to {}: cos θ is at most 1 (ln cos θ ≤ 0)",
                self.log_cos_incidence.hi
            )));
        }
        for k in 0..cells {
            if self.support[k] == Support::Outside {
                continue;
            }
            let (o, s, e) = (self.offset_m[k], self.spread_m[k], self.se_m[k]);
            if !(o.is_finite() && o.abs() <= MAX_OFFSET_M) {
                return Err(EpdError::InvalidOption(format!(
                    "depth table: offset {} mm of bin {k} is not a depth error (at most ±{} mm)",
                    o * 1e3,
                    MAX_OFFSET_M * 1e3
                )));
            }
            if !(s.is_finite() && s > 0.0 && s <= MAX_OFFSET_M && e.is_finite() && e >= 0.0) {
                return Err(EpdError::InvalidOption(format!(
                    "depth table: spread {} mm or standard error {} mm of bin {k}: need a \
                     spread > 0 and at most {} mm, a standard error ≥ 0",
                    s * 1e3,
                    e * 1e3,
                    MAX_OFFSET_M * 1e3
                )));
            }
        }
        if !self.support.contains(&Support::Observed) {
            return Err(EpdError::InvalidOption(
                "depth table: no bin was observed".into(),
            ));
        }
        Ok(())
    }

    /// The offset and spread at model range `r` (m), ln intensity `li` and ln cos θ
    /// `lc`, or `None` outside the support: the bin holding the point must be observed
    /// or bridged; the value is trilinear between bin centres (constant beyond the outer
    /// centres), each corner outside the support replaced by the holding bin's value.
    pub fn lookup(&self, r: f64, li: f64, lc: f64) -> Option<Lookup> {
        if !(self.range.holds(r)
            && self.log_intensity.holds(li)
            && self.log_cos_incidence.holds(lc))
        {
            return None;
        }
        let (bi, bj, bl) = (
            self.range.bin(r),
            self.log_intensity.bin(li),
            self.log_cos_incidence.bin(lc),
        );
        let home = self.index(bi, bj, bl);
        if self.support[home] == Support::Outside {
            return None;
        }
        let (i0, i1, fi) = self.range.bracket(r);
        let (j0, j1, fj) = self.log_intensity.bracket(li);
        let (l0, l1, fl) = self.log_cos_incidence.bracket(lc);
        let (mut o, mut s) = (0.0, 0.0);
        for (i, wi) in [(i0, 1.0 - fi), (i1, fi)] {
            for (j, wj) in [(j0, 1.0 - fj), (j1, fj)] {
                for (l, wl) in [(l0, 1.0 - fl), (l1, fl)] {
                    let w = wi * wj * wl;
                    if w == 0.0 {
                        continue;
                    }
                    let mut k = self.index(i, j, l);
                    if self.support[k] == Support::Outside {
                        k = home;
                    }
                    o += w * self.offset_m[k];
                    s += w * self.spread_m[k];
                }
            }
        }
        Some(Lookup {
            offset_m: o,
            spread_m: s,
            bin: home,
        })
    }

    /// Whether a measured point (range r, intensity I, cos θ) lies in the support.
    pub fn covers(&self, range_m: f64, intensity: f64, cos_incidence: f64) -> bool {
        intensity > 0.0
            && cos_incidence > 0.0
            && self
                .lookup(range_m, intensity.ln(), cos_incidence.ln())
                .is_some()
    }

    /// Correct measured points (SCS, m) along their rays: for each valid point with a
    /// finite intensity > 0 and a cos θ in (0, 1] (`cos_incidence`, from the fitted wall),
    /// the wall range ρ with ρ + T(ρ, I, θ) = r by the fixed point ρ ← r − T(ρ, I, θ)
    /// from ρ = r (stops when a step moves ρ by less than 10 µm, at most eight steps).
    /// A point outside the support is not corrected: it becomes NaN (the estimators drop
    /// it) and is counted in `outside` — the table's offsets are centimetres, so an
    /// uncorrected point among corrected ones would be a gross outlier, and an
    /// extrapolated correction a guess. A point without a usable intensity or incidence
    /// also becomes NaN.
    pub fn correct(
        &self,
        points: &mut [[f64; 3]],
        intensity: &[f64],
        cos_incidence: &[f64],
    ) -> Result<Correction, EpdError> {
        if points.len() != intensity.len() || points.len() != cos_incidence.len() {
            return Err(EpdError::InvalidOption(format!(
                "{} points but {} intensities and {} incidences: one of each per point",
                points.len(),
                intensity.len(),
                cos_incidence.len()
            )));
        }
        let per: Vec<(Option<u32>, f64, bool, bool)> = points
            .par_iter_mut()
            .zip(intensity.par_iter())
            .zip(cos_incidence.par_iter())
            .map(|((p, &i), &c)| {
                if !super::table::usable(p) {
                    return (None, f64::NAN, false, false);
                }
                if !(i > 0.0 && i.is_finite() && c > 0.0 && c <= 1.0) {
                    *p = [f64::NAN; 3];
                    return (None, f64::NAN, false, false);
                }
                let (li, lc) = (i.ln(), c.ln());
                let r = super::table::norm(p);
                let Some(mut look) = self.lookup(r, li, lc) else {
                    *p = [f64::NAN; 3];
                    return (None, f64::NAN, false, true);
                };
                let mut rho = r - look.offset_m;
                for _ in 0..7 {
                    let Some(next) = self.lookup(rho, li, lc) else {
                        break;
                    };
                    let step = r - next.offset_m;
                    let done = (step - rho).abs() < 1e-5;
                    rho = step;
                    look = next;
                    if done {
                        break;
                    }
                }
                let f = rho / r;
                if !(f > 0.0 && f.is_finite()) {
                    *p = [f64::NAN; 3];
                    return (None, f64::NAN, false, false);
                }
                *p = [p[0] * f, p[1] * f, p[2] * f];
                (Some(look.bin as u32), look.spread_m, true, false)
            })
            .collect();
        let mut c = Correction {
            moved: 0,
            outside: 0,
            bin: Vec::with_capacity(per.len()),
            sigma_m: Vec::with_capacity(per.len()),
        };
        for (b, s, moved, out) in per {
            c.moved += usize::from(moved);
            c.outside += usize::from(out);
            c.bin.push(b);
            c.sigma_m.push(s);
        }
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table of one range row whose observed bins lie on two segments of one line of
    /// the (intensity, incidence) bin plane, as two rig sizes' bins do at one range, with
    /// values exactly linear in the bin coordinates: the bridged bins of the line between
    /// the segments take the linear values (to the ridge's 10⁻⁹ and rounding), where an
    /// inverse-distance mean leans towards the longer segment; every bridged value stays
    /// within the observed values' range.
    #[test]
    fn bridged_bins_reproduce_a_linear_trend_along_the_rigs_line() {
        let n = 16;
        let linear = |j: usize, l: usize| 0.03 + 0.002 * j as f64 - 0.001 * l as f64;
        let mut t = IncidenceTable {
            range: Axis::new(0.5, 2.0, 1),
            log_intensity: Axis::new(-2.0, 2.0, n),
            log_cos_incidence: Axis::new(-2.0, 0.0, n),
            offset_m: vec![f64::NAN; n * n],
            spread_m: vec![f64::NAN; n * n],
            se_m: vec![f64::NAN; n * n],
            count: vec![0; n * n],
            support: vec![Support::Outside; n * n],
        };
        // The line j = l + 2: a long segment (l = 0..7) and a short one (l = 12..13).
        for l in (0..8).chain(12..14) {
            let k = t.index(0, l + 2, l);
            t.offset_m[k] = linear(l + 2, l);
            t.spread_m[k] = 0.01;
            t.se_m[k] = 0.001;
            t.count[k] = 100;
            t.support[k] = Support::Observed;
        }
        t.bridge();
        let (lo, hi) = (linear(2, 0), linear(15, 13));
        for l in 8..12 {
            let k = t.index(0, l + 2, l);
            assert_eq!(t.support[k], Support::Bridged);
            // The ridge biases the slopes by 10⁻⁹ of themselves: at most 10⁻⁹ of the
            // largest change of value along the row.
            assert!(
                (t.offset_m[k] - linear(l + 2, l)).abs() <= 1e-9 * (hi - lo) * n as f64,
                "bin ({}, {l}): {} vs {}",
                l + 2,
                t.offset_m[k],
                linear(l + 2, l)
            );
        }
        for k in 0..n * n {
            if t.support[k] == Support::Bridged {
                assert!((lo..=hi).contains(&t.offset_m[k]), "{}", t.offset_m[k]);
            }
        }
    }
}
