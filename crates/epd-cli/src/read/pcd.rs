//! Point Cloud Library PCD (v0.7): `DATA ascii`, `binary` and `binary_compressed` (LZF).
//! Fields `x`, `y`, `z` are required; the other single-count fields are kept.

use super::{PointCloud, ReadError, Scalar, err, split_header};

const F: &str = "PCD";

struct Field {
    name: String,
    ty: Scalar,
    count: usize,
}

/// Running sums: the offset of each item given the sizes before it.
fn offsets(sizes: impl Iterator<Item = usize>) -> Vec<usize> {
    sizes
        .scan(0, |acc, s| {
            let o = *acc;
            *acc += s;
            Some(o)
        })
        .collect()
}

/// LZF decompression (the format `binary_compressed` uses), with every length checked.
pub fn lzf_decompress(input: &[u8], out_len: usize) -> Result<Vec<u8>, ReadError> {
    let mut out = Vec::with_capacity(out_len.min(1 << 30));
    let mut i = 0;
    let bad = || err(F, "corrupt LZF data in binary_compressed");
    while i < input.len() {
        let ctrl = input[i] as usize;
        i += 1;
        if ctrl < 32 {
            // A literal run of ctrl + 1 bytes.
            let n = ctrl + 1;
            let s = input.get(i..i + n).ok_or_else(bad)?;
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
            if back > out.len() {
                return Err(bad());
            }
            let start = out.len() - back;
            for k in 0..len {
                let b = out[start + k];
                out.push(b);
            }
        }
        if out.len() > out_len {
            return Err(bad());
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
        let bad = |what: &str| err(F, format!("header line {}: {what}: `{line}`", i + 1));
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
    let mut fields = Vec::new();
    for k in 0..names.len() {
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
                        names[k]
                    ),
                ));
            }
        };
        if counts[k] == 0 {
            return Err(err(F, format!("field `{}` has COUNT 0", names[k])));
        }
        fields.push(Field {
            name: names[k].clone(),
            ty,
            count: counts[k],
        });
    }
    let n = match (points, width, height) {
        (Some(p), _, _) => p,
        (None, Some(w), Some(h)) => w.saturating_mul(h),
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
    // Value offsets of each field within a point (in values and in bytes).
    let values_per_point: usize = fields.iter().map(|f| f.count).sum();
    let record: usize = fields.iter().map(|f| f.ty.size() * f.count).sum();
    let mut cloud = PointCloud::default();
    let extra_fields: Vec<usize> = (0..fields.len())
        .filter(|&k| k != ix && k != iy && k != iz && fields[k].count == 1)
        .collect();
    cloud.extra = extra_fields
        .iter()
        .map(|&k| (fields[k].name.clone(), Vec::new()))
        .collect();
    let push = |vals: &dyn Fn(usize) -> f64, cloud: &mut PointCloud| {
        cloud.points.push([vals(ix), vals(iy), vals(iz)]);
        for (e, &k) in extra_fields.iter().enumerate() {
            cloud.extra[e].1.push(vals(k));
        }
    };
    match data.as_str() {
        "ascii" => {
            let text = std::str::from_utf8(body)
                .map_err(|_| err(F, "DATA ascii but the body is not text"))?;
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
                            err(F, format!("data line {}: `{w}` is not a number", li + 1))
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
                push(&|k| v[first_value[k]], &mut cloud);
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
            if body.len() < n.saturating_mul(record) {
                return Err(err(
                    F,
                    format!(
                        "{} bytes of data for {n} points of {record} bytes (truncated?)",
                        body.len()
                    ),
                ));
            }
            let offsets = offsets(fields.iter().map(|f| f.ty.size() * f.count));
            cloud.points.reserve(n);
            for r in 0..n {
                let rec = &body[r * record..(r + 1) * record];
                push(
                    &|k| fields[k].ty.decode(&rec[offsets[k]..], true),
                    &mut cloud,
                );
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
            if usize_ != n.saturating_mul(record) {
                return Err(err(
                    F,
                    format!(
                        "binary_compressed holds {usize_} bytes, {n} points need {}",
                        n.saturating_mul(record)
                    ),
                ));
            }
            let comp = body
                .get(8..8 + csize)
                .ok_or_else(|| err(F, "binary_compressed data are truncated"))?;
            let raw = lzf_decompress(comp, usize_)?;
            // Field-major: all values of field 0, then of field 1, …
            let starts = offsets(fields.iter().map(|f| n * f.ty.size() * f.count));
            cloud.points.reserve(n);
            for r in 0..n {
                push(
                    &|k| {
                        let sz = fields[k].ty.size() * fields[k].count;
                        fields[k].ty.decode(&raw[starts[k] + r * sz..], true)
                    },
                    &mut cloud,
                );
            }
        }
        other => {
            return Err(err(
                F,
                format!("DATA `{other}` is not ascii, binary or binary_compressed"),
            ));
        }
    }
    Ok(cloud)
}
