//! The scene ahead of the sensor, as every front end reads it: the survey of the frame
//! (`epd_core::segment::survey`: a straight pipe, a bend or a tee ahead, or in a bend),
//! which points belong to the straight section, and the report of what was found
//! ([`GeometryReport`]), the bend's values withheld where a depth table did not observe
//! the camera's error.

use epd_core::calibration::DepthTable;
use epd_core::segment::{SegmentOptions, Survey, outside_ring_mask, straight_mask, survey};
use epd_core::{EpdError, EstimateOptions, Method};

/// What the scene step found in one frame ([`FrameScene::survey`]).
#[derive(Clone, Debug)]
pub struct FrameScene {
    /// The survey: the straight section's estimate, what lies ahead, the bend's fit.
    pub survey: Survey,
    /// Its report (the keys `geometry`, `straight_until_m`, `bend_*`).
    pub geometry: GeometryReport,
    /// When something lies ahead: which points belong to the straight section (those
    /// whose ray meets the straight wall before its end, less the survey's margin); with
    /// a ring of range error left out, those outside it (`epd_core::segment::Ring`); with
    /// an answer refitted before a departure that vanished or from a near window, its
    /// points (`epd_core::segment::Segmentation::fitted_before_m`, `window_m`); `None`
    /// when every point does.
    pub straight: Option<Vec<bool>>,
    /// The bend's radius as fitted (mm), before any withholding.
    pub bend_radius_fit_mm: Option<f64>,
    /// The fraction of the bend's points the depth table observed
    /// ([`bend_table_coverage`]), when there is a table and a fitted bend.
    pub bend_table_coverage: Option<f64>,
}

impl FrameScene {
    /// Survey `points` (SCS, m; as they will be fitted, i.e. after any depth table) with
    /// `method` and `options`. With `table` = (the depth table, each point's measured
    /// range before the correction (m), its intensity), a fitted bend's radius, angle and
    /// direction are withheld when the table did not observe most of its points
    /// ([`GeometryReport::check_bend_against_table`]).
    pub fn survey(
        points: &[[f64; 3]],
        method: Method,
        options: &EstimateOptions,
        table: Option<(&DepthTable, &[f64], &[f64])>,
    ) -> Result<Self, EpdError> {
        let survey = survey(points, method, options, &SegmentOptions::default())?;
        let mut geometry = GeometryReport::of(&survey);
        let bend_radius_fit_mm = geometry.bend_radius_mm;
        let bend_table_coverage = table.and_then(|(t, raw_range_m, intensity)| {
            bend_table_coverage(&survey, points, raw_range_m, intensity, t)
        });
        geometry.check_bend_against_table(bend_table_coverage);
        let seg = &survey.segmentation;
        let defaults = SegmentOptions::default();
        let straight = match (seg.straight_until, &seg.ring) {
            (Some(end), _) => Some(straight_mask(
                points,
                &seg.straight.params,
                end,
                defaults.margin_m,
            )),
            // The ring's points are not the straight section's: its estimate left them
            // out, and so must a weighted or calibrated refit and the RMS residual.
            (None, Some(ring)) => Some(outside_ring_mask(
                points,
                &seg.straight.params,
                ring,
                defaults.slice_m,
            )),
            // An answer refitted on the points before a departure that vanished, or
            // from a near window that found no end: those points alone.
            (None, None) => match (seg.fitted_before_m, seg.window_m) {
                (Some(end), _) => Some(straight_mask(
                    points,
                    &seg.straight.params,
                    end,
                    defaults.margin_m,
                )),
                (None, Some(reach)) => Some(points.iter().map(|p| p[0] <= reach).collect()),
                (None, None) => None,
            },
        };
        Ok(Self {
            survey,
            geometry,
            straight,
            bend_radius_fit_mm,
            bend_table_coverage,
        })
    }
}

