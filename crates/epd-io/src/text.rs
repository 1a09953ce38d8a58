//! Delimited text: `x y z` per line, separated by commas, semicolons, tabs or spaces,
//! with an optional header. A header naming `x`, `y` and `z` picks those columns;
//! otherwise the first three are x, y, z. Other numeric columns are kept by name.
//!
//! Also read: a UTF-8 byte-order mark; UTF-16 text with a byte-order mark; lines starting
//! with `#` or `//` (comments; CloudCompare's `//X,Y,Z,…` header line names the columns);
//! PTS and CloudCompare ASC files, whose first line is the point count (also before each
//! further scan of a multi-scan PTS file) and whose columns after x, y, z are
//! `intensity` (4 columns), `r g b` (6) or `intensity r g b` (7). Binary data are refused
//! with the offset of the first byte that is not text.

use crate::read::{PointCloud, ReadError, err, quote};

const F: &str = "CSV";

fn fields(line: &str) -> Vec<&str> {
    line.split(|c: char| c == ',' || c == ';' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .collect()
}

/// Whether a character code is one text files hold: not a control code other than tab,
/// line feed, vertical tab, form feed and carriage return.
fn is_text(c: u32) -> bool {
    (c >= 0x20 || matches!(c, 0x09..=0x0d)) && c != 0x7f
}

/// The file as text: UTF-8 (after an optional byte-order mark) or UTF-16 with a
/// byte-order mark; an error naming the first byte that is not text.
fn decode(bytes: &[u8]) -> Result<std::borrow::Cow<'_, str>, ReadError> {
    let not_text = |what: String| err(F, format!("not text: {what}"));
    for (bom, little) in [(b"\xff\xfe", true), (b"\xfe\xff", false)] {
        if let Some(rest) = bytes.strip_prefix(bom) {
            let units: Vec<u16> = rest
                .chunks(2)
                .map(|c| match c {
                    [a, b] if little => u16::from_le_bytes([*a, *b]),
                    [a, b] => u16::from_be_bytes([*a, *b]),
                    _ => 0,
                })
                .collect();
            if rest.len() % 2 == 1 {
                return Err(not_text(
                    "UTF-16 text (it starts with a UTF-16 byte-order mark) of an odd number of bytes".into(),
                ));
            }
            if let Some(k) = units.iter().position(|&u| !is_text(u as u32)) {
                return Err(not_text(format!(
                    "UTF-16 code 0x{:04x} at offset {} (a binary file?)",
                    units[k],
                    2 + 2 * k
                )));
            }
            return String::from_utf16(&units)
                .map(std::borrow::Cow::Owned)
                .map_err(|_| not_text("invalid UTF-16 (unpaired surrogate)".into()));
        }
    }
    let (skip, body) = without_bom(bytes);
    // A DOS end-of-file mark (Ctrl-Z) may end the file.
    let body = body.strip_suffix(b"\x1a").unwrap_or(body);
    if let Some(m) = binary_byte(body, skip, None) {
        return Err(not_text(m));
    }
    std::str::from_utf8(body)
        .map(std::borrow::Cow::Borrowed)
        .map_err(|e| {
            let k = e.valid_up_to();
            not_text(format!(
                "byte 0x{:02x} at offset {} is not UTF-8 (save the file as UTF-8)",
                body.get(k).copied().unwrap_or(0),
                skip + k
            ))
        })
}

/// Column names from a header line (lowercase, quotes removed), an error when one is
/// there twice.
fn header_names(f: &[&str], line_no: usize) -> Result<Vec<String>, ReadError> {
    let names: Vec<String> = f
        .iter()
        .map(|s| s.trim_matches('"').trim_matches('\'').to_ascii_lowercase())
        .collect();
    let mut seen = std::collections::HashSet::new();
    for n in &names {
        if !seen.insert(n.as_str()) {
            return Err(err(
                F,
                format!(
                    "line {line_no}: the header names column `{}` twice",
                    quote(n)
                ),
            ));
        }
    }
    Ok(names)
}

/// The error [`read`] would give for the text's first bytes `head`, when they already hold
/// a byte that is not text (a control code, NUL): found before the rest of a stream is read
/// (`epd estimate - < /dev/zero` had read 4 GiB to say so). `None` for UTF-16 text (its
/// units are checked whole) and when the head is text; a DOS end-of-file mark is left to
/// [`read`], as it may end the file.
pub(crate) fn early_not_text(head: &[u8]) -> Option<ReadError> {
    if head.starts_with(b"\xff\xfe") || head.starts_with(b"\xfe\xff") {
        return None;
    }
    let (skip, body) = without_bom(head);
    binary_byte(body, skip, Some(0x1a)).map(|m| err(F, format!("not text: {m}")))
}

/// UTF-8 text after its optional byte-order mark, and the mark's length.
fn without_bom(bytes: &[u8]) -> (usize, &[u8]) {
    match bytes.strip_prefix(b"\xef\xbb\xbf") {
        Some(rest) => (3, rest),
        None => (0, bytes),
    }
}

