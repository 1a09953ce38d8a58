//! Scenario files (README, Scenario files): one base setting and one swept variable, checked into
//! [`Setting`]s before anything runs.

use std::path::{Path, PathBuf};

use epd_core::{Loss, Method};
use serde::Deserialize;
use tof_sim::{Noise, NoiseModel, Pipe, PoseRanges, Sensor, Subsample};

/// A scenario that cannot be used, with the file and the key at fault.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file cannot be read.
    #[error("cannot read scenario `{path}`: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax, an unknown key or a wrong type (the toml crate names the key and line).
    #[error("scenario `{path}`: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The file is larger than [`MAX_SCENARIO_BYTES`].
    #[error("scenario `{path}` is larger than {MAX_SCENARIO_BYTES} bytes: not a scenario file")]
    TooLarge {
        /// The file.
        path: PathBuf,
    },
    /// A value outside its range.
    #[error("scenario `{path}`: `{key}` {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The dotted key.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// `points = "all"` or an integer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Points {
    /// Every point within range.
    #[default]
    All,
    /// A uniform subsample of this many points.
    N(usize),
}

impl<'de> Deserialize<'de> for Points {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(Bounded {
            key: "points",
            lo: MIN_POINTS as u64,
            hi: MAX_POINTS as u64,
            all: true,
        })
        .map(|n| n.map_or(Points::All, |n| Points::N(n as usize)))
    }
}

/// A number as the file wrote it, for error messages (`1e18`, not eighteen zeros).
fn float_text(v: f64) -> String {
    if v.is_finite() && v.abs() < 1e15 {
        // `1e7` is shown as `10000000.0`: a float, as the message then says.
        if v.fract() == 0.0 {
            format!("{v:.1}")
        } else {
            format!("{v}")
        }
    } else {
        format!("{v:e}")
    }
}

/// Reads an integer key and checks it against its limits as it is read, so a bad value
/// (too large, negative, a float such as `1e18`, a string) is one clear message naming
/// the key, the value and the limits; `Ok(None)` is `"all"` where that is allowed.
struct Bounded {
    key: &'static str,
    lo: u64,
    hi: u64,
    /// Whether `"all"` is accepted (`points`).
    all: bool,
}

impl Bounded {
    fn expected(&self) -> String {
        let all = if self.all { "\"all\" or " } else { "" };
        format!("must be {all}an integer in [{}, {}]", self.lo, self.hi)
    }

    fn error<E: serde::de::Error>(&self, value: impl std::fmt::Display) -> E {
        E::custom(format!("`{}` = {value}: {}", self.key, self.expected()))
    }
}

impl<'de> serde::de::Visitor<'de> for Bounded {
    type Value = Option<u64>;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "`{}`: {}", self.key, self.expected())
    }

    fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Self::Value, E> {
        if (self.lo..=self.hi).contains(&v) {
            Ok(Some(v))
        } else {
            Err(self.error(v))
        }
    }

    fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Self::Value, E> {
        match u64::try_from(v) {
            Ok(v) => self.visit_u64(v),
            Err(_) => Err(self.error(v)),
        }
    }

    fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Self::Value, E> {
        Err(self.error(format!("{} (a float)", float_text(v))))
    }

    fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Self::Value, E> {
        if self.all && v == "all" {
            Ok(None)
        } else {
            Err(self.error(format!("{v:?}")))
        }
    }

    fn visit_bool<E: serde::de::Error>(self, v: bool) -> Result<Self::Value, E> {
        Err(self.error(v))
    }
}

/// An integer key with limits; `"all"` is not accepted.
fn bounded<'de, D: serde::Deserializer<'de>>(
    d: D,
    key: &'static str,
    lo: u64,
    hi: u64,
) -> Result<u64, D::Error> {
    let v = d.deserialize_any(Bounded {
        key,
        lo,
        hi,
        all: false,
    })?;
    // Unreachable with `all: false`; kept as an error rather than a panic.
    v.ok_or_else(|| serde::de::Error::custom(format!("`{key}`: \"all\" is not allowed")))
}

fn trials_key<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    bounded(d, "trials", 1, MAX_TRIALS as u64).map(|v| v as usize)
}

fn width_key<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u32, D::Error> {
    bounded(d, "sensor.width", 1, u64::from(MAX_SENSOR_SIDE)).map(|v| v as u32)
}

fn height_key<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u32, D::Error> {
    bounded(d, "sensor.height", 1, u64::from(MAX_SENSOR_SIDE)).map(|v| v as u32)
}

