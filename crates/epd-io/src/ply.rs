//! Stanford PLY, read and written.
//!
//! Reading ([`read`], [`read_path`]): `format ascii 1.0`, `binary_little_endian 1.0`,
//! `binary_big_endian 1.0`. The `vertex` element must have `x`, `y`, `z` (any scalar type, each once); its other
//! scalar properties are kept. Elements before it (faces…) are read past, elements after
//! it are not read. Every element count is checked against the bytes that follow the
//! header before anything is reserved or looped over: a binary record takes at least the
//! sum of its property sizes, an ASCII record at least one token per property; an element
//! without properties holds no data and is skipped whatever its count.
//!
//! Writing ([`write()`], [`save`]): a [`SensorCloud`] (points with their pixels, comments
//! and named per-point properties) as ASCII or binary little-endian.

use crate::WriteError;
use crate::cloud::{SensorCloud, Values};
use crate::read::{MAX_HEADER_LINES, PointCloud, ReadError, Scalar, err, quote, split_header};
use std::io::{BufRead, Write};
use std::path::Path;

const F: &str = "PLY";

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Binary { little: bool },
}

#[derive(Clone, Debug)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    /// A list (e.g. a face's vertex indices), read past.
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Property::Scalar { name, .. } | Property::List { name, .. } => name,
        }
    }

    /// The fewest bytes the property takes in a binary record.
    fn min_size(&self) -> usize {
        match self {
            Property::Scalar { ty, .. } => ty.size(),
            Property::List { count, .. } => count.size(),
        }
    }
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
}

impl Element {
    /// The fewest bytes a binary record takes (0 for an element without properties).
    fn min_record(&self) -> usize {
        self.props.iter().map(Property::min_size).sum()
    }

    fn too_short(&self) -> ReadError {
        err(
            F,
            format!(
                "element `{}` declares {} records but the file is too short for them (truncated?)",
                self.name, self.count
            ),
        )
    }
}

fn scalar(name: &str) -> Option<Scalar> {
    Some(match name {
        "char" | "int8" => Scalar::I8,
        "uchar" | "uint8" => Scalar::U8,
        "short" | "int16" => Scalar::I16,
        "ushort" | "uint16" => Scalar::U16,
        "int" | "int32" => Scalar::I32,
        "uint" | "uint32" => Scalar::U32,
        "float" | "float32" => Scalar::F32,
        "double" | "float64" => Scalar::F64,
        _ => return None,
    })
}

/// One header line after `ply`, split in words: an `element` or `property` line adds to
/// `elements`; a `format` line gives the encoding; `bad` makes the error of this line.
fn header_line(
    words: &[&str],
    elements: &mut Vec<Element>,
    bad: impl Fn(&str) -> ReadError,
) -> Result<Option<Encoding>, ReadError> {
    match words {
        [] => {}
        ["comment", ..] | ["obj_info", ..] | ["end_header"] => {}
        ["format", f, _version] => {
            return Ok(Some(match *f {
                "ascii" => Encoding::Ascii,
                "binary_little_endian" => Encoding::Binary { little: true },
                "binary_big_endian" => Encoding::Binary { little: false },
                _ => return Err(bad("unknown format")),
            }));
        }
        ["element", name, count] => {
            let count: u64 = count
                .parse()
                .map_err(|_| bad("the element count is not a whole number from 0 to 2^64 - 1"))?;
            if *name == "vertex" && elements.iter().any(|e| e.name == "vertex") {
                return Err(bad("a second `vertex` element"));
            }
            elements.push(Element {
                name: name.to_string(),
                count,
                props: Vec::new(),
            });
        }
        ["property", "list", c, t, name] => {
            let el = elements
                .last_mut()
                .ok_or_else(|| bad("a property before any element"))?;
            let count = scalar(c).ok_or_else(|| bad("unknown list count type"))?;
            let item = scalar(t).ok_or_else(|| bad("unknown list item type"))?;
            if matches!(count, Scalar::F32 | Scalar::F64) {
                return Err(bad("a list count must be an integer type"));
            }
            el.props.push(Property::List {
                name: name.to_string(),
                count,
                item,
            });
        }
        ["property", t, name] => {
            let el = elements
                .last_mut()
                .ok_or_else(|| bad("a property before any element"))?;
            let ty = scalar(t).ok_or_else(|| bad("unknown property type"))?;
            el.props.push(Property::Scalar {
                name: name.to_string(),
                ty,
            });
        }
        _ => return Err(bad("not a PLY header line")),
    }
    Ok(None)
}

