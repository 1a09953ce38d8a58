//! A frame's points as the estimator takes them: read from a file or standard input
//! ([`read_input`]), converted to metres in the sensor frame with a check that the unit
//! is plausible ([`to_sensor_metres`]), and their per-point `intensity` ([`intensity`]).

use std::borrow::Cow;
use std::path::Path;

use crate::config::{InputConfig, InputFrame, Units};
use crate::read::{MAX_INPUT_BYTES, PointCloud, read_from, read_path};

/// A cloud whose median distance from the sensor exceeds this (m) is not in metres. From
/// inside a pipe the median range of a ToF frame is a fraction of the camera's reach
/// (0.3–5 m for the Helios2's 6 m mode and pipes of 8"–48"); the same frame read as
/// millimetres is 1000 times farther (300–5000 "m"). 30 m sits between the two with a
/// factor of 6 to spare above the farthest plausible median and 10 below the nearest
/// misread one, so the hint "pass --units mm" is right whenever it is given.
const MAX_MEDIAN_RANGE_M: f64 = 30.0;
/// A cloud whose median distance from the sensor is below this (m) is not in the unit
/// given (e.g. metres read as millimetres: 0.3–5 mm). 2 cm is 15 times below the nearest
/// plausible median (0.3 m) and 4 times above the farthest misread one (5 mm).
const MIN_MEDIAN_RANGE_M: f64 = 0.02;

/// Convert the points to metres in the sensor frame, in place, and check that the
/// unit is plausible for a camera inside a pipe: its points lie between 2 cm and 30 m
/// (median distance) from the sensor.
pub fn to_sensor_metres(
    points: &mut [[f64; 3]],
    units: Units,
    frame: InputFrame,
) -> Result<(), String> {
    convert_to_sensor_metres(points, units, frame);
    check_units(points, units)
}

/// The conversion of [`to_sensor_metres`] without its check of the unit (for points
/// read a few at a time, whose first ones were checked).
pub fn convert_to_sensor_metres(points: &mut [[f64; 3]], units: Units, frame: InputFrame) {
    let k = match units {
        Units::Metres => 1.0,
        Units::Millimetres => 1e-3,
    };
    for p in points.iter_mut() {
        let [x, y, z] = *p;
        *p = match frame {
            InputFrame::Sensor => [k * x, k * y, k * z],
            // X_sensor = Z_optical, Y_sensor = X_optical, Z_sensor = −Y_optical (a
            // reflection: the sensor frame is left-handed).
            InputFrame::Optical => [k * z, k * x, -k * y],
            // Y_sensor (right) = −Y_body (left); X and Z are the same.
            InputFrame::Body => [k * x, -k * y, k * z],
        };
    }
}

/// [`to_sensor_metres`] of borrowed points: borrowed back unchanged (no copy) when they
/// are already metres in the sensor frame, else converted in a copy.
pub fn sensor_metres(
    points: &[[f64; 3]],
    units: Units,
    frame: InputFrame,
) -> Result<Cow<'_, [[f64; 3]]>, String> {
    if units == Units::Metres && frame == InputFrame::Sensor {
        check_units(points, units)?;
        return Ok(Cow::Borrowed(points));
    }
    let mut owned = points.to_vec();
    to_sensor_metres(&mut owned, units, frame)?;
    Ok(Cow::Owned(owned))
}

/// The plausibility check of [`to_sensor_metres`] on points already converted.
fn check_units(points: &[[f64; 3]], units: Units) -> Result<(), String> {
    let stride = points.len().div_ceil(4096).max(1);
    let mut r: Vec<f64> = points
        .iter()
        .step_by(stride)
        .filter(|p| p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0))
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect();
    if r.is_empty() {
        return Ok(());
    }
    let mid = r.len() / 2;
    let (_, &mut median, _) = r.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    if median > MAX_MEDIAN_RANGE_M {
        return Err(match units {
            Units::Metres if median / 1e3 <= MAX_MEDIAN_RANGE_M => format!(
                "the points lie a median {median:.1} m from the sensor: the cloud looks like millimetres \
                 (the Helios2 SDK writes mm); pass --units mm"
            ),
            Units::Metres => format!(
                "the points lie a median {median:.3e} m from the sensor, too far even for \
                 millimetres: the coordinates are not read as written (a binary file's byte order \
                 or value type, a decimal comma, an extra leading column such as an index?)"
            ),
            Units::Millimetres => format!(
                "the points lie a median {median:.1} m from the sensor even read as millimetres: \
                 not a frame from inside a pipe"
            ),
        });
    }
    if median < MIN_MEDIAN_RANGE_M {
        return Err(match units {
            Units::Millimetres => format!(
                "read as millimetres, the points lie a median {:.1} mm from the sensor: the cloud looks like \
                 metres; drop --units mm",
                median * 1e3
            ),
            Units::Metres => format!(
                "the points lie a median {:.1} mm from the sensor: the cloud is not in metres \
                 (kilometres?) or not a frame from inside a pipe",
                median * 1e3
            ),
        });
    }
    Ok(())
}

