//! Where a branch opening begins along the pipe, to within the points' spacing rather
//! than a slice, and how sure that is: a change point in one side's exceedances, with
//! its profile-likelihood interval.
//!
//! A ray that crosses a branch opening runs on to the branch's far wall, so its point
//! lies far outside the straight pipe's wall (its deviation d ≫ σ); before the opening
//! such points occur only as the noise's far tail. Along the axis, on the side of the
//! opening, the indicator zᵢ = [dᵢ > c·σ̂] is then a Bernoulli sequence whose rate steps
//! up from p₀ to p₁ where the opening begins. Its maximum-likelihood change point x̂ and
//! the set of change points the likelihood ratio does not reject at 95 % (Hinkley 1970's
//! profile-likelihood interval) give `straight_until_m` and its 1-σ.

use crate::params::Params;
use crate::residual::Geometry;
use crate::scene::profile::deviation;

/// The exceedance level c of zᵢ = [dᵢ > c·σ̂], in robust σ of the deviations: a
/// Gaussian wall point exceeds it with p₀ = 1.35·10⁻³, so that a few hundred points of
/// wall before the opening hold about none, while a ray through the opening exceeds it
/// by the branch's whole depth.
pub const EXCEEDANCE_SIGMAS: f64 = 3.0;

/// The normal quantile at 97.5 %: ±1.96σ is the 95 % interval the tests check.
#[cfg(test)]
const Z_975: f64 = 1.959_963_984_540_054;

/// A located edge: where the exceedances begin along the straight fit's axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Edge {
    /// The change point (PCS x, m): midway between the last point before the step and
    /// the first after it.
    pub at_m: f64,
    /// Its 1-σ (m): the RMS distance from `at_m` of the change point under its profile
    /// likelihood (`change_point`), at least the spacing of the two points it falls
    /// between over √12 (a uniform position between them).
    pub sigma_m: f64,
    /// The share of the clock sectors tested (those with [`MIN_WALL_POINTS`] of wall
    /// before the opening) whose exceedances rise within a quarter of the window after
    /// `at_m` ([`open_share`]).
    pub open_share: f64,
    /// The same share among the tested sectors on the far side of the pipe from the
    /// opening's centre angle, which a branch cannot open ([`open_share`]); 0 when none
    /// there is tested.
    pub far_open_share: f64,
}

