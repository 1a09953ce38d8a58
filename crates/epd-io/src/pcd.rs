//! Point Cloud Library PCD (v0.7): `DATA ascii`, `binary` and `binary_compressed` (LZF).
//! Fields `x`, `y`, `z` are required (each once); the other single-count fields are kept,
//! except PCL's `_` padding fields. Sizes, counts and offsets are computed with checked
//! arithmetic and checked against the bytes that follow the header before anything is
//! reserved; a `binary_compressed` size is checked against what LZF can expand to.

use crate::read::{PointCloud, ReadError, Scalar, err, quote, split_header};

const F: &str = "PCD";

/// The most bytes LZF can decompress one input byte to: a 3-byte back reference copies
/// up to 264 bytes.
pub const LZF_MAX_RATIO: usize = 88;

struct Field {
    name: String,
    ty: Scalar,
    count: usize,
    /// `ty.size() × count`.
    bytes: usize,
}

/// Running sums: the offset of each item given the sizes before it (the caller checked
/// that the total fits).
fn offsets(sizes: impl Iterator<Item = usize>) -> Vec<usize> {
    sizes
        .scan(0usize, |acc, s| {
            let o = *acc;
            *acc = acc.saturating_add(s);
            Some(o)
        })
        .collect()
}

/// LZF decompression (the format `binary_compressed` uses), with every length checked: the
/// output never exceeds `out_len` bytes nor what `input` can expand to, so any `out_len`
/// is safe.
pub fn lzf_decompress(input: &[u8], out_len: usize) -> Result<Vec<u8>, ReadError> {
    let bad = || err(F, "corrupt LZF data in binary_compressed");
    let mut out = Vec::new();
    out.try_reserve_exact(out_len.min(input.len().saturating_mul(LZF_MAX_RATIO)))
        .map_err(|_| {
            err(
                F,
                format!("not enough memory to decompress {out_len} bytes"),
            )
        })?;
    let mut i = 0;
    while let Some(&ctrl) = input.get(i) {
        let ctrl = ctrl as usize;
        i += 1;
        if ctrl < 32 {
            // A literal run of ctrl + 1 bytes.
            let n = ctrl + 1;
            let s = input.get(i..i + n).ok_or_else(bad)?;
            if out.len() + n > out_len {
                return Err(bad());
            }
            out.extend_from_slice(s);
            i += n;
        } else {
            // A back reference.
            let mut len = ctrl >> 5;
            if len == 7 {
                len += *input.get(i).ok_or_else(bad)? as usize;
                i += 1;
            }
            len += 2;
            let lo = *input.get(i).ok_or_else(bad)? as usize;
            i += 1;
            let back = ((ctrl & 0x1f) << 8) + lo + 1;
            if back > out.len() || out.len() + len > out_len {
                return Err(bad());
            }
            let start = out.len() - back;
            for k in start..start + len {
                // k < out.len(): out grows by one per step and back ≥ 1.
                let b = *out.get(k).ok_or_else(bad)?;
                out.push(b);
            }
        }
    }
    if out.len() != out_len {
        return Err(err(
            F,
            format!(
                "binary_compressed data decompress to {} bytes, the header says {out_len}",
                out.len()
            ),
        ));
    }
    Ok(out)
}

/// Read a PCD file.
pub fn read(bytes: &[u8]) -> Result<PointCloud, ReadError> {
    // The header ends at its DATA line; `data` in lower case ends it too, so that the
    // header's parser names the key's case rather than the binary body as not text.
    let (lines, body) = split_header(
        bytes,
        |l| l.get(..4).is_some_and(|k| k.eq_ignore_ascii_case("DATA")),
        F,
    )?;
    let header = parse_header(&lines)?;
    let layout = Layout::new(&header)?;
    let mut cloud = layout.empty_cloud();
    match header.data.as_str() {
        "ascii" => read_ascii(body, &layout, &mut cloud)?,
        "binary" => read_binary(body, &layout, &mut cloud)?,
        "binary_compressed" => read_compressed(body, &layout, &mut cloud)?,
        other => {
            return Err(err(
                F,
                format!(
                    "DATA `{}` is not ascii, binary or binary_compressed",
                    quote(other)
                ),
            ));
        }
    }
    Ok(cloud)
}

/// The header's keys as written: one entry per field in `names`, `sizes`, `types` and
/// `counts` (not yet checked against each other).
#[derive(Default)]
struct Header {
    names: Vec<String>,
    sizes: Vec<usize>,
    types: Vec<char>,
    counts: Vec<usize>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
    /// `ascii`, `binary` or `binary_compressed` (anything else is refused later).
    data: String,
}

