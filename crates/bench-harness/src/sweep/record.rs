//! One trial of a sweep as every output needs it: a [`TrialRecord`] with one
//! [`MethodRecord`] per method — a row of `trials.csv` each — made by a run
//! ([`super::trial::run_trial`]) or read back from a shard's records by a merge.
//!
//! The same types are the records of a shard ([`crate::output::RECORDS_FILE`], one JSON
//! object per trial and line): serde writes every floating-point value as the integer of
//! its IEEE-754 bit pattern ([`f64::to_bits`]), so a merge reads back exactly the values
//! the shard computed, NaN payloads and signed zeros included.

use epd_core::{FitOutcome, Method, N_PARAMS, ParamErrors, Params, Sigmas, errors_against};
use serde::{Deserialize, Serialize};

/// One method's result on one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MethodRecord {
    /// The method (its name in the records).
    #[serde(with = "bits::method")]
    pub method: Method,
    /// How the estimate's fit ended ([`epd_core::FitStatus::outcome`]); `None` when no
    /// estimate could be made (written `error`).
    pub status: Option<FitOutcome>,
    /// The reason or error message.
    pub message: String,
    /// Solver iterations.
    pub iterations: usize,
    /// Wall time of the estimate call alone (ms).
    #[serde(with = "bits::float")]
    pub time_ms: f64,
    /// The canonical estimate, when one was made.
    #[serde(with = "bits::opt_params")]
    pub estimate: Option<Params>,
    /// Its reported 1-σ.
    #[serde(with = "bits::sigmas")]
    pub sigma: Sigmas,
    /// Estimate − truth under the symmetries.
    #[serde(with = "bits::opt_errors")]
    pub errors: Option<ParamErrors>,
    /// The geometry ahead the frame library reported (`straight`, `bend_ahead`,
    /// `tee_ahead`, `in_bend`) when the scenario surveys it (`geometry = true`); `None`
    /// otherwise, or when no estimate could be made.
    #[serde(default)]
    pub geometry: Option<String>,
    /// Whether the survey withheld the straight section's estimate (in a bend, or too
    /// little straight pipe in view): `epd estimate` then reports no diameters, so the
    /// trial does not count in the statistics.
    #[serde(default)]
    pub straight_withheld: bool,
}

impl MethodRecord {
    /// Whether the fit converged and its estimate is reported (the trial counts in the
    /// statistics).
    pub fn ok(&self) -> bool {
        self.status == Some(FitOutcome::Converged)
            && self.errors.is_some()
            && !self.straight_withheld
    }

    /// Whether the frame's geometry was reported as anything but `straight` (`None`: no
    /// geometry reported).
    pub fn false_alarm(&self) -> Option<bool> {
        self.geometry.as_deref().map(|g| g != "straight")
    }

    /// The status as written in `trials.csv`: the estimate's, or `error`.
    pub fn status_name(&self) -> &'static str {
        self.status.map_or("error", FitOutcome::name)
    }
}

/// One trial of one setting: the frame's truth and bound, and every method's result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrialRecord {
    /// Index of the setting (swept value) in the scenario.
    pub setting: usize,
    /// Trial index within the setting.
    pub trial: usize,
    /// Points in the cloud the methods saw.
    pub n_points: usize,
    /// The true β (canonical form).
    #[serde(with = "bits::params")]
    pub truth: Params,
    /// Cramér–Rao 1-σ per parameter for range noise of the setting's σ.
    #[serde(with = "bits::sigmas")]
    pub crb: Sigmas,
    /// Why the frame could not be made, if it could not.
    pub error: Option<String>,
    /// One record per method, in the scenario's order.
    pub methods: Vec<MethodRecord>,
}

impl TrialRecord {
    /// Trials or estimates of this trial that could not be made at all (status
    /// `error`): the frame, and each method without an estimate.
    pub fn errors(&self) -> usize {
        usize::from(self.error.is_some())
            + self.methods.iter().filter(|m| m.status.is_none()).count()
    }

    /// Whether the record agrees with itself: each method's `errors` are its estimate
    /// against the trial's truth ([`errors_against`], bit for bit: the merge runs the
    /// shards' code), and a method has errors exactly when it has an estimate; else what
    /// disagrees. An edited estimate or truth (a digit changed by hand) is caught here.
    pub fn check_consistent(&self) -> Result<(), String> {
        let bits = |e: &ParamErrors| {
            [
                e.d_max, e.d_min, e.d_mean, e.roll, e.pitch, e.yaw, e.dy, e.dz,
            ]
            .map(f64::to_bits)
        };
        for m in &self.methods {
            let agrees = match (&m.estimate, &m.errors) {
                (Some(est), Some(err)) => bits(&errors_against(est, &self.truth)) == bits(err),
                (None, None) => true,
                _ => false,
            };
            if !agrees {
                return Err(format!(
                    "trial {} of setting {}, method `{}`: its errors are not its estimate \
                     against the trial's truth (the record was changed after the shard ran)",
                    self.trial,
                    self.setting,
                    m.method.name()
                ));
            }
        }
        Ok(())
    }

