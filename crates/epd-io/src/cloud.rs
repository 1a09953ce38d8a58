//! A frame as the writers take it, whatever made it: points in the sensor frame, each
//! with its pixel, and named per-point properties. The simulator (`tof-sim`) and any other
//! source hand their frames to the PLY and depth-image writers through it, so this crate
//! knows no simulator.

/// The values of one per-point property, in the type it is written with.
#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    /// `float` (e.g. a camera's intensity in counts).
    F32(Vec<f32>),
    /// `ushort` (e.g. a segment index).
    U16(Vec<u16>),
    /// `uchar` (e.g. a class code).
    U8(Vec<u8>),
}

impl Values {
    /// Number of values.
    pub fn len(&self) -> usize {
        match self {
            Values::F32(v) => v.len(),
            Values::U16(v) => v.len(),
            Values::U8(v) => v.len(),
        }
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// One named per-point property, one value per point.
#[derive(Clone, Debug, PartialEq)]
pub struct Property {
    /// Its name in the file (`intensity`, `segment`, `part`, …).
    pub name: String,
    /// Its values, in point order.
    pub values: Values,
}

/// An organised frame: each point (SCS, m: X forward, Y right, Z up) with the pixel
/// (u right, v down) it came from, in an image of `image_size` (W, H); invalid pixels are
/// held as the camera writes them, `[0, 0, 0]`.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorCloud<'a> {
    /// The measured points (SCS, m).
    pub points: &'a [[f64; 3]],
    /// Pixel (u, v) of each point.
    pub pixels: &'a [[u32; 2]],
    /// Image size (W, H) the pixels index.
    pub image_size: [u32; 2],
    /// The PLY header's comment lines, in order, each without `comment ` (what the frame
    /// is, its units and frame, a simulated frame's truth, what the properties mean).
    pub comments: Vec<String>,
    /// Per-point properties written after x, y, z, u, v, in order.
    pub properties: Vec<Property>,
}
