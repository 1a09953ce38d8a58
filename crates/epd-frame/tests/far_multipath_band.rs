//! A band of multipath (every ray whose true range lies in [1, 2] m read 5 cm long) in
//! pipes of two sizes. Among the far, grazing rays of a small pipe: few points, much of the
//! information on the diameters; the error they share must reach the 1-σ (the test for
//! errors shared along the axis, `epd_core::fit::form`), or the frame must not be answered
//! `converged` (issue 22: none more than max(5σ̂, 0.5 mm) off). Over the ranges where a
//! large pipe's wall fills most of the view: a straight pipe seen through a ring of range
//! error, not a sensor in a bend (issue 23: ≤ 1 % of straight frames read as a bend or a
//! tee); the survey refits the straight pipe without the ring (`epd_core::scene::segment`)
//! and takes it when it holds.

use std::borrow::Cow;

use epd_core::{Params, errors_against};
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};
use tof_sim::camera::{CameraNoise, MultipathBand};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};

/// An 8" pipe (8.625" outside, 8.18 mm wall, 2 % ovality).
const SMALL: Pipe = Pipe {
    ovality: 0.02,
    nominal_od_in: 8.625,
    wall_thickness: 8.18e-3,
};

/// A 42" pipe (12.7 mm wall, 2 % ovality).
const LARGE: Pipe = Pipe {
    ovality: 0.02,
    nominal_od_in: 42.0,
    wall_thickness: 12.7e-3,
};

/// Frame `k` of `pipe` at one of the paper's random poses, seen by tof-sim's Helios2 model
/// (640 × 480) with σ = 0.02 m and every ray whose true range lies in [1, 2] m read 5 cm
/// long (2.5σ): the frames of `EPD_OD_IN=… EPD_WALL_MM=… cargo run --release -p epd-frame
/// --example coverage -- 40 multipath`.
fn frame(pipe: &Pipe, k: u64) -> (Params, Vec<[f64; 3]>) {
    let truth = PoseRanges::default()
        .sample(pipe, 7, k)
        .expect("a pose of the paper's ranges");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).expect("a valid scene");
    let camera = CameraNoise {
        multipath_bands: vec![MultipathBand {
            near_m: 1.0,
            far_m: 2.0,
            extra_m: 0.05,
        }],
        ..CameraNoise::default()
    };
    let f = tof_sim::simulate_with(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.02),
        &camera,
        Subsample::All,
        FrameSeed {
            seed: 7,
            trial: k,
            sweep_index: 0,
        },
    )
    .expect("a frame");
    (truth, f.measured)
}

/// A frame's verdict: its index, `geometry`, and `None` when answered (`converged`, the
/// estimate not withheld), else its status; and for an answer, its RMS range residual
/// over its 1-σ for σ = 0.02 m and its points, σ/√(2n) (the RMS of n Gaussian residuals).
type Verdict = (u64, Option<&'static str>, Option<&'static str>, Option<f64>);

