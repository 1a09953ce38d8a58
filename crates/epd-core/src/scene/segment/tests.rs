//! The survey's tests (`segment`): the departure rules on crafted profiles (a bump, a
//! lone slice, a growing shift), the tests' level and evidence under clustered noise, and
//! an invalid cloud's dropped points.

use super::*;
use crate::scene::profile::{ROBUST_DOF_SHARE, calibrate_tests, critical_values, slice_stats};
use crate::scene::uniforms;

/// A slice at `x` with a shift (m) toward +Y and a bump (m), standard errors 0.1 mm,
/// tested as one of 12 slices of 12 sectors.
fn slice(x: f64, shift: f64, bump: f64) -> Slice {
    let (critical_f, critical_t) = critical_values(12, 12.0 * 9.0 * ROBUST_DOF_SHARE - 2.0, 12);
    Slice {
        start_m: x,
        n_points: 1000,
        n_sectors: 12,
        widening_m: 0.0,
        shift_m: [shift, 0.0],
        shift_se_m: 1e-4,
        opposite_m: -shift,
        bump_m: bump,
        bump_se_m: 1e-4,
        bump_psi: 0.5,
        bump_follows_wall: true,
        variance_ratio: 1.0,
        shift_cov_m2: [1e-8, 0.0, 1e-8],
        misfit_dof: 9,
        variance_scale: 1.0,
        departure_p: f64::NAN,
        shift_f: 0.5 * (shift / 1e-4).powi(2),
        critical_f,
        critical_t,
        ..Slice::empty(x)
    }
}

/// Slices of a straight pipe whose points share one error per (slice, sector) cell
/// (a cluster: what correlated range noise does to a sector's median) of standard
/// deviation `tau` (m) beside independent noise σ = 20 mm, plus a lateral `shift` (m)
/// toward +Y in slice 7. Points: 60 per sector.
fn clustered_profile(rng: &mut impl FnMut() -> f64, tau: f64, shift: f64) -> Vec<Slice> {
    let (ns, n, sigma) = (12, 60, 0.02);
    let normal = |rng: &mut dyn FnMut() -> f64| {
        // Box–Muller from two uniforms.
        let (u, v) = (rng().max(1e-300), rng());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    };
    let o = SegmentOptions::default();
    let mut slices: Vec<Slice> = (0..16)
        .map(|i| {
            let cells: Vec<Vec<f32>> = (0..ns)
                .map(|k| {
                    let psi = (k as f64 + 0.5) / ns as f64 * std::f64::consts::TAU;
                    let lateral = if i == 7 { shift * psi.cos() } else { 0.0 };
                    let shared = tau * normal(rng) + lateral;
                    (0..n)
                        .map(|_| (shared + sigma * normal(rng)) as f32)
                        .collect()
                })
                .collect();
            slice_stats(&cells, 0.05 * i as f64, &o)
        })
        .collect();
    calibrate_tests(&mut slices, ns, &AxisSigma::default(), 0.05);
    slices
}

/// The level of the departure tests under clustered noise whose shared part is 3× the
/// median's independent standard error (a variance scale κ ≈ 10): over 2000 straight
/// profiles at most [`SURVEY_FALSE_ALARM`] + 4 binomial standard errors depart
/// (≤ 0.0038, i.e. ≤ 7 frames); the medians' independent variances alone would flag
/// most of them (checked: the unscaled shift F exceeds its critical value in most
/// frames), so the test can fail.
#[test]
fn clustered_noise_keeps_the_false_alarm_rate() {
    let o = SegmentOptions::default();
    let mut rng = uniforms(23);
    let se_median = (std::f64::consts::FRAC_PI_2 * 0.02f64.powi(2) / 60.0).sqrt();
    let tau = 3.0 * se_median;
    let frames = 2000;
    let (mut departed, mut naive) = (0, 0);
    for _ in 0..frames {
        let prof = clustered_profile(&mut rng, tau, 0.0);
        departed += prof.iter().any(|s| {
            s.departs(&SegmentOptions {
                min_shift_m: 0.0,
                ..o
            })
        }) as usize;
        // The same slices judged with the independent-point variances.
        naive += prof
            .iter()
            .any(|s| s.shift_f * s.variance_scale > s.critical_f) as usize;
    }
    let bound = SURVEY_FALSE_ALARM
        + 4.0 * (SURVEY_FALSE_ALARM * (1.0 - SURVEY_FALSE_ALARM) / frames as f64).sqrt();
    assert!(
        (departed as f64) <= bound * frames as f64,
        "{departed} of {frames} straight profiles departed (bound {bound})"
    );
    assert!(naive > frames / 2, "unscaled: {naive} of {frames}");
}

