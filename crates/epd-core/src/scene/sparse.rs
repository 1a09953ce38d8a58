//! The opening test of the cells too sparse for the medians' tests: a coarse camera
//! (160 × 120 pixels) or a distant stretch of pipe leaves fewer than
//! [`crate::segment::SegmentOptions::min_points`] points in a slice's sectors, whose
//! medians the harmonic fit (`profile`'s shift and bump) then leaves out — all of them
//! in a sparse slice, where the fit is not defined, and a branch opening 1.5 m ahead went
//! unseen (`test_independent_tees.py`: 0 of 8 frames at 160 × 120); some of them in a
//! slice the medians do test, where an opening's sector may be one so left out (tof-sim's
//! tee 3 m ahead, full frames: 3 of 6 read `straight`). Every cell is tested by one of the
//! two: by the medians when it holds `min_points`, else here.
//!
//! A ray that crosses an opening runs on to the branch's far wall, so its point lies
//! many σ outside the straight wall; a wall point does so only as the noise's tail. In
//! each sparse cell, a point *exceeds* when its deviation is above the local wall's
//! median + [`EXCEEDANCE_SIGMAS`]·1.4826·MAD (taken over the sector's points in the slice
//! and its neighbours, at least [`LOCAL_WALL_POINTS`] points: `sector_limit`). A sector of n points with e exceedances is
//! tested against the wall's rate p₀ by the binomial upper tail P(X ≥ e), X ~ Bin(n, p₀),
//! with the points' correlation taken into account by their design effect κ(n) (a
//! cluster of n correlated points carries the information of n/κ independent ones):
//! P = I_{p₀}(e/κ, n/κ − e/κ + 1), the regularised incomplete beta that extends the
//! binomial tail to a fractional count. κ is the profile's law of the medians' variance
//! scale ([`DesignEffect`]): by Gebelein's inequality the correlation of two
//! exceedance indicators of a Gaussian pair is at most the pair's own correlation, so
//! the counts' design effect is at most the values', and κ is conservative for them.
//! The p-values are adjusted by Bonferroni over every sector tested in the frame, and a
//! slice *opens* when its least adjusted p-value is below [`OPENING_FALSE_ALARM`].

use rayon::prelude::*;

use crate::scene::edge::{EXCEEDANCE_SIGMAS, MIN_WALL_POINTS, OPEN_RATE};
use crate::scene::profile::{MIN_SECTORS_TESTED, Slice};
use crate::segment::SegmentOptions;

/// The false-alarm rate of the opening test per frame (a straight pipe's frame has an
/// opening slice with at most this probability, whatever the dependence between
/// sectors): 10⁻³, the same budget as the medians' tests
/// ([`crate::scene::profile::SURVEY_FALSE_ALARM`]); the two together read a straight
/// frame as departing with probability at most 2·10⁻³, within the 1 %.
pub const OPENING_FALSE_ALARM: f64 = 1e-3;

/// The fewest points the local wall's median and MAD are taken from: two of
/// [`MIN_WALL_POINTS`] (the MAD's relative standard error about 1.17/√n, 0.14 at 68), the
/// slices on either side of the tested one added until they hold as many.
pub const LOCAL_WALL_POINTS: usize = 2 * MIN_WALL_POINTS;

/// The medians' variance scale as a function of the points a sector holds,
/// κ(n) = exp(a)·n^b (`profile::calibrate_tests`, fitted over the slices the medians'
/// tests could judge); κ = 1 (independent points) where none could be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DesignEffect {
    /// ln κ at n = 1.
    pub a: f64,
    /// The exponent b ∈ [0, 1].
    pub b: f64,
}

impl DesignEffect {
    /// Independent points: κ = 1.
    pub const INDEPENDENT: Self = Self { a: 0.0, b: 0.0 };

    /// κ(n), at least 1 (a cluster carries no more information than its points).
    pub fn at(&self, n: f64) -> f64 {
        (self.a + self.b * n.max(1.0).ln()).exp().max(1.0)
    }
}

