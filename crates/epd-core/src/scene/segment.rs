//! Where the straight pipe ends: a frame near a bend or a tee (the paper's §5, item 3).
//!
//! A robot approaching an elbow sees it metres ahead; fitted as one straight elliptic
//! cylinder, the bend's points bias the estimate and nothing tells the user. [`segment`]
//! fits the straight pipe, looks at how the points depart from it along the axis, and
//! refits on the points before the departure.
//!
//! **How it decides.** The points are taken to the PCS of the straight fit (eq. 3) and
//! each gets its radial deviation from the wall, d = ρ − ρ_w(ψ), with ρ, ψ the polar
//! coordinates in the cross-section and ρ_w(ψ) the ellipse's radius there. The axis is
//! cut into slices (5 cm) and each slice into angular sectors (30°); per sector the
//! median deviation m_k, and per slice the least-squares fit m_k ≈ c₀ + c₁cos ψ_k +
//! c₂sin ψ_k weighted by the medians' variances. c₀ is the slice's mean widening (what a
//! range-dependent depth bias also produces), (c₁, c₂) its *lateral shift*: a straight
//! pipe, however tilted, has none; a bend moves its tube toward its centre of curvature
//! (the wall on that side out, the opposite wall in), a tee's opening lets the points on
//! its side run outward. A slice departs when its shift is significant at the survey's
//! false-alarm rate and exceeds `min_shift_m`, or when one sector's median lies that far
//! *outside* the harmonic fit (a *bump*: the opening's one or two sectors, whose rays
//! run on to the branch's far wall, are imprecise medians that the weighted harmonic
//! hardly follows), in `persistence` consecutive slices (or in one, at α^persistence,
//! where the slices after it cannot be judged, or in one when it is a bump:
//! `first_departure`); the slices, their statistics
//! and the tests' levels are the departure profile's ([`crate::scene::profile`]). The
//! departure is then located to the first departing slice's edge refined by the
//! shift's growth (a bend's centreline leaves the axis as R_b − √(R_b² − s²) at an axial
//! distance s past its start), the straight pipe refitted on the points before it (less
//! a margin), and the test repeated with the new fit until the end stops moving. When
//! the refit sees no departure at all, the frame is straight: the departure was the wider
//! fit's, pulled off the pipe by what lies beyond the cut (numpy frames with multipath, a
//! band of ranges read long: 18 of 800 straight frames read `tee_ahead` when the wider fit
//! was kept, 7 with the refit's verdict; docs/bends-and-tees.md).
//!
//! A frame read as the sensor in a bend, or a straight pipe whose fit lacks fit or whose
//! refit is implausible, has a
//! second candidate: a straight pipe seen through a ring of range error (a multipath band
//! of ranges that reads the wall out all around, `ring_run`). The straight pipe is
//! refitted without the ring and taken when the wall before and after it holds the same
//! straight pipe at the survey's false-alarm rate (`ring_refit`); the ring is reported
//! ([`Ring`]).
//!
//! A bend and a tee differ on the far side: a bend pulls the opposite wall in (its
//! sector's median goes negative with the shift), a tee leaves it on the cylinder.

use nalgebra::Vector3;

use crate::bend::BEND_POINTS;
use crate::check::{FitOutcome, FitStatus, Implausible};
use crate::cloud::clean;
use crate::error::EpdError;
use crate::estimate::{Estimate, EstimateOptions, Method, estimate, estimate_masked};
use crate::params::Params;
use crate::points::{Mask, Points};
pub use crate::scene::axis::axis_under_straight_pipe;
use crate::scene::select::{axial_mask, axial_sample, quantile_of};
pub use crate::scene::select::{outside_ring_mask, straight_mask};

pub use crate::scene::profile::{
    AxisSigma, MIN_SECTORS_TESTED, SURVEY_FALSE_ALARM, Slice, departure_evidence, profile,
    profile_of,
};

/// What the frame shows ahead of the sensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// One straight pipe as far as the points reach.
    Straight,
    /// A straight pipe, then a bend.
    BendAhead,
    /// A straight pipe with a branch opening (a tee) ahead.
    TeeAhead,
    /// The sensor is already in a bend: no straight section in view.
    InBend,
}

impl Layout {
    /// The name in reports: `straight`, `bend_ahead`, `tee_ahead`, `in_bend`.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Straight => "straight",
            Layout::BendAhead => "bend_ahead",
            Layout::TeeAhead => "tee_ahead",
            Layout::InBend => "in_bend",
        }
    }
}

/// Settings of [`segment`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegmentOptions {
    /// Slice length along the axis (m).
    pub slice_m: f64,
    /// Angular sectors per slice (≥ [`MIN_SECTORS_TESTED`]).
    pub sectors: usize,
    /// Points a sector needs for its median to count.
    pub min_points: usize,
    /// A slice departs when its lateral shift exceeds this many of its standard errors…
    pub threshold_sigmas: f64,
    /// …and this shift (m).
    pub min_shift_m: f64,
    /// Consecutive departing slices that make a departure.
    pub persistence: usize,
    /// Points within this axial distance before the end are left out of the refit (m).
    pub margin_m: f64,
    /// Refits at most.
    pub max_rounds: usize,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        Self {
            slice_m: 0.05,
            sectors: 12,
            min_points: 12,
            threshold_sigmas: 6.0,
            min_shift_m: 0.002,
            persistence: 2,
            margin_m: 0.03,
            max_rounds: 4,
        }
    }
}

impl SegmentOptions {
    /// An error naming the first field out of range.
    pub fn validate(&self) -> Result<(), EpdError> {
        let bad = |name: &str, v: f64, why: &str| {
            Err(EpdError::InvalidOption(format!(
                "segmentation {name} = {v}: {why}"
            )))
        };
        if !(self.slice_m > 0.001 && self.slice_m <= 1.0) {
            return bad("slice_m", self.slice_m, "must lie in (0.001, 1] m");
        }
        if !(MIN_SECTORS_TESTED..=360).contains(&self.sectors) {
            // Fewer sectors than a slice needs for its tests would test nothing.
            return bad("sectors", self.sectors as f64, "must lie in [6, 360]");
        }
        if self.min_points < 3 {
            return bad("min_points", self.min_points as f64, "must be ≥ 3");
        }
        if !(self.threshold_sigmas > 0.0 && self.threshold_sigmas.is_finite()) {
            return bad("threshold_sigmas", self.threshold_sigmas, "must be > 0");
        }
        if !(self.min_shift_m >= 0.0 && self.min_shift_m.is_finite()) {
            return bad("min_shift_m", self.min_shift_m, "must be ≥ 0 m");
        }
        if self.persistence == 0 {
            return bad("persistence", 0.0, "must be ≥ 1");
        }
        if !(self.margin_m >= 0.0 && self.margin_m.is_finite()) {
            return bad("margin_m", self.margin_m, "must be ≥ 0 m");
        }
        if self.max_rounds == 0 {
            return bad("max_rounds", 0.0, "must be ≥ 1");
        }
        Ok(())
    }
}

/// A frame split into its straight section and what lies beyond.
#[derive(Clone, Debug)]
pub struct Segmentation {
    /// What lies ahead.
    pub layout: Layout,
    /// Axial distance (PCS x, m) from the sensor to the end of the straight section;
    /// `None` when the straight section runs out of view or no straight section is in
    /// view.
    pub straight_until: Option<f64>,
    /// The straight section's estimate, on its points only — unless
    /// `straight_withheld`.
    pub straight: Estimate,
    /// Whether `straight` must not be reported: the sensor is in a bend
    /// ([`Layout::InBend`]), or the straight section ends so close ahead that too few of
    /// its points (within the range gate) remain to fit it on its own; then `straight`
    /// is the last fit made, on points beyond its end too.
    pub straight_withheld: bool,
    /// Clean points beyond the straight section's end (its bend or tee), in the SCS: an
    /// even sample of at most [`BEND_POINTS`] of them (every ⌈n/`BEND_POINTS`⌉-th of their
    /// n, from the first), which is what the bend fit reads of them.
    pub beyond: Vec<[f64; 3]>,
    /// Direction of the departure in the straight fit's cross-section: the angle from
    /// the PCS +Y (major) axis toward +Z (rad); for a bend, toward its centre of
    /// curvature; for a tee, toward its branch.
    pub direction: Option<f64>,
    /// A ring of range error left out of the straight estimate ([`Ring`]).
    pub ring: Option<Ring>,
    /// The reach (SCS x, m) of the near window whose points alone the straight estimate
    /// used, when the survey answered from a window that found no end (`restart_from_near`):
    /// the points with x at most this are the straight section's. `None` otherwise.
    pub window_m: Option<f64>,
    /// Where (PCS x of the straight fit, m) the points of the straight estimate end,
    /// less the margin, when it was refitted on the points before a departure that then
    /// vanished (`refine`) and no end is reported. `None` otherwise.
    pub fitted_before_m: Option<f64>,
    /// The departure profile of the last round.
    pub profile: Vec<Slice>,
    /// Fits made.
    pub rounds: usize,
}

