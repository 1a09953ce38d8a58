//! The points of a frame that carry the information (`epd estimate --max-points N`): N
//! of a frame's points chosen before the scene, the fit, the checks and the 1-σ, so that a
//! frame costs what N points cost (issue 25, the paper's future work 2).
//!
//! Three ways to choose ([`SamplingMethod`]):
//! - **uniform**: N of the valid points, each as likely as any other;
//! - **stratified**: the same number from each cell of ray geometry ([`strata`]: clock
//!   angle around the optical axis × how far the ray travels per metre of radius), so
//!   the few far rays, which carry much of the information on the diameters, are not
//!   left out as a uniform sample leaves them;
//! - **informed** (the default): a pilot fit on a small uniform sample
//!   ([`PILOT_POINTS`]), then the points whose rays carry the most information on the
//!   mean diameter at the pilot's β (their influence (gᵢ·M⁻¹c)², gᵢ the gradient of the
//!   range residual, M = Σ gᵢgᵢᵀ, c the mean diameter's gradient), with a stratified
//!   floor ([`INFORMED_FLOOR`]) so that every parameter, roll included, stays determined.
//!
//! **Why the choice biases nothing.** A subset chosen without looking at the points' own
//! noise is fitted like any frame with fewer pixels: the estimate stays the maximum
//! likelihood on those points. The choice here looks at each point's *ray*, not at its
//! measured range: the range residual is r = ‖p‖ − ρ(d; β), with ρ the model's range
//! along the ray's direction d = p/‖p‖, so its gradient −∂ρ/∂β depends on d alone (the
//! pixel), not on where along the ray the noise put the point; the strata are made of
//! directions too. The residual itself (which carries the noise) is never looked at. Two
//! weak links remain and are small: the pilot's β is fitted on noisy points (of which at
//! most [`PILOT_POINTS`] may be chosen again: its error moves every score smoothly, not
//! one point's), and noise across the ray (isotropic noise, flying pixels) moves d by
//! σ/range, a fraction of a pixel.
//!
//! The choice is deterministic for a seed ([`Sampling::seed`]): the same frame and seed
//! give the same points, whatever the number of threads.
//!
//! **Reading only what is used.** The choice reads a frame's points by index
//! ([`Records`]; [`choose_from`]): the stratified and informed choices look only at the
//! first point of each block of [`BLOCK`] consecutive points, then read the blocks they
//! choose; the uniform choice reads the points it draws. From a binary PLY or PCD
//! (`epd_io::records`) the rest of the file is never decoded
//! (`crate::measure::measure_records`); from memory ([`choose`]) the same points are
//! chosen.

use std::fmt;
use std::str::FromStr;

use epd_core::residual::{Geometry, Residual};
use epd_core::{EstimateOptions, Method, N_PARAMS, Params, estimate};
use nalgebra::{SMatrix, SVector};

mod witness;
pub use witness::{WITNESS_ALPHA, Witness};

/// How the points are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum SamplingMethod {
    /// Every valid point equally likely.
    Uniform,
    /// The same number from each cell of ray geometry ([`strata`]).
    Stratified,
    /// By their information on the mean diameter at a pilot fit, with a stratified floor.
    #[default]
    Informed,
}

impl SamplingMethod {
    /// All methods, in the order of the figure.
    pub const ALL: [SamplingMethod; 3] = [Self::Uniform, Self::Stratified, Self::Informed];

    /// The name on command lines, in scenario files and reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Uniform => "uniform",
            Self::Stratified => "stratified",
            Self::Informed => "informed",
        }
    }
}

impl fmt::Display for SamplingMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SamplingMethod {
    type Err = SamplingError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| SamplingError::Method(s.to_string()))
    }
}

/// Why a sampling setting cannot be used.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SamplingError {
    /// Too few points asked for.
    #[error(
        "--max-points {0}: need at least {MIN_MAX_POINTS} points (the scene's survey and the \
         1-σ's {CELLS} wall cells need tens of points each); omit it to use every point"
    )]
    TooFew(usize),
    /// An unknown method name.
    #[error("sampling method `{0}`: expected one of uniform, stratified, informed")]
    Method(String),
}

/// The cells of the cluster-robust 1-σ (`epd_core::estimate`: 12 clock sectors × 8 axial
/// bins), named in [`SamplingError::TooFew`].
const CELLS: usize = epd_core::estimate::CLOCK_SECTORS * epd_core::estimate::AXIAL_CELLS;

