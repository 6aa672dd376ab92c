//! The rate limiter between actors and the learner (appendix C.1's asynchronous
//! actor-learner loop, made reproducible).
//!
//! Off-policy ([`Pace::Ratio`]): once the replay holds `min_replay_transitions`, the
//! learner may take `floor((env_steps - min_replay) * ratio)` steps in total.
//! On-policy ([`Pace::OnPolicy`]): the learner may take `floor(unrolls inserted /
//! batch_size)` steps, each consuming one batch. Either way actors wait until the
//! learner has taken the steps allowed so far before committing a further step
//! (off-policy actors compute that step meanwhile, `actor` module; on-policy ones only
//! then act, so the next batch is acted by the policy that the last batch produced),
//! and the learner waits for env steps. With one actor the interleaving is therefore fixed,
//! and a run with the same config and seed reproduces its learning curve on the same
//! machine.
//!
//! Both paces count from a [`PaceOrigin`]: zero, or the resume point of a run resumed
//! without its replay, which then refills `min_replay_transitions` and goes on at the
//! ratio instead of catching up on the steps the counters say it is behind. An
//! actor's step (snippets, env steps, episodes, its log rows) is committed under one
//! lock ([`Schedule::commit`]) that a checkpoint's [`Schedule::snapshot`] also takes,
//! so a checkpoint sees every actor step whole or not at all.

use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Instant;

use crate::core::replay::SnippetReplay;
use crate::runtime::checkpoint::run::{ActorProgress, PaceOrigin};
use crate::runtime::solve::SolveRecord;

mod eval_tap;
pub use eval_tap::EvalPoint;
use eval_tap::EvalTap;

mod counters;
pub use counters::{ActorStep, CommitError, Counters, RECENT};

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
    /// Where the pace counts from (module docs).
    origin: PaceOrigin,
    /// When this invocation's actor-learner loop was set up (wall-clock stamps of
    /// episodes, learner records, "solved" and the summary).
    started: Instant,
    /// Training wall seconds of the invocations before this one (a resume's
    /// checkpoint's), which the clock continues from.
    elapsed_before: f64,
    /// Periodic evaluations, when asked for.
    eval_tap: Mutex<Option<EvalTap>>,
}

impl Schedule {
    /// A schedule starting from `counters` (non-zero when resuming), its pace
    /// counting from `origin`.
    pub fn new(replay: SnippetReplay, pace: Pace, counters: Counters, origin: PaceOrigin) -> Self {
        Self {
            origin,
            counters: Mutex::new(counters),
            learner_wake: Condvar::new(),
            actor_wake: tokio::sync::Notify::new(),
            replay: Mutex::new(replay),
            pace,
            started: Instant::now(),
            elapsed_before: 0.0,
            eval_tap: Mutex::new(None),
        }
    }

    /// This schedule with its clock going on from `seconds` of earlier invocations.
    pub fn continuing_from(self, seconds: f64) -> Self {
        Self {
            elapsed_before: seconds,
            ..self
        }
    }

    /// Calls `notify` each time the env steps reach the next multiple of `period`
    /// (after the counts already made), inside the commit that reaches it: the
    /// actors have then waited for every learner step allowed so far and the
    /// learner cannot step until the commit ends, so the policy published at that
    /// moment is the one after `EvalPoint::learner_steps`, on every invocation.
    pub fn set_eval_tap(&self, period: u64, notify: impl Fn(EvalPoint) + Send + Sync + 'static) {
        let tap = EvalTap::new(period, self.lock().env_steps, Box::new(notify));
        *self.eval_tap.lock().unwrap_or_else(|e| e.into_inner()) = Some(tap);
    }

    /// Stops the evaluation tap (its `notify` is dropped).
    pub fn clear_eval_tap(&self) {
        self.eval_tap
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
    }

    /// The run's training wall seconds: since the schedule was made (after the
    /// learner is built and before the first env step), plus the earlier invocations'
    /// when resumed.
    pub fn elapsed_seconds(&self) -> f64 {
        self.elapsed_before + self.started.elapsed().as_secs_f64()
    }

    /// When the run first counted as solved, if it has.
    pub fn solved(&self) -> Option<SolveRecord> {
        self.lock().solve.solved().cloned()
    }

    /// A consistent copy of the counters.
    pub fn counters(&self) -> Counters {
        self.lock().clone()
    }

    /// Where the pace counts from.
    pub fn origin(&self) -> PaceOrigin {
        self.origin
    }

