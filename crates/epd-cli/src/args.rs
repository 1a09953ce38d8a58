//! The `epd` command line: every flag defined once, in clap's derive tables, and turned
//! into the frame library's settings (`epd_frame::InputConfig`, `EstimateSettings`).

use std::num::NonZeroUsize;
use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};
use epd_core::Method;
use epd_frame::read::Format;
use epd_frame::rig::MAX_TABLE_BINS;
use epd_frame::sampling::SamplingMethod;
use epd_frame::shard::ShardSpec;
use epd_frame::{InputConfig, InputFrame, Units};

/// Pipe diameters and sensor pose from 3D time-of-flight point clouds (RU-EPD, ML-EPD).
#[derive(Parser, Debug)]
#[command(
    name = "epd",
    version,
    propagate_version = true,
    subcommand_required = true,
    arg_required_else_help = false
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Estimate the pipe and the pose from point-cloud files, one result per file (per
    /// PointCloud2 message for a ROS 2 bag).
    Estimate(EstimateArgs),
    /// Build a depth-calibration table from frames recorded in a pipe of known diameter.
    Calibrate(CalibrateArgs),
    /// Simulate Helios2-like frames (PLY) with their ground truth (JSON).
    Simulate(SimulateArgs),
    /// List the topics of ROS 2 bags (MCAP) with their message types and counts.
    Topics(TopicsArgs),
    /// A profile of a run: per frame the mean diameter, ovality, geometry and status with
    /// their 1-σ, against time or distance (profile.csv, profile.png).
    Profile(ProfileArgs),
    /// One frame's points coloured by their residual over the fitted wall, unrolled
    /// (distance along the pipe × clock angle), as a PNG.
    View(ViewArgs),
}

/// The estimator, by its name in reports.
#[derive(Clone, Copy, Debug, ValueEnum)]
#[allow(clippy::enum_variant_names)] // the paper's names
pub enum MethodArg {
    /// Range residual along the sensing line (maximum likelihood; unbiased across tilt).
    #[value(name = "ml-epd")]
    MlEpd,
    /// The paper's error-based residual (eqs. 20–23).
    #[value(name = "ru-epd")]
    RuEpd,
    /// The canonical-ellipse residual (eq. 6; biased under noise).
    #[value(name = "c-epd")]
    CEpd,
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Method {
        match m {
            MethodArg::MlEpd => Method::MlEpd,
            MethodArg::RuEpd => Method::RuEpd,
            MethodArg::CEpd => Method::CEpd,
        }
    }
}

/// How results are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OutputFormat {
    /// A few lines per file, for people.
    Text,
    /// One JSON object per file and line.
    Json,
    /// A header, then one row per file.
    Csv,
}

/// The robust loss.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LossArg {
    /// Cauchy (far outliers weigh almost nothing).
    Cauchy,
    /// Huber.
    Huber,
    /// Plain least squares.
    None,
}

/// The length unit of the file.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum UnitsArg {
    /// Metres.
    M,
    /// Millimetres (the Helios2 SDK's unit).
    Mm,
}

/// The coordinate frame of the file.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FrameArg {
    /// X forward (optical axis), Y right, Z up: the paper's frame (not ROS's body frame,
    /// whose Y points left: use `body`/`flu`).
    Sensor,
    /// X right, Y down, Z forward: camera SDKs, PCL, Open3D, ROS `*_optical_frame`.
    Optical,
    /// X forward, Y left, Z up (FLU): a ROS body frame (REP 103: `base_link`,
    /// `camera_link`, a lidar's frame); alias `flu`.
    #[value(aliases = ["flu", "ros-body"])]
    Body,
}