/// Parse the header lines; blank lines and `#` comments are skipped, `VERSION` and
/// `VIEWPOINT` ignored, any other unknown key refused.
/// The header keys of PCD v0.7.
const PCD_KEYS: [&str; 10] = [
    "VERSION",
    "FIELDS",
    "SIZE",
    "TYPE",
    "COUNT",
    "WIDTH",
    "HEIGHT",
    "VIEWPOINT",
    "POINTS",
    "DATA",
];

fn parse_header(lines: &[String]) -> Result<Header, ReadError> {
    let mut h = Header::default();
    // Each key once: a second FIELDS or POINTS line would silently replace the first.
    let mut first_line: Vec<(String, usize)> = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or("");
        let rest: Vec<&str> = words.collect();
        let bad = |what: &str| {
            err(
                F,
                format!("header line {}: {what}: `{}`", i + 1, quote(line)),
            )
        };
        let nums = |v: &[&str]| -> Result<Vec<usize>, ReadError> {
            v.iter()
                .map(|w| {
                    w.parse::<usize>()
                        .map_err(|_| bad("expected whole numbers"))
                })
                .collect()
        };
        if let Some((_, at)) = first_line.iter().find(|(k, _)| k == key) {
            return Err(bad(&format!("`{key}` again (first on header line {at})")));
        }
        first_line.push((key.to_string(), i + 1));
        match key {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => h.names = rest.iter().map(|s| s.to_string()).collect(),
            "SIZE" => h.sizes = nums(&rest)?,
            "TYPE" => {
                h.types = rest
                    .iter()
                    .map(|s| match *s {
                        "I" | "U" | "F" => Ok(s.chars().next().unwrap_or('F')),
                        _ => Err(bad("TYPE must be I, U or F")),
                    })
                    .collect::<Result<_, _>>()?
            }
            "COUNT" => h.counts = nums(&rest)?,
            "WIDTH" => h.width = nums(&rest)?.first().copied(),
            "HEIGHT" => h.height = nums(&rest)?.first().copied(),
            "POINTS" => h.points = nums(&rest)?.first().copied(),
            "DATA" => h.data = rest.first().unwrap_or(&"").to_string(),
            _ if PCD_KEYS.iter().any(|k| k.eq_ignore_ascii_case(key)) => {
                return Err(bad("header keys are upper case (PCL's)"));
            }
            _ => return Err(bad("unknown header key")),
        }
    }
    Ok(h)
}

/// The scalar type of a field of PCD `TYPE` `t` (I, U or F) and `SIZE` `s` bytes.
fn scalar(t: char, s: usize) -> Option<Scalar> {
    Some(match (t, s) {
        ('I', 1) => Scalar::I8,
        ('U', 1) => Scalar::U8,
        ('I', 2) => Scalar::I16,
        ('U', 2) => Scalar::U16,
        ('I', 4) => Scalar::I32,
        ('U', 4) => Scalar::U32,
        ('I', 8) => Scalar::I64,
        ('U', 8) => Scalar::U64,
        ('F', 4) => Scalar::F32,
        ('F', 8) => Scalar::F64,
        _ => return None,
    })
}

/// The fields of the header, checked: the lists agree in length, no name twice (but PCL's
/// `_` padding), a supported type, a count ≥ 1 whose bytes fit in `usize`.
fn fields(h: &Header) -> Result<Vec<Field>, ReadError> {
    let names = &h.names;
    if names.is_empty() {
        return Err(err(F, "the header has no FIELDS"));
    }
    let counts = match h.counts.is_empty() {
        true => vec![1; names.len()],
        false => h.counts.clone(),
    };
    if h.sizes.len() != names.len() || h.types.len() != names.len() || counts.len() != names.len() {
        return Err(err(
            F,
            "FIELDS, SIZE, TYPE and COUNT list different numbers of fields",
        ));
    }
    let mut fields: Vec<Field> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (k, name) in names.iter().enumerate() {
        // PCL names padding fields `_`, as many as there are.
        if name != "_" && !seen.insert(name.as_str()) {
            return Err(err(F, format!("FIELDS names `{}` twice", quote(name))));
        }
        let ty = scalar(h.types[k], h.sizes[k]).ok_or_else(|| {
            err(
                F,
                format!(
                    "field `{}`: TYPE {} with SIZE {} is not supported",
                    quote(name),
                    h.types[k],
                    h.sizes[k]
                ),
            )
        })?;
        let count = counts[k];
        if count == 0 {
            return Err(err(F, format!("field `{}` has COUNT 0", quote(name))));
        }
        let bytes = count.checked_mul(ty.size()).ok_or_else(|| {
            err(
                F,
                format!("field `{}`: COUNT {count} is too large", quote(name)),
            )
        })?;
        fields.push(Field {
            name: name.clone(),
            ty,
            count,
            bytes,
        });
    }
    Ok(fields)
}

