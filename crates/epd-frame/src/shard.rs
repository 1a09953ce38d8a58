//! `--shard K/N`: the K-th of N disjoint parts of a job, for running one job as N
//! independent processes (a Slurm job array, a Kubernetes Indexed Job, a shell loop).
//!
//! The same spelling and the same checks serve `epd estimate --shard K/N` (contiguous
//! blocks of the sorted file list: [`ShardSpec::block`]) and `bench-harness SCENARIO
//! --shard K/N` (round robin over the scenario's trials: [`ShardSpec::owns`]).

use std::ops::Range;
use std::str::FromStr;

/// A `--shard K/N` value that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ShardError {
    /// Not of the form `K/N` with two whole numbers.
    #[error("`{0}`: expected K/N, two whole numbers with 1 ≤ K ≤ N (e.g. 2/4)")]
    Syntax(String),
    /// N is zero.
    #[error("`{0}`: N = 0; a job is split into at least one shard")]
    NoShards(String),
    /// K is zero.
    #[error("`{0}`: K = 0; shards are numbered from 1 to N")]
    Zero(String),
    /// K is larger than N.
    #[error("`{text}`: K = {k} is larger than N = {n}; shards are numbered from 1 to N")]
    TooLarge {
        /// The value as given.
        text: String,
        /// K.
        k: u64,
        /// N.
        n: u64,
    },
}

/// The K-th of N shards (1 ≤ K ≤ N), as given by `--shard K/N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ShardSpec {
    k: u64,
    n: u64,
}

impl ShardSpec {
    /// Shard `k` of `n`; `Err` unless 1 ≤ k ≤ n.
    pub fn new(k: u64, n: u64) -> Result<Self, ShardError> {
        let text = format!("{k}/{n}");
        if n == 0 {
            Err(ShardError::NoShards(text))
        } else if k == 0 {
            Err(ShardError::Zero(text))
        } else if k > n {
            Err(ShardError::TooLarge { text, k, n })
        } else {
            Ok(Self { k, n })
        }
    }

    /// K, from 1 to N.
    pub fn k(&self) -> u64 {
        self.k
    }

    /// N, the number of shards.
    pub fn n(&self) -> u64 {
        self.n
    }

    /// The contiguous block of `len` items this shard takes:
    /// `[⌊(K−1)·len/N⌋, ⌊K·len/N⌋)`. The N blocks are disjoint, cover `0..len` in
    /// order and differ in size by at most one.
    pub fn block(&self, len: usize) -> Range<usize> {
        let at = |k: u64| {
            // u128: no overflow for any usize length and u64 shard numbers.
            ((u128::from(k) * len as u128) / u128::from(self.n)) as usize
        };
        at(self.k - 1)..at(self.k)
    }

    /// Whether item `index` (from 0) is this shard's in a round robin: item i goes to
    /// shard (i mod N) + 1.
    pub fn owns(&self, index: u64) -> bool {
        index % self.n == self.k - 1
    }
}

impl std::fmt::Display for ShardSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

impl FromStr for ShardSpec {
    type Err = ShardError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let syntax = || ShardError::Syntax(s.to_string());
        let (k, n) = s.split_once('/').ok_or_else(syntax)?;
        // Digits only: no sign, no spaces, no `0x`.
        let whole = |t: &str| {
            if t.is_empty() || !t.bytes().all(|b| b.is_ascii_digit()) {
                return Err(syntax());
            }
            t.parse::<u64>().map_err(|_| syntax())
        };
        let (k, n) = (whole(k)?, whole(n)?);
        Self::new(k, n).map_err(|e| match e {
            // Name the value as the user wrote it (`01/4`).
            ShardError::NoShards(_) => ShardError::NoShards(s.to_string()),
            ShardError::Zero(_) => ShardError::Zero(s.to_string()),
            ShardError::TooLarge { k, n, .. } => ShardError::TooLarge {
                text: s.to_string(),
                k,
                n,
            },
            other => other,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_refuses() {
        let s: ShardSpec = "2/4".parse().unwrap();
        assert_eq!((s.k(), s.n()), (2, 4));
        assert_eq!(s.to_string(), "2/4");
        assert_eq!(
            "1/1".parse::<ShardSpec>().unwrap(),
            ShardSpec::new(1, 1).unwrap()
        );
        for bad in [
            "a/b", "2", "2/", "/4", "-1/4", "+1/4", " 1/4", "1/4/2", "1.0/4", "",
        ] {
            assert!(
                matches!(bad.parse::<ShardSpec>(), Err(ShardError::Syntax(_))),
                "{bad}"
            );
        }
        assert!(matches!(
            "0/4".parse::<ShardSpec>(),
            Err(ShardError::Zero(_))
        ));
        assert!(matches!(
            "1/0".parse::<ShardSpec>(),
            Err(ShardError::NoShards(_))
        ));
        let e = "5/4".parse::<ShardSpec>().unwrap_err();
        assert_eq!(
            e,
            ShardError::TooLarge {
                text: "5/4".into(),
                k: 5,
                n: 4
            }
        );
        assert!(e.to_string().contains("K = 5 is larger than N = 4"), "{e}");
        assert!(matches!(
            "99999999999999999999/4".parse::<ShardSpec>(),
            Err(ShardError::Syntax(_))
        ));
    }

    #[test]
    fn blocks_partition_in_order_and_balance() {
        for len in [0usize, 1, 3, 7, 10, 100] {
            for n in 1..=12u64 {
                let mut next = 0;
                let mut sizes = Vec::new();
                for k in 1..=n {
                    let b = ShardSpec::new(k, n).unwrap().block(len);
                    assert_eq!(b.start, next, "len {len} shard {k}/{n}");
                    next = b.end;
                    sizes.push(b.len());
                }
                assert_eq!(next, len);
                let (lo, hi) = (sizes.iter().min(), sizes.iter().max());
                assert!(hi.unwrap() - lo.unwrap() <= 1, "{sizes:?}");
            }
        }
    }

    #[test]
    fn round_robin_gives_each_index_to_exactly_one_shard() {
        for n in 1..=7u64 {
            for i in 0..50u64 {
                let owners: Vec<u64> = (1..=n)
                    .filter(|&k| ShardSpec::new(k, n).unwrap().owns(i))
                    .collect();
                assert_eq!(owners, vec![i % n + 1]);
            }
        }
    }
}
