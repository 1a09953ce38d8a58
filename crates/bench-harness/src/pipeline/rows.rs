//! The per-frame rows of a pipeline run: the depth table from the rig, then every method
//! on every frame, without and with the table, after the frame's survey as `epd estimate`
//! does it.

use anyhow::Context;
use epd_core::FitOutcome;
use epd_core::calibration::{CalibrationFrame, CalibrationSettings, IncidenceTable};
use epd_core::{
    DepthTable, EstimateOptions, Loss, LossScale, Method, Params, cramer_rao_bound_weighted,
    estimate, estimate_weighted,
};
use epd_frame::config::DEFAULT_LOSS_SCALE_M;
use epd_frame::input::ranges;
use rayon::prelude::*;
use tof_sim::{Frame, PartKind, Pipe, Segment};

use super::plan::FramePlan;
use super::{METHODS, PipelineScenario};
use crate::route::TruthAhead;

/// What the survey said of one frame and what the route holds there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Geometry {
    /// The survey's layout name.
    pub(super) found: &'static str,
    /// Its straight_until (m).
    pub(super) straight_until: Option<f64>,
    /// Its bend radius (mm), as `epd estimate` reports it.
    pub(super) bend_radius_mm: Option<f64>,
    /// The bend radius as fitted (mm), also where it is withheld.
    pub(super) bend_radius_fit_mm: Option<f64>,
    /// The fraction of the bend's points the depth table observed.
    pub(super) bend_table_coverage: Option<f64>,
    /// The truth.
    pub(super) truth: TruthAhead,
}

/// What became of one method's estimate on one frame (`status` in `profile.csv`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FrameStatus {
    /// The estimator ran: how its fit ended.
    Fit(FitOutcome),
    /// Not estimated: the survey found no straight section to fit on its own.
    Withheld,
    /// The estimator returned an error (too few points, …).
    Error,
}

impl FrameStatus {
    /// The name in `profile.csv`: the fit's outcome, `withheld` or `error`.
    pub(super) fn name(self) -> &'static str {
        match self {
            FrameStatus::Fit(o) => o.name(),
            FrameStatus::Withheld => "withheld",
            FrameStatus::Error => "error",
        }
    }
}

/// One estimate of one frame: a row of `profile.csv`, what the sections' statistics and
/// the figures read.
#[derive(Clone, Debug)]
pub(super) struct ProfileRow {
    /// [`FramePlan::place`].
    pub(super) section: usize,
    /// The pipe at the frame.
    pub(super) pipe: Pipe,
    /// The survey's verdict and the route's truth.
    pub(super) geometry: Geometry,
    /// [`FramePlan::index`].
    pub(super) frame: usize,
    /// Odometer distance (m).
    pub(super) distance_m: f64,
    /// One of [`METHODS`].
    pub(super) method: &'static str,
    /// With the depth table.
    pub(super) calibrated: bool,
    /// How the estimate ended.
    pub(super) status: FrameStatus,
    /// Dmax, Dmin (m) when converged.
    pub(super) d: Option<(f64, f64)>,
    /// The true Dmax, Dmin (m).
    pub(super) truth: (f64, f64),
    /// Points the estimator used.
    pub(super) n_points: usize,
    /// Cramér–Rao 1-σ of Dmax, Dmin (m) on the straight pipe, when defined.
    pub(super) crb: (Option<f64>, Option<f64>),
}

impl ProfileRow {
    /// Dmax, Dmin (mm) when converged.
    pub(super) fn d_mm(&self) -> Option<(f64, f64)> {
        self.d.map(|(a, b)| (a * 1e3, b * 1e3))
    }
}

/// A table bin with fewer rig points is empty and takes the nearest filled bin's values:
/// 30, as `epd calibrate --min-count` by default.
const MIN_BIN_COUNT: usize = 30;

/// The estimator options of the run: Cauchy with the scale from the residuals, the gate.
pub(super) fn options(gate: (f64, f64)) -> anyhow::Result<EstimateOptions> {
    Ok(EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", DEFAULT_LOSS_SCALE_M)?)?
        .with_loss_scale(LossScale::Auto)
        .with_range_gate(gate.0, gate.1)?)
}

/// The depth tables of the run: the range × intensity table (the survey reads a bend's
/// coverage from it) and, with `pipeline.rig.incidence_bins`, the incidence table that
/// then corrects the frames.
pub(super) struct RunTables {
    /// The range × intensity table.
    pub(super) plain: DepthTable,
    /// The range × intensity × incidence table, when asked for.
    pub(super) incidence: Option<IncidenceTable>,
    /// The spans the rig's observations covered (range, intensity, cos θ).
    pub(super) spans: [(f64, f64); 3],
    /// Point observations behind the tables.
    pub(super) n_observations: u64,
}