/// What the header says of every point: its fields, how many points, the size of a record,
/// where x, y, z and the kept extra fields are.
struct Layout {
    fields: Vec<Field>,
    /// Points in the file.
    n: usize,
    /// Bytes of one point in `binary` (the sum of the fields' bytes).
    record: usize,
    /// Numbers on one line of `ascii` (the sum of the COUNTs).
    values_per_point: usize,
    /// Indices of x, y and z in `fields`.
    xyz: [usize; 3],
    /// Indices of the fields kept as extra properties: single-count, not padding.
    extra: Vec<usize>,
}

impl Layout {
    fn new(h: &Header) -> Result<Self, ReadError> {
        let fields = fields(h)?;
        let too_large = || {
            err(
                F,
                "the COUNT values are too large (a point would take more than 2^64 bytes)",
            )
        };
        let values_per_point = fields
            .iter()
            .try_fold(0usize, |a, f| a.checked_add(f.count))
            .ok_or_else(too_large)?;
        let record = fields
            .iter()
            .try_fold(0usize, |a, f| a.checked_add(f.bytes))
            .ok_or_else(too_large)?;
        let n = match (h.points, h.width, h.height) {
            (Some(p), Some(w), Some(hh)) if w.checked_mul(hh) != Some(p) => {
                return Err(err(
                    F,
                    format!(
                        "the header's POINTS {p} is not WIDTH × HEIGHT = {w} × {hh}: \
                         which count holds is unclear"
                    ),
                ));
            }
            (Some(p), _, _) => p,
            (None, Some(w), Some(h)) => w
                .checked_mul(h)
                .ok_or_else(|| err(F, "WIDTH × HEIGHT is too large"))?,
            _ => {
                return Err(err(
                    F,
                    "the header gives neither POINTS nor WIDTH and HEIGHT",
                ));
            }
        };
        let find = |nm: &str| fields.iter().position(|f| f.name == nm);
        let xyz = match (find("x"), find("y"), find("z")) {
            (Some(x), Some(y), Some(z)) => [x, y, z],
            _ => return Err(err(F, "the fields lack x, y and z")),
        };
        let extra = (0..fields.len())
            .filter(|&k| !xyz.contains(&k) && fields[k].count == 1 && fields[k].name != "_")
            .collect();
        Ok(Layout {
            fields,
            n,
            record,
            values_per_point,
            xyz,
            extra,
        })
    }

    /// A cloud with no points and one empty vector per extra field.
    fn empty_cloud(&self) -> PointCloud {
        PointCloud {
            points: Vec::new(),
            extra: self
                .extra
                .iter()
                .map(|&k| (self.fields[k].name.clone(), Vec::new()))
                .collect(),
        }
    }

    /// Append one point to `cloud`; `value(k)` is its value of field `k`.
    fn push(&self, cloud: &mut PointCloud, value: impl Fn(usize) -> f64) {
        let [ix, iy, iz] = self.xyz;
        cloud.points.push([value(ix), value(iy), value(iz)]);
        for (&k, (_, values)) in self.extra.iter().zip(cloud.extra.iter_mut()) {
            values.push(value(k));
        }
    }

    fn truncated(&self, have: usize) -> ReadError {
        let (n, record) = (self.n, self.record);
        err(
            F,
            format!("{have} bytes of data for {n} points of {record} bytes (truncated?)"),
        )
    }
}

/// `DATA ascii`: one line of `values_per_point` numbers per point, exactly `n` lines.
fn read_ascii(body: &[u8], l: &Layout, cloud: &mut PointCloud) -> Result<(), ReadError> {
    let (n, values_per_point) = (l.n, l.values_per_point);
    let text = std::str::from_utf8(body).map_err(|e| {
        err(
            F,
            format!(
                "DATA ascii but the body is not text (byte {} after the header)",
                e.valid_up_to()
            ),
        )
    })?;
    let first_value = offsets(l.fields.iter().map(|f| f.count));
    let mut rows = 0;
    for (li, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|w| {
                w.parse::<f64>().map_err(|_| {
                    err(
                        F,
                        format!("data line {}: `{}` is not a number", li + 1, quote(w)),
                    )
                })
            })
            .collect::<Result<_, _>>()?;
        if v.len() != values_per_point {
            return Err(err(
                F,
                format!(
                    "data line {}: {} values, expected {values_per_point}",
                    li + 1,
                    v.len()
                ),
            ));
        }
        if rows == n {
            return Err(err(
                F,
                format!(
                    "data line {}: more data lines than the {n} points the header says",
                    li + 1
                ),
            ));
        }
        // v has values_per_point values and first_value[k] < values_per_point.
        l.push(cloud, |k| {
            first_value
                .get(k)
                .and_then(|&i| v.get(i))
                .copied()
                .unwrap_or(f64::NAN)
        });
        rows += 1;
    }
    if rows != n {
        return Err(err(
            F,
            format!("{rows} data lines, the header says {n} points (truncated?)"),
        ));
    }
    Ok(())
}