impl std::fmt::Display for Points {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Points::All => f.write_str("all"),
            Points::N(n) => write!(f, "{n}"),
        }
    }
}

fn default_methods() -> Vec<String> {
    vec!["c-epd".into(), "ru-epd".into(), "ml-epd".into()]
}

/// The file as written (units of the file: mm, degrees).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    #[serde(default = "crate::defaults::seed")]
    seed: u64,
    #[serde(default = "hundred", deserialize_with = "trials_key")]
    trials: usize,
    #[serde(default = "default_methods")]
    methods: Vec<String>,
    #[serde(default)]
    points: Points,
    #[serde(default)]
    timing: bool,
    #[serde(default = "default_loss")]
    loss: String,
    #[serde(default = "default_loss_scale")]
    loss_scale_m: f64,
    /// `"fixed"` (`loss_scale_m` as given) or `"auto"` (scaled to the residuals).
    #[serde(default = "default_loss_scale_mode")]
    loss_scale: String,
    /// The estimator's range gate [min, max] (m) on the model range; unset: none.
    #[serde(default)]
    range_gate_m: Option<[f64; 2]>,
    #[serde(default)]
    sensor: SensorFile,
    #[serde(default)]
    pipe: PipeFile,
    #[serde(default)]
    noise: NoiseFile,
    #[serde(default)]
    poses: PosesFile,
    sweep: Option<SweepFile>,
}

fn default_loss() -> String {
    "none".into()
}
fn default_loss_scale_mode() -> String {
    "fixed".into()
}
fn default_loss_scale() -> f64 {
    0.05
}

