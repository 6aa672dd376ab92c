//! Cuts one env instance's transitions into T-step snippets (appendix C.2).
//!
//! Within an episode a snippet is emitted every T transitions. When an episode
//! ends with transitions not yet emitted, its last T transitions are emitted
//! (overlapping the previous snippet) for off-policy replay; on-policy unrolls
//! (`SnippetLayout::on_policy`) never overlap, so each transition is used once, and
//! carry only the transitions not yet emitted. Missing steps are padding: absorbing
//! steps with reward 0, discount 0, `valid` 0 and a behaviour log-probability of
//! [`PAD_LOG_PROB`], which makes the Retrace trace coefficient c = min(1, π/b) ≈ 0,
//! so padding never leaks into the targets of real steps.

use std::collections::VecDeque;

use super::{Snippet, SnippetLayout};

/// log b(a|s) of padding steps: e^-60 relative to any real density cuts the trace.
pub const PAD_LOG_PROB: f32 = 60.0;

/// One transition as the actor saw it.
#[derive(Debug, Clone, PartialEq)]
pub struct AdderStep<'a> {
    /// Action taken (`[D]`, or `[1]` holding the discrete index).
    pub action: &'a [f32],
    /// Reward vector `[K]`.
    pub reward: &'a [f32],
    /// Observation after the step (the episode's last one when it ended).
    pub next_observation: &'a [f32],
    /// The MDP ended: no bootstrapping from `next_observation`.
    pub terminated: bool,
    /// A time limit ended the episode (bootstrapping stays valid).
    pub truncated: bool,
    /// log b(a|s) of the acting policy.
    pub log_prob: f32,
}

#[derive(Debug, Clone)]
struct Transition {
    observation: Vec<f32>,
    action: Vec<f32>,
    reward: Vec<f32>,
    discount: f32,
    log_prob: f32,
}

/// Per-instance snippet builder.
#[derive(Debug, Clone)]
pub struct SnippetAdder {
    layout: SnippetLayout,
    window: VecDeque<Transition>,
    current: Option<Vec<f32>>,
    since_emit: usize,
}

impl SnippetAdder {
    /// An adder waiting for its first observation.
    pub fn new(layout: SnippetLayout) -> Self {
        Self {
            layout,
            window: VecDeque::with_capacity(layout.length),
            current: None,
            since_emit: 0,
        }
    }

    /// Start an episode at `observation`.
    pub fn observe_first(&mut self, observation: &[f32]) {
        self.window.clear();
        self.since_emit = 0;
        self.current = Some(observation.to_vec());
    }

    /// Record one transition; returns a snippet when one is complete.
    ///
    /// Panics if no episode was started with [`SnippetAdder::observe_first`].
    pub fn add(&mut self, step: AdderStep<'_>) -> Option<Snippet> {
        let observation = self.current.take().expect("observe_first before add");
        if self.window.len() == self.layout.length {
            self.window.pop_front();
        }
        self.window.push_back(Transition {
            observation,
            action: step.action.to_vec(),
            reward: step.reward.to_vec(),
            discount: if step.terminated { 0.0 } else { 1.0 },
            log_prob: step.log_prob,
        });
        self.since_emit += 1;
        let ended = step.terminated || step.truncated;
        let snippet = if self.since_emit == self.layout.length || (ended && self.since_emit > 0) {
            let fresh = if self.layout.on_policy {
                self.since_emit
            } else {
                self.window.len()
            };
            self.since_emit = 0;
            Some(self.emit(step.next_observation, fresh))
        } else {
            None
        };
        if ended {
            self.window.clear();
        } else {
            self.current = Some(step.next_observation.to_vec());
        }
        snippet
    }

