//! A physical model of a continuous-wave (4-phase) ToF camera's depth errors: return
//! amplitude, amplitude-dependent random error, invalid (dark or saturated) pixels, and
//! the systematic errors wiggling, intensity-related offset and multipath.
//!
//! Amplitudes are dimensionless, "relative to a head-on ρ = 1 wall at 1 m": a Lambertian
//! wall of reflectivity ρ seen at range r (m) under incidence θ (between the ray and the
//! wall normal) returns A = ρ·cos θ / r² (the radiometric falloff used by Lange, 2000,
//! ch. 4). All ranges are along the pixel's ray in the SCS (X forward, Y right, Z up), in
//! metres.
//!
//! When a [`crate::Noise`] carries `physics: Some(..)`, this model replaces the noise's
//! constant `sigma` and its bias `bias_b0`, `bias_b1`; the outlier fractions still apply
//! afterwards, and the noise `model` still chooses whether the random error lies along the
//! ray or in every coordinate. See [`crate::frame::simulate_into`] for the order.

use std::f64::consts::TAU;

use crate::error::{Rule, SimError, first_broken};

/// Speed of light in vacuum (m/s).
pub const SPEED_OF_LIGHT: f64 = 299_792_458.0;

/// The parameters of the ToF sensor model. Plain data; [`ToFPhysics::validate`] checks
/// them, [`ToFPhysics::helios2`] gives the documented defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToFPhysics {
    /// Wall reflectivity ρ at the illumination wavelength (Lambertian), in (0, 1].
    pub reflectivity: f64,
    /// σ_ref: standard deviation of the random range error (m) at amplitude A = 1.
    pub sigma_ref_m: f64,
    /// Background light B in the amplitude unit (ambient light, dark current, readout
    /// noise lumped together), ≥ 0: B = 0 gives shot-noise-limited σ ∝ 1/√A, B ≫ A
    /// ambient-limited σ ∝ 1/A.
    pub ambient: f64,
    /// Pixels whose measured amplitude is below this are invalid (too dark: the camera's
    /// confidence threshold). > 0.
    pub min_amplitude: f64,
    /// Pixels whose measured amplitude is above this are invalid (saturated).
    pub saturation_amplitude: f64,
    /// Camera counts for amplitude 1: the frame's intensity = `intensity_scale` · A_measured.
    pub intensity_scale: f64,
    /// Modulation frequency f_mod (Hz); the unambiguous range is L = c/(2 f_mod).
    pub modulation_hz: f64,
    /// Amplitude a_w of the wiggling error (m).
    pub wiggle_amplitude_m: f64,
    /// Phase φ_w of the wiggling error (rad).
    pub wiggle_phase_rad: f64,
    /// Intensity-related offset per natural-log unit of 1/A (m): weak returns read long.
    pub amplitude_offset_m_per_ln: f64,
    /// Indirect (multipath) return as a fraction of what a head-on ρ = 1 wall would return
    /// at the same range: its amplitude is `multipath_ratio` / r². ≥ 0.
    pub multipath_ratio: f64,
    /// Extra range Δ of the indirect return (m): it arrives as if from range r + Δ (an extra
    /// round-trip path of 2Δ). In [0, L/2).
    pub multipath_extra_path_m: f64,
}

