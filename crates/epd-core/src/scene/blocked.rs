//! A bend far ahead seen where it blocks the view down the pipe: returns short of the
//! straight wall.
//!
//! Down a straight pipe a ray near the axis meets the wall far ahead, or nothing within
//! the camera's reach. A bend's outer wall stands across those rays: they return from
//! it, at ranges short of where the straight wall continued would put them. On a small
//! pipe under large noise those returns are the whole of what the bend shows: on an 8"
//! pipe under σ = 5 cm with an elbow 3 m ahead (the numpy caster of
//! `crates/epd-py/tests/test_independent_bends.py`, 320 × 240) they are 160–180 points
//! (0.2 % of the frame), at 3.0–3.4 m along the axis, 0.5–7 m short of the straight wall,
//! in slices too sparse for the profile's medians, and the frame read `straight`.
//!
//! The test: the points whose range residual lies below −z·s ([`OFF_WALL_TAIL`](crate::scene::axis::OFF_WALL_TAIL), the
//! straight fit's scale) — short of the wall — counted against the one-sided Gaussian
//! share at the whole frame's scale, a binomial count exceeded with probability below the
//! survey's false-alarm rate (`OffWall::excess`), and against the points as far off on
//! the long side (a sign test: errors symmetric about the wall, whatever their tails —
//! range-dependent noise, wiggling, correlated noise — put a point off the wall short or
//! long with probability ½; the short ones must exceed half at the same rate).
//! Multipath returns long, far outliers mostly long (a range drawn anywhere within the
//! camera's reach is longer than a near wall's): a surface across the view returns many
//! points short and few long. When both counts are in excess, a torus started
//! at the nearest of them (their 5th percentile along the axis, so that a few stray
//! returns nearer do not place it) is fitted to the points from a diameter before it on,
//! from the four sides ([`BEND_START_TURNS`](crate::segment)), the best fitting taken;
//! it must be shaped as a bend beyond a departure must ([`crate::segment::survey`]), at
//! residuals within twice the straight fit's robust scale.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::estimate::Estimate;
use crate::residual::Residual;
use crate::scene::axis::{OffWall, binomial_upper_tail};
use crate::scene::profile::SURVEY_FALSE_ALARM;

/// The returns short of a straight fit's wall.
#[derive(Clone, Debug, PartialEq)]
pub struct ShortReturns {
    /// Their number.
    pub count: usize,
    /// The 5th percentile of their axial coordinate (PCS x of the fit, m): where the
    /// surface across the view begins.
    pub near_m: f64,
    /// The clock direction of their mean offset from the axis (rad, from PCS +Y toward
    /// +Z).
    pub side: f64,
}

/// The share of the short returns nearer than the one that places the surface
/// (their 5th percentile): a few stray short returns nearer do not move it.
const NEAR_QUANTILE: f64 = 0.05;