#[derive(Args, Debug)]
pub struct EstimateArgs {
    /// Point-cloud files: PLY, PCD, CSV/XYZ/TXT/PTS; `-` reads standard input. A ROS 2 bag
    /// (an `.mcap` file, or a rosbag2 folder with its `metadata.yaml`) gives one result per
    /// `sensor_msgs/msg/PointCloud2` message of its topic (see --topic).
    #[arg(required = true, value_name = "FILE")]
    pub files: Vec<PathBuf>,
    /// The PointCloud2 topic read from each bag (other topics are skipped); without it, a
    /// bag's only PointCloud2 topic (`epd topics BAG` lists them).
    #[arg(long, value_name = "T")]
    pub topic: Option<String>,
    #[command(flatten)]
    pub fit: FitArgs,
    /// How results are written.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    pub format: OutputFormat,
    /// Write the results to FILE (atomically) instead of standard output.
    #[arg(short = 'o', long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// Worker threads, 1 ≤ N ≤ 1024 (default: all cores).
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub threads: Option<NonZeroUsize>,
    /// Process only the K-th of N parts of the files (1 ≤ K ≤ N), e.g. one task of a
    /// job array: the files are sorted by the bytes of their paths (as `LC_ALL=C ls`)
    /// and cut into N contiguous blocks whose sizes differ by at most one; shard K
    /// takes the K-th block (possibly none). Concatenating the outputs of shards 1, 2,
    /// …, N in that order gives the output of one run over the sorted list, timings
    /// (elapsed_ms, read_ms) aside; with --format csv only shard 1 writes the header
    /// line. Standard input (`-`) cannot be sharded.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<ShardSpec>,
    /// No progress bar and no summary of failures: only the results and the exit code.
    #[arg(short, long)]
    pub quiet: bool,
    /// Also write the fit where a viewer shows it: the points with their residual to the
    /// fitted wall (`residual_mm`, the range error along the ray, positive beyond the
    /// wall) and the fitted wall as a triangle mesh (elliptic cylinder over the straight
    /// section, a torus over a bend ahead), one binary PLY in the file's unit and frame
    /// (Open3D, CloudCompare, MeshLab, plyfile). One input file only.
    #[arg(long, value_name = "OUT.ply")]
    pub export_fit: Option<PathBuf>,
}

/// How each frame is fitted: the flags `epd estimate`, `epd profile` and `epd view` share.
#[derive(Args, Debug)]
pub struct FitArgs {
    /// The estimator.
    #[arg(long, value_enum, default_value_t = MethodArg::MlEpd)]
    pub method: MethodArg,
    /// Keep the points whose ray meets the fitted wall at least this far (m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub min_range: Option<f64>,
    /// Keep the points whose ray meets the fitted wall at most this far (m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub max_range: Option<f64>,
    /// Nominal outer diameter (inch): the wall thickness is estimated from it.
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub nominal_od_in: Option<f64>,
    /// Robust loss against outliers.
    #[arg(long, value_enum, default_value_t = LossArg::Cauchy)]
    pub loss: LossArg,
    /// Fixed loss scale (m of range error); without it the scale comes from the residuals.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub loss_scale: Option<f64>,
    #[command(flatten)]
    pub input: InputArgs,
    /// Depth-calibration table (JSON from `epd calibrate`): each point is moved along
    /// its ray by the table's offset at its range and intensity before the fit (the
    /// files need a per-point `intensity`).
    #[arg(long, value_name = "LUT.json")]
    pub calibration: Option<PathBuf>,
    /// With --calibration, do not weight each residual by 1/σᵢ (σᵢ: the table's spread
    /// at the point's range and intensity).
    #[arg(long)]
    pub unweighted: bool,
    /// Fit every point as one straight pipe, without looking for a bend or a tee ahead.
    /// By default the frame is surveyed first (JSON keys `geometry`, `geometry_evidence`,
    /// `straight_until_m`, `sigma_straight_until_m`, `bend_radius_mm`,
    /// `sigma_bend_radius_mm`, `bend_angle_deg`, `sigma_bend_angle_deg`, `bend_direction_deg`,
    /// `bend_withheld`): the estimate then uses
    /// the straight section's points only, and a sensor already in a bend gets no result.
    #[arg(long)]
    pub straight_only: bool,
    /// Fit at most N points of each frame (at least 1000), chosen by --sampling before
    /// the scene, the fit, the checks and the 1-σ: a frame then costs what N points cost.
    /// JSON/CSV keys `n_sampled` (the points fitted) and `sampling` (how they were chosen).
    #[arg(long, value_name = "N")]
    pub max_points: Option<usize>,
    /// How the --max-points points are chosen: `informed` (a pilot fit, then the rays of
    /// most information on the mean diameter, spread over range and clock angle),
    /// `stratified` (as many from each range × clock-angle cell) or `uniform`.
    #[arg(long, value_enum, default_value_t = SamplingArg::Informed, requires = "max_points")]
    pub sampling: SamplingArg,
}