/// The sectors (of 12, 30° each) a slice must have points in for its sparse cells to be
/// tested: [`MIN_SECTORS_TESTED`], as many as the medians' tests need medians in. A slice at the edge of the view, where the wall
/// enters it near the sensor, has points in a few sectors only — many of them, at short
/// range with a noise there far below the fit's own error (range noise growing as r²: 10
/// of 120 straight 8" frames read `in_bend` when such slices were tested, their sectors
/// exceeding by the fitted axis's offset); it is not sparse but partly out of view.
pub const MIN_SECTORS_IN_VIEW: usize = MIN_SECTORS_TESTED;

/// Test the cells the medians could not (those with fewer than `min_points` points, or
/// every cell of a slice with fewer than [`MIN_SECTORS_TESTED`] sectors with a median) of the slices with at
/// least [`MIN_SECTORS_IN_VIEW`] sectors in view for an opening, setting the slices'
/// `opening_p` and `opening_psi` (and `departure_p` to the least of its own and
/// `opening_p`): `cells` holds each slice's sectors' deviations (slice-major, `sectors` per
/// slice), as `profile` binned them.
pub(crate) fn test_openings<C: AsRef<[f32]> + Sync>(
    slices: &mut [Slice],
    cells: &[C],
    o: &SegmentOptions,
    law: &DesignEffect,
) {
    let (sectors, min_points) = (o.sectors, o.min_points);
    let in_view = |i: usize| {
        cells[i * sectors..(i + 1) * sectors]
            .iter()
            .filter(|c| !c.as_ref().is_empty())
            .count()
    };
    let sparse: Vec<usize> = (0..slices.len())
        .filter(|&i| in_view(i) >= MIN_SECTORS_IN_VIEW)
        .collect();
    if sparse.is_empty() {
        return;
    }
    let cell = |i: usize, k: usize| cells[i * sectors + k].as_ref();
    // Per slice tested, per sector: (points, exceedances); (0, 0) for a cell left to the
    // medians. With every cell's (points, exceedances) of the slices tested, the medians'
    // too: the wall's rate. Slice by slice on all cores (each cell's limit is a median
    // and a MAD of its neighbourhood; the sums are of whole numbers, the same in any
    // order).
    let judged: &[Slice] = slices;
    let rows: Vec<SliceCounts> = sparse
        .par_iter()
        .map_init(Scratch::default, |scratch, &i| {
            let (mut n, mut e_sum) = (0usize, 0usize);
            let row = (0..sectors)
                .map(|k| {
                    let d = cell(i, k);
                    if d.is_empty() {
                        // No point to exceed: the limit is not needed.
                        return (0, 0);
                    }
                    let limit = sector_limit(cells, sectors, i, k, o.min_shift_m, scratch);
                    let e = d.iter().filter(|&&v| f64::from(v) > limit).count();
                    n += d.len();
                    e_sum += e;
                    // A cell whose median the medians' tests use is theirs.
                    if judged[i].n_sectors >= MIN_SECTORS_TESTED && d.len() >= min_points {
                        return (0, 0);
                    }
                    (d.len(), e)
                })
                .collect();
            (row, n, e_sum)
        })
        .collect();
    let (n_all, e_all) = rows
        .iter()
        .fold((0usize, 0usize), |(n, e), r| (n + r.1, e + r.2));
    let counts: Vec<Vec<(usize, usize)>> = rows.into_iter().map(|r| r.0).collect();
    // The wall's rate: the pooled rate of every cell of the slices tested (an opening
    // raises it, which only makes the test more conservative), at least ten times the
    // Gaussian tail, as the edge's ring test takes it ([`OPEN_RATE`]: a camera's systematic
    // errors raise the wall's rate above the Gaussian 0.135 %).
    let p0 = (e_all as f64 / n_all.max(1) as f64).max(OPEN_RATE);
    // Every (window, sector) tested, over the scales: the Bonferroni factor.
    // Window starts j (in `sparse`) of `w` slices.
    let windows = |w: usize| -> Vec<usize> {
        (0..sparse.len().saturating_sub(w - 1))
            .filter(|&j| sparse[j + w - 1] - sparse[j] < 2 * w)
            .collect()
    };
    // Sectors k, k + 1, …, k + v − 1 around the clock (wrapping).
    let arc = |k: usize, v: usize| (k..k + v).map(move |m| m % sectors);
    let pooled = |j: usize, w: usize, k: usize, v: usize| {
        counts[j..j + w]
            .iter()
            .fold((0usize, 0usize), |(n, e), row| {
                arc(k, v).fold((n, e), |(n, e), m| (n + row[m].0, e + row[m].1))
            })
    };
    // The clock windows: each width up to the sectors there are (wrapping makes a
    // window of every sector the same for each start: counted once).
    let widths: Vec<usize> = WINDOW_SECTORS
        .iter()
        .copied()
        .filter(|&v| v < sectors)
        .collect();
    let tested = WINDOW_SLICES
        .iter()
        .map(|&w| {
            windows(w)
                .into_iter()
                .map(|j| {
                    widths
                        .iter()
                        .map(|&v| (0..sectors).filter(|&k| pooled(j, w, k, v).0 > 0).count())
                        .sum::<usize>()
                })
                .sum::<usize>()
        })
        .sum::<usize>()
        .max(1) as f64;
    for &i in &sparse {
        slices[i].opening_p = 1.0;
    }
    for &w in &WINDOW_SLICES {
        for j in windows(w) {
            for &v in &widths {
                for k in 0..sectors {
                    let (n, e) = pooled(j, w, k, v);
                    let p = (tested * binomial_tail(n, e, p0, law)).min(1.0);
                    // Where in the window the exceedances begin: its first slice with one
                    // in these sectors (a window may start on wall before the opening).
                    let Some(first) = (j..j + w).find(|&m| arc(k, v).any(|s| counts[m][s].1 > 0))
                    else {
                        continue;
                    };
                    let i = sparse[first];
                    if !(p >= slices[i].opening_p) {
                        slices[i].opening_p = p;
                        slices[i].opening_psi = ((k as f64 + 0.5 * v as f64) / sectors as f64
                            * std::f64::consts::TAU)
                            % std::f64::consts::TAU;
                    }
                }
            }
        }
    }
    for &i in &sparse {
        let (p, o) = (slices[i].departure_p, slices[i].opening_p);
        slices[i].departure_p = if p.is_nan() { o } else { p.min(o) };
    }
}

