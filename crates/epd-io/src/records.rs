//! The fixed-size records of a binary file read by index, not the whole file decoded
//! (`epd estimate --max-points N`, issue 25): a binary PLY whose `vertex` element comes
//! first with scalar properties only, and a PCD with `DATA binary`. [`RecordFile::open`]
//! reads the header and checks that the file holds every record it declares;
//! [`RecordFile::points`] and [`RecordFile::cloud`] then read the records asked for,
//! coalescing neighbours into one read ([`MAX_GAP_BYTES`]), and decode only those.
//!
//! A record `i` is point `i` of the file as the full readers ([`crate::read_path`]) number
//! it: in an organised cloud (row by row, as cameras write them) the pixel of index `i`,
//! whose other properties (`u`, `v`, `intensity`, …) come with it.

use std::path::Path;

use crate::read::{MAX_INPUT_BYTES, PointCloud, ReadError, Scalar, open_regular, split_header};

/// The most bytes [`RecordFile::open`] reads to find the end of a header: 1 MiB, as the
/// streamed PLY reader (a camera's header is under 1 KiB; a longer one is read whole by
/// the full readers).
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// The first bytes read for a header: 4 KiB (a camera's PLY header is under 1 KiB).
const FIRST_HEADER_BYTES: u64 = 4 << 10;

/// Two wanted records at most this many bytes apart are read in one read, the bytes
/// between them with them: 8 KiB. A read call costs about a microsecond, the same as
/// copying ~8 KiB from the page cache; beyond that gap a second call is cheaper.
pub const MAX_GAP_BYTES: u64 = 8 << 10;

/// The most bytes of one read: 1 MiB, so that the buffer stays small whatever the file.
pub const MAX_READ_BYTES: u64 = 1 << 20;

/// How a record holds a point: x, y, z and the other scalar properties, each as a type
/// at an offset within the record.
#[derive(Clone, Debug)]
pub(crate) struct RecordLayout {
    /// The format's name in errors (`PLY`, `PCD`).
    pub(crate) format: &'static str,
    /// What the records are, in errors (`element \`vertex\``, `the points`).
    pub(crate) what: String,
    /// Records in the file.
    pub(crate) count: u64,
    /// Bytes of one record.
    pub(crate) record: usize,
    /// Byte order.
    pub(crate) little: bool,
    /// Type and offset of x, y and z.
    pub(crate) xyz: [(Scalar, usize); 3],
    /// Name, type and offset of the other properties kept.
    pub(crate) extra: Vec<(String, Scalar, usize)>,
}

/// A file of fixed-size records, open for reading records by index.
#[derive(Debug)]
pub struct RecordFile {
    file: std::fs::File,
    /// Where the records start (the header's length).
    start: u64,
    layout: RecordLayout,
}

/// Why a record file cannot be read.
fn short(l: &RecordLayout) -> String {
    ReadError {
        format: l.format,
        message: format!(
            "{} declares {} records of {} bytes but the file is too short for them (truncated?)",
            l.what, l.count, l.record
        ),
    }
    .to_string()
}

impl RecordFile {
    /// Open `path` for reading its records by index: `Ok(None)` when it is not a file of
    /// fixed-size records that this reads (ASCII PLY or PCD, a PLY with lists or with data
    /// before its vertices, compressed PCD, text, a header longer than
    /// [`MAX_HEADER_BYTES`] or one the full readers would refuse): read it with
    /// [`crate::read_path`], which says what is wrong, if anything. An error when the
    /// file cannot be read, or is shorter than its header's records need.
    pub fn open(path: &Path) -> Result<Option<RecordFile>, String> {
        #[cfg(not(unix))]
        {
            let _ = path;
            return Ok(None);
        }
        #[cfg(unix)]
        {
            use std::io::Read;
            let (file, len) = open_regular(path)?;
            if len > MAX_INPUT_BYTES {
                return Ok(None);
            }
            // The header is read in growing pieces (a camera's fits in the first 4 KiB):
            // until it ends, or MAX_HEADER_BYTES.
            let mut head = Vec::new();
            let mut want = FIRST_HEADER_BYTES.min(MAX_HEADER_BYTES);
            let (layout, start) = loop {
                let have = head.len() as u64;
                (&file)
                    .take(want.min(len).saturating_sub(have))
                    .read_to_end(&mut head)
                    .map_err(|e| format!("cannot read: {e}"))?;
                if let Some(found) = layout_of(&head) {
                    break found;
                }
                let ended = header_ended(&head);
                if ended || want >= MAX_HEADER_BYTES.min(len) {
                    return Ok(None);
                }
                want = (want * 8).min(MAX_HEADER_BYTES);
            };
            let available = len.saturating_sub(start as u64);
            if layout
                .count
                .checked_mul(layout.record as u64)
                .is_none_or(|need| need > available)
                || layout.record == 0
            {
                return Err(short(&layout));
            }
            Ok(Some(RecordFile {
                file,
                start: start as u64,
                layout,
            }))
        }
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        // Checked at open: count × record ≤ the file's length.
        self.layout.count as usize
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.layout.count == 0
    }

    /// The names of the properties besides x, y and z, in the file's order.
    pub fn extra_names(&self) -> Vec<&str> {
        self.layout
            .extra
            .iter()
            .map(|(n, _, _)| n.as_str())
            .collect()
    }

    /// x, y, z of the records `indices` (strictly ascending, each below [`len`](Self::len)),
    /// in that order, as the full reader gives them.
    pub fn points(&self, indices: &[u32]) -> Result<Vec<[f64; 3]>, String> {
        let mut out = Vec::with_capacity(indices.len());
        self.visit(indices, |r| out.push(self.xyz(r)))?;
        Ok(out)
    }

