//! Point-cloud readers: PLY (ASCII, binary little- and big-endian), PCD (ascii, binary,
//! binary_compressed) and delimited text (CSV, XYZ, TXT, PTS, ASC). Every reader takes
//! bytes and returns a [`PointCloud`] or a [`ReadError`] saying what is wrong; none panics,
//! loops or allocates beyond a constant times the input on any input (every count in a
//! header is checked against the bytes that can follow it; property-tested on random and
//! mutated bytes and files).
//!
//! [`read_path`] reads regular files only (not FIFOs, devices or directories) of at most
//! [`MAX_INPUT_BYTES`]; [`read_from`] reads any [`Read`] (standard input) up to a cap.
//! Formats the readers do not read (LAS, LAZ, E57, VTK, archives…) are recognised by their
//! first bytes, else by their extension, and refused with a message saying so.

use crate::{pcd, ply, text};
use std::io::{BufRead, BufReader, Cursor, Read};
use std::path::Path;

/// The largest input the readers accept (4 GiB): a larger file is refused before it is read.
pub const MAX_INPUT_BYTES: u64 = 4 << 30;

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
    /// The format being read (`PLY`, `PCD`, `CSV`), or `unsupported format` for a file in a
    /// format the readers do not read (the message then names that format).
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

impl PointCloud {
    /// Reserve room for `n` more points in `points` and in every `extra` vector (`n`
    /// already checked against the input's size), or an error if memory runs short.
    pub(crate) fn reserve(&mut self, n: usize, format: &'static str) -> Result<(), ReadError> {
        let short = |_| err(format, format!("not enough memory for {n} points"));
        self.points.try_reserve_exact(n).map_err(short)?;
        for (_, values) in &mut self.extra {
            values.try_reserve_exact(n).map_err(short)?;
        }
        Ok(())
    }
}

/// A file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Stanford PLY.
    Ply,
    /// Point Cloud Library PCD.
    Pcd,
    /// Delimited text: CSV, XYZ, TXT, PTS, ASC.
    Text,
}

impl Format {
    /// The format from the file's first bytes, else from its extension, else text. A file
    /// in a format the readers do not read (see [`detect_format`]) is reported as text.
    pub fn detect(path: &Path, bytes: &[u8]) -> Format {
        detect_format(Some(path), bytes).unwrap_or(Format::Text)
    }
}

impl std::str::FromStr for Format {
    type Err = String;

    /// A format by name or extension, case-insensitive: `ply`; `pcd`; `csv`, `txt`,
    /// `xyz`, `pts`, `asc` or `text` (e.g. for a `--input-format` option with `-`).
    fn from_str(s: &str) -> Result<Format, String> {
        match s.to_ascii_lowercase().as_str() {
            "ply" => Ok(Format::Ply),
            "pcd" => Ok(Format::Pcd),
            "csv" | "txt" | "xyz" | "pts" | "asc" | "text" => Ok(Format::Text),
            _ => Err(format!(
                "unknown format `{}` (ply, pcd, csv, txt, xyz, pts or asc)",
                quote(s)
            )),
        }
    }
}

/// The format of a file from its first bytes (a `ply` or PCD header, after an optional
/// UTF-8 byte-order mark), else from the extension of `name`, else delimited text.
/// A format the readers do not read is an error naming it: by its magic bytes (LAS and
/// LAZ `LASF`, E57 `ASTM-E57`, legacy and XML VTK, zip, gzip, bzip2, xz, zstd, 7z, NumPy,
/// ROS bag, MCAP (a ROS 2 bag: read by `bag`, not here), HDF5, images, PDF, ASCII STL) or by
/// its extension (`.las .laz .e57 .vtk .vtp
/// .vtu .obj .stl .off .ply2 .bag .bin .npy .npz .ptx .fls .rcp .rcs .h5 .hdf5 .pcap`
/// and archives).
pub fn detect_format(name: Option<&Path>, bytes: &[u8]) -> Result<Format, ReadError> {
    let ext = name
        .and_then(|p| p.extension())
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if let Some(found) = by_magic(bytes, &ext) {
        return found;
    }
    if let Some(what) = unsupported_extension(&ext) {
        return Err(unsupported(what));
    }
    Ok(match ext.as_str() {
        "ply" => Format::Ply,
        "pcd" => Format::Pcd,
        _ => Format::Text,
    })
}

