//! The survey of a frame as every front end makes it (`epd_frame::FrameScene::survey`,
//! over `epd_core::segment::survey`) on frames of pipelines with an elbow or a tee ahead
//! (issue 12): the straight section's end, the bend's torus and the straight estimate,
//! against the pipeline's ground truth. Here, beside the frame library, because the
//! frames come from tof-sim, which depends on epd-core (epd-core's own tests cannot use
//! it without a cycle).

use std::f64::consts::FRAC_PI_2;

use epd_core::segment::{Layout, SegmentOptions, Survey, clock_angle_deg, survey};
use epd_core::{EstimateOptions, Loss, Method, Params, estimate};
use epd_frame::FrameScene;
use rayon::prelude::*;
use tof_sim::pipeline::LabeledMesh;
use tof_sim::{
    FrameSeed, MeshResolution, Noise, Pipe, Pipeline, PoseRanges, Scene, Segment, Sensor,
    Subsample, ToFPhysics, simulate,
};

/// The paper's 20" pipe (2 % ovality) with a 90° long-radius elbow (R = 1.5·20" =
/// 762 mm) `ahead` metres in front of the sensor, turning toward φ = 0.7 rad.
fn elbow(ahead: f64) -> Pipeline {
    let pipe = Pipe::paper_20in();
    Pipeline::with_one_bend(
        pipe.d_max(),
        pipe.d_min(),
        -1.0,
        ahead,
        Segment::Bend {
            radius: 1.5 * 20.0 * tof_sim::pipe::INCH,
            angle: FRAC_PI_2,
            direction: 0.7,
        },
        6.0,
    )
}

/// A frame of `pipeline` from the paper's random pose `k`, range noise σ.
fn frame(pipeline: &Pipeline, k: u64, sigma: f64) -> (Vec<[f64; 3]>, Params) {
    let truth = pose(pipeline, k);
    let scene = Scene::pipeline(&truth, pipeline, &MeshResolution::default()).unwrap();
    (cast(&scene, k, sigma), truth)
}

/// Pose `k` of seed 9 ([`PoseRanges::default`] in the paper's pipe) with `pipeline`'s
/// diameters.
fn pose(pipeline: &Pipeline, k: u64) -> Params {
    let mut truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 9, k)
        .unwrap();
    truth.d_max = pipeline.d_max;
    truth.d_min = pipeline.d_min;
    truth
}

/// The measured points of frame `k` of seed 9 through `scene` by the Helios2 sensor, with
/// range noise of `sigma` (m; none at 0), every pixel.
fn cast(scene: &Scene, k: u64, sigma: f64) -> Vec<[f64; 3]> {
    let noise = if sigma > 0.0 {
        Noise::range(sigma)
    } else {
        Noise::none()
    };
    let seed = FrameSeed {
        seed: 9,
        trial: k,
        sweep_index: 0,
    };
    simulate(&Sensor::helios2(), scene, &noise, Subsample::All, seed)
        .unwrap()
        .measured
}

fn options() -> EstimateOptions {
    EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", 0.05).unwrap())
        .unwrap()
}

/// The survey of `points` by ML-EPD with [`options`] as every front end makes it
/// ([`FrameScene::survey`]: the default segment options, no depth table).
fn ml_survey(points: &[[f64; 3]]) -> Survey {
    FrameScene::survey(points, Method::MlEpd, &options(), None)
        .unwrap()
        .survey
}

/// The Helios2 model's range-dependent noise and invalid pixels, without its systematic
/// errors (wiggling, intensity offset, multipath: what a depth table removes).
fn camera_noise() -> Noise {
    Noise {
        physics: Some(ToFPhysics {
            wiggle_amplitude_m: 0.0,
            amplitude_offset_m_per_ln: 0.0,
            multipath_ratio: 0.0,
            ..ToFPhysics::helios2()
        }),
        ..Noise::none()
    }
}

fn mean_diameter_error_mm(est: &Params, truth: &Params) -> f64 {
    0.5e3 * ((est.d_max + est.d_min) - (truth.d_max + truth.d_min))
}

