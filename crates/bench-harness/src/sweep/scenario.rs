//! Sweep scenario files (docs/paper.md, Scenario files): one base setting and one swept
//! variable, checked into [`Setting`]s before anything runs. The keys as written are read
//! in `sweep/scenario/keys.rs`; the checks of their ranges and of the run's size are here.

use std::path::{Path, PathBuf};

use epd_core::{Loss, Method};
use tof_sim::{
    CameraNoise, Contamination, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel,
};

use crate::scenario::{KeyError, ScenarioError, check_name, key_err, read_source};
pub use keys::Points;
use keys::{File, SweepFile};

mod keys;
#[cfg(test)]
mod tests;

/// One fully checked setting: what a trial needs, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    /// The sensor.
    pub sensor: Sensor,
    /// The pipe.
    pub pipe: Pipe,
    /// The depth errors.
    pub noise: Noise,
    /// What a real camera adds to them (`[noise.camera]`).
    pub camera: CameraNoise,
    /// What lies in or deforms the pipe (`[contamination]`).
    pub contamination: Contamination,
    /// The pose ranges.
    pub poses: PoseRanges,
    /// Points kept per frame.
    pub points: Points,
    /// The methods, in the order listed.
    pub methods: Vec<Method>,
    /// The robust loss of every estimate (`loss`, `loss_scale_m`).
    pub loss: Loss,
    /// Whether the loss's scale is taken from the residuals (`loss_scale = "auto"`).
    pub loss_scale_auto: bool,
    /// The estimator's range gate (m), `range_gate_m`.
    pub range_gate: Option<(f64, f64)>,
    /// The points fitted of each frame (`sampling`; `None`: all of them).
    pub sampling: Option<epd_frame::sampling::Sampling>,
    /// Whether each frame goes through the frame library with the scene ahead surveyed,
    /// as `epd estimate` measures a file (`geometry = true`), its reported geometry
    /// recorded; else every point is fitted as one straight pipe.
    pub geometry: bool,
}

impl Setting {
    /// The subsample of the frame.
    pub fn subsample(&self) -> Subsample {
        match self.points {
            Points::All => Subsample::All,
            Points::N(n) => Subsample::Points(n),
        }
    }
}

/// A checked scenario: its settings, one per swept value.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// `name`: the results go to `results/<name>/`.
    pub name: String,
    /// `seed`.
    pub seed: u64,
    /// `trials` per swept value.
    pub trials: usize,
    /// Whether trials run one at a time for uncontended timings (`timing = true`, or a
    /// sweep over `points`).
    pub timing: bool,
    /// The swept dotted key (`"none"` without a `[sweep]`).
    pub sweep_variable: String,
    /// (value as text, setting) per swept value, in file order.
    pub sweeps: Vec<(String, Setting)>,
    /// The file's text, copied into the results.
    pub source: String,
    /// The file.
    pub path: PathBuf,
}

/// Most trials per setting (`trials`, `--trials`).
pub const MAX_TRIALS: usize = 1_000_000;
/// Most swept values (`sweep.values`).
pub const MAX_SWEEP_VALUES: usize = 10_000;
/// Largest sensor side (`sensor.width`, `sensor.height`), pixels.
pub const MAX_SENSOR_SIDE: u32 = 4096;
/// Largest subsample (`points`).
pub const MAX_POINTS: usize = 10_000_000;
/// Smallest subsample (`points`): the estimators' minimum
/// ([`epd_core::init::MIN_ESTIMATE_POINTS`], nine for the initial guess's quadric), so
/// that a subsample the scenario accepts is one the estimators take.
pub const MIN_POINTS: usize = epd_core::init::MIN_ESTIMATE_POINTS;
/// Most estimates in one run: trials × swept values × methods.
pub const MAX_ESTIMATES: usize = 100_000_000;