/// The first byte of `body` (which starts at offset `skip` of the file) that is not text
/// nor `allowed`, as "byte 0x.. at offset N (a binary file?)".
fn binary_byte(body: &[u8], skip: usize, allowed: Option<u8>) -> Option<String> {
    let k = body
        .iter()
        .position(|&c| !is_text(c as u32) && Some(c) != allowed)?;
    Some(format!(
        "byte 0x{:02x} at offset {} (a binary file?)",
        body[k],
        skip + k
    ))
}

/// Read delimited text.
pub fn read(bytes: &[u8]) -> Result<PointCloud, ReadError> {
    let text = decode(bytes)?;
    let mut r = Reader::default();
    // Lines end in LF (or CR LF: the CR is trimmed with the line's spaces), or in CR alone
    // when the text holds no LF (classic Mac OS text, some instruments' exports).
    let end = if text.contains('\n') { '\n' } else { '\r' };
    for (i, raw) in text.split(end).enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(comment) = line.strip_prefix("//") {
            r.comment_header(comment, i + 1)?;
            continue;
        }
        let f = fields(line);
        if r.point_count(&f) {
            continue;
        }
        let nums: Result<Vec<f64>, _> = f.iter().map(|s| s.parse::<f64>()).collect();
        match nums {
            Ok(v) => r.row(&v, i + 1)?,
            Err(_) if r.cloud.points.is_empty() && r.width.is_none() && r.names.is_empty() => {
                // A header that starts with a delimiter names its first column with
                // nothing: an index, as pandas writes one (`,x,y,z`), kept as `column1`
                // like any unnamed column.
                let mut names = f;
                if line.starts_with([',', ';']) {
                    names.insert(0, "column1");
                }
                r.header(&names, i + 1)?;
            }
            Err(_) => {
                return Err(err(
                    F,
                    format!("line {}: `{}` is not a row of numbers", i + 1, quote(line)),
                ));
            }
        }
    }
    if let Some((count, rows)) = r.scan
        && rows != count
    {
        // The point count of a PTS or ASC file (or of its last scan) is the writer's
        // word for what follows it: fewer rows is a file cut short, more a damaged count.
        return Err(err(
            F,
            format!(
                "the point-count line says {count} points, {rows} rows follow it{}",
                if rows < count { " (truncated?)" } else { "" }
            ),
        ));
    }
    Ok(r.cloud)
}

/// What the lines read so far say.
#[derive(Default)]
struct Reader {
    cloud: PointCloud,
    /// The columns of x, y and z, when a header names them (else the first three).
    columns: Option<[usize; 3]>,
    /// The header's column names (lowercase), if there is a header.
    names: Vec<String>,
    /// Values per row, set by the first row.
    width: Option<usize>,
    /// Point-count lines (PTS, ASC): the count of the current scan and its rows so far.
    scan: Option<(u64, u64)>,
}

impl Reader {
    /// A `//` comment: CloudCompare writes its header as one (`//X,Y,Z,R,G,B`), taken
    /// when it names x, y and z and comes before any row or other header.
    fn comment_header(&mut self, comment: &str, line_no: usize) -> Result<(), ReadError> {
        let f = fields(comment);
        if self.width.is_none() && self.names.is_empty() {
            let n = header_names(&f, line_no)?;
            let pos = |c: &str| n.iter().position(|v| v == c);
            if let (Some(x), Some(y), Some(z)) = (pos("x"), pos("y"), pos("z")) {
                self.columns = Some([x, y, z]);
                self.names = n;
            }
        }
        Ok(())
    }

    /// Whether `f` is a point count alone on a line at the start, or after a complete
    /// scan of a file that started with one; it then starts a scan.
    fn point_count(&mut self, f: &[&str]) -> bool {
        if let [one] = f
            && let Ok(count) = one.parse::<u64>()
        {
            let starts =
                self.width.is_none() && self.cloud.points.is_empty() && self.scan.is_none();
            let next_scan = self.scan.is_some_and(|(n, rows)| rows == n);
            if starts || next_scan {
                self.scan = Some((count, 0));
                return true;
            }
        }
        false
    }

    /// A header line: its names, and the columns of x, y and z when it names them.
    fn header(&mut self, f: &[&str], line_no: usize) -> Result<(), ReadError> {
        self.names = header_names(f, line_no)?;
        let pos = |n: &str| self.names.iter().position(|c| c == n);
        if let (Some(x), Some(y), Some(z)) = (pos("x"), pos("y"), pos("z")) {
            self.columns = Some([x, y, z]);
        }
        Ok(())
    }

    /// One row of numbers: a point and its extra values.
    fn row(&mut self, v: &[f64], line_no: usize) -> Result<(), ReadError> {
        let [cx, cy, cz] = self.columns.unwrap_or([0, 1, 2]);
        let need = cx.max(cy).max(cz) + 1;
        if v.len() < need {
            return Err(err(
                F,
                format!(
                    "line {line_no}: {} values, at least {need} expected (x, y, z)",
                    v.len()
                ),
            ));
        }
        match self.width {
            None => self.first_row(v.len(), [cx, cy, cz]),
            Some(w) if w != v.len() => {
                return Err(err(
                    F,
                    format!("line {line_no}: {} values, the first row had {w}", v.len()),
                ));
            }
            _ => {}
        }
        if let Some((_, rows)) = &mut self.scan {
            *rows += 1;
        }
        self.cloud.points.push([v[cx], v[cy], v[cz]]);
        let mut extra = self.cloud.extra.iter_mut();
        for (c, val) in v.iter().enumerate() {
            if c != cx
                && c != cy
                && c != cz
                && let Some((_, values)) = extra.next()
            {
                values.push(*val);
            }
        }
        Ok(())
    }

