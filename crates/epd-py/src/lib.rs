//! The `epd` Python package: `epd.estimate`, `epd.simulate` and `epd.read` over the
//! workspace's libraries, with numpy arrays at the boundary.
//!
//! Every result goes through the same code as the `epd` tool (the frame library
//! `epd_frame`: `measure_frame`, `measure_file`, its reports and readers; `tof_sim::settings`
//! for `epd.simulate`), so `epd.estimate` returns
//! the keys and values of one JSON object of `epd estimate --format json`, and the
//! errors carry the tool's messages. The GIL is released while a cloud is read,
//! converted and fitted. A C-contiguous, aligned float64 (N, 3) array is read in place
//! (no copy); any other real array is converted once.
//!
//! Long calls stay under the caller's control: the work runs on a thread of its own while
//! the calling thread waits without the GIL and checks for signals every
//! [`SIGNAL_POLL`] (Ctrl-C raises `KeyboardInterrupt` once the estimator reaches its next
//! step: `epd_core::cancel`); an allocation that cannot be made raises `MemoryError`
//! (the working memory is reserved before the fit: `control::reserve_working_memory`); the
//! thread pool belongs to one process and is rebuilt in a child made by `os.fork`
//! (`control::pool`); a masked array (`numpy.ma`) has its masked points dropped.
#![deny(missing_docs)]

use std::borrow::Cow;
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use epd_core::Method;
use epd_core::report::Field;
use epd_frame::input::sensor_metres;
use epd_frame::report::{FileEstimate, FileReport};
use epd_frame::sampling::SamplingMethod;
use epd_frame::{
    ConfigError, EstimateConfig, EstimateSettings, FrameInput, InputConfig, InputFrame, Units,
    measure_file, measure_frame,
};
use numpy::{
    PyArray1, PyArray2, PyArrayDescrMethods, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{
    PyIsADirectoryError, PyKeyboardInterrupt, PyMemoryError, PyOSError, PyRuntimeError,
    PyValueError,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};
use tof_sim::settings::{PoseOverride, SimulateError, SimulateSettings, Simulator};

mod arrays;
mod bag;
mod control;

use arrays::*;
use bag::*;
use control::*;
pub use control::{SIGNAL_POLL, WORKING_BYTES_PER_POINT};

/// The Python exception for a failure to read `path` with the tool's `message`:
/// `OSError` (with its errno, so `FileNotFoundError`, `PermissionError`, …) when the file
/// cannot be opened or is not a regular file, else `ValueError` (the contents are wrong).
fn file_error(path: &Path, message: String) -> PyErr {
    let name = path.display().to_string();
    let os = |e: std::io::Error| match e.raw_os_error() {
        Some(errno) => PyOSError::new_err((errno, message.clone(), name.clone())),
        None => PyOSError::new_err(message.clone()),
    };
    match std::fs::metadata(path) {
        Err(e) => os(e),
        Ok(m) if m.is_dir() => PyIsADirectoryError::new_err(message),
        Ok(m) if !m.is_file() => PyOSError::new_err(message),
        // A regular file: opening it cannot block.
        Ok(_) => match std::fs::File::open(path) {
            Err(e) => os(e),
            Ok(_) => PyValueError::new_err(message),
        },
    }
}

/// A report field as a Python value.
fn field_value<'py>(py: Python<'py>, f: &Field) -> PyResult<Bound<'py, PyAny>> {
    Ok(match f {
        Field::Num(v) if v.is_finite() => v.into_pyobject(py)?.into_any(),
        Field::Num(_) | Field::Null => py.None().into_bound(py),
        Field::Int(v) => v.into_pyobject(py)?.into_any(),
        Field::Int64(v) => v.into_pyobject(py)?.into_any(),
        Field::Text(s) => PyString::new(py, s).into_any(),
        Field::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
    })
}