/// One tested slice's (points, exceedances) per sector ((0, 0) for a cell left to the
/// medians), and its points and exceedances over every cell ([`test_openings`]).
type SliceCounts = (Vec<(usize, usize)>, usize, usize);

/// The lengths, in slices, of the windows the opening test pools a sector's counts over:
/// an opening seen by a coarse camera may leave one or two exceeding points per slice
/// over several slices, too few in any one. Dyadic lengths up to 4 slices (20 cm): an
/// opening is as long as its branch is wide, and the branches the checks use (0.5–1·D of
/// a 20" pipe, 24–48 cm) are longer; the three scales cost a factor of about 3 in the
/// Bonferroni adjustment. A window holds consecutive tested slices within twice its
/// length (the slices between holding no points); its p-value goes to its first slice
/// with an exceedance in the sector tested.
pub const WINDOW_SLICES: [usize; 3] = [1, 2, 4];

/// The widths, in sectors, of the clock windows the opening test pools a window's
/// counts over: one sector, and two neighbouring ones (around the clock). A branch of
/// 0.5–1·D spans 0.16–0.32 of the circumference (2–4 of 12 sectors), and wherever the
/// fitted roll puts it, its opening may straddle a sector boundary with its exceedances
/// split between two sectors, too few in either (`test_independent_tees.py`, 160 × 120
/// at 3 m: 4 exceeding points of 4 in one sector, the others in the next). Two widths
/// double the Bonferroni factor, a cost of ln 2 in the exponent of a tail that falls as
/// p₀^e.
pub const WINDOW_SECTORS: [usize; 2] = [1, 2];

