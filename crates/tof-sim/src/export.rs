//! A frame handed to the writers of `epd-io` ([`Frame::cloud`]): the measured points with
//! their pixels, the truth in the header's comments, and the `intensity`, `segment` and
//! `part` properties when the frame has them.

use epd_io::cloud::{Property, SensorCloud, Values};

use crate::frame::Frame;
use crate::pipeline::PartKind;

/// The code of a part kind in a file's `part` property: 1 straight, 2 bend, 3 branch (0
/// is "no wall", a pixel whose ray met none).
pub fn part_code(kind: PartKind) -> u8 {
    match kind {
        PartKind::Straight => 1,
        PartKind::Bend => 2,
        PartKind::Branch => 3,
    }
}

impl Frame {
    /// The frame as the writers take it: its measured points (SCS, m; invalid pixels as
    /// zeros) with their pixel (u, v); the truth β in a header comment; a `float
    /// intensity` (camera counts) when any intensity is finite (the physical sensor
    /// model; the plain model's are NaN and are not written); and, for a frame with labels
    /// ([`Frame::part`], a pipeline scene), `ushort segment` (the index in
    /// `Pipeline::segments`) and `uchar part` ([`part_code`]), described in a comment.
    pub fn cloud(&self) -> SensorCloud<'_> {
        let n = self.measured.len();
        let t = &self.truth;
        let mut comments = vec![
            "tof-sim frame: measured points in the sensor frame (m; X forward, Y right, Z up)"
                .to_string(),
            format!(
                "truth d_max_m {} d_min_m {} roll_rad {} pitch_rad {} yaw_rad {} dy_m {} dz_m {}",
                t.d_max, t.d_min, t.roll, t.pitch, t.yaw, t.dy, t.dz
            ),
        ];
        let mut properties = Vec::new();
        if self.intensity.len() == n && self.intensity.iter().any(|i| i.is_finite()) {
            properties.push(Property {
                name: "intensity".into(),
                values: Values::F32(self.intensity.clone()),
            });
        }
        if !self.part.is_empty() && self.part.len() == n {
            comments.push(
                "part: what the pixel's ray hit, 0 no wall, 1 straight, 2 bend, 3 branch; \
                 segment: its index in the pipeline"
                    .to_string(),
            );
            let (segment, part): (Vec<u16>, Vec<u8>) = self
                .part
                .iter()
                .map(|p| p.map_or((0, 0), |p| (p.segment, part_code(p.kind))))
                .unzip();
            properties.push(Property {
                name: "segment".into(),
                values: Values::U16(segment),
            });
            properties.push(Property {
                name: "part".into(),
                values: Values::U8(part),
            });
        }
        SensorCloud {
            points: &self.measured,
            pixels: &self.pixels,
            image_size: self.image_size,
            comments,
            properties,
        }
    }
}