/// tof-sim's 8" pipe (8.2 mm wall, 2 % ovality) under σ = 0.05 m of range noise, half its
/// radius, with `feature` ahead; frames of seed `seed`.
fn small_noisy_pipe(
    seed: u64,
    feature: tof_sim::settings::Feature,
) -> tof_sim::settings::Simulator {
    use tof_sim::settings::{PoseOverride, SimulateSettings, Simulator};
    Simulator::new(&SimulateSettings {
        seed,
        sigma: 0.05,
        od_in: 8.0,
        ovality: 0.02,
        wall_mm: 8.2,
        points: None,
        outliers: 0.0,
        noise: tof_sim::NoiseModel::Range,
        helios2: false,
        pose: PoseOverride::default(),
        feature: Some(feature),
    })
    .unwrap()
}

/// `epd estimate`'s options: the Cauchy loss, its scale from the points.
fn cli_defaults() -> EstimateOptions {
    epd_frame::EstimateConfig::new(&epd_frame::EstimateSettings::default())
        .unwrap()
        .options
}

/// Noise-free frames recover the elbow: its start, radius, tube and direction.
#[test]
fn noise_free_elbow_is_recovered() {
    let p = elbow(1.0);
    let bend = p.first_bend().unwrap();
    for k in 0..2 {
        let (pts, truth) = frame(&p, k, 0.0);
        let s = ml_survey(&pts);
        let seg = &s.segmentation;
        assert_eq!(seg.layout, Layout::BendAhead, "frame {k}");
        let until = seg.straight_until.unwrap();
        assert!(
            (until - 1.0).abs() < 1e-3,
            "frame {k}: straight until {until}"
        );
        let b = s.bend.unwrap();
        let r_err = (b.geometry.radius - bend.radius) / bend.radius;
        assert!(
            r_err.abs() < 1e-3,
            "frame {k}: bend radius {}",
            b.geometry.radius
        );
        let tube = 2.0 * b.geometry.tube_radius - 2.0 * p.bend_tube_radius();
        assert!(
            tube.abs() < 2e-4,
            "frame {k}: tube diameter off by {tube} m"
        );
        let clock = clock_angle_deg(&seg.straight.params, b.geometry.direction);
        let want = clock_angle_deg(&truth, 0.7);
        let diff = (clock - want + 180.0).rem_euclid(360.0) - 180.0;
        assert!(diff.abs() < 0.5, "frame {k}: clock {clock}° vs {want}°");
        let e = mean_diameter_error_mm(&seg.straight.params, &truth);
        assert!(e.abs() < 0.01, "frame {k}: straight estimate off by {e} mm");
    }
}

/// With σ = 30 mm along the rays, the elbow 1 m ahead: the straight estimate on the
/// straight section's points stays within 0.3 mm (the plain fit on every point is off
/// by 0.8–1.8 mm in these frames), its end within 5 cm, the bend radius within 2 %.
#[test]
fn noisy_elbow_is_cut_off_the_straight_estimate() {
    let p = elbow(1.0);
    let mut plain_worst: f64 = 0.0;
    for k in 0..2 {
        let (pts, truth) = frame(&p, k, 0.03);
        let s = ml_survey(&pts);
        let seg = &s.segmentation;
        assert_eq!(seg.layout, Layout::BendAhead, "frame {k}");
        let until = seg.straight_until.unwrap();
        assert!(
            (until - 1.0).abs() < 0.05,
            "frame {k}: straight until {until}"
        );
        let r = s.bend.unwrap().geometry.radius;
        assert!((r / 0.762 - 1.0).abs() < 0.02, "frame {k}: bend radius {r}");
        let e = mean_diameter_error_mm(&seg.straight.params, &truth);
        assert!(e.abs() < 0.3, "frame {k}: straight estimate off by {e} mm");
        let plain = estimate(&pts, Method::MlEpd, &options()).unwrap();
        plain_worst = plain_worst.max(mean_diameter_error_mm(&plain.params, &truth).abs());
    }
    assert!(
        plain_worst > 0.5,
        "the elbow biases the plain fit: {plain_worst} mm"
    );
}

