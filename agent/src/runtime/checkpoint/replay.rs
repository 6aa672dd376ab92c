//! The replay's contents on disk: segment files in `<run>/replay/`, each holding the
//! snippets inserted between two checkpoints, so that a checkpoint appends what is
//! new instead of rewriting a replay of up to a million transitions.
//!
//! Snippets are numbered in insertion order from 0 (`SnippetReplay::inserted`). A
//! checkpoint records the numbers its replay held (`held_from..inserted`); segment
//! `segment_<start>_<end>.safetensors` holds numbers `start..end` as one f32 tensor
//! `snippets [end - start, width]`, each row a snippet's fields concatenated in
//! [`Snippet`]'s order. A segment is written to a temporary name and renamed, so a
//! crash leaves no partial segment under a segment's name.

use std::path::{Path, PathBuf};

use tch::Tensor;

use super::{CheckpointError, io, sync_path};
use crate::core::replay::{Snippet, SnippetLayout};

const TENSOR: &str = "snippets";

/// Snippet numbers `start..end`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SnippetRange {
    /// First number.
    pub start: u64,
    /// One past the last.
    pub end: u64,
}

/// Values per snippet row.
fn width(l: &SnippetLayout) -> usize {
    (l.length + 1) * l.obs_dim + l.length * (l.action_width + l.num_rewards + 3)
}

fn flatten(snippets: &[Snippet], out: &mut Vec<f32>) {
    for s in snippets {
        for field in [
            &s.observations,
            &s.actions,
            &s.rewards,
            &s.discounts,
            &s.behaviour_log_probs,
            &s.valid,
        ] {
            out.extend_from_slice(field);
        }
    }
}

fn unflatten(row: &[f32], l: &SnippetLayout) -> Snippet {
    let mut at = 0;
    let mut take = |n: usize| {
        at += n;
        row[at - n..at].to_vec()
    };
    Snippet {
        observations: take((l.length + 1) * l.obs_dim),
        actions: take(l.length * l.action_width),
        rewards: take(l.length * l.num_rewards),
        discounts: take(l.length),
        behaviour_log_probs: take(l.length),
        valid: take(l.length),
    }
}

fn segment_name(range: SnippetRange) -> String {
    format!("segment_{:012}_{:012}.safetensors", range.start, range.end)
}

/// The range a segment file name stands for (`None` for other files).
fn parse_name(name: &str) -> Option<SnippetRange> {
    let stem = name
        .strip_prefix("segment_")?
        .strip_suffix(".safetensors")?;
    let (start, end) = stem.split_once('_')?;
    Some(SnippetRange {
        start: start.parse().ok()?,
        end: end.parse().ok()?,
    })
}

/// Segments in `dir`, by start.
fn segments(dir: &Path) -> Result<Vec<(SnippetRange, PathBuf)>, CheckpointError> {
    if !dir.exists() {
        return Ok(Vec::new());
    }
    let mut out: Vec<(SnippetRange, PathBuf)> = std::fs::read_dir(dir)
        .map_err(io(dir))?
        .filter_map(|e| {
            let path = e.ok()?.path();
            Some((parse_name(path.file_name()?.to_str()?)?, path))
        })
        .collect();
    out.sort_by_key(|(r, _)| r.start);
    Ok(out)
}

/// Write `snippets`, numbered from `start`, as one segment in `dir`.
pub fn write_segment(
    dir: &Path,
    layout: &SnippetLayout,
    start: u64,
    snippets: &[Snippet],
) -> Result<PathBuf, CheckpointError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let range = SnippetRange {
        start,
        end: start + snippets.len() as u64,
    };
    let path = dir.join(segment_name(range));
    let tmp = dir.join(format!(
        "{}.tmp-{}",
        segment_name(range),
        std::process::id()
    ));
    let mut flat = Vec::with_capacity(snippets.len() * width(layout));
    flatten(snippets, &mut flat);
    let tensor = Tensor::from_slice(&flat).view([snippets.len() as i64, width(layout) as i64]);
    Tensor::write_safetensors(&[(TENSOR, tensor)], &tmp)?;
    sync_path(&tmp)?;
    std::fs::rename(&tmp, &path).map_err(io(&path))?;
    sync_path(dir)?;
    Ok(path)
}

