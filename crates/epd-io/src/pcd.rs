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
    let (lines, body) = split_header(bytes, |l| l.starts_with("DATA"), F)?;
    let mut names: Vec<String> = Vec::new();
    let mut sizes: Vec<usize> = Vec::new();
    let mut types: Vec<char> = Vec::new();
    let mut counts: Vec<usize> = Vec::new();
    let (mut width, mut height, mut points) = (None, None, None);
    let mut data = String::new();
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
        match key {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => names = rest.iter().map(|s| s.to_string()).collect(),
            "SIZE" => sizes = nums(&rest)?,
            "TYPE" => {
                types = rest
                    .iter()
                    .map(|s| match *s {
                        "I" | "U" | "F" => Ok(s.chars().next().unwrap_or('F')),
                        _ => Err(bad("TYPE must be I, U or F")),
                    })
                    .collect::<Result<_, _>>()?
            }
            "COUNT" => counts = nums(&rest)?,
            "WIDTH" => width = nums(&rest)?.first().copied(),
            "HEIGHT" => height = nums(&rest)?.first().copied(),
            "POINTS" => points = nums(&rest)?.first().copied(),
            "DATA" => data = rest.first().unwrap_or(&"").to_string(),
            _ => return Err(bad("unknown header key")),
        }
    }
    if names.is_empty() {
        return Err(err(F, "the header has no FIELDS"));
    }
    if counts.is_empty() {
        counts = vec![1; names.len()];
    }
    if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
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
        let ty = match (types[k], sizes[k]) {
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
            (t, s) => {
                return Err(err(
                    F,
                    format!(
                        "field `{}`: TYPE {t} with SIZE {s} is not supported",
                        quote(name)
                    ),
                ));
            }
        };
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
    let n = match (points, width, height) {
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
    let (ix, iy, iz) = match (find("x"), find("y"), find("z")) {
        (Some(x), Some(y), Some(z)) => (x, y, z),
        _ => return Err(err(F, "the fields lack x, y and z")),
    };
    let extra_fields: Vec<usize> = (0..fields.len())
        .filter(|&k| ![ix, iy, iz].contains(&k) && fields[k].count == 1 && fields[k].name != "_")
        .collect();
    let mut cloud = PointCloud {
        points: Vec::new(),
        extra: extra_fields
            .iter()
            .map(|&k| (fields[k].name.clone(), Vec::new()))
            .collect(),
    };
    let truncated = |have: usize| {
        err(
            F,
            format!("{have} bytes of data for {n} points of {record} bytes (truncated?)"),
        )
    };
    // The data of `n` points take `need` bytes; an error unless `have` bytes hold them.
    let need = |have: usize| {
        n.checked_mul(record)
            .filter(|&b| b <= have)
            .ok_or_else(|| truncated(have))
    };
    match data.as_str() {
        "ascii" => {
            let text = std::str::from_utf8(body).map_err(|e| {
                err(
                    F,
                    format!(
                        "DATA ascii but the body is not text (byte {} after the header)",
                        e.valid_up_to()
                    ),
                )
            })?;
            let first_value = offsets(fields.iter().map(|f| f.count));
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
                let val = |k: usize| {
                    first_value
                        .get(k)
                        .and_then(|&i| v.get(i))
                        .copied()
                        .unwrap_or(f64::NAN)
                };
                cloud.points.push([val(ix), val(iy), val(iz)]);
                for (&k, (_, values)) in extra_fields.iter().zip(cloud.extra.iter_mut()) {
                    values.push(val(k));
                }
                rows += 1;
            }
            if rows != n {
                return Err(err(
                    F,
                    format!("{rows} data lines, the header says {n} points (truncated?)"),
                ));
            }
        }
        "binary" => {
            let bytes = need(body.len())?;
            let offsets = offsets(fields.iter().map(|f| f.bytes));
            let data = body.get(..bytes).ok_or_else(|| truncated(body.len()))?;
            cloud.reserve(n, F)?;
            // Field `k` of a record: `record` ≥ offsets[k] + its size.
            let value = |rec: &[u8], k: usize| {
                rec.get(offsets[k]..)
                    .and_then(|s| fields[k].ty.decode(s, true))
                    .unwrap_or(f64::NAN)
            };
            for rec in data.chunks_exact(record.max(1)).take(n) {
                cloud
                    .points
                    .push([value(rec, ix), value(rec, iy), value(rec, iz)]);
                for (&k, (_, values)) in extra_fields.iter().zip(cloud.extra.iter_mut()) {
                    values.push(value(rec, k));
                }
            }
        }
        "binary_compressed" => {
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
            let starts = offsets(fields.iter().map(|f| n.saturating_mul(f.bytes)));
            let value = |r: usize, k: usize| {
                let f = &fields[k];
                r.checked_mul(f.bytes)
                    .and_then(|o| o.checked_add(starts[k]))
                    .and_then(|o| raw.get(o..))
                    .and_then(|s| f.ty.decode(s, true))
                    .unwrap_or(f64::NAN)
            };
            cloud.reserve(n, F)?;
            for r in 0..n {
                cloud
                    .points
                    .push([value(r, ix), value(r, iy), value(r, iz)]);
                for (&k, (_, values)) in extra_fields.iter().zip(cloud.extra.iter_mut()) {
                    values.push(value(r, k));
                }
            }
        }
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