/// Report fields as a dict, keys in order; `file` is `None` when the points came as an
/// array.
fn fields_dict<'py>(
    py: Python<'py>,
    fields: &[(&'static str, Field)],
    from_array: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, v) in fields {
        if from_array && *k == "file" {
            d.set_item(*k, py.None())?;
        } else {
            d.set_item(*k, field_value(py, v)?)?;
        }
    }
    Ok(d)
}

fn parse_units(units: &str) -> PyResult<Units> {
    match units {
        "m" => Ok(Units::Metres),
        "mm" => Ok(Units::Millimetres),
        other => Err(PyValueError::new_err(format!(
            "units={other:?}: expected \"m\" or \"mm\""
        ))),
    }
}

fn parse_frame(frame: &str) -> PyResult<InputFrame> {
    match frame {
        "sensor" => Ok(InputFrame::Sensor),
        "optical" => Ok(InputFrame::Optical),
        "body" | "flu" => Ok(InputFrame::Body),
        other => Err(PyValueError::new_err(format!(
            "frame={other:?}: expected \"sensor\", \"optical\" or \"body\" (alias \"flu\"; ROS REP 103)"
        ))),
    }
}

/// What `estimate` works on once the arguments are taken.
enum Input<'py> {
    /// A file, read as `epd estimate FILE` reads it.
    File(PathBuf),
    /// Points (and per-point values) borrowed or copied from arrays.
    Array {
        points: Taken<PyReadonlyArray2<'py, f64>>,
        intensity: Option<Taken<PyReadonlyArray1<'py, f64>>>,
        sigma: Option<Taken<PyReadonlyArray1<'py, f64>>>,
    },
}