/// Read one input (a file, or standard input for `-`) and convert its points to metres
/// in the sensor frame.
pub fn read_input(path: &Path, input: &InputConfig) -> Result<PointCloud, String> {
    let mut cloud = if path.as_os_str() == "-" {
        read_from(std::io::stdin().lock(), input.format, MAX_INPUT_BYTES)?
    } else {
        read_path(path)?
    };
    to_sensor_metres(&mut cloud.points, input.units, input.frame)?;
    Ok(cloud)
}

/// Whether a cloud has a per-point `intensity` (any case).
pub fn has_intensity(cloud: &PointCloud) -> bool {
    cloud
        .extra
        .iter()
        .any(|(name, _)| name.eq_ignore_ascii_case("intensity"))
}

/// The per-point `intensity` of a cloud (any case), or why there is none.
pub fn intensity(cloud: &PointCloud, why: &str) -> Result<Vec<f64>, String> {
    cloud
        .extra
        .iter()
        .find(|(name, _)| name.eq_ignore_ascii_case("intensity"))
        .map(|(_, v)| v.clone())
        .ok_or_else(|| {
            let have: Vec<&str> = cloud.extra.iter().map(|(n, _)| n.as_str()).collect();
            format!(
                "no per-point `intensity` in the file ({}); {why}",
                if have.is_empty() {
                    "it holds x, y, z only".to_string()
                } else {
                    format!("it holds x, y, z, {}", have.join(", "))
                }
            )
        })
}

/// Each point's distance from the sensor (m).
pub fn ranges(points: &[[f64; 3]]) -> Vec<f64> {
    points
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect()
}

/// What `--calibration` says when the input has no intensity.
pub const CALIBRATION_NEEDS_INTENSITY: &str = "--calibration needs one per point";

#[cfg(test)]
mod tests {
    use super::*;

    /// Borrowed points in metres in the sensor frame are not copied; others are
    /// converted like `to_sensor_metres` does in place.
    #[test]
    fn sensor_metres_borrows_only_when_nothing_changes() {
        let pts = vec![[1.0, 0.2, -0.1], [2.0, -0.3, 0.25]];
        let same = sensor_metres(&pts, Units::Metres, InputFrame::Sensor).unwrap();
        assert!(matches!(same, Cow::Borrowed(p) if std::ptr::eq(p, pts.as_slice())));
        let mm: Vec<[f64; 3]> = pts
            .iter()
            .map(|p| [p[1] * 1e3, -p[2] * 1e3, p[0] * 1e3])
            .collect();
        let conv = sensor_metres(&mm, Units::Millimetres, InputFrame::Optical).unwrap();
        assert!(matches!(conv, Cow::Owned(_)));
        let mut inplace = mm.clone();
        to_sensor_metres(&mut inplace, Units::Millimetres, InputFrame::Optical).unwrap();
        assert_eq!(conv.as_ref(), inplace.as_slice());
        let e = sensor_metres(&mm, Units::Metres, InputFrame::Sensor).unwrap_err();
        assert!(e.contains("pass --units mm"), "{e}");
    }

    /// Millimetres are suggested only where they would explain the distances: coordinates
    /// a thousand times too far even for millimetres (a wrong byte order, a decimal comma,
    /// an index column) get the causes that could, not a hint that fails next.
    #[test]
    fn the_millimetre_hint_only_where_millimetres_fit() {
        let far: Vec<[f64; 3]> = (0..100).map(|i| [1e6 + i as f64, 10.0, 5.0]).collect();
        let e = sensor_metres(&far, Units::Metres, InputFrame::Sensor).unwrap_err();
        assert!(!e.contains("--units mm") && e.contains("byte order"), "{e}");
        let mm: Vec<[f64; 3]> = (0..100).map(|i| [1500.0 + i as f64, 10.0, 5.0]).collect();
        let e = sensor_metres(&mm, Units::Metres, InputFrame::Sensor).unwrap_err();
        assert!(e.contains("pass --units mm"), "{e}");
    }
}