/// The exceedance limit of sector `k` in slice `i`: the median +
/// [`EXCEEDANCE_SIGMAS`]·1.4826·MAD of that sector's deviations over a neighbourhood of
/// slice `i` holding [`LOCAL_WALL_POINTS`], the lower of two: the slices before it (nearer
/// the sensor) added one at a time, then, when those hold too few, the slices after; and
/// the slices on both sides added a pair at a time. Each fails where the other does not:
/// an opening is longer than a sparse sector's neighbourhood — a branch as long as a 10"
/// pipe is wide spans 5 slices, and at 6 points a cell the 68 points on both sides span
/// 11, so in the opening's first slice half of them lay in it, whose spread raised the
/// limit above its own points (off-grid numpy tees, `scripts/offgrid-numpy.py`: 10"–16"
/// pipes 1.3–3 m ahead, 23 of 71 frames read `straight` found with the wall before);
/// while at 2 points a cell the wall before spans 1.7 m, over which the incidence, and
/// with it the deviations' spread, changes twofold (a 12" and a 16" tee 2.75 and 2.95 m
/// ahead read `straight` with the wall before alone, `tee_ahead` with either). A limit
/// that errs low raises the rate the cells are tested against where that rate is above
/// its floor (`test_openings`' p₀, pooled over the same limits, at least [`OPEN_RATE`]).
/// The numpy straight frames of `test_straight_false_alarms.py` read otherwise in 0 of
/// 4000 with each rule and with the lower of both. The noise grows with range, so the
/// wall's spread is taken near the slice; and it differs between sectors, most at a
/// distance, where around an off-axis sensor the incidence (and so the deviations'
/// spread, the range noise times cos θ) differs by sector: pooled over a slice's sectors,
/// a straight `epd simulate` frame (σ = 30 mm, the sensor 57 mm off the axis) read as a
/// tee 4.9 m ahead, its noisier sector exceeding in 4 of 5 points.
///
/// The excess is at least `min_excess` (the survey's
/// [`SegmentOptions::min_shift_m`], the smallest departure it reports): on a noise-free
/// frame the MAD is the fit's rounding error, 10⁻¹³ m, and the rounding's tail read
/// straight frames as tees and bends. A ray through an opening runs on to the branch's
/// far wall, about a diameter beyond, far above either.
fn sector_limit<C: AsRef<[f32]>>(
    cells: &[C],
    sectors: usize,
    i: usize,
    k: usize,
    min_excess: f64,
    scratch: &mut Scratch,
) -> f64 {
    let n_slices = cells.len() / sectors;
    let len = |j: usize| cells[j * sectors + k].as_ref().len();
    // Before first (then after): the slices nearest the sensor.
    let (mut lo, mut hi) = (i, i);
    let mut n = len(i);
    while n < LOCAL_WALL_POINTS && lo > 0 {
        lo -= 1;
        n += len(lo);
    }
    while n < LOCAL_WALL_POINTS && hi + 1 < n_slices {
        hi += 1;
        n += len(hi);
    }
    let before = limit_over(cells, sectors, k, lo..=hi, min_excess, scratch);
    // On both sides, one slice each at a time.
    let (mut lo2, mut hi2) = (i, i);
    let mut n = len(i);
    while n < LOCAL_WALL_POINTS && (lo2 > 0 || hi2 + 1 < n_slices) {
        if lo2 > 0 {
            lo2 -= 1;
            n += len(lo2);
        }
        if hi2 + 1 < n_slices {
            hi2 += 1;
            n += len(hi2);
        }
    }
    if (lo2, hi2) == (lo, hi) {
        return before;
    }
    before.min(limit_over(
        cells,
        sectors,
        k,
        lo2..=hi2,
        min_excess,
        scratch,
    ))
}

/// The median + [`EXCEEDANCE_SIGMAS`]·1.4826·MAD (at least `min_excess` above the median)
/// of sector `k`'s deviations over the slices `range`.
fn limit_over<C: AsRef<[f32]>>(
    cells: &[C],
    sectors: usize,
    k: usize,
    range: std::ops::RangeInclusive<usize>,
    min_excess: f64,
    scratch: &mut Scratch,
) -> f64 {
    let Scratch(d, dev) = scratch;
    d.clear();
    for j in range {
        d.extend(
            cells[j * sectors + k]
                .as_ref()
                .iter()
                .map(|&v| f64::from(v)),
        );
    }
    let (centre, sigma) = crate::loss::median_and_mad_sigma_in(d, dev);
    centre + (EXCEEDANCE_SIGMAS * sigma).max(min_excess)
}

