//! A whole run's checkpoint on disk: `<run>/checkpoints/step_<n>_env_<e>/` holds the
//! learner's files and `run.json` (what the schedule, the actors, the replay's
//! sampler and the log files had reached, [`RunProgress`]); the replay's snippets are
//! in segments under `<run>/replay/` (`replay.rs`); `checkpoints/latest.json` names
//! the newest complete checkpoint.
//!
//! Order of writing: the new replay segment, then the checkpoint directory (one
//! atomic rename), then `latest.json` (atomic rename), then the pruning of what no
//! kept checkpoint reads. A crash at any point leaves `latest.json` naming a complete
//! checkpoint whose segments are all there. The two newest checkpoints are kept.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::replay::{SnippetRange, prune, read_range, write_segment};
use super::{CheckpointError, ExtraFile, io, sync_path};
use crate::core::algo::Learner;
use crate::core::replay::{Snippet, SnippetLayout};
use crate::runtime::solve::SolveState;

/// Layout version of `run.json`.
pub const RUN_FORMAT_VERSION: u32 = 2;

/// `run.json`: everything of a run besides the learner that its continuation needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunProgress {
    /// [`RUN_FORMAT_VERSION`] when written.
    pub format_version: u32,
    /// Env steps when the checkpoint was written.
    pub env_steps: u64,
    /// Learner steps (equals the learner's own counter).
    pub learner_steps: u64,
    /// Episodes finished.
    pub episodes: u64,
    /// Returns of the latest episodes, oldest first (the running mean shown).
    pub recent_returns: Vec<Vec<f64>>,
    /// The solve tracker's window and record.
    pub solve: SolveState,
    /// Per actor, in actor order.
    pub actors: Vec<ActorProgress>,
    /// The rate limiter's reference point.
    pub pace_origin: PaceOrigin,
    /// The replay's contents and sampler; `None` with `run.checkpoint_replay = false`.
    pub replay: Option<ReplayState>,
    /// Lengths of the log files, which a resume truncates back to.
    pub logs: LogLengths,
    /// Training wall seconds when the checkpoint was written, summed over the run's
    /// invocations: a resume's clock goes on from here, so a resumed run's wall times
    /// are the run's, not its last leg's. 0 in checkpoints written before it was kept.
    #[serde(default)]
    pub wall_seconds: f64,
}

impl RunProgress {
    /// A run that has taken `learner_steps` learner steps and kept nothing else: a
    /// learner written as a run's checkpoint by tools and tests.
    pub fn learner_only(learner_steps: u64) -> Self {
        Self {
            format_version: RUN_FORMAT_VERSION,
            env_steps: 0,
            learner_steps,
            episodes: 0,
            recent_returns: Vec::new(),
            solve: SolveState::default(),
            actors: Vec::new(),
            pace_origin: PaceOrigin::default(),
            replay: None,
            logs: LogLengths::default(),
            wall_seconds: 0.0,
        }
    }
}

/// How far one actor got.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorProgress {
    /// Act calls made: the counter of its sampling stream, and what seeds the env
    /// session it makes next.
    pub acts: u64,
}

/// Where the rate limiter counts from: zero for a run that has its whole replay, the
/// resume point for one that resumed with an empty replay (`schedule.rs`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaceOrigin {
    /// Env steps at the origin.
    pub env_steps: u64,
    /// Learner steps at the origin.
    pub learner_steps: u64,
    /// Snippets inserted into the replay at the origin.
    pub inserted: u64,
}

/// What the replay held and where its sampler was.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayState {
    /// Number of the oldest snippet held.
    pub held_from: u64,
    /// Snippets inserted so far (one past the newest's number).
    pub inserted: u64,
    /// The sampler's ChaCha8 word position, in decimal (a u128 does not fit a JSON
    /// number that every reader takes).
    pub sampler_position: String,
}

/// Bytes of each log file at the checkpoint.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogLengths {
    /// `episodes.csv`.
    pub episodes_csv: u64,
    /// `learner.jsonl`.
    pub learner_jsonl: u64,
    /// Every `events.out.tfevents.*` file by name.
    pub events: BTreeMap<String, u64>,
}

/// Snippets to append as a new replay segment.
#[derive(Debug, Clone, Copy)]
pub struct NewSnippets<'a> {
    /// Their sizes.
    pub layout: SnippetLayout,
    /// Number of the first.
    pub start: u64,
    /// The snippets, oldest first.
    pub snippets: &'a [Snippet],
}

#[derive(Debug, Serialize, Deserialize)]
struct Latest {
    checkpoint: String,
}

fn json_error(path: &Path) -> impl FnOnce(serde_json::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Json {
        path: path.to_path_buf(),
        source,
    }
}

/// `<run>/replay`.
pub fn replay_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("replay")
}

fn checkpoints_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("checkpoints")
}

/// A checkpoint's directory name: learner step and env steps, so that two states of a
/// run never share a name (env steps advance after the learner's last step).
pub fn checkpoint_name(progress: &RunProgress) -> String {
    format!(
        "step_{:09}_env_{:012}",
        progress.learner_steps, progress.env_steps
    )
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), CheckpointError> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    let mut f = std::fs::File::create(&tmp).map_err(io(&tmp))?;
    f.write_all(bytes).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))?;
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => sync_path(dir),
        _ => Ok(()),
    }
}