    /// The newest `count` transitions of the window, padded to T.
    fn emit(&self, last_observation: &[f32], count: usize) -> Snippet {
        let l = self.layout;
        let mut s = Snippet {
            observations: Vec::with_capacity((l.length + 1) * l.obs_dim),
            actions: Vec::with_capacity(l.length * l.action_width),
            rewards: Vec::with_capacity(l.length * l.num_rewards),
            discounts: Vec::with_capacity(l.length),
            behaviour_log_probs: Vec::with_capacity(l.length),
            valid: Vec::with_capacity(l.length),
        };
        for t in self.window.iter().skip(self.window.len() - count) {
            s.observations.extend_from_slice(&t.observation);
            s.actions.extend_from_slice(&t.action);
            s.rewards.extend_from_slice(&t.reward);
            s.discounts.push(t.discount);
            s.behaviour_log_probs.push(t.log_prob);
            s.valid.push(1.0);
        }
        for _ in count..l.length {
            s.observations.extend_from_slice(last_observation);
            s.actions.extend(std::iter::repeat_n(0.0, l.action_width));
            s.rewards.extend(std::iter::repeat_n(0.0, l.num_rewards));
            s.discounts.push(0.0);
            s.behaviour_log_probs.push(PAD_LOG_PROB);
            s.valid.push(0.0);
        }
        s.observations.extend_from_slice(last_observation);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(length: usize) -> SnippetLayout {
        SnippetLayout {
            length,
            obs_dim: 1,
            action_width: 1,
            num_rewards: 1,
            discrete: true,
            on_policy: false,
        }
    }

    /// Steps t = 0.. of an episode: obs t, action t, reward 10 t, next obs t + 1.
    fn run(adder: &mut SnippetAdder, steps: usize, end: Option<bool>) -> Vec<Snippet> {
        adder.observe_first(&[0.0]);
        (0..steps)
            .filter_map(|t| {
                let last = t + 1 == steps;
                adder.add(AdderStep {
                    action: &[t as f32],
                    reward: &[10.0 * t as f32],
                    next_observation: &[t as f32 + 1.0],
                    terminated: last && end == Some(true),
                    truncated: last && end == Some(false),
                    log_prob: -1.0,
                })
            })
            .collect()
    }

    #[test]
    fn snippets_every_t_steps_then_the_overlapping_tail_at_episode_end() {
        let mut adder = SnippetAdder::new(layout(3));
        let snippets = run(&mut adder, 7, Some(true));
        // Steps 0-2, 3-5, then the tail 4-6 (overlapping) because step 6 ended the episode.
        assert_eq!(snippets.len(), 3);
        assert_eq!(snippets[0].observations, [0.0, 1.0, 2.0, 3.0]);
        assert_eq!(snippets[1].actions, [3.0, 4.0, 5.0]);
        assert_eq!(snippets[2].actions, [4.0, 5.0, 6.0]);
        assert_eq!(snippets[2].observations, [4.0, 5.0, 6.0, 7.0]);
        assert_eq!(snippets[2].discounts, [1.0, 1.0, 0.0]);
        assert_eq!(snippets[1].discounts, [1.0, 1.0, 1.0]);
    }

    #[test]
    fn truncation_keeps_the_bootstrap_discount() {
        let mut adder = SnippetAdder::new(layout(2));
        let snippets = run(&mut adder, 4, Some(false));
        assert_eq!(snippets.len(), 2);
        assert_eq!(snippets[1].discounts, [1.0, 1.0]);
        assert_eq!(snippets[1].observations, [2.0, 3.0, 4.0]);
    }

    #[test]
    fn short_episodes_are_padded_with_absorbing_steps() {
        let mut adder = SnippetAdder::new(layout(4));
        let snippets = run(&mut adder, 2, Some(true));
        assert_eq!(snippets.len(), 1);
        let s = &snippets[0];
        assert_eq!(s.observations, [0.0, 1.0, 2.0, 2.0, 2.0]);
        assert_eq!(s.rewards, [0.0, 10.0, 0.0, 0.0]);
        assert_eq!(s.discounts, [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(
            s.behaviour_log_probs,
            [-1.0, -1.0, PAD_LOG_PROB, PAD_LOG_PROB]
        );
        assert_eq!(s.valid, [1.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn on_policy_unrolls_are_disjoint_and_pad_the_tail() {
        let mut adder = SnippetAdder::new(SnippetLayout {
            on_policy: true,
            ..layout(3)
        });
        let snippets = run(&mut adder, 7, Some(false));
        // Steps 0-2, 3-5, then step 6 alone, padded; truncation keeps its discount 1.
        assert_eq!(snippets.len(), 3);
        assert_eq!(snippets[2].actions, [6.0, 0.0, 0.0]);
        assert_eq!(snippets[2].observations, [6.0, 7.0, 7.0, 7.0]);
        assert_eq!(snippets[2].discounts, [1.0, 0.0, 0.0]);
        assert_eq!(snippets[2].valid, [1.0, 0.0, 0.0]);
        assert_eq!(snippets[1].valid, [1.0, 1.0, 1.0]);
    }

    #[test]
    fn one_step_snippets_for_td0() {
        let mut adder = SnippetAdder::new(layout(1));
        let snippets = run(&mut adder, 3, Some(true));
        assert_eq!(snippets.len(), 3);
        assert_eq!(snippets[2].observations, [2.0, 3.0]);
        assert_eq!(snippets[2].discounts, [0.0]);
    }
}