/// The fewest points `--max-points` may ask for: 1000, about ten per wall cell of the 1-σ
/// (`CELLS` = 96 cells; the cluster jackknife needs a spread within each) and enough
/// for the scene's survey to find a bend's points among them.
pub const MIN_MAX_POINTS: usize = 1000;

/// Points of the pilot fit of the informed choice: 1024 uniform points (of the blocks'
/// first points, themselves one point in [`BLOCK`]). The pilot only orients the scores,
/// which depend smoothly on β: with 1024 of a 20" frame's ~306 000 points its 1-σ is
/// √(306 000/1024) ≈ 17 × the full frame's (mean diameter: ≈ 0.55 mm against 0.032 mm
/// measured at σ = 0.03 m, `results/realtime`), i.e. β within ~0.1 % of the diameter
/// and a fraction of a degree — a change of the scores far below their spread between
/// rays (orders of magnitude). Measured (`cargo run --release -p epd-frame --example
/// sampling informed`, 6 frames, N = 20 000, blocks of 8): the informed choice's
/// mean-diameter bound is 1.438 × the full frame's with a pilot of 2048, 1024 or 512
/// points (1.439 × with 512); the pilot's fit costs ≈ 2.1 ms with 2048 points and
/// ≈ 1.4 ms with 1024 on one core (its checks and 1-σ included); 1024 keeps a margin
/// of points for the fit's checks (96 wall cells of the 1-σ, ~10 points each).
pub const PILOT_POINTS: usize = 1024;

/// The share of N the informed choice spreads evenly over the strata before it picks by
/// influence: 1/4. The mean diameter's influence concentrates on the far rays; the roll
/// and the offsets need rays all around and near too. With a quarter of N in the
/// [`CLOCK_BINS`] × [`REACH_BINS`] cells every parameter's bound stays below that of a
/// uniform sample of N (0.3–0.7 × over six poses; the test
/// `every_parameter_stays_determined` requires < 1.25 ×), and the mean diameter's is
/// 1.44 × the full frame's at N = 20 000 (`cargo run --release -p epd-frame --example
/// sampling`); a floor of 1/10 gave 1.43 ×, so the floor costs the mean diameter little.
pub const INFORMED_FLOOR: f64 = 0.25;

/// Clock-angle sectors of the strata (around the optical axis): 12 of 30°, as the
/// 1-σ's cells (`epd_core::estimate::CLOCK_SECTORS`).
pub const CLOCK_BINS: usize = 12;

/// Bins of a ray's reach ‖p‖/√(y² + z²) (metres along the ray per metre off the axis,
/// ≈ 1/sin of the angle off the axis) in the strata: 8, equal in log(reach) between the
/// frame's smallest and largest, so the far rays (the last bins, about 1 % of a frame's
/// points) get as many points as the near ones.
pub const REACH_BINS: usize = 8;

/// The default seed of the choice.
pub const DEFAULT_SEED: u64 = 0x005E_ED25;

/// How many points, and how they are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sampling {
    /// The most points kept.
    pub max_points: usize,
    /// How they are chosen.
    pub method: SamplingMethod,
    /// The seed of the random choices (the pilot's points, the points within a stratum).
    pub seed: u64,
}

impl Sampling {
    /// At most `max_points` points chosen by `method` (seed [`DEFAULT_SEED`]); at least
    /// [`MIN_MAX_POINTS`].
    pub fn new(max_points: usize, method: SamplingMethod) -> Result<Self, SamplingError> {
        if max_points < MIN_MAX_POINTS {
            return Err(SamplingError::TooFew(max_points));
        }
        Ok(Self {
            max_points,
            method,
            seed: DEFAULT_SEED,
        })
    }

    /// The same with another seed.
    pub fn with_seed(self, seed: u64) -> Self {
        Self { seed, ..self }
    }
}

/// The points chosen from a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Chosen {
    /// Their indices in the frame, ascending.
    pub indices: Vec<usize>,
    /// The method that chose them: the one asked for, or `stratified` when the informed
    /// choice's pilot fit failed (a frame the straight model does not fit).
    pub method: SamplingMethod,
    /// The informed choice's pilot fit (β of [`PILOT_POINTS`] of the frame's points),
    /// a start for the fit of the chosen points
    /// (`epd_core::EstimateOptions::with_start`); `None` for the other methods.
    pub pilot: Option<Params>,
    /// The pilot's mean diameter and its 1-σ, against which the fit of the chosen points
    /// is checked ([`Witness`]); `None` for the other methods or without a 1-σ.
    pub witness: Option<Witness>,
}