/// [`frame`] through a mesh of `pipeline` built once by the caller (meshing the elbow
/// takes longer than casting a frame through it): the same frame, bit for bit.
fn frame_through(
    mesh: &LabeledMesh,
    pipeline: &Pipeline,
    k: u64,
    sigma: f64,
) -> (Vec<[f64; 3]>, Params) {
    let truth = pose(pipeline, k);
    let mesh = LabeledMesh {
        mesh: mesh.mesh.clone(),
        labels: mesh.labels.clone(),
    };
    let scene = Scene::with_labeled_mesh(&truth, mesh).unwrap();
    (cast(&scene, k, sigma), truth)
}

/// The one-sided binomial test against a rate of ½: the fewest successes of `n` that
/// a rate of ½ reaches with probability at most `alpha`, with that probability
/// (P(Bin(n, ½) ≥ k) = Σᵢ₌ₖⁿ C(n, i)/2ⁿ).
fn least_of(n: u64, alpha: f64) -> (u64, f64) {
    // C(n, i)/2ⁿ from i = 0 up.
    let mut pmf = vec![0.5f64.powi(n as i32)];
    for i in 1..=n {
        let prev = pmf[i as usize - 1];
        pmf.push(prev * (n - i + 1) as f64 / i as f64);
    }
    let mut tail = 0.0;
    for k in (0..=n).rev() {
        if tail + pmf[k as usize] > alpha {
            return (k + 1, tail);
        }
        tail += pmf[k as usize];
    }
    (0, tail)
}

/// With σ = 30 mm along the rays, the elbow 2 and 3 m ahead, seen from afar at a
/// grazing angle: every frame that finds the bend has its radius within the goal's 2 %
/// and its start within 5 cm; a frame that does not find it reads `straight` (no bend,
/// no end: never a tee). (Before the bend model had the oval pipe's joint step, the
/// rays crossing that step met a far part of the ring torus in the model; their jumps
/// held the fit in false minima with x₀ early and R up to 4.5 % high.)
///
/// How often the bend is found is a one-sided binomial test against a detection rate
/// of one half at α = 5 % ([`least_of`]): at 2 m all of 5 frames (a rate of ½ passes
/// with 0.5⁵ = 3.1 %), at 3 m, where the departure is near the detection limit, at
/// least 12 of 16 (P(Bin(16, ½) ≥ 12) = 3.8 %). Measured over more of these poses
/// (`EPD_TEST_FRAMES=40,60 cargo test -p epd-frame --test segmentation -- far_elbow
/// --nocapture`): found in 40 of 40 frames at 2 m, 52 of 60 at 3 m (frames 2, 21, 24,
/// 27, 34, 40, 41 and 58 read `straight`). At that rate, 0.867, a fresh set of 16
/// frames would fail the 3 m count with P(Bin(16, 0.867) ≤ 11) = 5.2 %; these 16
/// find it 15 times.
///
/// The frames run in parallel: 21 frames, ≈ 21 s of CPU.
#[test]
fn a_far_elbow_under_noise_keeps_its_radius() {
    let frames: Vec<u64> = std::env::var("EPD_TEST_FRAMES")
        .ok()
        .map(|v| v.split(',').map(|n| n.trim().parse().unwrap()).collect())
        .unwrap_or_else(|| vec![5, 16]);
    for (ahead, frames) in [2.0, 3.0].into_iter().zip(frames) {
        let (least_found, chance) = least_of(frames, 0.05);
        let p = elbow(ahead);
        let mesh = p.mesh(&MeshResolution::default()).unwrap();
        let surveys: Vec<_> = (0..frames)
            .into_par_iter()
            .map(|k| {
                let (pts, _) = frame_through(&mesh, &p, k, 0.03);
                ml_survey(&pts)
            })
            .collect();
        let mut found = 0;
        for (k, s) in surveys.iter().enumerate() {
            let seg = &s.segmentation;
            if seg.layout == Layout::Straight {
                // Not found: then nothing else was, and the straight runs on.
                eprintln!("{ahead} m, frame {k}: read straight");
                assert!(s.bend.is_none(), "{ahead} m, frame {k}");
                assert_eq!(seg.straight_until, None, "{ahead} m, frame {k}");
                continue;
            }
            found += 1;
            assert_eq!(seg.layout, Layout::BendAhead, "{ahead} m, frame {k}");
            let until = seg.straight_until.unwrap();
            assert!(
                (until - ahead).abs() < 0.05,
                "{ahead} m, frame {k}: straight until {until}"
            );
            let r = s.bend.as_ref().unwrap().geometry.radius;
            assert!(
                (r / 0.762 - 1.0).abs() < 0.02,
                "{ahead} m, frame {k}: bend radius {r}"
            );
        }
        eprintln!(
            "{ahead} m: bend found in {found} of {frames} frames (at least {least_found}: a \
             rate of ½ gets there with {chance:.3})"
        );
        assert!(
            found >= least_found,
            "{ahead} m: bend found in {found} of {frames} frames, fewer than {least_found}"
        );
    }
}