/// The error for a format the readers do not read.
fn unsupported(what: &str) -> ReadError {
    let how = if what.ends_with("-compressed data") || what.ends_with("archive") {
        "decompress it first; the readers take PLY, PCD or CSV"
    } else {
        "convert to PLY, PCD or CSV, e.g. with PDAL or CloudCompare"
    };
    err("unsupported format", format!("{what} ({how})"))
}

/// The format from the first bytes, when they say: `Some(Ok)` for PLY and PCD,
/// `Some(Err)` for a format the readers do not read, `None` when they do not say.
fn by_magic(bytes: &[u8], ext: &str) -> Option<Result<Format, ReadError>> {
    let b = strip_bom(bytes);
    let line_end = |rest: &[u8]| rest.starts_with(b"\n") || rest.starts_with(b"\r\n");
    if let Some(rest) = b.strip_prefix(b"ply")
        && line_end(rest)
    {
        return Some(Ok(Format::Ply));
    }
    if b.starts_with(b"# .PCD")
        || b.strip_prefix(b"VERSION")
            .is_some_and(|r| r.first().is_some_and(|c| *c == b' ' || *c == b'\t'))
    {
        return Some(Ok(Format::Pcd));
    }
    if bytes.starts_with(b"\x89MCAP") {
        return Some(Err(err(
            "unsupported format",
            "MCAP (a ROS 2 bag): read it as a bag from its path (`epd estimate BAG.mcap \
             --topic T`, `epd.read_bag`), not as one point cloud or from standard input",
        )));
    }
    let head = &bytes[..bytes.len().min(1024)];
    let contains = |needle: &[u8]| head.windows(needle.len()).any(|w| w == needle);
    let what = if bytes.starts_with(b"LASF") {
        if ext == "laz" {
            "LAZ (compressed LAS)"
        } else {
            "LAS"
        }
    } else if bytes.starts_with(b"ASTM-E57") {
        "E57"
    } else if b.starts_with(b"# vtk DataFile") {
        "VTK (legacy)"
    } else if (b.starts_with(b"<?xml") || b.starts_with(b"<VTKFile")) && contains(b"<VTKFile") {
        "VTK (XML)"
    } else if b.starts_with(b"<?xml") {
        "XML"
    } else if bytes.starts_with(b"PK\x03\x04") || bytes.starts_with(b"PK\x05\x06") {
        if ext == "npz" {
            "NumPy .npz (a zip archive)"
        } else {
            "zip archive"
        }
    } else if bytes.starts_with(b"\x1f\x8b") {
        "gzip-compressed data"
    } else if bytes.starts_with(b"BZh") && bytes.get(3).is_some_and(|c| c.is_ascii_digit()) {
        "bzip2-compressed data"
    } else if bytes.starts_with(b"\xfd7zXZ\x00") {
        "xz-compressed data"
    } else if bytes.starts_with(b"\x28\xb5\x2f\xfd") {
        "zstd-compressed data"
    } else if bytes.starts_with(b"7z\xbc\xaf\x27\x1c") {
        "7z archive"
    } else if bytes.starts_with(b"Rar!\x1a\x07") {
        "RAR archive"
    } else if bytes.get(257..262) == Some(b"ustar") {
        "tar archive"
    } else if bytes.starts_with(b"\x93NUMPY") {
        "NumPy .npy"
    } else if bytes.starts_with(b"#ROSBAG") {
        "ROS bag"
    } else if bytes.starts_with(b"\x89HDF\r\n\x1a\n") {
        "HDF5"
    } else if bytes.starts_with(b"\x89PNG") {
        "PNG image"
    } else if bytes.starts_with(b"\xff\xd8\xff") {
        "JPEG image"
    } else if bytes.starts_with(b"%PDF") {
        "PDF"
    } else if bytes.starts_with(b"glTF") {
        "glTF (binary)"
    } else if b.starts_with(b"solid") && contains(b"facet") {
        "STL (ASCII)"
    } else {
        return None;
    };
    Some(Err(unsupported(what)))
}