/// Choose the points of `points` (SCS, m) to fit. `None` when every valid point is kept
/// (no more valid points than `max_points`): then the frame is used whole. Invalid points
/// (non-finite, at the origin) are never chosen. The informed choice's pilot is fitted
/// with `method` and `options` (its range gate included). The same choice as
/// [`choose_from`] of the same points read from a file.
pub fn choose(
    points: &[[f64; 3]],
    sampling: &Sampling,
    method: Method,
    options: &EstimateOptions,
) -> Option<Chosen> {
    if points.iter().filter(|p| usable(p)).count() <= sampling.max_points {
        return None;
    }
    // Reading from memory cannot fail.
    choose_from(&mut InMemory(points), sampling, method, options)
        .ok()
        .flatten()
}

/// A frame's points by index, as the choice reads them: the whole frame in memory
/// ([`InMemory`]), or the fixed-size records of a file read on demand, so that a file's
/// points the choice leaves out are never decoded (`epd_io::records`).
pub trait Records {
    /// Number of points, valid or not.
    fn len(&self) -> usize;
    /// Whether there are none.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The points (SCS, m) of `indices` (strictly ascending, each below
    /// [`len`](Self::len)), in that order.
    fn points(&mut self, indices: &[u32]) -> Result<Vec<[f64; 3]>, String>;
}

/// A frame's points held in memory.
#[derive(Clone, Copy, Debug)]
pub struct InMemory<'a>(pub &'a [[f64; 3]]);

impl Records for InMemory<'_> {
    fn len(&self) -> usize {
        self.0.len()
    }

    fn points(&mut self, indices: &[u32]) -> Result<Vec<[f64; 3]>, String> {
        indices
            .iter()
            .map(|&i| {
                self.0
                    .get(i as usize)
                    .copied()
                    .ok_or_else(|| format!("point {i} asked for of {}", self.0.len()))
            })
            .collect()
    }
}

/// [`choose`] from points read by index ([`Records`]): only the points the choice looks
/// at are read — for the stratified and informed choices the first point of every block
/// of [`BLOCK`] (its ray classifies and scores the block), then the chosen blocks; for
/// the uniform choice the chosen points alone. `Ok(None)` when there are no more points
/// than `max_points`, or too few valid ones to choose `max_points` of: then the frame is
/// used whole. The error is a read's.
pub fn choose_from<R: Records + ?Sized>(
    records: &mut R,
    sampling: &Sampling,
    method: Method,
    options: &EstimateOptions,
) -> Result<Option<Chosen>, String> {
    let k = sampling.max_points;
    if records.len() <= k {
        return Ok(None);
    }
    let mut rng = SplitMix(sampling.seed);
    let (chosen, used, pilot) = match sampling.method {
        SamplingMethod::Uniform => (
            uniform_records(records, k, &mut rng)?,
            SamplingMethod::Uniform,
            None,
        ),
        how => {
            let heads = Heads::read(records)?;
            let informed = if how == SamplingMethod::Informed {
                informed(&heads, k, method, options, &mut rng)
            } else {
                None
            };
            match informed {
                Some((order, pilot)) => (
                    fill(records, &heads, order, k)?,
                    SamplingMethod::Informed,
                    Some(pilot),
                ),
                None => (
                    fill(records, &heads, stratified(&heads, k, &mut rng), k)?,
                    SamplingMethod::Stratified,
                    None,
                ),
            }
        }
    };
    let Some(mut chosen) = chosen else {
        return Ok(None);
    };
    chosen.sort_unstable();
    Ok(Some(Chosen {
        indices: chosen.into_iter().map(|i| i as usize).collect(),
        method: used,
        pilot: pilot.map(|p: Pilot| p.params),
        witness: pilot.and_then(|p| p.witness),
    }))
}

/// Finite and away from the origin, as `epd_core::cloud::clean` keeps them.
fn usable(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0)
}

/// A small deterministic generator (SplitMix64, Steele et al. 2014): fast, seedable,
/// and the same on every platform.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n > 0), by Lemire's multiply-shift (bias below 2⁻³² for the
    /// sizes of a frame).
    fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next()) * n as u128) >> 64) as usize
    }
}