    /// Whether the record's methods are `methods`, in that order (a record read back from
    /// a shard); else what differs.
    pub fn check_methods(&self, methods: &[Method]) -> Result<(), String> {
        if self.methods.len() != methods.len() {
            return Err(format!(
                "trial {} of setting {} has {} methods, the scenario {}",
                self.trial,
                self.setting,
                self.methods.len(),
                methods.len()
            ));
        }
        for (r, &m) in self.methods.iter().zip(methods) {
            if r.method != m {
                return Err(format!(
                    "trial {} of setting {}: method `{}` where the scenario has `{}`",
                    self.trial,
                    self.setting,
                    r.method.name(),
                    m.name()
                ));
            }
        }
        Ok(())
    }
}

/// The serde forms of the records' fields: floats as their bit patterns, a method as its
/// name.
mod bits {
    use super::*;
    use serde::{Deserializer, Serializer, de::Error};

    /// An `f64` as `u64` bits.
    pub(super) mod float {
        use super::*;

        pub(crate) fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
            v.to_bits().serialize(s)
        }

        pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
            u64::deserialize(d).map(f64::from_bits)
        }
    }

    /// β as the bits of its seven values, in [`Params::to_array`] order.
    pub(super) mod params {
        use super::*;

        pub(crate) fn serialize<S: Serializer>(p: &Params, s: S) -> Result<S::Ok, S::Error> {
            p.to_array().map(f64::to_bits).serialize(s)
        }

        pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Params, D::Error> {
            <[u64; N_PARAMS]>::deserialize(d).map(|a| Params::from_array(a.map(f64::from_bits)))
        }
    }

    /// An optional β (`null` when none).
    pub(super) mod opt_params {
        use super::*;

        pub(crate) fn serialize<S: Serializer>(
            p: &Option<Params>,
            s: S,
        ) -> Result<S::Ok, S::Error> {
            p.map(|p| p.to_array().map(f64::to_bits)).serialize(s)
        }

        pub(crate) fn deserialize<'de, D: Deserializer<'de>>(
            d: D,
        ) -> Result<Option<Params>, D::Error> {
            Option::<[u64; N_PARAMS]>::deserialize(d)
                .map(|a| a.map(|a| Params::from_array(a.map(f64::from_bits))))
        }
    }

    /// Seven optional 1-σ.
    pub(super) mod sigmas {
        use super::*;

        pub(crate) fn serialize<S: Serializer>(v: &Sigmas, s: S) -> Result<S::Ok, S::Error> {
            v.map(|v| v.map(f64::to_bits)).serialize(s)
        }

        pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Sigmas, D::Error> {
            <[Option<u64>; N_PARAMS]>::deserialize(d).map(|a| a.map(|v| v.map(f64::from_bits)))
        }
    }

    /// The eight errors (Dmax, Dmin, mean diameter, roll, pitch, yaw, δy, δz), or `null`.
    pub(super) mod opt_errors {
        use super::*;

        pub(crate) fn serialize<S: Serializer>(
            e: &Option<ParamErrors>,
            s: S,
        ) -> Result<S::Ok, S::Error> {
            e.map(|e| {
                [
                    e.d_max, e.d_min, e.d_mean, e.roll, e.pitch, e.yaw, e.dy, e.dz,
                ]
                .map(f64::to_bits)
            })
            .serialize(s)
        }

        pub(crate) fn deserialize<'de, D: Deserializer<'de>>(
            d: D,
        ) -> Result<Option<ParamErrors>, D::Error> {
            Ok(Option::<[u64; 8]>::deserialize(d)?.map(|e| {
                let [d_max, d_min, d_mean, roll, pitch, yaw, dy, dz] = e.map(f64::from_bits);
                ParamErrors {
                    d_max,
                    d_min,
                    d_mean,
                    roll,
                    pitch,
                    yaw,
                    dy,
                    dz,
                }
            }))
        }
    }

    /// A method by its name ([`Method::name`], read back with its `FromStr`).
    pub(super) mod method {
        use super::*;

        pub(crate) fn serialize<S: Serializer>(m: &Method, s: S) -> Result<S::Ok, S::Error> {
            s.serialize_str(m.name())
        }

        pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Method, D::Error> {
            let name = String::deserialize(d)?;
            name.parse().map_err(D::Error::custom)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_bit_for_bit() {
        let nan_payload = f64::from_bits(0x7ff8_0000_0000_1234);
        let record = TrialRecord {
            setting: 2,
            trial: 17,
            n_points: 306_001,
            truth: Params::from_array([0.1 + 0.2, 1e-300, -0.0, 5e-324, 1.0 / 3.0, -2.5, 7.0]),
            crb: [
                Some(1e-7),
                None,
                Some(f64::INFINITY),
                None,
                None,
                None,
                Some(nan_payload),
            ],
            methods: vec![
                MethodRecord {
                    method: Method::CEpd,
                    status: Some(FitOutcome::Implausible),
                    message: "a \"quoted\", multi\nline message".into(),
                    iterations: 12,
                    time_ms: 2.718_281_828_459_1,
                    estimate: Some(Params::from_array([0.49, 0.48, 0.1, 0.2, 0.3, 0.01, -0.02])),
                    sigma: [None, Some(1e-5), None, None, None, None, Some(2e-5)],
                    errors: Some(ParamErrors {
                        d_max: 1e-4,
                        d_min: -2e-4,
                        d_mean: -5e-5,
                        roll: 0.1,
                        pitch: f64::NAN,
                        yaw: -0.0,
                        dy: 1e-3,
                        dz: 2e-3,
                    }),
                    geometry: Some("tee_ahead".into()),
                    straight_withheld: true,
                },
                MethodRecord {
                    method: Method::MlEpd,
                    status: None,
                    message: "no estimate".into(),
                    iterations: 0,
                    time_ms: 0.0,
                    estimate: None,
                    sigma: [None; N_PARAMS],
                    errors: None,
                    geometry: None,
                    straight_withheld: false,
                },
            ],
            error: Some("x".into()),
        };
        let line = serde_json::to_string(&record).unwrap();
        assert!(!line.contains('\n'));
        // The form of the records file: floats as their bits, the fields in this order.
        assert!(
            line.starts_with(&format!(
                r#"{{"setting":2,"trial":17,"n_points":306001,"truth":[{},"#,
                (0.1f64 + 0.2).to_bits()
            )),
            "{line}"
        );
        assert!(
            line.contains(r#""error":"x","methods":[{"method":"c-epd","status":"implausible""#),
            "{line}"
        );
        let back: TrialRecord = serde_json::from_str(&line).unwrap();
        back.check_methods(&[Method::CEpd, Method::MlEpd]).unwrap();
        // Bit for bit, NaN payloads and signed zeros included.
        let again = serde_json::to_string(&back).unwrap();
        assert_eq!(line, again);
        assert_eq!(
            back.truth.to_array().map(f64::to_bits),
            record.truth.to_array().map(f64::to_bits)
        );
        assert_eq!(back.methods[0].message, record.methods[0].message);
        assert_eq!(back.methods[0].geometry.as_deref(), Some("tee_ahead"));
        assert!(back.methods[0].straight_withheld && !back.methods[0].ok());
        // Records of a shard written before the geometry was recorded read back as
        // not surveyed.
        let old = line
            .replace(r#","geometry":"tee_ahead","straight_withheld":true"#, "")
            .replace(r#","geometry":null,"straight_withheld":false"#, "");
        assert!(!old.contains("geometry"), "{old}");
        let old: TrialRecord = serde_json::from_str(&old).unwrap();
        assert_eq!(old.methods[0].geometry, None);
        assert!(!old.methods[0].straight_withheld);
        assert_eq!(
            back.methods[0].time_ms.to_bits(),
            record.methods[0].time_ms.to_bits()
        );
        // The scenario's methods must match, in order.
        assert!(back.check_methods(&[Method::MlEpd, Method::CEpd]).is_err());
        assert!(back.check_methods(&[Method::CEpd]).is_err());
        // The status is written by serde as the name of `trials.csv` (`error` is no
        // status: a missing estimate is `null`), and an unknown name is refused.
        assert!(line.contains(r#""status":"implausible""#), "{line}");
        assert!(line.contains(r#""status":null"#), "{line}");
        let bad = line.replace("implausible", "fine");
        let e = serde_json::from_str::<TrialRecord>(&bad).expect_err("refused");
        assert!(e.to_string().contains("unknown variant `fine`"), "{e}");
        let bad = line.replace("\"c-epd\"", "\"d-epd\"");
        assert!(serde_json::from_str::<TrialRecord>(&bad).is_err());
    }

    #[test]
    fn statuses_are_written_with_their_names() {
        for o in FitOutcome::ALL {
            let json = serde_json::to_string(&o).unwrap();
            assert_eq!(json, format!("\"{}\"", o.name()));
            assert_eq!(serde_json::from_str::<FitOutcome>(&json).unwrap(), o);
        }
        let names = FitOutcome::ALL.map(FitOutcome::name);
        assert_eq!(
            names,
            [
                "converged",
                "iteration_limit",
                "degenerate",
                "implausible",
                "lack_of_fit"
            ]
        );
    }
}