/// Estimate the pipe's diameters and the sensor's pose from one cloud.
///
/// `points` is an (N, 3) array (float64 C-contiguous arrays are read in place; other
/// real arrays are converted once), an object with a `points` attribute such as an
/// Open3D `PointCloud` (read as `numpy.asarray(obj.points)`), or the path of a
/// PLY/PCD/CSV/XYZ file. The other arguments are those of `epd estimate`: `method`
/// ("ml-epd", "ru-epd", "c-epd"), `units` ("m", "mm"), `frame` ("sensor": X forward,
/// Y right, Z up; "optical": X right, Y down, Z forward, as Open3D, PCL and camera SDKs
/// write; "body" or "flu": X forward, Y left, Z up, a ROS body frame, REP 103), `loss`
/// ("cauchy", "huber", "none"; `None` is "none"), `loss_scale` (m; `None`: from the
/// residuals), `min_range`/`max_range` (m), `calibration` (a depth-table JSON file; needs
/// `intensity`, one per point, or a file with an `intensity` property), `unweighted`,
/// `nominal_od_in` (inch), `straight_only`, `max_points` (fit at most that many points,
/// at least 1000; `None`: every point) and `sampling` ("informed", "stratified",
/// "uniform": how they are chosen). `sigma` gives each point's range standard deviation
/// (m) for a weighted fit.
///
/// Returns a dict, the keys of one JSON object of `epd estimate --format json`:
/// `file` (`None` for an array), `method`, `status` ("converged", "iteration_limit",
/// "degenerate", "implausible", "lack_of_fit"), `status_reason`, `iterations`,
/// `n_points` (points fitted), `n_dropped` (NaN, inf or zero points dropped), the
/// diameters `d_max_mm`, `d_min_mm` (mm), the pose `roll_deg`, `pitch_deg`, `yaw_deg`
/// (degrees), `dy_mm`, `dz_mm` (mm: the sensor's offset from the pipe's axis),
/// `roll_determined`, the 1-σ of each (`sigma_d_max_mm` … `sigma_dz_mm`, same units;
/// `None` where the data do not determine it; when the roll is not determined, the
/// pose's 1-σ are those at the reported roll, conditional on it), `d_mean_mm`, `sigma_d_mean_mm` (mm),
/// `ovality_pct`, `sigma_ovality_pct` (% of the mean diameter), `n_read`,
/// `n_out_of_range`, `n_calibrated`, `weighted`, `rms_residual_mm` (mm), `elapsed_ms`,
/// `read_ms` (ms), `loss`, `loss_scale_m` (m), `nominal_od_mm`, `wall_thickness_est_mm`
/// (mm), `geometry` ("straight", "bend_ahead", "tee_ahead", "in_bend"),
/// `geometry_evidence` (−log₁₀ of the departure test's adjusted p-value; 3 or more is a
/// departure at the survey's false-alarm rate of 10⁻³ per frame), `straight_until_m` (m)
/// and its 1-σ `sigma_straight_until_m` (m), `bend_radius_mm` and its 1-σ
/// `sigma_bend_radius_mm` (mm), `bend_angle_deg` and its 1-σ `sigma_bend_angle_deg` (null
/// while the bend's end is not in view), `bend_direction_deg` (degrees), `bend_withheld`, `dent_at_m` (m), `dent_clock_deg`
/// (degrees), `dent_depth_mm` (mm; a dent, debris or an obstacle on a straight pipe's
/// wall), `ring_from_m`, `ring_to_m` (m) and `ring_widening_mm` (mm; a stretch of wall
/// read out all around, multipath over a band of ranges, left out of the estimate),
/// `n_sampled` and `sampling` (with `max_points`; `sampling` is "uniform" where
/// the informed choice's fit disagreed with its pilot and the frame was measured again
/// on uniform points), `calibration_outside` (the fraction of the points outside an incidence
/// table's support, with `calibration`), `error`, `stamp_ns`, `frame_id` (a bag
/// message's header; `None` here). A result that cannot be believed is `None` with the
/// reason in `error`.
///
/// Raises `ValueError` for bad arguments or a cloud that cannot be fitted and `OSError`
/// for a file that cannot be read, with the tool's messages in Python's terms
/// (`units="mm"` for `--units mm`). The GIL is released during the fit.
#[pyfunction]
#[pyo3(
    text_signature = "(points, method='ml-epd', units='m', frame='sensor', \
    loss='cauchy', loss_scale=None, min_range=None, max_range=None, calibration=None, \
    intensity=None, sigma=None, unweighted=False, nominal_od_in=None, straight_only=False, \
    max_points=None, sampling='informed')"
)]
#[pyo3(signature = (
    points, method="ml-epd", units="m", frame="sensor", loss=Some("cauchy"),
    loss_scale=None, min_range=None, max_range=None, calibration=None,
    intensity=None, sigma=None, unweighted=false, nominal_od_in=None, straight_only=false,
    max_points=None, sampling="informed",
))]
#[allow(clippy::too_many_arguments)] // the tool's flags, as keyword arguments
fn estimate<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    method: &str,
    units: &str,
    frame: &str,
    loss: Option<&str>,
    loss_scale: Option<f64>,
    min_range: Option<f64>,
    max_range: Option<f64>,
    calibration: Option<PathBuf>,
    intensity: Option<&Bound<'py, PyAny>>,
    sigma: Option<&Bound<'py, PyAny>>,
    unweighted: bool,
    nominal_od_in: Option<f64>,
    straight_only: bool,
    max_points: Option<i64>,
    sampling: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let sampling: SamplingMethod = sampling
        .parse()
        .map_err(|e: epd_frame::sampling::SamplingError| PyValueError::new_err(e.to_string()))?;
    // A negative count is the same usage error as one too small (not an OverflowError).
    let max_points = max_points
        .map(|n| {
            usize::try_from(n).map_err(|_| {
                PyValueError::new_err(format!(
                    "max_points={n}: need at least {} points; None uses every point",
                    epd_frame::sampling::MIN_MAX_POINTS
                ))
            })
        })
        .transpose()?;
    let method: Method = method
        .parse()
        .map_err(|e: epd_core::EpdError| PyValueError::new_err(e.to_string()))?;
    let settings = EstimateSettings {
        method,
        min_range,
        max_range,
        nominal_od_in,
        loss: loss.unwrap_or("none").to_string(),
        loss_scale,
        calibration,
        unweighted,
        geometry: !straight_only,
        input: InputConfig {
            units: parse_units(units)?,
            frame: parse_frame(frame)?,
            frame_given: true,
            format: None,
        },
        max_points,
        sampling,
    };
    let input = take_input(points, intensity, sigma, &settings)?;
    match input {
        Input::File(path) => estimate_file_dict(py, &path, &settings),
        Input::Array {
            points,
            intensity,
            sigma,
        } => estimate_array_dict(py, &points, intensity.as_ref(), sigma.as_ref(), &settings),
    }
}

