//! The fit where people can see it: a frame's points with their residual to the fitted
//! wall, and the fitted wall as a triangle mesh (`epd estimate --export-fit OUT.ply`), or
//! the points unrolled over the fitted section (`epd view`).
//!
//! The residual of a point is ML-EPD's range residual (`epd_core::Residual::Range`): its
//! measured range minus the range at which its ray meets the fitted elliptic cylinder,
//! in mm, positive beyond the wall. The wall is the elliptic cylinder of the estimate
//! (eq. 5 in the pipe frame of eq. 3) over the axial stretch of the straight section's
//! points, and a bend ahead's torus (`epd_core::bend::BendGeometry`) over the angle seen.

use std::f64::consts::TAU;
use std::io::Write;
use std::path::Path;

use epd_core::Params;
use epd_core::bend::BendGeometry;
use epd_core::residual::{Geometry, Residual};
use nalgebra::{Point3, Vector3};

use crate::config::{EstimateConfig, InputFrame, Units};
use crate::input::read_input;
use crate::measure::measure_cloud;
use crate::report::{FileEstimate, FileReport};

/// Vertices around the elliptic cylinder's (and the torus tube's) circumference: 96, a
/// vertex every 3.75°, whose chords leave the mesh within 0.08 % of the radius of the
/// true wall between vertices (1 − cos(π/96)): 0.2 mm in a 20" pipe, below a ToF
/// camera's noise.
pub const MESH_AROUND: usize = 96;

/// The longest edge along the axis of the cylinder's mesh (m): 5 cm, so a viewer's
/// lighting shows the wall's curvature along a bend; a straight wall needs only its two
/// ends, but the rings also make the mesh easy to pick in CloudCompare.
pub const MESH_STEP_M: f64 = 0.05;

/// The quantiles of the straight section's wall points along the axis that bound the
/// cylinder's mesh: 0.5 % and 99.5 %, so that a few stray points far along (a reflection
/// through the pipe's end) do not stretch the wall past where the camera saw it.
pub const AXIAL_QUANTILES: (f64, f64) = (0.005, 0.995);

/// The measured points of one frame with the fit: what `--export-fit` and `epd view` draw.
#[derive(Clone, Debug)]
pub struct FittedFrame {
    /// The fitted parameters.
    pub params: Params,
    /// The bend ahead, as in [`FileEstimate::bend_fit`].
    pub bend: Option<(Params, BendGeometry, f64)>,
    /// The valid points (finite, not at the origin), in metres in the sensor frame.
    pub points: Vec<[f64; 3]>,
    /// Each point's residual (mm), NaN where its ray never meets the wall.
    pub residual_mm: Vec<f64>,
    /// Each point's place on the unrolled wall: (distance along the pipe axis from the
    /// sensor (m), clock angle seen from the sensor (deg: 0 up, 90 right)).
    pub unrolled: Vec<(f64, f64)>,
    /// The fitted wall in the sensor frame (m).
    pub mesh: Mesh,
}

/// A triangle mesh: its vertices, its triangles (three vertex indices) and which part of
/// the wall each triangle belongs to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// The vertices (m).
    pub vertices: Vec<[f64; 3]>,
    /// The triangles.
    pub faces: Vec<[u32; 3]>,
    /// Per triangle: 0 the straight pipe's elliptic cylinder, 1 a bend's torus.
    pub part: Vec<u8>,
}

impl Mesh {
    fn append(&mut self, other: Mesh) {
        let base = self.vertices.len() as u32;
        self.vertices.extend(other.vertices);
        self.faces.extend(
            other
                .faces
                .iter()
                .map(|f| [f[0] + base, f[1] + base, f[2] + base]),
        );
        self.part.extend(other.part);
    }

    /// A grid of `rows` × [`MESH_AROUND`] vertices (row-major, closed around) as triangles.
    fn grid(vertices: Vec<[f64; 3]>, rows: usize, part: u8) -> Mesh {
        let n = MESH_AROUND;
        let mut faces = Vec::with_capacity(2 * n * rows.saturating_sub(1));
        for r in 0..rows.saturating_sub(1) {
            for k in 0..n {
                let a = (r * n + k) as u32;
                let b = (r * n + (k + 1) % n) as u32;
                let c = a + n as u32;
                let d = b + n as u32;
                faces.push([a, b, d]);
                faces.push([a, d, c]);
            }
        }
        let part = vec![part; faces.len()];
        Mesh {
            vertices,
            faces,
            part,
        }
    }
}