/// `k` of `pool` (without repetition), by a partial Fisher–Yates shuffle.
fn uniform(pool: &[u32], k: usize, rng: &mut SplitMix) -> Vec<u32> {
    let mut v = pool.to_vec();
    let k = k.min(v.len());
    for i in 0..k {
        let j = i + rng.below(v.len() - i);
        v.swap(i, j);
    }
    v.truncate(k);
    v
}

/// The stratum of each of the `valid` points (an index below [`CLOCK_BINS`] ×
/// [`REACH_BINS`]): its ray's clock angle around the optical axis in [`CLOCK_BINS`]
/// sectors of 30°, and its reach ‖p‖/√(y² + z²) in [`REACH_BINS`] bins equal in
/// log(reach) between the frame's extremes. Both are functions of the ray's direction
/// alone. Computed without a transcendental function per point (a frame has 300 000):
/// the sector by comparing |z| with tan 30°·|y| and tan 60°·|y|, the reach bin by
/// comparing x²/(y² + z²) = reach² − 1 with the bins' edges.
pub fn strata(points: &[[f64; 3]], valid: &[u32]) -> Vec<u16> {
    const TAN_30: f64 = 0.577_350_269_189_625_8;
    const TAN_60: f64 = 1.732_050_807_568_877_2;
    let q: Vec<f64> = valid
        .iter()
        .map(|&i| {
            let p = &points[i as usize];
            let off2 = p[1] * p[1] + p[2] * p[2];
            // A ray along the axis reaches infinitely far: the last bin.
            if off2 > 0.0 {
                p[0] * p[0] / off2
            } else {
                f64::INFINITY
            }
        })
        .collect();
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for &v in q.iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    // Edges equal in log(reach), reach = √(1 + q), as values of q.
    let (llo, lhi) = ((1.0 + lo).ln() / 2.0, (1.0 + hi).ln() / 2.0);
    let edges: Vec<f64> = (1..REACH_BINS)
        .map(|b| (2.0 * (llo + (lhi - llo) * b as f64 / REACH_BINS as f64)).exp() - 1.0)
        .collect();
    valid
        .iter()
        .zip(&q)
        .map(|(&i, &qi)| {
            let p = &points[i as usize];
            let (ay, az) = (p[1].abs(), p[2].abs());
            // Sector within the quadrant (0: |angle from the ±y axis| < 30°, …).
            let within = usize::from(az >= TAN_30 * ay) + usize::from(az >= TAN_60 * ay);
            let sector = match (p[1] >= 0.0, p[2] >= 0.0) {
                (true, true) => within,
                (false, true) => 5 - within,
                (false, false) => 6 + within,
                (true, false) => 11 - within,
            };
            let bin = edges.partition_point(|&e| e <= qi);
            (sector * REACH_BINS + bin) as u16
        })
        .collect()
}

/// How many of `k` points each stratum of `sizes` gets: the same share for every
/// stratum, a stratum with fewer points giving all of them and the rest shared among the
/// others (water-filling); the total is min(k, Σ sizes).
fn allocate(sizes: &[usize], k: usize) -> Vec<usize> {
    let mut take = vec![0usize; sizes.len()];
    let mut left = k.min(sizes.iter().sum());
    loop {
        let open: Vec<usize> = (0..sizes.len()).filter(|&s| take[s] < sizes[s]).collect();
        if left == 0 || open.is_empty() {
            return take;
        }
        let share = (left / open.len()).max(1);
        for s in open {
            let add = share.min(sizes[s] - take[s]).min(left);
            take[s] += add;
            left -= add;
        }
    }
}

/// Points per block of the stratified and informed choices: 8 consecutive points,
/// which in an organised cloud (row by row, as cameras write them) are neighbouring
/// pixels of one row (0.8° on a Helios2, whose 640 columns span 69°), whose rays carry
/// nearly the same information. A block is classified and scored by its first point
/// and chosen whole, so the choice reads, scores and sorts one point in 8 (a frame's
/// ~38 000 blocks, not its ~306 000 points) before it reads the chosen blocks. For an
/// unorganised cloud a block is 8 arbitrary points: the choice is then less informed,
/// but still made of rays, not of noise (see the module doc). Measured (`cargo run
/// --release -p epd-frame --example sampling informed`, 6 frames, N = 20 000): the
/// informed choice's mean-diameter bound is 1.436 × the full frame's with blocks of 4,
/// 1.438 × with 8, 1.451 × with 16, 1.497 × with 32 (a block of 32 pixels reaches past
/// the few far rays that carry the information); scoring costs in proportion to the
/// blocks (≈ 1.5 ms for 8, 3–6 ms for 4 on one core).
pub const BLOCK: usize = 8;

