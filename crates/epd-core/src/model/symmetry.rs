//! The symmetries of the elliptic-cylinder model (README, Conventions), the canonical form of an
//! estimate, and errors against a ground truth taken modulo those symmetries.
//!
//! The same point cloud fits equally well after
//! - a 180° turn of the PCS about the pipe axis: (θx+π, −θy, −θz, −δy, −δz), same
//!   diameters ([`flip_180`]);
//! - a 90° turn of the PCS about the pipe axis with Dmax and Dmin swapped
//!   ([`turn_90`]); the pitch/yaw pair is re-expressed exactly through the rotation
//!   matrix, not by adding 90° to the roll.

use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::params::{Params, wrap_pi};

/// The 180° symmetry: the PCS turned by π about its X axis.
/// Rx(π)·Rz(θz)·Ry(θy)·Rx(θx) = Rz(−θz)·Ry(−θy)·Rx(θx+π) and Rx(π)·[0, δy, δz] = [0, −δy, −δz].
pub fn flip_180(p: &Params) -> Params {
    Params {
        roll: wrap_pi(p.roll + std::f64::consts::PI),
        pitch: -p.pitch,
        yaw: -p.yaw,
        dy: -p.dy,
        dz: -p.dz,
        ..*p
    }
}

/// The 90° symmetry: the PCS turned by −90° about its X axis (new Y = old Z,
/// new Z = −old Y), so the diameters swap. The rotation is re-expressed exactly:
/// R' = Rx(−π/2)·R and [0, δy', δz'] = [0, δz, −δy].
pub fn turn_90(p: &Params) -> Params {
    let q = Rotation3::from_axis_angle(&Vector3::x_axis(), -std::f64::consts::FRAC_PI_2);
    let r: Matrix3<f64> = q.matrix() * p.rotation().matrix();
    let swapped = Params {
        d_max: p.d_min,
        d_min: p.d_max,
        ..*p
    };
    swapped.with_rotation(&r, p.dz, -p.dy)
}

/// The PCS turned by `phi` about its X axis, the diameters kept: R' = Rx(φ)·R and
/// [0, δy', δz'] = Rx(φ)·[0, δy, δz]. For a round pipe (Dmax = Dmin) this is a symmetry
/// for every φ — the roll is then undetermined, and the pitch, yaw and offsets that go
/// with a roll are those of this turn; [`flip_180`] is its φ = π for any pipe, and
/// [`turn_90`] its φ = −π/2 with the diameters swapped.
pub fn turn_about_axis(p: &Params, phi: f64) -> Params {
    let q = Rotation3::from_axis_angle(&Vector3::x_axis(), phi);
    let r: Matrix3<f64> = q.matrix() * p.rotation().matrix();
    let (s, c) = phi.sin_cos();
    p.with_rotation(&r, c * p.dy - s * p.dz, s * p.dy + c * p.dz)
}

/// The end-for-end symmetry: the PCS turned by π about its Z axis, so that its X axis
/// points the other way along the pipe: Rz(π)·Rz(θz) = Rz(θz+π) and [0, δy, δz] →
/// [0, −δy, δz]. Canonical estimates have the PCS X axis pointing forward (cos θz > 0).
pub fn reverse_axis(p: &Params) -> Params {
    Params {
        yaw: wrap_pi(p.yaw + std::f64::consts::PI),
        dy: -p.dy,
        ..*p
    }
}

/// Which symmetries [`canonical_form`] applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Applied {
    /// The 90° turn (diameters swapped).
    pub turned: bool,
    /// The 180° turn.
    pub flipped: bool,
    /// The end-for-end turn ([`reverse_axis`]).
    pub reversed: bool,
}

/// The canonical member of the symmetry class of `p` (README, Conventions): Dmax ≥ Dmin and
/// θx in [−90°, 90°), with the PCS X axis pointing forward along the pipe (θz in
/// [−90°, 90°); the end-for-end turn is a further symmetry, see README's Conventions).
pub fn canonicalize(p: &Params) -> Params {
    canonical_form(p).0
}

