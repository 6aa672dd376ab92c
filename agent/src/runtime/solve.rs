//! Time-to-solve: the env steps and wall seconds at which the running mean of the
//! last `SOLVE_WINDOW` training episodes' undiscounted returns first reaches every
//! threshold of `run.solve_threshold` (named by objective), as RL benchmarks report
//! "solved" (e.g. Pendulum-v1: mean of 10 episodes above -200).

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};

use crate::core::learner_config::ConfigError;

/// Training episodes in the running mean that decides "solved".
pub const SOLVE_WINDOW: usize = 10;

/// When a run first counted as solved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolveRecord {
    /// Env steps (summed over instances) when the deciding episode ended.
    pub env_steps: u64,
    /// Seconds since this `train` invocation began training (`Schedule::elapsed_seconds`).
    pub wall_seconds: f64,
    /// Training episodes finished by then.
    pub episodes: u64,
    /// The running mean of the last `SOLVE_WINDOW` episodes' returns, per objective.
    pub running_mean: Vec<f64>,
}

/// Thresholds bound to reward columns, and the episodes seen so far.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SolveTracker {
    /// `(column, threshold)` pairs.
    thresholds: Vec<(usize, f64)>,
    recent: VecDeque<Vec<f64>>,
    solved: Option<SolveRecord>,
    /// End the run once solved (`run.stop_on_solve`).
    pub stop_on_solve: bool,
}

impl SolveTracker {
    /// Binds `thresholds` (objective name -> return) to the env's objectives; an
    /// unknown name is an error naming `run.solve_threshold`.
    pub fn new(
        thresholds: &BTreeMap<String, f64>,
        objectives: &[String],
    ) -> Result<Self, ConfigError> {
        let mut bound = Vec::new();
        for (name, &value) in thresholds {
            let column =
                objectives
                    .iter()
                    .position(|o| o == name)
                    .ok_or_else(|| ConfigError::Invalid {
                        field: format!("run.solve_threshold.{name}"),
                        requirement: format!("an objective of the env, one of {objectives:?}"),
                        got: format!("{name:?}"),
                    })?;
            bound.push((column, value));
        }
        Ok(Self {
            thresholds: bound,
            ..Self::default()
        })
    }

    /// Records one finished episode; returns the record the first time the run counts
    /// as solved.
    pub fn observe(
        &mut self,
        episode_return: &[f64],
        env_steps: u64,
        episodes: u64,
        wall_seconds: f64,
    ) -> Option<&SolveRecord> {
        if self.thresholds.is_empty() || self.solved.is_some() {
            return None;
        }
        if self.recent.len() == SOLVE_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(episode_return.to_vec());
        if self.recent.len() < SOLVE_WINDOW {
            return None;
        }
        let k = episode_return.len();
        let n = self.recent.len() as f64;
        let running_mean: Vec<f64> = (0..k)
            .map(|i| self.recent.iter().map(|r| r[i]).sum::<f64>() / n)
            .collect();
        if self
            .thresholds
            .iter()
            .all(|&(column, threshold)| running_mean[column] >= threshold)
        {
            self.solved = Some(SolveRecord {
                env_steps,
                wall_seconds,
                episodes,
                running_mean,
            });
        }
        self.solved.as_ref()
    }

    /// The record, once solved.
    pub fn solved(&self) -> Option<&SolveRecord> {
        self.solved.as_ref()
    }

    /// What a checkpoint keeps: the window and the record (the thresholds come from
    /// the config again).
    pub fn state(&self) -> SolveState {
        SolveState {
            recent: self.recent.iter().cloned().collect(),
            solved: self.solved.clone(),
        }
    }

    /// Continue from a checkpoint's window and record.
    pub fn restore(&mut self, state: SolveState) {
        self.recent = state.recent.into();
        self.solved = state.solved;
    }
}

/// The part of a [`SolveTracker`] that changes while a run trains.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SolveState {
    /// Returns of the last (at most `SOLVE_WINDOW`) episodes, oldest first.
    pub recent: Vec<Vec<f64>>,
    /// When the run first counted as solved, if it has.
    pub solved: Option<SolveRecord>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_when_the_mean_of_the_last_ten_reaches_every_threshold() {
        let names = vec!["task".to_string(), "action_norm".to_string()];
        let thresholds = BTreeMap::from([("task".to_string(), -200.0)]);
        let mut t = SolveTracker::new(&thresholds, &names).unwrap();
        // Nine good episodes are not a window of ten.
        for i in 0..9 {
            assert!(
                t.observe(&[-100.0, -50.0], 200 * (i + 1), i + 1, 1.0)
                    .is_none()
            );
        }
        // Tenth: mean of (9 x -100 + -1200) / 10 = -210 < -200.
        assert!(t.observe(&[-1200.0, -50.0], 2000, 10, 2.0).is_none());
        // Eleventh drops the first -100: mean (8 x -100 - 1200 - 100) / 10 = -210.
        assert!(t.observe(&[-100.0, -50.0], 2200, 11, 3.0).is_none());
        for i in 0..8 {
            t.observe(&[-100.0, -50.0], 2400 + 200 * i, 12 + i, 4.0);
        }
        // The -1200 has left the window after 10 more episodes.
        let got = t.observe(&[-150.0, -50.0], 4000, 20, 5.0).cloned();
        let want = SolveRecord {
            env_steps: 4000,
            wall_seconds: 5.0,
            episodes: 20,
            running_mean: vec![-105.0, -50.0],
        };
        assert_eq!(got, Some(want.clone()));
        // Later episodes do not move the first record.
        assert!(t.observe(&[-2000.0, 0.0], 4200, 21, 6.0).is_none());
        assert_eq!(t.solved(), Some(&want));
    }

    #[test]
    fn unknown_objectives_are_named() {
        let thresholds = BTreeMap::from([("taks".to_string(), -200.0)]);
        let err = SolveTracker::new(&thresholds, &["task".to_string()])
            .unwrap_err()
            .to_string();
        assert_eq!(
            err,
            r#"run.solve_threshold.taks must be an objective of the env, one of ["task"], got "taks""#
        );
    }
}