/// Blocks for `k` points ([`BLOCK`] each).
fn blocks_for(k: usize) -> usize {
    k.div_ceil(BLOCK)
}

/// The first point of every block ([`BLOCK`]) that is valid: its index and the point.
struct Heads {
    /// Points read.
    n: usize,
    /// Index of each valid first point.
    first: Vec<u32>,
    /// The points.
    pts: Vec<[f64; 3]>,
}

impl Heads {
    fn read<R: Records + ?Sized>(records: &mut R) -> Result<Self, String> {
        let n = records.len();
        let idx: Vec<u32> = (0..n).step_by(BLOCK).map(|i| i as u32).collect();
        let pts = records.points(&idx)?;
        let (first, pts) = idx.into_iter().zip(pts).filter(|(_, p)| usable(p)).unzip();
        Ok(Self { n, first, pts })
    }

    /// The points of block `b`.
    fn block(&self, b: usize) -> std::ops::Range<u32> {
        let h = self.first[b];
        h..(h as usize + BLOCK).min(self.n) as u32
    }
}

/// The blocks in the order a choice takes them: `first` (enough for `k` points when all
/// are valid), then, while invalid points leave it short, those of `rest` in order.
struct Order<'a> {
    first: Vec<usize>,
    rest: Box<dyn FnOnce() -> Vec<usize> + 'a>,
}

/// `k` valid points of the blocks of `order`, taken in its order (a block's invalid
/// points left out, the last block's extra points dropped), or `None` when its blocks
/// hold fewer than `k` valid points.
fn fill<R: Records + ?Sized>(
    records: &mut R,
    heads: &Heads,
    order: Order<'_>,
    k: usize,
) -> Result<Option<Vec<u32>>, String> {
    let mut out: Vec<u32> = Vec::with_capacity(k + BLOCK);
    let mut take = |blocks: &[usize], out: &mut Vec<u32>| -> Result<(), String> {
        // The blocks in file order (their heads ascend with the block, and blocks do not
        // overlap), each with where its records begin in the read.
        let mut sorted: Vec<(usize, usize)> = blocks.iter().map(|&b| (b, 0)).collect();
        sorted.sort_unstable();
        let mut idx: Vec<u32> = Vec::with_capacity(blocks.len() * BLOCK);
        for (b, at) in &mut sorted {
            *at = idx.len();
            idx.extend(heads.block(*b));
        }
        let pts = records.points(&idx)?;
        for &b in blocks {
            let Ok(j) = sorted.binary_search_by_key(&b, |&(b, _)| b) else {
                continue;
            };
            let at = sorted[j].1;
            for (m, i) in heads.block(b).enumerate() {
                if pts.get(at + m).is_some_and(usable) {
                    out.push(i);
                }
            }
        }
        Ok(())
    };
    take(&order.first, &mut out)?;
    if out.len() < k {
        let rest = (order.rest)();
        let mut at = 0;
        while out.len() < k && at < rest.len() {
            let upto = (at + blocks_for(k - out.len())).min(rest.len());
            take(&rest[at..upto], &mut out)?;
            at = upto;
        }
    }
    if out.len() < k {
        return Ok(None);
    }
    out.truncate(k);
    Ok(Some(out))
}

/// `k` valid points, each as likely as any other: drawn without repetition (a partial
/// Fisher–Yates shuffle of all indices), read, the invalid ones left out and as many
/// more drawn, until `k` or none left (`None`).
fn uniform_records<R: Records + ?Sized>(
    records: &mut R,
    k: usize,
    rng: &mut SplitMix,
) -> Result<Option<Vec<u32>>, String> {
    let n = records.len();
    let mut pool: Vec<u32> = (0..n as u32).collect();
    let mut drawn = 0;
    let mut out = Vec::with_capacity(k);
    while out.len() < k && drawn < n {
        let want = (k - out.len()).min(n - drawn);
        for i in drawn..drawn + want {
            let j = i + rng.below(n - i);
            pool.swap(i, j);
        }
        let mut idx = pool[drawn..drawn + want].to_vec();
        idx.sort_unstable();
        drawn += want;
        let pts = records.points(&idx)?;
        out.extend(
            idx.iter()
                .zip(&pts)
                .filter(|(_, p)| usable(p))
                .map(|(&i, _)| i),
        );
    }
    Ok((out.len() >= k).then_some(out))
}

