//! The depth table's part of a measurement: a version-2 (incidence) table's rounds of
//! fit → incidence → correction, the scene surveyed on the plain table's points, the
//! frames left uncorrected for lying outside the table's support, and what the table leaves to
//! the 1-σ (its bins' standard errors, shared by the points each corrected, and the
//! transfer from the rigs' sizes to the pipe's).

use epd_core::fit_pose;

use crate::config::EstimateConfig;
use crate::scene::FrameScene;
use crate::table::CalibrationTable;

/// A frame more than this fraction of whose points lie outside the depth table's support
/// is not corrected: 90 %. A fit of the corrected points would rest on under a tenth of
/// the wall the camera saw — on the Helios2 model a band of ranges near the rig's, where
/// the diameters and the sensor's offset are not told apart: of eight such frames (a 20"
/// table, 30" frames, 93–100 % outside) seven ended `implausible` and the eighth 19.6 mm
/// off. The frame is fitted on its raw points instead, with the camera's unknown error
/// in its 1-σ ([`UncorrectedFrame`]).
pub const REFUSE_OUTSIDE: f64 = 0.9;

/// A frame too far outside the depth table's support to be corrected
/// ([`REFUSE_OUTSIDE`]): it is fitted on its raw points, and the camera's error, which
/// the table measured only where its rigs looked, enters the 1-σ as one error shared by
/// every point, of standard deviation the largest offset the rigs showed, max |offset|
/// over the table's observed bins (`largest_offset_m`).
///
/// The assumption, stated: the camera's error where the rigs did not look is no larger
/// than anywhere they did. Under it the error's effect on the diameters is at most that
/// of a shift of every range by the largest offset, so the 1-σ itself covers the error
/// (the goal asks the reported 1-σ to cover it), not only the ±1.96σ interval.
/// A shared error, not an independent one per point, because the error of one camera at
/// one set of conditions is the same for every point there (the depth table's premise).
/// The root mean square of the offsets instead (a 1-σ of one draw of the errors the rigs
/// showed) covered none of the 25 uncorrected one-size 28" and 30" frames within 1σ
/// (`scenarios/calibration_transfer.toml`: raw errors +20 mm, 1-σ 16–22 mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UncorrectedFrame {
    /// Of the valid points with an intensity, the fraction outside the support.
    pub outside_fraction: f64,
    /// The largest |offset| over the table's observed bins (m), the shared error's
    /// standard deviation.
    pub shared_error_m: f64,
}

/// The largest |offset| over a table's observed bins (m; bins with points, not those
/// bridged between rigs, whose offsets lie within their row's observed range):
/// [`UncorrectedFrame`]. 0 for a table with no observed bin.
pub fn largest_offset_m(table: &epd_core::calibration::IncidenceTable) -> f64 {
    table
        .offset_m
        .iter()
        .zip(&table.count)
        .filter(|(o, c)| o.is_finite() && **c > 0)
        .fold(0.0f64, |m, (o, _)| m.max(o.abs()))
}

/// Rounds of fit → incidence → correction → refit at most: the incidence comes from the
/// fitted wall, which moves with the correction. The mean diameter settles within
/// [`INCIDENCE_TOLERANCE_M`] in two rounds on the Helios2 model (a 1 mm change of the
/// diameter changes cos θ by 0.2 % at a 0.5 m pipe, and the correction by far less
/// than a micrometre), so three leave a margin.
pub const INCIDENCE_ROUNDS: usize = 3;

/// The convergence criterion of the rounds: the mean diameter moved by less than 10 µm
/// (a hundredth of the 1 mm resolution the report gives the diameters to).
pub const INCIDENCE_TOLERANCE_M: f64 = 1e-5;

/// A frame more than this fraction of whose points lie outside the depth table's
/// support is said to be (in `status_reason`): the majority of its wall, one half, was
/// left out of the fit (points outside the support are not corrected and not fitted),
/// so its diameters rest on less than half of what the camera saw.
pub const MOSTLY_OUTSIDE: f64 = 0.5;