/// The name of a format the readers do not read, from a file extension (lowercase).
fn unsupported_extension(ext: &str) -> Option<&'static str> {
    Some(match ext {
        "las" => "LAS",
        "laz" => "LAZ (compressed LAS)",
        "e57" => "E57",
        "vtk" => "VTK (legacy)",
        "vtp" | "vtu" => "VTK (XML)",
        "obj" => "OBJ",
        "stl" => "STL",
        "off" => "OFF",
        "bag" => "ROS bag",
        "bin" => "raw binary (.bin: no header says its layout)",
        "npy" => "NumPy .npy",
        "npz" => "NumPy .npz",
        "ptx" => "Leica PTX",
        "fls" => "FARO FLS",
        "rcp" | "rcs" => "Autodesk ReCap",
        "h5" | "hdf5" => "HDF5",
        "pcap" | "pcapng" => "packet capture (pcap)",
        "zip" => "zip archive",
        "gz" | "tgz" => "gzip-compressed data",
        "bz2" => "bzip2-compressed data",
        "xz" => "xz-compressed data",
        "zst" => "zstd-compressed data",
        "7z" => "7z archive",
        "tar" => "tar archive",
        "rar" => "RAR archive",
        _ => return None,
    })
}

/// The bytes without a leading UTF-8 byte-order mark.
pub(crate) fn strip_bom(bytes: &[u8]) -> &[u8] {
    bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes)
}