impl ToFPhysics {
    /// A Helios2-like camera in its 6 m mode, inside a steel pipe. Each default and its
    /// source:
    ///
    /// - `modulation_hz` = 25 MHz: the 6 m operating mode of the LUCID Helios2 technical
    ///   reference (operating-mode table; /work/shared/notes/field-notes.md). L = 5.996 m.
    /// - `reflectivity` = 0.5: bare or lightly oxidised steel at near infrared (the Helios2
    ///   emits at 850 nm) is a mediocre, partly specular reflector; 0.5 is an assumed
    ///   middle between bright machined steel and a rusty or coated wall, not a measured
    ///   value.
    /// - `sigma_ref_m` = 2 mm, `ambient` = 0.02: Lange (2000, eq. 4.17) gives σ ∝ L·√B/A.
    ///   No citable Helios2 precision figure was found (searched "Helios2 precision accuracy
    ///   datasheet"); vendor material is commonly quoted at about 1 mm at 1 m for a bright
    ///   target in a short-range mode, so the 6 m mode (the longest wavelength, σ ∝ L) is
    ///   assumed at a few mm: σ = 2.9 mm for a head-on ρ = 0.5 wall at 1 m (A = 0.5). These
    ///   values make a 20" pipe (ID 0.484 m, sensor on the axis) noisy at grazing incidence
    ///   as the paper's simulations assume (σ = 10–50 mm): σ ≈ 2 mm at 0.5 m, 6 mm at 1 m,
    ///   22 mm at 2 m, 58 mm at 3 m (at the measured amplitude, multipath included). The
    ///   small B (no daylight inside a pipe) keeps σ close to
    ///   shot-noise-limited at A ≳ 0.1 and ambient-limited below.
    /// - `min_amplitude` = 0.003: a confidence threshold at which σ ≈ 0.1 m; in the 20" pipe
    ///   above, wall points beyond ≈ 3.7 m are invalid. Assumed.
    /// - `saturation_amplitude` = 10: a head-on ρ = 1 target closer than 0.32 m saturates
    ///   (the Helios2's working range starts near 0.3 m). Assumed.
    /// - `intensity_scale` = 1000 counts at A = 1 (arbitrary camera-like units).
    /// - `wiggle_amplitude_m` = 6 mm (12 mm peak to peak), `wiggle_phase_rad` = 0: the field
    ///   notes report tens of mm peak to peak before calibration; a factory-calibrated camera
    ///   keeps a residual, assumed here at 6 mm. Period L/4 (Lange, 2000; Lindner & Kolb,
    ///   2006).
    /// - `amplitude_offset_m_per_ln` = 3 mm: Lindner & Kolb (2006) report an
    ///   intensity-related depth error (dark returns read long); its size for the Helios2 is
    ///   unpublished: 3 mm per e-fold gives +7 mm at A = 0.1 and +14 mm at A = 0.01.
    /// - `multipath_ratio` = 0.01, `multipath_extra_path_m` = 0.5 m: multipath always
    ///   lengthens ranges, worst in concave scenes (field notes); no pipe figure is published,
    ///   so both are parameters. The indirect light is 1 % of a head-on ρ = 1 return at the
    ///   same range (≈ 4 % of the direct return at 0.5 m and 17 % at 2 m in the centred 20"
    ///   pipe), delayed by about one 20" diameter: it lengthens ranges there by ≈ 19 mm at
    ///   0.5 m, 37 mm at 1 m and 69 mm at 2 m.
    pub fn helios2() -> Self {
        Self {
            reflectivity: 0.5,
            sigma_ref_m: 0.002,
            ambient: 0.02,
            min_amplitude: 0.003,
            saturation_amplitude: 10.0,
            intensity_scale: 1000.0,
            modulation_hz: 25e6,
            wiggle_amplitude_m: 0.006,
            wiggle_phase_rad: 0.0,
            amplitude_offset_m_per_ln: 0.003,
            multipath_ratio: 0.01,
            multipath_extra_path_m: 0.5,
        }
    }

    /// Check every field; the error names the first bad one (scenario key style).
    pub fn validate(&self) -> Result<(), SimError> {
        use Rule::{Finite, NonNegative, Positive};
        let (r, extra) = (self.reflectivity, self.multipath_extra_path_m);
        let l = self.unambiguous_range();
        // (key, value, rule), in checking order.
        let checks = [
            (
                "sensor_model.reflectivity",
                r,
                Rule::Holds(r.is_finite() && r > 0.0 && r <= 1.0, "must lie in (0, 1]"),
            ),
            ("sensor_model.sigma_ref_m", self.sigma_ref_m, NonNegative),
            ("sensor_model.ambient", self.ambient, NonNegative),
            ("sensor_model.min_amplitude", self.min_amplitude, Positive),
            (
                "sensor_model.saturation_amplitude",
                self.saturation_amplitude,
                Rule::Holds(
                    self.saturation_amplitude > self.min_amplitude,
                    "must be greater than sensor_model.min_amplitude (may be infinite)",
                ),
            ),
            (
                "sensor_model.intensity_scale",
                self.intensity_scale,
                Positive,
            ),
            ("sensor_model.modulation_hz", self.modulation_hz, Positive),
            (
                "sensor_model.wiggle_amplitude_m",
                self.wiggle_amplitude_m,
                NonNegative,
            ),
            (
                "sensor_model.wiggle_phase_rad",
                self.wiggle_phase_rad,
                Finite,
            ),
            (
                "sensor_model.amplitude_offset_m_per_ln",
                self.amplitude_offset_m_per_ln,
                Finite,
            ),
            (
                "sensor_model.multipath_ratio",
                self.multipath_ratio,
                NonNegative,
            ),
            (
                "sensor_model.multipath_extra_path_m",
                extra,
                Rule::Holds(
                    extra.is_finite() && extra >= 0.0 && extra < 0.5 * l,
                    "must lie in [0, L/2), L = c/(2·sensor_model.modulation_hz)",
                ),
            ),
        ];
        match first_broken(checks) {
            Some((key, value, rule)) => Err(SimError::invalid(key, value, rule.reason())),
            None => Ok(()),
        }
    }

