//! `--max-points N` on a binary PLY reads the records the choice looks at, not the whole
//! file (`epd_frame::measure::measure_records`, issue 25 item 2): the answer is the one
//! of the whole file read and then sampled, for every method, with invalid pixels in
//! the file, with per-point properties, and in millimetres; `n_read` is still the file's
//! points.

use epd_frame::read::read_path;
use epd_frame::sampling::SamplingMethod;
use epd_frame::{EstimateConfig, EstimateSettings, Units, measure_cloud, measure_file};
use epd_io::ply::{PlyFormat, PlyPrecision, write as write_ply};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};

/// A full frame of the paper's 20" pipe with every 13th pixel invalid (zeros, as cameras
/// write them), written as a binary PLY (float32 x y z, u, v) scaled by `scale`.
fn frame_file(dir: &std::path::Path, scale: f64) -> std::path::PathBuf {
    let pipe = Pipe {
        ovality: 0.02,
        ..Pipe::paper_20in()
    };
    let truth = PoseRanges::default().sample(&pipe, 5, 2).expect("pose");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).expect("scene");
    let mut f = tof_sim::simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.03),
        Subsample::All,
        FrameSeed::default(),
    )
    .expect("frame");
    for (i, p) in f.measured.iter_mut().enumerate() {
        *p = if i % 13 == 4 {
            [0.0; 3]
        } else {
            p.map(|v| v * scale)
        };
    }
    let mut ply = Vec::new();
    write_ply(
        &mut ply,
        &f.cloud(),
        PlyFormat::BinaryLittleEndian,
        PlyPrecision::F32,
    )
    .expect("ply");
    let path = dir.join(format!("frame_{scale}.ply"));
    std::fs::write(&path, &ply).expect("write");
    path
}

#[test]
fn the_selective_read_answers_as_the_whole_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    for (scale, units) in [(1.0, Units::Metres), (1000.0, Units::Millimetres)] {
        let path = frame_file(dir.path(), scale);
        let whole = read_path(&path).expect("read");
        let n_file = whole.points.len();
        for how in SamplingMethod::ALL {
            let mut settings = EstimateSettings {
                max_points: Some(5000),
                sampling: how,
                ..EstimateSettings::default()
            };
            settings.input.units = units;
            let cfg = EstimateConfig::new(&settings).expect("config");
            let s = cfg.sampling.expect("sampling");
            let part = epd_frame::measure::measure_records(&path, &s, &cfg)
                .expect("read by records")
                .expect("a file of fixed-size records");
            let mut cloud = whole.clone();
            epd_frame::input::to_sensor_metres(&mut cloud.points, units, cfg.input.frame)
                .expect("units");
            let full = measure_cloud(cloud, 0.0, &cfg).expect("whole file");
            assert_eq!(part.sampled, full.sampled, "{how} {units:?}");
            assert_eq!(part.sampled.map(|s| s.0), Some(5000), "{how}");
            assert_eq!(
                part.estimate.params, full.estimate.params,
                "{how} {units:?}"
            );
            assert_eq!(part.estimate.sigma, full.estimate.sigma, "{how}");
            assert_eq!(part.n_read, n_file, "{how}: n_read is the file's points");
            // measure_file takes the same path.
            let r = measure_file(&path, &cfg);
            let e = r.outcome.expect("measure_file");
            assert_eq!(e.estimate.params, full.estimate.params, "{how}");
        }
    }
}

/// More points asked for than the file holds: the file is read whole (`None`), and
/// `measure_file` answers as without `--max-points`.
#[test]
fn a_small_file_is_read_whole() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = frame_file(dir.path(), 1.0);
    let n = read_path(&path).expect("read").points.len();
    let settings = EstimateSettings {
        max_points: Some(n),
        ..EstimateSettings::default()
    };
    let cfg = EstimateConfig::new(&settings).expect("config");
    let s = cfg.sampling.expect("sampling");
    assert!(
        epd_frame::measure::measure_records(&path, &s, &cfg)
            .expect("read")
            .is_none()
    );
    let with = measure_file(&path, &cfg).outcome.expect("with");
    let without = measure_file(
        &path,
        &EstimateConfig::new(&EstimateSettings::default()).expect("cfg"),
    )
    .outcome
    .expect("without");
    assert_eq!(with.sampled, None);
    assert_eq!(with.estimate.params, without.estimate.params);
}