#[test]
fn least_of_is_the_binomial_critical_count() {
    // 0.5⁵ = 0.031; P(Bin(16, ½) ≥ 12) = 2517/65536 = 0.038, ≥ 11: 0.105.
    assert_eq!(least_of(5, 0.05), (5, 0.5f64.powi(5)));
    let (k, p) = least_of(16, 0.05);
    assert_eq!(k, 12);
    assert!((p - 2517.0 / 65536.0).abs() < 1e-15, "{p}");
    assert_eq!(least_of(3, 0.05).0, 4, "3 frames cannot reach 5 %");
}

/// The Helios2 model's range-dependent noise alone (σ ∝ √(A+B)/A: the bend, farther
/// away and seen more obliquely, is several times noisier than the straight section):
/// the elbow 2 m ahead is still found as a bend. Its torus misses by more than twice the
/// straight section's RMS, so only the comparison with the straight wall continued over
/// the same points tells it from a tee; the same comparison keeps a tee a tee.
#[test]
fn range_dependent_noise_keeps_the_elbow_an_elbow() {
    let noise = camera_noise();
    let cast = |p: &Pipeline, k: u64| {
        let scene = Scene::pipeline(&pose(p, k), p, &MeshResolution::default()).unwrap();
        let seed = FrameSeed {
            seed: 9,
            trial: k,
            sweep_index: 1,
        };
        simulate(&Sensor::helios2(), &scene, &noise, Subsample::All, seed)
            .unwrap()
            .measured
    };
    let p = elbow(2.0);
    for k in 0..2 {
        let s = ml_survey(&cast(&p, k));
        assert_eq!(s.segmentation.layout, Layout::BendAhead, "frame {k}");
        let b = s.bend.unwrap();
        assert!(
            b.residual_sigma > 2.0 * s.segmentation.straight.rms_residual,
            "frame {k}: the case the old rule refused ({} vs rms {})",
            b.residual_sigma,
            s.segmentation.straight.rms_residual
        );
        assert!(b.residual_sigma < 0.5 * b.straight_sigma);
        let until = s.segmentation.straight_until.unwrap();
        assert!(
            (until - 2.0).abs() < 0.1,
            "frame {k}: straight until {until}"
        );
    }
    let tee = Pipeline {
        d_max: p.d_max,
        d_min: p.d_min,
        bend_diameter: None,
        start_x: -1.0,
        segments: vec![
            Segment::Straight { length: 2.85 },
            Segment::Tee {
                length: 0.6,
                branch_diameter: 0.3,
                direction: 0.7,
            },
            Segment::Straight { length: 6.0 },
        ],
    };
    for k in 0..2 {
        let s = ml_survey(&cast(&tee, k));
        assert_eq!(s.segmentation.layout, Layout::TeeAhead, "tee frame {k}");
    }
}

/// A tee 2 m ahead: a tee (not a bend), its opening's near edge within 5 cm.
#[test]
fn tee_is_told_from_a_bend() {
    let pipe = Pipe::paper_20in();
    let p = Pipeline {
        d_max: pipe.d_max(),
        d_min: pipe.d_min(),
        bend_diameter: None,
        start_x: -1.0,
        segments: vec![
            Segment::Straight { length: 2.9 },
            Segment::Tee {
                length: 0.8,
                branch_diameter: 0.3,
                direction: 0.7,
            },
            Segment::Straight { length: 6.0 },
        ],
    };
    let want = p.straight_until().unwrap();
    let (pts, _) = frame(&p, 0, 0.03);
    let s = ml_survey(&pts);
    assert_eq!(s.segmentation.layout, Layout::TeeAhead);
    assert!(s.bend.is_none());
    let until = s.segmentation.straight_until.unwrap();
    assert!((until - want).abs() < 0.05, "until {until} vs {want}");
}