/// The buffers one thread's [`sector_limit`]s reuse: the neighbourhood's deviations and
/// their distances from its median (allocated once per thread, not per cell).
#[derive(Default)]
struct Scratch(Vec<f64>, Vec<f64>);

/// P(X ≥ e) for X ~ Bin(n/κ, p₀) at the fractional count e/κ (κ = `law`.at(n)):
/// I_{p₀}(e/κ, n/κ − e/κ + 1). 1 when e is no more than expected.
fn binomial_tail(n: usize, e: usize, p0: f64, law: &DesignEffect) -> f64 {
    if e == 0 || (e as f64) <= n as f64 * p0 {
        return 1.0;
    }
    let kappa = law.at(n as f64);
    let (n, e) = (n as f64 / kappa, e as f64 / kappa);
    let p = crate::fit::student::incomplete_beta(e, n - e + 1.0, p0, 1.0 - p0);
    if p.is_nan() { 1.0 } else { p }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::uniforms;

    /// The tail at whole counts is the binomial's: P(X ≥ 2) for Bin(5, 0.1) =
    /// 1 − 0.9⁵ − 5·0.1·0.9⁴ = 0.08146; P(X ≥ 5) = 10⁻⁵; a design effect of 5 makes 5 of
    /// 5 count as 1 of 1: P = p₀.
    #[test]
    fn the_tail_is_the_binomials() {
        let ind = DesignEffect::INDEPENDENT;
        let exact = 1.0 - 0.9f64.powi(5) - 5.0 * 0.1 * 0.9f64.powi(4);
        assert!((binomial_tail(5, 2, 0.1, &ind) - exact).abs() < 1e-12);
        assert!((binomial_tail(5, 5, 0.1, &ind) - 1e-5).abs() < 1e-15);
        assert_eq!(binomial_tail(5, 0, 0.1, &ind), 1.0);
        let five = DesignEffect {
            a: 5f64.ln(),
            b: 0.0,
        };
        assert!((binomial_tail(5, 5, 0.1, &five) - 0.1).abs() < 1e-12);
    }

    /// A bare slice for the tests: `n` points, no sector with a median.
    fn sparse_slice(start_m: f64, n: usize) -> Slice {
        Slice {
            n_points: n,
            ..Slice::empty(start_m)
        }
    }

    /// Slices of a few Gaussian points per sector (σ = 2 mm), as a coarse camera
    /// gives; `open(i, k)` puts its cell 0.2 m outside.
    fn frame(
        u: &mut impl FnMut() -> f64,
        per_cell: usize,
        open: impl Fn(usize, usize) -> bool,
    ) -> (Vec<Slice>, Vec<Vec<f32>>) {
        let (n_slices, ns) = (40, 12);
        let mut cells = vec![Vec::new(); n_slices * ns];
        for i in 0..n_slices {
            for k in 0..ns {
                for _ in 0..per_cell {
                    // Box–Muller.
                    let g = (-2.0 * (1.0 - u()).ln()).sqrt() * (std::f64::consts::TAU * u()).cos();
                    cells[i * ns + k].push((0.002 * g + if open(i, k) { 0.2 } else { 0.0 }) as f32);
                }
            }
        }
        let slices = (0..n_slices)
            .map(|i| sparse_slice(i as f64 * 0.05, per_cell * ns))
            .collect();
        (slices, cells)
    }

    /// Straight frames of 4 points per cell: over 2000 frames the share with an opening
    /// slice stays within the level, 10⁻³ (the binomial bound's one-sided 95 % limit for 0
    /// of 2000 is 1.5·10⁻³, so a rate at the level passes with probability 0.14 and one
    /// of 3·10⁻³ with 0.0025); two cells of a branch opening, 4 of 4 points 0.2 m out,
    /// open their slices, in the branch's sector.
    #[test]
    fn sparse_openings_are_found_at_the_stated_false_alarm_rate() {
        let mut u = uniforms(29);
        let law = DesignEffect::INDEPENDENT;
        let mut alarms = 0;
        for _ in 0..2000 {
            let (mut slices, cells) = frame(&mut u, 4, |_, _| false);
            test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
            alarms += usize::from(slices.iter().any(|s| s.opening_p < OPENING_FALSE_ALARM));
        }
        assert!(alarms <= 2, "{alarms} of 2000 straight frames opened");
        let (mut slices, cells) = frame(&mut u, 4, |i, k| (20..22).contains(&i) && k == 3);
        test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
        for (i, s) in slices.iter().enumerate() {
            let opens = s.opening_p < OPENING_FALSE_ALARM;
            assert_eq!(opens, (20..22).contains(&i), "slice {i}: {s:?}");
            if opens {
                assert!((s.opening_psi - 3.5 / 12.0 * std::f64::consts::TAU).abs() < 1e-12);
            }
        }
    }

    /// A noise-free frame: the deviations are the fit's rounding, here exactly 0 but in
    /// two cells of one sector, where 3 of 4 points lie 10⁻¹⁵ m out (the local wall's MAD
    /// is 0, so without a floor each is an exceedance, and 6 of 8 at p₀ = 0.3 % opens).
    /// Nothing opens below the survey's `min_shift_m`; the same cells 0.2 m out do.
    #[test]
    fn rounding_is_no_opening() {
        let mut u = uniforms(41);
        let law = DesignEffect::INDEPENDENT;
        for (out, opens) in [(1e-15, false), (0.2, true)] {
            let (mut slices, mut cells) = frame(&mut u, 4, |_, _| false);
            for (c, cell) in cells.iter_mut().enumerate() {
                let (i, k) = (c / 12, c % 12);
                for (m, d) in cell.iter_mut().enumerate() {
                    let branch = (20..22).contains(&i) && k == 3 && m < 3;
                    *d = if branch { out } else { 0.0 };
                }
            }
            test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
            let open: Vec<usize> = (0..slices.len()).filter(|&i| slices[i].opens()).collect();
            assert_eq!(!open.is_empty(), opens, "{out} m out: {open:?}");
        }
    }

    /// An opening too thin for any one slice: 2 of each cell's 4 points 0.2 m out in
    /// slices 20 to 23 of one sector. One slice's 2 of 4 (P ≈ 6p₀² ≈ 10⁻³ before the
    /// adjustment) does not open; pooled over 4 slices, 8 of 16 does, first at slice 20
    /// (the windows that start inside the opening open too).
    #[test]
    fn windows_pool_a_thin_opening() {
        let mut u = uniforms(37);
        let law = DesignEffect::INDEPENDENT;
        let (mut slices, mut cells) = frame(&mut u, 4, |_, _| false);
        for i in 20..24 {
            for d in cells[i * 12 + 3].iter_mut().take(2) {
                *d += 0.2;
            }
        }
        assert_eq!(
            cells.iter().filter(|c| c.iter().any(|&d| d > 0.1)).count(),
            4
        );
        test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
        let open: Vec<usize> = (0..slices.len()).filter(|&i| slices[i].opens()).collect();
        assert_eq!(open.first(), Some(&20), "{:?}", &slices[18..24]);
        assert!(open.iter().all(|i| (20..24).contains(i)), "{open:?}");
        assert!(
            slices.iter().all(|s| s.opening_p <= 1.0),
            "every slice tested"
        );
        let one = (tested_cells(12, 40) as f64) * binomial_tail(4, 2, OPEN_RATE, &law);
        assert!(one > OPENING_FALSE_ALARM, "{one}");
    }

    /// Sectors of unequal spread, as an off-axis sensor's incidence makes them far down
    /// the pipe: one sector's noise three times the others' (6 against 2 mm), 5 points per
    /// cell. Its own wall's limit keeps it from opening: no straight frame of 500 opens.
    /// (A limit pooled over the slice's sectors would lie near 1σ of the noisy sector,
    /// 3 × 2 mm against its 6 mm, far above the wall's rate of exceedances.)
    #[test]
    fn a_noisier_sector_is_no_opening() {
        let mut u = uniforms(43);
        let law = DesignEffect::INDEPENDENT;
        let mut opened = 0;
        for _ in 0..500 {
            let (mut slices, mut cells) = frame(&mut u, 5, |_, _| false);
            for i in 0..slices.len() {
                for d in cells[i * 12 + 4].iter_mut() {
                    *d *= 3.0;
                }
            }
            test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
            opened += usize::from(slices.iter().any(|s| s.opens()));
        }
        assert_eq!(opened, 0);
    }

    /// In a slice the medians test (6 or more sectors with 12 points), a cell with fewer
    /// points is tested here: 4 of its 4 points 0.2 m out open the slice, in that sector;
    /// the same 4 points among 20 wall points in a cell the medians use are theirs, and
    /// the slice does not open here.
    #[test]
    fn a_sparse_cell_in_a_dense_slice_is_tested() {
        let mut u = uniforms(41);
        let law = DesignEffect::INDEPENDENT;
        for (wall, opens) in [(0, true), (20, false)] {
            let (mut slices, mut cells) = frame(&mut u, 20, |_, _| false);
            for s in slices.iter_mut() {
                s.n_sectors = 12;
            }
            let c = &mut cells[20 * 12 + 3];
            c.truncate(wall);
            c.extend([0.2, 0.201, 0.199, 0.2]);
            test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
            assert_eq!(slices[20].opens(), opens, "{:?}", slices[20]);
            if opens {
                assert!(
                    (slices[20].opening_psi - 3.5 / 12.0 * std::f64::consts::TAU).abs() < 1e-12
                );
            }
            assert!(
                slices
                    .iter()
                    .enumerate()
                    .all(|(i, s)| i == 20 || !s.opens())
            );
        }
    }

    /// An opening longer than a sector's neighbourhood: slices 20 to 33 of sector 3, 4
    /// points a cell 0.2 m out. Taken over 17 slices on both sides of slice 20, the wall
    /// would hold 9 of the opening's slices, more than half its points, and its limit would
    /// lie above them (no exceedance); taken before it, slice 20 opens, and nothing before
    /// it does.
    #[test]
    fn an_opening_longer_than_the_walls_neighbourhood_opens_at_its_start() {
        let mut u = uniforms(47);
        let law = DesignEffect::INDEPENDENT;
        let (mut slices, cells) = frame(&mut u, 4, |i, k| (20..34).contains(&i) && k == 3);
        test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
        let open: Vec<usize> = (0..slices.len()).filter(|&i| slices[i].opens()).collect();
        assert_eq!(open.first(), Some(&20), "{:?}", &slices[18..24]);
        assert!((slices[20].opening_psi - 3.5 / 12.0 * std::f64::consts::TAU).abs() < 1e-12);
    }

    /// Far down a pipe the deviations' spread shrinks with distance (the incidence grows
    /// more grazing): 80 slices of 2 points a cell, the spread 0.12/(i + 20) m, and a
    /// shallow opening, 7.5 mm out, in slices 40 to 43 of sectors 3 and 4. The wall before
    /// slice 40 spans slices 7 to 40, its spread well above the slice's own, and its
    /// limit lies above most of the opening's points; the wall on both sides, slices 23 to
    /// 57, lies about the slice, and the lower of the two opens the slice.
    #[test]
    fn a_far_opening_is_judged_by_the_wall_about_it() {
        let mut u = uniforms(59);
        let law = DesignEffect::INDEPENDENT;
        let (n_slices, ns) = (80, 12);
        let mut cells = vec![Vec::new(); n_slices * ns];
        for i in 0..n_slices {
            let spread = 0.12 / (i as f64 + 20.0);
            for k in 0..ns {
                for _ in 0..2 {
                    let g = (-2.0 * (1.0 - u()).ln()).sqrt() * (std::f64::consts::TAU * u()).cos();
                    let open = (40..44).contains(&i) && (3..5).contains(&k);
                    cells[i * ns + k].push((spread * g + if open { 0.0075 } else { 0.0 }) as f32);
                }
            }
        }
        let mut slices: Vec<Slice> = (0..n_slices)
            .map(|i| sparse_slice(i as f64 * 0.05, 2 * ns))
            .collect();
        test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
        let open: Vec<usize> = (0..n_slices).filter(|&i| slices[i].opens()).collect();
        assert_eq!(open.first(), Some(&40), "{:?}", &slices[38..44]);
    }

    /// The sectors tested over the windows of a frame of `slices` sparse slices, every
    /// sector holding points.
    fn tested_cells(sectors: usize, slices: usize) -> usize {
        WINDOW_SLICES
            .iter()
            .map(|&w| sectors * (slices + 1 - w) * WINDOW_SECTORS.len())
            .sum()
    }

    /// An opening across a sector boundary (between sectors 11 and 0, where the clock
    /// wraps): 2 of each cell's 4 points 0.2 m out in slices 20 and 21 of both. Each
    /// sector alone, 4 of 8 (P ≈ 70p₀⁴ ≈ 2·10⁻⁶ before the adjustment), does not open;
    /// the two sectors pooled, 8 of 16, do, first at slice 20, at the boundary's clock
    /// angle (0).
    #[test]
    fn neighbouring_sectors_pool_an_opening_across_their_boundary() {
        let mut u = uniforms(43);
        let law = DesignEffect::INDEPENDENT;
        let (mut slices, mut cells) = frame(&mut u, 4, |_, _| false);
        for i in 20..22 {
            for k in [11, 0] {
                for d in cells[i * 12 + k].iter_mut().take(2) {
                    *d += 0.2;
                }
            }
        }
        let alone = tested_cells(12, 40) as f64 * binomial_tail(8, 4, OPEN_RATE, &law);
        assert!(alone > OPENING_FALSE_ALARM, "{alone}");
        test_openings(&mut slices, &cells, &SegmentOptions::default(), &law);
        let open: Vec<usize> = (0..slices.len()).filter(|&i| slices[i].opens()).collect();
        assert_eq!(open.first(), Some(&20), "{:?}", &slices[18..24]);
        assert!(open.iter().all(|i| (20..22).contains(i)), "{open:?}");
        let psi = slices[20].opening_psi;
        assert!(psi.min(std::f64::consts::TAU - psi) < 1e-12, "{psi}");
    }

    /// Points correlated in patches (each cell's 8 points share one draw, as a 3-pixel
    /// smoothing would give): with κ = 8 no straight frame of 500 opens; taken as
    /// independent (κ = 1), most do.
    #[test]
    fn the_design_effect_keeps_patches_from_opening() {
        let mut u = uniforms(31);
        let patchy = |u: &mut dyn FnMut() -> f64| {
            let (n_slices, ns) = (40, 12);
            let mut cells = vec![Vec::new(); n_slices * ns];
            for c in cells.iter_mut() {
                let g = (-2.0 * (1.0 - u()).ln()).sqrt() * (std::f64::consts::TAU * u()).cos();
                for _ in 0..8 {
                    c.push((0.002 * g + 0.0002 * (u() - 0.5)) as f32);
                }
            }
            let slices: Vec<Slice> = (0..n_slices)
                .map(|i| sparse_slice(i as f64 * 0.05, 8 * ns))
                .collect();
            (slices, cells)
        };
        let eight = DesignEffect {
            a: 8f64.ln(),
            b: 0.0,
        };
        let (mut with_law, mut without) = (0, 0);
        for _ in 0..500 {
            let (mut slices, cells) = patchy(&mut u);
            test_openings(&mut slices, &cells, &SegmentOptions::default(), &eight);
            with_law += usize::from(slices.iter().any(|s| s.opening_p < OPENING_FALSE_ALARM));
            test_openings(
                &mut slices,
                &cells,
                &SegmentOptions::default(),
                &DesignEffect::INDEPENDENT,
            );
            without += usize::from(slices.iter().any(|s| s.opening_p < OPENING_FALSE_ALARM));
        }
        assert_eq!(with_law, 0);
        // A cell's shared draw beyond 3σ: 1 − (1 − Φ(−3))^480 = 48 % of frames.
        assert!(without > 150, "{without}");
    }
}
