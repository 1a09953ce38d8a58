//! `sensor_msgs/msg/PointCloud2` decoded from its CDR bytes (ROS 2's serialisation: OMG
//! XCDR version 1, as written by Fast DDS, Cyclone DDS and `rosbags`).
//!
//! The layout: a 4-byte encapsulation header (`00 01` little-endian CDR, `00 00`
//! big-endian; the two option bytes ignored), then the fields in order, each primitive
//! aligned to its size counted from the byte after the header:
//! `header.stamp.sec: i32`, `header.stamp.nanosec: u32`, `header.frame_id: string` (u32
//! length including the final NUL, then the bytes), `height: u32`, `width: u32`,
//! `fields: sequence<PointField>` (u32 count; each `name: string`, `offset: u32`,
//! `datatype: u8`, `count: u32`), `is_bigendian: bool`, `point_step: u32`,
//! `row_step: u32`, `data: sequence<u8>`, `is_dense: bool`.
//!
//! The points: point (row r, column c) starts at `r·row_step + c·point_step` of `data`;
//! each field at its `offset` within the point, in the datatype of `sensor_msgs/PointField`
//! (1 INT8, 2 UINT8, 3 INT16, 4 UINT16, 5 INT32, 6 UINT32, 7 FLOAT32, 8 FLOAT64) and the
//! byte order of `is_bigendian`. Every count and offset is checked against the bytes
//! before anything is reserved: a crafted message gives an error, never a panic or an
//! allocation beyond a constant times its size.

use crate::read::{PointCloud, ReadError, Scalar, err};

/// The format named in this module's errors.
pub const F: &str = "PointCloud2";

/// The ROS 2 type name of the messages this module decodes.
pub const POINT_CLOUD2: &str = "sensor_msgs/msg/PointCloud2";

/// The most fields a PointCloud2 may declare: a camera's cloud has 3–10 (x, y, z,
/// intensity, rgb, ring, time, …); 1000 leaves room for any real layout and bounds the work
/// on a crafted count (each field takes at least 13 bytes of the message too).
pub const MAX_FIELDS: usize = 1000;

/// One decoded PointCloud2 message: its header and its points.
#[derive(Clone, Debug, PartialEq)]
pub struct PointCloud2 {
    /// `header.stamp` as integer nanoseconds (sec·10⁹ + nanosec).
    pub stamp_ns: i64,
    /// `header.frame_id`.
    pub frame_id: String,
    /// `height` (1 for an unorganised cloud).
    pub height: u32,
    /// `width`.
    pub width: u32,
    /// `is_dense` as written (the points are kept as stored either way).
    pub is_dense: bool,
    /// The points, row after row, as stored (NaN and zeros included: the estimator drops
    /// and counts them, as for the other readers), and every other field with `count` 1 as
    /// a per-point property (`intensity`, …) by its name.
    pub cloud: PointCloud,
}

/// A cursor over CDR bytes with XCDR1 alignment counted from the byte after the
/// encapsulation header.
struct Cdr<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
    /// The message type named in errors.
    format: &'static str,
}

impl<'a> Cdr<'a> {
    fn new(bytes: &'a [u8]) -> Result<Self, ReadError> {
        Self::of(bytes, F)
    }

    /// A cursor over a message of type `format` (named in errors).
    fn of(bytes: &'a [u8], format: &'static str) -> Result<Self, ReadError> {
        let Some((head, body)) = bytes.split_first_chunk::<4>() else {
            return Err(err(
                format,
                format!(
                    "{} bytes: too short for the 4-byte CDR encapsulation header",
                    bytes.len()
                ),
            ));
        };
        let little = match [head[0], head[1]] {
            [0, 1] => true,
            [0, 0] => false,
            [a, b] => {
                return Err(err(
                    format,
                    format!(
                        "CDR encapsulation {a:02x} {b:02x} is not plain CDR (00 00 big-endian, \
                         00 01 little-endian): XCDR2 or parameter-list encodings are not read"
                    ),
                ));
            }
        };
        Ok(Cdr {
            body,
            pos: 0,
            little,
            format,
        })
    }