/// Write a whole-run checkpoint of `learner`'s member `member` (see module docs);
/// returns its directory.
pub fn write_run_checkpoint(
    run_dir: &Path,
    learner: &Learner,
    member: usize,
    progress: &RunProgress,
    new_snippets: Option<NewSnippets<'_>>,
) -> Result<PathBuf, CheckpointError> {
    let dir = checkpoints_dir(run_dir);
    let name = checkpoint_name(progress);
    let ckpt = dir.join(&name);
    if let Some(new) = new_snippets.filter(|n| !n.snippets.is_empty()) {
        write_segment(&replay_dir(run_dir), &new.layout, new.start, new.snippets)?;
    }
    // The same name is the same state (nothing was acted or learned since): the
    // final checkpoint right after a periodic one.
    if !ckpt.exists() {
        let json_path = ckpt.join("run.json");
        let text = serde_json::to_vec_pretty(progress).map_err(json_error(&json_path))?;
        learner.save_member_checkpoint(
            &ckpt,
            member,
            &[ExtraFile {
                name: "run.json",
                contents: &text,
            }],
        )?;
    }
    let latest = dir.join("latest.json");
    let text = serde_json::to_vec_pretty(&Latest {
        checkpoint: name.clone(),
    })
    .map_err(json_error(&latest))?;
    write_atomic(&latest, &text)?;
    prune_checkpoints(run_dir, &name)?;
    Ok(ckpt)
}

/// Checkpoint directory names in `dir`, oldest first.
fn checkpoint_names(dir: &Path) -> Result<Vec<String>, CheckpointError> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map_err(io(dir))?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with("step_") && !n.contains('.'))
        .collect();
    names.sort();
    Ok(names)
}

/// Keep `latest` and the one before it; drop newer ones (never completed as latest),
/// older ones, leftovers of interrupted writes, and the segments none kept reads.
fn prune_checkpoints(run_dir: &Path, latest: &str) -> Result<(), CheckpointError> {
    let dir = checkpoints_dir(run_dir);
    let names = checkpoint_names(&dir)?;
    let keep: Vec<&String> = names
        .iter()
        .filter(|n| n.as_str() <= latest)
        .rev()
        .take(2)
        .collect();
    for entry in std::fs::read_dir(&dir).map_err(io(&dir))?.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let stale = (name.starts_with("step_") && !keep.iter().any(|k| **k == name))
            || name.contains(".tmp-");
        if stale {
            let path = entry.path();
            if path.is_dir() {
                std::fs::remove_dir_all(&path).map_err(io(&path))?;
            } else {
                std::fs::remove_file(&path).map_err(io(&path))?;
            }
        }
    }
    let mut keep_from = u64::MAX;
    let mut drop_from = u64::MAX;
    for (i, name) in keep.iter().enumerate() {
        if let Some(replay) = read_progress(&dir.join(name))?.replay {
            keep_from = keep_from.min(replay.held_from);
            if i == 0 {
                drop_from = replay.inserted;
            }
        }
    }
    prune(&replay_dir(run_dir), keep_from, drop_from)
}

fn read_progress(ckpt: &Path) -> Result<RunProgress, CheckpointError> {
    let path = ckpt.join("run.json");
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let progress: RunProgress = serde_json::from_str(&text).map_err(json_error(&path))?;
    if progress.format_version != RUN_FORMAT_VERSION {
        return Err(CheckpointError::Content {
            path,
            message: format!(
                "format_version: expected {RUN_FORMAT_VERSION}, got {}",
                progress.format_version
            ),
        });
    }
    Ok(progress)
}

/// The newest complete checkpoint of a run: its directory and progress.
pub fn latest_checkpoint(run_dir: &Path) -> Result<(PathBuf, RunProgress), CheckpointError> {
    let dir = checkpoints_dir(run_dir);
    let latest_path = dir.join("latest.json");
    let text = std::fs::read_to_string(&latest_path)
        .map_err(|_| CheckpointError::NoCheckpoint(run_dir.to_path_buf()))?;
    let latest: Latest = serde_json::from_str(&text).map_err(json_error(&latest_path))?;
    let ckpt = dir.join(latest.checkpoint);
    let progress = read_progress(&ckpt)?;
    Ok((ckpt, progress))
}

/// Before a resume from `latest`: remove what a crash after it left (a newer,
/// unfinished checkpoint, its segment, temporary files), so that the resumed run
/// writes its own.
pub fn discard_after(run_dir: &Path, latest: &Path) -> Result<(), CheckpointError> {
    let name = latest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    prune_checkpoints(run_dir, &name)
}

/// The snippets a checkpoint's replay held, oldest first.
pub fn load_replay(
    run_dir: &Path,
    layout: &SnippetLayout,
    state: &ReplayState,
) -> Result<Vec<Snippet>, CheckpointError> {
    let range = SnippetRange {
        start: state.held_from,
        end: state.inserted,
    };
    read_range(&replay_dir(run_dir), layout, range)
}