/// How `--max-points` points are chosen (`epd_frame::sampling::SamplingMethod`).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum SamplingArg {
    /// A pilot fit, then the rays of most information on the mean diameter.
    Informed,
    /// As many points from each range × clock-angle cell.
    Stratified,
    /// Every point as likely.
    Uniform,
}

impl From<SamplingArg> for SamplingMethod {
    fn from(s: SamplingArg) -> Self {
        match s {
            SamplingArg::Informed => SamplingMethod::Informed,
            SamplingArg::Stratified => SamplingMethod::Stratified,
            SamplingArg::Uniform => SamplingMethod::Uniform,
        }
    }
}

/// How the files are read.
#[derive(Args, Debug)]
pub struct InputArgs {
    /// Length unit of the files.
    #[arg(long, value_enum, default_value_t = UnitsArg::M)]
    pub units: UnitsArg,
    /// Coordinate frame of the files [default: sensor; a bag's cloud whose frame_id ends
    /// in `_optical_frame`: optical].
    #[arg(long, value_enum, value_name = "FRAME")]
    pub frame: Option<FrameArg>,
    /// Format of standard input (ply, pcd, csv, xyz, txt, pts, asc); default: from its
    /// first bytes.
    #[arg(long, value_name = "FORMAT")]
    pub input_format: Option<Format>,
}