    /// The byte offset in the message (header included) of the cursor, for errors.
    fn at(&self) -> usize {
        self.pos + 4
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], ReadError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.body.len());
        let Some(end) = end else {
            return Err(err(
                self.format,
                format!(
                    "the message ends in {what} (byte {} of {}, {n} bytes needed): truncated",
                    self.at(),
                    self.body.len() + 4
                ),
            ));
        };
        let s = &self.body[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn align(&mut self, n: usize, what: &str) -> Result<(), ReadError> {
        let pad = (n - self.pos % n) % n;
        self.take(pad, what).map(|_| ())
    }

    fn u8(&mut self, what: &str) -> Result<u8, ReadError> {
        Ok(self.take(1, what)?[0])
    }

    fn bool(&mut self, what: &str) -> Result<bool, ReadError> {
        match self.u8(what)? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(err(
                self.format,
                format!(
                    "{what} is {v}, not a boolean (0 or 1): not a {} message",
                    self.format
                ),
            )),
        }
    }

    fn u32(&mut self, what: &str) -> Result<u32, ReadError> {
        self.align(4, what)?;
        let b: [u8; 4] = self
            .take(4, what)?
            .try_into()
            .map_err(|_| err(self.format, "internal: 4 bytes"))?;
        Ok(if self.little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    fn f64(&mut self, what: &str) -> Result<f64, ReadError> {
        self.align(8, what)?;
        let b: [u8; 8] = self
            .take(8, what)?
            .try_into()
            .map_err(|_| err(self.format, "internal: 8 bytes"))?;
        Ok(if self.little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        })
    }

    fn i32(&mut self, what: &str) -> Result<i32, ReadError> {
        self.u32(what).map(|v| v as i32)
    }

    /// A CDR string: u32 length including the final NUL, the bytes, the NUL.
    fn string(&mut self, what: &str) -> Result<String, ReadError> {
        let n = self.u32(what)? as usize;
        let bytes = self.take(n, what)?;
        let text = match bytes.split_last() {
            Some((0, text)) => text,
            // Some writers leave the NUL out; an empty string may have length 0.
            Some(_) => bytes,
            None => &[],
        };
        String::from_utf8(text.to_vec())
            .map_err(|_| err(self.format, format!("{what} is not UTF-8 text")))
    }
}

/// A field of the point layout.
struct Field {
    name: String,
    offset: usize,
    ty: Scalar,
    count: u32,
}

/// The scalar type of a `sensor_msgs/PointField` datatype (1–8).
fn datatype(code: u8, name: &str) -> Result<Scalar, ReadError> {
    Ok(match code {
        1 => Scalar::I8,
        2 => Scalar::U8,
        3 => Scalar::I16,
        4 => Scalar::U16,
        5 => Scalar::I32,
        6 => Scalar::U32,
        7 => Scalar::F32,
        8 => Scalar::F64,
        _ => {
            return Err(err(
                F,
                format!(
                    "field `{}` has datatype {code}: sensor_msgs/PointField defines 1 (INT8) \
                     to 8 (FLOAT64)",
                    crate::read::quote(name)
                ),
            ));
        }
    })
}

/// Decode one `sensor_msgs/msg/PointCloud2` message from its CDR bytes.
pub fn decode_point_cloud2(bytes: &[u8]) -> Result<PointCloud2, ReadError> {
    let mut c = Cdr::new(bytes)?;
    let sec = c.i32("header.stamp.sec")?;
    let nanosec = c.u32("header.stamp.nanosec")?;
    let frame_id = c.string("header.frame_id")?;
    let height = c.u32("height")?;
    let width = c.u32("width")?;
    let n_fields = c.u32("fields")? as usize;
    // Each field takes at least 13 bytes (name length, offset, datatype, count).
    let left = bytes.len().saturating_sub(c.at());
    if n_fields > MAX_FIELDS || n_fields > left / 13 {
        return Err(err(
            F,
            format!(
                "{n_fields} fields declared: more than the message's {left} remaining bytes \
                 can hold (truncated?) or than {MAX_FIELDS}, the most read"
            ),
        ));
    }
    let mut fields = Vec::with_capacity(n_fields);
    for _ in 0..n_fields {
        let name = c.string("a field's name")?;
        let offset = c.u32("a field's offset")? as usize;
        let code = c.u8("a field's datatype")?;
        let count = c.u32("a field's count")?;
        let ty = datatype(code, &name)?;
        // As the file readers: a name twice leaves which column is meant to chance.
        if fields.iter().any(|f: &Field| f.name == name) {
            return Err(err(
                F,
                format!(
                    "the field `{}` is declared twice",
                    crate::read::quote(&name)
                ),
            ));
        }
        fields.push(Field {
            name,
            offset,
            ty,
            count,
        });
    }
    let is_bigendian = c.bool("is_bigendian")?;
    let point_step = c.u32("point_step")? as usize;
    let row_step = c.u32("row_step")? as usize;
    let n_data = c.u32("data")? as usize;
    let data = c.take(n_data, "data")?;
    // Some writers end the message right after `data`; `is_dense` then reads as false.
    let is_dense = if c.pos < c.body.len() {
        c.bool("is_dense")?
    } else {
        false
    };
    let cloud = points(
        &fields,
        height,
        width,
        point_step,
        row_step,
        data,
        !is_bigendian,
    )?;
    Ok(PointCloud2 {
        stamp_ns: i64::from(sec) * 1_000_000_000 + i64::from(nanosec),
        frame_id,
        height,
        width,
        is_dense,
        cloud,
    })
}