impl RunTables {
    /// The tables as `epd estimate` holds a version-2 file of them: the rig's known
    /// diameters and frames, its observations' spans.
    pub(super) fn calibration(&self, s: &PipelineScenario) -> epd_frame::CalibrationTable {
        epd_frame::CalibrationTable {
            table: self.plain.clone(),
            known: (s.rig.d_max(), s.rig.d_min()),
            frames: s.rig_frames,
            n_observations: self.n_observations,
            incidence: self.incidence.clone(),
            rigs: vec![((s.rig.d_max(), s.rig.d_min()), s.rig_frames)],
            spans: Some(self.spans),
        }
    }
}

/// Build the depth tables from the rig's frames ([`epd_core::calibration::calibrate`])
/// and the observations behind them.
pub(super) fn calibrate(s: &PipelineScenario) -> anyhow::Result<(RunTables, usize)> {
    let frames: Vec<(Frame, Vec<f64>)> = (0..s.rig_frames)
        .into_par_iter()
        .with_max_len(1)
        .map(|k| -> anyhow::Result<(Frame, Vec<f64>)> {
            let frame = s.rig_frame(k, s.rig_distance(k))?;
            let intensity = frame.intensity.iter().map(|&i| i as f64).collect();
            Ok((frame, intensity))
        })
        .collect::<anyhow::Result<_>>()?;
    let views: Vec<CalibrationFrame<'_>> = frames
        .iter()
        .map(|(f, i)| CalibrationFrame {
            points: &f.measured,
            intensity: i,
        })
        .collect();
    let settings = CalibrationSettings {
        known: (s.rig.d_max(), s.rig.d_min()),
        gate: s.range_gate,
        bins: s.table_bins,
        min_count: MIN_BIN_COUNT,
        passes: s.calibration_passes,
        incidence_bins: s.incidence_bins,
    };
    let cal = epd_core::calibration::calibrate(&views, &settings, &options(s.range_gate)?)?;
    if let Some(e) = cal.fits.iter().find_map(|f| f.as_ref().err()) {
        anyhow::bail!("a rig frame could not be fitted with the known diameters: {e}");
    }
    Ok((
        RunTables {
            plain: cal.table,
            incidence: cal.incidence,
            spans: cal.spans,
            n_observations: cal.n_observations as u64,
        },
        cal.n_observations,
    ))
}

/// Every method on one frame, without and with the table. The geometry ahead is
/// surveyed on the calibrated points as `epd estimate` does (ML-EPD, the run's options):
/// when something lies ahead every method fits the straight section's points only, and
/// in a bend every estimate is withheld (status `withheld`).
pub(super) fn frame_rows(
    s: &PipelineScenario,
    table: &RunTables,
    plan: &FramePlan,
) -> anyhow::Result<Vec<ProfileRow>> {
    let (truth, frame, local) = s.frame(plan)?;
    let opts = options(s.range_gate)?;
    let sv = Surveyed::of(s, table, plan, &frame, &opts)?;
    let crb = straight_crb(s, plan, &frame, local.as_ref(), &truth);
    let mut rows = Vec::new();
    for calibrated in [false, true] {
        let (points, sigma) = if calibrated {
            (&sv.corrected, &sv.table_sigma)
        } else {
            (&frame.measured, &frame.sigma)
        };
        let pts = kept(sv.keep.as_deref(), points);
        let sigma = kept(sv.keep.as_deref(), sigma);
        for method in METHODS {
            let (status, d, n_points) = if sv.withheld {
                (FrameStatus::Withheld, None, 0)
            } else {
                estimate_one(method, &pts, &sigma, &opts)
            };
            rows.push(ProfileRow {
                section: plan.place,
                pipe: plan.pipe,
                geometry: sv.geometry,
                frame: plan.index,
                distance_m: plan.x,
                method,
                calibrated,
                status,
                d,
                truth: (truth.d_max, truth.d_min),
                n_points,
                crb,
            });
        }
    }
    Ok(rows)
}

/// One frame corrected with the depth table and surveyed as `epd estimate` does.
pub(super) struct Surveyed {
    /// The measured points corrected with the table (SCS, m).
    pub(super) corrected: Vec<[f64; 3]>,
    /// Each point's σ from the table's spread at its range and intensity (m).
    pub(super) table_sigma: Vec<f64>,
    /// The survey's verdict and the route's truth.
    pub(super) geometry: Geometry,
    /// The survey withholds the estimate (the sensor is in a bend).
    pub(super) withheld: bool,
    /// When something lies ahead: which points belong to the straight section.
    pub(super) keep: Option<Vec<bool>>,
}

