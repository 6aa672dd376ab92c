//! Replay of trajectory snippets for MO-MPO (appendix C.1, Algorithm 2), and the queue
//! of on-policy unrolls for MO-V-MPO (appendix D, Table 5).
//!
//! Actors cut each instance's stream of transitions into snippets of T steps
//! ([`adder::SnippetAdder`]). Off-policy, the learner samples B of them uniformly
//! ([`SnippetReplay::sample`]) as a [`SnippetBatch`] `[T(+1), B, ...]`; capacity is
//! counted in transitions (Table 2: 1e6) and stored as T-step snippets. On-policy
//! (`SnippetLayout::on_policy`), `sample` takes the B oldest unrolls out of the queue,
//! so each is used exactly once.

pub mod adder;

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use tch::Tensor;

use crate::core::algo::batch::SnippetBatch;
use crate::core::random::{Purpose, StreamKey};

/// Sizes of one snippet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SnippetLayout {
    /// Transitions per snippet T.
    pub length: usize,
    /// Flattened observation size O.
    pub obs_dim: usize,
    /// D for continuous actions, 1 (the index) for discrete ones.
    pub action_width: usize,
    /// Env reward columns K.
    pub num_rewards: usize,
    /// Discrete actions are stored as their index and batched as i64.
    pub discrete: bool,
    /// On-policy unrolls: disjoint (never overlapping) and consumed once, oldest first.
    pub on_policy: bool,
}

/// T transitions of one env instance; flat, time-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Snippet {
    /// `[T+1, O]`: s_0 .. s_T.
    pub observations: Vec<f32>,
    /// `[T, action_width]`.
    pub actions: Vec<f32>,
    /// `[T, K]`.
    pub rewards: Vec<f32>,
    /// `[T]`: 0 when s_{t+1} is terminal (or padding), else 1.
    pub discounts: Vec<f32>,
    /// `[T]`: log b(a_t|s_t).
    pub behaviour_log_probs: Vec<f32>,
    /// `[T]`: 1 for real transitions, 0 for padding after the episode's end.
    pub valid: Vec<f32>,
}

/// A snippet whose sizes do not match the replay's layout.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("snippet.{field}: expected {expected} values, got {got}")]
pub struct ReplayError {
    /// Field that was wrong.
    pub field: &'static str,
    /// Expected length.
    pub expected: usize,
    /// Received length.
    pub got: usize,
}

/// Uniform replay of snippets in a ring buffer.
#[derive(Debug)]
pub struct SnippetReplay {
    layout: SnippetLayout,
    capacity: usize,
    snippets: Vec<Snippet>,
    next: usize,
    inserted: u64,
    rng: ChaCha8Rng,
}

impl SnippetReplay {
    /// A replay holding up to `capacity_transitions / T` snippets, sampling with `seed`.
    pub fn new(layout: SnippetLayout, capacity_transitions: usize, seed: u64) -> Self {
        let capacity = (capacity_transitions / layout.length).max(1);
        Self {
            layout,
            capacity,
            snippets: Vec::new(),
            next: 0,
            inserted: 0,
            rng: StreamKey::new(seed, Purpose::Replay, 0).rng(),
        }
    }

    /// The snippet sizes.
    pub fn layout(&self) -> SnippetLayout {
        self.layout
    }

    /// Snippets held.
    pub fn len(&self) -> usize {
        self.snippets.len()
    }

    /// True when nothing has been inserted.
    pub fn is_empty(&self) -> bool {
        self.snippets.is_empty()
    }

    /// Snippets inserted since creation (including evicted ones).
    pub fn inserted(&self) -> u64 {
        self.inserted
    }

    /// Number (in insertion order, from 0) of the oldest snippet held: the replay holds
    /// snippets `held_from()..inserted()`, whether a full ring evicted the older ones
    /// or the learner took them off an on-policy queue.
    pub fn held_from(&self) -> u64 {
        self.inserted - self.snippets.len() as u64
    }

    /// Copies of the held snippets numbered `from..inserted()`, oldest first (`from`
    /// is raised to `held_from()`).
    pub fn snippets_from(&self, from: u64) -> Vec<Snippet> {
        let from = from.max(self.held_from());
        (from..self.inserted)
            .map(|j| self.snippets[self.slot(j)].clone())
            .collect()
    }

    /// Where snippet number `j` (held) sits: a full ring wraps at `capacity`; an
    /// on-policy queue is kept oldest first.
    fn slot(&self, j: u64) -> usize {
        if self.layout.on_policy {
            (j - self.held_from()) as usize
        } else {
            (j % self.capacity as u64) as usize
        }
    }

    /// The sampler's position in its stream (ChaCha8 words drawn), for a checkpoint.
    pub fn sampler_position(&self) -> u128 {
        self.rng.get_word_pos()
    }