/// The ROS 2 type name of the odometry messages [`decode_odometry`] reads.
pub const ODOMETRY: &str = "nav_msgs/msg/Odometry";

/// The format named in odometry errors.
const ODOMETRY_F: &str = "Odometry";

/// The largest odometry coordinate taken (m): the path length sums √(Δx² + Δy² + Δz²)
/// over the messages, and with every coordinate within ±1e150 each Δ² stays below 4e300
/// and their sum over 2³² messages finite, where positions of ±1e308 had made every
/// distance 0 or infinite. A NaN or infinite coordinate is refused too (it had silently
/// stalled the distance).
pub const MAX_ODOMETRY_COORDINATE_M: f64 = 1e150;

/// The position of a `nav_msgs/msg/Odometry` message at its header stamp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdometryPosition {
    /// `header.stamp` as integer nanoseconds.
    pub stamp_ns: i64,
    /// `pose.pose.position` (x, y, z) in the odometry's frame (m).
    pub position: [f64; 3],
}

/// Decode the stamp and position of one `nav_msgs/msg/Odometry` message from its CDR
/// bytes: `header` (stamp, `frame_id`), `child_frame_id: string`, then
/// `pose.pose.position` as three float64 (aligned to 8); the rest (orientation,
/// covariances, twist) is not read.
pub fn decode_odometry(bytes: &[u8]) -> Result<OdometryPosition, ReadError> {
    let mut c = Cdr::of(bytes, ODOMETRY_F)?;
    let sec = c.i32("header.stamp.sec")?;
    let nanosec = c.u32("header.stamp.nanosec")?;
    c.string("header.frame_id")?;
    c.string("child_frame_id")?;
    let position = [
        c.f64("pose.pose.position.x")?,
        c.f64("pose.pose.position.y")?,
        c.f64("pose.pose.position.z")?,
    ];
    if let Some(v) = position
        .iter()
        .find(|v| !(v.abs() <= MAX_ODOMETRY_COORDINATE_M))
    {
        return Err(err(
            ODOMETRY_F,
            format!(
                "pose.pose.position holds {v:e} m: a coordinate must be a finite number of at \
                 most {MAX_ODOMETRY_COORDINATE_M:e} m in size"
            ),
        ));
    }
    Ok(OdometryPosition {
        stamp_ns: i64::from(sec) * 1_000_000_000 + i64::from(nanosec),
        position,
    })
}

