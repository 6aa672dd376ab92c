//! `--shard I/N`: one deterministic slice of a sweep's jobs. Job j belongs to shard
//! j mod N, so every shard gets settings from the whole grid (balanced to within one
//! job) and the slice depends only on the sweep file, never on which machine asks.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Shard `index` of `count` (`--shard index/count`, 0 <= index < count).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Shard {
    /// Which slice, from 0.
    pub index: usize,
    /// How many slices the sweep is cut into.
    pub count: usize,
}

/// A `--shard` value that is not `I/N` with 0 <= I < N.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("expected I/N with whole numbers 0 <= I < N (e.g. 0/4), got {got:?}")]
pub struct ShardError {
    /// The text given.
    pub got: String,
}

impl FromStr for Shard {
    type Err = ShardError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let bad = || ShardError { got: text.into() };
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// Whether job number `job` (its place in the whole sweep's job list) is this shard's.
    pub fn owns(&self, job: usize) -> bool {
        job % self.count == self.index
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_split_the_jobs_round_robin() {
        let s: Shard = "1/3".parse().unwrap();
        assert_eq!(s, Shard { index: 1, count: 3 });
        assert_eq!(s.to_string(), "1/3");
        let owned: Vec<usize> = (0..8).filter(|&j| s.owns(j)).collect();
        assert_eq!(owned, [1, 4, 7]);
        for bad in ["3/2", "2/2", "x", "1", "1/0", "-1/2", "1/2/3", ""] {
            let e = bad.parse::<Shard>().unwrap_err().to_string();
            assert!(
                e.contains("expected I/N") && e.contains(&format!("{bad:?}")),
                "{e}"
            );
        }
    }
}