/// Set `dotted` (e.g. `noise.sigma_m`) in a TOML table to `value`, creating sections.
fn set_dotted(table: &mut toml::Table, dotted: &str, value: toml::Value) -> Result<(), String> {
    let parts: Vec<&str> = dotted.split('.').collect();
    let (last, sections) = parts.split_last().ok_or("empty key")?;
    let mut t = table;
    for s in sections {
        let entry = t
            .entry(s.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        t = entry
            .as_table_mut()
            .ok_or_else(|| format!("`{s}` is not a section"))?;
    }
    t.insert(last.to_string(), value);
    Ok(())
}

/// Set the swept `variable` to `value` in a copy of the file's table: one dotted key, or
/// several joined by `+` (`"pipe+noise"`), swept together: each value is then a table
/// holding every one of them (and optionally a `label`), e.g. `{ label = "8 in /
/// independent", pipe = { nominal_od_in = 8.0 }, noise = { sigma_m = 0.02 } }`, each
/// set at its key as a single swept key is.
fn set_swept(table: &mut toml::Table, variable: &str, value: &toml::Value) -> Result<(), String> {
    if !variable.contains('+') {
        return set_dotted(table, variable, value.clone());
    }
    let parts: Vec<&str> = variable.split('+').collect();
    let toml::Value::Table(v) = value else {
        return Err(format!(
            "is not a table: sweeping `{variable}` together, each value is a table with the \
             keys {}",
            parts.join(", ")
        ));
    };
    if let Some(k) = v
        .keys()
        .find(|k| k.as_str() != "label" && !parts.contains(&k.as_str()))
    {
        return Err(format!(
            "has `{k}`, which is not swept: the keys of `{variable}` (and `label`) only"
        ));
    }
    for part in parts {
        let Some(x) = v.get(part) else {
            return Err(format!(
                "lacks `{part}`: every value of `{variable}` sets it"
            ));
        };
        set_dotted(table, part, x.clone())?;
    }
    Ok(())
}

/// A swept value as the results name it: a string as written, a table by its `label`
/// (when it has one), anything else as TOML.
fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        toml::Value::Table(t) if t.get("label").is_some_and(toml::Value::is_str) => t
            .get("label")
            .and_then(toml::Value::as_str)
            .unwrap_or_default()
            .to_string(),
        other => other.to_string(),
    }
}

impl Scenario {
    /// Read and check a scenario file. Every error names the file and the key.
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let read_err = |source| ScenarioError::Read {
            path: path.to_path_buf(),
            source,
        };
        // A regular file only: opening a FIFO would wait for a writer.
        let (file, _) =
            epd_io::read::open_regular(path).map_err(|e| read_err(std::io::Error::other(e)))?;
        Self::from_reader(path, file)
    }

    /// Read and check a scenario from `reader` (standard input, say); `path` names it in
    /// errors. At most [`MAX_SCENARIO_BYTES`](crate::scenario::MAX_SCENARIO_BYTES) are
    /// read ([`read_source`]).
    pub fn from_reader(path: &Path, reader: impl std::io::Read) -> Result<Self, ScenarioError> {
        Self::parse(path, &read_source(path, reader)?)
    }

    /// Check `trials` trials per setting against the limits: at most [`MAX_TRIALS`], and
    /// at most [`MAX_ESTIMATES`] estimates (trials × swept values × methods) in the run.
    /// `key` names where the number came from (`trials`, `--trials`).
    pub fn check_trials(&self, key: &str, trials: usize) -> Result<(), ScenarioError> {
        let methods = self.sweeps.first().map_or(1, |(_, s)| s.methods.len());
        check_work(&self.path, key, trials, self.sweeps.len(), methods)
    }

    /// Check a scenario given as text (`path` names it in errors).
    pub fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        let parse_err = |e: toml::de::Error| ScenarioError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().to_string(),
        };
        let invalid = |key: &str, message: String| ScenarioError::Invalid {
            path: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        let table: toml::Table = toml::from_str(source).map_err(parse_err)?;
        let base: File = toml::from_str(source).map_err(parse_err)?;
        check_name(&base.name).map_err(|(key, msg)| invalid(&key, msg))?;
        // `trials` was checked against [1, MAX_TRIALS] as it was read.
        let (variable, values) = match &base.sweep {
            Some(s) => {
                check_sweep(s).map_err(|(key, msg)| invalid(&key, msg))?;
                (s.variable.clone(), s.values.clone())
            }
            None => ("none".to_string(), vec![]),
        };
        let methods = {
            let mut m = base.methods.clone();
            m.sort();
            m.dedup();
            m.len()
        };
        check_work(path, "trials", base.trials, values.len().max(1), methods)?;
        // Each swept value is set in a copy of the file without its [sweep] section, and
        // turned into a [`Setting`] at once, so memory stays linear in the number of
        // values (a copy of the whole file, values included, per value was quadratic:
        // > 3 GB for 10 000 values).
        let mut table = table;
        table.remove("sweep");
        let mut sweeps = Vec::with_capacity(values.len().max(1));
        if values.is_empty() {
            let setting = to_setting(&base).map_err(|(key, msg)| invalid(&key, msg))?;
            sweeps.push(("-".to_string(), setting));
        }
        for value in &values {
            let text = value_text(value);
            let mut t = table.clone();
            set_swept(&mut t, &variable, value).map_err(|m| {
                if variable.contains('+') {
                    invalid("sweep.values", format!("(swept value {text}) {m}"))
                } else {
                    invalid("sweep.variable", m)
                }
            })?;
            let f: File = t.try_into().map_err(|e: toml::de::Error| {
                invalid(
                    &variable,
                    format!("(swept value {text}): {}", e.to_string().trim_end()),
                )
            })?;
            let setting = to_setting(&f)
                .map_err(|(key, msg)| invalid(&key, format!("{msg} (swept value {text})")))?;
            sweeps.push((text, setting));
        }
        let timing = base.timing || variable == "points";
        Ok(Self {
            name: base.name,
            seed: base.seed,
            trials: base.trials,
            timing,
            sweep_variable: variable,
            sweeps,
            source: source.to_string(),
            path: path.to_path_buf(),
        })
    }
}

