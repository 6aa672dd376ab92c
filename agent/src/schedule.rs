//! The rate limiter between actors and the learner (appendix C.1's asynchronous
//! actor-learner loop, made reproducible).
//!
//! Off-policy ([`Pace::Ratio`]): once the replay holds `min_replay_transitions`, the
//! learner may take `floor((env_steps - min_replay) * ratio)` steps in total.
//! On-policy ([`Pace::OnPolicy`]): the learner may take `floor(unrolls inserted /
//! batch_size)` steps, each consuming one batch. Either way actors wait until the
//! learner has taken the steps allowed so far before stepping further (on-policy, the
//! next batch is therefore acted by the policy that the last batch produced), and the
//! learner waits for env steps. With one actor the interleaving is therefore fixed,
//! and a run with the same config and seed reproduces its learning curve on the same
//! machine.

use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Instant;

use crate::replay::SnippetReplay;
use crate::solve::{SolveRecord, SolveTracker};

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
}

/// How many learner steps the data so far allows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// Off-policy replay: a fixed ratio of learner steps to env steps after warm-up.
    Ratio {
        /// Learner steps per env step once warm.
        learner_steps_per_env_step: f64,
        /// Transitions in the replay before the first learner step.
        min_replay_transitions: usize,
    },
    /// On-policy unrolls: one learner step per `batch_size` unrolls.
    OnPolicy {
        /// Unrolls per learner step.
        batch_size: usize,
    },
}

/// What the replay holds, for the pace.
#[derive(Debug, Clone, Copy)]
struct Fill {
    transitions: u64,
    inserted: u64,
}

/// Shared state of one run.
#[derive(Debug)]
pub struct Schedule {
    counters: Mutex<Counters>,
    learner_wake: Condvar,
    actor_wake: tokio::sync::Notify,
    /// The replay, filled by actors and sampled by the learner.
    pub replay: Mutex<SnippetReplay>,
    pace: Pace,
    /// Learner steps already done when the replay was made (resumed runs), so that an
    /// on-policy budget counts only this invocation's unrolls.
    learner_steps_at_start: u64,
    /// When this invocation's actor-learner loop was set up (wall-clock stamps of
    /// episodes and of "solved").
    started: Instant,
}

impl Schedule {
    /// A schedule starting from `counters` (non-zero when resuming).
    pub fn new(replay: SnippetReplay, pace: Pace, counters: Counters) -> Self {
        Self {
            learner_steps_at_start: counters.learner_steps,
            counters: Mutex::new(counters),
            learner_wake: Condvar::new(),
            actor_wake: tokio::sync::Notify::new(),
            replay: Mutex::new(replay),
            pace,
            started: Instant::now(),
        }
    }

    /// Seconds since the schedule was made: the start of this `train` invocation's
    /// training, after the learner is built and before the first env step.
    pub fn elapsed_seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// When the run first counted as solved, if it has.
    pub fn solved(&self) -> Option<SolveRecord> {
        self.lock().solve.solved().cloned()
    }

    /// A consistent copy of the counters.
    pub fn counters(&self) -> Counters {
        self.lock().clone()
    }

    fn lock(&self) -> MutexGuard<'_, Counters> {
        self.counters.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Learner steps allowed in total with `c` and the replay at `fill`.
    fn allowed(&self, c: &Counters, fill: Fill) -> u64 {
        match self.pace {
            Pace::Ratio {
                learner_steps_per_env_step,
                min_replay_transitions,
            } => {
                let min_replay = min_replay_transitions as u64;
                if fill.transitions < min_replay {
                    return c.learner_steps;
                }
                let warm = c.env_steps.saturating_sub(min_replay) as f64;
                (warm * learner_steps_per_env_step).floor() as u64
            }
            Pace::OnPolicy { batch_size } => {
                self.learner_steps_at_start + fill.inserted / batch_size as u64
            }
        }
    }

    fn fill(&self) -> Fill {
        let r = self.replay.lock().unwrap_or_else(|e| e.into_inner());
        Fill {
            transitions: (r.len() * r.layout().length) as u64,
            inserted: r.inserted(),
        }
    }

    /// Record env steps and finished episodes' returns from an actor; wake the learner.
    pub fn add_env_steps(&self, steps: u64, episode_returns: impl IntoIterator<Item = Vec<f64>>) {
        let wall = self.elapsed_seconds();
        let mut c = self.lock();
        c.env_steps += steps;
        for r in episode_returns {
            c.episodes += 1;
            let (env_steps, episodes) = (c.env_steps, c.episodes);
            if let Some(record) = c.solve.observe(&r, env_steps, episodes, wall) {
                tracing::info!(env_steps, wall_seconds = record.wall_seconds, mean = ?record.running_mean, "solved");
                if c.solve.stop_on_solve {
                    c.stop = true;
                }
            }
            if c.recent_returns.len() == RECENT {
                c.recent_returns.pop_front();
            }
            c.recent_returns.push_back(r);
        }
        let stopping = c.stop;
        drop(c);
        self.learner_wake.notify_all();
        if stopping {
            self.actor_wake.notify_waiters();
        }
    }