    /// The unambiguous range L = c/(2 f_mod) (m).
    pub fn unambiguous_range(&self) -> f64 {
        SPEED_OF_LIGHT / (2.0 * self.modulation_hz)
    }

    /// The wiggling period P = L/4 (m): 4-phase sampling aliases the odd harmonics of the
    /// non-sinusoidal modulation (3rd, 5th) onto the 4th harmonic of the range phase 2πr/L
    /// (Lange, 2000, ch. 4; Lindner & Kolb, 2006).
    pub fn wiggle_period(&self) -> f64 {
        0.25 * self.unambiguous_range()
    }

    /// Direct return amplitude A = ρ·cos θ / r² of a wall at true range `range` (m) under
    /// incidence `cos_incidence` = |d·n| (d the unit ray, n the wall normal).
    pub fn amplitude(&self, range: f64, cos_incidence: f64) -> f64 {
        self.reflectivity * cos_incidence / (range * range)
    }

    /// Standard deviation of the random range error (m) at amplitude A, after Lange (2000,
    /// eq. 4.17), σ ∝ √(A + B)/A, normalised to σ_ref at A = 1:
    /// σ(A) = σ_ref · √((A + B)/(1 + B)) / A.
    pub fn sigma_at(&self, amplitude: f64) -> f64 {
        self.sigma_ref_m * ((amplitude + self.ambient) / (1.0 + self.ambient)).sqrt() / amplitude
    }

    /// Wiggling error (m) at true range r: a_w · sin(2π r / P + φ_w), P = L/4.
    pub fn wiggle(&self, range: f64) -> f64 {
        self.wiggle_amplitude_m * (TAU * range / self.wiggle_period() + self.wiggle_phase_rad).sin()
    }

    /// Intensity-related offset (m) at measured amplitude A: k · ln(1/A), positive (long)
    /// for A < 1 (Lindner & Kolb, 2006).
    pub fn amplitude_offset(&self, amplitude: f64) -> f64 {
        -self.amplitude_offset_m_per_ln * amplitude.ln()
    }

    /// Multipath: the direct return A e^{iφ} (φ = 2π r/L) plus the indirect one
    /// a_i e^{i(φ + δ)}, a_i = `multipath_ratio`/r², δ = 2πΔ/L. Returns the range shift
    /// (m) L/(2π) · atan2(a_i sin δ, A + a_i cos δ) — the phase of the sum relative to φ,
    /// so unwrapped near r — and the measured amplitude |A + a_i e^{iδ}|. For 0 ≤ δ < π
    /// (Δ < L/2) the shift lies in [0, Δ]: multipath always lengthens the range, the more
    /// the weaker the direct return.
    pub fn multipath(&self, range: f64, amplitude: f64) -> (f64, f64) {
        let ai = self.multipath_ratio / (range * range);
        if ai == 0.0 {
            return (0.0, amplitude);
        }
        let l = self.unambiguous_range();
        let delta = TAU * self.multipath_extra_path_m / l;
        let (re, im) = (amplitude + ai * delta.cos(), ai * delta.sin());
        (l / TAU * im.atan2(re), re.hypot(im))
    }