/// The blocks grouped by stratum (of their first point, [`strata`]).
fn by_stratum(heads: &Heads) -> Vec<Vec<usize>> {
    let all: Vec<u32> = (0..heads.pts.len() as u32).collect();
    let s = strata(&heads.pts, &all);
    let mut groups = vec![Vec::new(); CLOCK_BINS * REACH_BINS];
    for (b, &k) in s.iter().enumerate() {
        groups[k as usize].push(b);
    }
    groups
}

/// The same number of blocks from each stratum ([`allocate`]), chosen uniformly within
/// each; then the others, one from each stratum in turn.
fn stratified<'a>(heads: &Heads, k: usize, rng: &mut SplitMix) -> Order<'a> {
    let mut groups = by_stratum(heads);
    let sizes: Vec<usize> = groups.iter().map(Vec::len).collect();
    let take = allocate(&sizes, blocks_for(k));
    let mut first = Vec::with_capacity(blocks_for(k));
    let mut left = Vec::with_capacity(groups.len());
    for (g, t) in groups.iter_mut().zip(take) {
        shuffle(g, rng);
        first.extend_from_slice(&g[..t]);
        left.push(g.split_off(t));
    }
    Order {
        first,
        rest: Box::new(move || round_robin(left)),
    }
}

/// The items of `groups`, one from each group in turn.
fn round_robin(groups: Vec<Vec<usize>>) -> Vec<usize> {
    let longest = groups.iter().map(Vec::len).max().unwrap_or(0);
    (0..longest)
        .flat_map(|i| groups.iter().filter_map(move |g| g.get(i).copied()))
        .collect()
}

/// The gradient of the range residual over β of each point (SCS, m) at `geom`.
fn gradients(geom: &Geometry, pts: &[[f64; 3]]) -> Vec<[f64; N_PARAMS]> {
    geom.gradients(Residual::Range, pts)
}

/// The mean diameter's gradient over β: c = (½, ½, 0, …).
const D_MEAN: [f64; N_PARAMS] = [0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0];

/// The informed choice's pilot fit: its β and its witness ([`Witness`]).
#[derive(Clone, Copy, Debug)]
struct Pilot {
    params: Params,
    witness: Option<Witness>,
}

/// The informed choice ([`SamplingMethod::Informed`]) of the blocks with the pilot
/// fit's β, or `None` when the pilot fit does not converge or leaves the model.
fn informed<'a>(
    heads: &'a Heads,
    k: usize,
    method: Method,
    options: &EstimateOptions,
    rng: &mut SplitMix,
) -> Option<(Order<'a>, Pilot)> {
    let all: Vec<u32> = (0..heads.pts.len() as u32).collect();
    let pilot_idx = uniform(&all, PILOT_POINTS, rng);
    let pilot_pts: Vec<[f64; 3]> = pilot_idx.iter().map(|&i| heads.pts[i as usize]).collect();
    let pilot = estimate(&pilot_pts, method, options).ok()?;
    if !pilot.status.is_converged() {
        return None;
    }
    let geom = Geometry::new(&pilot.params)?;
    let grads = gradients(&geom, &heads.pts);
    let scores = influence(&grads)?;
    let all_strata = strata(&heads.pts, &all);
    let first = pick(&all_strata, &scores, blocks_for(k), rng);
    let chosen = first.clone();
    let rest = move || {
        let mut taken = vec![false; scores.len()];
        for &b in &chosen {
            taken[b] = true;
        }
        let mut rest: Vec<usize> = (0..scores.len()).filter(|&b| !taken[b]).collect();
        rest.sort_by(|x, y| scores[*y].total_cmp(&scores[*x]));
        rest
    };
    Some((
        Order {
            first,
            rest: Box::new(rest),
        },
        Pilot {
            params: pilot.params,
            witness: Witness::of(&pilot),
        },
    ))
}

