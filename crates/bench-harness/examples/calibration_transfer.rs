//! Depth tables from one (20") and two (20" + 30") rig sizes applied to 16"–30" pipes
//! under tof-sim's Helios2 model (`bench_harness::calibration_transfer`):
//! `cargo run --release -p bench-harness --example calibration_transfer -- OUT_DIR
//! [FRAMES_PER_SIZE] [PASSES]` (default results/calibration_transfer, 5 frames per size,
//! 3 passes of the rigs' pose/table refinement as `epd calibrate --passes`).

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let out = args
        .next()
        .unwrap_or_else(|| "results/calibration_transfer".into());
    let n = match args.next() {
        Some(s) => s
            .parse::<u64>()
            .map_err(|e| anyhow::anyhow!("FRAMES_PER_SIZE {s:?}: {e}"))?,
        None => 5,
    };
    let passes = match args.next() {
        Some(s) => s
            .parse::<u32>()
            .map_err(|e| anyhow::anyhow!("PASSES {s:?}: {e}"))?,
        None => 3,
    };
    bench_harness::calibration_transfer::run(std::path::Path::new(&out), n.max(1), passes.max(1))
}