/// The indices of the vertex element's scalar properties x, y and z; an error if one is
/// missing or a property is named twice.
fn vertex_xyz(vertex: &Element) -> Result<[usize; 3], ReadError> {
    let mut seen = std::collections::HashSet::new();
    for p in &vertex.props {
        if !seen.insert(p.name()) {
            return Err(err(
                F,
                format!(
                    "the vertex element has property `{}` twice",
                    quote(p.name())
                ),
            ));
        }
    }
    let find = |n: &str| {
        vertex
            .props
            .iter()
            .position(|p| matches!(p, Property::Scalar { name, .. } if name == n))
    };
    match (find("x"), find("y"), find("z")) {
        (Some(x), Some(y), Some(z)) => Ok([x, y, z]),
        _ => Err(err(
            F,
            "the vertex element lacks scalar properties x, y and z",
        )),
    }
}

/// A parsed header: the encoding, the elements, the index of `vertex` and those of its
/// `x`, `y`, `z` properties.
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    vi: usize,
    xyz: [usize; 3],
}

impl Header {
    fn parse(lines: &[String]) -> Result<Header, ReadError> {
        if lines.first().map(|l| l.trim()) != Some("ply") {
            return Err(err(F, "the file does not start with `ply`"));
        }
        let mut encoding = None;
        let mut elements: Vec<Element> = Vec::new();
        for (i, line) in lines.iter().enumerate().skip(1) {
            let words: Vec<&str> = line.split_whitespace().collect();
            let bad = |what: &str| {
                err(
                    F,
                    format!("header line {}: {what}: `{}`", i + 1, quote(line)),
                )
            };
            if let Some(e) = header_line(&words, &mut elements, bad)? {
                // A second format line would change how the body reads.
                if encoding.is_some() {
                    return Err(bad("a second `format` line"));
                }
                encoding = Some(e);
            }
        }
        let encoding = encoding.ok_or_else(|| err(F, "the header has no `format` line"))?;
        let vi = elements
            .iter()
            .position(|e| e.name == "vertex")
            .ok_or_else(|| err(F, "no `vertex` element"))?;
        let xyz = vertex_xyz(&elements[vi])?;
        Ok(Header {
            encoding,
            elements,
            vi,
            xyz,
        })
    }

    /// The layout for decoding the vertices in place: binary, every element before the
    /// vertices without properties (so without data), scalar vertex properties only.
    fn fast_layout(&self) -> Option<VertexLayout> {
        let Encoding::Binary { little } = self.encoding else {
            return None;
        };
        if self.elements[..self.vi].iter().any(|e| !e.props.is_empty()) {
            return None;
        }
        VertexLayout::new(&self.elements[self.vi], little, self.xyz)
    }
}

/// A cursor over the body.
struct Body<'a> {
    bytes: &'a [u8],
    pos: usize,
    encoding: Encoding,
    /// ASCII: whether the next value is a record's first, which may start on a new line;
    /// the others must be on its line (one record per line).
    at_record_start: bool,
}