/// The influence (gᵢ·M⁻¹c)² of each row gᵢ of `grads` on the mean diameter, for the
/// information M = Σ gⱼgⱼᵀ of all of them and c the mean diameter's gradient. The
/// inverse is the pseudo-inverse on the determined directions (the roll of a round pipe
/// is not). `None` when M is not finite.
///
/// Tried and not kept (`cargo run --release -p epd-frame --example sampling`, 6 frames
/// of the paper's 20" pipe, σ = 0.03 m, N = 20 000): M of the chosen set instead of the
/// frame's, in a second or third round (1.45–1.49× the full frame's bound on the mean
/// diameter, against 1.44×); scoring only a stratified pool of 2N–8N points
/// (1.46–1.61×).
fn influence(grads: &[[f64; N_PARAMS]]) -> Option<Vec<f64>> {
    // Σ gⱼgⱼᵀ on and above the diagonal (the same products, summed in the same order,
    // as the full outer products), mirrored below.
    let mut upper = [[0.0f64; N_PARAMS]; N_PARAMS];
    for g in grads {
        for (i, row) in upper.iter_mut().enumerate() {
            for j in i..N_PARAMS {
                row[j] += g[i] * g[j];
            }
        }
    }
    let m = SMatrix::<f64, N_PARAMS, N_PARAMS>::from_fn(|i, j| upper[i.min(j)][i.max(j)]);
    // Scaled to unit diagonal so the pseudo-inverse's cut is relative per parameter.
    let d = SVector::<f64, N_PARAMS>::from_fn(|i, _| {
        let v = m[(i, i)];
        if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 }
    });
    let scaled = SMatrix::<f64, N_PARAMS, N_PARAMS>::from_fn(|i, j| m[(i, j)] * d[i] * d[j]);
    let inv = scaled.pseudo_inverse(1e-10).ok()?;
    let c = SVector::<f64, N_PARAMS>::from(D_MEAN).component_mul(&d);
    let a: [f64; N_PARAMS] = (d.component_mul(&(inv * c))).into();
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(
        grads
            .iter()
            .map(|g| {
                let s: f64 = g.iter().zip(&a).map(|(g, a)| g * a).sum();
                s * s
            })
            .collect(),
    )
}

/// The informed pick of `k` of the rows with strata `st` and `scores`:
/// [`INFORMED_FLOOR`] of `k` spread over the strata (the highest scores of each stratum's
/// share), then the rest by the highest scores among the rows left. Ties are broken by a
/// seeded shuffle, so that equal scores do not favour a part of the image.
fn pick(st: &[u16], scores: &[f64], k: usize, rng: &mut SplitMix) -> Vec<usize> {
    let mut groups: Vec<Vec<usize>> = vec![Vec::new(); CLOCK_BINS * REACH_BINS];
    for (j, &s) in st.iter().enumerate() {
        groups[s as usize].push(j);
    }
    let sizes: Vec<usize> = groups.iter().map(Vec::len).collect();
    let floor = allocate(&sizes, (INFORMED_FLOOR * k as f64).round() as usize);
    let mut taken = vec![false; scores.len()];
    let mut out = Vec::with_capacity(k);
    // Each row with its score beside it (the selection reads them in place, not by
    // index), highest first.
    let with_scores =
        |rows: &[usize]| -> Vec<(f64, usize)> { rows.iter().map(|&j| (scores[j], j)).collect() };
    let by_score = |x: &(f64, usize), y: &(f64, usize)| y.0.total_cmp(&x.0);
    for (g, t) in groups.iter_mut().zip(floor) {
        if t == 0 {
            continue;
        }
        shuffle(g, rng);
        let mut g = with_scores(g);
        g.select_nth_unstable_by(t - 1, by_score);
        for &(_, j) in &g[..t] {
            taken[j] = true;
            out.push(j);
        }
    }
    let mut rest: Vec<usize> = (0..scores.len()).filter(|&j| !taken[j]).collect();
    let more = k.saturating_sub(out.len()).min(rest.len());
    if more > 0 {
        shuffle(&mut rest, rng);
        let mut rest = with_scores(&rest);
        rest.select_nth_unstable_by(more - 1, by_score);
        out.extend(rest[..more].iter().map(|&(_, j)| j));
    }
    out
}

/// A seeded Fisher–Yates shuffle.
fn shuffle<T>(v: &mut [T], rng: &mut SplitMix) {
    for i in (1..v.len()).rev() {
        let j = rng.below(i + 1);
        v.swap(i, j);
    }
}

#[cfg(test)]
mod tests;
