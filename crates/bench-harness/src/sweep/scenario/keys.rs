//! A sweep scenario as written: its keys in file units (mm, degrees), read with their
//! limits ([`Points`], the bounded integers) and turned into the simulator's types.

use epd_frame::config::DEFAULT_LOSS_SCALE_M;
use serde::Deserialize;
use tof_sim::{
    CameraNoise, Contamination, Dent, FloorLayer, FlyingPixels, MultipathBand, Noise, NoiseModel,
    Obstacle, Pipe, PoseRanges, Sensor, ViewSector, Wiggle,
};

use super::{MAX_POINTS, MAX_SENSOR_SIDE, MAX_TRIALS, MIN_POINTS};
use crate::scenario::{KeyError, key_err};

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
pub(super) struct Bounded {
    pub(super) key: &'static str,
    pub(super) lo: u64,
    pub(super) hi: u64,
    /// Whether `"all"` is accepted (`points`).
    pub(super) all: bool,
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

/// `methods`: the paper's two estimators and ML-EPD.
fn default_methods() -> Vec<String> {
    vec!["c-epd".into(), "ru-epd".into(), "ml-epd".into()]
}

/// The file as written (units of the file: mm, degrees).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct File {
    pub(super) name: String,
    #[serde(default = "crate::defaults::seed")]
    pub(super) seed: u64,
    #[serde(default = "default_trials", deserialize_with = "trials_key")]
    pub(super) trials: usize,
    #[serde(default = "default_methods")]
    pub(super) methods: Vec<String>,
    #[serde(default)]
    pub(super) points: Points,
    #[serde(default)]
    pub(super) timing: bool,
    #[serde(default = "default_loss")]
    pub(super) loss: String,
    #[serde(default = "default_loss_scale")]
    pub(super) loss_scale_m: f64,
    /// `"fixed"` (`loss_scale_m` as given) or `"auto"` (scaled to the residuals).
    #[serde(default = "default_loss_scale_mode")]
    pub(super) loss_scale: String,
    /// The estimator's range gate [min, max] (m) on the model range; unset: none.
    #[serde(default)]
    pub(super) range_gate_m: Option<[f64; 2]>,
    #[serde(default)]
    pub(super) sensor: SensorFile,
    #[serde(default)]
    pub(super) pipe: PipeFile,
    #[serde(default)]
    pub(super) noise: NoiseFile,
    #[serde(default)]
    pub(super) poses: PosesFile,
    #[serde(default)]
    pub(super) contamination: ContaminationFile,
    /// `sampling = { max_points = N, method = "informed" }`: fit N chosen points of each
    /// frame (`epd estimate --max-points N --sampling METHOD`); unset or
    /// `max_points = "all"`: every point.
    #[serde(default)]
    pub(super) sampling: Option<SamplingFile>,
    /// `geometry = true`: each frame is measured as `epd estimate` measures a file, the
    /// scene ahead surveyed first (`epd_frame::measure_frame`), and the geometry it
    /// reports is recorded; unset or `false`: every point fitted as one straight pipe.
    #[serde(default)]
    pub(super) geometry: bool,
    pub(super) sweep: Option<SweepFile>,
}

/// `sampling`: how many points of each frame are fitted and how they are chosen
/// (`epd_frame::sampling`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SamplingFile {
    /// A swept value's name in the results (read from the TOML table by the sweep's
    /// `value_text`, not from here).
    #[serde(default)]
    #[allow(dead_code)]
    pub(super) label: Option<String>,
    /// The most points fitted, or `"all"`.
    #[serde(deserialize_with = "max_points_key")]
    pub(super) max_points: Option<u64>,
    /// `informed`, `stratified` or `uniform`.
    #[serde(default = "default_sampling_method")]
    pub(super) method: String,
}

/// `sampling.method`: `epd estimate`'s default.
fn default_sampling_method() -> String {
    epd_frame::sampling::SamplingMethod::default().name().into()
}

/// `sampling.max_points`: `"all"` or a count in [`epd_frame::sampling::MIN_MAX_POINTS`],
/// [`MAX_POINTS`]].
fn max_points_key<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    d.deserialize_any(Bounded {
        key: "sampling.max_points",
        lo: epd_frame::sampling::MIN_MAX_POINTS as u64,
        hi: MAX_POINTS as u64,
        all: true,
    })
}

/// `loss`: least squares, the paper's estimators.
fn default_loss() -> String {
    "none".into()
}