/// A tee close ahead, under the camera's noise model (amplitude-dependent σ, its
/// systematic errors, invalid pixels) with the points gated to [0.5, 2] m, as in the
/// pipeline run. Its opening is a hole in the straight wall whose rays run on to the
/// branch's far wall: one or two sectors far outside, the rest on the wall. The
/// survey finds it from the bump 0.75 m ahead (before, from 1.2 m on, these frames read
/// `straight`). 0.5 and 0.35 m ahead the side of the wall with the opening comes into
/// view only at about 0.5 m: the survey never fails, never says `straight`, and either
/// withholds the straight estimate or reports one that the opening did not bias (within
/// 5 of its own 1-σ; one such frame, before the rule on the wall's view, was 9σ off).
#[test]
fn a_close_tee_under_the_cameras_noise_is_found_or_withheld() {
    let noise = camera_noise();
    let pipe = Pipe::paper_20in();
    let tee = |ahead: f64| Pipeline {
        d_max: pipe.d_max(),
        d_min: pipe.d_min(),
        bend_diameter: None,
        start_x: -1.0,
        segments: vec![
            // The opening's near edge lies half the tee's length less the branch's
            // radius past the tee's start.
            Segment::Straight {
                length: 1.0 + ahead - 0.15,
            },
            Segment::Tee {
                length: 0.6,
                branch_diameter: 0.3,
                direction: 1.2,
            },
            Segment::Straight { length: 6.0 },
        ],
    };
    let gated = options().with_range_gate(0.5, 2.0).unwrap();
    let cases = [0.75, 0.75, 0.5, 0.5, 0.5, 0.5, 0.35, 0.35, 0.35, 0.35];
    for (k, ahead) in cases.into_iter().enumerate() {
        let k = k as u64;
        let p = tee(ahead);
        let want = p.straight_until().unwrap();
        assert!((want - ahead).abs() < 1e-9, "the opening at {want}");
        let mut truth = PoseRanges::default().sample(&pipe, 11, k).unwrap();
        truth.d_max = p.d_max;
        truth.d_min = p.d_min;
        let scene = Scene::pipeline(&truth, &p, &MeshResolution::default()).unwrap();
        let seed = FrameSeed {
            seed: 11,
            trial: k,
            sweep_index: 2,
        };
        let f = simulate(&Sensor::helios2(), &scene, &noise, Subsample::All, seed).unwrap();
        let s = FrameScene::survey(&f.measured, Method::MlEpd, &gated, None)
            .unwrap_or_else(|e| panic!("{ahead} m, frame {k}: {e}"))
            .survey;
        let seg = &s.segmentation;
        if ahead > 0.6 {
            assert_eq!(seg.layout, Layout::TeeAhead, "{ahead} m, frame {k}");
            assert!(!seg.straight_withheld, "{ahead} m, frame {k}");
            let until = seg.straight_until.unwrap();
            assert!((until - want).abs() < 0.05, "frame {k}: until {until}");
        } else {
            assert_ne!(seg.layout, Layout::Straight, "{ahead} m, frame {k}");
            if !seg.straight_withheld {
                // Reported: then it is the straight pipe's, within 5 of its own 1-σ.
                let (s0, s1) = (
                    seg.straight.sigma[0].unwrap(),
                    seg.straight.sigma[1].unwrap(),
                );
                let err = mean_diameter_error_mm(&seg.straight.params, &truth);
                assert!(
                    err.abs() <= 5.0 * 0.5e3 * (s0 + s1),
                    "{ahead} m, frame {k}: reported {err:.3} mm off, 1-σ {:.3}/{:.3} mm",
                    s0 * 1e3,
                    s1 * 1e3
                );
            }
        }
    }
}