/// What `estimate` fits: the file `points` names (a `str` or `os.PathLike`), or the
/// array `points` with its per-point `intensity` and `sigma`; `ValueError` for a mix.
fn take_input<'py>(
    points: &Bound<'py, PyAny>,
    intensity: Option<&Bound<'py, PyAny>>,
    sigma: Option<&Bound<'py, PyAny>>,
    settings: &EstimateSettings,
) -> PyResult<Input<'py>> {
    if points.is_instance_of::<PyString>() || has_fspath(points)? {
        let path: PathBuf = points.extract()?;
        if path.as_os_str() == "-" {
            return Err(PyValueError::new_err(
                "points=\"-\": standard input is not read here; pass a file path or an array",
            ));
        }
        if intensity.is_some() || sigma.is_some() {
            return Err(PyValueError::new_err(
                "intensity= and sigma= go with an array of points; a file brings its own \
                 properties",
            ));
        }
        return Ok(Input::File(path));
    }
    let points = take_points(points)?;
    if points.array.len() == 0 {
        return Err(PyValueError::new_err("the array holds no points"));
    }
    if sigma.is_some() && settings.calibration.is_some() && !settings.unweighted {
        return Err(PyValueError::new_err(
            "sigma= and a weighting calibration= both give per-point σ: pass one, or \
             unweighted=True",
        ));
    }
    Ok(Input::Array {
        points,
        intensity: intensity.map(|a| take_values(a, "intensity")).transpose()?,
        sigma: sigma.map(|a| take_values(a, "sigma")).transpose()?,
    })
}

/// The tool's checked configuration of `settings` (the depth table read), or why not.
fn estimate_config(settings: &EstimateSettings) -> Result<EstimateConfig, Failure> {
    EstimateConfig::new(settings).map_err(|e| match &e {
        ConfigError::Calibration { path, .. } => Failure::File(path.clone(), e.to_string()),
        ConfigError::Setting(m) => Failure::Value(m.clone()),
    })
}

/// `estimate` of a file, as `epd estimate FILE` (the GIL released).
fn estimate_file_dict<'py>(
    py: Python<'py>,
    path: &Path,
    settings: &EstimateSettings,
) -> PyResult<Bound<'py, PyDict>> {
    let report: FileReport = run_interruptible(py, || -> Result<FileReport, Failure> {
        Ok(measure_file(path, &estimate_config(settings)?))
    })
    .map_err(Stop::into_py_err)?;
    match &report.outcome {
        Ok(_) => fields_dict(py, &report.keyed_fields(), false),
        Err(msg) => Err(file_error(path, python_terms(msg))),
    }
}

