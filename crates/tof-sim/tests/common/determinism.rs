//! Frames compared bit for bit: the same for one and two threads, and a function of the
//! seeds.

#![allow(dead_code)]

use tof_sim::Frame;

/// Every number of a frame, as bits (NaN compares equal to itself): per point its
/// measured and exact position, its direction, its pixel, its intensity and its σ.
pub fn bits(f: &Frame) -> Vec<u64> {
    let mut v = Vec::new();
    for i in 0..f.len() {
        v.extend(f.measured[i].map(f64::to_bits));
        v.extend(f.exact[i].map(f64::to_bits));
        v.extend(f.directions[i].map(f64::to_bits));
        v.extend(f.pixels[i].map(u64::from));
        v.push(f.intensity[i].to_bits() as u64);
        v.push(f.sigma[i].to_bits());
    }
    v
}

/// `f` run in a pool of `threads` threads: the simulator's parallel loops inside it use
/// that many.
pub fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}
