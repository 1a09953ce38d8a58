//! The pinhole ToF sensor (README, Conventions).

use nalgebra::Vector3;

use crate::error::SimError;

/// A pinhole ToF camera. Rays live in the SCS: X forward (optical axis), Y right, Z up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sensor {
    /// Image width W (pixels).
    pub width: u32,
    /// Image height H (pixels).
    pub height: u32,
    /// Horizontal field of view (rad).
    pub fov_h: f64,
    /// Vertical field of view (rad).
    pub fov_v: f64,
    /// Shortest measured range kept (m).
    pub min_range: f64,
    /// Longest measured range kept (m).
    pub max_range: f64,
}

impl Sensor {
    /// The Helios2-like preset: 640×480 pixels, 69°×51°, ranges 0–6 m.
    pub fn helios2() -> Self {
        Self {
            width: 640,
            height: 480,
            fov_h: 69f64.to_radians(),
            fov_v: 51f64.to_radians(),
            min_range: 0.0,
            max_range: 6.0,
        }
    }

    /// Check every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SimError> {
        if self.width == 0 {
            return Err(SimError::invalid(
                "sensor.width",
                self.width,
                "must be at least 1 pixel",
            ));
        }
        if self.height == 0 {
            return Err(SimError::invalid(
                "sensor.height",
                self.height,
                "must be at least 1 pixel",
            ));
        }
        let fov_ok = |f: f64| f > 0.0 && f < std::f64::consts::PI;
        if !fov_ok(self.fov_h) {
            return Err(SimError::invalid(
                "sensor.fov_h_deg",
                self.fov_h.to_degrees(),
                "must lie in (0°, 180°) for a pinhole camera",
            ));
        }
        if !fov_ok(self.fov_v) {
            return Err(SimError::invalid(
                "sensor.fov_v_deg",
                self.fov_v.to_degrees(),
                "must lie in (0°, 180°) for a pinhole camera",
            ));
        }
        if !(self.min_range >= 0.0 && self.min_range.is_finite()) {
            return Err(SimError::invalid(
                "sensor.min_range_m",
                self.min_range,
                "must be a finite number ≥ 0",
            ));
        }
        if !(self.max_range > self.min_range && self.max_range.is_finite()) {
            return Err(SimError::invalid(
                "sensor.max_range_m",
                self.max_range,
                "must be finite and greater than sensor.min_range_m",
            ));
        }
        Ok(())
    }

    /// Focal lengths (fx, fy) in pixels: fx = (W/2)/tan(FOVh/2), fy = (H/2)/tan(FOVv/2).
    pub fn focal(&self) -> (f64, f64) {
        (
            (self.width as f64 / 2.0) / (self.fov_h / 2.0).tan(),
            (self.height as f64 / 2.0) / (self.fov_v / 2.0).tan(),
        )
    }

    /// Unit ray direction (SCS) of pixel (u, v), u to the right and v downwards:
    /// normalise([1, (u+0.5−W/2)/fx, −(v+0.5−H/2)/fy]).
    pub fn ray_direction(&self, u: u32, v: u32) -> Vector3<f64> {
        self.rays().direction(u, v)
    }

    /// The pinhole model with its focal lengths computed once, for casting many rays.
    pub fn rays(&self) -> Pinhole {
        let (fx, fy) = self.focal();
        Pinhole {
            inv_fx: 1.0 / fx,
            inv_fy: 1.0 / fy,
            cx: self.width as f64 / 2.0,
            cy: self.height as f64 / 2.0,
        }
    }

    /// Number of pixels W·H.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// The pixel → ray map of a [`Sensor`], precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pinhole {
    inv_fx: f64,
    inv_fy: f64,
    cx: f64,
    cy: f64,
}

impl Pinhole {
    /// Unit ray direction (SCS) of pixel (u, v), as [`Sensor::ray_direction`].
    #[inline]
    pub fn direction(&self, u: u32, v: u32) -> Vector3<f64> {
        Vector3::new(
            1.0,
            (u as f64 + 0.5 - self.cx) * self.inv_fx,
            -(v as f64 + 0.5 - self.cy) * self.inv_fy,
        )
        .normalize()
    }
}

impl Default for Sensor {
    fn default() -> Self {
        Self::helios2()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_rays_span_the_field_of_view() {
        let s = Sensor::helios2();
        // The outer edges of the corner pixels lie on the field-of-view boundary.
        let (fx, fy) = s.focal();
        assert!(((320.0 / fx).atan().to_degrees() - 34.5).abs() < 1e-12);
        assert!(((240.0 / fy).atan().to_degrees() - 25.5).abs() < 1e-12);
        let d = s.ray_direction(0, 0);
        assert!(d.y < 0.0 && d.z > 0.0, "top-left pixel looks left and up");
        let d = s.ray_direction(639, 479);
        assert!(d.y > 0.0 && d.z < 0.0);
        assert!((s.ray_direction(5, 7).norm() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn validation_names_the_field() {
        let mut s = Sensor::helios2();
        s.fov_h = std::f64::consts::PI;
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("sensor.fov_h_deg")
        );
        let mut s = Sensor::helios2();
        s.width = 0;
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("sensor.width")
        );
        let mut s = Sensor::helios2();
        s.min_range = 7.0;
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("sensor.max_range_m")
        );
        let mut s = Sensor::helios2();
        s.fov_v = -0.1;
        assert!(
            s.validate()
                .unwrap_err()
                .to_string()
                .contains("sensor.fov_v_deg")
        );
    }
}
