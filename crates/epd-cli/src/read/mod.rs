//! Point-cloud readers: PLY (ASCII, binary little- and big-endian), PCD (ascii, binary,
//! binary_compressed) and delimited text (CSV, XYZ, TXT). Every reader takes bytes and
//! returns a [`PointCloud`] or a [`ReadError`] saying what is wrong; none panics on any
//! input (property-tested on random and mutated bytes).

pub mod pcd;
pub mod ply;
pub mod text;

use std::path::Path;

/// Points in the sensor frame (m) and the other per-point properties of the file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// x, y, z of every point, as stored (NaN and zeros included).
    pub points: Vec<[f64; 3]>,
    /// Other per-point properties (intensity, confidence, …) by name, one value per point.
    pub extra: Vec<(String, Vec<f64>)>,
}

/// What is wrong with a file's contents.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{format}: {message}")]
pub struct ReadError {
    /// The format being read (`PLY`, `PCD`, `CSV`).
    pub format: &'static str,
    /// What is wrong.
    pub message: String,
}

pub(crate) fn err(format: &'static str, message: impl Into<String>) -> ReadError {
    ReadError {
        format,
        message: message.into(),
    }
}

/// A file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Stanford PLY.
    Ply,
    /// Point Cloud Library PCD.
    Pcd,
    /// Delimited text: CSV, XYZ, TXT.
    Text,
}

impl Format {
    /// The format from the file's extension, else from its first bytes.
    pub fn detect(path: &Path, bytes: &[u8]) -> Format {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match ext.as_str() {
            "ply" => Format::Ply,
            "pcd" => Format::Pcd,
            "csv" | "xyz" | "txt" | "pts" => Format::Text,
            _ if bytes.starts_with(b"ply") => Format::Ply,
            _ if bytes.starts_with(b"# .PCD") || bytes.starts_with(b"VERSION") => Format::Pcd,
            _ => Format::Text,
        }
    }
}

/// Read a cloud from bytes in the given format.
pub fn read_bytes(format: Format, bytes: &[u8]) -> Result<PointCloud, ReadError> {
    match format {
        Format::Ply => ply::read(bytes),
        Format::Pcd => pcd::read(bytes),
        Format::Text => text::read(bytes),
    }
}

/// Read a cloud from a file, the format from its extension or first bytes. The error
/// says what is wrong (without the file name, which the caller adds).
pub fn read_path(path: &Path) -> Result<PointCloud, String> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ext == "ply" {
        return ply::read_path(path);
    }
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    read_bytes(Format::detect(path, &bytes), &bytes).map_err(|e| e.to_string())
}

/// Scalar types shared by PLY and PCD.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Scalar {
    pub(crate) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::I64 | Scalar::U64 | Scalar::F64 => 8,
        }
    }

    /// Decode one value from exactly `size()` bytes.
    pub(crate) fn decode(self, b: &[u8], little: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                if little {
                    <$t>::from_le_bytes(a) as f64
                } else {
                    <$t>::from_be_bytes(a) as f64
                }
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::I64 => get!(i64, 8),
            Scalar::U64 => get!(u64, 8),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        }
    }
}

/// Split off the header (up to and including the line `end`), returning its lines and the
/// body. Accepts \n and \r\n line ends.
pub(crate) fn split_header<'a>(
    bytes: &'a [u8],
    end: impl Fn(&str) -> bool,
    format: &'static str,
) -> Result<(Vec<String>, &'a [u8]), ReadError> {
    let mut lines = Vec::new();
    let mut pos = 0;
    while pos < bytes.len() {
        let nl = bytes[pos..]
            .iter()
            .position(|&c| c == b'\n')
            .map(|i| pos + i);
        let line_end = nl.unwrap_or(bytes.len());
        let line = std::str::from_utf8(&bytes[pos..line_end])
            .map_err(|_| {
                err(
                    format,
                    format!("header line {} is not text", lines.len() + 1),
                )
            })?
            .trim_end_matches('\r')
            .to_string();
        pos = nl.map_or(bytes.len(), |i| i + 1);
        let done = end(line.trim());
        lines.push(line);
        if done {
            return Ok((lines, &bytes[pos..]));
        }
        if lines.len() > 10_000 {
            break;
        }
    }
    Err(err(format, "the header never ends (truncated file?)"))
}