impl Body<'_> {
    fn remaining(&self) -> u64 {
        self.bytes.len().saturating_sub(self.pos) as u64
    }

    /// Whether `n` items (values, or records of `min_record` bytes) can still follow:
    /// binary, `n × size` bytes; ASCII, `n` tokens, which take at least `2n - 1` bytes.
    fn can_hold(&self, n: u64, size: usize) -> bool {
        match self.encoding {
            Encoding::Binary { .. } => n
                .checked_mul(size as u64)
                .is_some_and(|b| b <= self.remaining()),
            Encoding::Ascii => n <= self.remaining().div_ceil(2),
        }
    }

    fn token(&mut self) -> Option<&[u8]> {
        let b = self.bytes;
        while b.get(self.pos).is_some_and(|c| c.is_ascii_whitespace()) {
            self.pos += 1;
        }
        let start = self.pos;
        while b.get(self.pos).is_some_and(|c| !c.is_ascii_whitespace()) {
            self.pos += 1;
        }
        b.get(start..self.pos).filter(|t| !t.is_empty())
    }

    /// ASCII: skip the blanks of the current line (not its end).
    fn skip_blanks(&mut self) {
        while self
            .bytes
            .get(self.pos)
            .is_some_and(|c| matches!(c, b' ' | b'\t' | b'\r'))
        {
            self.pos += 1;
        }
    }

    /// After a record: ASCII, the rest of its line must be blank (more values there than
    /// the header declares would shift every record after it).
    fn end_record(&mut self, what: &dyn Fn() -> String) -> Result<(), ReadError> {
        if let Encoding::Ascii = self.encoding {
            self.skip_blanks();
            if self.bytes.get(self.pos).is_some_and(|&c| c != b'\n') {
                return Err(err(
                    F,
                    format!(
                        "{}: its line holds more values than the header's properties \
                         (one record per line)",
                        what()
                    ),
                ));
            }
            self.at_record_start = true;
        }
        Ok(())
    }

    fn value(&mut self, ty: Scalar, what: &dyn Fn() -> String) -> Result<f64, ReadError> {
        match self.encoding {
            Encoding::Ascii => {
                if !self.at_record_start {
                    self.skip_blanks();
                    if self.bytes.get(self.pos) == Some(&b'\n') {
                        return Err(err(
                            F,
                            format!(
                                "{}: its line ends before the header's properties do (one \
                                 record per line)",
                                what()
                            ),
                        ));
                    }
                }
                self.at_record_start = false;
                let t = self.token().ok_or_else(|| {
                    err(F, format!("the file ends inside {} (truncated?)", what()))
                })?;
                std::str::from_utf8(t)
                    .ok()
                    .and_then(|s| s.parse::<f64>().ok())
                    .ok_or_else(|| {
                        err(
                            F,
                            format!(
                                "`{}` in {} is not a number",
                                quote(&String::from_utf8_lossy(t)),
                                what()
                            ),
                        )
                    })
            }
            Encoding::Binary { little } => {
                let v = self
                    .pos
                    .checked_add(ty.size())
                    .and_then(|end| self.bytes.get(self.pos..end))
                    .and_then(|s| ty.decode(s, little))
                    .ok_or_else(|| {
                        err(F, format!("the file ends inside {} (truncated?)", what()))
                    })?;
                self.pos += ty.size();
                Ok(v)
            }
        }
    }

    /// Read past a list property's items.
    fn skip_list(
        &mut self,
        count: Scalar,
        item: Scalar,
        what: &dyn Fn() -> String,
    ) -> Result<(), ReadError> {
        let n = self.value(count, what)?;
        if !(n >= 0.0 && n.fract() == 0.0 && self.can_hold(n as u64, item.size())) {
            return Err(err(
                F,
                format!(
                    "list length {n} in {} is beyond the end of the file",
                    what()
                ),
            ));
        }
        let n = n as u64;
        match self.encoding {
            // can_hold checked that n × size bytes follow.
            Encoding::Binary { .. } => {
                self.pos = self
                    .pos
                    .saturating_add((n as usize).saturating_mul(item.size()))
            }
            Encoding::Ascii => {
                for _ in 0..n {
                    self.value(item, what)?;
                }
            }
        }
        Ok(())
    }

    /// Read past an element before the vertices.
    fn skip_element(&mut self, el: &Element) -> Result<(), ReadError> {
        if el.props.is_empty() {
            return Ok(());
        }
        if !self.can_hold(el.count.saturating_mul(el.props.len() as u64), 1)
            || !self.can_hold(el.count, el.min_record())
        {
            return Err(el.too_short());
        }
        let lists = el.props.iter().any(|p| matches!(p, Property::List { .. }));
        if let (Encoding::Binary { .. }, false) = (self.encoding, lists) {
            // can_hold checked that count × record bytes follow.
            self.pos = self
                .pos
                .saturating_add((el.count as usize).saturating_mul(el.min_record()));
            return Ok(());
        }
        for r in 0..el.count {
            let what = || format!("`{}` record {}", el.name, r + 1);
            for p in &el.props {
                match p {
                    Property::Scalar { ty, .. } => {
                        self.value(*ty, &what)?;
                    }
                    Property::List { count, item, .. } => self.skip_list(*count, *item, &what)?,
                }
            }
            self.end_record(&what)?;
        }
        Ok(())
    }
}