/// The snippets numbered `range`, oldest first, gathered from the segments of `dir`.
pub fn read_range(
    dir: &Path,
    layout: &SnippetLayout,
    range: SnippetRange,
) -> Result<Vec<Snippet>, CheckpointError> {
    let w = width(layout);
    let mut out = Vec::with_capacity((range.end - range.start) as usize);
    for (seg, path) in segments(dir)? {
        let next = range.start + out.len() as u64;
        if seg.end <= next || seg.start > next || next >= range.end {
            continue;
        }
        let tensors = Tensor::read_safetensors(&path)?;
        let values = tensors
            .into_iter()
            .find(|(name, t)| {
                name == TENSOR && t.size() == [(seg.end - seg.start) as i64, w as i64]
            })
            .map(|(_, t)| Vec::<f32>::try_from(t.flatten(0, -1)))
            .transpose()?
            .ok_or_else(|| CheckpointError::Content {
                path: path.clone(),
                message: format!(
                    "expected tensor {TENSOR} of shape [{}, {w}]",
                    seg.end - seg.start
                ),
            })?;
        let last = seg.end.min(range.end);
        for j in next..last {
            let row = (j - seg.start) as usize * w;
            out.push(unflatten(&values[row..row + w], layout));
        }
    }
    if out.len() as u64 != range.end - range.start {
        return Err(CheckpointError::Content {
            path: dir.to_path_buf(),
            message: format!(
                "replay snippets {}..{} expected, segments hold {}..{}",
                range.start,
                range.end,
                range.start,
                range.start + out.len() as u64
            ),
        });
    }
    Ok(out)
}

/// Remove what no kept checkpoint reads: segments ending at or before `keep_from`,
/// segments starting at or after `drop_from` (written for a checkpoint that a crash
/// left unfinished) and temporary files of interrupted writes.
pub fn prune(dir: &Path, keep_from: u64, drop_from: u64) -> Result<(), CheckpointError> {
    for (seg, path) in segments(dir)? {
        if seg.end <= keep_from || seg.start >= drop_from {
            std::fs::remove_file(&path).map_err(io(&path))?;
        }
    }
    if dir.exists() {
        for entry in std::fs::read_dir(dir).map_err(io(dir))?.flatten() {
            if entry.file_name().to_string_lossy().contains(".tmp-") {
                let path = entry.path();
                std::fs::remove_file(&path).map_err(io(&path))?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> SnippetLayout {
        SnippetLayout {
            length: 2,
            obs_dim: 3,
            action_width: 1,
            num_rewards: 2,
            discrete: false,
            on_policy: false,
        }
    }

    fn snippet(j: u64) -> Snippet {
        let v = j as f32;
        Snippet {
            observations: (0..9).map(|i| v + i as f32 * 0.01).collect(),
            actions: vec![v, -v],
            rewards: vec![v; 4],
            discounts: vec![1.0, 0.0],
            behaviour_log_probs: vec![-v, v],
            valid: vec![1.0, 1.0],
        }
    }

    #[test]
    fn ranges_are_read_across_segments_and_pruned() {
        let dir = tempfile::tempdir().unwrap();
        let l = layout();
        let all: Vec<Snippet> = (0..10).map(snippet).collect();
        write_segment(dir.path(), &l, 0, &all[..4]).unwrap();
        write_segment(dir.path(), &l, 4, &all[4..7]).unwrap();
        write_segment(dir.path(), &l, 7, &all[7..]).unwrap();
        let range = SnippetRange { start: 2, end: 9 };
        assert_eq!(read_range(dir.path(), &l, range).unwrap(), all[2..9]);
        // The first segment ends at 4: not needed from 5 on. The last starts at 7.
        prune(dir.path(), 5, 7).unwrap();
        let range = SnippetRange { start: 5, end: 7 };
        assert_eq!(read_range(dir.path(), &l, range).unwrap(), all[5..7]);
        let err = read_range(dir.path(), &l, SnippetRange { start: 2, end: 9 })
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("replay snippets 2..9 expected, segments hold 2..2"),
            "{err}"
        );
    }
}