impl Surveyed {
    /// Correct `frame` with the run's tables and read its scene (ML-EPD, `opts`) as `epd
    /// estimate --calibration` does: with an incidence table
    /// ([`epd_frame::measure::incidence_frame`]), the scene read from the points the plain
    /// table corrected (the incidence table leaves a bend's points outside its support
    /// out: docs/calibration.md, the pipeline run), then the incidence rounds on the
    /// straight section it found; with the plain table alone
    /// ([`epd_frame::measure::plain_frame`]), the scene read from its points. Where the rounds cannot run
    /// or refuse the frame (`epd estimate` refuses it), the plain table's points serve:
    /// the run compares the methods on every frame it can.
    pub(super) fn of(
        s: &PipelineScenario,
        tables: &RunTables,
        plan: &FramePlan,
        frame: &Frame,
        opts: &EstimateOptions,
    ) -> anyhow::Result<Self> {
        let intensity: Vec<f64> = frame.intensity.iter().map(|&i| i as f64).collect();
        let raw_range_m = ranges(&frame.measured);
        let context = || {
            format!(
                "the geometry survey of {} frame {} at {:.2} m ({} valid points)",
                s.place_name(plan.place),
                plan.index,
                plan.x,
                frame.measured.iter().filter(|p| **p != [0.0; 3]).count()
            )
        };
        let cal = tables.calibration(s);
        let (scene, corrected, table_sigma) = match &tables.incidence {
            Some(it) => {
                let f = epd_frame::measure::incidence_frame(
                    &cal,
                    it,
                    &frame.measured,
                    &intensity,
                    &raw_range_m,
                    Method::MlEpd,
                    opts,
                )
                .map_err(|e| anyhow::anyhow!(e))
                .with_context(context)?;
                let (points, sigma) = match f.rounds {
                    Ok(r) if r.uncorrected.is_none() => (r.points, r.correction.sigma_m),
                    // Refused, or left uncorrected, by `epd estimate`; the run takes the
                    // plain table's points, to compare the methods on every frame.
                    _ => {
                        let mut p = frame.measured.clone();
                        let (_, sigma) = tables.plain.correct_with_sigmas(&mut p, &intensity)?;
                        (p, sigma)
                    }
                };
                (f.scene, points, sigma)
            }
            None => {
                let mut points = frame.measured.clone();
                let f = epd_frame::measure::plain_frame(
                    &cal,
                    &mut points,
                    &intensity,
                    &raw_range_m,
                    true,
                    Method::MlEpd,
                    opts,
                )
                .map_err(|e| anyhow::anyhow!(e))
                .with_context(context)?;
                (f.scene, points, f.sigma_m.unwrap_or_default())
            }
        };
        let report = &scene.geometry;
        let geometry = Geometry {
            found: report.layout,
            straight_until: report.straight_until_m,
            bend_radius_mm: report.bend_radius_mm,
            bend_radius_fit_mm: scene.bend_radius_fit_mm,
            bend_table_coverage: scene.bend_table_coverage,
            truth: s.route.truth(plan.x, s.sensor.max_range),
        };
        Ok(Self {
            withheld: report.withheld().is_some(),
            corrected,
            table_sigma,
            geometry,
            keep: scene.straight,
        })
    }
}

/// The Cramér–Rao bound (Dmax, Dmin) of the heteroscedastic model over the valid pixels
/// in the gate on the sensor's straight pipe (before any bend of `local`, the mesh the
/// frame was cast on); none in an elbow or when the bound is undefined.
pub(super) fn straight_crb(
    s: &PipelineScenario,
    plan: &FramePlan,
    frame: &Frame,
    local: Option<&tof_sim::Pipeline>,
    truth: &Params,
) -> (Option<f64>, Option<f64>) {
    if s.route.in_elbow(plan.x).is_some() {
        return (None, None);
    }
    let first_bend = local.and_then(|p| {
        p.segments
            .iter()
            .position(|g| matches!(g, Segment::Bend { .. }))
    });
    let on_straight = |i: usize| match frame.part.get(i).copied().flatten() {
        None => true,
        Some(part) => {
            part.kind == PartKind::Straight
                && first_bend.is_none_or(|b| (part.segment as usize) < b)
        }
    };
    let (mut exact, mut sig) = (Vec::new(), Vec::new());
    for i in 0..frame.len() {
        let e = frame.exact[i];
        let r = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        let valid = frame.measured[i] != [0.0; 3] && frame.sigma[i].is_finite();
        if valid && on_straight(i) && (s.range_gate.0..=s.range_gate.1).contains(&r) {
            exact.push(e);
            sig.push(frame.sigma[i]);
        }
    }
    cramer_rao_bound_weighted(&exact, &sig, truth)
        .map(|c| (c[0], c[1]))
        .unwrap_or((None, None))
}