/// A point's shared range error: its bin and the bin mean's standard error (m).
pub(super) type Shift = Option<(u32, f64)>;

/// The shared range errors of a frame's points.
#[derive(Clone, Debug)]
pub(super) enum Shares {
    /// One bin per point (the incidence table: the bin holding the point).
    Home(Vec<Shift>),
    /// The 4 bins a version-1 table's bilinear interpolation read, each with its weight
    /// × its standard error (`epd_core::DepthTable::shared_error_terms`).
    Interpolated(Vec<[(u32, f64); 4]>),
}

/// What the incidence table's correction leaves to the 1-σ: per point the bin whose
/// mean corrected it (its standard error shared by every point of the bin).
#[derive(Clone, Debug)]
pub(super) struct SharedErrors {
    /// Per point: the bins whose errors it shares, with their standard errors (m).
    pub(super) shift: Shares,
    /// Groups: the table's bins.
    pub(super) n_groups: usize,
    /// Of the valid points with an intensity, the fraction outside the support.
    pub(super) outside_fraction: f64,
    /// The table's spread at each corrected point (m), for a weighted fit.
    pub(super) sigma_m: Vec<f64>,
    /// The (Dmax, Dmin) of the fit on the raw points (m): the correction's whole effect
    /// on the diameters is the corrected fit's minus these (the incidence table's
    /// rounds fit them; `None` for a version-1 table, which is not checked against the
    /// rig's size).
    pub(super) raw_diameters: Option<(f64, f64)>,
}

/// What a depth table made of a frame before its straight fit ([`calibrate`]).
pub(super) struct Calibrated {
    /// Points the table moved.
    pub(super) n_calibrated: usize,
    /// Of the valid points with an intensity, the fraction outside the table's support.
    pub(super) outside: Option<f64>,
    /// Each point's σ from the table's spread (m), for a weighted fit.
    pub(super) sigma: Option<Vec<f64>>,
    /// The scene ahead, when surveyed (`cfg.geometry`).
    pub(super) scene: Option<FrameScene>,
    /// Whether the scene was surveyed on the points fitted (a version-1 table's), not
    /// on other points (a version-2 table's: [`incidence_frame`]).
    pub(super) surveyed_here: bool,
    /// What the table leaves to the 1-σ.
    pub(super) shared: Option<SharedErrors>,
    /// The frame lay too far outside the table's support to be corrected.
    pub(super) uncorrected: Option<UncorrectedFrame>,
}

