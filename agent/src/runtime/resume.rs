//! A run's state in and out of its checkpoints: the learner loop's [`Checkpointer`]
//! takes a consistent snapshot of the schedule, the replay and the log files and
//! writes it (`checkpoint/run.rs`); [`open_checkpoint`] and [`restore_schedule`]
//! give a resumed run that state back, with its logs cut to the checkpoint's rows.
//!
//! What a resume cannot restore: env sessions (the protocol has no way to save a
//! simulator's state), so each actor makes a new session, seeded from its act counter
//! rather than the run's first seeds, and the episodes in progress at the checkpoint
//! are cut short (their transitions after the last whole snippet are not in the
//! replay). Everything else (learner, duals, optimizers, replay contents and sampler,
//! the actors' sampling counters, counters, solve tracker, recent returns, the rate
//! limiter's origin, log rows) continues exactly.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use tch::Device;

use crate::core::algo::Learner;
use crate::core::replay::{Snippet, SnippetLayout, SnippetReplay};
use crate::report::metrics::{EVAL_CSV, RunFiles};
use crate::runtime::checkpoint::CheckpointError;
use crate::runtime::checkpoint::run::{
    LogLengths, NewSnippets, PaceOrigin, RUN_FORMAT_VERSION, ReplayState, RunProgress,
    discard_after, latest_checkpoint, load_replay, write_run_checkpoint,
};
use crate::runtime::schedule::Schedule;

const EVENTS_PREFIX: &str = "events.out.tfevents.";

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes a run's checkpoints from the learner thread.
#[derive(Debug)]
pub struct Checkpointer {
    files: Arc<RunFiles>,
    /// Write the replay's contents (`run.checkpoint_replay`).
    replay: bool,
    /// Snippets numbered below this are in segments already.
    segments_end: u64,
    /// Which member of the learner this run is.
    member: usize,
}

impl Checkpointer {
    /// Checkpoints of the run `files` writes; `segments_end` is the resumed
    /// checkpoint's `replay.inserted` (0 for a new run).
    pub fn new(files: Arc<RunFiles>, replay: bool, segments_end: u64) -> Self {
        Self {
            files,
            replay,
            segments_end,
            member: 0,
        }
    }

    /// The checkpoints of member `member` of a population learner.
    pub fn for_member(self, member: usize) -> Self {
        Self { member, ..self }
    }

    /// Write a checkpoint of `learner` and the run's state; returns its directory.
    pub fn save(
        &mut self,
        learner: &Learner,
        schedule: &Schedule,
    ) -> Result<PathBuf, CheckpointError> {
        let dir = self.files.dir().to_path_buf();
        let origin = schedule.origin();
        let wall_seconds = schedule.elapsed_seconds();
        // Under the schedule's lock no actor is between its replay insert and its log
        // rows, so counters, replay and file lengths agree.
        let snapshot = schedule.snapshot(|c, replay| {
            self.files.flush().map_err(io(&dir))?;
            let logs = log_lengths(&dir)?;
            let state = self.replay.then(|| ReplayState {
                held_from: replay.held_from(),
                inserted: replay.inserted(),
                sampler_position: replay.sampler_position().to_string(),
            });
            let start = self.segments_end.max(replay.held_from());
            let snippets = if self.replay {
                replay.snippets_from(start)
            } else {
                Vec::new()
            };
            let progress = RunProgress {
                format_version: RUN_FORMAT_VERSION,
                env_steps: c.env_steps,
                learner_steps: learner.step_count(),
                episodes: c.episodes,
                recent_returns: c.recent_returns.iter().cloned().collect(),
                solve: c.solve.state(),
                actors: c.actors.clone(),
                pace_origin: origin,
                replay: state,
                logs,
                wall_seconds,
            };
            Ok::<_, CheckpointError>(Snapshot {
                progress,
                layout: replay.layout(),
                start,
                snippets,
            })
        })?;
        let new = NewSnippets {
            layout: snapshot.layout,
            start: snapshot.start,
            snippets: &snapshot.snippets,
        };
        let progress = &snapshot.progress;
        let ckpt = write_run_checkpoint(
            &dir,
            learner,
            self.member,
            progress,
            self.replay.then_some(new),
        )?;
        if let Some(state) = &progress.replay {
            self.segments_end = state.inserted;
        }
        Ok(ckpt)
    }
}

/// The run's state taken under the schedule's lock.
struct Snapshot {
    progress: RunProgress,
    layout: SnippetLayout,
    /// Number of the first snippet not yet in a segment.
    start: u64,
    /// The snippets from `start` on, for the next segment.
    snippets: Vec<Snippet>,
}