/// [`canonicalize`], also telling which symmetries it applied.
pub fn canonical_form(p: &Params) -> (Params, Applied) {
    let mut applied = Applied::default();
    let mut c = if p.d_max < p.d_min {
        applied.turned = true;
        turn_90(p)
    } else {
        *p
    };
    c.roll = wrap_pi(c.roll);
    c.yaw = wrap_pi(c.yaw);
    if c.yaw.cos() * c.pitch.cos() < 0.0 {
        applied.reversed = true;
        c = reverse_axis(&c);
    }
    if !(-std::f64::consts::FRAC_PI_2..std::f64::consts::FRAC_PI_2).contains(&c.roll) {
        applied.flipped = true;
        c = flip_180(&c);
    }
    c.roll = wrap_pi(c.roll);
    c.yaw = wrap_pi(c.yaw);
    if c.roll >= std::f64::consts::FRAC_PI_2 {
        // Rounding at the edge of the interval.
        c.roll -= std::f64::consts::PI;
    }
    (c, applied)
}

/// The members of the symmetry class of `truth` that are labelled as `truth` is:
/// the truth and its 180° turn, plus the two 90° turns when the pipe is circular
/// (Dmax = Dmin), where they keep Dmax ≥ Dmin.
pub fn symmetry_class(truth: &Params) -> Vec<Params> {
    let mut v = vec![*truth, flip_180(truth)];
    if truth.d_max == truth.d_min {
        let t = turn_90(truth);
        v.push(t);
        v.push(flip_180(&t));
    }
    v
}

/// Estimate − truth for each parameter of eq. (2), in metres and radians, taken against
/// the member of the truth's symmetry class closest to the estimate. Angles are
/// wrapped into [−π, π), so the roll error lies in [−90°, 90°) for a canonical estimate
/// of an elliptic pipe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamErrors {
    /// Dmax error (m).
    pub d_max: f64,
    /// Dmin error (m).
    pub d_min: f64,
    /// Mean-diameter error ((Dmax+Dmin)/2) (m).
    pub d_mean: f64,
    /// Roll error (rad).
    pub roll: f64,
    /// Pitch error (rad).
    pub pitch: f64,
    /// Yaw error (rad).
    pub yaw: f64,
    /// δy error (m).
    pub dy: f64,
    /// δz error (m).
    pub dz: f64,
}

/// Distance between two rotations: the Frobenius norm of the difference of their
/// matrices (monotone in the geodesic angle, and free of acos rounding).
fn rotation_distance(a: &Params, b: &Params) -> f64 {
    (a.rotation().matrix() - b.rotation().matrix()).norm()
}

/// Errors of `estimate` against `truth` under the symmetries (README, Conventions): the estimate is
/// canonicalised, then compared with the member of the truth's class whose rotation is
/// closest to the estimate's.
pub fn errors_against(estimate: &Params, truth: &Params) -> ParamErrors {
    let e = canonicalize(estimate);
    let t = canonicalize(truth);
    let best = symmetry_class(&t)
        .into_iter()
        .min_by(|a, b| rotation_distance(&e, a).total_cmp(&rotation_distance(&e, b)))
        .unwrap_or(t);
    ParamErrors {
        d_max: e.d_max - best.d_max,
        d_min: e.d_min - best.d_min,
        d_mean: 0.5 * (e.d_max + e.d_min) - 0.5 * (best.d_max + best.d_min),
        roll: wrap_pi(e.roll - best.roll),
        pitch: wrap_pi(e.pitch - best.pitch),
        yaw: wrap_pi(e.yaw - best.yaw),
        dy: e.dy - best.dy,
        dz: e.dz - best.dz,
    }
}