/// `loss_scale`: the given `loss_scale_m`, fixed.
fn default_loss_scale_mode() -> String {
    "fixed".into()
}

/// `loss_scale_m`: `epd estimate`'s ([`DEFAULT_LOSS_SCALE_M`]).
fn default_loss_scale() -> f64 {
    DEFAULT_LOSS_SCALE_M
}

/// `trials`: the paper's 100 random poses per simulated setting (§4.1).
fn default_trials() -> usize {
    100
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct SensorFile {
    #[serde(deserialize_with = "width_key")]
    pub(super) width: u32,
    #[serde(deserialize_with = "height_key")]
    pub(super) height: u32,
    pub(super) fov_h_deg: f64,
    pub(super) fov_v_deg: f64,
    pub(super) min_range_m: f64,
    pub(super) max_range_m: f64,
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
pub(super) struct PipeFile {
    pub(super) nominal_od_in: f64,
    pub(super) wall_thickness_mm: f64,
    pub(super) ovality: f64,
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
pub(super) struct NoiseFile {
    pub(super) model: String,
    pub(super) sigma_m: f64,
    pub(super) outlier_fraction: f64,
    pub(super) far_outlier_fraction: f64,
    pub(super) bias_b0_m: f64,
    pub(super) bias_b1: f64,
    /// A name for this noise model in the results (the swept value's text when the
    /// whole `noise` table is swept); not used by the simulator.
    pub(super) label: Option<String>,
    /// `[noise.camera]`: what a real ToF camera adds (tof-sim's `CameraNoise`).
    pub(super) camera: CameraFile,
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
            label: None,
            camera: CameraFile::default(),
        }
    }
}

/// `[noise.camera]`: the keys of tof-sim's `CameraNoise` (its doc states each model),
/// every one off by default.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct CameraFile {
    /// Correlation length of the range error over the pixel grid (pixels).
    pub(super) correlation_length_px: f64,
    /// σ(r) = σ·(r/r0)^p: the exponent p.
    pub(super) sigma_range_exponent: f64,
    /// r0 (m).
    pub(super) sigma_reference_range_m: f64,
    /// Wiggling a·sin(2πr/P + φ): a (m); 0 for none.
    pub(super) wiggle_amplitude_m: f64,
    /// P (m).
    pub(super) wiggle_period_m: f64,
    /// φ (degrees) when not random.
    pub(super) wiggle_phase_deg: f64,
    /// A phase drawn per frame (as a camera's modulation phase drifts).
    pub(super) wiggle_random_phase: bool,
    /// Multipath bands `[near_m, far_m, extra_m]`: rays whose true range lies in
    /// [near, far] read `extra_m` long.
    pub(super) multipath_bands: Vec<[f64; 3]>,
    /// Probability of a flying pixel at a depth edge.
    pub(super) flying_pixel_probability: f64,
}

impl Default for CameraFile {
    fn default() -> Self {
        let d = CameraNoise::default();
        let w = Wiggle::helios2();
        Self {
            correlation_length_px: d.correlation_length_px,
            sigma_range_exponent: d.sigma_range_exponent,
            sigma_reference_range_m: d.sigma_reference_range_m,
            wiggle_amplitude_m: 0.0,
            wiggle_period_m: w.period_m,
            wiggle_phase_deg: 0.0,
            wiggle_random_phase: true,
            multipath_bands: Vec::new(),
            flying_pixel_probability: 0.0,
        }
    }
}

impl CameraFile {
    /// Degrees → radians; zero amplitudes and probabilities turn their part off.
    pub(super) fn to_camera(&self) -> CameraNoise {
        CameraNoise {
            correlation_length_px: self.correlation_length_px,
            sigma_range_exponent: self.sigma_range_exponent,
            sigma_reference_range_m: self.sigma_reference_range_m,
            wiggle: (self.wiggle_amplitude_m != 0.0).then_some(Wiggle {
                amplitude_m: self.wiggle_amplitude_m,
                period_m: self.wiggle_period_m,
                phase_rad: self.wiggle_phase_deg.to_radians(),
                random_phase: self.wiggle_random_phase,
            }),
            multipath_bands: self
                .multipath_bands
                .iter()
                .map(|&[near_m, far_m, extra_m]| MultipathBand {
                    near_m,
                    far_m,
                    extra_m,
                })
                .collect(),
            flying_pixels: (self.flying_pixel_probability != 0.0)
                .then(|| FlyingPixels::new(self.flying_pixel_probability)),
        }
    }
}

