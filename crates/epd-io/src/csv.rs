//! CSV written through the `csv` crate with one rule for the whole workspace: comma
//! delimited, `\n` after each record, a field quoted (with `"` doubled) exactly when it
//! holds a comma, a quote, `\n` or `\r`. Numbers are their shortest round-trip decimal
//! text (Rust's `Display`, no exponent), empty for NaN, ±∞ and no value.
//!
//! A report's text value that a spreadsheet would run as a formula (it starts with `=`,
//! `+`, `-`, `@`, a tab or a carriage return: a file named `=HYPERLINK(…).ply`) is
//! written after a `'`, as OWASP's "CSV injection" advice has it; spreadsheets show the
//! text and run nothing ([`field`], [`FORMULA_STARTS`]). Numbers are never changed
//! (`-0.5` stays a number).

use std::borrow::Cow;
use std::io::Write;

use epd_core::report::Field;

/// A CSV writer with the workspace's rule (see the module).
pub fn writer<W: Write>(w: W) -> ::csv::Writer<W> {
    ::csv::WriterBuilder::new()
        .delimiter(b',')
        .terminator(::csv::Terminator::Any(b'\n'))
        .quote_style(::csv::QuoteStyle::Necessary)
        .has_headers(false)
        .from_writer(w)
}

/// A `csv` error as an I/O error (what the writers here return).
pub fn io_error(e: ::csv::Error) -> std::io::Error {
    match e.into_kind() {
        ::csv::ErrorKind::Io(e) => e,
        other => std::io::Error::other(format!("{other:?}")),
    }
}

/// One record as a line of text, without the final `\n`.
pub fn line<I, T>(fields: I) -> String
where
    I: IntoIterator<Item = T>,
    T: AsRef<[u8]>,
{
    let mut w = writer(Vec::new());
    // Writing into memory cannot fail.
    let bytes = w
        .write_record(fields)
        .ok()
        .and_then(|()| w.into_inner().ok())
        .unwrap_or_default();
    let mut text = String::from_utf8_lossy(&bytes).into_owned();
    if text.ends_with('\n') {
        text.pop();
    }
    text
}

/// A number as CSV text: the shortest decimal that reads back to `v`, empty when `v` is
/// not finite.
pub fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        String::new()
    }
}

/// The first characters that make a spreadsheet (Excel, LibreOffice, Google Sheets) read
/// a cell as a formula: OWASP's list for CSV injection.
pub const FORMULA_STARTS: [char; 6] = ['=', '+', '-', '@', '\t', '\r'];

/// `text` as a CSV cell that no spreadsheet runs: after a `'` when it starts with one of
/// [`FORMULA_STARTS`], else as it is.
pub fn text_cell(text: &str) -> Cow<'_, str> {
    if text.starts_with(FORMULA_STARTS) {
        Cow::Owned(format!("'{text}"))
    } else {
        Cow::Borrowed(text)
    }
}

/// A report value as CSV text (before quoting): numbers as [`num`], empty for no value,
/// text through [`text_cell`].
pub fn field(f: &Field) -> Cow<'_, str> {
    match f {
        Field::Num(v) => Cow::Owned(num(*v)),
        Field::Null => Cow::Borrowed(""),
        Field::Int(v) => Cow::Owned(v.to_string()),
        Field::Int64(v) => Cow::Owned(v.to_string()),
        Field::Bool(b) => Cow::Borrowed(if *b { "true" } else { "false" }),
        Field::Text(s) => text_cell(s),
    }
}

/// The values of report fields as one CSV line (no final `\n`), in their order.
pub fn fields_line(fields: &[(&str, Field)]) -> String {
    line(fields.iter().map(|(_, v)| field(v).into_owned()))
}

/// Points (m, sensor frame) as CSV: a header `x,y,z`, then one point per line.
pub fn write_points<W: Write>(w: &mut W, points: &[[f64; 3]]) -> std::io::Result<()> {
    let mut c = writer(w);
    c.write_record(["x", "y", "z"]).map_err(io_error)?;
    for p in points {
        c.write_record(p.map(|v| format!("{v}")))
            .map_err(io_error)?;
    }
    c.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_quoting_rule() {
        assert_eq!(line(["a", "b c", ""]), "a,b c,");
        assert_eq!(line(["a,b", "say \"hi\""]), "\"a,b\",\"say \"\"hi\"\"\"");
        assert_eq!(line(["x\ny", "x\ry"]), "\"x\ny\",\"x\ry\"");
    }

    #[test]
    fn report_values() {
        let f = [
            ("a", Field::Num(1.5)),
            ("b", Field::Num(f64::NAN)),
            ("c", Field::Text("x,y".into())),
            ("d", Field::Bool(true)),
            ("e", Field::Int(7)),
            ("f", Field::Null),
            ("g", Field::Num(1e-7)),
        ];
        assert_eq!(fields_line(&f), "1.5,,\"x,y\",true,7,,0.0000001");
        assert_eq!(num(f64::INFINITY), "");
    }

    /// Text a spreadsheet would run gets a `'`; numbers, negative ones too, stay numbers.
    #[test]
    fn formulas_are_not_run() {
        let f = [
            (
                "file",
                Field::Text("=HYPERLINK(\"http://x\",\"a\").ply".into()),
            ),
            ("a", Field::Text("+1".into())),
            ("b", Field::Text("-2+3".into())),
            ("c", Field::Text("@SUM(A1)".into())),
            ("d", Field::Text("\tx".into())),
            ("e", Field::Text("\rx".into())),
            ("g", Field::Num(-0.5)),
            ("h", Field::Text("a=b".into())),
        ];
        assert_eq!(
            fields_line(&f),
            "\"'=HYPERLINK(\"\"http://x\"\",\"\"a\"\").ply\",'+1,'-2+3,'@SUM(A1),'\tx,\"'\rx\",-0.5,a=b"
        );
    }

    #[test]
    fn points_with_a_header() {
        let mut out = Vec::new();
        write_points(&mut out, &[[1.0, -0.25, 3e-5], [0.0, 0.0, 0.0]]).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "x,y,z\n1,-0.25,0.00003\n0,0,0\n"
        );
    }
}