#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// Frames recorded in a pipe of known diameter (PLY, PCD, CSV… with a per-point
    /// `intensity`).
    #[arg(required_unless_present = "rigs", value_name = "FILE")]
    pub files: Vec<PathBuf>,
    /// The known inner diameter (mm); the major one when --known-dmin-mm is given.
    #[arg(
        long,
        value_name = "D",
        allow_negative_numbers = true,
        required_unless_present = "rigs"
    )]
    pub known_id_mm: Option<f64>,
    /// The known minor inner diameter (mm) of an oval pipe.
    #[arg(long, value_name = "D2", allow_negative_numbers = true)]
    pub known_dmin_mm: Option<f64>,
    /// Rigs of several pipe sizes: a TOML file of `[[rig]]` tables, each with
    /// `known_id_mm = D` (and optionally `known_dmin_mm`) and `files = ["…", …]` (paths
    /// relative to the TOML file), in place of FILE… and --known-id-mm.
    #[arg(long, value_name = "RIGS.toml", conflicts_with_all = ["files", "known_id_mm", "known_dmin_mm"])]
    pub rigs: Option<PathBuf>,
    /// Where the table is written (JSON, atomically).
    #[arg(long, value_name = "LUT.json")]
    pub out: PathBuf,
    /// Use the points whose ray meets the known wall at least this far (m).
    #[arg(
        long,
        value_name = "M",
        default_value_t = 0.5,
        allow_negative_numbers = true
    )]
    pub min_range: f64,
    /// Use the points whose ray meets the known wall at most this far (m).
    #[arg(
        long,
        value_name = "M",
        default_value_t = 2.0,
        allow_negative_numbers = true
    )]
    pub max_range: f64,
    /// Range bins of the table (range × intensity bins at most 2²⁰ = 1048576).
    #[arg(long, value_name = "N", default_value_t = 30, value_parser = table_bins)]
    pub range_bins: usize,
    /// Intensity bins of the table (even in log-intensity).
    #[arg(long, value_name = "N", default_value_t = 12, value_parser = table_bins)]
    pub intensity_bins: usize,
    /// Incidence bins of the table (even in ln cos θ of the angle between the ray and the
    /// fitted wall's normal); 0: a range × intensity table alone (version-1 behaviour).
    #[arg(long, value_name = "N", default_value_t = 16)]
    pub incidence_bins: usize,
    /// A bin with fewer points (at least 5) is empty: outside the incidence table's
    /// support (its points are not corrected) unless it lies between two rigs' bins of
    /// its range, which bridge it; in a range × intensity table it takes the nearest
    /// filled bin's values.
    #[arg(long, value_name = "N", default_value_t = 30)]
    pub min_count: usize,
    /// Passes of the alternating refinement of the poses and the table (1: the poses
    /// fitted once on the raw points).
    #[arg(long, value_name = "N", default_value_t = epd_frame::rig::DEFAULT_PASSES,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(epd_frame::rig::MAX_PASSES)))]
    pub passes: u32,
    #[command(flatten)]
    pub input: InputArgs,
    /// Worker threads, 1 ≤ N ≤ 1024 (default: all cores).
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub threads: Option<NonZeroUsize>,
    /// Only errors.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct ProfileArgs {
    /// A ROS 2 bag (an `.mcap` file or a rosbag2 folder), or point-cloud files in the
    /// order of the run (PLY, PCD, CSV…); several bags are read one after the other.
    #[arg(required = true, value_name = "FILE")]
    pub files: Vec<PathBuf>,
    /// The PointCloud2 topic of the bags (without it, a bag's only PointCloud2 topic).
    #[arg(long, value_name = "T")]
    pub topic: Option<String>,
    /// Folder for profile.csv and profile.png (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// A `nav_msgs/msg/Odometry` topic of the bag: the profile is drawn against the
    /// distance travelled (the path length of its positions, interpolated at each
    /// cloud's stamp).
    #[arg(long, value_name = "TOPIC", conflicts_with = "speed")]
    pub odometry_topic: Option<String>,
    /// A constant speed (m/s): the profile is drawn against the distance speed × the time
    /// since the topic's first message.
    #[arg(long, value_name = "M_PER_S", allow_negative_numbers = true)]
    pub speed: Option<f64>,
    #[command(flatten)]
    pub fit: FitArgs,
    /// Process only the K-th of N contiguous blocks of the run's frames (a bag's
    /// messages, then the files in the order given; 1 ≤ K ≤ N): profile.csv of shard 1
    /// has the header line, those of shards 2…N not, so that concatenating them in order
    /// gives the whole run's table; each shard draws its own profile.png.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<ShardSpec>,
    /// Worker threads, 1 ≤ N ≤ 1024 (default: all cores).
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub threads: Option<NonZeroUsize>,
    /// No progress bar, no summary.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// One point-cloud file (PLY, PCD, CSV…).
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// Where the picture is written (PNG).
    #[arg(long, value_name = "frame.png")]
    pub out: PathBuf,
    /// The colour scale's limit (mm): residuals from −L to +L; default: 3 × the frame's
    /// RMS residual.
    #[arg(long, value_name = "L")]
    pub limit_mm: Option<f64>,
    #[command(flatten)]
    pub fit: FitArgs,
}

#[derive(Args, Debug)]
pub struct TopicsArgs {
    /// ROS 2 bags: `.mcap` files or rosbag2 folders (with `metadata.yaml`).
    #[arg(required = true, value_name = "BAG")]
    pub bags: Vec<PathBuf>,
}