/// `estimate` of arrays: the points converted to metres in the sensor frame, then fitted
/// as the tool fits a file's (the GIL released).
fn estimate_array_dict<'py>(
    py: Python<'py>,
    points: &Taken<PyReadonlyArray2<'py, f64>>,
    intensity: Option<&Taken<PyReadonlyArray1<'py, f64>>>,
    sigma: Option<&Taken<PyReadonlyArray1<'py, f64>>>,
    settings: &EstimateSettings,
) -> PyResult<Bound<'py, PyDict>> {
    let pts = rows(&points.array)?;
    let i = intensity
        .map(|t| values(&t.array, "intensity"))
        .transpose()?;
    let s = sigma.map(|t| values(&t.array, "sigma")).transpose()?;
    if let Some(s) = s {
        check_sigma(pts, s)?;
    }
    reserve_working_memory(pts.len())?;
    let outcome = run_interruptible(py, || -> Result<FileEstimate, Failure> {
        let cfg = estimate_config(settings)?;
        let t0 = Instant::now();
        let pts: Cow<'_, [[f64; 3]]> =
            sensor_metres(pts, cfg.input.units, cfg.input.frame).map_err(Failure::Value)?;
        let read_ms = t0.elapsed().as_secs_f64() * 1e3;
        let input = FrameInput {
            points: pts,
            intensity: i,
            sigma: s,
            read_ms,
        };
        measure_frame(input, &cfg).map_err(Failure::Value)
    })
    .map_err(Stop::into_py_err)?;
    let report = FileReport {
        file: String::new(),
        file_bytes: None,
        outcome: Ok(outcome),
        message: None,
    };
    fields_dict(py, &report.keyed_fields(), true)
}

/// The check of `sigma=` against the points: one finite σ > 0 (m) for every usable point
/// (finite, not at the origin); a point that is itself invalid may have any σ.
fn check_sigma(points: &[[f64; 3]], sigma: &[f64]) -> PyResult<()> {
    if sigma.len() != points.len() {
        return Err(PyValueError::new_err(format!(
            "sigma: {} values for {} points; pass one range standard deviation (m) per point",
            sigma.len(),
            points.len()
        )));
    }
    let usable = |p: &[f64; 3]| p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0);
    let mut bad = points
        .iter()
        .zip(sigma)
        .enumerate()
        .filter(|(_, (p, s))| usable(p) && !(s.is_finite() && **s > 0.0));
    if let Some((first, (_, s))) = bad.next() {
        let n = 1 + bad.count();
        return Err(PyValueError::new_err(format!(
            "sigma: {n} of {} values are not a finite number > 0 (m), the first at index \
             {first} ({s}); each usable point needs its range standard deviation",
            sigma.len()
        )));
    }
    Ok(())
}

/// An error found with the GIL released, turned into a Python exception afterwards.
enum Failure {
    /// Bad input: `ValueError`.
    Value(String),
    /// A file that could not be used: `OSError` or `ValueError` (see [`file_error`]).
    File(PathBuf, String),
}

impl Stop<Failure> {
    fn into_py_err(self) -> PyErr {
        match self {
            Stop::Failed(f) => f.into_py_err(),
            Stop::Signal(e) => e,
        }
    }
}

impl Failure {
    fn into_py_err(self) -> PyErr {
        match self {
            Failure::Value(m) => PyValueError::new_err(python_terms(&m)),
            Failure::File(p, m) => file_error(&p, python_terms(&m)),
        }
    }
}

/// A message of the tool in Python's terms: its flags as `estimate`'s keyword arguments
/// (`--units mm` → `units="mm"`).
fn python_terms(message: &str) -> String {
    message.replace("--units mm", "units=\"mm\"")
}

/// Whether `obj` is an `os.PathLike` (has `__fspath__`).
fn has_fspath(obj: &Bound<'_, PyAny>) -> PyResult<bool> {
    obj.hasattr("__fspath__")
}

/// The address of the float64 data that `estimate` would fit for `points`, and whether
/// it is a copy: `(address, copied)`. For tests of the no-copy path.
#[pyfunction]
fn _points_buffer(points: &Bound<'_, PyAny>) -> PyResult<(usize, bool)> {
    let t = take_points(points)?;
    let rows = rows(&t.array)?;
    Ok((rows.as_ptr() as usize, t.copied))
}