/// The depth table's part of `epd estimate --calibration` on a frame: `points` corrected
/// in place, with `raw_range_m` their measured ranges before the correction (for the
/// scene's lookups) and `sigma_given` whether the caller gave per-point σ. A version-2
/// table: the scene surveyed on the plain table's points, then its straight section
/// corrected by the incidence rounds ([`incidence_frame`]). A
/// version-1 table: every point corrected, then the scene surveyed on them. `n_read`
/// completes the messages.
pub(super) fn calibrate(
    cal: &CalibrationTable,
    points: &mut Vec<[f64; 3]>,
    intensity: Option<&[f64]>,
    sigma_given: bool,
    raw_range_m: Option<&[f64]>,
    cfg: &EstimateConfig,
    n_read: usize,
) -> Result<Calibrated, String> {
    if let (Some(inc), Some(i)) = (&cal.incidence, intensity) {
        if cfg.weighted && sigma_given {
            return Err(
                "per-point σ given with a weighting depth table: give one or the other \
                        (or the table unweighted)"
                    .into(),
            );
        }
        let (scene, rounds) = if cfg.geometry {
            let raw_r = raw_range_m.unwrap_or(&[]);
            let f = incidence_frame(cal, inc, points, i, raw_r, cfg.method, &cfg.options).map_err(
                |e| format!("{e} (the survey on the plain table's points; {n_read} points read)"),
            )?;
            (Some(f.scene), f.rounds)
        } else {
            let rounds = incidence_rounds(cal, inc, points, i, cfg.method, &cfg.options);
            (None, rounds)
        };
        let rounds = rounds?;
        let uncorrected = rounds.uncorrected;
        let (moved, s) = shared_errors(inc, rounds, points);
        return Ok(Calibrated {
            n_calibrated: moved,
            outside: Some(s.outside_fraction),
            // Uncorrected points have no spread from the table: the fit is unweighted.
            sigma: (cfg.weighted && uncorrected.is_none()).then(|| s.sigma_m.clone()),
            scene,
            surveyed_here: false,
            shared: Some(s),
            uncorrected,
        });
    }
    let mut outside = None;
    if let Some(i) = intensity
        && i.len() == points.len()
    {
        let (valid, covered) = points.iter().zip(i).fold((0usize, 0usize), |a, (p, &v)| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if !(r.is_finite() && r > 0.0) {
                return a;
            }
            (a.0 + 1, a.1 + usize::from(cal.table.covers(r, v)))
        });
        outside = (valid > 0).then(|| (valid - covered) as f64 / valid as f64);
    }
    // Corrected, and the scene read from the corrected points ([`plain_frame`]).
    let (moved, sigma, scene) = match intensity {
        Some(i) if cfg.geometry && !(cfg.weighted && sigma_given) => {
            let f = plain_frame(
                cal,
                points,
                i,
                raw_range_m.unwrap_or(&[]),
                cfg.weighted,
                cfg.method,
                &cfg.options,
            )
            .map_err(|e| match e {
                PlainFrameError::Correction(m) => m,
                PlainFrameError::Survey(m) => format!("{m} ({n_read} points read)"),
            })?;
            (f.moved, f.sigma_m, Some(f.scene))
        }
        _ => {
            let (moved, sigma) =
                cal.correct_points(cfg.weighted, points, intensity, sigma_given)?;
            (moved, sigma, None)
        }
    };
    // The bins' standard errors, shared by the points each one corrected.
    let shared = match intensity {
        Some(i) if i.len() == points.len() => Some(SharedErrors {
            shift: Shares::Interpolated(cal.table.shared_error_terms(points, i)),
            n_groups: cal.table.offset_m.len(),
            outside_fraction: outside.unwrap_or(0.0),
            sigma_m: Vec::new(),
            raw_diameters: None,
        }),
        _ => None,
    };
    Ok(Calibrated {
        n_calibrated: moved,
        outside,
        sigma,
        scene,
        surveyed_here: true,
        shared,
        uncorrected: None,
    })
}

/// A frame corrected in place by a version-1 (range × intensity) table and its scene, as
/// `epd estimate --calibration` makes them (`calibrate`; the bench harness's pipeline
/// run makes the same): every point the table's axes hold moved along its ray, then the
/// scene surveyed on the corrected points, a bend checked against the table when
/// `raw_range_m` (each point's measured range, m; empty for none) is given. `weighted`:
/// each point's σ from the table's spread as well. Invalid pixels (NaN, inf, zeros) are
/// left for the estimator to drop and count.
pub fn plain_frame(
    cal: &CalibrationTable,
    points: &mut [[f64; 3]],
    intensity: &[f64],
    raw_range_m: &[f64],
    weighted: bool,
    method: epd_core::Method,
    options: &epd_core::EstimateOptions,
) -> Result<PlainFrame, PlainFrameError> {
    let (moved, sigma_m) = cal
        .correct_points(weighted, points, Some(intensity), false)
        .map_err(PlainFrameError::Correction)?;
    epd_core::cancel::checkpoint();
    let lookups =
        (raw_range_m.len() == points.len()).then_some((&cal.table, raw_range_m, intensity));
    let scene = FrameScene::survey(points, method, options, lookups)
        .map_err(|e| PlainFrameError::Survey(e.to_string()))?;
    Ok(PlainFrame {
        moved,
        sigma_m,
        scene,
    })
}