/// The departure p-value is the tests' statistic on another scale: in every tested
/// slice of 500 straight profiles and 200 with a shift of 8 scaled standard errors
/// (clustered noise as above), it falls below [`SURVEY_FALSE_ALARM`] exactly when the
/// shift's F or the bump's t exceeds its critical value; the straight frames' evidence
/// reaches 3 no more often than the false-alarm bound above allows, the shifted ones'
/// in most frames.
#[test]
fn the_departure_evidence_is_the_tests_p_value() {
    let mut rng = uniforms(31);
    let se_median = (std::f64::consts::FRAC_PI_2 * 0.02f64.powi(2) / 60.0).sqrt();
    let tau = 3.0 * se_median;
    let se_shift = ((se_median.powi(2) + tau * tau) / 6.0).sqrt();
    let level = -SURVEY_FALSE_ALARM.log10();
    let (mut straight_alarms, mut shifted_found, mut checked) = (0, 0, 0);
    for k in 0..700 {
        let shift = if k < 500 { 0.0 } else { 8.0 * se_shift };
        let prof = clustered_profile(&mut rng, tau, shift);
        for s in prof.iter().filter(|s| !s.departure_p.is_nan()) {
            let by_stat = s.shift_f > s.critical_f || s.bump_m > s.critical_t * s.bump_se_m;
            // Away from the boundary, where rounding of the two routes could differ.
            let near = (s.departure_p / SURVEY_FALSE_ALARM - 1.0).abs() < 1e-6;
            if !near {
                assert_eq!(s.departure_p < SURVEY_FALSE_ALARM, by_stat, "{s:?}");
                checked += 1;
            }
        }
        let evidence = departure_evidence(&prof);
        assert!(evidence >= 0.0 && evidence.is_finite());
        if k < 500 {
            straight_alarms += usize::from(evidence >= level);
        } else {
            shifted_found += usize::from(evidence >= level);
        }
    }
    assert!(checked > 700 * 12, "{checked} slices checked");
    let bound = SURVEY_FALSE_ALARM + 4.0 * (SURVEY_FALSE_ALARM / 500.0).sqrt();
    assert!(
        (straight_alarms as f64) <= bound * 500.0,
        "{straight_alarms} of 500"
    );
    assert!(shifted_found > 100, "{shifted_found} of 200");
}

/// Power: a lateral shift of 10 scaled standard errors in one slice (under the same
/// clustered noise) departs in at least 99 % of 500 profiles, at that slice.
#[test]
fn a_clear_shift_departs_under_clustered_noise() {
    let o = SegmentOptions {
        min_shift_m: 0.0,
        ..SegmentOptions::default()
    };
    let mut rng = uniforms(29);
    let se_median = (std::f64::consts::FRAC_PI_2 * 0.02f64.powi(2) / 60.0).sqrt();
    let tau = 3.0 * se_median;
    // The shift's standard error: the harmonic fit of 12 equal-variance medians gives
    // Var(c₁) = 2·v/12, v the median's total variance.
    let se_shift = ((se_median.powi(2) + tau * tau) / 6.0).sqrt();
    let frames = 500;
    let found = (0..frames)
        .filter(|_| {
            let prof = clustered_profile(&mut rng, tau, 10.0 * se_shift);
            prof[7].departs(&o)
        })
        .count();
    assert!(found * 100 >= 99 * frames, "{found} of {frames}");
}

#[test]
fn a_bump_departs_and_is_a_tee_that_resumes() {
    let o = SegmentOptions::default();
    // Wall, an opening (bumps of 30 mm) over three slices, wall again.
    let mut prof: Vec<Slice> = (0..12).map(|i| slice(0.05 * i as f64, 0.0, 0.0)).collect();
    for s in &mut prof[4..7] {
        s.bump_m = 0.03;
    }
    // The slice before the opening: a weak bump (5σ, under min_shift) on its side.
    prof[3].bump_m = 5e-4;
    let i = first_departure(&prof, &o).unwrap();
    assert_eq!(i, 4);
    assert!(!prof[i].shifts(&o) && prof[i].bumps(&o));
    assert_eq!(opening_slice(&prof, i), 3);
    assert_eq!(locate_end(&prof, i, &o), prof[3].start_m);
    assert_eq!(classify(&prof[i..], &o), Layout::TeeAhead);
    assert!(resumes(&prof[i..], &o, 0.5));
    // Three slices of wall after it are not enough to say it resumes, nor is a wall
    // farther than `within` from the departure.
    assert!(!resumes(&prof[i..10], &o, 0.5));
    assert!(!resumes(&prof[i..], &o, 0.1));
    // Nor a wall well inside the straight one (a bend's tube, turned away).
    let mut inside = prof.clone();
    for s in &mut inside[7..] {
        s.widening_m = -0.05;
    }
    assert!(!resumes(&inside[i..], &o, 0.5));
}