/// The change point of the exceedances on the side `psi` (polar angle of the straight
/// fit's cross-section from +Y toward +Z, rad) within ±`half_width` (rad), over the
/// axial window `from_m`..`to_m` (PCS x), of the points (SCS, clean) against the
/// straight fit `beta`.
///
/// The wall's spread is taken before `wall_until_m` (the slices before the opening's:
/// median and 1.4826·MAD of their deviations, or of the whole window's with fewer than
/// [`MIN_WALL_POINTS`] there), and a point exceeds it by [`EXCEEDANCE_SIGMAS`]. An
/// opening does not begin at one axial position around the pipe: a branch of radius ρ_b
/// meets the main wall (radius ρ) from x_c − ρ_b at its centre angle ψ_c, and Δψ from it
/// only ρ(1 − cos Δψ) later for an equal tee. A first change point over the whole
/// window finds the opening; the circular mean angle of its exceedances within a
/// quarter of the window after it gives ψ_c; a second change point within ±`half_width`/2
/// of ψ_c locates the edge. Within that narrower window the opening still begins over a
/// ramp of length L = ρ̄(1 − cos(half_width/2)) (ρ̄ the fit's mean radius), and a single
/// step fitted to a rate that rises over a ramp lies within it: taken as uniform there,
/// the edge is the step less L/2, and its 1-σ adds L/√12 to the change point's
/// (`change_point`). (On tof-sim's tees, `tee_pass`, the step without that correction
/// lay +1.6 to +7.8 mm past the true edge from 0.75 to 3 m, with L/2 = 4.3 mm.) `None`
/// without points on both sides or without an exceedance.
pub fn opening_edge(
    points: &[[f64; 3]],
    beta: &Params,
    psi: f64,
    half_width: f64,
    (from_m, wall_until_m, to_m): (f64, f64, f64),
) -> Option<Edge> {
    let geom = Geometry::new(beta)?;
    let off = |a: f64, c: f64| {
        (a - c + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
    };
    let window: Vec<(f64, f64, f64)> = points
        .iter()
        .filter_map(|p| deviation(&geom, p))
        .filter(|&(x, _, _)| x >= from_m && x < to_m)
        .collect();
    let mut side: Vec<(f64, f64, f64)> = window
        .iter()
        .copied()
        .filter(|&(_, _, a)| off(a, psi).abs() <= half_width)
        .collect();
    side.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut wall: Vec<f64> = side
        .iter()
        .filter(|v| v.0 < wall_until_m)
        .map(|v| v.1)
        .collect();
    if wall.len() < MIN_WALL_POINTS {
        wall = side.iter().map(|v| v.1).collect();
    }
    let (centre, sigma) = crate::loss::median_and_mad_sigma(&mut wall);
    if !(sigma > 0.0) {
        return None;
    }
    let exceeds = |d: f64| d - centre > EXCEEDANCE_SIGMAS * sigma;
    let locate = |width: f64, about: f64| {
        let near: Vec<&(f64, f64, f64)> = side
            .iter()
            .filter(|v| off(v.2, about).abs() <= width)
            .collect();
        let x: Vec<f64> = near.iter().map(|v| v.0).collect();
        let z: Vec<bool> = near.iter().map(|v| exceeds(v.1)).collect();
        change_point(&x, &z)
    };
    let first = locate(half_width, psi)?;
    let reach = first.at_m + 0.25 * (to_m - from_m);
    let (sy, sz) = side
        .iter()
        .filter(|v| v.0 >= first.at_m && v.0 < reach && exceeds(v.1))
        .fold((0.0, 0.0), |(y, z), v| (y + v.2.cos(), z + v.2.sin()));
    let rho = 0.25 * (beta.d_max + beta.d_min);
    let ramp = |w: f64| rho * (1.0 - w.cos());
    let narrow = 0.5 * half_width;
    let second = (sy != 0.0 || sz != 0.0)
        .then(|| locate(narrow, sz.atan2(sy)))
        .flatten();
    let (edge, w) = match second {
        Some(e) => (e, narrow),
        None => (first, half_width),
    };
    let at_m = edge.at_m - 0.5 * ramp(w);
    let sectors = (std::f64::consts::TAU / half_width).round().max(1.0) as usize;
    let centre = match second {
        Some(_) => sz.atan2(sy),
        None => psi,
    };
    let shares = open_share(&window, sectors, wall_until_m, (edge.at_m, reach), centre);
    Some(Edge {
        at_m,
        sigma_m: edge.sigma_m.hypot(ramp(w) / 12f64.sqrt()),
        open_share: shares.all,
        far_open_share: shares.far,
    })
}

/// The one-sided level of [`open_share`]'s test per sector.
pub const OPEN_SECTOR_ALPHA: f64 = 0.05;

/// The exceedance rate a sector must exceed to open: ten times the Gaussian tail beyond
/// [`EXCEEDANCE_SIGMAS`], Φ(−3) = 1.35·10⁻³. The factor leaves room for what a camera
/// adds to Gaussian noise: its systematic range errors raised the wall's rate to 0.5 %
/// (4×) over a slice in tof-sim's camera model (`a_close_tee_under_the_cameras_noise`),
/// which a test of any rise would call open; an opening's or a multipath band's rays
/// exceed by their whole depth, at rates of tens of percent.
pub const OPEN_RATE: f64 = 10.0 * 1.349_898_031_630_094_6e-3;

/// Its normal quantile, Φ⁻¹(1 − [`OPEN_SECTOR_ALPHA`]).
const Z_OPEN: f64 = 1.644_853_626_951_472_2;

/// The share of `sectors` clock sectors in which an opening begins: for each sector
/// with at least [`MIN_WALL_POINTS`] window points before `wall_until_m`, a point
/// exceeds that sector's wall (its median + [`EXCEEDANCE_SIGMAS`]·1.4826·MAD, as the
/// incidence and so the deviations' spread differ around the pipe), and the sector
/// opens when the share of exceedances in `after` (m..m) is above the wall's by the
/// one-sided two-proportion z-test at [`OPEN_SECTOR_ALPHA`]. A branch no wider than the
/// main pipe opens over at most half the circumference (±90° at its centre, less near its
/// edge), so more than half the sectors opening at once is no branch: a band of range
/// error all around (multipath over a range band, a change of the pipe's diameter).
///
/// The share over all tested sectors depends on which are tested: far down the pipe
/// the window holds few points per sector, and at 3 m a numpy tee's opening was the one
/// sector with [`MIN_WALL_POINTS`] of wall (share 1 of 1, `test_independent_tees.py`).
/// So the share is also taken over the far side alone: the sectors whose centre lies
/// more than 90° plus one sector from `centre` (the opening's centre angle, rad), where
/// a branch no wider than the pipe has no opening at all — there a sector opens only by
/// the test's false alarm, [`OPEN_SECTOR_ALPHA`], and a band all around opens every one.
/// Each share is 0 without a tested sector.
pub fn open_share(
    window: &[(f64, f64, f64)],
    sectors: usize,
    wall_until_m: f64,
    (after_from, after_to): (f64, f64),
    centre: f64,
) -> Openings {
    let tau = std::f64::consts::TAU;
    let sector_of = |a: f64| ((a.rem_euclid(tau) / tau * sectors as f64) as usize).min(sectors - 1);
    let mut wall: Vec<Vec<f64>> = vec![Vec::new(); sectors];
    for &(_, d, a) in window.iter().filter(|v| v.0 < wall_until_m) {
        wall[sector_of(a)].push(d);
    }
    let limits: Vec<Option<(f64, usize, usize)>> = wall
        .iter_mut()
        .map(|d| {
            (d.len() >= MIN_WALL_POINTS).then(|| {
                let n = d.len();
                let (c, s) = crate::loss::median_and_mad_sigma(d);
                let limit = c + EXCEEDANCE_SIGMAS * s;
                let e = d.iter().filter(|&&v| v > limit).count();
                (limit, n, e)
            })
        })
        .collect();
    let mut after = vec![(0usize, 0usize); sectors];
    for &(_, d, a) in window
        .iter()
        .filter(|v| v.0 >= after_from && v.0 < after_to)
    {
        let k = sector_of(a);
        if let Some((limit, _, _)) = limits[k] {
            after[k].0 += 1;
            after[k].1 += usize::from(d > limit);
        }
    }
    let width = tau / sectors as f64;
    let far_from = 0.5 * std::f64::consts::PI + width;
    let off = |a: f64| (a - centre + std::f64::consts::PI).rem_euclid(tau) - std::f64::consts::PI;
    let (mut tested, mut open, mut far_tested, mut far_open) = (0usize, 0usize, 0usize, 0usize);
    for (k, (lim, &(n_a, e_a))) in limits.iter().zip(&after).enumerate() {
        let Some((_, n_b, e_b)) = *lim else { continue };
        if n_a == 0 {
            continue;
        }
        let (n_a, e_a, n_b, e_b) = (n_a as f64, e_a as f64, n_b as f64, e_b as f64);
        let p = OPEN_RATE.max(e_b / n_b);
        let se = (p * (1.0 - p) / n_a).sqrt();
        let opens = usize::from(e_a / n_a - p > Z_OPEN * se);
        tested += 1;
        open += opens;
        if off((k as f64 + 0.5) * width).abs() > far_from {
            far_tested += 1;
            far_open += opens;
        }
    }
    let share = |o: usize, t: usize| if t == 0 { 0.0 } else { o as f64 / t as f64 };
    Openings {
        all: share(open, tested),
        far: share(far_open, far_tested),
    }
}

/// [`open_share`]'s answer: the shares of the tested clock sectors that open.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Openings {
    /// Over all tested sectors.
    pub all: f64,
    /// Over the tested sectors on the far side from the opening's centre angle.
    pub far: f64,
}