/// `name` becomes a folder: not empty, no path separator, not `.` or `..`.
/// `[sweep]`: 1 to [`MAX_SWEEP_VALUES`] values of a key that can be swept (not the run's
/// own keys: `name`, `seed`, `trials`, `methods`, `timing`, `sweep.*`), or of several such
/// keys joined by `+` ([`set_swept`]).
fn check_sweep(s: &SweepFile) -> Result<(), KeyError> {
    if s.values.is_empty() {
        return Err(key_err(
            "sweep.values",
            "is empty: list at least one value".into(),
        ));
    }
    if s.values.len() > MAX_SWEEP_VALUES {
        return Err(key_err(
            "sweep.values",
            format!("has {} values: at most {MAX_SWEEP_VALUES}", s.values.len()),
        ));
    }
    let fixed = |part: &str| {
        part.is_empty()
            || part.starts_with("sweep")
            || ["name", "seed", "trials", "methods", "timing"].contains(&part)
    };
    if s.variable.split('+').any(fixed) {
        return Err(key_err(
            "sweep.variable",
            format!("= \"{}\": cannot be swept", s.variable),
        ));
    }
    Ok(())
}

/// The limits on one run's work: `trials` ≤ [`MAX_TRIALS`] and trials × swept values ×
/// methods ≤ [`MAX_ESTIMATES`]; `key` names where `trials` came from.
fn check_work(
    path: &Path,
    key: &str,
    trials: usize,
    values: usize,
    methods: usize,
) -> Result<(), ScenarioError> {
    let invalid = |message: String| ScenarioError::Invalid {
        path: path.to_path_buf(),
        key: key.to_string(),
        message,
    };
    if !(1..=MAX_TRIALS).contains(&trials) {
        return Err(invalid(format!(
            "= {trials}: must be an integer in [1, {MAX_TRIALS}]"
        )));
    }
    let estimates = trials
        .saturating_mul(values.max(1))
        .saturating_mul(methods.max(1));
    if estimates > MAX_ESTIMATES {
        return Err(invalid(format!(
            "= {trials}: {trials} trials × {values} swept values × {methods} methods = \
             {estimates} estimates, at most {MAX_ESTIMATES} in one run"
        )));
    }
    Ok(())
}

/// File units → a checked [`Setting`], or (key, message). Checked in the order of the
/// steps below, so a file with several errors names the first.
fn to_setting(f: &File) -> Result<Setting, KeyError> {
    let methods = parse_methods(&f.methods)?;
    check_sizes(f)?;
    let sensor = f.sensor.to_sensor();
    let pipe = f.pipe.to_pipe();
    let noise = f.noise.to_noise()?;
    let poses = f.poses.to_ranges();
    let sim = |e: tof_sim::SimError| match e {
        tof_sim::SimError::Invalid {
            field,
            value,
            reason,
        } => (field.to_string(), format!("= {value}: {reason}")),
        other => ("?".to_string(), other.to_string()),
    };
    sensor.validate().map_err(sim)?;
    pipe.validate().map_err(sim)?;
    noise.validate().map_err(sim)?;
    poses.validate().map_err(sim)?;
    check_sensor_inside(&pipe, &poses)?;
    let camera = f.noise.camera.to_camera();
    camera
        .validate(&noise)
        .map_err(sim)
        .map_err(|(k, m)| (camera_key(&k), m))?;
    let contamination = f.contamination.to_contamination();
    // The contamination's own checks (in metres and radians, against the pipe's size) on
    // the pipe at the centre of the pose ranges: they do not depend on the pose.
    let centre = PoseRanges {
        roll: (0.0, 0.0),
        pitch: (0.0, 0.0),
        yaw: (0.0, 0.0),
        dy: (0.0, 0.0),
        dz: (0.0, 0.0),
        tilt: None,
    }
    .sample(&pipe, 0, 0)
    .map_err(sim)?;
    Scene::new(&centre, WallModel::Exact, sensor.max_range)
        .and_then(|s| s.with_contamination(contamination))
        .map_err(sim)?;
    let loss_scale_auto = match f.loss_scale.as_str() {
        "fixed" => false,
        "auto" => true,
        other => {
            return Err(key_err(
                "loss_scale",
                format!("= \"{other}\": must be \"fixed\" or \"auto\""),
            ));
        }
    };
    let range_gate = match f.range_gate_m {
        None => None,
        Some([lo, hi]) if lo >= 0.0 && hi > lo && hi.is_finite() => Some((lo, hi)),
        Some([lo, hi]) => {
            return Err(key_err(
                "range_gate_m",
                format!("= [{lo}, {hi}]: need 0 ≤ min < max, finite"),
            ));
        }
    };
    let loss = Loss::from_name(&f.loss, f.loss_scale_m).map_err(|e| {
        let key = if f.loss_scale_m > 0.0 && f.loss_scale_m.is_finite() {
            "loss"
        } else {
            "loss_scale_m"
        };
        key_err(key, e.to_string())
    })?;
    let sampling = match &f.sampling {
        None => None,
        Some(s) => {
            let method = s
                .method
                .parse()
                .map_err(|e: epd_frame::sampling::SamplingError| {
                    key_err("sampling.method", e.to_string())
                })?;
            match s.max_points {
                None => None,
                Some(n) => Some(
                    epd_frame::sampling::Sampling::new(n as usize, method)
                        .map_err(|e| key_err("sampling.max_points", e.to_string()))?,
                ),
            }
        }
    };
    Ok(Setting {
        sampling,
        geometry: f.geometry,
        sensor,
        pipe,
        noise,
        camera,
        contamination,
        poses,
        points: f.points,
        methods,
        loss,
        loss_scale_auto,
        range_gate,
    })
}