/// An opening confirmed as a departure is: a significant bump in each of the
/// `persistence` slices from the departure (30 mm at 0.1 mm standard error); a shift
/// alone (a multipath band's edge), a bump in one slice of the run, or a run cut short by
/// the profile's end is not.
#[test]
fn an_opening_needs_a_bump_in_every_slice_of_the_run() {
    let o = SegmentOptions::default();
    assert_eq!(o.persistence, 2);
    let wall: Vec<Slice> = (0..12).map(|i| slice(0.05 * i as f64, 0.0, 0.0)).collect();
    let mut bumps = wall.clone();
    for s in &mut bumps[4..8] {
        s.bump_m = 0.03;
    }
    assert!(opens_ahead(&bumps, 4, &o));
    assert!(opens_ahead(&bumps, 6, &o));
    let mut shifts = wall.clone();
    for (k, s) in shifts.iter_mut().enumerate().skip(4).take(4) {
        *s = slice(0.05 * k as f64, 0.01, 0.0);
    }
    assert!(shifts[4].departs(&o) && !opens_ahead(&shifts, 4, &o));
    let mut once = shifts.clone();
    once[4].bump_m = 0.03;
    assert!(!opens_ahead(&once, 4, &o));
    assert!(!opens_ahead(&bumps[..5], 4, &o));
}

/// One slice that shifts (10 mm at 0.1 mm standard error) departs alone only when its
/// adjusted p-value is below α² and the slice after it has too few sectors to be
/// judged; a judged slice after it that does not depart, or a p-value above α², leaves
/// the frame straight.
#[test]
fn a_lone_slice_departs_where_its_next_cannot_confirm_it() {
    let o = SegmentOptions::default();
    let mut prof: Vec<Slice> = (0..12).map(|i| slice(0.05 * i as f64, 0.0, 0.0)).collect();
    prof[6] = slice(0.3, 0.01, 0.0);
    for (p, next_sectors, departs) in [
        (1e-7, 4, true),
        (1e-7, 12, false),
        (1e-5, 4, false),
        (1e-5, 12, false),
    ] {
        prof[6].departure_p = p;
        prof[7].n_sectors = next_sectors;
        assert!(prof[6].departs(&o));
        let found = first_departure(&prof, &o);
        assert_eq!(
            found == Some(6),
            departs,
            "p {p}, next {next_sectors} sectors"
        );
        assert!(found.is_none() || found == Some(6));
    }
}

/// A bump in one slice (30 mm outside the harmonic at 0.1 mm standard error: an
/// opening's near edge) departs alone though the slices after it are judged and on the
/// wall; a shift of the same size there does not (the previous test), nor does a bump
/// below its critical value.
#[test]
fn a_lone_bump_departs() {
    let o = SegmentOptions::default();
    let mut prof: Vec<Slice> = (0..12).map(|i| slice(0.05 * i as f64, 0.0, 0.0)).collect();
    prof[6] = slice(0.3, 0.0, 0.03);
    assert!(prof[6].bumps(&o) && !prof[7].departs(&o) && prof[7].n_sectors == 12);
    assert_eq!(first_departure(&prof, &o), Some(6));
    prof[6].bump_m = 0.5 * prof[6].critical_t * prof[6].bump_se_m;
    assert_eq!(first_departure(&prof, &o), None);
}

#[test]
fn a_growing_shift_never_resumes() {
    let o = SegmentOptions::default();
    // A bend: the shift grows as (x − x₀)²/(2R) past x₀ = 0.2 m, R = 0.76 m.
    let prof: Vec<Slice> = (0..20)
        .map(|i| {
            let x = 0.05 * i as f64;
            slice(x, (x - 0.2).max(0.0).powi(2) / 1.52, 0.0)
        })
        .collect();
    let i = first_departure(&prof, &o).unwrap();
    assert!(prof[i].shifts(&o));
    assert!(!resumes(&prof[i..], &o, 1.0));
    assert_eq!(classify(&prof[i..], &o), Layout::BendAhead);
}

