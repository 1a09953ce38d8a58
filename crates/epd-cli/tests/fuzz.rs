//! The three readers on random and mutated bytes: an error or a cloud, never a panic.

mod common;

use epd_cli::read::{Format, read_bytes};
use proptest::prelude::*;
use tof_sim::output::{PlyFormat, PlyPrecision, write_ply};

fn seeds() -> &'static [(Format, Vec<u8>)] {
    static SEEDS: std::sync::OnceLock<Vec<(Format, Vec<u8>)>> = std::sync::OnceLock::new();
    SEEDS.get_or_init(make_seeds)
}

fn make_seeds() -> Vec<(Format, Vec<u8>)> {
    let frame = common::frame(0, 50);
    let mut v = Vec::new();
    for (f, p) in [
        (PlyFormat::BinaryLittleEndian, PlyPrecision::F64),
        (PlyFormat::Ascii, PlyPrecision::F32),
    ] {
        let mut b = Vec::new();
        write_ply(&mut b, &frame, f, p).unwrap();
        v.push((Format::Ply, b));
    }
    for d in ["ascii", "binary", "binary_compressed"] {
        v.push((Format::Pcd, common::pcd(&frame, d)));
    }
    v.push((Format::Text, common::xyz(&frame)));
    v
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, .. ProptestConfig::default() })]

    #[test]
    fn random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..600), f in 0usize..3) {
        let format = [Format::Ply, Format::Pcd, Format::Text][f];
        let _ = read_bytes(format, &bytes);
        // Random bytes behind a valid-looking header too.
        let mut b = match format {
            Format::Ply => b"ply\nformat binary_little_endian 1.0\nelement vertex 20\nproperty double x\nproperty double y\nproperty double z\nend_header\n".to_vec(),
            Format::Pcd => b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 20\nHEIGHT 1\nPOINTS 20\nDATA binary_compressed\n".to_vec(),
            Format::Text => b"x y z\n".to_vec(),
        };
        b.extend(&bytes);
        let _ = read_bytes(format, &b);
    }

    #[test]
    fn mutated_files(which in 0usize..6, edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..8)) {
        let (format, mut b) = seeds()[which].clone();
        for (idx, byte, kind) in edits {
            if b.is_empty() { break; }
            let i = idx.index(b.len());
            match kind {
                0 => b[i] = byte,
                1 => { b.truncate(i); }
                _ => { b.insert(i, byte); }
            }
        }
        if let Ok(cloud) = read_bytes(format, &b) {
            prop_assert!(cloud.extra.iter().all(|(_, v)| v.len() == cloud.points.len()));
        }
    }
}