/// An 8" pipe (8.2 mm wall) under 5 cm of range noise — half its radius, the goal's
/// noisiest case — with a long-radius elbow 0.5 m ahead (`epd simulate --od-in 8
/// --wall-mm 8.2 --bend-at 0.5 --sigma 0.05 --seed 31`, 20 frames): no frame reads
/// `straight` with a straight estimate fitted to every point, the elbow's included.
/// The fit on every point is dragged by the elbow and its 1-σ inflated until nothing
/// departs; the survey then restarts from the near points. Its windows were 1.0 and
/// 0.6 m, which on this pipe hold the whole frame: 3 of these 20 frames read `straight`,
/// "converged", on every point. They are now the nearest 85 % and 60 % of the points
/// (`epd_core::segment::RESTART_NEAREST_SHARE`). Before the check of the noise judged
/// the points' scatter across the axis (`epd_core::check::MAX_NOISE_TO_RADIUS`), every
/// one of these frames was refused. Not yet right: frame 7 reads `straight` on a fit of
/// the near wall alone (0.1–0.17 m), where the elbow's departure vanished for want of
/// power, and that fit's Dmin is 5.8 of its 1-σ off. ≈ 20 s of CPU.
#[test]
fn a_close_elbow_in_a_small_noisy_pipe_is_not_fitted_as_straight() {
    use tof_sim::settings::Feature;
    let sim = small_noisy_pipe(31, Feature::BendAt(0.5));
    let defaults = cli_defaults();
    let read: Vec<(Layout, bool, bool)> = (0..20u64)
        .into_par_iter()
        .map(|k| {
            let mut f = tof_sim::Frame::empty();
            sim.frame(k, &mut f).unwrap();
            let scene = FrameScene::survey(&f.measured, Method::MlEpd, &defaults, None).unwrap();
            let seg = &scene.survey.segmentation;
            (
                seg.layout,
                seg.straight.status.is_converged(),
                seg.straight.n_points + seg.straight.n_dropped == f.measured.len(),
            )
        })
        .collect();
    let found = read.iter().filter(|r| r.0 == Layout::BendAhead).count();
    eprintln!("8\" elbow 0.5 m ahead, σ 0.05 m: bend_ahead in {found} of 20 frames");
    for (k, (layout, converged, every_point)) in read.into_iter().enumerate() {
        assert!(
            !(layout == Layout::Straight && converged && every_point),
            "frame {k}: read straight, converged, on every point"
        );
    }
}

/// Nothing but straight pipe in view (the elbow beyond the 6 m range): the survey
/// says so and its estimate is the plain one, bit for bit.
#[test]
fn straight_pipe_stays_the_plain_estimate() {
    let p = elbow(8.0);
    let (pts, _) = frame(&p, 0, 0.03);
    let s = ml_survey(&pts);
    assert_eq!(s.segmentation.layout, Layout::Straight);
    assert_eq!(s.segmentation.straight_until, None);
    let plain = estimate(&pts, Method::MlEpd, &options()).unwrap();
    assert_eq!(s.segmentation.straight.params, plain.params);
}

#[test]
fn bad_options_are_refused() {
    let o = SegmentOptions {
        slice_m: 0.0,
        ..SegmentOptions::default()
    };
    let err = survey(&[[1.0, 0.0, 0.0]; 10], Method::MlEpd, &options(), &o).unwrap_err();
    assert!(err.to_string().contains("slice_m"), "{err}");
}