#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Folder for frame_KKKK.ply and frame_KKKK.json.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 1)]
    pub frames: u64,
    /// Seed of the poses and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Standard deviation of the depth noise (m).
    #[arg(long, default_value_t = 0.03, allow_negative_numbers = true)]
    pub sigma: f64,
    /// Nominal outer diameter (inch).
    #[arg(long, default_value_t = 20.0, allow_negative_numbers = true)]
    pub od_in: f64,
    /// Ovality (Dmax − Dmin)/ID.
    #[arg(long, default_value_t = 0.02, allow_negative_numbers = true)]
    pub ovality: f64,
    /// Wall thickness (mm).
    #[arg(long, default_value_t = 12.0, allow_negative_numbers = true)]
    pub wall_mm: f64,
    /// Keep a uniform subsample of N points (default: all).
    #[arg(long, value_name = "N")]
    pub points: Option<NonZeroUsize>,
    /// Fraction of range outliers.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub outliers: f64,
    /// Noise model.
    #[arg(long, value_enum, default_value_t = NoiseArg::Range)]
    pub noise: NoiseArg,
    /// Error model of the camera: `plain` (range noise of --sigma) or `helios2` (the
    /// realistic model: amplitude-dependent noise, invalid pixels written as zeros,
    /// wiggling, intensity offset, multipath; the PLY gets an `intensity` property;
    /// --sigma and --noise do not apply).
    #[arg(long, value_enum, default_value_t = SensorArg::Plain)]
    pub sensor: SensorArg,
    /// A 90° long-radius elbow (radius 1.5 × the inner diameter) starting M metres ahead
    /// of the sensor along the pipe; the truth JSON then has `geometry` (`bend_ahead`)
    /// and `straight_until_m`.
    #[arg(
        long,
        value_name = "M",
        allow_negative_numbers = true,
        conflicts_with = "tee_at"
    )]
    pub bend_at: Option<f64>,
    /// A tee whose branch (0.6 × the inner diameter) opens M metres ahead of the sensor
    /// along the pipe; the truth JSON then has `geometry` (`tee_ahead`) and
    /// `straight_until_m`.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub tee_at: Option<f64>,
    /// PLY encoding.
    #[arg(long, value_enum, default_value_t = PlyArg::Binary)]
    pub ply: PlyArg,
    /// PLY coordinate precision.
    #[arg(long, value_enum, default_value_t = PrecisionArg::F64)]
    pub precision: PrecisionArg,
}

/// Depth-noise model of `simulate`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum NoiseArg {
    /// Along the sensing line.
    Range,
    /// In no particular direction.
    Isotropic,
}

/// Camera error model of `simulate`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SensorArg {
    /// Range noise of constant σ.
    Plain,
    /// tof_sim's realistic Helios2 (6 m mode) model.
    Helios2,
}

/// PLY encoding of `simulate`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum PlyArg {
    /// binary_little_endian.
    Binary,
    /// ascii.
    Ascii,
}

/// PLY precision of `simulate`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum PrecisionArg {
    /// double.
    #[value(alias = "double")]
    F64,
    /// float.
    #[value(alias = "float")]
    F32,
}

/// The input settings as the library takes them.
impl From<&InputArgs> for InputConfig {
    fn from(a: &InputArgs) -> Self {
        Self {
            units: match a.units {
                UnitsArg::M => Units::Metres,
                UnitsArg::Mm => Units::Millimetres,
            },
            frame: match a.frame.unwrap_or(FrameArg::Sensor) {
                FrameArg::Sensor => InputFrame::Sensor,
                FrameArg::Optical => InputFrame::Optical,
                FrameArg::Body => InputFrame::Body,
            },
            frame_given: a.frame.is_some(),
            format: a.input_format,
        }
    }
}

/// A number of table bins: a whole number in [1, [`MAX_TABLE_BINS`]] (the most a table may
/// have in all), checked as it is parsed, so that no product of two of them can overflow.
fn table_bins(s: &str) -> Result<usize, String> {
    let n: u64 = s
        .parse()
        .map_err(|_| format!("expected a whole number of bins in [1, {MAX_TABLE_BINS}]"))?;
    match usize::try_from(n) {
        Ok(n) if (1..=MAX_TABLE_BINS).contains(&n) => Ok(n),
        _ => Err(format!(
            "{n} bins: expected 1 to {MAX_TABLE_BINS} (2²⁰, the most bins a table may have)"
        )),
    }
}

/// Most worker threads (`--threads`), as bench-harness allows: each worker holds a frame's
/// buffers (about 25 MB for a full 640 × 480 frame), so 1024 of them already fill a large
/// node's memory, and beyond the cores more only costs their start (100 000 took minutes).
pub const MAX_THREADS: usize = 1024;

/// `--threads N`: 1 ≤ N ≤ [`MAX_THREADS`].
fn parse_threads(s: &str) -> Result<NonZeroUsize, String> {
    let n: NonZeroUsize = s
        .parse()
        .map_err(|e| format!("`{s}` is not a whole number of at least 1 ({e})"))?;
    if n.get() > MAX_THREADS {
        return Err(format!("{n} threads: at most {MAX_THREADS}"));
    }
    Ok(n)
}