/// `s` for an error message: at most 60 characters, the rest elided.
pub(crate) fn quote(s: &str) -> String {
    const MAX: usize = 60;
    match s.char_indices().nth(MAX) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
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

/// Read a cloud from a file, the format from its first bytes, else its extension (see
/// [`detect_format`]). Only regular files (symbolic links followed) of at most
/// [`MAX_INPUT_BYTES`] are read: a FIFO, device or directory is refused before anything is
/// read from it, and a file that grows while it is read is an error. The error says what
/// is wrong (without the file name, which the caller adds).
pub fn read_path(path: &Path) -> Result<PointCloud, String> {
    read_path_as(path, None)
}

/// [`read_path`] with the format given (`None`: detected).
pub(crate) fn read_path_as(path: &Path, format: Option<Format>) -> Result<PointCloud, String> {
    // Opening a FIFO for reading would block until a writer comes.
    let (file, len) = open_regular(path)?;
    if len > MAX_INPUT_BYTES {
        return Err(format!(
            "the file is {len} bytes, more than the {} the readers accept",
            bytes_text(MAX_INPUT_BYTES)
        ));
    }
    read_stream(file, Some(path), format, Limit::File(len))
}

/// Open `path` for reading if it is a regular file (symbolic links followed), without
/// ever waiting: the kind is checked before it is opened, and it is opened non-blocking
/// and checked again, so a FIFO put in its place meanwhile is refused too, not waited on.
/// The file and its length; the error says what is wrong (without the file name, which
/// the caller adds).
pub fn open_regular(path: &Path) -> Result<(std::fs::File, u64), String> {
    check_regular(&std::fs::metadata(path).map_err(cannot_read)?)?;
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // O_NONBLOCK: opening a FIFO returns at once; a regular file's reads ignore it.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(cannot_read)?;
    let meta = file.metadata().map_err(cannot_read)?;
    check_regular(&meta)?;
    Ok((file, meta.len()))
}

/// Read a cloud from a reader (e.g. standard input) holding at most `cap` bytes (more is an
/// error; [`MAX_INPUT_BYTES`] is a sensible cap). The format is `format_hint` when given,
/// else detected from the first bytes (see [`detect_format`]; text when they do not say); a
/// format the readers do not read is refused either way. The error says what is wrong.
pub fn read_from<R: Read>(
    reader: R,
    format_hint: Option<Format>,
    cap: u64,
) -> Result<PointCloud, String> {
    read_stream(reader, None, format_hint, Limit::Cap(cap))
}

/// How many bytes a source may hold.
#[derive(Clone, Copy, Debug)]
enum Limit {
    /// A file of this length (from its metadata).
    File(u64),
    /// A stream of at most this many bytes.
    Cap(u64),
}

impl Limit {
    fn bytes(self) -> u64 {
        match self {
            Limit::File(n) | Limit::Cap(n) => n,
        }
    }

    fn exceeded(self) -> String {
        match self {
            Limit::File(n) => format!("the file grew while it was read (it was {n} bytes)"),
            Limit::Cap(n) => format!(
                "the input is longer than {}, the most the readers accept",
                bytes_text(n)
            ),
        }
    }
}

fn cannot_read(e: std::io::Error) -> String {
    format!("cannot read: {e}")
}

/// `n` bytes in words: `4 GiB`, `1.5 MiB`, `200 bytes`.
fn bytes_text(n: u64) -> String {
    let units = [(1u64 << 30, "GiB"), (1 << 20, "MiB"), (1 << 10, "KiB")];
    for (size, unit) in units {
        if n >= size {
            let v = n as f64 / size as f64;
            return if n.is_multiple_of(size) {
                format!("{} {unit}", n / size)
            } else {
                format!("{v:.1} {unit}")
            };
        }
    }
    format!("{n} bytes")
}

/// An error unless `meta` is that of a regular file.
fn check_regular(meta: &std::fs::Metadata) -> Result<(), String> {
    if meta.is_file() {
        return Ok(());
    }
    let ft = meta.file_type();
    let kind = if ft.is_dir() {
        "a directory"
    } else {
        special_kind(&ft)
    };
    Err(format!(
        "not a regular file ({kind}); only regular files are read"
    ))
}

#[cfg(unix)]
fn special_kind(ft: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_fifo() {
        "a FIFO"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
fn special_kind(_: &std::fs::FileType) -> &'static str {
    "a special file"
}

/// How many first bytes the format detection looks at.
const SNIFF_BYTES: u64 = 1024;

/// Read a cloud from `reader` holding at most `limit` bytes: detect the format from the
/// first bytes (and `name`), stream binary PLY, read anything else whole.
fn read_stream<R: Read>(
    reader: R,
    name: Option<&Path>,
    hint: Option<Format>,
    limit: Limit,
) -> Result<PointCloud, String> {
    // One byte beyond the limit tells that the input exceeds it.
    let mut reader =
        BufReader::with_capacity(1 << 16, reader.take(limit.bytes().saturating_add(1)));
    let mut head = Vec::new();
    (&mut reader)
        .take(SNIFF_BYTES)
        .read_to_end(&mut head)
        .map_err(cannot_read)?;
    // A format the readers do not read is refused even when a format is given.
    let detected = detect_format(name, &head).map_err(|e| e.to_string())?;
    let format = hint.unwrap_or(detected);
    if format == Format::Text
        && let Some(e) = text::early_not_text(&head)
    {
        return Err(e.to_string());
    }
    let mut stream = Cursor::new(head).chain(reader);
    let start = if format == Format::Ply {
        match ply::read_stream(&mut stream, limit.bytes(), matches!(limit, Limit::File(_)))? {
            ply::Stream::Done(cloud) => return Ok(cloud),
            ply::Stream::Whole(header) => header,
        }
    } else {
        Vec::new()
    };
    let bytes = read_rest(stream, start, limit)?;
    read_bytes(format, &bytes).map_err(|e| e.to_string())
}

/// `start` followed by the rest of `stream`, which must not take the total beyond `limit`.
fn read_rest(mut stream: impl BufRead, start: Vec<u8>, limit: Limit) -> Result<Vec<u8>, String> {
    let mut bytes = start;
    if let Limit::File(n) = limit {
        // The file's size is known (and at most MAX_INPUT_BYTES): one allocation.
        let want = usize::try_from(n.saturating_add(1))
            .map_err(|_| format!("the file is too large ({n} bytes) for this machine"))?;
        bytes
            .try_reserve_exact(want.saturating_sub(bytes.len()))
            .map_err(|_| format!("not enough memory to read the file ({n} bytes)"))?;
    }
    stream.read_to_end(&mut bytes).map_err(cannot_read)?;
    if bytes.len() as u64 > limit.bytes() {
        return Err(limit.exceeded());
    }
    Ok(bytes)
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

    /// Decode one value from the first `size()` bytes of `b`; `None` when `b` is shorter.
    pub(crate) fn decode(self, b: &[u8], little: bool) -> Option<f64> {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b.get(..$n)?.try_into().ok()?;
                if little {
                    <$t>::from_le_bytes(a) as f64
                } else {
                    <$t>::from_be_bytes(a) as f64
                }
            }};
        }
        Some(match self {
            Scalar::I8 => get!(i8, 1),
            Scalar::U8 => get!(u8, 1),
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::I64 => get!(i64, 8),
            Scalar::U64 => get!(u64, 8),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        })
    }
}