/// The record layout of a PCD with `DATA binary` from its header lines (`None` for any
/// other PCD): [`crate::records::RecordFile`].
pub(crate) fn record_layout(lines: &[String]) -> Option<crate::records::RecordLayout> {
    let h = parse_header(lines).ok()?;
    if h.data != "binary" {
        return None;
    }
    let l = Layout::new(&h).ok()?;
    let offsets = offsets(l.fields.iter().map(|f| f.bytes));
    let at = |k: usize| (l.fields[k].ty, offsets[k]);
    Some(crate::records::RecordLayout {
        format: F,
        what: "the header".into(),
        count: l.n as u64,
        record: l.record,
        little: true,
        xyz: l.xyz.map(at),
        extra: l
            .extra
            .iter()
            .map(|&k| (l.fields[k].name.clone(), l.fields[k].ty, offsets[k]))
            .collect(),
    })
}

/// `DATA binary`: `n` little-endian records of `record` bytes, point-major.
fn read_binary(body: &[u8], l: &Layout, cloud: &mut PointCloud) -> Result<(), ReadError> {
    let bytes =
        l.n.checked_mul(l.record)
            .filter(|&b| b <= body.len())
            .ok_or_else(|| l.truncated(body.len()))?;
    let offsets = offsets(l.fields.iter().map(|f| f.bytes));
    let data = body.get(..bytes).ok_or_else(|| l.truncated(body.len()))?;
    cloud.reserve(l.n, F)?;
    for rec in data.chunks_exact(l.record.max(1)).take(l.n) {
        // Field `k` of a record: `record` ≥ offsets[k] + its size.
        l.push(cloud, |k| {
            rec.get(offsets[k]..)
                .and_then(|s| l.fields[k].ty.decode(s, true))
                .unwrap_or(f64::NAN)
        });
    }
    Ok(())
}

/// `DATA binary_compressed`: the compressed and the raw size (two little-endian u32),
/// then LZF data that decompress to the `n` points field-major (all values of field 0,
/// then of field 1, …).
fn read_compressed(body: &[u8], l: &Layout, cloud: &mut PointCloud) -> Result<(), ReadError> {
    let (n, record) = (l.n, l.record);
    let word = |i: usize| -> Result<usize, ReadError> {
        let b = body
            .get(i..i + 4)
            .ok_or_else(|| err(F, "binary_compressed data are truncated"))?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let (csize, usize_) = (word(0)?, word(4)?);
    let expected = n.checked_mul(record);
    if expected != Some(usize_) {
        return Err(err(
            F,
            format!(
                "binary_compressed holds {usize_} bytes, {n} points of {record} bytes need {}",
                expected.map_or("more than 2^64".to_string(), |b| b.to_string())
            ),
        ));
    }
    let comp = csize
        .checked_add(8)
        .and_then(|end| body.get(8..end))
        .ok_or_else(|| {
            err(
                F,
                format!(
                    "binary_compressed data are truncated ({csize} bytes said, {} there)",
                    body.len().saturating_sub(8)
                ),
            )
        })?;
    if usize_ > csize.saturating_mul(LZF_MAX_RATIO) {
        return Err(err(
            F,
            format!(
                "binary_compressed: {usize_} bytes cannot come from {csize} bytes of LZF data (at most {LZF_MAX_RATIO}×; corrupt header?)"
            ),
        ));
    }
    let raw = lzf_decompress(comp, usize_)?;
    // Field-major: all values of field 0, then of field 1, … (n × record = raw.len()).
    let starts = offsets(l.fields.iter().map(|f| n.saturating_mul(f.bytes)));
    cloud.reserve(n, F)?;
    for r in 0..n {
        l.push(cloud, |k| {
            let f = &l.fields[k];
            r.checked_mul(f.bytes)
                .and_then(|o| o.checked_add(starts[k]))
                .and_then(|o| raw.get(o..))
                .and_then(|s| f.ty.decode(s, true))
                .unwrap_or(f64::NAN)
        });
    }
    Ok(())
}