/// The fewest wall points before the opening from which its spread is taken: with n
/// points the MAD's relative standard error is about 1.17/√n (its asymptotic
/// efficiency 0.37), 0.2 at 34; with fewer, the window's points give it.
pub const MIN_WALL_POINTS: usize = 34;

/// The change point of the indicators `z` at the sorted positions `x`: the split k
/// (points 0..k before) maximising ℓ(k) = k·h(s₀/k) + (n − k)·h(s₁/(n − k)), h(p) =
/// p ln p + (1 − p) ln(1 − p), with s₀, s₁ the exceedances before and after and the rate
/// after above the rate before; its 1-σ is the RMS of split(k) − split(k̂) under the
/// weights exp(ℓ(k) − ℓ̂)·(x_k − x_{k−1}). `None` when no split has a higher rate after it.
fn change_point(x: &[f64], z: &[bool]) -> Option<Edge> {
    let n = x.len();
    if n < 2 || z.len() != n {
        return None;
    }
    let h = |s: f64, m: f64| {
        let p = s / m;
        let t = |q: f64| if q > 0.0 { q * q.ln() } else { 0.0 };
        m * (t(p) + t(1.0 - p))
    };
    let total = z.iter().filter(|&&v| v).count() as f64;
    let mut before = 0.0;
    // ℓ(k) for k = 1..n−1, NaN where the rate does not rise.
    let ll: Vec<f64> = (1..n)
        .map(|k| {
            before += f64::from(u8::from(z[k - 1]));
            let (n0, n1) = (k as f64, (n - k) as f64);
            let after = total - before;
            if after / n1 > before / n0 {
                h(before, n0) + h(after, n1)
            } else {
                f64::NAN
            }
        })
        .collect();
    let (best, &l_max) = ll
        .iter()
        .enumerate()
        .filter(|(_, l)| !l.is_nan())
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    let k = best + 1;
    let split = |k: usize| 0.5 * (x[k - 1] + x[k]);
    let at = split(k);
    // The profile likelihood as a posterior over the change point, flat in x: split k
    // weighs exp(ℓ(k) − ℓ̂) times the spacing of the two points it lies between.
    let (mut w_sum, mut m2) = (0.0, 0.0);
    for (i, l) in ll.iter().enumerate().filter(|(_, l)| !l.is_nan()) {
        let k = i + 1;
        let w = (l - l_max).exp() * (x[k] - x[k - 1]).max(0.0);
        w_sum += w;
        m2 += w * (split(k) - at).powi(2);
    }
    let spacing = x[k] - x[k - 1];
    let rms = if w_sum > 0.0 {
        (m2 / w_sum).sqrt()
    } else {
        0.0
    };
    Some(Edge {
        at_m: at,
        sigma_m: rms.max(spacing / 12f64.sqrt()),
        // Sectors are [`opening_edge`]'s to judge.
        open_share: f64::NAN,
        far_open_share: f64::NAN,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::uniforms;
    use nalgebra::Vector3;

    /// The unit vector of the polar angle `psi` in the cross-section (PCS, 0 along x).
    fn radial(psi: f64) -> Vector3<f64> {
        Vector3::new(0.0, psi.cos(), psi.sin())
    }

    /// A step in the rate of exceedances at a known x, points at random positions: the
    /// 95 % interval (±1.96σ) holds the true step in about 95 % of 2000 trials (within
    /// four binomial standard errors, ±0.02), and the estimate lies within a few point
    /// spacings of it.
    #[test]
    fn the_interval_covers_a_known_step() {
        let mut u = uniforms(7);
        let (trials, n, step) = (2000, 400, 0.6);
        let (p0, p1) = (0.002, 0.3);
        let mut covered = 0;
        for _ in 0..trials {
            let mut x: Vec<f64> = (0..n).map(|_| u()).collect();
            x.sort_by(f64::total_cmp);
            let z: Vec<bool> = x
                .iter()
                .map(|&x| u() < if x < step { p0 } else { p1 })
                .collect();
            let e = change_point(&x, &z).unwrap();
            covered += usize::from((e.at_m - step).abs() <= Z_975 * e.sigma_m);
            assert!((e.at_m - step).abs() < 0.2, "{e:?}");
        }
        let rate = covered as f64 / trials as f64;
        let se = (0.95 * 0.05 / trials as f64).sqrt();
        assert!((rate - 0.95).abs() <= 4.0 * se, "coverage {rate}");
    }

    /// No rise in the rate, no edge; a rate that falls is no opening either.
    #[test]
    fn no_rise_no_edge() {
        let x: Vec<f64> = (0..100).map(|i| i as f64).collect();
        assert_eq!(change_point(&x, &[false; 100]), None);
        let falling: Vec<bool> = (0..100).map(|i| i < 50).collect();
        assert_eq!(change_point(&x, &falling), None);
        assert_eq!(change_point(&x[..1], &[true]), None);
    }

    /// Points on a round pipe's wall (2 mm noise, on axis) from 0.5 to 2 m, with `open`
    /// deciding which read 0.3 m long.
    fn wall_with(open: impl Fn(f64, f64) -> bool, seed: u64) -> Vec<[f64; 3]> {
        let mut u = uniforms(seed);
        (0..20_000)
            .map(|_| {
                let x = 0.5 + 1.5 * u();
                let psi = std::f64::consts::TAU * u();
                let wall = Vector3::new(x, 0.0, 0.0) + 0.25 * radial(psi);
                let noise = 0.002 * (u() + u() + u() - 1.5) * 2.0;
                let r = wall.norm() + noise + if open(x, psi) { 0.3 } else { 0.0 };
                let p = wall.normalize() * r;
                [p.x, p.y, p.z]
            })
            .collect()
    }

    /// A branch opens in few sectors and none on the far side; a band of range error all
    /// around (from 1.23 m, as multipath over a range band gives) opens in all: the
    /// shares tell them apart on either side of one half.
    #[test]
    fn a_ring_is_no_opening() {
        let beta = Params::from_array([0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let tee = wall_with(
            |x, psi| (psi - 1.0).abs() < 0.5 && x >= 1.23 + 0.25 * (1.0 - (psi - 1.0).cos()),
            13,
        );
        let e = opening_edge(&tee, &beta, 1.0, 0.5, (1.0, 1.2, 1.5)).unwrap();
        assert!(e.open_share < 0.5 && e.far_open_share < 0.5, "{e:?}");
        let ring = wall_with(|x, _| x >= 1.23, 17);
        let e = opening_edge(&ring, &beta, 1.0, 0.5, (1.0, 1.2, 1.5)).unwrap();
        assert!((e.at_m - 1.23).abs() < 0.01, "{e:?}");
        assert!(e.open_share > 0.9 && e.far_open_share > 0.9, "{e:?}");
    }

    /// Far down a pipe few sectors hold enough wall to be tested: here only the
    /// opening's side (the wall's points elsewhere thinned to a tenth). Its share over
    /// the tested sectors is then 1, as a ring's; over the far side, where nothing is
    /// tested, it is 0, and the opening stays a branch.
    #[test]
    fn an_opening_alone_in_its_tested_sector_is_no_ring() {
        let beta = Params::from_array([0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let mut u = uniforms(19);
        let near = |psi: f64| (psi - 1.0).abs() < 0.6;
        let pts: Vec<[f64; 3]> = wall_with(
            |x, psi| (psi - 1.0).abs() < 0.5 && x >= 1.23 + 0.25 * (1.0 - (psi - 1.0).cos()),
            23,
        )
        .into_iter()
        .filter(|p| near(p[2].atan2(p[1]).rem_euclid(std::f64::consts::TAU)) || u() < 0.1)
        .collect();
        let e = opening_edge(&pts, &beta, 1.0, 0.5, (1.0, 1.2, 1.5)).unwrap();
        assert!((e.at_m - 1.23).abs() < 0.01, "{e:?}");
        assert!(e.open_share > 0.5 && e.far_open_share == 0.0, "{e:?}");
    }

    /// Points on a round pipe's wall (2 mm noise) with an equal tee's opening on one
    /// side from x = 1.23 m at its centre angle: rays there read 0.3 m long. The edge is found within 5 mm, its
    /// interval holds it, and the other side (noise bounded by ±3 mm, under 3σ) shows
    /// none.
    #[test]
    fn an_opening_in_a_wall_is_located() {
        let beta = Params::from_array([0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let mut u = uniforms(11);
        let mut pts = Vec::new();
        for _ in 0..20_000 {
            let x = 0.5 + 1.5 * u();
            let psi = std::f64::consts::TAU * u();
            let wall = Vector3::new(x, 0.0, 0.0) + 0.25 * radial(psi);
            // An equal tee's opening: from 1.23 m at its centre angle, ρ(1 − cos Δψ)
            // later Δψ away.
            let open = (psi - 1.0).abs() < 0.5 && x >= 1.23 + 0.25 * (1.0 - (psi - 1.0).cos());
            let noise = 0.002 * (u() + u() + u() - 1.5) * 2.0;
            let r = wall.norm() + noise + if open { 0.3 } else { 0.0 };
            let p = wall.normalize() * r;
            pts.push([p.x, p.y, p.z]);
        }
        let e = opening_edge(&pts, &beta, 1.0, 0.5, (1.0, 1.2, 1.5)).unwrap();
        assert!((e.at_m - 1.23).abs() < 0.005, "{e:?}");
        assert!((e.at_m - 1.23).abs() <= Z_975 * e.sigma_m + 1e-3, "{e:?}");
        let other = opening_edge(
            &pts,
            &beta,
            1.0 + std::f64::consts::PI,
            0.5,
            (1.0, 1.2, 1.5),
        );
        assert_eq!(other, None);
    }
}