/// One method of [`METHODS`] on `pts` (`ml-epd-w`: weighted by 1/σᵢ², `sigma`): its
/// status, (Dmax, Dmin) when converged (m) and the points it used.
pub(super) fn estimate_one(
    method: &str,
    pts: &[[f64; 3]],
    sigma: &[f64],
    opts: &EstimateOptions,
) -> (FrameStatus, Option<(f64, f64)>, usize) {
    let result = match method {
        "c-epd" => estimate(pts, Method::CEpd, opts),
        "ru-epd" => estimate(pts, Method::RuEpd, opts),
        "ml-epd" => estimate(pts, Method::MlEpd, opts),
        _ => estimate_weighted(pts, sigma, Method::MlEpd, opts),
    };
    match result {
        Ok(e) => (
            FrameStatus::Fit(e.status.outcome()),
            e.status
                .is_converged()
                .then_some((e.params.d_max, e.params.d_min)),
            e.n_points,
        ),
        Err(_) => (FrameStatus::Error, None, 0),
    }
}

/// The entries of `v` whose `keep` flag is set (all of them without flags).
pub(super) fn kept<T: Copy>(keep: Option<&[bool]>, v: &[T]) -> Vec<T> {
    match keep {
        None => v.to_vec(),
        Some(k) => v
            .iter()
            .zip(k)
            .filter(|(_, k)| **k)
            .map(|(p, _)| *p)
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use epd_core::segment::Layout;

    use super::*;

    /// Regression: with a 256-cell mesh, the frame 0.4 m before the elbow made the
    /// survey's near-point restart cut the straight section to too few points, and the
    /// whole survey failed ("only 0 usable points") instead of saying `in_bend`.
    #[test]
    fn the_frame_before_the_elbow_is_surveyed_with_a_coarse_mesh() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenarios/pipeline_run.toml"
        ));
        let source = std::fs::read_to_string(path).expect("the committed scenario");
        // The rig's plain table as it was made before the incidence axis (whose passes
        // refine the rig's poses with the incidence table and so change the plain table
        // too: with it this coarse-mesh frame reads `Straight`, a miss the committed run's
        // finer mesh does not make — issue 24's notes).
        let source = source
            .replace("[pipeline]\n", "[pipeline]\nmesh_segments = 256\n")
            .replace("incidence_bins = 16", "incidence_bins = 0");
        let s = PipelineScenario::parse(path, &source).expect("a valid scenario");
        let plan = s
            .plans()
            .into_iter()
            .find(|p| (p.x - 17.6).abs() < 1e-9)
            .expect("a frame at 17.6 m");
        let (_, frame, _) = s.frame(&plan).expect("the frame");
        let (tables, _) = calibrate(&s).expect("the rig's table");
        let table = tables.plain;
        let intensity: Vec<f64> = frame.intensity.iter().map(|&i| i as f64).collect();
        let mut corrected = frame.measured.clone();
        table
            .correct_with_sigmas(&mut corrected, &intensity)
            .expect("the table applies");
        let opts = options(s.range_gate).expect("options");
        let sv = epd_core::segment::survey(
            &corrected,
            Method::MlEpd,
            &opts,
            &epd_core::segment::SegmentOptions::default(),
        )
        .expect("a verdict, not an error");
        // The elbow starts 0.4 m ahead: the survey must see a bend (today it says the
        // sensor is already in it, and the estimate is withheld).
        let layout = sv.segmentation.layout;
        assert!(
            matches!(layout, Layout::InBend | Layout::BendAhead),
            "{layout:?}"
        );
    }

    /// The frame 1 m before the elbow, corrected by the rig's table: the survey fits the
    /// bend, but most of its points lie where the straight rig never showed the camera's
    /// error (beyond its ranges, or brighter), so the radius is withheld with the reason,
    /// as `epd estimate` does; the fitted radius stays in the run's diagnostics.
    #[test]
    fn a_bend_the_rigs_table_did_not_observe_has_its_radius_withheld() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenarios/pipeline_run.toml"
        ));
        let source = std::fs::read_to_string(path).expect("the committed scenario");
        let s = PipelineScenario::parse(path, &source).expect("a valid scenario");
        let plan = s
            .plans()
            .into_iter()
            .find(|p| (p.x - 17.0).abs() < 1e-9)
            .expect("a frame at 17.0 m");
        let (_, frame, _) = s.frame(&plan).expect("the frame");
        let (tables, _) = calibrate(&s).expect("the rig's table");
        let opts = options(s.range_gate).expect("options");
        let sv = Surveyed::of(&s, &tables, &plan, &frame, &opts).expect("a verdict");
        let g = &sv.geometry;
        assert_eq!(g.found, "bend_ahead");
        assert!(g.bend_radius_fit_mm.is_some(), "the bend was fitted");
        let c = g.bend_table_coverage.expect("a coverage");
        assert!(
            c < epd_frame::scene::MIN_BEND_TABLE_COVERAGE,
            "coverage {c}"
        );
        assert_eq!(g.bend_radius_mm, None);
        assert!(!sv.withheld, "the straight estimate is still reported");
    }
}