    /// The deterministic range error (m) of a wall at true range `range` whose direct
    /// return has amplitude `amplitude` ([`ToFPhysics::amplitude`]): wiggle(r) +
    /// amplitude_offset(A_measured) + multipath shift, A_measured from
    /// [`ToFPhysics::multipath`].
    pub fn systematic_error(&self, range: f64, amplitude: f64) -> f64 {
        let (shift, measured) = self.multipath(range, amplitude);
        self.wiggle(range) + self.amplitude_offset(measured) + shift
    }

    /// Whether a pixel of measured amplitude A gives a depth:
    /// `min_amplitude` ≤ A ≤ `saturation_amplitude`.
    pub fn is_valid(&self, measured_amplitude: f64) -> bool {
        measured_amplitude >= self.min_amplitude && measured_amplitude <= self.saturation_amplitude
    }

    /// A range beyond which no pixel can be valid: the measured amplitude is at most
    /// (ρ + `multipath_ratio`)/r², below `min_amplitude` past √((ρ + ratio)/min).
    pub fn max_valid_range(&self) -> f64 {
        ((self.reflectivity + self.multipath_ratio) / self.min_amplitude).sqrt()
    }
}

impl Default for ToFPhysics {
    fn default() -> Self {
        Self::helios2()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn helios2_is_valid_and_its_figures_hold() {
        let p = ToFPhysics::helios2();
        p.validate().unwrap();
        assert!((p.unambiguous_range() - 5.995_849_16).abs() < 1e-8);
        // A head-on ρ = 0.5 wall at 1 m: A = 0.5, σ a few mm.
        let s = p.sigma_at(p.amplitude(1.0, 1.0));
        assert!((0.002..0.004).contains(&s), "{s}");
        // The centred 20" pipe (R = 0.242 m): cos θ = R/r; noisy at 2 m.
        let s2 = p.sigma_at(p.amplitude(2.0, 0.242 / 2.0));
        assert!((0.01..0.03).contains(&s2), "{s2}");
    }

    #[test]
    fn validation_names_the_field() {
        let field = |p: ToFPhysics| match p.validate().unwrap_err() {
            SimError::Invalid { field, .. } => field,
            e => panic!("{e}"),
        };
        let h = ToFPhysics::helios2();
        let cases = [
            (
                ToFPhysics {
                    reflectivity: 1.5,
                    ..h
                },
                "sensor_model.reflectivity",
            ),
            (
                ToFPhysics {
                    sigma_ref_m: f64::NAN,
                    ..h
                },
                "sensor_model.sigma_ref_m",
            ),
            (
                ToFPhysics {
                    min_amplitude: 0.0,
                    ..h
                },
                "sensor_model.min_amplitude",
            ),
            (
                ToFPhysics {
                    saturation_amplitude: 0.001,
                    ..h
                },
                "sensor_model.saturation_amplitude",
            ),
            (
                ToFPhysics {
                    modulation_hz: -1.0,
                    ..h
                },
                "sensor_model.modulation_hz",
            ),
            (
                ToFPhysics {
                    multipath_extra_path_m: 3.0,
                    ..h
                },
                "sensor_model.multipath_extra_path_m",
            ),
            (
                ToFPhysics {
                    multipath_ratio: -0.1,
                    ..h
                },
                "sensor_model.multipath_ratio",
            ),
        ];
        for (p, f) in cases {
            assert_eq!(field(p), f);
        }
        // An infinite saturation level means "never saturates".
        ToFPhysics {
            saturation_amplitude: f64::INFINITY,
            ..h
        }
        .validate()
        .unwrap();
    }

    #[test]
    fn multipath_is_a_phasor_sum() {
        let p = ToFPhysics::helios2();
        let (shift, a) = p.multipath(1.0, 0.1);
        // Hand computation: a_i = 0.01, δ = 2π·0.5/L.
        let l = p.unambiguous_range();
        let d = TAU * 0.5 / l;
        let (re, im) = (0.1 + 0.01 * d.cos(), 0.01 * d.sin());
        assert!((a - (re * re + im * im).sqrt()).abs() < 1e-15);
        assert!((shift - l * (im / re).atan() / TAU).abs() < 1e-15);
        // Only the direct return: the indirect phase; no direct return: shift → Δ.
        assert!((p.multipath(1.0, 1e-12).0 - 0.5).abs() < 1e-9);
    }
}