/// Read a PLY file.
pub fn read(bytes: &[u8]) -> Result<PointCloud, ReadError> {
    let (lines, body) = split_header(bytes, |l| l == "end_header", F)?;
    let header = Header::parse(&lines)?;
    if let Some(layout) = header.fast_layout() {
        let need = layout.need(body.len() as u64)?;
        let mut cloud = layout.empty_cloud(layout.count)?;
        layout.decode(body.get(..need).unwrap_or_default(), &mut cloud);
        return Ok(cloud);
    }
    let mut cur = Body {
        bytes: body,
        pos: 0,
        encoding: header.encoding,
        at_record_start: true,
    };
    for el in &header.elements[..header.vi] {
        cur.skip_element(el)?;
    }
    let el = &header.elements[header.vi];
    let [ix, iy, iz] = header.xyz;
    // Every vertex property takes at least one byte (binary) or one token (ASCII).
    if !cur.can_hold(el.count.saturating_mul(el.props.len() as u64), 1)
        || !cur.can_hold(el.count, el.min_record())
    {
        return Err(el.too_short());
    }
    // Checked above: count ≤ the body's length.
    let count = el.count as usize;
    let mut cloud = PointCloud::default();
    for (pi, p) in el.props.iter().enumerate() {
        if let Property::Scalar { name, .. } = p
            && ![ix, iy, iz].contains(&pi)
        {
            cloud.extra.push((name.clone(), Vec::new()));
        }
    }
    cloud.reserve(count, F)?;
    for r in 0..count {
        let what = || format!("`{}` record {}", el.name, r + 1);
        let mut xyz = [0.0; 3];
        let mut e = 0;
        for (pi, p) in el.props.iter().enumerate() {
            match p {
                Property::Scalar { ty, .. } => {
                    let v = cur.value(*ty, &what)?;
                    if pi == ix {
                        xyz[0] = v;
                    } else if pi == iy {
                        xyz[1] = v;
                    } else if pi == iz {
                        xyz[2] = v;
                    } else if let Some((_, values)) = cloud.extra.get_mut(e) {
                        values.push(v);
                        e += 1;
                    }
                }
                Property::List { count, item, .. } => cur.skip_list(*count, *item, &what)?,
            }
        }
        cur.end_record(&what)?;
        cloud.points.push(xyz);
    }
    Ok(cloud)
}

/// The record layout of a binary vertex element with scalar properties only: the fast
/// path, decoding fixed-size records in place.
struct VertexLayout {
    name: String,
    count: u64,
    record: usize,
    little: bool,
    xyz: [(Scalar, usize); 3],
    extra: Vec<(String, Scalar, usize)>,
}

impl VertexLayout {
    /// The layout of `vertex`, or `None` when it has list properties.
    fn new(vertex: &Element, little: bool, xyz: [usize; 3]) -> Option<Self> {
        let mut record = 0;
        let mut fields = Vec::with_capacity(vertex.props.len());
        for p in &vertex.props {
            match p {
                Property::Scalar { name, ty } => {
                    fields.push((name.clone(), *ty, record));
                    record += ty.size();
                }
                Property::List { .. } => return None,
            }
        }
        let mut at = [(Scalar::F64, 0); 3];
        for (a, i) in at.iter_mut().zip(xyz) {
            let (_, ty, offset) = fields.get(i)?;
            *a = (*ty, *offset);
        }
        let extra = fields
            .into_iter()
            .enumerate()
            .filter(|(k, _)| !xyz.contains(k))
            .map(|(_, f)| f)
            .collect();
        Some(Self {
            name: vertex.name.clone(),
            count: vertex.count,
            record,
            little,
            xyz: at,
            extra,
        })
    }

    /// The bytes the records take, or an error when fewer than that are `available`.
    fn need(&self, available: u64) -> Result<usize, ReadError> {
        self.count
            .checked_mul(self.record as u64)
            .filter(|&n| n <= available)
            .and_then(|n| usize::try_from(n).ok())
            .ok_or_else(|| self.too_short())
    }

