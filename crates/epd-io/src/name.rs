//! Names shown as data: a file name (or a message quoting one) printed for people cannot
//! move the cursor, ring the bell, start a new line or turn the text around, so a crafted
//! name cannot fake a result line; a name that is not UTF-8 is carried whole.
//!
//! - [`escape_controls`]: control characters as visible escapes: `\n`, `\r`, `\t`, `\xNN`
//!   (the other C0 codes and DEL), `\u{NN}` (C1 codes), and the characters that move or
//!   reorder text without being control codes: the line and paragraph separators
//!   (U+2028, U+2029) and the bidirectional marks, embeddings, overrides and isolates
//!   (U+061C, U+200E, U+200F, U+202A–U+202E, U+2066–U+2069). A backslash is left as
//!   it is (Windows paths stay readable), so the escape is for reading, not for parsing.
//! - [`shown`]: a path as [`escape_controls`] shows it, each byte that is not UTF-8 as
//!   `\xNN`.
//! - [`bytes_hex`]: the bytes of a name that is not UTF-8, as lowercase hex (the
//!   `file_bytes_hex` key of `epd estimate`'s JSON and CSV): lossless where the text is
//!   not.

use std::borrow::Cow;
use std::fmt::Write as _;
use std::path::Path;

/// Whether `c` is shown escaped (see the module).
fn needs_escape(c: char) -> bool {
    c.is_control()
        || matches!(
            c,
            '\u{061C}'
                | '\u{200E}'
                | '\u{200F}'
                | '\u{2028}'
                | '\u{2029}'
                | '\u{202A}'..='\u{202E}'
                | '\u{2066}'..='\u{2069}'
        )
}

/// Push `c`'s escape onto `out`.
fn push_escape(out: &mut String, c: char) {
    match c {
        '\n' => out.push_str("\\n"),
        '\r' => out.push_str("\\r"),
        '\t' => out.push_str("\\t"),
        c if (c as u32) < 0x80 => {
            let _ = write!(out, "\\x{:02x}", c as u32);
        }
        c => {
            let _ = write!(out, "\\u{{{:x}}}", c as u32);
        }
    }
}

/// `text` with its control characters (and the characters that move text) escaped (see
/// the module); borrowed when there is none.
pub fn escape_controls(text: &str) -> Cow<'_, str> {
    if !text.chars().any(needs_escape) {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for c in text.chars() {
        if needs_escape(c) {
            push_escape(&mut out, c);
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

/// A path as shown to people (see the module): UTF-8 with control characters escaped,
/// each byte that is not UTF-8 as `\xNN`.
pub fn shown(path: &Path) -> String {
    shown_bytes(path.as_os_str().as_encoded_bytes())
}

/// A name's bytes as shown to people: [`shown`] of bytes.
pub fn shown_bytes(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len());
    for chunk in bytes.utf8_chunks() {
        out.push_str(&escape_controls(chunk.valid()));
        for b in chunk.invalid() {
            let _ = write!(out, "\\x{b:02x}");
        }
    }
    out
}

/// The bytes of `path` as lowercase hex when they are not UTF-8 (`None` when they are).
pub fn bytes_hex(path: &Path) -> Option<String> {
    let bytes = path.as_os_str().as_encoded_bytes();
    if std::str::from_utf8(bytes).is_ok() {
        return None;
    }
    Some(hex(bytes))
}

/// Bytes as lowercase hex, two digits each.
pub fn hex(bytes: &[u8]) -> String {
    let mut hex = String::with_capacity(2 * bytes.len());
    for b in bytes {
        let _ = write!(hex, "{b:02x}");
    }
    hex
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A name that would print a fake result line prints as one line of visible escapes.
    #[test]
    fn a_crafted_name_stays_on_its_line() {
        let name = "good.ply: ML-EPD converged\n  Dmax 999.99 mm\r\x1b[2K\x07\x7f";
        let e = escape_controls(name);
        assert!(!e.chars().any(|c| c.is_control()), "{e}");
        assert_eq!(
            e,
            "good.ply: ML-EPD converged\\n  Dmax 999.99 mm\\r\\x1b[2K\\x07\\x7f"
        );
        assert_eq!(
            escape_controls("a\u{85}b\u{202e}c\u{2028}"),
            "a\\u{85}b\\u{202e}c\\u{2028}"
        );
        assert!(matches!(escape_controls("plain é ✓.ply"), Cow::Borrowed(_)));
    }

    #[cfg(unix)]
    #[test]
    fn bytes_that_are_not_utf8_are_kept() {
        use std::os::unix::ffi::OsStrExt;
        let p = Path::new(std::ffi::OsStr::from_bytes(b"scan\xff\x1b.ply"));
        assert_eq!(shown(p), "scan\\xff\\x1b.ply");
        assert_eq!(bytes_hex(p).as_deref(), Some("7363616eff1b2e706c79"));
        assert_eq!(bytes_hex(Path::new("scan.ply")), None);
    }
}
