//! The learner's input: B trajectory snippets of T steps (T = Retrace length, C.2).
//!
//! Shape legend: P members, T snippet length, B snippets, O observation size, D action
//! dims, K env reward columns, C critic heads.

use crate::core::nets::ActionKind;
use tch::{Device, Kind, Tensor};

/// B snippets `(s_0, a_0, r_0, ..., s_{T-1}, a_{T-1}, r_{T-1}, s_T)`.
#[derive(Debug)]
pub struct SnippetBatch {
    /// `[T+1, B, O]` f32.
    pub observations: Tensor,
    /// `[T, B, D]` f32 (the sampled, unclipped action) or `[T, B]` i64 (0-based index).
    pub actions: Tensor,
    /// `[T, B, K]` f32, columns in env objective order.
    pub rewards: Tensor,
    /// `[T, B]` f32: 0 when s_{t+1} is terminal, else 1 (truncation keeps 1).
    pub discounts: Tensor,
    /// `[T, B]` f32: log b(a_t|s_t) of the acting policy.
    pub behaviour_log_probs: Tensor,
    /// `[T, B]` f32: 1 for real transitions, 0 for padding after an episode's end.
    pub valid: Tensor,
}

/// The sizes of the members' batches stacked member-first (`[P, T+1, B, ..]`) and of
/// the learner's critic heads: what a step's tensors are reshaped by.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StepShape {
    /// P members.
    pub(crate) members: i64,
    /// T steps per snippet (unroll).
    pub(crate) t_len: i64,
    /// B snippets (unrolls) per member.
    pub(crate) b: i64,
    /// C critic heads.
    pub(crate) heads: i64,
}

impl StepShape {
    /// The shape of `stacked`, a member-first batch, for `heads` critic heads.
    pub(crate) fn of(stacked: &SnippetBatch, heads: i64) -> Self {
        let size = stacked.observations.size();
        Self {
            members: size[0],
            t_len: size[1] - 1,
            b: size[2],
            heads,
        }
    }

    /// (T+1)B states: every snippet's T states acted from and its last one.
    pub(crate) fn states(&self) -> i64 {
        (self.t_len + 1) * self.b
    }

    /// TB taken (state, action) pairs.
    pub(crate) fn pairs(&self) -> i64 {
        self.t_len * self.b
    }
}

/// A batch whose shapes or dtypes do not match the learner.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("SnippetBatch.{field}: expected {expected}, got {got}")]
pub struct BatchError {
    /// Field name.
    pub field: &'static str,
    /// Expected shape and dtype.
    pub expected: String,
    /// Received shape and dtype.
    pub got: String,
}

fn expect(field: &'static str, t: &Tensor, shape: &[i64], kind: Kind) -> Result<(), BatchError> {
    if t.size() == shape && t.kind() == kind {
        return Ok(());
    }
    Err(BatchError {
        field,
        expected: format!("{shape:?} {kind:?}"),
        got: format!("{:?} {:?}", t.size(), t.kind()),
    })
}

impl SnippetBatch {
    /// Snippet length T.
    pub fn len(&self) -> i64 {
        self.actions.size()[0]
    }

    /// True when T = 0.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of snippets B.
    pub fn batch_size(&self) -> i64 {
        self.actions.size()[1]
    }

    /// Checks every shape and dtype against the learner's dimensions.
    pub fn check(
        &self,
        obs_dim: i64,
        action: ActionKind,
        num_rewards: i64,
    ) -> Result<(), BatchError> {
        let (t, b) = (self.len(), self.batch_size());
        expect(
            "observations",
            &self.observations,
            &[t + 1, b, obs_dim],
            Kind::Float,
        )?;
        match action {
            ActionKind::Continuous { dim } => {
                expect("actions", &self.actions, &[t, b, dim], Kind::Float)?
            }
            ActionKind::Discrete { .. } => expect("actions", &self.actions, &[t, b], Kind::Int64)?,
        }
        expect("rewards", &self.rewards, &[t, b, num_rewards], Kind::Float)?;
        expect("discounts", &self.discounts, &[t, b], Kind::Float)?;
        expect(
            "behaviour_log_probs",
            &self.behaviour_log_probs,
            &[t, b],
            Kind::Float,
        )?;
        expect("valid", &self.valid, &[t, b], Kind::Float)
    }

    /// The snippets at `index` (on the batch's device), in that order.
    /// # Shapes
    /// `index [B'] i64 -> ` a batch of B' snippets.
    pub fn select_unrolls(&self, index: &Tensor) -> SnippetBatch {
        SnippetBatch {
            observations: self.observations.index_select(1, index),
            actions: self.actions.index_select(1, index),
            rewards: self.rewards.index_select(1, index),
            discounts: self.discounts.index_select(1, index),
            behaviour_log_probs: self.behaviour_log_probs.index_select(1, index),
            valid: self.valid.index_select(1, index),
        }
    }

    /// The same batch on `device`.
    pub fn to_device(&self, device: Device) -> SnippetBatch {
        SnippetBatch {
            observations: self.observations.to_device(device),
            actions: self.actions.to_device(device),
            rewards: self.rewards.to_device(device),
            discounts: self.discounts.to_device(device),
            behaviour_log_probs: self.behaviour_log_probs.to_device(device),
            valid: self.valid.to_device(device),
        }
    }
}