    /// A cloud with room for `n` points (`n` already checked against the input's size).
    fn empty_cloud(&self, n: u64) -> Result<PointCloud, ReadError> {
        let mut cloud = PointCloud {
            points: Vec::new(),
            extra: self
                .extra
                .iter()
                .map(|(name, _, _)| (name.clone(), Vec::new()))
                .collect(),
        };
        cloud.reserve(usize::try_from(n).unwrap_or(usize::MAX), F)?;
        Ok(cloud)
    }

    /// Append the whole records in `data` to `cloud`.
    fn decode(&self, data: &[u8], cloud: &mut PointCloud) {
        let rows = || data.chunks_exact(self.record.max(1));
        let [(tx, ox), (ty, oy), (tz, oz)] = self.xyz;
        let little = self.little;
        // Offsets and sizes come from the record layout, so every value is inside its
        // record; a value that were not would read as NaN.
        match (tx, ty, tz, little) {
            // The common layouts, decoded without a type dispatch per value.
            (Scalar::F64, Scalar::F64, Scalar::F64, true) => {
                let f = |r: &[u8], o: usize| {
                    r.get(o..o + 8)
                        .and_then(|s| s.try_into().ok())
                        .map_or(f64::NAN, f64::from_le_bytes)
                };
                cloud
                    .points
                    .extend(rows().map(|r| [f(r, ox), f(r, oy), f(r, oz)]));
            }
            (Scalar::F32, Scalar::F32, Scalar::F32, true) => {
                let f = |r: &[u8], o: usize| {
                    r.get(o..o + 4)
                        .and_then(|s| s.try_into().ok())
                        .map_or(f64::NAN, |a| f32::from_le_bytes(a) as f64)
                };
                cloud
                    .points
                    .extend(rows().map(|r| [f(r, ox), f(r, oy), f(r, oz)]));
            }
            _ => {
                let f = |t: Scalar, r: &[u8], o: usize| {
                    r.get(o..)
                        .and_then(|s| t.decode(s, little))
                        .unwrap_or(f64::NAN)
                };
                cloud
                    .points
                    .extend(rows().map(|r| [f(tx, r, ox), f(ty, r, oy), f(tz, r, oz)]))
            }
        }
        for ((_, t, o), (_, values)) in self.extra.iter().zip(cloud.extra.iter_mut()) {
            values.extend(rows().map(|r| {
                r.get(*o..)
                    .and_then(|s| t.decode(s, little))
                    .unwrap_or(f64::NAN)
            }));
        }
    }

    fn too_short(&self) -> ReadError {
        err(
            F,
            format!(
                "element `{}` declares {} records of {} bytes but the file is too short for them (truncated?)",
                self.name, self.count, self.record
            ),
        )
    }
}

/// The record layout of a binary PLY whose `vertex` element comes first with scalar
/// properties only, from its header lines (`None` for any other PLY):
/// [`crate::records::RecordFile`].
pub(crate) fn record_layout(lines: &[String]) -> Option<crate::records::RecordLayout> {
    let l = Header::parse(lines).ok()?.fast_layout()?;
    Some(crate::records::RecordLayout {
        format: F,
        what: format!("element `{}`", l.name),
        count: l.count,
        record: l.record,
        little: l.little,
        xyz: l.xyz,
        extra: l.extra,
    })
}

/// What [`read_stream`] did.
pub(crate) enum Stream {
    /// The vertices, decoded as they streamed in.
    Done(PointCloud),
    /// The file cannot be streamed (ASCII, lists, data before the vertices, or a header
    /// [`read`] should judge): the bytes read so far; the caller reads the rest and
    /// calls [`read`] on the whole.
    Whole(Vec<u8>),
}

/// The most bytes a streamed header may take before the whole file is read instead.
const MAX_STREAMED_HEADER: u64 = 1 << 20;