/// A stretch of the wall that reads wider all around than the straight pipe before and
/// after it — a multipath band of ranges, a calibration error over some ranges, or a
/// local widening of the pipe — whose points the straight estimate leaves out
/// (`ring_refit`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ring {
    /// Where it begins (PCS x of the straight fit, m).
    pub from_m: f64,
    /// Where it ends (m).
    pub to_m: f64,
    /// Its slices' mean widening against the straight fit ([`Slice::widening_m`], m).
    pub widening_m: f64,
}

/// The first slice of the first run of `persistence` departing slices, counting only
/// the slices that hold points (far down the pipe, or with a coarse camera, a slice may
/// fall between two rings of pixels and hold none, which says nothing either way), or
/// the first slice whose bump departs ([`Slice::bumps`]), or
/// the first slice whose sparse cells open on their own: the opening test's false-alarm rate is
/// stated for the whole frame ([`crate::scene::sparse::OPENING_FALSE_ALARM`]) without
/// persistence, and an opening seen by a coarse camera may fill the cells of a single
/// ring of pixels; or the first slice that departs at α^persistence when the slices after
/// it cannot be judged (below).
fn first_departure(profile: &[Slice], o: &SegmentOptions) -> Option<usize> {
    // Persistence asks the slices after a departing one to confirm it. Where they cannot
    // (fewer than [`MIN_SECTORS_TESTED`] sectors with medians: far ahead a branch takes some of a slice's
    // few points), a slice departs alone when its adjusted p-value is below α^persistence
    // ([`SURVEY_FALSE_ALARM`] to the power `persistence`): the evidence of `persistence`
    // independent slices in a row each at α, with a per-frame false alarm of at most
    // α^persistence, as the adjusted p-values are the frame's. Without it tof-sim's tee
    // 3 m ahead read `straight` at an evidence of 20–35 (3 of 12 frames of `epd simulate
    // --tee-at 3`). Where the next slices can be judged they still must confirm: a
    // multipath band's edge departs alone at such levels (straight numpy frames with a
    // band read `tee_ahead` in 42 of 800 when any slice could depart alone, 18 without).
    //
    // Persistence guards against what departs by a shift for one slice: a multipath
    // band's edge, crossing the sectors one by one. A bump — one or two sectors far
    // outside the slice's harmonic, the rest on the wall — is what an opening makes, and
    // an opening makes it mostly in one slice: the rays that cross its near edge run on to
    // the branch's far wall, those that cross the rest meet the branch's downstream wall
    // close by (a shallow view of the branch). So the bump departs alone, at the frame's
    // false-alarm rate its test already has. Measured: tof-sim's 8" tee 1 m ahead (σ 0.01
    // m, `epd simulate --od-in 8 --wall-mm 8.2 --tee-at 1`) read `straight` in 11 of 20
    // frames, its opening slice's bump at 13 standard errors and the next slice's at 3;
    // now 20 of 20. False alarms did not move: `scenarios/straight_false_alarm.toml` 4 of
    // 1080 before and after; the numpy straight frames (`test_straight_false_alarms.py`)
    // 7 and 8 of 800 with multipath, 0 of 3200 otherwise.
    let alone = SURVEY_FALSE_ALARM.powi(o.persistence.min(i32::MAX as usize) as i32);
    let seen: Vec<usize> = (0..profile.len())
        .filter(|&i| profile[i].n_points > 0)
        .collect();
    let flags: Vec<bool> = seen.iter().map(|&i| profile[i].departs(o)).collect();
    (0..flags.len())
        .find(|&j| {
            profile[seen[j]].opens()
                || (flags[j]
                    && profile[seen[j]].departure_p < alone
                    && profile[seen[j] + 1..]
                        .iter()
                        .take(o.persistence.saturating_sub(1))
                        .all(|s| s.n_sectors < MIN_SECTORS_TESTED))
                || (j + o.persistence <= flags.len()
                    && flags[j..j + o.persistence].iter().all(|&f| f))
                || profile[seen[j]].bumps(o)
        })
        .map(|j| seen[j])
}

