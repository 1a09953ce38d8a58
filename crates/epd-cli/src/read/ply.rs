//! Stanford PLY: `format ascii 1.0`, `binary_little_endian 1.0`, `binary_big_endian 1.0`.
//! The `vertex` element must have `x`, `y`, `z` (any scalar type); its other scalar
//! properties are kept; other elements (faces…) are read past.

use super::{PointCloud, ReadError, Scalar, err, split_header};

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
        count: Scalar,
        item: Scalar,
    },
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
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

fn parse_header(lines: &[String]) -> Result<(Encoding, Vec<Element>), ReadError> {
    if lines.first().map(|l| l.trim()) != Some("ply") {
        return Err(err(F, "the file does not start with `ply`"));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, line) in lines.iter().enumerate().skip(1) {
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = |what: &str| err(F, format!("header line {}: {what}: `{line}`", i + 1));
        match words.as_slice() {
            [] => {}
            ["comment", ..] | ["obj_info", ..] | ["end_header"] => {}
            ["format", f, _version] => {
                encoding = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Binary { little: true },
                    "binary_big_endian" => Encoding::Binary { little: false },
                    _ => return Err(bad("unknown format")),
                })
            }
            ["element", name, count] => {
                let count: usize = count
                    .parse()
                    .map_err(|_| bad("the element count is not a whole number"))?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            ["property", "list", c, t, _name] => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| bad("a property before any element"))?;
                let count = scalar(c).ok_or_else(|| bad("unknown list count type"))?;
                let item = scalar(t).ok_or_else(|| bad("unknown list item type"))?;
                if matches!(count, Scalar::F32 | Scalar::F64) {
                    return Err(bad("a list count must be an integer type"));
                }
                el.props.push(Property::List { count, item });
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
    }
    let encoding = encoding.ok_or_else(|| err(F, "the header has no `format` line"))?;
    Ok((encoding, elements))
}

/// A cursor over the body.
struct Body<'a> {
    bytes: &'a [u8],
    pos: usize,
    encoding: Encoding,
}

impl Body<'_> {
    fn token(&mut self) -> Option<&str> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if start == self.pos {
            None
        } else {
            std::str::from_utf8(&b[start..self.pos]).ok()
        }
    }

    fn value(&mut self, ty: Scalar, what: &dyn Fn() -> String) -> Result<f64, ReadError> {
        match self.encoding {
            Encoding::Ascii => {
                let t = self
                    .token()
                    .ok_or_else(|| err(F, format!("the file ends inside {}", what())))?;
                t.parse::<f64>()
                    .map_err(|_| err(F, format!("`{t}` in {} is not a number", what())))
            }
            Encoding::Binary { little } => {
                let n = ty.size();
                let s = self.bytes.get(self.pos..self.pos + n).ok_or_else(|| {
                    err(F, format!("the file ends inside {} (truncated?)", what()))
                })?;
                self.pos += n;
                Ok(ty.decode(s, little))
            }
        }
    }
}