/// An answered diameter far off: frame, diameter, error (mm), error over its 1-σ.
type FarOff = (u64, &'static str, f64, f64);

/// Frames 0..n of `pipe` measured with `epd estimate`'s defaults: their verdicts and the
/// answered diameters more than max(5σ̂, 0.5 mm) off.
fn measured(pipe: &Pipe, n: u64) -> (Vec<Verdict>, Vec<FarOff>) {
    let cfg = EstimateConfig::new(&EstimateSettings::default()).expect("the defaults are valid");
    let mut frames = Vec::new();
    let mut far = Vec::new();
    for k in 0..n {
        let (truth, points) = frame(pipe, k);
        let input = FrameInput {
            points: Cow::Owned(points),
            intensity: None,
            sigma: None,
            read_ms: 0.0,
        };
        let m = measure_frame(input, &cfg).expect("a full frame is measured");
        let layout = m.geometry.as_ref().map(|g| g.layout);
        let e = &m.estimate;
        if !e.status.is_converged() || m.geometry.as_ref().and_then(|g| g.withheld()).is_some() {
            frames.push((k, layout, Some(e.status.name()), None));
            continue;
        }
        let rms_z = m.rms_residual_mm.map(|rms| {
            let sigma = 20.0;
            (rms - sigma) / (sigma / (2.0 * e.n_points as f64).sqrt())
        });
        frames.push((k, layout, None, rms_z));
        let err = errors_against(&e.params, &truth);
        for (name, err, sigma) in [
            ("Dmax", err.d_max, e.sigma[0]),
            ("Dmin", err.d_min, e.sigma[1]),
        ] {
            let sigma = sigma.expect("a converged fit's diameters have a 1-σ");
            if err.abs() > (5.0 * sigma).max(0.5e-3) {
                far.push((k, name, err * 1e3, err / sigma));
            }
        }
    }
    (frames, far)
}

/// 40 frames of the 8" pipe: the goal allows none converged more than max(5σ̂, 0.5 mm)
/// off in Dmax or Dmin. With the form test on 2¹⁵ strided points
/// (`epd_core::fit::form::FORM_POINTS` before), frame 15 was: Dmin +1.3 mm at 5.1σ̂ (and
/// frames 5 and 30 of the same frames written as text and read by `epd estimate`): the
/// test for errors shared along the axis missed its band, and the 1-σ did not carry it
/// (checked: the test fails with 2¹⁵).
#[test]
fn a_far_band_of_multipath_is_carried_by_the_one_sigma() {
    let (_, far) = measured(&SMALL, 40);
    assert!(
        far.is_empty(),
        "converged far off (frame, diameter, mm, z): {far:?}"
    );
}

/// The fewest of `n` frames that a rate of `p` reaches with probability at most `alpha`
/// (one-sided binomial: P(Bin(n, p) ≥ k) ≤ α).
fn critical_count(n: u64, p: f64, alpha: f64) -> u64 {
    let pmf: Vec<f64> = (0..=n)
        .scan((1.0 - p).powi(n as i32), |term, i| {
            let t = *term;
            *term *= (n - i) as f64 / (i + 1) as f64 * p / (1.0 - p);
            Some(t)
        })
        .collect();
    let mut tail = 0.0;
    for k in (0..=n).rev() {
        if tail + pmf[k as usize] > alpha {
            return k + 1;
        }
        tail += pmf[k as usize];
    }
    0
}

/// 40 straight frames: the goal's rate of straight frames read otherwise, 1 %, reaches
/// the critical count (P(Bin(40, 0.01) ≥ k) ≤ 10⁻³, k = 4) with probability below 10⁻³;
/// before the ring's refit 5 of these 40 read `in_bend` (and 8 of the 120 42" multipath
/// frames of `scenarios/straight_false_alarm.toml`). None of those answered `converged`
/// lies more than max(5σ̂, 0.5 mm) off in Dmax or Dmin (issue 22's goal). And at least
/// half are answered: 3 of 40 converged before the ring's refit (the others `in_bend`,
/// `lack_of_fit` or `implausible`), 40 with it. And each answer's RMS range residual
/// is its own points': within 5 standard errors of σ (44 mm before the ring's points,
/// or the points beyond a refit's cut, were left out of it).
#[test]
fn a_ring_of_multipath_in_a_large_pipe_is_no_bend() {
    let n = 40;
    let (frames, far) = measured(&LARGE, n);
    let misread: Vec<_> = frames.iter().filter(|f| f.1 != Some("straight")).collect();
    let refused: Vec<_> = frames.iter().filter(|f| f.2.is_some()).collect();
    // The straight section's RMS residual is its points' (the ring's left out): within 5
    // of its standard errors of σ (with the ring's points in, 44 mm).
    let off: Vec<_> = frames
        .iter()
        .filter(|f| f.3.is_some_and(|z| z.abs() > 5.0))
        .collect();
    assert!(off.is_empty(), "RMS residual off σ: {off:?}");
    let converged = n as usize - refused.len();
    assert!(
        2 * converged >= n as usize,
        "{converged} of {n} answered; refused: {refused:?}"
    );
    let limit = critical_count(n, 0.01, 1e-3);
    assert_eq!(limit, 4);
    assert!(
        (misread.len() as u64) < limit,
        "{} of {n} straight frames read otherwise: {misread:?}",
        misread.len()
    );
    assert!(
        far.is_empty(),
        "converged far off (frame, diameter, mm, z): {far:?}"
    );
}