/// The straight pipe refitted on the points (SCS) whose ray meets the wall of `beta`
/// before `end − margin` ([`axial_mask`], read in place); `None` when too little straight pipe is
/// left for it: fewer than 1000 such points, an estimate that fails on them (none
/// within the range gate, …), or — when the departure is an opening (`opening`, see
/// [`opens_ahead`]) — an estimate its own check refuses as a partial view
/// ([`Implausible::PartialView`]): the straight wall before an opening close ahead lies
/// in a few sectors of the view, a fit of it extrapolates the diameters, and the
/// departure measured against that fit vanishes.
fn refit_before(
    pts: &[[f64; 3]],
    beta: &Params,
    end: f64,
    opening: bool,
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Option<Estimate> {
    let before = axial_mask(pts, beta, |x| x < end - seg.margin_m);
    if before.count() < 1000 {
        return None;
    }
    estimate_masked(pts, &before, method, options)
        .ok()
        .filter(|e| {
            !(opening
                && matches!(
                    e.status,
                    FitStatus::Implausible(Implausible::PartialView { .. })
                ))
        })
}

/// Whether the departure at slice `i` is an opening confirmed as any departure is: a
/// significant bump ([`Slice::bumps`]: rays through a branch reaching its far wall) in
/// each of the `persistence` slices from `i` on, the persistence the survey asks of a
/// departure asked of the bump itself. Of 30 frames of `epd simulate --tee-at 0.5`, 4 read
/// `straight` because the refit before the opening was a partial view (diameters
/// 100–1000 mm off) and the departure vanished from its profile; their openings' bumps
/// were 28–123 mm at 12–107 standard errors in four slices in a row. A multipath band's
/// edge departs by a shift; with a partial-view refit kept for a bump in any one slice, 3
/// of 40 straight 42" frames with multipath read as tees (scenarios/straight_false_alarm.toml).
/// This concerns what is done with a partial-view refit, not whether the slice departs: a
/// lone bump does depart ([`first_departure`]), and a partial-view refit before it is
/// then taken as for a shift (the tee approach runs read the same with and without).
fn opens_ahead(prof: &[Slice], i: usize, seg: &SegmentOptions) -> bool {
    let run = &prof[i..];
    run.len() >= seg.persistence
        && run
            .iter()
            .take(seg.persistence.max(1))
            .all(|s| s.bumps(seg))
}

/// What [`refine`] reached.
struct Refined {
    /// The last fit.
    fit: Estimate,
    /// Its departure profile.
    profile: Vec<Slice>,
    /// Fits made.
    rounds: usize,
    /// The end (PCS x, m) whose points before it (less the margin) the last fit used;
    /// `None` when it used every point.
    cut: Option<f64>,
}

/// From the straight fit `fit`: the departure, a refit on the points before it, until
/// the departure stops moving or vanishes (at most `max_rounds` refits).
fn refine(
    pts: &[[f64; 3]],
    mut fit: Estimate,
    against: &(Params, AxisSigma),
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Result<Refined, EpdError> {
    let mut end: Option<f64> = None;
    let mut cut: Option<f64> = None;
    let mut rounds = 1;
    let mut prof = profile(pts, &against.0, &against.1, seg);
    loop {
        let departure = first_departure(&prof, seg);
        let found = departure.map(|i| locate_end(&prof, i, seg));
        let opening = departure.is_some_and(|i| opens_ahead(&prof, i, seg));
        let moved = match (found, end) {
            (None, None) => false,
            (Some(a), Some(b)) => (a - b).abs() > 0.5 * seg.slice_m,
            _ => true,
        };
        if !moved || rounds > seg.max_rounds {
            break;
        }
        let Some(x_end) = found else {
            // The departure vanished with the last refit: the straight pipe fitted on the
            // points before it leaves no slice departing, so nothing departs from the
            // straight section where the survey's reference is the section itself; the
            // departure was the wider fit's, pulled off the pipe by what lies beyond the
            // cut (multipath, a range-dependent bias). Keep this fit.
            break;
        };
        end = found;
        // Too little straight pipe left to refit: the sensor is in the bend.
        let Some(refit) = refit_before(pts, &fit.params, x_end, opening, method, options, seg)
        else {
            break;
        };
        fit = refit;
        cut = Some(x_end);
        rounds += 1;
        prof = profile(pts, &fit.params, &AxisSigma::of(&fit), seg);
    }
    Ok(Refined {
        fit,
        profile: prof,
        rounds,
        cut,
    })
}

/// Whether the profile departs from its very first slices: either the sensor is in the
/// bend, or a bend close ahead dragged the fit off the straight pipe.
fn departs_at_start(prof: &[Slice], seg: &SegmentOptions) -> bool {
    let x_first = prof.first().map_or(0.0, |s| s.start_m);
    first_departure(prof, seg).is_some_and(|i| locate_end(prof, i, seg) <= x_first + seg.slice_m)
}

/// Whether a fit's wall differs along the axis (Welch's test of the estimate, at 10⁻³)
/// or the straight model does not fit its points (its form test): a fit that finds no
/// end although this holds has hidden what lies ahead in its misfit (and, through it, in
/// its 1-σ, [`AxisSigma`]) rather than found a straight pipe.
fn misfits(fit: &Estimate) -> bool {
    fit.shared_along_axis || matches!(fit.status, FitStatus::LackOfFit(_))
}

/// The near windows `restart_from_near` fits: the nearest 85 %, then 60 %, of the
/// frame's points by their forward coordinate (SCS x). Shares of the points, not reaches
/// in metres, so that they hold for any pipe and camera: the windows were 1.0 and 0.6 m,
/// measured on the paper's 20" pipe, where they hold these shares of a full Helios2 frame
/// (`epd simulate --frames 10 --seed 3`: 86 % of the points within 1.0 m, 61 % within
/// 0.6 m, so these shares reach 0.96 and 0.59 m there); on an 8" pipe both reaches held the whole frame, and an elbow 0.5 m
/// ahead was refitted with every point (3 of 20 frames of `epd simulate --od-in 8
/// --wall-mm 8.2 --bend-at 0.5 --sigma 0.05` then read `straight`, "converged"). A camera
/// looking along a pipe sees its points crowd near the sensor (the wall's image shrinks
/// as 1/x³ per unit of x), so a share of the points is a near reach that grows with the
/// pipe's radius and the camera's view, not with its resolution; nor does it take the
/// scale from a first fit that what lies ahead may have dragged.
pub const RESTART_NEAREST_SHARE: [f64; 2] = [0.85, 0.6];

/// The fewest points a near window needs to be fitted: a restart from fewer is not
/// tried.
const RESTART_MIN_POINTS: usize = 2000;

/// After a departure at the start ([`departs_at_start`]), or a fit on every point that
/// hid what lies ahead: start again from the near points only (those within each reach of
/// [`RESTART_NEAREST_SHARE`] in turn) and keep the first start whose fit its checks do
/// not refuse (status `implausible`) and that `finds` what is sought (told whether a
/// wider window's fit departed at its start);
/// `None` when none does (the frame keeps its first verdict). Also the fits made.
fn restart_from_near(
    pts: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
    finds: impl Fn(&Refined, bool) -> bool,
) -> (Option<(Refined, Option<f64>)>, usize) {
    let mut rounds = 0;
    // The windows are cut on the measured forward coordinate. A cut on the rays' angle to
    // the sensor's axis (range noise moves a point along its ray, so a cut on the measured
    // x keeps the window edge's short ranges: the windows' fits read 1–3 of their 1-σ low on
    // numpy multipath frames) was tried on 2026-12-06 and not kept: with it the Helios2
    // model's frame with the elbow 0.6 m ahead (`scenarios/pipeline_run.toml`) read
    // `in_bend`, its narrower window refused by the form test, where the cut on x reads
    // `bend_ahead` 0.1 mm from the truth.
    // Each window's reach, the quantile of the forward coordinates, counted without
    // holding them (`quantile_of`; issue 27: their copy was 8 B a point).
    // Whether a wider window's fit departed at its start too.
    let mut departed_at_start = false;
    for share in RESTART_NEAREST_SHARE {
        let reach = quantile_of(pts, |p| p[0], share);
        let close = Mask::new(pts, |p| p[0] <= reach);
        if close.count() < RESTART_MIN_POINTS {
            continue;
        }
        let Ok(start) = estimate_masked(pts, &close, method, options) else {
            continue;
        };
        // A start that cannot be refined (its cut leaves too few points) is one that did
        // not find a straight section.
        let Ok(r) = refine(
            pts,
            start,
            &(start.params, AxisSigma::of(&start)),
            method,
            options,
            seg,
        ) else {
            continue;
        };
        rounds += r.rounds;
        // A start whose fit its own checks refuse did not find a straight section.
        if !matches!(r.fit.status, FitStatus::Implausible(_)) && finds(&r, departed_at_start) {
            // A window whose fit was not cut again used the window's points alone.
            let window = r.cut.is_none().then_some(reach);
            return (Some((r, window)), rounds);
        }
        departed_at_start |= departs_at_start(&r.profile, seg);
    }
    (None, rounds)
}

/// The straight section, its end and what lies beyond, by refitting on the points
/// before the departure until the end stops moving (see the module's text).
pub fn segment(
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Result<Segmentation, EpdError> {
    seg.validate()?;
    crate::cloud::check_ranges(points)?;
    let cloud = clean(points);
    let pts: &[[f64; 3]] = &cloud.points;
    // The fits run on the clean points: an error counts the invalid ones as dropped, as
    // `estimate` on the raw points would.
    let first = estimate(pts, method, options).map_err(|e| match e {
        EpdError::TooFewPoints {
            usable,
            dropped,
            needed,
        } => EpdError::TooFewPoints {
            usable,
            dropped: dropped + cloud.dropped,
            needed,
        },
        other => other,
    })?;
    // Every later fit is of a part of the frame: it starts from its own points, not from
    // a start given for the whole frame ([`EstimateOptions::with_start`]).
    let options = &options.without_start();
    // The profile of the fit on every point tests its slices against the straight pipe's
    // uncertainty of the axis, not against what a fitting ahead does to the fit.
    let first_axis = axis_under_straight_pipe(pts, &first, method, options);
    let Refined {
        mut fit,
        profile: mut prof,
        mut rounds,
        mut cut,
    } = refine(pts, first, &first_axis, method, options, seg)?;
    // A fit on every point whose profile finds no end although its wall differs along
    // the axis (Welch's test of the estimate, at 10⁻³) or the straight model does not fit
    // it (its form test): what lies ahead may have biased the fit and, through the misfit,
    // its 1-σ ([`AxisSigma`]), which then hides it. The near section, fitted alone, has
    // neither.
    //
    // Likewise a refit before a departure that its own checks refuse (`implausible`: a
    // partial view, too little of the wall before the departure to measure the pipe)
    // where the fit on every point was not refused: that departure was the wider fit's,
    // dragged off the pipe by what lies ahead, and the refit's profile, against a pipe
    // the points do not determine, shows none. On the numpy caster's 42" elbows 3 m
    // ahead (σ = 0.05 m, 320 × 240), 3 of 10 frames read `straight` with no estimate so:
    // the fit on every point lacked fit at the bend's far wall 6 m ahead, its profile
    // departed 0.67 m ahead, and the refit before that held 2 073 points in 2 of 8
    // sectors (Dmax 1.92 m). The near windows below then fit the straight section
    // without the far wall — unless the fit on every point holds through a ring of range
    // error ([`ring_refit`]), sought first as it is below for any refused refit: a
    // multipath band also drags the fit on every point and makes such a partial view,
    // and two 42" frames of `scenarios/straight_false_alarm.toml` whose ring refit had
    // answered within 0.07 mm were answered from a window 0.97 mm (2.7σ̂) off when the
    // windows came first.
    let partial_refit = cut.is_some()
        && matches!(fit.status, FitStatus::Implausible(_))
        && !matches!(first.status, FitStatus::Implausible(_));
    // The ring refit of the fit on every point, against that fit's own profile: taken
    // when its fit converges.
    let ring_of_first = || {
        let first_profile = profile(pts, &first_axis.0, &first_axis.1, seg);
        ring_refit(pts, &first, &first_profile, method, options, seg)
            .filter(|(r, _)| r.fit.status.is_converged())
    };
    let mut early_ring = None;
    if partial_refit && let Some((r, ring)) = ring_of_first() {
        (fit, prof, cut) = (r.fit, r.profile, r.cut);
        rounds += r.rounds;
        early_ring = Some(ring);
    }
    let at_start = departs_at_start(&prof, seg);
    // A departure past the start before which no refit could be made (too little of the
    // wall in view before it: `refine` kept the fit on every point), found by a fit on
    // every point that misfits: the departure is the misfit's as much as the pipe's. On
    // the numpy caster's 42" elbows 1–3 m ahead (σ = 0.05 m, 320 × 240), 6 of 60 frames
    // read `tee_ahead` 0.6–0.9 m ahead, at the view's entry (the wall enters a 42" pipe's
    // view at about 0.8 m), where a fit dragged by the bend's far wall shifted 8 of 12
    // sectors' medians by 4 mm (F = 14.4 against 13.0). The near windows' fits, clear of
    // what lies ahead, are tried as for a refused refit, and a window is taken only if its
    // own fit does not misfit (one that does holds what lies ahead as well: a 42" tee
    // 0.5 m ahead, no wall in view before it, was answered 2.2 m ahead from such a window,
    // where the fit on every point had read 0.68 m).
    let departed = first_departure(&prof, seg).is_some();
    let unrefitted = cut.is_none() && !at_start && departed && misfits(&fit);
    let refused =
        (!departed && misfits(&fit)) || (partial_refit && early_ring.is_none()) || unrefitted;
    // A fit that finds no end and lacks fit: first, a straight pipe seen through a ring of
    // range error ([`ring_refit`], below), taken when its fit converges. Its refit without
    // the ring would show an end the misfit hid, so the near windows need not be tried: on
    // the Helios2 model's frames, whose misfit a ring of its range error makes, they were
    // two fits (≈ 70 ms) never taken.
    // The near window's reach (SCS x, m) when its fit, on its points alone, is the answer.
    let mut window = None;
    // Whether the ring was sought on the fit that is still the frame's (then it is not
    // sought again below).
    let mut ring_sought = refused && matches!(fit.status, FitStatus::LackOfFit(_));
    if ring_sought
        && early_ring.is_none()
        && let Some((r, ring)) = ring_refit(pts, &fit, &prof, method, options, seg)
            .filter(|(r, _)| r.fit.status.is_converged())
    {
        (fit, prof, cut) = (r.fit, r.profile, r.cut);
        rounds += r.rounds;
        early_ring = Some(ring);
    }
    if early_ring.is_none() && (refused || at_start) {
        // Taken when it finds a straight section: one that does not depart at its start
        // and finds the end, or, after a departure at the start, finds none while its own
        // fit holds (`misfits`: neither Welch's test nor the form test refuses it; before
        // it had to, the numpy multipath frame 147 of `test_straight_false_alarms.py` was
        // answered from a window reaching into the band, 29.4 mm off at 5.4σ̂). After a
        // fit on every point that found no end, a window must find one: a window that
        // finds none answers with a shorter view of the same pipe, and under a periodic
        // range error (tof-sim's wiggling, 6 mm) such answers were far off in 55 of 120
        // straight frames (`scenarios/straight_false_alarm.toml`, tried 2026-12-06), where
        // the fit on every point averages the error and carries it in its 1-σ. When a
        // wider window departed at its start too, a narrower one must find the end: two
        // fits that see the departure at the start outweigh a shorter one that sees none,
        // whose extrapolated fit may lack the power to (a Helios2-model frame at an elbow's
        // start plane read `straight` from its nearest 60 %, 0.49 m, after the nearest
        // 85 % departed at the start).
        let (restart, tried) = restart_from_near(pts, method, options, seg, |r, wider| {
            !departs_at_start(&r.profile, seg)
                && (first_departure(&r.profile, seg).is_some()
                    || (!misfits(&r.fit) && at_start && !wider))
                && !(unrefitted && misfits(&r.fit))
        });
        rounds += tried;
        if let Some((r, reach)) = restart {
            (fit, prof, cut) = (r.fit, r.profile, r.cut);
            window = reach;
            ring_sought = false;
        }
    }
    let x_first = prof.first().map_or(0.0, |s| s.start_m);
    // A departure at the start whose wall lies out all around is no bend the sensor is
    // in: a band of range error (multipath) holds the near view. The frame keeps its
    // straight verdict, and its fit its status.
    let (departure, straight_until) = first_departure(&prof, seg)
        .filter(|_| early_ring.is_none())
        .map(|i| (i, locate_end(&prof, i, seg)))
        .filter(|&(i, x)| x > x_first + seg.slice_m || !widens_all_around(&prof, i, seg))
        .unzip();
    let direction = departure.map(|i| departure_direction(&prof[i..], seg));
    let layout = match (departure, straight_until) {
        (None, _) | (_, None) => Layout::Straight,
        (Some(_), Some(x)) if x <= x_first + seg.slice_m => Layout::InBend,
        (Some(i), Some(_)) => classify(&prof[i..], seg),
    };
    // The sensor in a bend, against a straight pipe whose wall a ring of range error
    // holds ([`ring_refit`]): the second when its straight pipe holds without the ring.
    // A straight pipe whose fit the straight model refuses (lack of fit) although no end
    // was found, against the same pipe through a ring: the second when its fit holds
    // (converged). On the numpy multipath frames (320 × 240, `test_straight_false_alarms.py`'s
    // 200) this and the case below answer 52 frames more, ±1.96σ̂ covering Dmax and Dmin in
    // 0.954 and 0.985 of the 130, none beyond 5σ̂ (docs/bends-and-tees.md, "A ring of range
    // error").
    let ring = match layout {
        _ if early_ring.is_some() => None,
        Layout::InBend => ring_refit(pts, &fit, &prof, method, options, seg),
        Layout::Straight if matches!(fit.status, FitStatus::LackOfFit(_)) && !ring_sought => {
            ring_refit(pts, &fit, &prof, method, options, seg)
                .filter(|(r, _)| r.fit.status.is_converged())
        }
        // A refit the straight model's checks refuse as implausible (a partial view before
        // a band's edge taken for an end, a fit that left the model), after which the
        // departure vanished: the ring is sought on the fit on every point.
        Layout::Straight if matches!(fit.status, FitStatus::Implausible(_)) && !partial_refit => {
            ring_of_first()
        }
        _ => None,
    };
    let (ring, (departure, straight_until, direction, layout)) = match ring {
        Some((r, ring)) => {
            (fit, prof, cut) = (r.fit, r.profile, r.cut);
            rounds += r.rounds;
            (Some(ring), (None, None, None, Layout::Straight))
        }
        None => (early_ring, (departure, straight_until, direction, layout)),
    };
    // The straight estimate must come from the straight section's points alone. When
    // the last refit could not be cut at the end found (too few points before it, or
    // none within the range gate), try once more; failing that, the estimate is
    // withheld: the sensor is too close to the end to measure the straight pipe.
    let mut withheld = layout == Layout::InBend;
    // A departure by a bump (a branch opening) on a side of the wall that was not in
    // view just before it: the opening may begin where the view does not reach, and
    // the straight section's points may hold some of it.
    if let Some(i) = departure
        && !withheld
        && !prof[i].shifts(seg)
        && !prof[opening_slice(&prof, i)].bump_follows_wall
    {
        withheld = true;
    }
    if let (Some(x), false) = (straight_until, withheld)
        && !cut.is_some_and(|c| c <= x + 0.5 * seg.slice_m)
    {
        match refit_before(pts, &fit.params, x, false, method, options, seg) {
            Some(refit) => {
                fit = refit;
                rounds += 1;
            }
            None => withheld = true,
        }
    }
    // The fits ran on the clean points: the invalid ones count as dropped, as in
    // `estimate`.
    fit.n_dropped += cloud.dropped;
    let beyond = match straight_until {
        Some(x) => axial_sample(pts, &fit.params, |a| a >= x, BEND_POINTS),
        None => Vec::new(),
    };
    Ok(Segmentation {
        layout,
        straight_until: if layout == Layout::InBend {
            None
        } else {
            straight_until
        },
        straight: fit,
        straight_withheld: withheld,
        beyond,
        direction,
        ring,
        window_m: window.filter(|_| ring.is_none() && straight_until.is_none()),
        fitted_before_m: cut.filter(|_| ring.is_none() && straight_until.is_none()),
        profile: prof,
        rounds,
    })
}

/// Where a branch opening starts, from the first departing slice `i`: that slice's near
/// edge, or up to two slices earlier while the slice before shows a bump in the same
/// sector above [`EDGE_SIGMAS`] of its standard error (without the `min_shift_m` floor).
/// The opening's first centimetres depart weakly: near its edge the rays that cross it
/// run far up the branch, where the camera drops most of them as too faint.
fn opening_start(profile: &[Slice], i: usize) -> f64 {
    profile[opening_slice(profile, i)].start_m
}

/// The slice where a branch opening starts ([`opening_start`]).
fn opening_slice(profile: &[Slice], i: usize) -> usize {
    let psi = profile[i].side();
    let mut j = i;
    while j > 0 && i - j < 2 {
        let p = &profile[j - 1];
        let weak_bump = p.n_sectors >= MIN_SECTORS_TESTED
            && (p.bump_psi - psi).abs() < 1e-9
            && p.bump_m > EDGE_SIGMAS * p.bump_se_m;
        if !weak_bump {
            break;
        }
        j -= 1;
    }
    j
}

/// A slice before an opening's first departing slice belongs to the opening when its
/// bump, in the same sector, exceeds this many standard errors.
const EDGE_SIGMAS: f64 = 3.0;

/// The departure's direction (angle from the PCS +Y toward +Z, rad) from the first few
/// slices of the departing `run`: their shifts' sum over the slices that shift, else
/// the first bump's sector.
fn departure_direction(run: &[Slice], o: &SegmentOptions) -> f64 {
    let (sy, sz) = run
        .iter()
        .take(4)
        .filter(|s| s.shifts(o))
        .fold((0.0, 0.0), |(y, z), s| (y + s.shift_m[0], z + s.shift_m[1]));
    if sy != 0.0 || sz != 0.0 {
        return sz.atan2(sy);
    }
    run.iter()
        .find(|s| s.bumps(o) || s.opens())
        .map_or(0.0, |s| s.side())
}

/// The axial coordinate where the departure starts, from the first departing slice
/// `i`. A departure by a bump only (a branch opening, which starts abruptly) starts at
/// slice `i`'s near edge. Otherwise, the shift along the departure's direction u (that of the departing run) over
/// the run and three slices before it, fitted by c·(x − x₀)² for x > x₀ and 0 before
/// (the leading order of R − √(R² − (x − x₀)²), a bend's centreline leaving the axis);
/// x₀ on a grid of slice/20 steps from three slices before slice `i` to its far edge,
/// c ≥ 0 by weighted least squares for each x₀. A tee, whose shift jumps, gives the x₀
/// where the jump is best placed. A shift in the departing slice alone, the slices after
/// it judged and back on the pipe, locates no onset: the departure then starts as an
/// opening does ([`opening_start`]) when the slice bumps, else at its near edge.
fn locate_end(profile: &[Slice], i: usize, o: &SegmentOptions) -> f64 {
    locate_onset(profile, i, i.saturating_sub(3), o)
}

/// [`locate_end`] with the onset sought from slice `lo_i` on (the grid of x₀ and the
/// fitted slices start there).
fn locate_onset(profile: &[Slice], i: usize, lo_i: usize, o: &SegmentOptions) -> f64 {
    if !profile[i].shifts(o) {
        return opening_start(profile, i);
    }
    // The departing slice shifts alone: an opening's slice whose medians its far rays
    // pulled aside, not a centreline leaving the axis. One shifted slice fits the
    // parabola best from the grid's first x₀, three slices early, whatever the truth.
    // Alone means the next `persistence − 1` slices with points are judged (enough
    // sectors), do not shift, and shift less than slice `i` along its direction by more
    // than the critical value at the survey's false-alarm rate: a bend's shift grows
    // along the run, so a next slice merely below its own test (or not judged, or out
    // of view) keeps the onset fit.
    let shift_i = profile[i].shift_m;
    let norm_i = shift_i[0].hypot(shift_i[1]);
    let z = crate::fit::form::normal_upper_quantile(SURVEY_FALSE_ALARM);
    let next: Vec<&Slice> = profile[i + 1..]
        .iter()
        .filter(|s| s.n_points > 0)
        .take(o.persistence.saturating_sub(1).max(1))
        .collect();
    let lone = norm_i > 0.0
        && !next.is_empty()
        && next.iter().all(|s| {
            let along = (s.shift_m[0] * shift_i[0] + s.shift_m[1] * shift_i[1]) / norm_i;
            let se = profile[i].shift_se_m.hypot(s.shift_se_m);
            s.n_sectors >= MIN_SECTORS_TESTED
                && !s.shifts(o)
                && along.is_finite()
                && norm_i - along > z * se
        });
    if lone {
        return if profile[i].bumps(o) {
            opening_start(profile, i)
        } else {
            profile[i].start_m
        };
    }
    let hi_i = (i + 6).min(profile.len());
    let (uy, uz) = profile[i..hi_i]
        .iter()
        .filter(|s| s.shifts(o))
        .fold((0.0, 0.0), |(y, z), s| (y + s.shift_m[0], z + s.shift_m[1]));
    let norm = uy.hypot(uz);
    let (uy, uz) = if norm > 0.0 {
        (uy / norm, uz / norm)
    } else {
        (1.0, 0.0)
    };
    let pts: Vec<(f64, f64, f64)> = profile[lo_i..hi_i]
        .iter()
        .filter(|s| s.shift().is_finite() && s.shift_se_m > 0.0)
        .map(|s| {
            (
                s.start_m + 0.5 * o.slice_m,
                s.shift_m[0] * uy + s.shift_m[1] * uz,
                s.shift_se_m * s.shift_se_m,
            )
        })
        .collect();
    let edge = profile[i].start_m;
    let (x_lo, x_hi) = (profile[lo_i].start_m, edge + o.slice_m);
    let mut best = (f64::INFINITY, edge);
    let steps = 20 * (i - lo_i + 1);
    for k in 0..=steps {
        let x0 = x_lo + (x_hi - x_lo) * k as f64 / steps as f64;
        // For a given x₀, s ≈ (x − x₀)²/(2R) to leading order: linear in c = 1/(2R).
        let (mut num, mut den) = (0.0, 0.0);
        for &(x, s, v) in &pts {
            let q = (x - x0).max(0.0).powi(2);
            num += q * s / v;
            den += q * q / v;
        }
        let c = if den > 0.0 { (num / den).max(0.0) } else { 0.0 };
        let cost: f64 = pts
            .iter()
            .map(|&(x, s, v)| (s - c * (x - x0).max(0.0).powi(2)).powi(2) / v)
            .sum();
        if cost < best.0 {
            best = (cost, x0);
        }
    }
    best.1
}

/// Bend or tee, from the slices of the departing run that shift: a bend pulls the wall
/// opposite its shift inward (that sector's median goes below minus a third of the
/// shift) in most of them. A departure by bumps alone is a tee.
fn classify(run: &[Slice], o: &SegmentOptions) -> Layout {
    let departing: Vec<&Slice> = run.iter().take(8).filter(|s| s.shifts(o)).collect();
    let pulled = departing
        .iter()
        .filter(|s| s.opposite_m.is_finite() && s.opposite_m < -s.shift() / 3.0)
        .count();
    let judged = departing
        .iter()
        .filter(|s| s.opposite_m.is_finite())
        .count();
    if judged > 0 && 2 * pulled >= judged {
        Layout::BendAhead
    } else {
        Layout::TeeAhead
    }
}

/// The least inward mean deviation, as a fraction of the shift, of a slice that
/// departs inward. A slice's sector medians m_k are fitted by c₀ + c₁cos ψ + c₂sin ψ:
/// one sector of S (equal weights) deviating by h alone gives c₀ = h/S and a shift of
/// length 2|h|/S, so c₀/|shift| = +½ for a sector lying outside the wall (a branch
/// opening), −½ for one lying inside it (a dent, debris, an obstacle); a tube shifted
/// toward a bend's centre of curvature moves one side out and the opposite in, c₀ ≈ 0.
/// The boundaries lie halfway, at ±¼.
pub const INWARD_SHARE: f64 = 0.25;

/// Whether a departing `run` (starting at a departing slice) runs inward — most of its
/// first departing slices (by shift or bump; the first 8, as [`classify`] looks) have
/// c₀ < −[`INWARD_SHARE`]·|shift| — and if so the dent it shows, its clock angle taken
/// about the straight fit `beta`. A slice whose one sector lies far inside the wall also
/// departs by *bumps*: the harmonic fit, pulled toward that sector, leaves the sectors
/// beside it outside.
fn inward(run: &[Slice], beta: &Params, o: &SegmentOptions) -> Option<Dent> {
    let departing: Vec<&Slice> = run.iter().take(8).filter(|s| s.departs(o)).collect();
    let judged = departing
        .iter()
        .filter(|s| s.widening_m.is_finite() && s.shift().is_finite())
        .count();
    let inward = departing
        .iter()
        .filter(|s| s.widening_m < -INWARD_SHARE * s.shift())
        .count();
    if judged == 0 || 2 * inward <= judged {
        return None;
    }
    let deepest = run
        .iter()
        .take_while(|s| s.departs(o))
        .filter(|s| s.opposite_m.is_finite())
        .min_by(|a, b| a.opposite_m.total_cmp(&b.opposite_m))?;
    // The shift points away from an inward sector: the dent lies opposite it.
    let toward = deepest.direction() + std::f64::consts::PI;
    Some(Dent {
        from_m: run[0].start_m,
        at_m: deepest.start_m + 0.5 * o.slice_m,
        clock_deg: clock_angle_deg(beta, toward),
        depth_m: -deepest.opposite_m,
    })
}

/// The level at which a slice before an inward departure's first departing slice is
/// taken as part of it (`inward_start`): 1 % per slice. Each such slice is tested on
/// its own (the departure is already found at the survey's false-alarm rate), and a
/// false alarm only moves the straight section's end one slice nearer.
pub const DENT_EDGE_ALPHA: f64 = 0.01;

/// Where an inward departure starts, from its first departing slice `i`: back over the
/// slices before it while their shift points the same way (within 45°) and is
/// significant at [`DENT_EDGE_ALPHA`] on its own: F > −ln α, the upper α quantile of
/// F(2, ∞) = χ²₂/2 (whose tail is e^{−f}); F(2, ν)'s is larger for finite ν, so this
/// errs toward leaving a dent's gentle flank out of the straight section. A dent's
/// flank deepens gradually (tof-sim's is a Gaussian), and the slices where it is still
/// shallower than the departure test can see would bias the straight section.
fn inward_start(profile: &[Slice], i: usize) -> f64 {
    let critical = -DENT_EDGE_ALPHA.ln();
    let dir = profile[i].direction();
    let mut j = i;
    while j > 0 {
        let p = &profile[j - 1];
        let turn = (p.direction() - dir + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        if !(p.n_sectors >= MIN_SECTORS_TESTED
            && p.shift_f > critical
            && turn.abs() < std::f64::consts::FRAC_PI_4)
        {
            break;
        }
        j -= 1;
    }
    profile[j].start_m
}

/// A frame's geometry: its segmentation and, for a bend, the bend's fit.
#[derive(Clone, Debug)]
pub struct Survey {
    /// The straight section and what lies beyond. Its `layout` and `straight_until`
    /// are the survey's verdict (a departure whose torus fits is a bend, starting where
    /// the torus starts; one that does not is a tee).
    pub segmentation: Segmentation,
    /// The bend's fit, for [`Layout::BendAhead`].
    pub bend: Option<crate::bend::BendFit>,
    /// A local inward departure that the wall comes back from — a dent, debris or an
    /// obstacle on the wall (`inward`); the layout is then [`Layout::Straight`] and the
    /// straight section's estimate uses the points before it.
    pub dent: Option<Dent>,
    /// 1-σ (m) of `segmentation.straight_until`: for a bend, its start's from the bend's
    /// fit ([`crate::bend::BendFit::start_sigma`]); for a tee, the opening's change point's
    /// ([`crate::scene::edge::Edge::sigma_m`]); for a dent, whose start is the near edge
    /// of its first departing slice, the slice's width over √12 (a uniform position
    /// within it). `None` without an end, or when its fit leaves it undetermined.
    pub straight_until_sigma: Option<f64>,
    /// The evidence of a departure ([`departure_evidence`]): −log₁₀ of the profile's
    /// least adjusted p-value; a straight pipe's frame reaches −log₁₀
    /// [`SURVEY_FALSE_ALARM`] = 3 with probability at most [`SURVEY_FALSE_ALARM`].
    pub evidence: f64,
}

impl Survey {
    /// The survey of a segmentation with nothing found beyond its verdict.
    fn plain(segmentation: Segmentation) -> Self {
        Self {
            evidence: departure_evidence(&segmentation.profile),
            segmentation,
            bend: None,
            dent: None,
            straight_until_sigma: None,
        }
    }
}

/// A local inward departure of the wall from the straight pipe, which the wall comes
/// back from within the view: a dent, debris or an obstacle lying on the wall.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dent {
    /// Where it starts: the near edge of its first departing slice (PCS x, m); the
    /// straight section's estimate uses the points before it.
    pub from_m: f64,
    /// Where it is deepest: the centre of the slice whose sector opposite the shift
    /// lies furthest inside the wall (PCS x, m).
    pub at_m: f64,
    /// Its clock angle as the sensor sees it ([`clock_angle_deg`]; deg, 0 up, 90 right).
    pub clock_deg: f64,
    /// Its depth: the largest inward median deviation of one sector (m). A sector is
    /// 360°/`sectors` wide, so a dent narrower than a sector reads shallower than it is.
    pub depth_m: f64,
}

/// The straight section refitted on the points before the bend's fitted start less
/// one slice ([`SegmentOptions::slice_m`]) and [`SegmentOptions::margin_m`], and the bend
/// refitted from `first` to the straight fit so made and the points past that cut; taken
/// (the refit replacing `s.straight`, its points past the cut `s.beyond`) when the bend
/// still fits, its start is not later than the first's beyond what the first's 1-σ
/// allows, and the refit's outcome is `converged` or the same as before.
///
/// Why: the first straight fit takes the points before the first departing slice, and a
/// bend leaves the straight pipe tangentially (its wall a distance s past the start lies
/// about s²/2R off the cylinder), so the departure is seen some centimetres after the
/// bend begins and the straight fit holds the bend's first centimetres: its axis leans
/// toward the bend, and the bend fitted to that axis starts late. Where little straight
/// pipe is in view the lean is large: on the numpy casters' bends
/// (`scripts/approach-grid-numpy.py`) the start read +31 … +50 mm late on the 42" 45°
/// bend 1 m ahead (its ±1.96σ covering 1 of 5) and +8 … +46 mm on the 20" 45° bend
/// 0.5 m ahead. The fitted start is within a slice of the truth there (the survey
/// resolves a departure to a slice), so a cut one slice before it leaves the bend out;
/// with it those starts read −3 … +3 mm and −5 … +24 mm. One round: a second moved no
/// start by more than a few millimetres on those frames.
fn reseat_before_bend(
    s: &mut Segmentation,
    first: crate::bend::BendFit,
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
    fits: impl Fn(&crate::bend::BendFit) -> bool,
) -> crate::bend::BendFit {
    let cut = first.geometry.start - seg.slice_m;
    let Some(refit) = refit_before(points, &s.straight.params, cut, false, method, options, seg)
    else {
        return first;
    };
    let outcome = refit.status.outcome();
    if outcome != FitOutcome::Converged && outcome != s.straight.status.outcome() {
        return first;
    }
    let beyond = axial_sample(points, &refit.params, |a| a >= cut, BEND_POINTS);
    // The refit removes a lean that puts the start late: a refitted start later than the
    // first's by more than z of the first's 1-σ (z at the survey's false-alarm rate,
    // one-sided: 3.09) is another minimum, not that correction (numpy 20" 45° bend 3 m
    // ahead: a start 2.998 m ± 3 mm, R 727 mm, refitted to 3.104 m, R 293 mm).
    let z = crate::fit::form::normal_upper_quantile(SURVEY_FALSE_ALARM);
    let not_later =
        |b: &crate::bend::BendFit| b.geometry.start <= first.geometry.start + z * first.start_sigma;
    match crate::bend::fit_bend(
        &beyond,
        &refit.params,
        refit.axis_cov.as_ref(),
        &first.geometry,
    ) {
        Ok(b) if fits(&b) && not_later(&b) => {
            s.straight = refit;
            s.beyond = beyond;
            b
        }
        _ => first,
    }
}

/// [`segment`], then a torus fitted to what lies beyond a departure
/// ([`crate::bend::fit_bend`], started at the departure with a long-radius bend,
/// R = 1.5·D): when it converges with residuals within twice the straight section's
/// — or within half the residuals of the straight wall continued over the same points
/// (with range-dependent noise the bend, farther away, is noisier than the straight
/// section; a tee's main run goes on, so there the straight wall fits about as well as
/// any torus) — and a bend radius above the tube's, the departure is a bend and the
/// straight section ends where the torus starts; otherwise it is a tee (a branch
/// opening: the main pipe goes on).
pub fn survey(
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Result<Survey, EpdError> {
    let mut s = segment(points, method, options, seg)?;
    // The fits after the first are of parts of the frame (see [`segment`]).
    let options = &options.without_start();
    let (Some(end), Some(dir), Layout::BendAhead | Layout::TeeAhead) =
        (s.straight_until, s.direction, s.layout)
    else {
        if s.layout == Layout::Straight && !s.straight_withheld {
            return Ok(bend_across_view(s, points, method, options, seg));
        }
        return Ok(Survey::plain(s));
    };
    // An opening is at most the branch's diameter long, and a branch is no wider than
    // the main pipe: the wall must be back within a diameter and the resuming slices.
    let straight = s.straight.params;
    let within = straight.d_max + RESUMED_SLICES as f64 * seg.slice_m;
    if let Some(i) = first_departure(&s.profile, seg)
        && resumes(&s.profile[i..], seg, within)
    {
        // The wall comes back onto the straight pipe beyond the departure: the main run
        // goes on past an opening — or past a dent, debris or an obstacle when the
        // departure runs inward.
        return Ok(obstruction_or_tee(s, i, points, method, options, seg));
    }
    let beta = s.straight.params;
    let d_mean = 0.5 * (beta.d_max + beta.d_min);
    let straight_sigma = s.straight.rms_residual;
    let fits = |b: &crate::bend::BendFit| {
        is_bend_shaped(b, d_mean)
            && (b.residual_sigma <= 2.0 * straight_sigma.max(1e-4)
                || b.residual_sigma <= 0.5 * b.straight_sigma)
    };
    // The torus is started toward the departure's side and, when that side is a sparse
    // opening's, from the three other quarters too ([`BEND_START_TURNS`]); the best
    // fitting start that fits is taken ([`crate::bend::fit_best_bend`]).
    let sparse_side =
        first_departure(&s.profile, seg).is_some_and(|i| s.profile[i].side_is_opening());
    let turns = if sparse_side {
        &BEND_START_TURNS[..]
    } else {
        &BEND_START_TURNS[..1]
    };
    let starts: Vec<_> = turns
        .iter()
        .map(|turn| crate::bend::start_from(&beta, end, dir + turn, 1.5 * d_mean))
        .collect();
    let axis = s.straight.axis_cov;
    let accepted = crate::bend::fit_best_bend(&s.beyond, &beta, axis.as_ref(), &starts, fits)
        .map(|b| reseat_before_bend(&mut s, b, points, method, options, seg, fits));
    match accepted {
        Some(b) => {
            s.layout = Layout::BendAhead;
            s.straight_until = Some(b.geometry.start);
            s.direction = Some(b.geometry.direction);
        }
        None => {
            // No torus fits: an opening (a tee), or something lying inside the pipe
            // that hides the wall beyond it when the departure runs inward.
            let i = first_departure(&s.profile, seg).unwrap_or(0);
            return Ok(obstruction_or_tee(s, i, points, method, options, seg));
        }
    }
    Ok(Survey {
        straight_until_sigma: accepted.map(|b| b.start_sigma).filter(|v| v.is_finite()),
        bend: accepted,
        ..Survey::plain(s)
    })
}

/// A frame the profile reads `straight`: a bend far ahead where its outer wall blocks the
/// view down the pipe ([`crate::scene::blocked`]), when the returns short of the straight
/// wall are in excess and a torus started at them fits as a bend at residuals within
/// twice the straight fit's robust scale (the straight fit's RMS residual, which those
/// returns swell, is not the noise's). Then the straight section is refitted on the
/// points before the torus's start, kept unless its checks refuse it.
fn bend_across_view(
    mut s: Segmentation,
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Survey {
    // The reach of the profile: the far edge of its last slice with medians to test.
    let Some(reach) = s
        .profile
        .iter()
        .rev()
        .find(|sl| sl.n_sectors >= MIN_SECTORS_TESTED)
        .map(|sl| sl.start_m + seg.slice_m)
    else {
        return Survey::plain(s);
    };
    let Some(short) = crate::scene::blocked::short_returns(points, &s.straight, reach) else {
        return Survey::plain(s);
    };
    let beta = s.straight.params;
    let d_mean = 0.5 * (beta.d_max + beta.d_min);
    let Some(noise) = s
        .straight
        .diagnostics
        .as_ref()
        .map(|d| d.residual_scale)
        .filter(|v| *v > 0.0)
    else {
        return Survey::plain(s);
    };
    let beyond = axial_sample(points, &beta, |x| x >= short.near_m - d_mean, BEND_POINTS);
    // The outer wall's nearest returns lie on the side away from the centre of
    // curvature.
    let side = short.side + std::f64::consts::PI;
    let starts: Vec<_> = BEND_START_TURNS
        .iter()
        .map(|turn| crate::bend::start_from(&beta, short.near_m, side + turn, 1.5 * d_mean))
        .collect();
    let axis = s.straight.axis_cov;
    let accepted = crate::bend::fit_best_bend(&beyond, &beta, axis.as_ref(), &starts, |b| {
        is_bend_shaped(b, d_mean) && b.residual_sigma <= 2.0 * noise
    });
    let Some(b) = accepted else {
        return Survey::plain(s);
    };
    if let Some(refit) = refit_before(points, &beta, b.geometry.start, false, method, options, seg)
        .filter(|e| !matches!(e.status, FitStatus::Implausible(_)))
    {
        s.straight = refit;
        s.rounds += 1;
    }
    s.layout = Layout::BendAhead;
    s.straight_until = Some(b.geometry.start);
    s.direction = Some(b.geometry.direction);
    s.beyond = beyond;
    Survey {
        straight_until_sigma: Some(b.start_sigma).filter(|v| v.is_finite()),
        bend: Some(b),
        ..Survey::plain(s)
    }
}

/// Whether a torus fit is shaped as a bend of a pipe of mean diameter `d_mean` (m), as
/// both of the survey's bend acceptances ask before their residual rules: converged, a
/// ring torus (R above 1.05 tube radii), R below 100·D, and some angle of it seen.
fn is_bend_shaped(b: &crate::bend::BendFit, d_mean: f64) -> bool {
    b.status.is_converged()
        && b.geometry.radius > 1.05 * b.geometry.tube_radius
        && b.geometry.radius < 100.0 * d_mean
        && b.angle_seen > 0.0
}

/// The turns (rad) from the departure's side at which the bend's torus is started: the
/// side alone when it is a shift's, all four when it is a sparse opening's. Far
/// ahead a coarse camera's departure is an opening of sparse cells, whose side is that
/// of a few exceeding points and can be the bend's far side: a numpy elbow 3 m ahead at
/// 160 × 120 departed at 285° for a bend toward 90°, the torus started there settled on
/// a radius of the tube's, and the frame read `tee_ahead` (`test_independent_bends.py`).
/// A tee has no torus to fit from any side; the acceptance is the same for each start.
/// Of the starts that fit, the best fitting is taken ([`crate::bend::fit_best_bend`]),
/// not the first: the same numpy elbow frame's departure side, 270° for a bend toward 90°, gave
/// a torus that its acceptance's second rule (residuals within half the straight wall's
/// continued) let through at 12× the noise, R = 231 mm (0.91·D) and its start 0.28 m
/// late, where the start from the opposite side fits at the noise.
/// A shift's side is the fitted direction of a slice's medians and is not doubted: with
/// the other starts tried for every departure, two straight numpy frames under a
/// multipath band read `bend_ahead` (`test_straight_false_alarms.py`, 320 × 240).
const BEND_START_TURNS: [f64; 4] = [
    0.0,
    std::f64::consts::PI,
    std::f64::consts::FRAC_PI_2,
    -std::f64::consts::FRAC_PI_2,
];

/// The survey's verdict for a departure at slice `i` that is not a bend: a dent, debris
/// or an obstacle on the wall when it runs inward ([`inward`]) — the layout stays
/// [`Layout::Straight`], the straight section ends where the dent's flank begins
/// ([`inward_start`]) and is refitted on the points before it — otherwise a tee.
fn obstruction_or_tee(
    mut s: Segmentation,
    i: usize,
    points: &[[f64; 3]],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Survey {
    let straight = s.straight.params;
    let Some(mut dent) = s
        .profile
        .get(i..)
        .and_then(|run| inward(run, &straight, seg))
    else {
        return tee(s, points, seg);
    };
    // A dent's flank has no known length: its onset is sought over every slice before
    // the departure, and the earlier of that and the slices significant on their own
    // ([`inward_start`]) ends the straight section. Sought over the three slices before
    // it, as for a bend, the flank beyond them biased Dmin by about its 1-σ: Dmin's
    // ±1.96σ covered 0.75 ± 0.07 of 40 dented frames, now 0.95 ± 0.03 (`cargo run
    // --release -p epd-frame --example coverage -- 40 dent_25mm`).
    dent.from_m = inward_start(&s.profile, i).min(locate_onset(&s.profile, i, 0, seg));
    if s.straight_until.is_some_and(|end| dent.from_m < end)
        && let Some(fit) = refit_before(
            &clean(points).points,
            &straight,
            dent.from_m,
            false,
            method,
            options,
            seg,
        )
    {
        s.straight = fit;
    }
    s.layout = Layout::Straight;
    s.straight_until = Some(dent.from_m);
    Survey {
        dent: Some(dent),
        straight_until_sigma: Some(seg.slice_m / 12f64.sqrt()),
        ..Survey::plain(s)
    }
}

/// The share of the clock sectors on the far side from an opening
/// ([`crate::scene::edge::Edge::far_open_share`]) above which a departure is a ring, not a
/// branch ([`tee`]): a branch no wider than the main pipe opens none of them (each opens
/// by the sector test's false alarm alone, 5 %), while a multipath band opens nearly all.
/// The share over all sectors was used before: at 3 m a numpy tee's opening was the only
/// sector with enough wall to be tested, its share 1 of 1, and the frame read `straight`
/// (`test_independent_tees.py`, full frames).
const RING_SHARE: f64 = 0.5;

/// The survey's verdict for a tee. A branch opening starts abruptly, not where a
/// bend's growth would start: at the change point of the exceedances on its side
/// ([`crate::scene::edge::opening_edge`], within ± one sector of the bump's and two
/// slices of the near edge of its first slice, [`opening_start`], the wall taken in the
/// two slices before that edge, or failing that the two before them); failing that, at
/// that near edge, within a slice. When more than [`RING_SHARE`] of the sectors on the far
/// side from the opening open there too ([`crate::scene::edge::open_share`]) it is no
/// branch but a band of range error all around — multipath over a band of ranges, as a camera in a pipe sees — and the frame
/// reads [`Layout::Straight`], its straight section ending where the band begins.
fn tee(mut s: Segmentation, points: &[[f64; 3]], seg: &SegmentOptions) -> Survey {
    s.layout = Layout::TeeAhead;
    let mut sigma = None;
    if let Some(i) = first_departure(&s.profile, seg) {
        let j = opening_slice(&s.profile, i);
        let near = s.profile[j].start_m;
        let sector = std::f64::consts::TAU / seg.sectors as f64;
        let cleaned = clean(points).points;
        let edge_before = |wall_until: f64| {
            crate::scene::edge::opening_edge(
                &cleaned,
                &s.straight.params,
                s.profile[i].side(),
                sector,
                (
                    wall_until - 2.0 * seg.slice_m,
                    wall_until,
                    near + 2.0 * seg.slice_m,
                ),
            )
        };
        // The wall is taken before the opening's first slice; when the opening began
        // earlier than that slice says (a refit that moved the slices, a weak first
        // centimetre: [`opening_slice`] looks back two slices), the wall's window holds
        // it and its spread hides the step: then the two slices before.
        let edge = edge_before(near).or_else(|| edge_before(near - 2.0 * seg.slice_m));
        if edge.is_some_and(|e| e.far_open_share > RING_SHARE)
            || widens_all_around(&s.profile, i, seg)
        {
            s.layout = Layout::Straight;
        }
        let (at, sd) = edge.map_or((near, seg.slice_m / 12f64.sqrt()), |e| (e.at_m, e.sigma_m));
        s.straight_until = Some(at);
        sigma = Some(sd);
    }
    Survey {
        straight_until_sigma: sigma,
        ..Survey::plain(s)
    }
}

/// The slices (indices into `prof`, first and one past the last) of the longest run of
/// a ring of range error: consecutive slices tested all around ([`MIN_SECTORS_TESTED`]
/// sectors or more) whose every half of the wall lies outside the fitted wall
/// ([`Slice::least_half_m`] above the one-sided normal critical value at
/// [`SURVEY_FALSE_ALARM`] of its standard error) by at least [`RING_WIDENING_SHARE`] of the
/// slice's size (the larger of its shift and bump, as [`widens_all_around`] asks of a
/// run), at least `persistence` of them: what a multipath band of ranges makes and no
/// bend or branch opening does (each moves at most half the wall outward; a numpy tee 0.5
/// m ahead in a 42" pipe, its opening filling a partial view of 5–8 sectors, had least
/// halves 9–37 mm out beside shifts of 130–220 mm); grown on each side by the departing
/// slices next to it, where the band's edge crosses the sectors one by one (the camera
/// off the pipe's axis sees one range at different axial positions around the wall) and
/// the fit, pulled by the band, departs beside it.
fn ring_run(prof: &[Slice], seg: &SegmentOptions) -> Option<(usize, usize)> {
    let z = crate::fit::form::normal_upper_quantile(SURVEY_FALSE_ALARM);
    let out = |s: &Slice| {
        s.n_sectors >= MIN_SECTORS_TESTED
            && s.least_half_m > z * s.least_half_var_m2.sqrt()
            && s.least_half_m >= RING_WIDENING_SHARE * s.shift().max(s.bump_m)
    };
    let mut best: Option<(usize, usize)> = None;
    let mut k = 0;
    while k < prof.len() {
        if !out(&prof[k]) {
            k += 1;
            continue;
        }
        let start = k;
        while k < prof.len() && out(&prof[k]) {
            k += 1;
        }
        if best.is_none_or(|(a, b)| k - start > b - a) {
            best = Some((start, k));
        }
    }
    let (mut a, mut b) = best.filter(|&(a, b)| b - a >= seg.persistence)?;
    while a > 0 && prof[a - 1].departs(seg) {
        a -= 1;
    }
    while b < prof.len() && prof[b].departs(seg) {
        b += 1;
    }
    Some((a, b))
}

/// A straight pipe seen through a ring of range error, in place of a sensor in a bend:
/// the straight pipe refitted on the points outside the ring ([`ring_run`] of the
/// profile `prof` of `fit`, with a slice's margin on each side), taken when its fit is
/// not refused as implausible, the profile of its own points departs nowhere
/// ([`first_departure`], at the survey's false-alarm rate), and at least `persistence`
/// slices tested lie beyond the ring: the wall comes back onto the same straight pipe
/// after it, as it never does past a bend's start. A multipath band over the ranges
/// where a 42" pipe's wall fills most of the view pulls the fit on every point off the
/// pipe, and its near slices then depart at the start: 8 of the 120 straight 42" frames
/// under tof-sim's band (1–2 m, +5 cm) read `in_bend` (`scenarios/straight_false_alarm.toml`).
/// `None` when there is no ring or its refit does not hold; else the refit (its profile
/// over every point) and the ring.
fn ring_refit(
    pts: &[[f64; 3]],
    fit: &Estimate,
    prof: &[Slice],
    method: Method,
    options: &EstimateOptions,
    seg: &SegmentOptions,
) -> Option<(Refined, Ring)> {
    let (a, b) = ring_run(prof, seg)?;
    let from = prof[a].start_m - seg.slice_m;
    let to = prof.get(b).map_or(f64::INFINITY, |s| s.start_m) + seg.slice_m;
    let kept = axial_mask(pts, &fit.params, |x| x < from || x >= to);
    if kept.count() < RESTART_MIN_POINTS {
        return None;
    }
    let refit = estimate_masked(pts, &kept, method, options).ok()?;
    if matches!(refit.status, FitStatus::Implausible(_)) {
        return None;
    }
    let axis = AxisSigma::of(&refit);
    let own = profile_of(Points::masked(pts, &kept)?, &refit.params, &axis, seg);
    let beyond = own
        .iter()
        .filter(|s| s.start_m >= to && s.n_sectors >= MIN_SECTORS_TESTED)
        .count();
    if first_departure(&own, seg).is_some() || beyond < seg.persistence {
        return None;
    }
    let all = profile(pts, &refit.params, &axis, seg);
    let within: Vec<f64> = all
        .iter()
        .filter(|s| s.start_m >= prof[a].start_m && s.start_m < to - seg.slice_m)
        .map(|s| s.widening_m)
        .filter(|w| w.is_finite())
        .collect();
    let ring = Ring {
        from_m: prof[a].start_m,
        to_m: to - seg.slice_m,
        widening_m: within.iter().sum::<f64>() / within.len().max(1) as f64,
    };
    let refined = Refined {
        profile: all,
        fit: refit,
        rounds: 1,
        cut: None,
    };
    Some((refined, ring))
}

/// Whether the departing run from slice `i` reads wider all around, as no branch
/// opening or bend makes it ([`Slice::least_half_m`]): over its first 8 departing slices
/// (as [`classify`] looks), the sum of their least halves exceeds the one-sided normal
/// critical value at [`SURVEY_FALSE_ALARM`] of its standard error, and
/// [`RING_WIDENING_SHARE`] of the run's size. Under an opening or a bend each least half
/// has a mean ≤ 0 (it lies on the wall or in, and as a minimum over rotations errs low),
/// so a tee or a bend is taken for a ring with probability below the survey's
/// false-alarm rate. The least halves are taken from the wall the straight fit gives, not
/// from the slices before the departure: at an elbow's start plane (tof-sim's Helios2
/// model, `cargo test -p bench-harness --test pipeline`) a near window's slices before its
/// departure lay 18 mm in, and measured from them the bend's slices read a ring. Medians see what the exceedances of
/// [`crate::scene::edge::open_share`] miss: a multipath band that reads 2.5σ long moves a
/// point by a fraction of σ across the wall, yet 12 sector medians of hundreds of points
/// each by many of their standard errors (numpy frames of a 30" pipe at 320 × 240,
/// `test_straight_false_alarms.py`: the band's slices ≈ 15 mm out all around, ≈ 0.25 mm
/// standard error). Only slices with medians in [`MIN_SECTORS_TESTED`] sectors count, as
/// in [`ring_run`]: with fewer, every half may hold only the sectors that have medians —
/// in a sparse slice those the opening fills, its rays run on to the branch's far wall
/// (an off-grid numpy 16" tee 1.74 m ahead, σ = 10 mm: its one departing slice had
/// medians in 4 sectors, its least half 8.2 mm out, and the frame read `straight`).
fn widens_all_around(profile: &[Slice], i: usize, o: &SegmentOptions) -> bool {
    let i = i.min(profile.len());
    // (least half, its variance, the slice's size: the larger of shift and bump).
    let run: Vec<(f64, f64, f64)> = profile[i..]
        .iter()
        .take(8)
        .filter(|s| s.departs(o) && s.n_sectors >= MIN_SECTORS_TESTED)
        .map(|s| (s.least_half_m, s.least_half_var_m2, s.shift().max(s.bump_m)))
        .filter(|(h, v, _)| h.is_finite() && v.is_finite())
        .collect();
    if run.is_empty() {
        return false;
    }
    let excess: f64 = run.iter().map(|r| r.0).sum();
    let var: f64 = run.iter().map(|r| r.1).sum();
    let size: f64 = run.iter().map(|r| r.2).sum();
    excess > crate::fit::form::normal_upper_quantile(SURVEY_FALSE_ALARM) * var.sqrt()
        && excess >= RING_WIDENING_SHARE * size
}

/// The least share of a departing run's size (the sum over its slices of the larger of
/// the shift and the bump) that its wall's least half must lie out for
/// [`widens_all_around`]. An opening's or a bend's least half stays on the wall or goes
/// in, whatever the departure's size (share ≤ 0, up to the model's misfit); a ring of
/// range error, past the edge where it crosses the sectors one by one, lies out all
/// around by more than its slices shift (share ≥ 1: multipath numpy frames of a 30" pipe,
/// 0.95–30 over their runs, `test_straight_false_alarms.py`). The boundary lies halfway.
/// Without it tof-sim's 20" tee 0.5 m ahead under the Helios2 model's noise read as a
/// ring: its slices' least half 0.1–0.2 mm out at 7 standard errors (a misfit of
/// the straight model far below the camera's noise), beside bumps of 15–120 mm (`a_close_tee_under_the_cameras_noise_is_found_or_withheld`,
/// crates/epd-frame/tests/segmentation.rs).
const RING_WIDENING_SHARE: f64 = 0.5;

/// Slices back on the straight pipe, in a row, that show the wall resumes after a
/// departure.
const RESUMED_SLICES: usize = 4;

/// Whether the wall comes back onto the straight pipe after the departing `run`
/// (which starts at a departing slice) within `within_m` of its start:
/// [`RESUMED_SLICES`] consecutive slices, each with enough sectors for a fit, that
/// neither depart nor widen (|c₀| within `2·min_shift_m` or `threshold_sigmas` of the
/// shift's standard error). A bend never resumes (its tube moves ever further off the
/// straight axis; far past its start, where the tube has turned away, the points lie
/// well inside the straight wall); a tee's main run does, past an opening no longer
/// than the branch's diameter.
fn resumes(run: &[Slice], o: &SegmentOptions, within_m: f64) -> bool {
    let Some(x0) = run.first().map(|s| s.start_m) else {
        return false;
    };
    let mut in_row = 0;
    for s in run.iter().skip_while(|s| s.departs(o)) {
        if s.start_m > x0 + within_m {
            break;
        }
        let on_wall =
            s.widening_m.abs() <= (2.0 * o.min_shift_m).max(o.threshold_sigmas * s.shift_se_m);
        if s.departs(o) || s.n_sectors < MIN_SECTORS_TESTED || !s.shift().is_finite() || !on_wall {
            in_row = 0;
            continue;
        }
        in_row += 1;
        if in_row >= RESUMED_SLICES {
            return true;
        }
    }
    false
}

/// The clock angle (deg, [0, 360)) of a direction of the straight fit's cross-section
/// (angle φ from the PCS +Y toward +Z) as the sensor sees it: the direction taken to
/// the SCS and read about the sensor's forward axis, 0° up (+Z), 90° right (+Y),
/// 180° down, 270° left. Unlike φ, it does not depend on which member of the fit's
/// symmetry class (a 180° turn about the axis) was reported.
pub fn clock_angle_deg(beta: &Params, direction: f64) -> f64 {
    let u = beta.dir_pcs_to_scs(&Vector3::new(0.0, direction.cos(), direction.sin()));
    u.y.atan2(u.z).to_degrees().rem_euclid(360.0)
}

#[cfg(test)]
mod tests;