/// Read a PLY file from a stream of at most `limit` bytes (`exact`: exactly `limit`, the
/// size of a file). Binary files whose vertices have scalar properties only, with no data
/// before them, are decoded as they stream in (no copy of the whole file in memory); for
/// others the header bytes are handed back.
pub(crate) fn read_stream<R: BufRead>(
    r: &mut R,
    limit: u64,
    exact: bool,
) -> Result<Stream, String> {
    use std::io::Read;
    let cannot_read = |e: std::io::Error| format!("cannot read: {e}");
    let mut raw = Vec::new();
    let mut lines = Vec::new();
    loop {
        let start = raw.len();
        let budget = MAX_STREAMED_HEADER.saturating_sub(start as u64);
        let n = r
            .by_ref()
            .take(budget)
            .read_until(b'\n', &mut raw)
            .map_err(cannot_read)?;
        let ended = raw.last() == Some(&b'\n');
        if n == 0 || !ended || lines.len() >= MAX_HEADER_LINES {
            return Ok(Stream::Whole(raw));
        }
        let mut line = raw.get(start..).unwrap_or_default();
        if lines.is_empty() {
            line = crate::read::strip_bom(line);
        }
        let Ok(text) = std::str::from_utf8(line) else {
            return Ok(Stream::Whole(raw));
        };
        let text = text.trim_end_matches(['\n', '\r']).to_string();
        let end = text.trim() == "end_header";
        lines.push(text);
        if end {
            break;
        }
    }
    let Ok(header) = Header::parse(&lines) else {
        return Ok(Stream::Whole(raw));
    };
    let Some(layout) = header.fast_layout() else {
        return Ok(Stream::Whole(raw));
    };
    let available = limit.saturating_sub(raw.len() as u64);
    let need = layout.need(available).map_err(|e| e.to_string())?;
    // At most about 1 MiB of records per read; the cloud grows as the data arrive.
    let per_chunk = ((1usize << 20) / layout.record.max(1)).max(1);
    let chunk_bytes = per_chunk.saturating_mul(layout.record).min(need);
    let mut buf = vec![0u8; chunk_bytes];
    // A file's size is known, so the records are there (or the file shrank: an error
    // below); a stream may hold less than its limit, so the cloud grows as data arrive.
    let mut cloud = layout
        .empty_cloud(if exact { layout.count } else { 0 })
        .map_err(|e| e.to_string())?;
    let mut left = need;
    while left > 0 {
        let k = left.min(chunk_bytes);
        let chunk = buf.get_mut(..k).unwrap_or_default();
        r.read_exact(chunk).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => layout.too_short().to_string(),
            _ => cannot_read(e),
        })?;
        layout.decode(chunk, &mut cloud);
        left -= k;
    }
    Ok(Stream::Done(cloud))
}

/// Read a PLY file from disk (whatever its extension). Like [`crate::read::read_path`]: regular
/// files only, at most [`crate::read::MAX_INPUT_BYTES`]; binary files whose vertices come first
/// with scalar properties only are decoded as they stream in.
pub fn read_path(path: &std::path::Path) -> Result<PointCloud, String> {
    crate::read::read_path_as(path, Some(crate::read::Format::Ply))
}

// ---- Writing ----

/// PLY encodings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyFormat {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
}

/// Scalar type of the coordinates in a PLY file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyPrecision {
    /// `float` (32-bit).
    F32,
    /// `double` (64-bit).
    F64,
}

/// Write `cloud`'s points (SCS, m) with their pixel (u, v) as PLY: its comments first,
/// then the vertex element with `x`, `y`, `z` (`float` or `double`), `uint u`, `uint v`
/// and each of its properties in order (`float`, `ushort` or `uchar`). Invalid pixels are
/// written as they are held (x = y = z = 0). A property whose length is not the number of
/// points is refused (`InvalidInput`) before anything is written.
pub fn write<W: Write>(
    w: &mut W,
    cloud: &SensorCloud<'_>,
    format: PlyFormat,
    precision: PlyPrecision,
) -> std::io::Result<()> {
    let n = cloud.points.len();
    if cloud.pixels.len() != n {
        return Err(mismatch(format!(
            "{} pixels for {n} points",
            cloud.pixels.len()
        )));
    }
    if let Some(p) = cloud.properties.iter().find(|p| p.values.len() != n) {
        return Err(mismatch(format!(
            "property `{}` has {} values for {n} points",
            p.name,
            p.values.len()
        )));
    }
    write_header(w, cloud, format, precision)?;
    for (i, (p, px)) in cloud.points.iter().zip(cloud.pixels).enumerate() {
        write_vertex(w, format, precision, p, px)?;
        for prop in &cloud.properties {
            write_value(w, format, &prop.values, i)?;
        }
        if format == PlyFormat::Ascii {
            writeln!(w)?;
        }
    }
    Ok(())
}

