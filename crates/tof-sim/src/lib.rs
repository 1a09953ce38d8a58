//! A Helios2-like 3D time-of-flight camera inside an elliptic pipe: rays cast with
//! parry3d, Gaussian depth errors along the sensing lines, reproducible to the bit.
//!
//! Frames (README, Conventions): the SCS (sensor: X forward, Y right, Z up) and the PCS (pipe: X
//! along the axis, Y major axis, Z minor axis), related by eq. (3) of the RU-EPD paper
//! through [`epd_core::Params`] — the one definition of the convention in the workspace.
//!
//! [`Pipeline`] (module [`pipeline`]) chains straights, bends (tori) and tees in the PCS
//! of the first straight; [`Scene::pipeline`] casts against its labelled mesh, and the
//! frames then carry what each pixel hit ([`Frame::part`]) with the exact geometry as
//! ground truth ([`Pipeline::straight_until`], [`Pipeline::bends`], [`Pipeline::frames`]).
//!
//! [`ToFPhysics`] (optional, `Noise::physics`) adds a physical sensor model: amplitude
//! ρ·cos θ/r², Lange's amplitude-dependent range noise, dark and saturated pixels written
//! as zeros, wiggling, intensity-related offset and multipath, and a per-point intensity.
//!
//! [`Frame::cloud`] (module [`export`]) hands a frame to the writers of `epd-io` (PLY, the
//! depth image); [`settings`] holds what `epd simulate` and `epd.simulate` do for a frame.
//!
//! [`CameraNoise`] (module [`camera`], through [`simulate_with`]) adds what a camera does
//! beyond that: range errors correlated over the pixel grid, a range-dependent σ,
//! wiggling of a given period and phase (random per frame if asked), multipath bands and
//! flying pixels at depth edges. [`Contamination`] (module [`contamination`], through
//! [`Scene::with_contamination`]) puts a floor layer, an obstacle and a dent in a
//! straight pipe, and limits the view to a sector of clock angles. Every one of them is
//! off by default, and frames with them off are bit-identical to the frames before they
//! existed.
//!
//! ```
//! use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate};
//! let sensor = Sensor::helios2();
//! let pipe = Pipe::paper_20in();
//! let truth = PoseRanges::default().sample(&pipe, 1, 0)?;
//! let scene = Scene::new(&truth, WallModel::Exact, sensor.max_range)?;
//! let frame = simulate(&sensor, &scene, &Noise::range(0.03), Subsample::Points(1000), FrameSeed::default())?;
//! assert_eq!(frame.measured.len(), 1000);
//!
//! // Sediment 5 cm deep, correlated noise (ℓ = 2 px) and flying pixels.
//! use tof_sim::{CameraNoise, Contamination, FloorLayer, FlyingPixels, simulate_with};
//! let dirty = Scene::new(&truth, WallModel::Exact, sensor.max_range)?
//!     .with_contamination(Contamination {
//!         floor: Some(FloorLayer { depth_m: 0.05 }),
//!         ..Contamination::default()
//!     })?;
//! let camera = CameraNoise {
//!     correlation_length_px: 2.0,
//!     flying_pixels: Some(FlyingPixels::new(0.2)),
//!     ..CameraNoise::default()
//! };
//! let frame = simulate_with(&sensor, &dirty, &Noise::range(0.01), &camera, Subsample::All, FrameSeed::default())?;
//! assert!(frame.len() > 300_000);
//! # Ok::<(), tof_sim::SimError>(())
//! ```
#![deny(missing_docs)]

pub mod camera;
pub mod contamination;
pub mod elliptic_cylinder;
pub mod error;
pub mod export;
pub mod frame;
pub mod mesh;
pub mod noise;
pub mod physics;
pub mod pipe;
pub mod pipeline;
pub mod pose;
pub mod scene;
pub mod sensor;
pub mod settings;

pub use camera::{CameraNoise, FlyingPixels, MultipathBand, Wiggle};
pub use contamination::{Contamination, Dent, FloorLayer, Obstacle, ViewSector};
pub use elliptic_cylinder::EllipticCylinder;
pub use error::SimError;
pub use frame::{
    Frame, FrameSeed, Subsample, simulate, simulate_into, simulate_into_with, simulate_with,
};
pub use noise::{Noise, NoiseModel};
pub use physics::ToFPhysics;
pub use pipe::Pipe;
pub use pipeline::{
    BendTruth, BranchTruth, LabeledMesh, MeshResolution, Part, PartKind, Pipeline, Segment,
    SegmentFrame,
};
pub use pose::PoseRanges;
pub use scene::{Scene, WallModel};
pub use sensor::Sensor;