/// The fitted elliptic cylinder of `p` from `x0` to `x1` along its axis (m), in the sensor
/// frame: rings of [`MESH_AROUND`] vertices at most [`MESH_STEP_M`] apart.
pub fn cylinder_mesh(p: &Params, x0: f64, x1: f64) -> Mesh {
    let (a, b) = (0.5 * p.d_max, 0.5 * p.d_min);
    let rows = (((x1 - x0) / MESH_STEP_M).ceil().max(1.0) as usize) + 1;
    let mut v = Vec::with_capacity(rows * MESH_AROUND);
    for r in 0..rows {
        let x = x0 + (x1 - x0) * r as f64 / (rows - 1) as f64;
        for k in 0..MESH_AROUND {
            let phi = TAU * k as f64 / MESH_AROUND as f64;
            let s = p.pcs_to_scs(&Point3::new(x, a * phi.cos(), b * phi.sin()));
            v.push([s.x, s.y, s.z]);
        }
    }
    Mesh::grid(v, rows, 0)
}

/// A bend's torus tube from its start over `angle` (rad), in the sensor frame of the pipe
/// frame `straight`: rings of [`MESH_AROUND`] vertices every 2° of the turn.
pub fn torus_mesh(straight: &Params, bend: &BendGeometry, angle: f64) -> Mesh {
    let (s, c) = bend.direction.sin_cos();
    let n_hat = Vector3::new(0.0, c, s);
    let x_hat = Vector3::x();
    let axis = x_hat.cross(&n_hat);
    let centre = Vector3::new(bend.start, 0.0, 0.0) + bend.radius * n_hat;
    let rows = ((angle.abs().to_degrees() / 2.0).ceil().max(1.0) as usize) + 1;
    let mut v = Vec::with_capacity(rows * MESH_AROUND);
    for r in 0..rows {
        let theta = angle * r as f64 / (rows - 1) as f64;
        // From the centre of curvature to the centreline: −n̂ at the start, turning toward
        // +X̂.
        let out = -theta.cos() * n_hat + theta.sin() * x_hat;
        let on_line = centre + bend.radius * out;
        for k in 0..MESH_AROUND {
            let psi = TAU * k as f64 / MESH_AROUND as f64;
            let w = on_line + bend.section_radius(psi) * (psi.cos() * out + psi.sin() * axis);
            let q = straight.pcs_to_scs(&Point3::from(w));
            v.push([q.x, q.y, q.z]);
        }
    }
    Mesh::grid(v, rows, 1)
}

/// The residual (mm) of each point to the elliptic cylinder of `p` (NaN where its ray never
/// meets the wall or `p` puts the sensor outside it), and its place on the unrolled wall.
pub fn residuals(points: &[[f64; 3]], p: &Params) -> (Vec<f64>, Vec<(f64, f64)>) {
    let Some(g) = Geometry::new(p) else {
        return (
            vec![f64::NAN; points.len()],
            vec![(f64::NAN, f64::NAN); points.len()],
        );
    };
    let r = p.rotation();
    let inv = r.inverse();
    points
        .iter()
        .map(|q| {
            let t = g.line_parameter(q);
            let res = if t.is_finite() {
                g.residual(Residual::Range, q) * 1e3
            } else {
                f64::NAN
            };
            // The wall point where the ray meets the wall, in the pipe frame.
            let w = p.scs_to_pcs(&Point3::from(Vector3::from(*q) * t));
            let d = inv * Vector3::new(0.0, w.y, w.z);
            let clock = d.y.atan2(d.z).to_degrees().rem_euclid(360.0);
            (res, (w.x, clock))
        })
        .unzip()
}