/// The most header lines PLY and PCD headers may have: a camera's PLY has about 15 (a
/// few properties and comments), so 10 000 leaves room for any real header and bounds
/// the work on a crafted one.
pub(crate) const MAX_HEADER_LINES: usize = 10_000;

/// Split off the header (up to and including the line `end`), returning its lines and the
/// body. Accepts \n and \r\n line ends and a leading UTF-8 byte-order mark.
pub(crate) fn split_header<'a>(
    bytes: &'a [u8],
    end: impl Fn(&str) -> bool,
    format: &'static str,
) -> Result<(Vec<String>, &'a [u8]), ReadError> {
    let bytes = strip_bom(bytes);
    let mut lines = Vec::new();
    let mut rest = bytes;
    while !rest.is_empty() && lines.len() < MAX_HEADER_LINES {
        let (raw, after) = match rest.iter().position(|&c| c == b'\n') {
            Some(i) => (&rest[..i], &rest[i + 1..]),
            None => (rest, &rest[rest.len()..]),
        };
        let line = std::str::from_utf8(raw)
            .map_err(|_| {
                err(
                    format,
                    format!("header line {} is not text", lines.len() + 1),
                )
            })?
            .trim_end_matches('\r')
            .to_string();
        rest = after;
        let done = end(line.trim());
        lines.push(line);
        if done {
            return Ok((lines, rest));
        }
    }
    if lines.len() >= MAX_HEADER_LINES {
        return Err(err(
            format,
            format!(
                "the header has more than {MAX_HEADER_LINES} lines (elements, properties, \
                 comments), the most the readers accept: not a point cloud's header"
            ),
        ));
    }
    Err(err(format, "the header never ends (truncated file?)"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magic_bytes_come_before_the_extension() {
        let p = Path::new("a.csv");
        assert_eq!(detect_format(Some(p), b"ply\nformat"), Ok(Format::Ply));
        assert_eq!(
            detect_format(Some(p), b"\xef\xbb\xbfply\r\n"),
            Ok(Format::Ply)
        );
        assert_eq!(detect_format(Some(p), b"VERSION 0.7\n"), Ok(Format::Pcd));
        assert_eq!(detect_format(Some(p), b"plywood,1,2\n"), Ok(Format::Text));
        let e = detect_format(Some(Path::new("a.ply")), b"LASF\x00\x00").unwrap_err();
        assert_eq!(
            e.to_string(),
            "unsupported format: LAS (convert to PLY, PCD or CSV, e.g. with PDAL or CloudCompare)"
        );
        let e = detect_format(Some(Path::new("a.laz")), b"LASF\x00\x00").unwrap_err();
        assert!(e.to_string().contains("LAZ"));
        let e = detect_format(Some(Path::new("a.LAS")), b"1 2 3\n").unwrap_err();
        assert!(e.to_string().contains("LAS"));
        assert_eq!(detect_format(None, b"1 2 3\n"), Ok(Format::Text));
        let e = detect_format(None, b"\x89MCAP0\r\n\x01").unwrap_err();
        assert!(e.to_string().contains("a ROS 2 bag"), "{e}");
    }

    #[test]
    fn format_names() {
        assert_eq!("PLY".parse(), Ok(Format::Ply));
        assert_eq!("pcd".parse(), Ok(Format::Pcd));
        assert_eq!("xyz".parse(), Ok(Format::Text));
        assert!("las".parse::<Format>().is_err());
    }

    #[test]
    fn quote_elides_long_text() {
        assert_eq!(quote("abc"), "abc");
        let long = "é".repeat(100);
        assert_eq!(quote(&long).chars().count(), 61);
    }

    #[test]
    fn bytes_in_words() {
        assert_eq!(bytes_text(MAX_INPUT_BYTES), "4 GiB");
        assert_eq!(bytes_text(1536 << 10), "1.5 MiB");
        assert_eq!(bytes_text(12), "12 bytes");
    }
}
