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
    let (encoding, elements) = parse_header(&lines)?;
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
    let (ix, iy, iz) = match (find("x"), find("y"), find("z")) {
        (Some(x), Some(y), Some(z)) => (x, y, z),
        _ => {
            return Err(err(
                F,
                "the vertex element lacks scalar properties x, y and z",
            ));
        }
    };
    if let (Encoding::Binary { little }, 0) = (encoding, vi)
        && let Some(cloud) = read_binary_vertices(vertex, body, little, [ix, iy, iz])?
    {
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

/// Fast path for a binary file whose vertex element comes first and has scalar
/// properties only: fixed-size records decoded in place. `None` when it does not apply.
fn read_binary_vertices(
    vertex: &Element,
    body: &[u8],
    little: bool,
    [ix, iy, iz]: [usize; 3],
) -> Result<Option<PointCloud>, ReadError> {
    let mut scalars = Vec::with_capacity(vertex.props.len());
    for p in &vertex.props {
        match p {
            Property::Scalar { name, ty } => scalars.push((name.as_str(), *ty)),
            Property::List { .. } => return Ok(None),
        }
    }
    let mut offsets = Vec::with_capacity(scalars.len());
    let mut record = 0;
    for (_, t) in &scalars {
        offsets.push(record);
        record += t.size();
    }
    let need = vertex.count.checked_mul(record).filter(|&n| n <= body.len()).ok_or_else(|| {
        err(
            F,
            format!(
                "the vertex element declares {} records of {record} bytes but the file is too short (truncated?)",
                vertex.count
            ),
        )
    })?;
    let rows = || body[..need].chunks_exact(record.max(1));
    let (tx, ty, tz) = (scalars[ix].1, scalars[iy].1, scalars[iz].1);
    let (ox, oy, oz) = (offsets[ix], offsets[iy], offsets[iz]);
    let points: Vec<[f64; 3]> = match (tx, ty, tz, little) {
        // The common layouts, decoded without a type dispatch per value.
        (Scalar::F64, Scalar::F64, Scalar::F64, true) => {
            let f =
                |r: &[u8], o: usize| f64::from_le_bytes(r[o..o + 8].try_into().unwrap_or([0; 8]));
            rows().map(|r| [f(r, ox), f(r, oy), f(r, oz)]).collect()
        }
        (Scalar::F32, Scalar::F32, Scalar::F32, true) => {
            let f = |r: &[u8], o: usize| {
                f32::from_le_bytes(r[o..o + 4].try_into().unwrap_or([0; 4])) as f64
            };
            rows().map(|r| [f(r, ox), f(r, oy), f(r, oz)]).collect()
        }
        _ => rows()
            .map(|r| {
                [
                    tx.decode(&r[ox..], little),
                    ty.decode(&r[oy..], little),
                    tz.decode(&r[oz..], little),
                ]
            })
            .collect(),
    };
    let extra = (0..scalars.len())
        .filter(|&k| k != ix && k != iy && k != iz)
        .map(|k| {
            let (t, o) = (scalars[k].1, offsets[k]);
            (
                scalars[k].0.to_string(),
                rows().map(|r| t.decode(&r[o..], little)).collect(),
            )
        })
        .collect();
    Ok(Some(PointCloud { points, extra }))
}