/// `methods`: the names parsed, duplicates dropped, in the order listed; at least one.
fn parse_methods(names: &[String]) -> Result<Vec<Method>, KeyError> {
    let mut methods = Vec::new();
    for m in names {
        let method: Method = m
            .parse()
            .map_err(|e: epd_core::EpdError| key_err("methods", e.to_string()))?;
        if !methods.contains(&method) {
            methods.push(method);
        }
    }
    if methods.is_empty() {
        return Err(key_err(
            "methods",
            "is empty: list at least one of c-epd, ru-epd, ml-epd".into(),
        ));
    }
    Ok(methods)
}

/// The limits on a frame's size: sensor sides ≤ [`MAX_SENSOR_SIDE`], `points` in
/// [[`MIN_POINTS`], [`MAX_POINTS`]].
fn check_sizes(f: &File) -> Result<(), KeyError> {
    for (key, v) in [
        ("sensor.width", f.sensor.width),
        ("sensor.height", f.sensor.height),
    ] {
        if !(1..=MAX_SENSOR_SIDE).contains(&v) {
            return Err(key_err(
                key,
                format!("= {v}: must lie in [1, {MAX_SENSOR_SIDE}] pixels"),
            ));
        }
    }
    if let Points::N(n) = f.points
        && !(MIN_POINTS..=MAX_POINTS).contains(&n)
    {
        return Err(key_err(
            "points",
            format!("= {n}: must be \"all\" or an integer in [{MIN_POINTS}, {MAX_POINTS}]"),
        ));
    }
    Ok(())
}

/// The largest offsets must keep the sensor inside the pipe: (δy/a)² + (δz/b)² < 1 for
/// the semi-axes a = D_max/2, b = D_min/2.
fn check_sensor_inside(pipe: &Pipe, poses: &PoseRanges) -> Result<(), KeyError> {
    let (a, b) = (pipe.d_max() / 2.0, pipe.d_min() / 2.0);
    let dy = poses.dy.0.abs().max(poses.dy.1.abs());
    let dz = poses.dz.0.abs().max(poses.dz.1.abs());
    if (dy / a).powi(2) + (dz / b).powi(2) >= 1.0 {
        return Err(key_err(
            "poses.dy_mm",
            format!(
                "and poses.dz_mm reach ({:.0}, {:.0}) mm: outside the pipe (semi-axes {:.0} × {:.0} mm)",
                dy * 1e3,
                dz * 1e3,
                a * 1e3,
                b * 1e3
            ),
        ));
    }
    Ok(())
}

/// tof-sim names the camera's fields as `CameraNoise` does; the file's key is
/// `noise.camera.<field>` (the wiggle's and flying pixels' parts by their file names).
fn camera_key(field: &str) -> String {
    let last = field.rsplit('.').next().unwrap_or(field);
    let file_key = match field {
        f if f.contains("wiggle") => match last {
            "amplitude_m" => "wiggle_amplitude_m",
            "period_m" => "wiggle_period_m",
            "phase_rad" => "wiggle_phase_deg",
            other => other,
        },
        f if f.contains("flying") => "flying_pixel_probability",
        f if f.contains("multipath") => "multipath_bands",
        _ => last,
    };
    format!("noise.camera.{file_key}")
}
