//! The points a fit reads, in place: every point of a slice, or those of a slice that a
//! [`Mask`] keeps. A refit of part of a frame (the straight pipe before a bend) reads the
//! caller's points through a mask of one bit per point instead of a copy of 24 bytes per
//! kept point (issue 27: an estimate's memory beside its input).
//!
//! The kept points are numbered 0..[`Points::len`] in their order in the slice, and every
//! pass reads them in ranges of that numbering ([`Points::range`]), so a fit through a
//! mask sees the same points in the same order, cut into the same chunks, as a fit of
//! their copy: the same sums, to the bit.

use std::borrow::Cow;
use std::ops::Range;

/// Bits per mask word.
const WORD: usize = 64;

/// Which points of a slice are kept: one bit per point, with the count of kept points
/// before each word (to find the k-th kept point by a binary search over words).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mask {
    /// Bit i of word w: point 64·w + i is kept.
    words: Vec<u64>,
    /// Kept points before word w (one more entry: the total).
    before: Vec<usize>,
    /// Points the mask covers.
    len: usize,
}

impl Mask {
    /// The mask of the points of `points` for which `keep` holds (tested once each, in
    /// order, with a stop check every [`crate::cancel::TICKS_PER_CHECK`] points).
    pub fn new(points: &[[f64; 3]], keep: impl Fn(&[f64; 3]) -> bool) -> Self {
        let mut words = vec![0u64; points.len().div_ceil(WORD)];
        for (w, block) in words.iter_mut().zip(points.chunks(WORD)) {
            for (i, p) in block.iter().enumerate() {
                crate::cancel::tick();
                if keep(p) {
                    *w |= 1 << i;
                }
            }
        }
        Self::of_words(words, points.len())
    }

    /// The mask keeping point i where `flags[i]`.
    pub fn from_flags(flags: &[bool]) -> Self {
        let mut words = vec![0u64; flags.len().div_ceil(WORD)];
        for (w, block) in words.iter_mut().zip(flags.chunks(WORD)) {
            for (i, _) in block.iter().enumerate().filter(|(_, f)| **f) {
                *w |= 1 << i;
            }
        }
        Self::of_words(words, flags.len())
    }

    /// The mask of `words` over `len` points, with its counts.
    fn of_words(words: Vec<u64>, len: usize) -> Self {
        let mut before = Vec::with_capacity(words.len() + 1);
        let mut total = 0;
        for w in &words {
            before.push(total);
            total += w.count_ones() as usize;
        }
        before.push(total);
        Self { words, before, len }
    }

    /// Points kept.
    pub fn count(&self) -> usize {
        self.before.last().copied().unwrap_or(0)
    }

    /// The index in the slice of the `k`-th kept point (`k < count`).
    fn index_of(&self, k: usize) -> usize {
        // The last word with fewer than k + 1 kept points before it holds the k-th.
        let w = self.before.partition_point(|&b| b <= k) - 1;
        let mut bits = self.words[w];
        for _ in 0..(k - self.before[w]) {
            bits &= bits - 1;
        }
        w * WORD + bits.trailing_zeros() as usize
    }
}

/// Points (SCS, m) read in place: all of `all`, or those `mask` keeps (see the module's
/// doc). Cheap to copy.
#[derive(Clone, Copy, Debug)]
pub struct Points<'a> {
    all: &'a [[f64; 3]],
    mask: Option<&'a Mask>,
}

impl<'a> From<&'a [[f64; 3]]> for Points<'a> {
    fn from(all: &'a [[f64; 3]]) -> Self {
        Self { all, mask: None }
    }
}

impl<'a> Points<'a> {
    /// Every point of `all`.
    pub fn all(all: &'a [[f64; 3]]) -> Self {
        Self { all, mask: None }
    }

    /// The points of `all` that `mask` keeps; `None` when the mask was made for a slice
    /// of another length.
    pub fn masked(all: &'a [[f64; 3]], mask: &'a Mask) -> Option<Self> {
        (mask.len == all.len()).then_some(Self {
            all,
            mask: Some(mask),
        })
    }

    /// Points read.
    pub fn len(&self) -> usize {
        self.mask.map_or(self.all.len(), Mask::count)
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The points as one slice when they are one (no mask).
    pub fn as_slice(&self) -> Option<&'a [[f64; 3]]> {
        self.mask.is_none().then_some(self.all)
    }

