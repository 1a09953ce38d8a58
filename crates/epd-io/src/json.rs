//! JSON through `serde_json`, with numbers written as the rest of the workspace writes
//! them: the shortest decimal that reads back to the same `f64`, without an exponent
//! (Rust's `Display`: `0.0000001`, `100`), so files keep their bytes across versions.
//! NaN and ±∞ are `null`.

use std::io::Write;

use epd_core::report::Field;
use serde::ser::{Serialize, SerializeMap, Serializer};

/// A `serde_json` formatter that writes `f64` with `Display` (see the module).
#[derive(Clone, Copy, Debug, Default)]
pub struct DecimalFormatter;

impl serde_json::ser::Formatter for DecimalFormatter {
    fn write_f64<W: ?Sized + Write>(&mut self, w: &mut W, value: f64) -> std::io::Result<()> {
        // serde_json calls this for finite values only (NaN and ±∞ become `null`).
        write!(w, "{value}")
    }

    fn write_f32<W: ?Sized + Write>(&mut self, w: &mut W, value: f32) -> std::io::Result<()> {
        write!(w, "{value}")
    }
}

/// `value` as compact JSON (numbers as in the module doc).
pub fn to_string<T: Serialize + ?Sized>(value: &T) -> Result<String, serde_json::Error> {
    let mut out = Vec::new();
    let mut ser = serde_json::Serializer::with_formatter(&mut out, DecimalFormatter);
    value.serialize(&mut ser)?;
    // serde_json writes UTF-8 only.
    String::from_utf8(out).map_err(|e| serde::ser::Error::custom(e.to_string()))
}

/// Report fields as one JSON object, keys in their order: [`Field::Num`] a number (or
/// `null` when not finite), [`Field::Int`] and [`Field::Int64`] an integer, [`Field::Text`] a string,
/// [`Field::Bool`] a boolean, [`Field::Null`] `null`.
#[derive(Clone, Copy, Debug)]
pub struct Fields<'a>(pub &'a [(&'a str, Field)]);

/// One report value (see [`Fields`]).
struct Value<'a>(&'a Field);

impl Serialize for Value<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self.0 {
            Field::Num(v) if v.is_finite() => s.serialize_f64(*v),
            Field::Num(_) | Field::Null => s.serialize_unit(),
            Field::Int(v) => s.serialize_u64(*v),
            Field::Int64(v) => s.serialize_i64(*v),
            Field::Bool(b) => s.serialize_bool(*b),
            Field::Text(t) => s.serialize_str(t),
        }
    }
}

impl Serialize for Fields<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in self.0 {
            m.serialize_entry(k, &Value(v))?;
        }
        m.end()
    }
}

/// Report fields as one compact JSON object (see [`Fields`]).
pub fn object(fields: &[(&str, Field)]) -> String {
    // Serialising strings, numbers and booleans into memory cannot fail.
    to_string(&Fields(fields)).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_fields_as_an_object() {
        let f = [
            ("a", Field::Num(1.5)),
            ("b", Field::Num(f64::NAN)),
            ("c", Field::Text("x\"y\\z\n\r\t\u{1}".into())),
            ("d", Field::Bool(true)),
            ("e", Field::Int(7)),
            ("f", Field::Null),
            ("g", Field::Num(1e-7)),
            ("h", Field::Num(100.0)),
            ("i", Field::Num(-2.5e21)),
        ];
        assert_eq!(
            object(&f),
            r#"{"a":1.5,"b":null,"c":"x\"y\\z\n\r\t\u0001","d":true,"e":7,"f":null,"g":0.0000001,"h":100,"i":-2500000000000000000000}"#
        );
    }

    /// Finite numbers over the range reports hold read back to themselves.
    #[test]
    fn numbers_round_trip() {
        for v in [0.1, 1.0 / 3.0, 6.02e23, 1e-12, -2.5e-7, 123456.789, 1e300] {
            let text = object(&[("v", Field::Num(v))]);
            let back: serde_json::Value = serde_json::from_str(&text).unwrap();
            assert_eq!(back["v"].as_f64().unwrap().to_bits(), v.to_bits(), "{text}");
        }
    }
}
