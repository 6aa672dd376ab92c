//! The schedule's evaluation tap (`run.eval_period`): which periodic evaluations fall
//! due as the env steps grow, told to whoever asked (`train/evals.rs`) inside the
//! commit that reaches them, so the policy published then is known exactly.

/// A periodic evaluation that fell due (`run.eval_period`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EvalPoint {
    /// The multiple of the period the run's env steps reached.
    pub env_steps: u64,
    /// Learner steps taken at that moment: the published policy is theirs.
    pub learner_steps: u64,
}

/// Who hears of evaluations as they fall due.
pub(super) struct EvalTap {
    period: u64,
    next: u64,
    notify: Box<dyn Fn(EvalPoint) + Send + Sync>,
}

impl std::fmt::Debug for EvalTap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EvalTap")
            .field("period", &self.period)
            .field("next", &self.next)
            .finish_non_exhaustive()
    }
}

impl EvalTap {
    /// A tap whose first evaluation is the next multiple of `period` after
    /// `env_steps` (the counts already made; a period of 0 counts as 1).
    pub(super) fn new(
        period: u64,
        env_steps: u64,
        notify: Box<dyn Fn(EvalPoint) + Send + Sync>,
    ) -> Self {
        let period = period.max(1);
        Self {
            period,
            next: (env_steps / period + 1) * period,
            notify,
        }
    }

    /// Tells of every multiple of the period that `env_steps` has reached.
    pub(super) fn reach(&mut self, env_steps: u64, learner_steps: u64) {
        while env_steps >= self.next {
            (self.notify)(EvalPoint {
                env_steps: self.next,
                learner_steps,
            });
            self.next += self.period;
        }
    }
}