fn mismatch(message: String) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("PLY: a cloud to write must have one value per point: {message}"),
    )
}

/// The PLY type name of a property's values.
fn type_name(v: &Values) -> &'static str {
    match v {
        Values::F32(_) => "float",
        Values::U16(_) => "ushort",
        Values::U8(_) => "uchar",
    }
}

/// The header of [`write()`]: the cloud's comments, then the vertex element's properties
/// x, y, z, u, v and the cloud's own.
fn write_header<W: Write>(
    w: &mut W,
    cloud: &SensorCloud<'_>,
    format: PlyFormat,
    precision: PlyPrecision,
) -> std::io::Result<()> {
    let fmt = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
    };
    let ty = match precision {
        PlyPrecision::F32 => "float",
        PlyPrecision::F64 => "double",
    };
    write!(w, "ply\nformat {fmt} 1.0\n")?;
    for c in &cloud.comments {
        // A comment is one header line: a line break inside it would end the comment.
        writeln!(w, "comment {}", c.replace(['\n', '\r'], " "))?;
    }
    write!(
        w,
        "element vertex {}\nproperty {ty} x\nproperty {ty} y\nproperty {ty} z\nproperty uint u\nproperty uint v\n",
        cloud.points.len()
    )?;
    for p in &cloud.properties {
        writeln!(w, "property {} {}", type_name(&p.values), p.name)?;
    }
    writeln!(w, "end_header")
}

/// One vertex's point `p` (SCS, m) and pixel, as [`write()`] writes them.
fn write_vertex<W: Write>(
    w: &mut W,
    format: PlyFormat,
    precision: PlyPrecision,
    p: &[f64; 3],
    px: &[u32; 2],
) -> std::io::Result<()> {
    match (format, precision) {
        (PlyFormat::Ascii, PlyPrecision::F64) => {
            write!(w, "{} {} {} {} {}", p[0], p[1], p[2], px[0], px[1])
        }
        (PlyFormat::Ascii, PlyPrecision::F32) => write!(
            w,
            "{} {} {} {} {}",
            p[0] as f32, p[1] as f32, p[2] as f32, px[0], px[1]
        ),
        (PlyFormat::BinaryLittleEndian, prec) => {
            for c in p {
                match prec {
                    PlyPrecision::F64 => w.write_all(&c.to_le_bytes())?,
                    PlyPrecision::F32 => w.write_all(&(*c as f32).to_le_bytes())?,
                }
            }
            w.write_all(&px[0].to_le_bytes())?;
            w.write_all(&px[1].to_le_bytes())
        }
    }
}

/// The `i`-th value of a property, after a space in ASCII.
fn write_value<W: Write>(
    w: &mut W,
    format: PlyFormat,
    values: &Values,
    i: usize,
) -> std::io::Result<()> {
    match (format, values) {
        (PlyFormat::Ascii, Values::F32(v)) => write!(w, " {}", v[i]),
        (PlyFormat::Ascii, Values::U16(v)) => write!(w, " {}", v[i]),
        (PlyFormat::Ascii, Values::U8(v)) => write!(w, " {}", v[i]),
        (PlyFormat::BinaryLittleEndian, Values::F32(v)) => w.write_all(&v[i].to_le_bytes()),
        (PlyFormat::BinaryLittleEndian, Values::U16(v)) => w.write_all(&v[i].to_le_bytes()),
        (PlyFormat::BinaryLittleEndian, Values::U8(v)) => w.write_all(&[v[i]]),
    }
}

/// [`write()`] into a file, written whole ([`crate::atomic::write_file_atomic`]).
pub fn save(
    path: &Path,
    cloud: &SensorCloud<'_>,
    format: PlyFormat,
    precision: PlyPrecision,
) -> Result<(), WriteError> {
    crate::atomic::write_file_atomic(path, |w| write(w, cloud, format, precision))
}