/// What [`plain_frame`] made of a frame.
#[derive(Clone, Debug)]
pub struct PlainFrame {
    /// Points the table moved.
    pub moved: usize,
    /// Each point's σ from the table's spread (m), when asked for (NaN for invalid points).
    pub sigma_m: Option<Vec<f64>>,
    /// The scene, surveyed on the corrected points.
    pub scene: FrameScene,
}

/// Why [`plain_frame`] failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlainFrameError {
    /// The table refused the frame (another camera's, or no intensity per point).
    #[error("{0}")]
    Correction(String),
    /// The survey of the corrected points failed.
    #[error("{0}")]
    Survey(String),
}

/// A frame to be corrected by a version-2 (incidence) table, as `epd estimate
/// --calibration` makes it (`calibrate`; the bench harness's pipeline run makes the
/// same): the scene surveyed on the points corrected by the table's plain range ×
/// intensity part, then the incidence rounds ([`incidence_rounds`]) on the raw points of
/// the straight section it found (the others left out, NaN).
///
/// The incidence table leaves out (NaN) the points outside its support — a bend's or a
/// tee's wall, whose incidences and ranges straight rigs never showed — so a survey of
/// its points would not see what lies ahead (issue 24: a bend read `straight` with the
/// version-2 table of the pipeline run); the plain table corrects every point its range
/// and intensity axes hold. And a bend's or a tee's wall is no straight cylinder: the
/// incidences of a fit that included it would be wrong. `raw_range_m` (each point's
/// measured range, m) lets the scene check a bend against the table; empty for none.
/// An error when the plain correction or the survey fails; the rounds' own failure (they
/// cannot fit the straight section, or it lies mostly outside the support) is
/// [`IncidenceFrame::rounds`].
pub fn incidence_frame(
    cal: &CalibrationTable,
    table: &epd_core::calibration::IncidenceTable,
    raw: &[[f64; 3]],
    intensity: &[f64],
    raw_range_m: &[f64],
    method: epd_core::Method,
    options: &epd_core::EstimateOptions,
) -> Result<IncidenceFrame, String> {
    // The plain table's points live only as long as the survey: the rounds that follow
    // hold their own copies of the frame.
    let scene = {
        let mut plain = raw.to_vec();
        cal.correct_points(false, &mut plain, Some(intensity), false)?;
        let lookups =
            (raw_range_m.len() == raw.len()).then_some((&cal.table, raw_range_m, intensity));
        FrameScene::survey(&plain, method, options, lookups).map_err(|e| e.to_string())?
    };
    let mut straight = raw.to_vec();
    if let Some(keep) = &scene.straight {
        for (p, &k) in straight.iter_mut().zip(keep) {
            if !k {
                *p = [f64::NAN; 3];
            }
        }
    }
    let rounds = incidence_rounds(cal, table, &straight, intensity, method, options);
    Ok(IncidenceFrame { scene, rounds })
}

/// What [`incidence_frame`] made of a frame.
#[derive(Clone, Debug)]
pub struct IncidenceFrame {
    /// The scene, surveyed on the points corrected by the table's plain range ×
    /// intensity part.
    pub scene: FrameScene,
    /// The incidence rounds on the scene's straight section, or why they could not run
    /// or refused the frame.
    pub rounds: Result<IncidenceRounds, String>,
}