/// Errors of `estimate` against `truth` turned about its axis to the estimate's roll
/// ([`turn_about_axis`] by the φ that makes the canonical truth's roll the canonical
/// estimate's, found by Newton's method with the turn's derivative dθx/dφ = cos θz / cos θy,
/// from row 3 of Rx(φ)·R). For an estimate whose roll is undetermined
/// ([`crate::Estimate::roll_determined`] false): its pitch, yaw and offsets are those that
/// go with the roll the fit took, and their reported 1-σ are taken at that roll, so their
/// errors are taken there too. The diameters' errors are [`errors_against`]'s. Falls
/// back to [`errors_against`] when the Newton iteration does not reach the roll.
pub fn errors_at_roll(estimate: &Params, truth: &Params) -> ParamErrors {
    let e = canonicalize(estimate);
    let t = canonicalize(truth);
    let mut phi = wrap_pi(e.roll - t.roll);
    let mut turned = turn_about_axis(&t, phi);
    for _ in 0..50 {
        let miss = wrap_pi(e.roll - turned.roll);
        if miss.abs() < 1e-12 {
            break;
        }
        let slope = turned.yaw.cos() / turned.pitch.cos();
        if !(slope.abs() > 1e-3) {
            break;
        }
        phi += miss / slope;
        turned = turn_about_axis(&t, phi);
    }
    let plain = errors_against(estimate, truth);
    if wrap_pi(e.roll - turned.roll).abs() > 1e-9 || turned.yaw.cos() * turned.pitch.cos() <= 0.0 {
        return plain;
    }
    ParamErrors {
        roll: 0.0,
        pitch: wrap_pi(e.pitch - turned.pitch),
        yaw: wrap_pi(e.yaw - turned.yaw),
        dy: e.dy - turned.dy,
        dz: e.dz - turned.dz,
        ..plain
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn p(roll: f64, pitch: f64, yaw: f64) -> Params {
        Params {
            d_max: 0.50,
            d_min: 0.48,
            roll,
            pitch,
            yaw,
            dy: 0.03,
            dz: -0.01,
        }
    }

    /// Both symmetric parameter sets map any PCS wall point to a wall point: the same
    /// SCS point satisfies eq. (5) under both.
    fn same_surface(a: &Params, b: &Params) {
        for k in 0..24 {
            let phi = k as f64 * 0.26;
            let x = 0.3 + 0.2 * k as f64;
            let wall_p = Point3::new(x, 0.5 * a.d_max * phi.cos(), 0.5 * a.d_min * phi.sin());
            let s = a.pcs_to_scs(&wall_p);
            let q = b.scs_to_pcs(&s);
            let r = (q.y / (0.5 * b.d_max)).powi(2) + (q.z / (0.5 * b.d_min)).powi(2) - 1.0;
            assert!(r.abs() < 1e-12, "k={k} r={r}");
        }
        // And the sensor origin has the same PCS cross-section position up to the turn.
        let o_a = a.sensor_origin_pcs();
        let o_b = b.sensor_origin_pcs();
        assert!(((o_a.coords.norm()) - o_b.coords.norm()).abs() < 1e-12);
    }

    /// Any turn about the axis maps a round pipe onto itself, and φ = π is the flip.
    #[test]
    fn a_turn_about_the_axis_is_a_symmetry_of_a_round_pipe() {
        let round = Params {
            d_min: 0.50,
            ..p(0.4, 0.05, -0.08)
        };
        for phi in [-2.5, -0.7, 0.3, 1.1, 3.0] {
            same_surface(&round, &turn_about_axis(&round, phi));
        }
        let e = p(0.4, 0.05, -0.08);
        let (a, b) = (turn_about_axis(&e, std::f64::consts::PI), flip_180(&e));
        for (x, y) in a.to_array().iter().zip(b.to_array()) {
            assert!((wrap_pi(x - y)).abs() < 1e-12, "{a:?} {b:?}");
        }
    }

    /// A round pipe's estimate that is its truth turned about the axis has no pose error
    /// at its roll, though `errors_against` sees the turn in pitch, yaw and the offsets.
    #[test]
    fn errors_at_the_estimates_roll_do_not_see_a_turn_about_the_axis() {
        let truth = Params {
            d_min: 0.50,
            ..p(0.4, 0.05, -0.08)
        };
        let est = turn_about_axis(&truth, 0.9);
        let plain = errors_against(&est, &truth);
        assert!(
            plain.dy.abs() > 1e-3 && plain.pitch.abs() > 1e-3,
            "{plain:?}"
        );
        let at = errors_at_roll(&est, &truth);
        for v in [at.pitch, at.yaw, at.dy, at.dz, at.roll] {
            assert!(v.abs() < 1e-12, "{at:?}");
        }
        // A large yaw, where the turn moves the roll by cos θz / cos θy ≈ 0.36 per radian.
        let yawed = Params { yaw: 1.2, ..truth };
        let at = errors_at_roll(&turn_about_axis(&yawed, 0.9), &yawed);
        for v in [at.pitch, at.yaw, at.dy, at.dz, at.roll] {
            assert!(v.abs() < 1e-12, "{at:?}");
        }
    }

    #[test]
    fn flip_is_a_symmetry() {
        let a = p(0.4, 0.08, -0.05);
        same_surface(&a, &flip_180(&a));
    }

    #[test]
    fn turn_is_a_symmetry_with_tilt() {
        let a = p(0.4, 0.08, -0.05);
        let t = turn_90(&a);
        assert_eq!(t.d_max, a.d_min);
        same_surface(&a, &t);
        // Not just roll + 90°: pitch and yaw are re-expressed.
        assert!((t.pitch - a.pitch).abs() > 1e-3 || (t.yaw - a.yaw).abs() > 1e-3);
        // Four quarter turns give the identity.
        let back = turn_90(&turn_90(&turn_90(&t)));
        let e = errors_against(&back, &a);
        assert!(e.roll.abs() < 1e-12 && e.pitch.abs() < 1e-12 && e.yaw.abs() < 1e-12);
        assert!((back.dy - a.dy).abs() < 1e-15 && (back.dz - a.dz).abs() < 1e-15);
    }

    #[test]
    fn reversed_axis_is_a_symmetry() {
        let a = p(0.4, 0.08, -0.05);
        let r = reverse_axis(&a);
        same_surface(&a, &r);
        let c = canonicalize(&r);
        assert!((c.yaw - a.yaw).abs() < 1e-12 && (c.dy - a.dy).abs() < 1e-15);
    }

    #[test]
    fn canonical_form() {
        for &(roll, pitch, yaw) in &[(2.5, 0.1, -0.2), (-2.0, -0.05, 0.07), (1.6, 0.0, 0.0)] {
            let a = p(roll, pitch, yaw);
            for m in [a, flip_180(&a), turn_90(&a), flip_180(&turn_90(&a))] {
                let c = canonicalize(&m);
                assert!(c.d_max >= c.d_min);
                assert!(
                    (-std::f64::consts::FRAC_PI_2..std::f64::consts::FRAC_PI_2).contains(&c.roll)
                );
                same_surface(&m, &c);
                // All members canonicalise to the same parameters.
                let c0 = canonicalize(&a);
                assert!(
                    (c.to_array()
                        .iter()
                        .zip(c0.to_array())
                        .map(|(x, y)| (x - y).abs()))
                    .fold(0.0, f64::max)
                        < 1e-12
                );
            }
        }
    }

    #[test]
    fn errors_pick_closest_member() {
        let truth = p(1.5, 0.03, -0.02);
        let est = Params {
            d_max: 0.501,
            roll: truth.roll - std::f64::consts::PI + 0.01,
            ..flip_180(&truth)
        };
        let e = errors_against(&est, &truth);
        assert!((e.roll - 0.01).abs() < 1e-12);
        assert!((e.d_max - 0.001).abs() < 1e-12);
        assert!(e.pitch.abs() < 1e-12 && e.dy.abs() < 1e-12);
    }

    #[test]
    fn circular_truth_uses_quarter_turns() {
        let mut truth = p(0.2, 0.02, 0.01);
        truth.d_min = truth.d_max;
        let est = canonicalize(&turn_90(&truth));
        let e = errors_against(&est, &truth);
        assert!(e.roll.abs() < 1e-12 && e.pitch.abs() < 1e-12 && e.yaw.abs() < 1e-12);
        assert!(e.dy.abs() < 1e-12 && e.dz.abs() < 1e-12);
    }
}
