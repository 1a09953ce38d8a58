//! An estimate as named fields in the units of reports (mm, degrees): one list of keys
//! shared by every front end (the `estimate` example, the `epd` tool's JSON, CSV and text).

use crate::estimate::Estimate;

/// A value of a report field.
#[derive(Clone, Debug, PartialEq)]
pub enum Field {
    /// A number (mm, degrees, ms or a count, as the key says).
    Num(f64),
    /// A whole number.
    Int(u64),
    /// Text.
    Text(String),
    /// A flag.
    Bool(bool),
    /// No value (e.g. the 1-σ of an undetermined roll).
    Null,
}

const MM: f64 = 1e3;
const DEG: f64 = 180.0 / std::f64::consts::PI;

/// The fields of an estimate, in order: `method, status, status_reason, iterations,
/// n_points, n_dropped, d_max_mm, d_min_mm, roll_deg, pitch_deg, yaw_deg, dy_mm, dz_mm,
/// roll_determined, sigma_d_max_mm, sigma_d_min_mm, sigma_roll_deg, sigma_pitch_deg,
/// sigma_yaw_deg, sigma_dy_mm, sigma_dz_mm`.
pub fn estimate_fields(est: &Estimate) -> Vec<(&'static str, Field)> {
    let p = est.params;
    let num = |v: f64| {
        if v.is_finite() {
            Field::Num(v)
        } else {
            Field::Null
        }
    };
    let sig = |i: usize, s: f64| est.sigma[i].map_or(Field::Null, |v| num(v * s));
    vec![
        ("method", Field::Text(est.method.name().into())),
        ("status", Field::Text(est.status.name().into())),
        ("status_reason", Field::Text(est.status.reason())),
        ("iterations", Field::Int(est.iterations as u64)),
        ("n_points", Field::Int(est.n_points as u64)),
        ("n_dropped", Field::Int(est.n_dropped as u64)),
        ("d_max_mm", num(p.d_max * MM)),
        ("d_min_mm", num(p.d_min * MM)),
        ("roll_deg", num(p.roll * DEG)),
        ("pitch_deg", num(p.pitch * DEG)),
        ("yaw_deg", num(p.yaw * DEG)),
        ("dy_mm", num(p.dy * MM)),
        ("dz_mm", num(p.dz * MM)),
        ("roll_determined", Field::Bool(est.roll_determined)),
        ("sigma_d_max_mm", sig(0, MM)),
        ("sigma_d_min_mm", sig(1, MM)),
        ("sigma_roll_deg", sig(2, DEG)),
        ("sigma_pitch_deg", sig(3, DEG)),
        ("sigma_yaw_deg", sig(4, DEG)),
        ("sigma_dy_mm", sig(5, MM)),
        ("sigma_dz_mm", sig(6, MM)),
    ]
}

impl Field {
    /// The value as JSON (`null` for [`Field::Null`] and non-finite numbers).
    pub fn json(&self) -> String {
        match self {
            Field::Num(v) if v.is_finite() => format!("{v}"),
            Field::Num(_) | Field::Null => "null".into(),
            Field::Int(v) => v.to_string(),
            Field::Bool(b) => b.to_string(),
            Field::Text(s) => json_string(s),
        }
    }

    /// The value as a CSV field (empty for no value; quoted when needed).
    pub fn csv(&self) -> String {
        match self {
            Field::Num(v) if v.is_finite() => format!("{v}"),
            Field::Num(_) | Field::Null => String::new(),
            Field::Int(v) => v.to_string(),
            Field::Bool(b) => b.to_string(),
            Field::Text(s) if s.contains([',', '"', '\n', '\r']) => {
                format!("\"{}\"", s.replace('"', "\"\""))
            }
            Field::Text(s) => s.clone(),
        }
    }
}

/// A JSON string literal.
fn json_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// Fields as one JSON object, keys in the given order.
pub fn json_object(fields: &[(&str, Field)]) -> String {
    let body: Vec<String> = fields
        .iter()
        .map(|(k, v)| format!("{}:{}", json_string(k), v.json()))
        .collect();
    format!("{{{}}}", body.join(","))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_and_csv_encoding() {
        let f = [
            ("a", Field::Num(1.5)),
            ("b", Field::Num(f64::NAN)),
            ("c", Field::Text("x\"y\\z\n".into())),
            ("d", Field::Bool(true)),
            ("e", Field::Int(7)),
            ("f", Field::Null),
        ];
        assert_eq!(
            json_object(&f),
            r#"{"a":1.5,"b":null,"c":"x\"y\\z\n","d":true,"e":7,"f":null}"#
        );
        assert_eq!(Field::Text("a,b".into()).csv(), "\"a,b\"");
        assert_eq!(Field::Num(f64::INFINITY).csv(), "");
        assert_eq!(Field::Num(1e-7).json(), "0.0000001");
    }
}