/// The points of `data` in the layout of `fields`.
fn points(
    fields: &[Field],
    height: u32,
    width: u32,
    point_step: usize,
    row_step: usize,
    data: &[u8],
    little: bool,
) -> Result<PointCloud, ReadError> {
    let find = |axis: &str| {
        fields
            .iter()
            .find(|f| f.name == axis && f.count >= 1)
            .ok_or_else(|| {
                let have: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
                err(
                    F,
                    format!(
                        "no field `{axis}` (the fields are: {})",
                        if have.is_empty() {
                            "none".to_string()
                        } else {
                            have.join(", ")
                        }
                    ),
                )
            })
    };
    let xyz = [find("x")?, find("y")?, find("z")?];
    // Every field read (count 1, or x, y, z) must lie within a point.
    let mut extra: Vec<&Field> = Vec::new();
    for f in fields {
        let is_axis = ["x", "y", "z"].contains(&f.name.as_str());
        if !is_axis && (f.count != 1 || extra.iter().any(|e| e.name == f.name)) {
            continue;
        }
        if f.offset
            .checked_add(f.ty.size())
            .is_none_or(|e| e > point_step)
        {
            return Err(err(
                F,
                format!(
                    "field `{}` at offset {} ({} bytes) does not fit in point_step {point_step}",
                    crate::read::quote(&f.name),
                    f.offset,
                    f.ty.size()
                ),
            ));
        }
        if !is_axis {
            extra.push(f);
        }
    }
    let (h, w) = (height as usize, width as usize);
    let n = h.checked_mul(w);
    let row_bytes = w.checked_mul(point_step);
    if row_bytes.is_some_and(|b| h > 1 && row_step < b) {
        return Err(err(
            F,
            format!(
                "row_step {row_step} is less than width {w} × point_step {point_step}: rows \
                 would overlap"
            ),
        ));
    }
    // The bytes the points need: the last row's start plus one row.
    let need = match (n, row_bytes) {
        (Some(0), _) => Some(0),
        (Some(_), Some(rb)) => (h - 1)
            .checked_mul(row_step)
            .and_then(|s| s.checked_add(rb)),
        _ => None,
    };
    let Some(n) = n.filter(|_| need.is_some_and(|b| b <= data.len())) else {
        return Err(err(
            F,
            format!(
                "height {h} × width {w} points of point_step {point_step} (row_step {row_step}) \
                 need more than the {} bytes of data",
                data.len()
            ),
        ));
    };
    let mut cloud = PointCloud {
        points: Vec::new(),
        extra: extra.iter().map(|f| (f.name.clone(), Vec::new())).collect(),
    };
    cloud.reserve(n, F)?;
    let value = |f: &Field, base: usize| -> Result<f64, ReadError> {
        data.get(base + f.offset..)
            .and_then(|b| f.ty.decode(b, little))
            .ok_or_else(|| err(F, "internal: a checked field lies outside the data"))
    };
    for r in 0..h {
        for col in 0..w {
            let base = r * row_step + col * point_step;
            cloud.points.push([
                value(xyz[0], base)?,
                value(xyz[1], base)?,
                value(xyz[2], base)?,
            ]);
            for (f, (_, values)) in extra.iter().zip(cloud.extra.iter_mut()) {
                values.push(value(f, base)?);
            }
        }
    }
    Ok(cloud)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A CDR writer with XCDR1 alignment, as a DDS middleware writes a message.
    struct W {
        out: Vec<u8>,
        little: bool,
    }

    impl W {
        fn new(little: bool) -> W {
            W {
                out: vec![0, u8::from(little), 0, 0],
                little,
            }
        }
        fn align(&mut self, n: usize) {
            while !(self.out.len() - 4).is_multiple_of(n) {
                self.out.push(0xAA);
            }
        }
        fn u32(&mut self, v: u32) {
            self.align(4);
            let b = if self.little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            };
            self.out.extend_from_slice(&b);
        }
        fn u8(&mut self, v: u8) {
            self.out.push(v);
        }
        fn string(&mut self, s: &str) {
            self.u32(s.len() as u32 + 1);
            self.out.extend_from_slice(s.as_bytes());
            self.out.push(0);
        }
    }

    /// A field: name, offset, datatype, count.
    pub(crate) type F = (&'static str, u32, u8, u32);

    /// A PointCloud2 message in CDR (`little`: the CDR byte order; `data_big`: the
    /// points' byte order).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn message(
        little: bool,
        frame: &str,
        (h, w): (u32, u32),
        fields: &[F],
        data_big: bool,
        point_step: u32,
        row_step: u32,
        data: &[u8],
    ) -> Vec<u8> {
        let mut c = W::new(little);
        c.u32((-3i32) as u32);
        c.u32(250_000_000);
        c.string(frame);
        c.u32(h);
        c.u32(w);
        c.u32(fields.len() as u32);
        for &(name, off, ty, n) in fields {
            c.string(name);
            c.u32(off);
            c.u8(ty);
            c.u32(n);
        }
        c.u8(u8::from(data_big));
        c.u32(point_step);
        c.u32(row_step);
        c.u32(data.len() as u32);
        c.out.extend_from_slice(data);
        c.u8(1);
        c.out
    }

    /// The bytes of `v` in datatype `ty` and byte order.
    fn enc(v: f64, ty: u8, big: bool) -> Vec<u8> {
        macro_rules! e {
            ($t:ty) => {
                if big {
                    (v as $t).to_be_bytes().to_vec()
                } else {
                    (v as $t).to_le_bytes().to_vec()
                }
            };
        }
        match ty {
            1 => e!(i8),
            2 => e!(u8),
            3 => e!(i16),
            4 => e!(u16),
            5 => e!(i32),
            6 => e!(u32),
            7 => e!(f32),
            8 => e!(f64),
            _ => unreachable!(),
        }
    }

    /// Every datatype as x, y, z and as `intensity`, in both CDR byte orders and both data
    /// byte orders, the header read back.
    #[test]
    fn every_datatype_and_byte_order() {
        let sizes = [0, 1, 1, 2, 2, 4, 4, 4, 8];
        for ty in 1..=8u8 {
            let s = sizes[ty as usize] as u32;
            // Values every datatype holds exactly (INT8 to FLOAT64; unsigned ones ≥ 0).
            let pts = [[1.0, 2.0, 3.0], [100.0, 0.0, 7.0], [5.0, 9.0, 127.0]];
            for little in [true, false] {
                for big in [false, true] {
                    let fields: Vec<F> = vec![
                        ("x", 0, ty, 1),
                        ("y", s, ty, 1),
                        ("z", 2 * s, ty, 1),
                        ("intensity", 3 * s, ty, 1),
                    ];
                    let mut data = Vec::new();
                    for (i, p) in pts.iter().enumerate() {
                        for v in p.iter().chain([&(i as f64 + 10.0)]) {
                            data.extend(enc(*v, ty, big));
                        }
                    }
                    let m = message(little, "cam", (1, 3), &fields, big, 4 * s, 12 * s, &data);
                    let d = decode_point_cloud2(&m).unwrap();
                    assert_eq!(d.stamp_ns, -3_000_000_000 + 250_000_000);
                    assert_eq!(d.frame_id, "cam");
                    assert!(d.is_dense);
                    assert_eq!(d.cloud.points, pts, "type {ty} little {little} big {big}");
                    assert_eq!(
                        d.cloud.extra,
                        vec![("intensity".to_string(), vec![10.0, 11.0, 12.0])]
                    );
                }
            }
        }
    }

    /// Negative values of the signed types and a NaN of the float types come through.
    #[test]
    fn signs_and_non_finite_values_are_kept() {
        for (ty, s) in [(1u8, 1u32), (3, 2), (5, 4)] {
            let fields: Vec<F> = vec![("x", 0, ty, 1), ("y", s, ty, 1), ("z", 2 * s, ty, 1)];
            let data: Vec<u8> = [-1.0, -100.0, 5.0]
                .iter()
                .flat_map(|v| enc(*v, ty, false))
                .collect();
            let d = decode_point_cloud2(&message(
                true,
                "",
                (1, 1),
                &fields,
                false,
                3 * s,
                3 * s,
                &data,
            ))
            .unwrap();
            assert_eq!(d.cloud.points, vec![[-1.0, -100.0, 5.0]]);
        }
        let fields: Vec<F> = vec![("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)];
        let data: Vec<u8> = [f32::NAN, 1.0, f32::INFINITY]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let d =
            decode_point_cloud2(&message(true, "", (1, 1), &fields, false, 12, 12, &data)).unwrap();
        let p = d.cloud.points[0];
        assert!(p[0].is_nan() && p[1] == 1.0 && p[2] == f64::INFINITY);
    }

    /// A field declared twice is an error naming it, as in the file readers (the first of
    /// two `x` fields had been taken).
    #[test]
    fn a_field_declared_twice_is_refused() {
        let fields: Vec<F> = vec![
            ("x", 0, 7, 1),
            ("y", 4, 7, 1),
            ("z", 8, 7, 1),
            ("x", 12, 7, 1),
        ];
        let data: Vec<u8> = [1.0f32, 2.0, 3.0, 4.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let e = decode_point_cloud2(&message(true, "", (1, 1), &fields, false, 16, 16, &data))
            .unwrap_err()
            .to_string();
        assert!(e.contains("the field `x` is declared twice"), "{e}");
    }

    /// An organised cloud with padding in each point (point_step 32 for 16 bytes of fields,
    /// the fields out of order) and at the end of each row (row_step > width·point_step):
    /// each point is read from r·row_step + c·point_step, the padding never.
    #[test]
    fn organised_with_point_and_row_padding() {
        let (h, w, step, row) = (3u32, 4u32, 32u32, 4 * 32 + 24);
        let fields: Vec<F> = vec![
            ("intensity", 0, 7, 1),
            ("rgb", 4, 7, 1),
            ("z", 20, 7, 1),
            ("x", 12, 7, 1),
            ("y", 16, 7, 1),
            ("ring", 24, 4, 1),
        ];
        let mut data = vec![0xEEu8; (h * row) as usize];
        let mut want = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let base = (r * row + c * step) as usize;
                let p = [1.0 + r as f32, 0.1 * c as f32, -0.5 * c as f32];
                for (off, v) in [(12, p[0]), (16, p[1]), (20, p[2]), (0, 7.0 * r as f32)] {
                    data[base + off..base + off + 4].copy_from_slice(&v.to_le_bytes());
                }
                data[base + 24..base + 26].copy_from_slice(&(r as u16).to_le_bytes());
                want.push(p.map(f64::from));
            }
        }
        let d = decode_point_cloud2(&message(
            true,
            "a_optical_frame",
            (h, w),
            &fields,
            false,
            step,
            row,
            &data,
        ))
        .unwrap();
        assert_eq!((d.height, d.width), (h, w));
        assert_eq!(d.cloud.points, want);
        let names: Vec<&str> = d.cloud.extra.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["intensity", "rgb", "ring"]);
        assert_eq!(
            d.cloud.extra[2].1,
            [0., 0., 0., 0., 1., 1., 1., 1., 2., 2., 2., 2.]
        );
    }

    /// A big-endian CDR message has its strings and counts aligned the same way (relative to
    /// the byte after the header): a frame_id of every length from 0 to 8 moves what follows
    /// across every alignment.
    #[test]
    fn alignment_after_strings_of_every_length() {
        let fields: Vec<F> = vec![("x", 0, 8, 1), ("y", 8, 8, 1), ("z", 16, 8, 1)];
        let data: Vec<u8> = [0.5f64, 0.25, 2.0]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        for len in 0..9 {
            let frame = "f".repeat(len);
            for little in [true, false] {
                let m = message(little, &frame, (1, 1), &fields, true, 24, 24, &data);
                let d = decode_point_cloud2(&m).unwrap();
                assert_eq!(d.frame_id, frame);
                assert_eq!(d.cloud.points, vec![[0.5, 0.25, 2.0]]);
            }
        }
    }

    /// Every prefix of a valid message is an error naming what is missing, never a panic;
    /// so is every layout that does not fit its data.
    #[test]
    fn truncated_and_inconsistent_messages_are_errors() {
        let fields: Vec<F> = vec![("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)];
        let data = vec![0u8; 2 * 3 * 12];
        let m = message(true, "cam", (2, 3), &fields, false, 12, 36, &data);
        assert!(decode_point_cloud2(&m).is_ok());
        // Without `is_dense` the message is still read (some writers end at `data`).
        assert!(decode_point_cloud2(&m[..m.len() - 1]).is_ok());
        for n in 0..m.len() - 1 {
            let e = decode_point_cloud2(&m[..n]).unwrap_err();
            assert!(
                e.message.contains("truncated")
                    || e.message.contains("too short")
                    || e.message.contains("need more"),
                "{n}: {e}"
            );
        }
        let bad = |fields: &[F], h, w, step, row, data: &[u8]| {
            decode_point_cloud2(&message(true, "", (h, w), fields, false, step, row, data))
                .unwrap_err()
                .to_string()
        };
        // More points than data.
        assert!(bad(&fields, 3, 3, 12, 36, &data).contains("need more than the 72 bytes"));
        // A field beyond the point.
        let wide: Vec<F> = vec![("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 10, 7, 1)];
        assert!(bad(&wide, 2, 3, 12, 36, &data).contains("does not fit in point_step 12"));
        // Rows overlapping.
        assert!(bad(&fields, 2, 3, 12, 30, &data).contains("rows would overlap"));
        // No z.
        let no_z: Vec<F> = vec![("x", 0, 7, 1), ("y", 4, 7, 1), ("intensity", 8, 7, 1)];
        assert!(
            bad(&no_z, 2, 3, 12, 36, &data)
                .contains("no field `z` (the fields are: x, y, intensity)")
        );
        // A datatype outside 1–8.
        let odd: Vec<F> = vec![("x", 0, 9, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)];
        assert!(bad(&odd, 2, 3, 12, 36, &data).contains("datatype 9"));
        // Sizes whose products come near or beyond usize are refused, not multiplied.
        assert!(bad(&fields, 1, u32::MAX, u32::MAX, u32::MAX, &data).contains("need more"));
        assert!(bad(&fields, u32::MAX, u32::MAX, u32::MAX, u32::MAX, &data).contains("overlap"));
        // A field count larger than the message.
        let mut c = W::new(true);
        for v in [0, 0, 1, 0, 1, 1, 1_000_000] {
            c.u32(v);
        }
        let e = decode_point_cloud2(&c.out).unwrap_err().to_string();
        assert!(e.contains("1000000 fields declared"), "{e}");
        // Not plain CDR.
        let mut x = m.clone();
        x[1] = 0x07;
        assert!(
            decode_point_cloud2(&x)
                .unwrap_err()
                .to_string()
                .contains("00 07 is not plain CDR")
        );
    }

    /// Random bytes after a valid header never panic.
    #[test]
    fn random_bytes_never_panic() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        for len in 0..400 {
            let mut b = vec![0u8, 1, 0, 0];
            for _ in 0..len {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                b.push(if len % 3 == 0 {
                    (state & 3) as u8
                } else {
                    state as u8
                });
            }
            let _ = decode_point_cloud2(&b);
        }
    }

    /// An Odometry message in CDR, little- and big-endian: its stamp and position read, the
    /// position aligned to 8 after the two strings; a truncated one is an error naming
    /// the field and the type.
    #[test]
    fn odometry_position() {
        for little in [true, false] {
            let mut w = W::new(little);
            w.u32(12);
            w.u32(500);
            w.string("odom");
            w.string("base_link");
            w.align(8);
            for v in [1.5f64, -2.25, 0.125] {
                let b = if little {
                    v.to_le_bytes()
                } else {
                    v.to_be_bytes()
                };
                w.out.extend_from_slice(&b);
            }
            // Orientation and the rest: not read.
            w.out.extend_from_slice(&[0u8; 64]);
            let o = decode_odometry(&w.out).unwrap();
            assert_eq!(o.stamp_ns, 12_000_000_500);
            assert_eq!(o.position, [1.5, -2.25, 0.125]);
            let cut = &w.out[..w.out.len() - 64 - 4];
            let e = decode_odometry(cut).unwrap_err().to_string();
            assert!(e.contains("Odometry") && e.contains("position.z"), "{e}");
        }
    }

    /// A position that is not finite, or too large for a path length, is refused with
    /// what it holds.
    #[test]
    fn an_odometry_position_beyond_its_bound_is_refused() {
        for bad in [
            f64::NAN,
            f64::INFINITY,
            -1e308,
            2.0 * MAX_ODOMETRY_COORDINATE_M,
        ] {
            let mut w = W::new(true);
            w.u32(1);
            w.u32(0);
            w.string("odom");
            w.string("base_link");
            w.align(8);
            for v in [1.0f64, bad, 0.0] {
                w.out.extend_from_slice(&v.to_le_bytes());
            }
            w.out.extend_from_slice(&[0u8; 64]);
            let e = decode_odometry(&w.out).unwrap_err().to_string();
            assert!(e.contains("pose.pose.position holds"), "{bad}: {e}");
        }
    }
}