/// A cloud of invalid points only (NaN, ±inf, the origin) is refused as `estimate`
/// refuses it: every point counted as dropped.
#[test]
fn an_invalid_cloud_counts_its_points_as_dropped() {
    let mut pts = vec![[f64::NAN, 0.0, 0.0]; 50];
    pts.extend(vec![[f64::INFINITY, 1.0, 0.0]; 30]);
    pts.extend(vec![[0.0; 3]; 20]);
    let o = EstimateOptions::default();
    let seg = segment(&pts, Method::MlEpd, &o, &SegmentOptions::default()).unwrap_err();
    let plain = estimate(&pts, Method::MlEpd, &o).unwrap_err();
    assert!(
        matches!(
            seg,
            EpdError::TooFewPoints {
                usable: 0,
                dropped: 100,
                ..
            }
        ),
        "{seg:?}"
    );
    assert_eq!(seg.to_string(), plain.to_string());
}

/// A lone departing slice that bumps and also shifts (an opening whose far rays pull the
/// slice's medians aside; the slices after it back on the pipe) starts at its near edge,
/// as a bump alone does — not three slices early, where the onset search begins and
/// where every onset fits alike (no parabola explains a shift that does not persist). A
/// lone shift without a bump (departing at α^persistence with the slices after it
/// unjudged) starts at its near edge too; a growing shift still has its onset fitted.
#[test]
fn a_lone_shifting_slice_starts_at_its_edge() {
    let o = SegmentOptions::default();
    for shift in [0.003, 0.01, 0.03] {
        let mut prof: Vec<Slice> = (0..12).map(|i| slice(0.05 * i as f64, 0.0, 0.0)).collect();
        prof[6] = slice(0.3, shift, 0.03);
        assert!(prof[6].shifts(&o) && prof[6].bumps(&o));
        assert_eq!(first_departure(&prof, &o), Some(6));
        let end = locate_end(&prof, 6, &o);
        assert!((end - 0.3).abs() < 1e-9, "shift {shift}: end {end}");
        // Without the bump.
        prof[6].bump_m = 0.0;
        let end = locate_end(&prof, 6, &o);
        assert!(
            (end - 0.3).abs() < 1e-9,
            "shift {shift}, no bump: end {end}"
        );
    }
    // A shift that grows from x₀ = 0.3 m on (a bend, R = 0.76 m) still has its onset
    // found by the fit, within a slice.
    let prof: Vec<Slice> = (0..12)
        .map(|i| {
            let x = 0.05 * i as f64;
            slice(x, (x + 0.025 - 0.3).max(0.0).powi(2) / 1.52, 0.0)
        })
        .collect();
    let i = first_departure(&prof, &o).expect("departs");
    let end = locate_end(&prof, i, &o);
    assert!((end - 0.3).abs() <= o.slice_m, "bend: end {end}");
    // The bend's next slice not judged (too few sectors), below its own test, or out of
    // view: not a lone slice, the onset is still fitted.
    let mut unjudged = prof.clone();
    unjudged[i + 1].n_sectors = MIN_SECTORS_TESTED - 1;
    let mut weak = prof.clone();
    weak[i + 1].shift_f = 0.5 * weak[i + 1].critical_f;
    assert!(!weak[i + 1].shifts(&o));
    let ends = prof[..=i].to_vec();
    for (name, p) in [("unjudged", unjudged), ("weak", weak), ("ends", ends)] {
        let end = locate_end(&p, i, &o);
        assert!(
            (end - 0.3).abs() <= o.slice_m,
            "bend, next slice {name}: end {end}"
        );
    }
}