    /// Actors: wait until the learner has caught up with the env steps so far (or stop).
    pub async fn wait_for_learner(&self) {
        loop {
            let notified = self.actor_wake.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            let fill = self.fill();
            {
                let c = self.lock();
                if c.stop || c.learner_steps >= self.allowed(&c, fill) {
                    return;
                }
            }
            notified.await;
        }
    }

    /// Learner: block until a step is allowed; false when the run is stopping.
    pub fn wait_for_work(&self) -> bool {
        let mut c = self.lock();
        loop {
            if c.stop {
                return false;
            }
            drop(c);
            let fill = self.fill();
            c = self.lock();
            if c.stop {
                return false;
            }
            if c.learner_steps < self.allowed(&c, fill) {
                return true;
            }
            c = self.learner_wake.wait(c).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Learner: one step done; wake waiting actors.
    pub fn learner_stepped(&self) -> u64 {
        let mut c = self.lock();
        c.learner_steps += 1;
        let n = c.learner_steps;
        drop(c);
        self.actor_wake.notify_waiters();
        n
    }

    /// End the run (idempotent); the first error given is kept.
    pub fn stop(&self, error: Option<String>) {
        let mut c = self.lock();
        c.stop = true;
        if c.error.is_none() {
            c.error = error;
        }
        drop(c);
        self.learner_wake.notify_all();
        self.actor_wake.notify_waiters();
    }

    /// End the run early because of `signal`: not an error, the run still reports.
    pub fn interrupt(&self, signal: &str) {
        let mut c = self.lock();
        c.stop = true;
        c.interrupted.get_or_insert_with(|| signal.to_string());
        drop(c);
        self.learner_wake.notify_all();
        self.actor_wake.notify_waiters();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::{Snippet, SnippetLayout};

    fn schedule(ratio: f64, min_replay: usize) -> Schedule {
        let layout = SnippetLayout {
            length: 1,
            obs_dim: 1,
            action_width: 1,
            num_rewards: 1,
            discrete: true,
            on_policy: false,
        };
        let pace = Pace::Ratio {
            learner_steps_per_env_step: ratio,
            min_replay_transitions: min_replay,
        };
        Schedule::new(
            SnippetReplay::new(layout, 1000, 0),
            pace,
            Counters::default(),
        )
    }

    fn fill(s: &Schedule, n: usize) {
        let mut r = s.replay.lock().unwrap();
        for _ in 0..n {
            let snippet = Snippet {
                observations: vec![0.0, 0.0],
                actions: vec![0.0],
                rewards: vec![0.0],
                discounts: vec![1.0],
                behaviour_log_probs: vec![0.0],
                valid: vec![1.0],
            };
            r.insert(snippet).unwrap();
        }
    }

    #[test]
    fn learner_budget_follows_the_ratio_after_warm_up() {
        let s = schedule(0.25, 10);
        fill(&s, 9);
        s.add_env_steps(9, []);
        assert_eq!(s.allowed(&s.counters(), s.fill()), 0, "replay not warm yet");
        fill(&s, 11);
        s.add_env_steps(11, []);
        // 20 env steps, 10 past warm-up, ratio 1/4 -> 2 learner steps.
        assert_eq!(s.allowed(&s.counters(), s.fill()), 2);
        assert!(s.wait_for_work());
        s.learner_stepped();
        assert!(s.wait_for_work());
        s.learner_stepped();
        s.stop(None);
        assert!(
            !s.wait_for_work(),
            "no third step: the budget is 2, and the run stopped"
        );
    }

    #[test]
    fn on_policy_allows_one_step_per_batch_of_unrolls() {
        let layout = SnippetLayout {
            length: 1,
            obs_dim: 1,
            action_width: 1,
            num_rewards: 1,
            discrete: true,
            on_policy: true,
        };
        let s = Schedule::new(
            SnippetReplay::new(layout, usize::MAX, 0),
            Pace::OnPolicy { batch_size: 4 },
            Counters::default(),
        );
        fill(&s, 3);
        assert_eq!(s.allowed(&s.counters(), s.fill()), 0, "3 of 4 unrolls");
        fill(&s, 6);
        assert_eq!(
            s.allowed(&s.counters(), s.fill()),
            2,
            "9 unrolls make two batches"
        );
        assert_eq!(s.replay.lock().unwrap().sample(4).batch_size(), 4);
        s.learner_stepped();
        assert_eq!(
            s.allowed(&s.counters(), s.fill()),
            2,
            "consuming a batch does not change the budget"
        );
    }

    #[tokio::test]
    async fn actors_wait_until_the_learner_catches_up() {
        let s = std::sync::Arc::new(schedule(1.0, 1));
        fill(&s, 3);
        s.add_env_steps(3, []);
        let learner = {
            let s = s.clone();
            std::thread::spawn(move || {
                let mut steps = 0;
                while s.wait_for_work() {
                    s.learner_stepped();
                    steps += 1;
                    if steps == 2 {
                        break;
                    }
                }
            })
        };
        tokio::time::timeout(std::time::Duration::from_secs(10), s.wait_for_learner())
            .await
            .unwrap();
        assert_eq!(
            s.counters().learner_steps,
            2,
            "(3 - 1) * 1.0 learner steps before the actor resumes"
        );
        learner.join().unwrap();
    }
}