    /// The first row sets the width and names the columns other than x, y, z: by the
    /// header, else by PTS's layout after a point count, else `columnN`.
    fn first_row(&mut self, width: usize, [cx, cy, cz]: [usize; 3]) {
        self.width = Some(width);
        let pts: &[&str] = match (self.scan.is_some() && self.names.is_empty(), width) {
            (true, 4) => &["intensity"],
            (true, 6) => &["r", "g", "b"],
            (true, 7) => &["intensity", "r", "g", "b"],
            _ => &[],
        };
        for c in 0..width {
            if c != cx && c != cy && c != cz {
                let name = self
                    .names
                    .get(c)
                    .cloned()
                    .or_else(|| pts.get(c.wrapping_sub(3)).map(|s| s.to_string()))
                    .unwrap_or_else(|| format!("column{}", c + 1));
                self.cloud.extra.push((name, Vec::new()));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_encodings() {
        let p = read(b"\xef\xbb\xbfx,y,z\n1,2,3\n").unwrap();
        assert_eq!(p.points, [[1.0, 2.0, 3.0]]);
        let utf16: Vec<u8> = "\u{feff}1 2 3\r\n4 5 6\r\n"
            .encode_utf16()
            .flat_map(|u| u.to_le_bytes())
            .collect();
        assert_eq!(read(&utf16).unwrap().points.len(), 2);
        let e = read(b"1 2 3\n4 5\x006\n").unwrap_err().to_string();
        assert_eq!(e, "CSV: not text: byte 0x00 at offset 9 (a binary file?)");
        let e = read(b"1 2 3\n\xff").unwrap_err().to_string();
        assert!(e.contains("byte 0xff at offset 6 is not UTF-8"), "{e}");
        assert_eq!(read(b"1 2 3\n\x1a").unwrap().points.len(), 1);
    }

    /// pandas' `to_csv` keeps the index as a first column whose header names nothing:
    /// the named columns are the ones after it.
    #[test]
    fn an_unnamed_index_column_is_not_x() {
        let p = read(b",x,y,z,intensity\n0,1.5,0.2,-0.1,40\n1,1.6,0.1,0.2,41\n").unwrap();
        assert_eq!(p.points, [[1.5, 0.2, -0.1], [1.6, 0.1, 0.2]]);
        let index = ("column1".to_string(), vec![0.0, 1.0]);
        assert_eq!(
            p.extra,
            [index, ("intensity".to_string(), vec![40.0, 41.0])]
        );
        let p = read(b";x;y;z\n7;1;2;3\n").unwrap();
        assert_eq!(p.points, [[1.0, 2.0, 3.0]]);
    }

    #[test]
    fn count_lines() {
        // Two scans, each after its point count.
        let c = read(b"2\n1 2 3 5\n4 5 6 7\n1\n7 8 9 1\n").unwrap();
        assert_eq!(c.points.len(), 3);
        assert_eq!(c.extra, [("intensity".to_string(), vec![5.0, 7.0, 1.0])]);
        // A single value is not a count line within a scan.
        let e = read(b"2\n1 2 3\n4\n").unwrap_err().to_string();
        assert!(e.contains("line 3: 1 values"), "{e}");
        let e = read(b"1\n2\n3\n").unwrap_err().to_string();
        assert!(e.contains("line 2: 1 values"), "{e}");
    }

    /// A count line that the rows after it do not match is an error naming both (a PTS
    /// file cut short had been read as complete).
    #[test]
    fn a_count_the_rows_do_not_match_is_an_error() {
        let e = read(b"3\n1 2 3\n4 5 6\n").unwrap_err().to_string();
        assert!(
            e.contains("says 3 points, 2 rows follow it (truncated?)"),
            "{e}"
        );
        let e = read(b"2\n1 2 3\n4 5 6\n1\n").unwrap_err().to_string();
        assert!(e.contains("says 1 points, 0 rows"), "{e}");
        assert_eq!(read(b"2\n1 2 3\n4 5 6\n").unwrap().points.len(), 2);
    }

    /// Lines ending in CR alone are lines (they had been read as one line).
    #[test]
    fn carriage_returns_alone_end_lines() {
        let c = read(b"x,y,z\r1,2,3\r4,5,6\r").unwrap();
        assert_eq!(c.points, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        let c = read(b"1 2 3\r\n4 5 6\r\n").unwrap();
        assert_eq!(c.points.len(), 2);
    }

    #[test]
    fn cloudcompare_header_comment() {
        let c = read(b"//X,Y,Z,R,G,B\n1,2,3,4,5,6\n").unwrap();
        let names: Vec<&str> = c.extra.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["r", "g", "b"]);
    }
}