/// Read a PLY file.
pub fn read(bytes: &[u8]) -> Result<PointCloud, ReadError> {
    let (lines, body) = split_header(bytes, |l| l == "end_header", F)?;
    let (encoding, elements, vi, [ix, iy, iz]) = layout_of(&lines)?;
    if let (Encoding::Binary { little }, 0) = (encoding, vi)
        && let Some(layout) = VertexLayout::new(&elements[0], little, [ix, iy, iz])
    {
        let need = layout
            .count
            .checked_mul(layout.record)
            .filter(|&n| n <= body.len())
            .ok_or_else(|| layout.too_short())?;
        let mut cloud = layout.empty_cloud();
        layout.decode(&body[..need], &mut cloud);
        return Ok(cloud);
    }
    let mut cur = Body {
        bytes: body,
        pos: 0,
        encoding,
    };
    let mut cloud = PointCloud::default();
    for (ei, el) in elements.iter().enumerate() {
        // Guard against absurd counts before reserving memory.
        let min_record = match encoding {
            Encoding::Binary { .. } => el
                .props
                .iter()
                .map(|p| match p {
                    Property::Scalar { ty, .. } => ty.size(),
                    Property::List { count, .. } => count.size(),
                })
                .sum::<usize>(),
            Encoding::Ascii => 2 * el.props.len(),
        };
        if el.count.saturating_mul(min_record) > body.len().saturating_sub(cur.pos) {
            return Err(err(
                F,
                format!(
                    "element `{}` declares {} records but the file is too short for them (truncated?)",
                    el.name, el.count
                ),
            ));
        }
        let keep = ei == vi;
        let mut extra: Vec<(String, Vec<f64>)> = Vec::new();
        if keep {
            cloud.points.reserve(el.count);
            for (pi, p) in el.props.iter().enumerate() {
                if let Property::Scalar { name, .. } = p
                    && pi != ix
                    && pi != iy
                    && pi != iz
                {
                    extra.push((name.clone(), Vec::with_capacity(el.count)));
                }
            }
        }
        for r in 0..el.count {
            let mut xyz = [0.0; 3];
            let mut e = 0;
            for (pi, p) in el.props.iter().enumerate() {
                let what = || format!("`{}` record {}", el.name, r + 1);
                match p {
                    Property::Scalar { ty, .. } => {
                        let v = cur.value(*ty, &what)?;
                        if keep {
                            if pi == ix {
                                xyz[0] = v;
                            } else if pi == iy {
                                xyz[1] = v;
                            } else if pi == iz {
                                xyz[2] = v;
                            } else {
                                extra[e].1.push(v);
                                e += 1;
                            }
                        }
                    }
                    Property::List { count, item, .. } => {
                        let n = cur.value(*count, &what)?;
                        if !(0.0..=1e6).contains(&n) {
                            return Err(err(
                                F,
                                format!("list length {n} in {} is not plausible", what()),
                            ));
                        }
                        for _ in 0..n as usize {
                            cur.value(*item, &what)?;
                        }
                    }
                }
            }
            if keep {
                cloud.points.push(xyz);
            }
        }
        if keep {
            cloud.extra = extra;
        }
    }
    Ok(cloud)
}

/// The record layout of a binary vertex element with scalar properties only: the fast
/// path, decoding fixed-size records in place.
struct VertexLayout {
    count: usize,
    record: usize,
    little: bool,
    xyz: [(Scalar, usize); 3],
    extra: Vec<(String, Scalar, usize)>,
}

impl VertexLayout {
    /// The layout of `vertex`, or `None` when it has list properties.
    fn new(vertex: &Element, little: bool, [ix, iy, iz]: [usize; 3]) -> Option<Self> {
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
        let xyz = [ix, iy, iz].map(|i| (fields[i].1, fields[i].2));
        let extra = fields
            .into_iter()
            .enumerate()
            .filter(|(k, _)| ![ix, iy, iz].contains(k))
            .map(|(_, f)| f)
            .collect();
        Some(Self {
            count: vertex.count,
            record,
            little,
            xyz,
            extra,
        })
    }

    fn empty_cloud(&self) -> PointCloud {
        PointCloud {
            points: Vec::with_capacity(self.count),
            extra: self
                .extra
                .iter()
                .map(|(n, _, _)| (n.clone(), Vec::with_capacity(self.count)))
                .collect(),
        }
    }