    /// The records `indices` (strictly ascending, each below [`len`](Self::len)) with
    /// every property, in that order: the cloud the full reader gives, restricted to
    /// those points.
    pub fn cloud(&self, indices: &[u32]) -> Result<PointCloud, String> {
        let l = &self.layout;
        let mut cloud = PointCloud {
            points: Vec::with_capacity(indices.len()),
            extra: l
                .extra
                .iter()
                .map(|(n, _, _)| (n.clone(), Vec::with_capacity(indices.len())))
                .collect(),
        };
        self.visit(indices, |r| {
            cloud.points.push(self.xyz(r));
            for ((_, t, o), (_, values)) in l.extra.iter().zip(cloud.extra.iter_mut()) {
                values.push(
                    r.get(*o..)
                        .and_then(|s| t.decode(s, l.little))
                        .unwrap_or(f64::NAN),
                );
            }
        })?;
        Ok(cloud)
    }

    /// x, y, z of one record (offsets and types from the layout, so inside the record; a
    /// value that were not would read as NaN).
    fn xyz(&self, r: &[u8]) -> [f64; 3] {
        let l = &self.layout;
        let f = |(t, o): (Scalar, usize)| match (t, l.little) {
            (Scalar::F32, true) => r
                .get(o..o + 4)
                .and_then(|s| s.try_into().ok())
                .map_or(f64::NAN, |a| f32::from_le_bytes(a) as f64),
            (Scalar::F64, true) => r
                .get(o..o + 8)
                .and_then(|s| s.try_into().ok())
                .map_or(f64::NAN, f64::from_le_bytes),
            _ => r
                .get(o..)
                .and_then(|s| t.decode(s, l.little))
                .unwrap_or(f64::NAN),
        };
        [f(l.xyz[0]), f(l.xyz[1]), f(l.xyz[2])]
    }

    /// Call `each` on the bytes of every record of `indices`, in order: runs of records
    /// less than [`MAX_GAP_BYTES`] apart read at once, at most [`MAX_READ_BYTES`] a read.
    #[cfg(unix)]
    fn visit(&self, indices: &[u32], mut each: impl FnMut(&[u8])) -> Result<(), String> {
        use std::os::unix::fs::FileExt;
        let l = &self.layout;
        let rec = l.record as u64;
        if let Some(w) = indices.windows(2).find(|w| w[0] >= w[1]) {
            return Err(format!(
                "records {} and {} asked for out of order: the indices must ascend",
                w[0], w[1]
            ));
        }
        if let Some(&last) = indices.last()
            && u64::from(last) >= l.count
        {
            return Err(format!(
                "record {last} asked for, but the file holds {} records",
                l.count
            ));
        }
        let mut buf: Vec<u8> = Vec::new();
        let mut i = 0;
        while let Some(&first) = indices.get(i) {
            // The run: indices[i..j], records first..=last.
            let mut j = i + 1;
            let mut last = first;
            while let Some(&next) = indices.get(j) {
                let gap = u64::from(next - last - 1) * rec;
                let span = (u64::from(next - first) + 1) * rec;
                if gap > MAX_GAP_BYTES || span > MAX_READ_BYTES.max(rec) {
                    break;
                }
                last = next;
                j += 1;
            }
            // Within the file: checked at open (count × record bytes follow the header).
            let bytes = ((u64::from(last - first) + 1) * rec) as usize;
            buf.resize(bytes, 0);
            let at = self.start + u64::from(first) * rec;
            self.file.read_exact_at(&mut buf, at).map_err(|e| {
                if e.kind() == std::io::ErrorKind::UnexpectedEof {
                    format!(
                        "{} (it ends before record {}: it shrank after it was opened?)",
                        short(l),
                        first
                    )
                } else {
                    format!("cannot read: {e}")
                }
            })?;
            for &k in &indices[i..j] {
                let o = ((k - first) as usize) * l.record;
                each(buf.get(o..o + l.record).unwrap_or_default());
            }
            i = j;
        }
        Ok(())
    }

    #[cfg(not(unix))]
    fn visit(&self, _indices: &[u32], _each: impl FnMut(&[u8])) -> Result<(), String> {
        Err("reading records by index needs a Unix system".into())
    }
}

/// Whether `head` holds a whole PLY or PCD header (its `end_header` or `DATA` line): then a
/// longer read tells nothing more.
fn header_ended(head: &[u8]) -> bool {
    head.split(|&c| c == b'\n').rev().skip(1).any(|l| {
        let l = String::from_utf8_lossy(l);
        let l = l.trim();
        l == "end_header" || l.starts_with("DATA")
    })
}

/// The record layout of a file whose first bytes are `head`, and where its records
/// start; `None` when it is not a file of fixed-size records this module reads.
fn layout_of(head: &[u8]) -> Option<(RecordLayout, usize)> {
    match crate::read::detect_format(None, head).ok()? {
        crate::read::Format::Ply => {
            let (lines, body) = split_header(head, |l| l == "end_header", "PLY").ok()?;
            let layout = crate::ply::record_layout(&lines)?;
            Some((layout, head.len() - body.len()))
        }
        crate::read::Format::Pcd => {
            let (lines, body) = split_header(head, |l| l.starts_with("DATA"), "PCD").ok()?;
            let layout = crate::pcd::record_layout(&lines)?;
            Some((layout, head.len() - body.len()))
        }
        crate::read::Format::Text => None,
    }
}