/// A dent on a straight pipe (tof-sim's Gaussian dent, 25 mm deep at 1.0 m ahead, axial
/// and circumferential extent σ 0.15 m, at clock angle φ_d, σ = 0.02 m): the wall comes
/// inward on one side and back, which is neither a tee (whose opening lies outside the
/// wall) nor a bend. Every frame reads `straight` with the dent: where it is deepest within
/// one axial σ of its centre; its clock angle within half a sector (15°) of φ_d; its depth
/// a sector's median, so at most the depth (plus 4 of the sector median's standard
/// errors, 0.6 mm at this noise) and, the dent being wider than a sector (a 30° sector is
/// 0.13 m of wall), at least half of it. The straight estimate, on the points before the
/// dent, lies within max(5σ̂, 0.5 mm) of the truth (issue 22's bound).
#[test]
fn a_dent_is_neither_a_tee_nor_a_bend() {
    let (depth, x_d, phi_d) = (0.025, 1.0, 2.0);
    let dents: Vec<_> = (0..6u64)
        .into_par_iter()
        .map(|k| dented_survey(11, k, depth, phi_d))
        .collect();
    for (k, (s, truth)) in dents.iter().enumerate() {
        assert_eq!(s.segmentation.layout, Layout::Straight, "frame {k}");
        let d = s.dent.unwrap_or_else(|| panic!("frame {k}: no dent"));
        assert!(
            (d.at_m - x_d).abs() <= 0.15,
            "frame {k}: deepest at {}",
            d.at_m
        );
        let want = clock_angle_deg(truth, FRAC_PI_2 - phi_d);
        let off = (d.clock_deg - want + 180.0).rem_euclid(360.0) - 180.0;
        assert!(
            off.abs() <= 15.0,
            "frame {k}: clock {} vs {want}",
            d.clock_deg
        );
        assert!(
            d.depth_m <= depth + 4.0 * 0.6e-3 && d.depth_m >= 0.5 * depth,
            "frame {k}: depth {}",
            d.depth_m
        );
        assert!(s.segmentation.straight_until.is_some_and(|x| x < d.at_m));
        let est = &s.segmentation.straight;
        for (got, want, sigma) in [
            (est.params.d_max, truth.d_max, est.sigma[0]),
            (est.params.d_min, truth.d_min, est.sigma[1]),
        ] {
            let bound = (5.0 * sigma.unwrap_or(f64::INFINITY)).max(0.5e-3);
            assert!(
                (got - want).abs() <= bound,
                "frame {k}: {got} vs {want} ± {bound}"
            );
        }
    }
}

/// The straight estimate before a dent leaves the dent's flank out: over 40 poses of
/// tof-sim's Gaussian dent (25 mm deep 1.0 m ahead, extent σ 0.15 m, 20" pipe, 2 %
/// ovality, σ = 0.02 m, full frames), Dmin's ±1.96σ covers its error in at least 33
/// frames: the goal's 0.90 less two of its binomial standard errors at 40 frames,
/// 0.90 − 2·√(0.9·0.1/40) = 0.805. With the flank's onset sought over the three slices
/// before the departure only, 31 of these 40 were covered.
#[test]
fn a_dents_flank_is_left_out_of_the_straight_estimate() {
    let n = 40u64;
    let covered: usize = (0..n)
        .into_par_iter()
        .map(|k| {
            let (s, truth) = dented_survey(23, k, 0.025, 0.0);
            assert!(s.dent.is_some(), "frame {k}: no dent");
            let est = &s.segmentation.straight;
            let sigma = est.sigma[1].unwrap_or(0.0);
            usize::from((est.params.d_min - truth.d_min).abs() <= 1.96 * sigma)
        })
        .sum();
    eprintln!("Dmin covered in {covered} of {n} dented frames");
    assert!(covered >= 33, "Dmin covered in {covered} of {n}");
}

/// The survey of frame `k` (seed `seed`) of tof-sim's Gaussian dent `depth` m deep,
/// 1.0 m ahead at clock angle `clock_rad`, extent σ 0.15 m along and around, in a 20"
/// pipe with 2 % ovality (σ = 0.02 m, full frames), and the frame's truth.
fn dented_survey(seed: u64, k: u64, depth: f64, clock_rad: f64) -> (Survey, Params) {
    use tof_sim::contamination::{Contamination, Dent};
    use tof_sim::{WallModel, simulate_with};
    let pipe = Pipe {
        ovality: 0.02,
        ..Pipe::paper_20in()
    };
    let truth = PoseRanges::default().sample(&pipe, seed, k).unwrap();
    let scene = Scene::new(&truth, WallModel::Exact, 6.0)
        .and_then(|s| {
            s.with_contamination(Contamination {
                dent: Some(Dent {
                    x_m: 1.0,
                    clock_rad,
                    depth_m: depth,
                    axial_sigma_m: 0.15,
                    circumferential_sigma_m: 0.15,
                }),
                ..Contamination::default()
            })
        })
        .unwrap();
    let f = simulate_with(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.02),
        &Default::default(),
        Subsample::All,
        FrameSeed {
            seed,
            trial: k,
            sweep_index: 0,
        },
    )
    .unwrap();
    (ml_survey(&f.measured), truth)
}