    /// Append the whole records in `data` to `cloud`.
    fn decode(&self, data: &[u8], cloud: &mut PointCloud) {
        let rows = || data.chunks_exact(self.record.max(1));
        let [(tx, ox), (ty, oy), (tz, oz)] = self.xyz;
        let little = self.little;
        match (tx, ty, tz, little) {
            // The common layouts, decoded without a type dispatch per value.
            (Scalar::F64, Scalar::F64, Scalar::F64, true) => {
                let f = |r: &[u8], o: usize| {
                    f64::from_le_bytes(r[o..o + 8].try_into().unwrap_or([0; 8]))
                };
                cloud
                    .points
                    .extend(rows().map(|r| [f(r, ox), f(r, oy), f(r, oz)]));
            }
            (Scalar::F32, Scalar::F32, Scalar::F32, true) => {
                let f = |r: &[u8], o: usize| {
                    f32::from_le_bytes(r[o..o + 4].try_into().unwrap_or([0; 4])) as f64
                };
                cloud
                    .points
                    .extend(rows().map(|r| [f(r, ox), f(r, oy), f(r, oz)]));
            }
            _ => cloud.points.extend(rows().map(|r| {
                [
                    tx.decode(&r[ox..], little),
                    ty.decode(&r[oy..], little),
                    tz.decode(&r[oz..], little),
                ]
            })),
        }
        for (e, (_, t, o)) in self.extra.iter().enumerate() {
            cloud.extra[e]
                .1
                .extend(rows().map(|r| t.decode(&r[*o..], little)));
        }
    }

    fn too_short(&self) -> ReadError {
        err(
            F,
            format!(
                "the vertex element declares {} records of {} bytes but the file is too short (truncated?)",
                self.count, self.record
            ),
        )
    }
}

/// Header, vertex index and x, y, z indices of a PLY file.
fn layout_of(lines: &[String]) -> Result<(Encoding, Vec<Element>, usize, [usize; 3]), ReadError> {
    let (encoding, elements) = parse_header(lines)?;
    let vi = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| err(F, "no `vertex` element"))?;
    let vertex = &elements[vi];
    let find = |n: &str| {
        vertex
            .props
            .iter()
            .position(|p| matches!(p, Property::Scalar { name, .. } if name == n))
    };
    match (find("x"), find("y"), find("z")) {
        (Some(x), Some(y), Some(z)) => Ok((encoding, elements, vi, [x, y, z])),
        _ => Err(err(
            F,
            "the vertex element lacks scalar properties x, y and z",
        )),
    }
}

/// Read a PLY file from disk. Binary files whose vertices come first with scalar
/// properties only are decoded as they stream in (no copy of the whole file in memory);
/// other files are read whole and parsed by [`read`].
pub fn read_path(path: &std::path::Path) -> Result<PointCloud, String> {
    use std::io::{BufRead, Read};
    let file = std::fs::File::open(path).map_err(|e| format!("cannot read: {e}"))?;
    let mut r = std::io::BufReader::with_capacity(1 << 20, file);
    let mut lines = Vec::new();
    loop {
        let mut line = Vec::new();
        let n = r
            .read_until(b'\n', &mut line)
            .map_err(|e| format!("cannot read: {e}"))?;
        if n == 0 || lines.len() > 10_000 {
            return Err(err(F, "the header never ends (truncated file?)").to_string());
        }
        let text = String::from_utf8(line).map_err(|_| {
            err(F, format!("header line {} is not text", lines.len() + 1)).to_string()
        })?;
        let text = text.trim_end_matches(['\n', '\r']).to_string();
        let end = text.trim() == "end_header";
        lines.push(text);
        if end {
            break;
        }
    }
    let (encoding, elements, vi, xyz) = layout_of(&lines).map_err(|e| e.to_string())?;
    let fast = match encoding {
        Encoding::Binary { little } if vi == 0 => VertexLayout::new(&elements[0], little, xyz),
        _ => None,
    };
    let Some(layout) = fast else {
        let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
        return read(&bytes).map_err(|e| e.to_string());
    };
    let mut cloud = layout.empty_cloud();
    let per_chunk = ((1 << 20) / layout.record.max(1)).max(1);
    let mut buf = vec![0u8; per_chunk * layout.record];
    let mut left = layout.count;
    while left > 0 {
        let k = left.min(per_chunk);
        let chunk = &mut buf[..k * layout.record];
        r.read_exact(chunk).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => layout.too_short().to_string(),
            _ => format!("cannot read: {e}"),
        })?;
        layout.decode(chunk, &mut cloud);
        left -= k;
    }
    Ok(cloud)
}