/// A run whose wall's least half lies out, by more than half the run's departure and many
/// of its standard errors, reads wider all around (`widens_all_around`); an opening
/// (a bump, the rest of the wall on it), a bend (a shift, its far half in), an opening
/// beside a least half out by a sliver of its size, and a ring within its noise do not.
#[test]
fn only_a_wall_out_all_around_is_a_ring() {
    let o = SegmentOptions::default();
    // Eight straight slices, then eight departing ones of `shift`, `bump` and least half
    // `least` (m), its standard error `se` (m).
    let run = |shift: f64, bump: f64, least: f64, se: f64| -> Vec<Slice> {
        (0..16)
            .map(|k| {
                let x = 0.4 + 0.05 * k as f64;
                let (s, b, l, v) = if k < 8 {
                    (0.0, 0.0, 0.0, 1e-8)
                } else {
                    (shift, bump, least, se * se)
                };
                Slice {
                    least_half_m: l,
                    least_half_var_m2: v,
                    ..slice(x, s, b)
                }
            })
            .collect()
    };
    let departs_at_8 = |p: &[Slice]| assert!(p[8].departs(&o) && !p[7].departs(&o));
    let ring = run(0.004, 0.0, 0.015, 1e-4);
    departs_at_8(&ring);
    assert!(widens_all_around(&ring, 8, &o), "a ring");
    let opening = run(0.0, 0.05, 0.0, 1e-4);
    departs_at_8(&opening);
    assert!(!widens_all_around(&opening, 8, &o), "an opening");
    let bend = run(0.004, 0.0, -0.004, 1e-4);
    assert!(!widens_all_around(&bend, 8, &o), "a bend");
    // 0.2 mm out at 20 standard errors beside a 50 mm bump: a misfit, not a ring.
    let sliver = run(0.0, 0.05, 0.0002, 1e-5);
    assert!(
        !widens_all_around(&sliver, 8, &o),
        "a sliver beside an opening"
    );
    // 15 mm out with a standard error of 30 mm per slice: 1.4 standard errors over eight.
    let noisy = run(0.004, 0.0, 0.015, 0.03);
    departs_at_8(&noisy);
    assert!(!widens_all_around(&noisy, 8, &o), "a ring within its noise");
    // The ring's slices seen on too few sectors for the medians' tests, departing by an
    // opening in their sparse cells: their least halves hold only the sectors with
    // medians, and the run is no ring.
    let partial: Vec<Slice> = ring
        .iter()
        .map(|s| Slice {
            n_sectors: MIN_SECTORS_TESTED - 1,
            opening_p: 0.0,
            ..*s
        })
        .collect();
    assert!(partial[8].departs(&o));
    assert!(
        !widens_all_around(&partial, 8, &o),
        "a ring seen on few sectors"
    );
}

/// A ring of range error's run (`ring_run`): the slices whose every half lies out, grown
/// by the departing slices beside it; none for a bend (its far half in), for an opening
/// (the rest of its wall on it), for a ring shorter than the persistence or within its
/// noise.
#[test]
fn a_ring_run_is_the_wall_out_all_around_and_its_departing_edges() {
    let o = SegmentOptions::default();
    // Slices 0–2 on the wall, 3 departing by a shift (the band's edge), 4–9 out all
    // around by 12 mm at `se`, 10 departing, 11–15 on the wall.
    let profile = |least: f64, se: f64, shift: f64, bump: f64| -> Vec<Slice> {
        (0..16)
            .map(|k| {
                let x = 0.5 + 0.05 * k as f64;
                let (s, b, l) = match k {
                    3 | 10 => (0.005, 0.0, 0.0),
                    4..=9 => (shift, bump, least),
                    _ => (0.0, 0.0, 0.0),
                };
                Slice {
                    least_half_m: l,
                    least_half_var_m2: se * se,
                    ..slice(x, s, b)
                }
            })
            .collect()
    };
    assert_eq!(ring_run(&profile(0.012, 5e-4, 0.0, 0.0), &o), Some((3, 11)));
    assert_eq!(
        ring_run(&profile(-0.004, 5e-4, 0.004, 0.0), &o),
        None,
        "a bend"
    );
    assert_eq!(
        ring_run(&profile(0.0, 5e-4, 0.0, 0.05), &o),
        None,
        "an opening"
    );
    // 12 mm out beside a 100 mm shift: an opening seen in part (least halves of a few
    // sectors), not a ring.
    assert_eq!(
        ring_run(&profile(0.012, 5e-4, 0.1, 0.0), &o),
        None,
        "a partial opening"
    );
    // 12 mm with a standard error of 10 mm per slice: within its noise.
    assert_eq!(ring_run(&profile(0.012, 0.01, 0.0, 0.0), &o), None, "noise");
    // One slice out: shorter than the persistence.
    let mut short = profile(0.0, 5e-4, 0.0, 0.0);
    short[6].least_half_m = 0.012;
    assert_eq!(ring_run(&short, &o), None, "one slice");
}