    /// Refill from a checkpoint: `held` are the snippets numbered
    /// `inserted - held.len()..inserted`, oldest first; each goes back to the slot it
    /// had, and the sampler continues at `sampler_position`, so the learner samples
    /// what an uninterrupted run samples.
    pub fn restore(
        &mut self,
        held: Vec<Snippet>,
        inserted: u64,
        sampler_position: u128,
    ) -> Result<(), ReplayError> {
        if held.len() > self.capacity || held.len() as u64 > inserted {
            return Err(ReplayError {
                field: "held",
                expected: self.capacity.min(inserted as usize),
                got: held.len(),
            });
        }
        self.snippets = held;
        self.inserted = inserted;
        if !self.layout.on_policy && self.snippets.len() == self.capacity {
            let first = self.held_from();
            self.snippets
                .rotate_right((first % self.capacity as u64) as usize);
        }
        self.next = if self.layout.on_policy {
            self.snippets.len() % self.capacity
        } else {
            (inserted % self.capacity as u64) as usize
        };
        self.rng.set_word_pos(sampler_position);
        Ok(())
    }

    /// Add a snippet, evicting the oldest when full.
    pub fn insert(&mut self, snippet: Snippet) -> Result<(), ReplayError> {
        let l = self.layout;
        let check = |field, expected: usize, got: usize| {
            if expected == got {
                Ok(())
            } else {
                Err(ReplayError {
                    field,
                    expected,
                    got,
                })
            }
        };
        check(
            "observations",
            (l.length + 1) * l.obs_dim,
            snippet.observations.len(),
        )?;
        check("actions", l.length * l.action_width, snippet.actions.len())?;
        check("rewards", l.length * l.num_rewards, snippet.rewards.len())?;
        check("discounts", l.length, snippet.discounts.len())?;
        check(
            "behaviour_log_probs",
            l.length,
            snippet.behaviour_log_probs.len(),
        )?;
        check("valid", l.length, snippet.valid.len())?;
        if self.snippets.len() < self.capacity {
            self.snippets.push(snippet);
        } else {
            self.snippets[self.next] = snippet;
        }
        self.next = (self.next + 1) % self.capacity;
        self.inserted += 1;
        Ok(())
    }

    /// `batch_size` snippets as time-major tensors: drawn uniformly with replacement,
    /// or, on-policy, the oldest ones, removed.
    ///
    /// Panics when empty, or on-policy with fewer than `batch_size` unrolls queued
    /// (callers wait for them first).
    pub fn sample(&mut self, batch_size: usize) -> SnippetBatch {
        assert!(!self.snippets.is_empty(), "sampling an empty replay");
        if self.layout.on_policy {
            assert!(
                self.snippets.len() >= batch_size,
                "on-policy batch of {batch_size} from {}",
                self.snippets.len()
            );
            let picks: Vec<usize> = (0..batch_size).collect();
            let batch = self.gather(&picks);
            self.snippets.drain(..batch_size);
            self.next = self.snippets.len() % self.capacity;
            return batch;
        }
        let picks: Vec<usize> = (0..batch_size)
            .map(|_| self.rng.random_range(0..self.snippets.len()))
            .collect();
        self.gather(&picks)
    }