/// Read a point-cloud file (PLY, PCD, CSV/XYZ/TXT/PTS/ASC) with the `epd` tool's readers.
///
/// Returns `(points, properties)`: the points as stored (an (N, 3) float64 array, not
/// converted: pass `units=`/`frame=` to `estimate`) and a dict of the other per-point
/// properties (`intensity`, …) as float64 arrays. Raises `OSError` when the file cannot be
/// opened and `ValueError` when its contents are not a point cloud, with the tool's
/// messages. The GIL is released while the file is read.
#[pyfunction]
fn read<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyDict>)> {
    let cloud =
        run_interruptible(py, || epd_frame::read::read_path(&path)).map_err(|s| match s {
            Stop::Failed(m) => file_error(&path, m),
            Stop::Signal(e) => e,
        })?;
    let props = PyDict::new(py);
    for (name, v) in cloud.extra {
        props.set_item(name, PyArray1::from_vec(py, v))?;
    }
    Ok((points_array(py, cloud.points)?, props))
}

/// Simulate one Helios2-like frame inside a pipe, as `epd simulate` does.
///
/// Arguments as the tool's flags: `od_in` (nominal outer diameter, inch), `wall_mm`,
/// `ovality` ((Dmax − Dmin)/ID), `sigma` (m of range noise), `seed`, `trial` (the frame
/// index: frame_KKKK of `epd simulate --seed S` is `trial=K`), `points` (a uniform
/// subsample of that many points), `outliers` (fraction), `noise` ("range",
/// "isotropic"), `sensor` ("plain", "helios2"); `roll_deg`, `pitch_deg`, `yaw_deg`,
/// `dy_mm`, `dz_mm` replace the drawn pose parameters; `bend_at` (m) puts a 90°
/// long-radius elbow (radius 1.5 × the inner diameter) that far ahead of the sensor along
/// the pipe, `tee_at` (m) a tee's branch opening (0.6 × the inner diameter), as
/// `epd simulate --bend-at M` / `--tee-at M` (then truth also has `geometry` and
/// `straight_until_m`). Returns `(points, truth)`: the
/// measured points (an (N, 3) float64 array, m, sensor frame) and the ground truth with
/// the keys and values of the JSON file `epd simulate` writes: `d_max_mm`, `d_min_mm`
/// (mm), `roll_deg`, `pitch_deg`, `yaw_deg` (degrees), `dy_mm`, `dz_mm` (mm), `n_points`,
/// `seed`, `trial`, `sigma_m` (m), `outlier_fraction`, `sensor`, and with a feature
/// `geometry` and `straight_until_m` (m); with
/// `return_properties=True`, `(points, truth, properties)` where properties holds `u`,
/// `v` and (Helios2) `intensity` as in the PLY file.
#[pyfunction]
#[pyo3(signature = (
    od_in=20.0, wall_mm=12.0, ovality=0.02, sigma=0.03, seed=1, trial=0, points=None,
    outliers=0.0, noise="range", sensor="plain", roll_deg=None, pitch_deg=None,
    yaw_deg=None, dy_mm=None, dz_mm=None, return_properties=false, bend_at=None, tee_at=None,
))]
#[allow(clippy::too_many_arguments)] // the tool's flags, as keyword arguments
fn simulate<'py>(
    py: Python<'py>,
    od_in: f64,
    wall_mm: f64,
    ovality: f64,
    sigma: f64,
    seed: u64,
    trial: u64,
    points: Option<usize>,
    outliers: f64,
    noise: &str,
    sensor: &str,
    roll_deg: Option<f64>,
    pitch_deg: Option<f64>,
    yaw_deg: Option<f64>,
    dy_mm: Option<f64>,
    dz_mm: Option<f64>,
    return_properties: bool,
    bend_at: Option<f64>,
    tee_at: Option<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    let noise = parse_noise(noise)?;
    let feature = match (bend_at, tee_at) {
        (Some(_), Some(_)) => {
            return Err(PyValueError::new_err(
                "bend_at and tee_at given together: a frame has one feature ahead; give one",
            ));
        }
        (Some(m), None) => Some(tof_sim::settings::Feature::BendAt(m)),
        (None, Some(m)) => Some(tof_sim::settings::Feature::TeeAt(m)),
        (None, None) => None,
    };
    let helios2 = parse_sensor(sensor)?;
    let points = match points {
        None => None,
        Some(n) => Some(NonZeroUsize::new(n).ok_or_else(|| {
            PyValueError::new_err("points=0: expected a number of points ≥ 1, or None for all")
        })?),
    };
    let rad = |d: Option<f64>| d.map(f64::to_radians);
    let m = |v: Option<f64>| v.map(|v| v * 1e-3);
    let settings = SimulateSettings {
        seed,
        sigma,
        od_in,
        ovality,
        wall_mm,
        points,
        outliers,
        noise,
        helios2,
        pose: PoseOverride {
            roll: rad(roll_deg),
            pitch: rad(pitch_deg),
            yaw: rad(yaw_deg),
            dy: m(dy_mm),
            dz: m(dz_mm),
        },
        feature,
    };
    let (frame, truth) = run_interruptible(py, || -> Result<_, SimulateError> {
        let sim = Simulator::new(&settings)?;
        let mut frame = tof_sim::Frame::empty();
        sim.frame(trial, &mut frame)?;
        let truth = sim.truth(trial, &frame);
        Ok((frame, truth))
    })
    .map_err(|s| match s {
        Stop::Failed(e) => PyValueError::new_err(e.to_string()),
        Stop::Signal(e) => e,
    })?;
    let truth = fields_dict(py, &truth, false)?;
    if return_properties {
        let props = frame_properties(py, &frame)?;
        let pts = points_array(py, frame.measured)?;
        Ok((pts, truth, props).into_pyobject(py)?.into_any())
    } else {
        let pts = points_array(py, frame.measured)?;
        Ok((pts, truth).into_pyobject(py)?.into_any())
    }
}