/// The geometry ahead of the sensor in a report (`epd_core::segment::survey`).
#[derive(Clone, Debug, PartialEq)]
pub struct GeometryReport {
    /// `straight`, `bend_ahead`, `tee_ahead` or `in_bend`.
    pub layout: &'static str,
    /// Axial distance from the sensor to the end of the straight section (m).
    pub straight_until_m: Option<f64>,
    /// Its 1-σ (m) (`epd_core::segment::Survey::straight_until_sigma`).
    pub sigma_straight_until_m: Option<f64>,
    /// The statistic behind the verdict (`epd_core::segment::Survey::evidence`): −log₁₀
    /// of the departure test's least p-value over the frame's slices, adjusted for their
    /// number; a straight pipe's frame reaches 3 with probability at most 10⁻³
    /// (`epd_core::segment::SURVEY_FALSE_ALARM`).
    pub evidence: f64,
    /// The bend's centreline radius (mm).
    pub bend_radius_mm: Option<f64>,
    /// Its 1-σ (mm) (`epd_core::bend::BendFit::radius_sigma`).
    pub sigma_bend_radius_mm: Option<f64>,
    /// The bend angle (deg): the fitted angle Θ when the bend's end is in view
    /// (`epd_core::bend::BendFit::end_seen`), else the angle seen so far (a lower bound).
    pub bend_angle_deg: Option<f64>,
    /// The fitted angle's 1-σ (deg) when the bend's end is in view; `None` otherwise
    /// (`bend_angle_deg` is then the angle seen so far).
    pub sigma_bend_angle_deg: Option<f64>,
    /// The bend's direction as a clock angle seen from the sensor (deg: 0 up, 90 right).
    pub bend_direction_deg: Option<f64>,
    /// Whether the straight estimate is withheld (in a bend, or too little straight
    /// pipe in view before what lies ahead).
    pub straight_withheld: bool,
    /// Why the bend's radius, angle and direction are not reported although a bend was
    /// fitted ([`GeometryReport::check_bend_against_table`]).
    pub bend_withheld: Option<String>,
    /// A dent, debris or an obstacle on the wall of a straight pipe
    /// (`epd_core::segment::Dent`): where it is deepest (m along the axis), its clock
    /// angle seen from the sensor (deg: 0 up, 90 right) and its depth (mm). The straight
    /// estimate then uses the points before it (`straight_until_m` is where it starts).
    pub dent: Option<DentReport>,
    /// A ring of the wall that reads wider all around than the straight pipe before and
    /// after it (`epd_core::segment::Ring`: multipath over a band of ranges, a calibration
    /// error, a local widening), left out of the straight estimate.
    pub ring: Option<RingReport>,
}

/// A ring in a report (keys `ring_from_m`, `ring_to_m`, `ring_widening_mm`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RingReport {
    /// Axial distance from the sensor to where it begins (m).
    pub from_m: f64,
    /// Axial distance to where it ends (m).
    pub to_m: f64,
    /// How far its wall reads out all around against the straight fit (mm).
    pub widening_mm: f64,
}

/// A dent in a report (keys `dent_at_m`, `dent_clock_deg`, `dent_depth_mm`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DentReport {
    /// Axial distance from the sensor to where it is deepest (m).
    pub at_m: f64,
    /// Clock angle seen from the sensor (deg: 0 up, 90 right).
    pub clock_deg: f64,
    /// Depth (mm): the deepest sector median inside the fitted wall.
    pub depth_mm: f64,
}

/// The least fraction of a bend's points that must lie where the depth table observed
/// the camera's error for its radius to be reported from calibrated points. Measured
/// (`scenarios/pipeline_run.toml`, Helios2 model, rig table): 0–38 % of the bend's points
/// covered went with radius errors of −6.9 … +1.3 %, against ≤ 1.3 % without systematic
/// errors (`scenarios/elbow_approach.toml`).
pub const MIN_BEND_TABLE_COVERAGE: f64 = 0.5;

/// The fraction of the bend's points whose measured range (`raw_range_m`, before the
/// correction) and intensity the depth table observed ([`DepthTable::covers`]): the
/// valid points whose ray meets the straight fit's wall at or past the straight section's
/// end (`epd_core::segment::straight_mask` without margin) of `points` (those surveyed).
/// `None` without a fitted bend, or without such points.
pub fn bend_table_coverage(
    s: &epd_core::segment::Survey,
    points: &[[f64; 3]],
    raw_range_m: &[f64],
    intensity: &[f64],
    table: &DepthTable,
) -> Option<f64> {
    s.bend?;
    let end = s.segmentation.straight_until?;
    let straight =
        epd_core::segment::straight_mask(points, &s.segmentation.straight.params, end, 0.0);
    let (mut n, mut covered) = (0usize, 0usize);
    for ((&r, &i), before) in raw_range_m.iter().zip(intensity).zip(straight) {
        if before || !(r > 0.0 && r.is_finite()) {
            continue;
        }
        n += 1;
        covered += usize::from(table.covers(r, i));
    }
    (n > 0).then(|| covered as f64 / n as f64)
}

