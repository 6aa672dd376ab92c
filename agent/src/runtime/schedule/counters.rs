//! What the schedule counts (env steps, learner steps, episodes, the recent returns,
//! "solved", each actor's progress) and what one actor step commits to it.

use crate::core::replay::{ReplayError, Snippet};
use crate::runtime::checkpoint::run::ActorProgress;
use crate::runtime::solve::SolveTracker;

/// Episodes kept for the running mean shown while training.
pub const RECENT: usize = 20;

impl Counters {
    /// Mean vector return of the recent episodes (empty before the first one).
    pub fn recent_mean_return(&self) -> Vec<f64> {
        let n = self.recent_returns.len() as f64;
        let k = self.recent_returns.front().map_or(0, Vec::len);
        (0..k)
            .map(|i| self.recent_returns.iter().map(|r| r[i]).sum::<f64>() / n)
            .collect()
    }
}

/// Counters shared by actors, learner and the progress display.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Counters {
    /// Env steps summed over all instances.
    pub env_steps: u64,
    /// Learner steps done.
    pub learner_steps: u64,
    /// Episodes finished.
    pub episodes: u64,
    /// Undiscounted vector returns of the latest episodes (at most `RECENT`).
    pub recent_returns: std::collections::VecDeque<Vec<f64>>,
    /// Set when the run should end (done, Ctrl-C, or an error).
    pub stop: bool,
    /// First fatal error, if any.
    pub error: Option<String>,
    /// The signal that stopped the run early (`Ctrl-C`, `SIGTERM`), if one did.
    pub interrupted: Option<String>,
    /// Decides and keeps when the run first counted as solved (`run.solve_threshold`).
    pub solve: SolveTracker,
    /// Per actor, what its last committed step reached.
    pub actors: Vec<ActorProgress>,
}

/// What one actor step adds to the run.
#[derive(Debug)]
pub struct ActorStep {
    /// The actor.
    pub actor: usize,
    /// Its act calls so far, this step's included.
    pub acts: u64,
    /// Env steps taken (B).
    pub env_steps: u64,
    /// Snippets completed, for the replay.
    pub snippets: Vec<Snippet>,
    /// Returns of the episodes that ended.
    pub episode_returns: Vec<Vec<f64>>,
}

/// Why an actor step could not be committed.
#[derive(Debug, thiserror::Error)]
pub enum CommitError {
    /// A snippet did not fit the replay.
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// Writing the step's log rows failed.
    #[error("episodes.csv: {0}")]
    Log(std::io::Error),
}