/// The incidence rounds' result as a measurement takes it: `points` replaced by the
/// corrected ones, and the points moved with what the 1-σ needs (each corrected point's
/// bin, whose standard error every point of the bin shares).
fn shared_errors(
    table: &epd_core::calibration::IncidenceTable,
    rounds: IncidenceRounds,
    points: &mut Vec<[f64; 3]>,
) -> (usize, SharedErrors) {
    let IncidenceRounds {
        points: corrected,
        correction: corr,
        raw_diameters,
        uncorrected,
    } = rounds;
    if let Some(u) = uncorrected {
        // One error shared by every valid point, of the table's largest offset.
        let shift = corrected
            .iter()
            .map(|p| {
                let r2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
                (r2.is_finite() && r2 > 0.0).then_some((0, u.shared_error_m))
            })
            .collect();
        *points = corrected;
        return (
            0,
            SharedErrors {
                shift: Shares::Home(shift),
                n_groups: 1,
                outside_fraction: u.outside_fraction,
                sigma_m: Vec::new(),
                // Nothing corrected: no correction's effect to add for a size outside
                // the rigs' ([`add_transfer_uncertainty`]).
                raw_diameters: None,
            },
        );
    }
    let shift = Shares::Home(
        corr.bin
            .iter()
            .map(|b| b.map(|b| (b, table.se_m[b as usize])))
            .collect(),
    );
    let total = corr.moved + corr.outside;
    *points = corrected;
    (
        corr.moved,
        SharedErrors {
            shift,
            n_groups: table.cells(),
            outside_fraction: if total == 0 {
                0.0
            } else {
                corr.outside as f64 / total as f64
            },
            sigma_m: corr.sigma_m,
            raw_diameters: Some(raw_diameters),
        },
    )
}

/// The incidence table's rounds on `raw` (SCS, m; points to leave out NaN), as `epd
/// estimate` makes them ([`incidence_frame`]; the bench harness's pipeline run makes
/// the same): the frame fitted on its raw points by `method` with `options`, then up to
/// [`INCIDENCE_ROUNDS`] rounds of cos θ of each ray at the fitted wall → the raw points
/// corrected by `table` → refit, until the mean diameter moves by less than
/// [`INCIDENCE_TOLERANCE_M`]. Left uncorrected, before the corrected points are fitted,
/// when more than [`REFUSE_OUTSIDE`] of them lie outside the table's support: the raw
/// points, with [`IncidenceRounds::uncorrected`] saying so. The corrected points
/// (those outside the support NaN), the last round's correction, and the raw fit's
/// (Dmax, Dmin) ([`IncidenceRounds`]).
pub fn incidence_rounds(
    cal: &CalibrationTable,
    table: &epd_core::calibration::IncidenceTable,
    raw: &[[f64; 3]],
    intensity: &[f64],
    method: epd_core::Method,
    options: &epd_core::EstimateOptions,
) -> Result<IncidenceRounds, String> {
    // Each round's fit is used for its β alone (the incidences of the next correction):
    // the final fit, with its 1-σ, is the caller's, of the corrected points.
    let fit = |p: &[[f64; 3]]| {
        fit_pose(p, method, options).map_err(|e| format!("{e} (the incidence round)"))
    };
    let mut pose = fit(raw)?;
    let raw_diameters = (pose.params.d_max, pose.params.d_min);
    let raw_status = pose.status;
    let mut out = None;
    for round in 0..INCIDENCE_ROUNDS {
        let cos = epd_core::calibration::incidences(raw, &pose.params);
        let mut c = raw.to_vec();
        let corr = cal.correct_with_incidence(table, &mut c, intensity, &cos)?;
        let total = corr.moved + corr.outside;
        if round == 0 && total > 0 && corr.outside as f64 > REFUSE_OUTSIDE * total as f64 {
            // Left uncorrected before the corrected points are fitted: too few lie in the
            // support.
            return Ok(uncorrected_rounds(raw, raw_diameters, table, &corr));
        }
        let next = fit(&c)?;
        let moved = (next.d_mean() - pose.d_mean()).abs();
        pose = next;
        out = Some((c, corr));
        if moved < INCIDENCE_TOLERANCE_M {
            break;
        }
    }
    let Some((corrected, corr)) = out else {
        return Err("no incidence round ran".into());
    };
    // The corrected points of a frame mostly outside the support (more than
    // [`MOSTLY_OUTSIDE`]) that do not determine the pipe — their fit's own check finds it
    // implausible (a partial view, diverged) — while the raw points did: the raw points,
    // with the camera's error in the 1-σ.
    let total = corr.moved + corr.outside;
    let mostly_outside = total > 0 && corr.outside as f64 > MOSTLY_OUTSIDE * total as f64;
    if mostly_outside
        && matches!(pose.status, epd_core::FitStatus::Implausible(_))
        && !matches!(raw_status, epd_core::FitStatus::Implausible(_))
    {
        return Ok(uncorrected_rounds(raw, raw_diameters, table, &corr));
    }
    Ok(IncidenceRounds {
        points: corrected,
        correction: corr,
        raw_diameters,
        uncorrected: None,
    })
}