impl GeometryReport {
    /// The report of a survey.
    pub fn of(s: &epd_core::segment::Survey) -> Self {
        let seg = &s.segmentation;
        let beta = seg.straight.params;
        Self {
            layout: seg.layout.name(),
            straight_until_m: seg.straight_until,
            sigma_straight_until_m: seg.straight_until.and(s.straight_until_sigma),
            evidence: s.evidence,
            bend_radius_mm: s.bend.map(|b| b.geometry.radius * 1e3),
            sigma_bend_radius_mm: s
                .bend
                .map(|b| b.radius_sigma * 1e3)
                .filter(|v| v.is_finite()),
            bend_angle_deg: s.bend.map(|b| {
                if b.end_seen {
                    b.geometry.angle.to_degrees()
                } else {
                    b.angle_seen.to_degrees()
                }
            }),
            sigma_bend_angle_deg: s
                .bend
                .filter(|b| b.end_seen)
                .map(|b| b.angle_sigma.to_degrees())
                .filter(|v| v.is_finite()),
            bend_direction_deg: s
                .bend
                .map(|b| epd_core::segment::clock_angle_deg(&beta, b.geometry.direction)),
            straight_withheld: seg.straight_withheld,
            bend_withheld: None,
            dent: s.dent.map(|d| DentReport {
                at_m: d.at_m,
                clock_deg: d.clock_deg,
                depth_mm: d.depth_m * 1e3,
            }),
            ring: seg.ring.map(|r| RingReport {
                from_m: r.from_m,
                to_m: r.to_m,
                widening_mm: r.widening_m * 1e3,
            }),
        }
    }

    /// With a depth table: when fewer than [`MIN_BEND_TABLE_COVERAGE`] of the bend's
    /// points lie where the table observed the camera's error (`coverage`, from
    /// [`bend_table_coverage`]), the bend's radius, angle and direction are withheld with
    /// the reason: there the correction is a neighbouring bin's guess, and the camera's
    /// multipath and intensity offsets bend the fitted torus.
    pub fn check_bend_against_table(&mut self, coverage: Option<f64>) {
        let Some(c) = coverage.filter(|c| *c < MIN_BEND_TABLE_COVERAGE) else {
            return;
        };
        if self.bend_radius_mm.is_none() {
            return;
        }
        self.bend_radius_mm = None;
        self.sigma_bend_radius_mm = None;
        self.bend_angle_deg = None;
        self.sigma_bend_angle_deg = None;
        self.bend_direction_deg = None;
        self.bend_withheld = Some(format!(
            "bend radius, angle and direction not reported: only {:.0} % of the bend's points \
             lie where the depth table observed the camera's error (its range × intensity \
             bins; at least {:.0} % needed); elsewhere its correction is a neighbouring \
             bin's. Calibrate with a rig whose frames reach the bend's ranges and brightness",
            100.0 * c,
            100.0 * MIN_BEND_TABLE_COVERAGE
        ));
    }

    /// Why the straight estimate is withheld: the sensor is in the bend, or what lies
    /// ahead starts too close for the straight pipe before it to be measured.
    pub fn withheld(&self) -> Option<String> {
        if self.layout == "in_bend" {
            return Some(
                "the sensor is in a bend, or a fitting starts where its view of the wall \
                 begins: no straight section in view to estimate (geometry in_bend)"
                    .to_string(),
            );
        }
        self.straight_withheld.then(|| {
            let what = match self.layout {
                "tee_ahead" => "a tee's branch opening",
                "bend_ahead" => "a bend",
                // A straight pipe's estimate is withheld only before something on its
                // wall (`dent`), which the survey found where the straight section ends.
                _ => "a dent, debris or an obstacle on the wall",
            };
            let at = self
                .straight_until_m
                .map_or(String::new(), |x| format!(" {x:.2} m ahead"));
            format!(
                "{what} starts{at}: too little straight pipe in view before it (within the \
                 range gate) to estimate (geometry {})",
                self.layout
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(layout: &'static str, dent: Option<DentReport>) -> GeometryReport {
        GeometryReport {
            layout,
            straight_until_m: Some(0.73),
            sigma_straight_until_m: None,
            evidence: 10.0,
            bend_radius_mm: None,
            sigma_bend_radius_mm: None,
            bend_angle_deg: None,
            sigma_bend_angle_deg: None,
            bend_direction_deg: None,
            straight_withheld: true,
            bend_withheld: None,
            dent,
            ring: None,
        }
    }

    /// A withheld straight estimate names what starts where it ends: a tee's opening, a
    /// bend, or — in a straight pipe — what lies on its wall (a frame of a 42" tee 0.5 m
    /// ahead whose opening read as a dent was said to have "a bend" ahead).
    #[test]
    fn the_reason_names_what_ends_the_straight_section() {
        let dent = DentReport {
            at_m: 0.75,
            clock_deg: 217.0,
            depth_mm: 3.0,
        };
        for (layout, dent, names) in [
            (
                "tee_ahead",
                None,
                "tee's branch opening starts 0.73 m ahead",
            ),
            ("bend_ahead", None, "a bend starts 0.73 m ahead"),
            ("straight", Some(dent), "a dent, debris or an obstacle"),
        ] {
            let why = report(layout, dent).withheld().unwrap();
            assert!(why.contains(names), "{layout}: {why}");
            assert!(why.contains(layout), "{layout}: {why}");
        }
        let why = report("in_bend", None).withheld().unwrap();
        assert!(why.contains("in a bend"), "{why}");
    }
}
