//! The camera's noise options ([`tof_sim::CameraNoise`]) against the statistics they
//! should produce, and the frames of the options left off against the frames the
//! simulator gave before they existed.

use tof_sim::{
    Frame, FrameSeed, Noise, NoiseModel, Pipe, PoseRanges, Scene, Sensor, Subsample, ToFPhysics,
    WallModel, simulate,
};

/// FNV-1a (64-bit) over the bits of every list of a frame: equal hashes ⇔ (for practical
/// purposes) bit-identical frames.
fn frame_hash(f: &Frame) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for i in 0..f.len() {
        for k in 0..3 {
            eat(f.measured[i][k].to_bits());
            eat(f.exact[i][k].to_bits());
            eat(f.directions[i][k].to_bits());
        }
        eat(u64::from(f.pixels[i][0]) << 32 | u64::from(f.pixels[i][1]));
        eat(u64::from(f.intensity[i].to_bits()));
        eat(f.sigma[i].to_bits());
    }
    eat(f.len() as u64);
    h
}

/// The configurations whose frames must not change: (name, wall, noise, subsample).
fn golden_cases() -> Vec<(&'static str, WallModel, Noise, Subsample)> {
    vec![
        (
            "range+outliers+bias",
            WallModel::Exact,
            Noise {
                outlier_fraction: 0.05,
                far_outlier_fraction: 0.02,
                bias_b0: 0.004,
                bias_b1: 0.003,
                ..Noise::range(0.03)
            },
            Subsample::All,
        ),
        (
            "isotropic, 5000 points",
            WallModel::Exact,
            Noise {
                model: NoiseModel::Isotropic,
                ..Noise::range(0.02)
            },
            Subsample::Points(5000),
        ),
        (
            "physics",
            WallModel::Exact,
            Noise {
                physics: Some(ToFPhysics::helios2()),
                outlier_fraction: 0.01,
                ..Noise::none()
            },
            Subsample::All,
        ),
        (
            "mesh, range",
            WallModel::Mesh { segments: 256 },
            Noise::range(0.01),
            Subsample::All,
        ),
    ]
}

/// The frames of `golden_cases` for one pose and seed.
fn golden_hashes() -> Vec<(&'static str, u64)> {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 7, 3)
        .unwrap();
    let seeds = FrameSeed {
        seed: 11,
        trial: 3,
        sweep_index: 2,
    };
    golden_cases()
        .into_iter()
        .map(|(name, wall, noise, sub)| {
            let scene = Scene::new(&truth, wall, 8.0).unwrap();
            let f = simulate(&Sensor::helios2(), &scene, &noise, sub, seeds).unwrap();
            (name, frame_hash(&f))
        })
        .collect()
}

/// Recorded from the simulator before `CameraNoise` and `Contamination` existed
/// (commit b6cad14): with every new option off, the seeded streams give the same frames,
/// bit for bit.
#[test]
fn frames_with_the_new_options_off_are_unchanged() {
    let expected: [(&str, u64); 4] = [
        ("range+outliers+bias", 0x4f3f_8400_0536_df89),
        ("isotropic, 5000 points", 0x0552_5109_bc98_bf66),
        ("physics", 0x6b12_2bac_4efc_8c89),
        ("mesh, range", 0x4fcc_def3_3e8d_5e51),
    ];
    let got = golden_hashes();
    for (g, e) in got.iter().zip(expected) {
        assert_eq!(g.0, e.0);
        assert_eq!(g.1, e.1, "{}: 0x{:016x}", g.0, g.1);
    }
}