/// A frame left uncorrected ([`UncorrectedFrame`]): its raw points, none moved, and the
/// fraction of them `corr` found outside the table's support.
fn uncorrected_rounds(
    raw: &[[f64; 3]],
    raw_diameters: (f64, f64),
    table: &epd_core::calibration::IncidenceTable,
    corr: &epd_core::calibration::Correction,
) -> IncidenceRounds {
    let total = corr.moved + corr.outside;
    IncidenceRounds {
        points: raw.to_vec(),
        correction: epd_core::calibration::Correction {
            moved: 0,
            outside: total,
            bin: vec![None; raw.len()],
            sigma_m: vec![f64::NAN; raw.len()],
        },
        raw_diameters,
        uncorrected: Some(UncorrectedFrame {
            outside_fraction: corr.outside as f64 / total.max(1) as f64,
            shared_error_m: largest_offset_m(table),
        }),
    }
}

/// What [`incidence_rounds`] made of a frame.
#[derive(Clone, Debug)]
pub struct IncidenceRounds {
    /// The points corrected by the last round (SCS, m; those outside the table's support
    /// NaN).
    pub points: Vec<[f64; 3]>,
    /// The last round's correction: each point's bin, the table's spread at it, the
    /// counts moved and outside.
    pub correction: epd_core::calibration::Correction,
    /// (Dmax, Dmin) of the fit on the raw points (m).
    pub raw_diameters: (f64, f64),
    /// The frame lay too far outside the table's support to be corrected
    /// ([`REFUSE_OUTSIDE`]): `points` are the raw ones.
    pub uncorrected: Option<UncorrectedFrame>,
}

/// The relative margin around the rigs' diameters within which a pipe counts as one of
/// their sizes: 3 %, the 2 % ovality a pipe may have (API 5L's out-of-roundness limit for
/// line pipe is 1.5 % of the OD at the ends, more along the body) plus the 1 % tolerance
/// of the nominal diameter — nominal sizes 2" apart at 16"–30" differ by 7 % or more.
pub const RIG_SIZE_MARGIN: f64 = 0.03;

/// When the frame's mean diameter lies outside the rigs' sizes (the smallest rig's
/// Dmin to the largest rig's Dmax, widened by [`RIG_SIZE_MARGIN`]), the table's
/// correction is not known to transfer to it (at the same range, intensity and
/// incidence the rigs' poses absorbed a part of the error that depends on the pipe's
/// size); when more than [`MOSTLY_OUTSIDE`] of its points lie outside the table's
/// support, the fit rests on a minority of the wall, the part the rigs showed. Either
/// way the whole effect of the correction on each diameter, |D_corrected − D_raw|, is
/// added to its variance — a 1-σ that spans the raw and the corrected result (a version-2
/// table's frames only: a version-1 table's are not fitted raw). Which of the two held
/// ([`Transfer`]).
pub(super) fn add_transfer_uncertainty(
    est: &mut epd_core::Estimate,
    s: &SharedErrors,
    cal: &crate::table::CalibrationTable,
) -> Transfer {
    let none = Transfer::default();
    let Some(raw) = s.raw_diameters else {
        return none;
    };
    let lo = cal.rigs.iter().map(|r| r.0.1).fold(f64::INFINITY, f64::min);
    let hi = cal.rigs.iter().map(|r| r.0.0).fold(0.0f64, f64::max);
    let d = est.d_mean();
    let outside_sizes = lo.is_finite()
        && hi > 0.0
        && !(lo * (1.0 - RIG_SIZE_MARGIN)..=hi * (1.0 + RIG_SIZE_MARGIN)).contains(&d);
    let mostly_outside = s.outside_fraction > MOSTLY_OUTSIDE;
    if !(outside_sizes || mostly_outside) {
        return none;
    }
    let delta = [est.params.d_max - raw.0, est.params.d_min - raw.1];
    if let Some(mut cov) = est.diameter_cov {
        for k in 0..2 {
            cov[k][k] += delta[k] * delta[k];
        }
        est.diameter_cov = Some(cov);
    }
    for k in 0..2 {
        if let Some(sig) = est.sigma[k] {
            est.sigma[k] = Some(sig.hypot(delta[k]));
        }
    }
    Transfer {
        size_outside_rigs: outside_sizes.then_some((lo * 1e3, hi * 1e3)),
        mostly_outside,
    }
}