/// The straight pipe the profile tests against (`epd_core::segment::axis_under_straight_pipe`)
/// on tof-sim's 8" pipe under σ = 0.05 m, `epd estimate`'s options, the axis's lateral
/// standard error 1 m ahead. A factor 2 in a standard error is a factor 4 in a variance,
/// far beyond the sampling error of one frame's cell jackknife (about √(2/95) ≈ 0.15 of
/// the variance over its 96 cells): on the straight frames (the elbow beyond the
/// camera's 6 m range) the straight pipe's lies within a factor 2 of the fit's own (some
/// frames take the fit within the limit: the camera's range drops the points whose noise
/// carries them beyond it, so that those kept near it lie short of the wall, a tail
/// Gaussian noise does not have — 93 points against 31 expected in one frame); with the
/// elbow 1 m ahead the fit's own is more than twice the straight frame's (the elbow's
/// points widen it; asserted so the test is not vacuous) and the straight pipe's less
/// than half the fit's own. Measured: straight 0.05–0.06 mm; with the elbow, own
/// 4.4–155 mm, the straight pipe's 0.75–0.99 mm (the elbow's points within the limit
/// still widen it).
#[test]
fn the_profile_tests_against_the_straight_walls_axis() {
    use epd_core::segment::{AxisSigma, axis_under_straight_pipe};
    use tof_sim::settings::{Feature, Simulator};
    let defaults = cli_defaults();
    let (elbow, straight) = (
        small_noisy_pipe(41, Feature::BendAt(1.0)),
        small_noisy_pipe(41, Feature::BendAt(9.0)),
    );
    let se_at_1m = |a: &AxisSigma| {
        let [vy, vz] = a.lateral_variance(1.0);
        (vy + vz).sqrt()
    };
    // A fit the form test refuses has no axis 1-σ of its own (it counts as known): such
    // frames are left out, and at least 4 of 6 must remain.
    let rows: Vec<Option<(f64, f64, f64)>> = (0..6u64)
        .into_par_iter()
        .map(|k| {
            let measure = |s: &Simulator| {
                let mut f = tof_sim::Frame::empty();
                s.frame(k, &mut f).unwrap();
                let fit = estimate(&f.measured, Method::MlEpd, &defaults).unwrap();
                let against = axis_under_straight_pipe(&f.measured, &fit, Method::MlEpd, &defaults);
                (!matches!(fit.status, epd_core::FitStatus::LackOfFit(_))).then_some((fit, against))
            };
            let (fit, against) = measure(&straight)?;
            let (own, under_straight) = (se_at_1m(&AxisSigma::of(&fit)), se_at_1m(&against.1));
            assert!(
                under_straight <= 2.0 * own && under_straight >= 0.5 * own,
                "straight frame {k}: {under_straight} against {own}"
            );
            let (e_fit, e_against) = measure(&elbow)?;
            Some((
                own,
                se_at_1m(&AxisSigma::of(&e_fit)),
                se_at_1m(&e_against.1),
            ))
        })
        .collect();
    assert!(rows.iter().flatten().count() >= 4, "{rows:?}");
    for (k, &(straight_se, own, under_straight)) in rows
        .iter()
        .enumerate()
        .filter_map(|(k, r)| Some((k, r.as_ref()?)))
    {
        eprintln!(
            "frame {k}: straight {:.2} mm; elbow 1 m ahead: own {:.2} mm, straight wall's {:.2} mm",
            straight_se * 1e3,
            own * 1e3,
            under_straight * 1e3
        );
        assert!(
            own > 2.0 * straight_se,
            "frame {k}: the elbow does not widen the fit's own"
        );
        assert!(
            under_straight < 0.5 * own,
            "frame {k}: the straight pipe's {under_straight} against the fit's own {own}"
        );
    }
}