/// `[contamination]`: what lies in or deforms the pipe (tof-sim's `Contamination`),
/// nothing by default.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct ContaminationFile {
    /// A name for this contamination in the results; not used by the simulator.
    pub(super) label: Option<String>,
    /// A flat layer on the floor (sediment, water): its depth (mm).
    pub(super) floor_depth_mm: Option<f64>,
    /// `{ x_m, length_m, width_m, height_mm, y_m }` (a box on the floor) or
    /// `{ x_m, radius_mm }` (a half cylinder across it).
    pub(super) obstacle: Option<ObstacleFile>,
    /// `{ x_m, clock_deg, depth_mm, axial_sigma_m, circumferential_sigma_m }`: a local
    /// inward deformation of the wall.
    pub(super) dent: Option<DentFile>,
    /// `{ start_deg, width_deg }`: the only sector of clock angles (tof-sim's
    /// `ViewSector`: from `start_deg` through `width_deg` of increasing atan2(y, z) in the
    /// PCS) in which the camera's pixels are valid, as in a half-filled pipe.
    pub(super) seen_sector: Option<SectorFile>,
}

/// `contamination.obstacle`.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields, untagged)]
pub(super) enum ObstacleFile {
    Box {
        x_m: f64,
        length_m: f64,
        width_m: f64,
        height_mm: f64,
        #[serde(default)]
        y_m: f64,
    },
    HalfCylinder {
        x_m: f64,
        radius_mm: f64,
    },
}

/// `contamination.dent`.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DentFile {
    x_m: f64,
    clock_deg: f64,
    depth_mm: f64,
    axial_sigma_m: f64,
    circumferential_sigma_m: f64,
}

/// `contamination.seen_sector`.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SectorFile {
    start_deg: f64,
    width_deg: f64,
}

impl ContaminationFile {
    /// mm → m, degrees → radians.
    pub(super) fn to_contamination(&self) -> Contamination {
        Contamination {
            floor: self
                .floor_depth_mm
                .map(|d| FloorLayer { depth_m: d * 1e-3 }),
            obstacle: self.obstacle.map(|o| match o {
                ObstacleFile::Box {
                    x_m,
                    length_m,
                    width_m,
                    height_mm,
                    y_m,
                } => Obstacle::Box {
                    x_m,
                    length_m,
                    width_m,
                    height_m: height_mm * 1e-3,
                    y_m,
                },
                ObstacleFile::HalfCylinder { x_m, radius_mm } => Obstacle::HalfCylinder {
                    x_m,
                    radius_m: radius_mm * 1e-3,
                },
            }),
            dent: self.dent.map(|d| Dent {
                x_m: d.x_m,
                clock_rad: d.clock_deg.to_radians(),
                depth_m: d.depth_mm * 1e-3,
                axial_sigma_m: d.axial_sigma_m,
                circumferential_sigma_m: d.circumferential_sigma_m,
            }),
            view: self.seen_sector.map(|v| ViewSector {
                start_rad: v.start_deg.to_radians(),
                width_rad: v.width_deg.to_radians(),
            }),
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct PosesFile {
    pub(super) roll_deg: [f64; 2],
    pub(super) pitch_deg: [f64; 2],
    pub(super) yaw_deg: [f64; 2],
    pub(super) dy_mm: [f64; 2],
    pub(super) dz_mm: [f64; 2],
    /// A fixed tilt (deg) or a range [lo, hi]; replaces pitch and yaw when set.
    pub(super) tilt_deg: Option<TiltFile>,
}

/// `poses.tilt_deg`: one angle, or a range.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum TiltFile {
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
pub(super) struct SweepFile {
    pub(super) variable: String,
    pub(super) values: Vec<toml::Value>,
}

impl SensorFile {
    /// Degrees → radians.
    pub(super) fn to_sensor(&self) -> Sensor {
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
    pub(super) fn to_pipe(&self) -> Pipe {
        Pipe {
            nominal_od_in: self.nominal_od_in,
            wall_thickness: self.wall_thickness_mm * 1e-3,
            ovality: self.ovality,
        }
    }
}

impl NoiseFile {
    /// The noise model by name (`range` or `isotropic`).
    pub(super) fn to_noise(&self) -> Result<Noise, KeyError> {
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
    pub(super) fn to_ranges(&self) -> PoseRanges {
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