/// Why [`add_transfer_uncertainty`] added the correction's whole effect to the 1-σ.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Transfer {
    /// The rigs' smallest and largest diameters (mm), when the frame's mean diameter
    /// lies outside them.
    pub size_outside_rigs: Option<(f64, f64)>,
    /// More than [`MOSTLY_OUTSIDE`] of the frame's points lie outside the support.
    pub mostly_outside: bool,
}

/// Add the depth table's own uncertainty to the diameters' 1-σ: each bin's standard
/// error, shared by every point the bin corrected (a version-1 table: by every point
/// whose bilinear interpolation read it, times its weight), propagated through the
/// fit's Jacobian ([`epd_core::calibration::shared_error_cov_terms`]) and added to the
/// fit's own covariance. The fitted points: those of the straight
/// section (`mask`) within the range gate.
pub(super) fn add_table_uncertainty(
    est: &mut epd_core::Estimate,
    points: &[[f64; 3]],
    mask: Option<&[bool]>,
    s: &SharedErrors,
    cfg: &EstimateConfig,
) {
    let Some(mut cov) = est.diameter_cov else {
        return;
    };
    let geom = epd_core::residual::Geometry::new(&est.params);
    let gate = cfg.options.range_gate();
    let fitted = |k: usize, p: &[f64; 3]| {
        mask.is_none_or(|m| m.get(k).copied().unwrap_or(false))
            && match (gate, &geom) {
                (Some((lo, hi)), Some(g)) => {
                    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    (lo..=hi).contains(&(g.line_parameter(p) * r))
                }
                _ => true,
            }
    };
    fn pick<T: Copy>(
        points: &[[f64; 3]],
        terms: &[T],
        keep: impl Fn(usize, &[f64; 3]) -> bool,
    ) -> (Vec<[f64; 3]>, Vec<T>) {
        points
            .iter()
            .zip(terms)
            .enumerate()
            .filter(|(k, (p, _))| keep(*k, p))
            .map(|(_, (p, t))| (*p, *t))
            .unzip()
    }
    let extra = match &s.shift {
        Shares::Home(sh) => {
            let (p, sh) = pick(points, sh, fitted);
            epd_core::calibration::shared_error_cov(&p, &sh, s.n_groups, &est.params)
        }
        Shares::Interpolated(t) => {
            let (p, t) = pick(points, t, fitted);
            epd_core::calibration::shared_error_cov_terms(&p, &t, s.n_groups, &est.params)
        }
    };
    let Some(extra) = extra else {
        return;
    };
    for a in 0..2 {
        for b in 0..2 {
            cov[a][b] += extra[a][b];
        }
    }
    est.diameter_cov = Some(cov);
    for k in 0..2 {
        if let Some(sig) = est.sigma[k] {
            est.sigma[k] = Some((sig * sig + extra[k][k]).sqrt());
        }
    }
}