/// The returns of `pts` (SCS, m) short of the wall of `fit` beyond −z·s that lie past
/// `from_m` along its axis (PCS x, m; the reach of the survey's profile, whose slices'
/// medians judge the wall before it), when more of them lie there than Gaussian noise
/// puts there at the survey's false-alarm rate (the one-sided share, half the two-sided
/// tail of `OffWall`, of the points past `from_m`) and than lie as far off long there
/// (the sign test); `None` otherwise.
pub fn short_returns(pts: &[[f64; 3]], fit: &Estimate, from_m: f64) -> Option<ShortReturns> {
    let off = OffWall::count(pts, fit)?;
    // Not even the whole frame has more points off the wall than Gaussian noise puts
    // there: nothing to look at (one pass in SIMD, where the next is scalar).
    if !off.excess(off.beyond, off.tail) {
        return None;
    }
    let rot = fit.params.rotation();
    let origin = Vector3::new(0.0, fit.params.dy, fit.params.dz);
    // PCS x = the first row of R times the SCS point (the offset has no x).
    let row = rot.matrix().row(0).transpose();
    let (n, long, short) = pts
        .par_iter()
        .filter(|p| row.dot(&Vector3::new(p[0], p[1], p[2])) > from_m)
        .fold(
            || (0usize, 0usize, Vec::new()),
            |(n, long, mut short), p| {
                let r = off.geom.residual(Residual::Range, p);
                if r < -off.limit {
                    short.push(rot * Vector3::new(p[0], p[1], p[2]) + origin);
                }
                (n + 1, long + usize::from(r > off.limit), short)
            },
        )
        .reduce(
            || (0, 0, Vec::new()),
            |(n, l, mut s), (n2, l2, s2)| {
                s.extend(s2);
                (n + n2, l + l2, s)
            },
        );
    // The count past `from_m` against the Gaussian share there, then the sign test: errors
    // symmetric about the wall put each point off it on either side with probability ½,
    // whatever their tails.
    let gaussian = OffWall { n, ..off };
    if !gaussian.excess(short.len(), 0.5 * off.tail)
        || !(binomial_upper_tail(short.len(), short.len() + long, 0.5) < SURVEY_FALSE_ALARM)
    {
        return None;
    }
    let mut x: Vec<f64> = short.iter().map(|q| q.x).collect();
    let near_m = crate::check::quantile(&mut x, NEAR_QUANTILE);
    let (y, z) = short
        .iter()
        .fold((0.0, 0.0), |(y, z), q| (y + q.y, z + q.z));
    Some(ShortReturns {
        count: short.len(),
        near_m,
        side: z.atan2(y),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::{EstimateOptions, Method, estimate};
    use crate::fit::options::LossScale;
    use crate::loss::Loss;
    use crate::scene::uniforms;

    /// Pipe radius (m), range noise σ (m), the camera's reach (m).
    const RADIUS: f64 = 0.1;
    const SIGMA: f64 = 0.01;
    const REACH: f64 = 6.0;

    /// A frame of our own ray cast, independent of the model's code: a 160 × 120
    /// pinhole camera of 69° × 51° at (0, 0.01, −0.02) in a round pipe along +X, its
    /// rays meeting the wall y² + z² = RADIUS² or, when `plane` is given, the plane
    /// x = `plane` across the pipe if nearer; rays beyond the reach return nothing.
    /// Range noise N(0, SIGMA²) along each ray, plus `stray(u)` (m) on every 50th point.
    fn frame(
        plane: Option<f64>,
        mut stray: impl FnMut(&mut dyn FnMut() -> f64) -> f64,
    ) -> Vec<[f64; 3]> {
        let mut u = uniforms(7);
        let (o_y, o_z) = (0.01, -0.02);
        let (w, h) = (160, 120);
        let (tx, ty) = (34.5f64.to_radians().tan(), 25.5f64.to_radians().tan());
        let mut pts = Vec::new();
        for j in 0..h {
            for i in 0..w {
                let dy = tx * (2.0 * (i as f64 + 0.5) / w as f64 - 1.0);
                let dz = ty * (2.0 * (j as f64 + 0.5) / h as f64 - 1.0);
                let n = (1.0 + dy * dy + dz * dz).sqrt();
                let d = [1.0 / n, dy / n, dz / n];
                // |o + t·d|² = R² in (y, z): a t² + b t + c = 0, c < 0 inside.
                let a = d[1] * d[1] + d[2] * d[2];
                let b = 2.0 * (o_y * d[1] + o_z * d[2]);
                let c = o_y * o_y + o_z * o_z - RADIUS * RADIUS;
                let mut t = (-b + (b * b - 4.0 * a * c).sqrt()) / (2.0 * a);
                if let Some(x) = plane {
                    t = t.min(x / d[0]);
                }
                if t > REACH {
                    continue;
                }
                let g = (-2.0 * (1.0 - u()).ln()).sqrt() * (std::f64::consts::TAU * u()).cos();
                let k = pts.len();
                let r = t + SIGMA * g + if k % 50 == 0 { stray(&mut u) } else { 0.0 };
                pts.push([r * d[0], o_y + r * d[1], o_z + r * d[2]]);
            }
        }
        pts
    }

    fn fit(pts: &[[f64; 3]]) -> Estimate {
        let options = EstimateOptions::default()
            .with_loss(Loss::Cauchy { scale: 0.05 })
            .unwrap()
            .with_loss_scale(LossScale::Auto);
        estimate(pts, Method::MlEpd, &options).unwrap()
    }

    /// A plane 2 m ahead stops the rays that would meet the wall beyond it: they return
    /// short of the wall, and past the profile's reach (1 m here) all of them are found,
    /// the nearest (their 5th percentile) within 2 cm of the plane — the short returns
    /// start at the plane, where its shortfall first passes z·s, and spread over ~0.1 m
    /// of its near edge. Without the plane nothing is found.
    #[test]
    fn a_surface_across_the_view_returns_short() {
        let pts = frame(Some(2.0), |_| 0.0);
        let f = fit(&pts);
        let short = short_returns(&pts, &f, 1.0).expect("the plane's returns");
        // The plane's points: those of the frame at x ≥ 2 − 3σ.
        let on_plane = pts.iter().filter(|p| p[0] > 2.0 - 3.0 * SIGMA).count();
        assert!(
            short.count as f64 >= 0.8 * on_plane as f64 && short.count <= on_plane,
            "{short:?} of {on_plane}"
        );
        assert!((short.near_m - 2.0).abs() < 0.02, "{short:?}");
        let clear = frame(None, |_| 0.0);
        assert_eq!(short_returns(&clear, &fit(&clear), 1.0), None);
    }

    /// Stray returns off the wall on both sides (every 50th point moved by ±0.2–1 m, the
    /// sign at random) are no surface: the sign test refuses them though they exceed
    /// Gaussian noise's count many times. Moved short only, they are found.
    #[test]
    fn strays_on_both_sides_are_no_surface() {
        let both = frame(None, |u| {
            let m = 0.2 + 0.8 * u();
            if u() < 0.5 { -m } else { m }
        });
        let f = fit(&both);
        assert_eq!(short_returns(&both, &f, 0.0), None);
        let off = OffWall::count(&both, &f).unwrap();
        assert!(off.excess(off.beyond, off.tail), "{} beyond", off.beyond);
        let short = frame(None, |u| -(0.2 + 0.8 * u()));
        assert!(short_returns(&short, &fit(&short), 0.0).is_some());
    }
}