    /// Runs `f` on the counters and the replay with no actor step half-committed
    /// (checkpoints).
    pub fn snapshot<R>(&self, f: impl FnOnce(&Counters, &SnippetReplay) -> R) -> R {
        let c = self.lock();
        let replay = self.replay.lock().unwrap_or_else(|e| e.into_inner());
        f(&c, &replay)
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
                let since = c.env_steps.saturating_sub(self.origin.env_steps);
                let warm = since.saturating_sub(min_replay) as f64;
                self.origin.learner_steps + (warm * learner_steps_per_env_step).floor() as u64
            }
            Pace::OnPolicy { batch_size } => {
                let inserted = fill.inserted.saturating_sub(self.origin.inserted);
                self.origin.learner_steps + inserted / batch_size as u64
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

    /// Record env steps and finished episodes' returns; wake the learner.
    pub fn add_env_steps(&self, steps: u64, episode_returns: impl IntoIterator<Item = Vec<f64>>) {
        let mut c = self.lock();
        self.count(&mut c, steps, episode_returns);
        drop(c);
        self.wake_after_steps();
    }

    /// Commit one actor step: its snippets into the replay, its counts, and its log
    /// rows (`log` gets the env steps after the step), all under the counters' lock.
    pub fn commit(
        &self,
        step: ActorStep,
        log: impl FnOnce(u64) -> std::io::Result<()>,
    ) -> Result<(), CommitError> {
        let mut c = self.lock();
        {
            let mut replay = self.replay.lock().unwrap_or_else(|e| e.into_inner());
            for s in step.snippets {
                replay.insert(s)?;
            }
        }
        log(c.env_steps + step.env_steps).map_err(CommitError::Log)?;
        if c.actors.len() <= step.actor {
            c.actors.resize(step.actor + 1, ActorProgress::default());
        }
        c.actors[step.actor].acts = step.acts;
        self.count(&mut c, step.env_steps, step.episode_returns);
        drop(c);
        self.wake_after_steps();
        Ok(())
    }

    fn count(
        &self,
        c: &mut Counters,
        steps: u64,
        episode_returns: impl IntoIterator<Item = Vec<f64>>,
    ) {
        let wall = self.elapsed_seconds();
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
        let mut tap = self.eval_tap.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(tap) = tap.as_mut() {
            tap.reach(c.env_steps, c.learner_steps);
        }
    }

    fn wake_after_steps(&self) {
        let stopping = self.lock().stop;
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
    ///
    /// The replay's fill is read with the counters' lock held (commits change both
    /// under it, and wake the learner after releasing it). Read before taking the
    /// lock, a commit landing in between was judged with the old fill and its wake-up
    /// was already spent: the learner slept while the actor waited for it, for good
    /// (issue 36: the hung runs of a loaded machine, whose preemptions widen that gap).
    pub fn wait_for_work(&self) -> bool {
        let mut c = self.lock();
        loop {
            if c.stop {
                return false;
            }
            let fill = self.fill();
            #[cfg(test)]
            tests::preempted_after_fill();
            if c.learner_steps < self.allowed(&c, fill) {
                return true;
            }
            c = self.learner_wake.wait(c).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Whether the learner has caught up with the env steps so far (or the run stops):
    /// what `wait_for_learner` waits for.
    pub fn caught_up(&self) -> bool {
        self.caught_up_after(0)
    }

    /// Whether the learner's next step leaves it caught up (or the run stops): the
    /// step after which a waiting actor may load a policy, so one the learner must
    /// publish. Only a commit, which waits for the catch-up, can raise the allowance.
    pub fn next_step_catches_up(&self) -> bool {
        self.caught_up_after(1)
    }

    /// Whether the learner is caught up once it has taken `more` steps beyond those done.
    fn caught_up_after(&self, more: u64) -> bool {
        let c = self.lock();
        let fill = self.fill();
        c.stop || c.learner_steps + more >= self.allowed(&c, fill)
    }

    /// Whether the run is stopping.
    pub fn stopping(&self) -> bool {
        self.lock().stop
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

/// Actors of a population (one schedule per member, stepped in lockstep): wait until
/// the learner has caught up with the member that allows it the fewest steps, so
/// that actors and learner never wait for each other (members' allowances differ
/// while their replays warm up). Stopped members do not count; with none left it
/// returns at once.
pub async fn wait_for_population_learner(schedules: &[&Schedule]) {
    loop {
        let active: Vec<&Schedule> = schedules
            .iter()
            .copied()
            .filter(|s| !s.stopping())
            .collect();
        let mut notified: Vec<_> = active
            .iter()
            .map(|s| Box::pin(s.actor_wake.notified()))
            .collect();
        for n in &mut notified {
            n.as_mut().enable();
        }
        if active.is_empty() || active.iter().any(|s| s.caught_up()) {
            return;
        }
        futures::future::select_all(notified).await;
    }
}

#[cfg(test)]
mod tests;