/// Bytes of each log file in `dir` now.
fn log_lengths(dir: &Path) -> Result<LogLengths, CheckpointError> {
    let len = |name: &str| -> Result<u64, CheckpointError> {
        let path = dir.join(name);
        match std::fs::metadata(&path) {
            Ok(m) => Ok(m.len()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(0),
            Err(e) => Err(io(&path)(e)),
        }
    };
    let mut events = BTreeMap::new();
    for name in events_files(dir)? {
        let n = len(&name)?;
        events.insert(name, n);
    }
    Ok(LogLengths {
        episodes_csv: len("episodes.csv")?,
        learner_jsonl: len("learner.jsonl")?,
        events,
    })
}

fn events_files(dir: &Path) -> Result<Vec<String>, CheckpointError> {
    Ok(std::fs::read_dir(dir)
        .map_err(io(dir))?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with(EVENTS_PREFIX))
        .collect())
}

/// Cut the log files back to the checkpoint's rows: what the stopped process wrote
/// after it is written again by the resumed one. TensorBoard files the checkpoint
/// does not know were made after it, by a process that died before its first
/// checkpoint, and go.
fn truncate_logs(dir: &Path, logs: &LogLengths, env_steps: u64) -> Result<(), CheckpointError> {
    let cut = |name: &str, len: u64| -> Result<(), CheckpointError> {
        let path = dir.join(name);
        if !path.exists() {
            return Ok(());
        }
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .map_err(io(&path))?;
        file.set_len(len).map_err(io(&path))
    };
    cut("episodes.csv", logs.episodes_csv)?;
    truncate_evaluations(dir, env_steps)?;
    cut("learner.jsonl", logs.learner_jsonl)?;
    for name in events_files(dir)? {
        match logs.events.get(&name) {
            Some(&len) => cut(&name, len)?,
            None => {
                let path = dir.join(&name);
                std::fs::remove_file(&path).map_err(io(&path))?;
            }
        }
    }
    Ok(())
}

/// Removes the rows of `eval.csv` after `env_steps`: the resumed run evaluates those
/// points again. (Evaluations are written as they finish, beside the checkpoints, so
/// the file's length at a checkpoint says nothing.)
fn truncate_evaluations(dir: &Path, env_steps: u64) -> Result<(), CheckpointError> {
    let path = dir.join(EVAL_CSV);
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(());
    };
    let kept: String = text
        .lines()
        .enumerate()
        .filter(|(i, line)| {
            *i == 0
                || line
                    .split(',')
                    .next()
                    .and_then(|v| v.parse::<u64>().ok())
                    .is_some_and(|at| at <= env_steps)
        })
        .map(|(_, line)| format!("{line}\n"))
        .collect();
    std::fs::write(&path, kept).map_err(io(&path))
}

/// A run reopened at its latest checkpoint.
#[derive(Debug)]
pub struct Reopened {
    /// The learner as it was.
    pub learner: Learner,
    /// The rest of the run's state.
    pub progress: RunProgress,
}

/// Reopen `run_dir` at its latest checkpoint: remove what a crash after it left, cut
/// the logs to its rows, and load the learner on `device`.
pub fn open_checkpoint(run_dir: &Path, device: Device) -> Result<Reopened, CheckpointError> {
    let (ckpt, progress) = latest_checkpoint(run_dir)?;
    discard_after(run_dir, &ckpt)?;
    truncate_logs(run_dir, &progress.logs, progress.env_steps)?;
    let learner = Learner::load_checkpoint(&ckpt, device)?;
    tracing::info!(checkpoint = %ckpt.display(), env_steps = progress.env_steps, "resuming");
    Ok(Reopened { learner, progress })
}

/// Put a checkpoint's replay back into `replay` (when it has one) and say where the
/// pace counts from: the checkpoint's origin with its replay, else the checkpoint
/// itself, so that a resume without replay refills and goes on at the ratio rather
/// than catching up in a burst.
pub fn restore_schedule(
    run_dir: &Path,
    progress: &RunProgress,
    replay: &mut SnippetReplay,
) -> Result<PaceOrigin, CheckpointError> {
    let Some(state) = &progress.replay else {
        return Ok(PaceOrigin {
            env_steps: progress.env_steps,
            learner_steps: progress.learner_steps,
            inserted: 0,
        });
    };
    let held = load_replay(run_dir, &replay.layout(), state)?;
    let position: u128 = state
        .sampler_position
        .parse()
        .map_err(|_| CheckpointError::Content {
            path: run_dir.join("checkpoints"),
            message: format!(
                "replay.sampler_position: expected a decimal u128, got {:?}",
                state.sampler_position
            ),
        })?;
    replay
        .restore(held, state.inserted, position)
        .map_err(|e| CheckpointError::Content {
            path: run_dir.join("replay"),
            message: e.to_string(),
        })?;
    Ok(progress.pace_origin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluations_after_the_checkpoint_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(EVAL_CSV);
        std::fs::write(
            &path,
            "env_steps,learner_steps,return_a\n1000,10,-5\n2000,20,-4\n3000,30,-3\n",
        )
        .unwrap();
        truncate_evaluations(dir.path(), 2000).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "env_steps,learner_steps,return_a\n1000,10,-5\n2000,20,-4\n"
        );
        // A run without evaluations has no file, and none is made.
        let empty = tempfile::tempdir().unwrap();
        truncate_evaluations(empty.path(), 0).unwrap();
        assert!(!empty.path().join(EVAL_CSV).exists());
    }
}