    fn gather(&self, picks: &[usize]) -> SnippetBatch {
        let batch_size = picks.len();
        let l = self.layout;
        let (t, b) = (l.length, batch_size);
        // Gather field `f` of every picked snippet into time-major [steps, B, width].
        let gather = |f: fn(&Snippet) -> &[f32], steps: usize, width: usize| -> Vec<f32> {
            let mut out = vec![0.0f32; steps * b * width];
            for (j, &i) in picks.iter().enumerate() {
                let src = f(&self.snippets[i]);
                for s in 0..steps {
                    let dst = (s * b + j) * width;
                    out[dst..dst + width].copy_from_slice(&src[s * width..(s + 1) * width]);
                }
            }
            out
        };
        let (t_, b_) = (t as i64, b as i64);
        let observations = Tensor::from_slice(&gather(|s| &s.observations, t + 1, l.obs_dim))
            .view([t_ + 1, b_, l.obs_dim as i64]);
        let actions_flat = gather(|s| &s.actions, t, l.action_width);
        let actions = if l.discrete {
            let idx: Vec<i64> = actions_flat.iter().map(|&a| a as i64).collect();
            Tensor::from_slice(&idx).view([t_, b_])
        } else {
            Tensor::from_slice(&actions_flat).view([t_, b_, l.action_width as i64])
        };
        SnippetBatch {
            observations,
            actions,
            rewards: Tensor::from_slice(&gather(|s| &s.rewards, t, l.num_rewards)).view([
                t_,
                b_,
                l.num_rewards as i64,
            ]),
            discounts: Tensor::from_slice(&gather(|s| &s.discounts, t, 1)).view([t_, b_]),
            behaviour_log_probs: Tensor::from_slice(&gather(|s| &s.behaviour_log_probs, t, 1))
                .view([t_, b_]),
            valid: Tensor::from_slice(&gather(|s| &s.valid, t, 1)).view([t_, b_]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> SnippetLayout {
        SnippetLayout {
            length: 2,
            obs_dim: 1,
            action_width: 1,
            num_rewards: 2,
            discrete: true,
            on_policy: false,
        }
    }

    fn snippet(tag: f32) -> Snippet {
        Snippet {
            observations: vec![tag, tag + 0.1, tag + 0.2],
            actions: vec![1.0, 3.0],
            rewards: vec![tag, -tag, tag, -tag],
            discounts: vec![1.0, 0.0],
            behaviour_log_probs: vec![-0.5, -0.25],
            valid: vec![1.0, 1.0],
        }
    }

    #[test]
    fn sample_is_time_major_and_keeps_fields_of_one_snippet_together() {
        let mut replay = SnippetReplay::new(layout(), 100, 0);
        replay.insert(snippet(1.0)).unwrap();
        replay.insert(snippet(2.0)).unwrap();
        let batch = replay.sample(16);
        assert_eq!(batch.observations.size(), [3, 16, 1]);
        assert_eq!(batch.actions.size(), [2, 16]);
        assert_eq!(batch.actions.kind(), tch::Kind::Int64);
        assert_eq!(batch.rewards.size(), [2, 16, 2]);
        for j in 0..16 {
            let tag = batch.observations.double_value(&[0, j, 0]);
            assert!((batch.observations.double_value(&[2, j, 0]) - (tag + 0.2)).abs() < 1e-6);
            assert_eq!(batch.rewards.double_value(&[1, j, 1]), -tag);
            assert_eq!(batch.actions.int64_value(&[1, j]), 3);
            assert_eq!(batch.discounts.double_value(&[1, j]), 0.0);
        }
    }

    #[test]
    fn full_replay_evicts_the_oldest_snippet() {
        // Capacity 4 transitions = 2 snippets of T = 2.
        let mut replay = SnippetReplay::new(layout(), 4, 0);
        for tag in [1.0, 2.0, 3.0] {
            replay.insert(snippet(tag)).unwrap();
        }
        assert_eq!((replay.len(), replay.inserted()), (2, 3));
        let batch = replay.sample(64);
        let first: Vec<f64> = (0..64)
            .map(|j| batch.observations.double_value(&[0, j, 0]))
            .collect();
        assert!(
            first.iter().all(|&t| t == 2.0 || t == 3.0),
            "snippet 1 was evicted: {first:?}"
        );
        assert!(first.contains(&2.0) && first.contains(&3.0));
    }

    #[test]
    fn on_policy_batches_take_the_oldest_unrolls_once() {
        let layout = SnippetLayout {
            on_policy: true,
            ..layout()
        };
        let mut queue = SnippetReplay::new(layout, usize::MAX, 0);
        for tag in [1.0, 2.0, 3.0] {
            queue.insert(snippet(tag)).unwrap();
        }
        let batch = queue.sample(2);
        let tags: Vec<f64> = (0..2)
            .map(|j| batch.observations.double_value(&[0, j, 0]))
            .collect();
        assert_eq!(tags, [1.0, 2.0]);
        assert_eq!(queue.len(), 1);
        queue.insert(snippet(4.0)).unwrap();
        let batch = queue.sample(2);
        let tags: Vec<f64> = (0..2)
            .map(|j| batch.observations.double_value(&[0, j, 0]))
            .collect();
        assert_eq!(tags, [3.0, 4.0]);
        assert!(queue.is_empty());
    }

    #[test]
    fn a_restored_replay_samples_what_the_original_samples() {
        // Capacity 3 snippets, 5 inserted: the ring has wrapped (slots hold 3, 4, 2).
        let mut original = SnippetReplay::new(layout(), 6, 9);
        for tag in 0..5 {
            original.insert(snippet(tag as f32)).unwrap();
        }
        original.sample(4);
        assert_eq!(original.held_from(), 2);
        let held = original.snippets_from(0);
        let mut restored = SnippetReplay::new(layout(), 6, 9);
        restored
            .restore(held, original.inserted(), original.sampler_position())
            .unwrap();
        let (a, b) = (original.sample(32), restored.sample(32));
        assert!(a.observations.equal(&b.observations));
        original.insert(snippet(7.0)).unwrap();
        restored.insert(snippet(7.0)).unwrap();
        assert_eq!(original.snippets_from(0), restored.snippets_from(0));
        assert!(
            original
                .sample(32)
                .rewards
                .equal(&restored.sample(32).rewards)
        );
    }

    #[test]
    fn wrong_sizes_are_rejected_with_the_field_name() {
        let mut replay = SnippetReplay::new(layout(), 100, 0);
        let mut bad = snippet(1.0);
        bad.rewards.pop();
        let err = replay.insert(bad).unwrap_err();
        assert_eq!(err.to_string(), "snippet.rewards: expected 4 values, got 3");
    }
}