/// The `q`-quantile of `v` (sorted in place; `None` when empty).
fn quantile(v: &mut [f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    v.get(i).copied()
}

/// Read `path`, measure it as `epd estimate` does (its report), and put the fit where it
/// can be seen: the points' residuals, their unrolled places and the wall's mesh. The
/// error says why there is no fit to show (the report's failure).
pub fn fit_file(path: &Path, cfg: &EstimateConfig) -> (FileReport, Result<FittedFrame, String>) {
    let t0 = std::time::Instant::now();
    let cloud = match read_input(path, &cfg.input) {
        Ok(c) => c,
        Err(e) => return (FileReport::of_path(path, Err(e.clone())), Err(e)),
    };
    let points: Vec<[f64; 3]> = cloud
        .points
        .iter()
        .copied()
        .filter(|q| q.iter().all(|v| v.is_finite()) && q.iter().any(|&v| v != 0.0))
        .collect();
    let outcome = measure_cloud(cloud, t0.elapsed().as_secs_f64() * 1e3, cfg);
    let report = FileReport::of_path(path, outcome);
    let fitted = fit_of(&report, points);
    (report, fitted)
}

/// [`fit_file`]'s picture of a measured frame's `points` (m, sensor frame).
fn fit_of(report: &FileReport, points: Vec<[f64; 3]>) -> Result<FittedFrame, String> {
    if let Some(why) = report.failure() {
        return Err(format!("no fit to show: {why}"));
    }
    let e: &FileEstimate = report
        .outcome
        .as_ref()
        .map_err(|e| format!("no fit to show: {e}"))?;
    let p = e.estimate.params;
    let (residual_mm, unrolled) = residuals(&points, &p);
    // The cylinder over the straight section's wall points along the axis (before the
    // bend's start when there is one).
    let end = e.geometry.as_ref().and_then(|g| g.straight_until_m);
    let mut along: Vec<f64> = unrolled
        .iter()
        .zip(&residual_mm)
        .filter(|(u, r)| r.is_finite() && u.0.is_finite() && end.is_none_or(|x| u.0 <= x))
        .map(|(u, _)| u.0)
        .collect();
    let (x0, x1) = match (
        quantile(&mut along, AXIAL_QUANTILES.0),
        quantile(&mut along, AXIAL_QUANTILES.1),
    ) {
        (Some(a), Some(b)) if b > a => (a, b),
        _ => return Err("no fit to show: no point meets the fitted wall".into()),
    };
    let mut mesh = cylinder_mesh(&p, x0, end.map_or(x1, |x| x.max(x0)));
    if let Some((straight, bend, angle)) = &e.bend_fit
        && bend.torus().is_some()
    {
        mesh.append(torus_mesh(straight, bend, *angle));
    }
    Ok(FittedFrame {
        params: p,
        bend: e.bend_fit,
        points,
        residual_mm,
        unrolled,
        mesh,
    })
}

/// A point in metres in the sensor frame back in the file's unit and frame (the inverse of
/// [`crate::input::to_sensor_metres`]), so the export lies over the file's own points in a viewer.
pub fn to_file_frame(q: [f64; 3], units: Units, frame: InputFrame) -> [f64; 3] {
    let k = match units {
        Units::Metres => 1.0,
        Units::Millimetres => 1e3,
    };
    let [x, y, z] = q;
    match frame {
        InputFrame::Sensor => [k * x, k * y, k * z],
        InputFrame::Optical => [k * y, -k * z, k * x],
        InputFrame::Body => [k * x, -k * y, k * z],
    }
}

/// Write `f` as one binary little-endian PLY (Open3D, CloudCompare, plyfile, MeshLab read
/// it): one `vertex` element with `x`, `y`, `z` (double, in the file's unit and frame),
/// `residual_mm` (float; 0 for the mesh's vertices, which lie on the wall) and `mesh`
/// (uchar: 0 a measured point, 1 a vertex of the fitted wall), the measured points first;
/// then a `face` element (`vertex_indices`, and `part`: 0 the elliptic cylinder, 1 the
/// bend's torus). Comments give the fitted parameters.
pub fn write_fit_ply<W: Write>(
    mut w: W,
    f: &FittedFrame,
    units: Units,
    frame: InputFrame,
) -> std::io::Result<()> {
    let n_points = f.points.len();
    let n_vertices = n_points + f.mesh.vertices.len();
    let mut head = String::from("ply\nformat binary_little_endian 1.0\n");
    head.push_str("comment epd --export-fit: measured points (mesh 0) with their range residual to the fitted wall (residual_mm, positive beyond the wall), and the fitted wall (mesh 1)\n");
    {
        let p = f.params;
        head.push_str(&format!(
            "comment epd d_max_mm {} d_min_mm {} roll_deg {} pitch_deg {} yaw_deg {} dy_mm {} dz_mm {} (the sensor frame, eq. 3)\n",
            p.d_max * 1e3,
            p.d_min * 1e3,
            p.roll.to_degrees(),
            p.pitch.to_degrees(),
            p.yaw.to_degrees(),
            p.dy * 1e3,
            p.dz * 1e3
        ));
        if let Some((_, b, angle)) = &f.bend {
            head.push_str(&format!(
                "comment epd bend radius_mm {} tube_radius_mm {} tube_ovality {} angle_deg {} (fitted to the end when seen, else the angle seen)\n",
                b.radius * 1e3,
                b.tube_radius * 1e3,
                b.tube_ovality,
                angle.to_degrees()
            ));
        }
    }
    head.push_str(&format!(
        "element vertex {n_vertices}\nproperty double x\nproperty double y\nproperty double z\n\
         property float residual_mm\nproperty uchar mesh\n\
         element face {}\nproperty list uchar int vertex_indices\nproperty uchar part\nend_header\n",
        f.mesh.faces.len()
    ));
    w.write_all(head.as_bytes())?;
    let mut buf = Vec::with_capacity(29 * n_vertices.min(1 << 20));
    let mut vertex = |w: &mut W, q: [f64; 3], r: f32, mesh: u8| -> std::io::Result<()> {
        for v in to_file_frame(q, units, frame) {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend_from_slice(&r.to_le_bytes());
        buf.push(mesh);
        if buf.len() >= 1 << 20 {
            w.write_all(&buf)?;
            buf.clear();
        }
        Ok(())
    };
    for (q, r) in f.points.iter().zip(&f.residual_mm) {
        vertex(&mut w, *q, *r as f32, 0)?;
    }
    for q in &f.mesh.vertices {
        vertex(&mut w, *q, 0.0, 1)?;
    }
    w.write_all(&buf)?;
    let mut faces = Vec::with_capacity(14 * f.mesh.faces.len());
    for (t, part) in f.mesh.faces.iter().zip(&f.mesh.part) {
        faces.push(3u8);
        for i in t {
            faces.extend_from_slice(&((*i as usize + n_points) as i32).to_le_bytes());
        }
        faces.push(*part);
    }
    w.write_all(&faces)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::to_sensor_metres;
    use std::f64::consts::PI;

    fn pose() -> Params {
        Params {
            d_max: 0.49,
            d_min: 0.47,
            roll: 0.3,
            pitch: 0.02,
            yaw: -0.03,
            dy: 0.01,
            dz: -0.02,
        }
    }

    /// The cylinder's vertices lie on the fitted wall: in the pipe frame, on the ellipse.
    #[test]
    fn cylinder_vertices_lie_on_the_ellipse() {
        let p = pose();
        let m = cylinder_mesh(&p, 0.4, 2.0);
        assert_eq!(m.vertices.len() % MESH_AROUND, 0);
        assert_eq!(m.faces.len(), m.part.len());
        for v in &m.vertices {
            let w = p.scs_to_pcs(&Point3::from(*v));
            let e = (w.y / (0.5 * p.d_max)).powi(2) + (w.z / (0.5 * p.d_min)).powi(2) - 1.0;
            assert!(e.abs() < 1e-9, "{e}");
            assert!((0.4 - 1e-9..=2.0 + 1e-9).contains(&w.x));
        }
        let max = m.faces.iter().flatten().max().copied().unwrap_or(0) as usize;
        assert!(max < m.vertices.len());
    }

    /// The torus's vertices lie on the bend's torus (`BendGeometry::torus`), which the
    /// survey fitted: distance to the centreline circle equals the tube radius.
    #[test]
    fn torus_vertices_lie_on_the_bend() {
        let p = pose();
        let b = BendGeometry {
            start: 1.2,
            direction: 0.7,
            radius: 0.75,
            tube_radius: 0.24,
            tube_ovality: 0.0,
            angle: epd_core::bend::OPEN_ANGLE,
        };
        let t = b.torus().unwrap();
        let m = torus_mesh(&p, &b, PI / 2.0);
        for v in &m.vertices {
            let w = p.scs_to_pcs(&Point3::from(*v)).coords - t.centre;
            let h = w.dot(&t.axis);
            let rho = (w.norm_squared() - h * h).sqrt();
            let d = ((rho - t.major_radius).powi(2) + h * h).sqrt();
            assert!((d - t.minor_radius).abs() < 1e-9, "{d}");
        }
        // It starts where the straight wall ends, turning by the angle.
        let first = p.scs_to_pcs(&Point3::from(m.vertices[0]));
        assert!((first.x - 1.2).abs() < 0.25);
    }

    /// A point on the wall has residual 0; one moved along its ray by 5 mm beyond the wall
    /// has +5 mm; the unrolled distance is the wall point's axial coordinate.
    #[test]
    fn residual_is_the_range_error_along_the_ray() {
        let p = pose();
        let m = cylinder_mesh(&p, 1.0, 1.0001);
        let on: Vec<[f64; 3]> = m.vertices[..MESH_AROUND].to_vec();
        let beyond: Vec<[f64; 3]> = on
            .iter()
            .map(|q| {
                let v = Vector3::from(*q);
                (v * (1.0 + 0.005 / v.norm())).into()
            })
            .collect();
        let (r0, u0) = residuals(&on, &p);
        let (r1, _) = residuals(&beyond, &p);
        for ((a, b), u) in r0.iter().zip(&r1).zip(&u0) {
            assert!(a.abs() < 1e-6, "{a}");
            assert!((b - 5.0).abs() < 1e-6, "{b}");
            assert!((u.0 - 1.0).abs() < 1e-6 && (0.0..360.0).contains(&u.1));
        }
    }

    /// The file frame is the inverse of the reading's conversion.
    #[test]
    fn file_frame_inverts_the_reading() {
        for frame in [InputFrame::Sensor, InputFrame::Optical, InputFrame::Body] {
            for units in [Units::Metres, Units::Millimetres] {
                let q = [1.5, -0.2, 0.1];
                let mut back = [to_file_frame(q, units, frame)];
                to_sensor_metres(&mut back, units, frame).unwrap();
                for k in 0..3 {
                    assert!((back[0][k] - q[k]).abs() < 1e-12);
                }
            }
        }
    }
}