/// `simulate`'s `noise=`: "range" or "isotropic".
fn parse_noise(noise: &str) -> PyResult<tof_sim::NoiseModel> {
    match noise {
        "range" => Ok(tof_sim::NoiseModel::Range),
        "isotropic" => Ok(tof_sim::NoiseModel::Isotropic),
        other => Err(PyValueError::new_err(format!(
            "noise={other:?}: expected \"range\" or \"isotropic\""
        ))),
    }
}

/// `simulate`'s `sensor=`: whether it is "helios2" (else "plain").
fn parse_sensor(sensor: &str) -> PyResult<bool> {
    match sensor {
        "plain" => Ok(false),
        "helios2" => Ok(true),
        other => Err(PyValueError::new_err(format!(
            "sensor={other:?}: expected \"plain\" or \"helios2\""
        ))),
    }
}

/// The frame's per-point properties as the PLY file has them: `u`, `v` and, when the
/// model gives one, `intensity`.
fn frame_properties<'py>(py: Python<'py>, frame: &tof_sim::Frame) -> PyResult<Bound<'py, PyDict>> {
    use epd_io::cloud::Values;
    let props = PyDict::new(py);
    let col = |i: usize| frame.pixels.iter().map(|p| f64::from(p[i])).collect();
    props.set_item("u", PyArray1::from_vec(py, col(0)))?;
    props.set_item("v", PyArray1::from_vec(py, col(1)))?;
    // The PLY's other properties: `intensity` (Helios2), `segment` and `part` (a frame with
    // a bend or a tee ahead), as `epd.read` reads them from the file.
    for p in frame.cloud().properties {
        let v: Vec<f64> = match &p.values {
            Values::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
            Values::U16(v) => v.iter().map(|&x| f64::from(x)).collect(),
            Values::U8(v) => v.iter().map(|&x| f64::from(x)).collect(),
        };
        props.set_item(p.name.as_str(), PyArray1::from_vec(py, v))?;
    }
    Ok(props)
}

/// Pipe elliptical diameters and sensor pose from 3D time-of-flight point clouds.
#[pymodule]
fn epd(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(estimate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(read_bag, m)?)?;
    m.add_class::<BagReader>()?;
    m.add_function(wrap_pyfunction!(_points_buffer, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}

#[cfg(test)]
mod tests;