fn hundred() -> usize {
    100
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct SensorFile {
    #[serde(deserialize_with = "width_key")]
    width: u32,
    #[serde(deserialize_with = "height_key")]
    height: u32,
    fov_h_deg: f64,
    fov_v_deg: f64,
    min_range_m: f64,
    max_range_m: f64,
}

impl Default for SensorFile {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            fov_h_deg: 69.0,
            fov_v_deg: 51.0,
            min_range_m: 0.0,
            max_range_m: 6.0,
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct PipeFile {
    nominal_od_in: f64,
    wall_thickness_mm: f64,
    ovality: f64,
}

impl Default for PipeFile {
    fn default() -> Self {
        Self {
            nominal_od_in: crate::defaults::nominal_od_in(),
            wall_thickness_mm: crate::defaults::wall_mm(),
            ovality: crate::defaults::ovality(),
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct NoiseFile {
    model: String,
    sigma_m: f64,
    outlier_fraction: f64,
    far_outlier_fraction: f64,
    bias_b0_m: f64,
    bias_b1: f64,
}

impl Default for NoiseFile {
    fn default() -> Self {
        Self {
            model: "range".into(),
            sigma_m: 0.03,
            outlier_fraction: 0.0,
            far_outlier_fraction: 0.0,
            bias_b0_m: 0.0,
            bias_b1: 0.0,
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct PosesFile {
    roll_deg: [f64; 2],
    pitch_deg: [f64; 2],
    yaw_deg: [f64; 2],
    dy_mm: [f64; 2],
    dz_mm: [f64; 2],
    /// A fixed tilt (deg) or a range [lo, hi]; replaces pitch and yaw when set.
    tilt_deg: Option<TiltFile>,
}

/// `poses.tilt_deg`: one angle, or a range.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(untagged)]
enum TiltFile {
    Fixed(f64),
    Range([f64; 2]),
}

impl Default for PosesFile {
    fn default() -> Self {
        Self {
            roll_deg: [-180.0, 180.0],
            pitch_deg: [-5.0, 5.0],
            yaw_deg: [-5.0, 5.0],
            dy_mm: [-50.0, 50.0],
            dz_mm: [-50.0, 50.0],
            tilt_deg: None,
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepFile {
    variable: String,
    values: Vec<toml::Value>,
}

/// One fully checked setting: what a trial needs, in SI units.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    /// The sensor.
    pub sensor: Sensor,
    /// The pipe.
    pub pipe: Pipe,
    /// The depth errors.
    pub noise: Noise,
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
/// Smallest subsample (`points`): the seven parameters need seven points.
pub const MIN_POINTS: usize = 7;
/// Largest scenario file (bytes): a 10 000-value sweep takes about 60 KB.
pub const MAX_SCENARIO_BYTES: u64 = 16 << 20;
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

fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
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
        let file = std::fs::File::open(path).map_err(read_err)?;
        Self::from_reader(path, file)
    }

    /// Read and check a scenario from `reader` (standard input, say); `path` names it in
    /// errors. At most [`MAX_SCENARIO_BYTES`] are read, so `/dev/zero` is an error, not
    /// a machine out of memory.
    pub fn from_reader(path: &Path, reader: impl std::io::Read) -> Result<Self, ScenarioError> {
        use std::io::Read;
        let read_err = |source| ScenarioError::Read {
            path: path.to_path_buf(),
            source,
        };
        let mut source = String::new();
        reader
            .take(MAX_SCENARIO_BYTES + 1)
            .read_to_string(&mut source)
            .map_err(read_err)?;
        if source.len() as u64 > MAX_SCENARIO_BYTES {
            return Err(ScenarioError::TooLarge {
                path: path.to_path_buf(),
            });
        }
        Self::parse(path, &source)
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
            set_dotted(&mut t, &variable, value.clone())
                .map_err(|m| invalid("sweep.variable", m))?;
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
pub(crate) fn check_name(name: &str) -> Result<(), KeyError> {
    if name.is_empty() || name.contains(['/', '\\']) || name == "." || name == ".." {
        return Err(key_err(
            "name",
            format!("= \"{name}\": must be a plain folder name"),
        ));
    }
    Ok(())
}

/// `[sweep]`: 1 to [`MAX_SWEEP_VALUES`] values of a key that can be swept (not the run's
/// own keys: `name`, `seed`, `trials`, `methods`, `timing`, `sweep.*`).
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
    if s.variable.starts_with("sweep")
        || ["name", "seed", "trials", "methods", "timing"].contains(&s.variable.as_str())
    {
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

/// A scenario error: the key and what is wrong with it.
pub(crate) type KeyError = (String, String);

pub(crate) fn key_err(key: &str, msg: String) -> KeyError {
    (key.to_string(), msg)
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
    Ok(Setting {
        sensor,
        pipe,
        noise,
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

impl SensorFile {
    /// Degrees → radians.
    fn to_sensor(&self) -> Sensor {
        Sensor {
            width: self.width,
            height: self.height,
            fov_h: self.fov_h_deg.to_radians(),
            fov_v: self.fov_v_deg.to_radians(),
            min_range: self.min_range_m,
            max_range: self.max_range_m,
        }
    }
}

impl PipeFile {
    /// Wall thickness mm → m.
    fn to_pipe(&self) -> Pipe {
        Pipe {
            nominal_od_in: self.nominal_od_in,
            wall_thickness: self.wall_thickness_mm * 1e-3,
            ovality: self.ovality,
        }
    }
}

impl NoiseFile {
    /// The noise model by name (`range` or `isotropic`).
    fn to_noise(&self) -> Result<Noise, KeyError> {
        let model = match self.model.as_str() {
            "range" => NoiseModel::Range,
            "isotropic" => NoiseModel::Isotropic,
            other => {
                return Err(key_err(
                    "noise.model",
                    format!("= \"{other}\": must be \"range\" or \"isotropic\""),
                ));
            }
        };
        Ok(Noise {
            model,
            sigma: self.sigma_m,
            outlier_fraction: self.outlier_fraction,
            far_outlier_fraction: self.far_outlier_fraction,
            bias_b0: self.bias_b0_m,
            bias_b1: self.bias_b1,
            physics: None,
        })
    }
}

impl PosesFile {
    /// Degrees → radians, mm → m; a fixed tilt as the range [t, t].
    fn to_ranges(&self) -> PoseRanges {
        let r = |a: [f64; 2]| (a[0].to_radians(), a[1].to_radians());
        let mm = |a: [f64; 2]| (a[0] * 1e-3, a[1] * 1e-3);
        PoseRanges {
            roll: r(self.roll_deg),
            pitch: r(self.pitch_deg),
            yaw: r(self.yaw_deg),
            dy: mm(self.dy_mm),
            dz: mm(self.dz_mm),
            tilt: self.tilt_deg.map(|t| match t {
                TiltFile::Fixed(v) => r([v, v]),
                TiltFile::Range(a) => r(a),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<Scenario, ScenarioError> {
        Scenario::parse(Path::new("test.toml"), s)
    }

    #[test]
    fn full_example_parses() {
        let s = parse(
            r#"
name = "sigma_sweep"
seed = 1
trials = 100
methods = ["c-epd", "ru-epd"]
points = "all"
[sensor]
width = 640
[pipe]
nominal_od_in = 20.0
[noise]
model = "range"
sigma_m = 0.03
[poses]
roll_deg = [-180.0, 180.0]
[sweep]
variable = "noise.sigma_m"
values = [0.01, 0.02, 0.03]
"#,
        )
        .unwrap();
        assert_eq!(s.sweeps.len(), 3);
        assert_eq!(s.sweeps[1].0, "0.02");
        assert_eq!(s.sweeps[1].1.noise.sigma, 0.02);
        assert_eq!(s.sweeps[1].1.methods, vec![Method::CEpd, Method::RuEpd]);
        assert!(!s.timing);
    }

    #[test]
    fn sweeps_over_points_and_integers() {
        let s =
            parse("name = \"n\"\n[sweep]\nvariable = \"points\"\nvalues = [100, 1000, \"all\"]\n")
                .unwrap();
        assert_eq!(s.sweeps[0].1.points, Points::N(100));
        assert_eq!(s.sweeps[2].1.points, Points::All);
        assert!(s.timing);
        let s = parse(
            "name = \"n\"\n[sweep]\nvariable = \"pipe.nominal_od_in\"\nvalues = [16, 18.0]\n",
        )
        .unwrap();
        assert_eq!(s.sweeps[0].1.pipe.nominal_od_in, 16.0);
    }

    #[test]
    fn errors_name_file_and_key() {
        let e = parse("name = \"x\"\n[noise]\nsigma = 0.1\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("test.toml") && e.contains("sigma") && e.contains("line 3"),
            "{e}"
        );
        let e = parse("name = \"x\"\nfoo = 1\n").unwrap_err().to_string();
        assert!(e.contains("foo"), "{e}");
        let e = parse("name = \"x\"\n[noise]\nsigma_m = -0.1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("noise.sigma_m"), "{e}");
        let e = parse("name = \"x\"\n[sweep]\nvariable = \"noise.sigma\"\nvalues = [0.1]\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("noise.sigma") && e.contains("unknown field"),
            "{e}"
        );
        let e = parse("name = \"x\"\n[sweep]\nvariable = \"pipe.ovality\"\nvalues = [0.1, 1.5]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("pipe.ovality") && e.contains("1.5"), "{e}");
        let e = parse("name = \"x\"\nmethods = [\"d-epd\"]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("methods") && e.contains("d-epd"), "{e}");
        let e = parse("name = \"x\"\npoints = 0\n").unwrap_err().to_string();
        assert!(e.contains("points"), "{e}");
        let e = parse("name = \"x\"\n[poses]\ndy_mm = [-300.0, 300.0]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("poses.dy_mm"), "{e}");
        let e = parse("name = \"x\"\ntrials = 0\n").unwrap_err().to_string();
        assert!(e.contains("trials"), "{e}");
        let e = parse("name = \"x\"\n[sensor]\nfov_h_deg = 180.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("sensor.fov_h_deg"), "{e}");
        let e = parse("name = \"x\"\n[noise]\nmodel = \"gauss\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("noise.model"), "{e}");
    }

    #[test]
    fn limits_name_the_key_the_value_and_the_limit() {
        for (src, needles) in [
            (
                "trials = 1e18",
                &["`trials` = 1e18 (a float)", "[1, 1000000]"][..],
            ),
            ("trials = 1000001", &["`trials` = 1000001", "[1, 1000000]"]),
            ("trials = \"10\"", &["`trials` = \"10\""]),
            ("trials = true", &["`trials` = true"]),
            (
                "[sensor]\nwidth = 4097",
                &["`sensor.width` = 4097", "[1, 4096]"],
            ),
            ("[sensor]\nheight = -1", &["`sensor.height` = -1"]),
            ("points = 6", &["`points` = 6", "[7, 10000000]"]),
            ("points = 1e7", &["`points` = 10000000.0 (a float)"]),
        ] {
            let e = parse(&format!("name = \"x\"\n{src}\n"))
                .unwrap_err()
                .to_string();
            for n in needles {
                assert!(e.contains(n), "{src}: `{n}` not in {e}");
            }
        }
        let s =
            parse("name = \"x\"\ntrials = 1000000\npoints = 7\n[sensor]\nwidth = 4096\n").unwrap();
        assert_eq!(s.trials, MAX_TRIALS);
        assert!(s.check_trials("--trials", 100).is_ok());
        let e = s
            .check_trials("--trials", MAX_TRIALS + 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`--trials` = 1000001"), "{e}");
        // Three methods by default: 3 × 10^6 estimates is within 10^8, 40 values not.
        let values = vec!["0.01"; 40].join(", ");
        let e = parse(&format!(
            "name = \"x\"\ntrials = 1000000\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [{values}]\n"
        ))
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("120000000 estimates") && e.contains("100000000"),
            "{e}"
        );
    }
}