    /// The points, in order.
    pub fn iter(&self) -> Iter<'a> {
        match self.mask {
            None => Iter::Every(self.all.iter()),
            Some(mask) => Iter::Kept {
                all: self.all,
                words: &mask.words,
                word: 0,
                bits: mask.words.first().copied().unwrap_or(0),
                left: mask.count(),
            },
        }
    }

    /// The points numbered `r` (`r.end ≤ len`): a sub-slice without a mask, their copy
    /// with one (at most `r.len()` points: a pass reads a range at a time).
    pub fn range(&self, r: Range<usize>) -> Cow<'a, [[f64; 3]]> {
        let Some(mask) = self.mask else {
            return Cow::Borrowed(&self.all[r]);
        };
        if r.is_empty() {
            return Cow::Owned(Vec::new());
        }
        let mut out = Vec::with_capacity(r.len());
        let from = mask.index_of(r.start);
        let mut w = from / WORD;
        let mut bits = mask.words[w] & (!0u64 << (from % WORD));
        loop {
            let need = r.len() - out.len();
            if bits == !0u64 && need >= WORD {
                // A whole word kept (a selection by position keeps runs): one copy.
                out.extend_from_slice(&self.all[w * WORD..(w + 1) * WORD]);
            } else {
                while bits != 0 && out.len() < r.len() {
                    out.push(self.all[w * WORD + bits.trailing_zeros() as usize]);
                    bits &= bits - 1;
                }
            }
            if out.len() == r.len() {
                break;
            }
            w += 1;
            bits = mask.words[w];
        }
        Cow::Owned(out)
    }

    /// Every `stride`-th point from the first, at most `max` of them with the stride
    /// `⌈len/max⌉` — as a slice whose own such sample (stride `⌈n/max⌉` over its n points)
    /// is that one: all the points when they are one slice (the reader strides it), the
    /// sample's copy through a mask. For the readers that use an even sample of a frame.
    pub fn sample(&self, max: usize) -> Cow<'a, [[f64; 3]]> {
        match self.as_slice() {
            Some(all) => Cow::Borrowed(all),
            None => {
                let stride = self.len().div_ceil(max.max(1)).max(1);
                Cow::Owned(self.iter().step_by(stride).copied().collect())
            }
        }
    }
}

/// The iterator of [`Points::iter`]: a slice's own (whose `nth` jumps), or the kept
/// points word by word.
#[derive(Clone, Debug)]
pub enum Iter<'a> {
    /// Every point of a slice.
    Every(std::slice::Iter<'a, [f64; 3]>),
    /// The points a mask keeps.
    Kept {
        /// The slice.
        all: &'a [[f64; 3]],
        /// The mask's words.
        words: &'a [u64],
        /// The word being read.
        word: usize,
        /// Its bits not yet read.
        bits: u64,
        /// Points not yet read.
        left: usize,
    },
}

impl<'a> Iterator for Iter<'a> {
    type Item = &'a [f64; 3];

    fn next(&mut self) -> Option<Self::Item> {
        match self {
            Iter::Every(it) => it.next(),
            Iter::Kept {
                all,
                words,
                word,
                bits,
                left,
            } => {
                if *left == 0 {
                    return None;
                }
                while *bits == 0 {
                    *word += 1;
                    *bits = words[*word];
                }
                let i = *word * WORD + bits.trailing_zeros() as usize;
                *bits &= *bits - 1;
                *left -= 1;
                Some(&all[i])
            }
        }
    }

    fn nth(&mut self, n: usize) -> Option<Self::Item> {
        match self {
            Iter::Every(it) => it.nth(n),
            Iter::Kept { .. } => {
                for _ in 0..n {
                    self.next()?;
                }
                self.next()
            }
        }
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = match self {
            Iter::Every(it) => it.len(),
            Iter::Kept { left, .. } => *left,
        };
        (n, Some(n))
    }
}

impl ExactSizeIterator for Iter<'_> {}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize) -> Vec<[f64; 3]> {
        (0..n).map(|i| [i as f64, 0.5 * i as f64, 1.0]).collect()
    }

    #[test]
    fn a_mask_reads_the_kept_points_as_their_copy_does() {
        let pts = cloud(1000);
        for modulus in [1usize, 2, 3, 7, 64, 65, 1001] {
            let keep = |p: &[f64; 3]| (p[0] as usize).is_multiple_of(modulus) || p[0] > 900.0;
            let copy: Vec<[f64; 3]> = pts.iter().filter(|p| keep(p)).copied().collect();
            let mask = Mask::new(&pts, keep);
            let flags: Vec<bool> = pts.iter().map(keep).collect();
            assert_eq!(Mask::from_flags(&flags), mask);
            let view = Points::masked(&pts, &mask).expect("same length");
            assert_eq!(view.len(), copy.len());
            assert_eq!(view.iter().copied().collect::<Vec<_>>(), copy);
            for r in [0..0, 0..1, 0..copy.len(), 3..17, 63..130] {
                let r = r.start.min(copy.len())..r.end.min(copy.len());
                assert_eq!(&*view.range(r.clone()), &copy[r], "mod {modulus}");
            }
            let s = view.sample(10);
            let stride = copy.len().div_ceil(10).max(1);
            let want: Vec<_> = copy.iter().step_by(stride).copied().collect();
            assert_eq!(&*s, &want[..]);
            // The sample's own even sample of at most 10 is itself.
            assert_eq!(s.len().div_ceil(10).max(1), 1);
        }
    }

    #[test]
    fn points_without_a_mask_are_the_slice() {
        let pts = cloud(100);
        let view = Points::all(&pts);
        assert_eq!(view.len(), 100);
        assert!(matches!(view.range(5..9), Cow::Borrowed(_)));
        assert_eq!(view.iter().count(), 100);
        assert!(Points::masked(&pts[..99], &Mask::new(&pts, |_| true)).is_none());
    }
}
