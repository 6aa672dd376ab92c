//! The distributions a policy network outputs (appendix A.2): a diagonal Gaussian's
//! mean and standard deviation, or a categorical's logits, with the log-probabilities,
//! samples and row selections the learner takes of them.
//!
//! Shape legend: P members, B states, R selected rows, M samples per state, D action
//! dims, A discrete actions.

use tch::{Kind, Tensor};

const HALF_LOG_TWO_PI: f64 = 0.918_938_533_204_672_7;

/// Mean and standard deviation of a diagonal Gaussian per state.
#[derive(Debug)]
pub struct GaussianParams {
    /// `[B, D]`.
    pub mean: Tensor,
    /// `[B, D]`, positive.
    pub std: Tensor,
}

impl GaussianParams {
    /// `log N(a; mean, diag(std^2))`, summed over D.
    /// # Shapes
    /// `actions [.., B, D]` (broadcast against `[B, D]`) `-> [.., B]`.
    pub fn log_prob(&self, actions: &Tensor) -> Tensor {
        let z = (actions - &self.mean) / &self.std;
        let per_dim = z.square() * -0.5 - self.std.log() - HALF_LOG_TWO_PI;
        per_dim.sum_dim_intlist(-1, false, Kind::Float)
    }

    /// The actions `mean + std * noise` for standard-normal `noise`.
    /// # Shapes
    /// `noise [M, B, D] -> [M, B, D]`.
    pub fn sample_from(&self, noise: &Tensor) -> Tensor {
        &self.mean + noise * &self.std
    }

    /// A copy with gradients cut.
    pub fn detach(&self) -> GaussianParams {
        GaussianParams {
            mean: self.mean.detach(),
            std: self.std.detach(),
        }
    }
}

/// Distribution parameters for a batch of states.
#[derive(Debug)]
pub enum PolicyOutput {
    /// Diagonal Gaussian.
    Gaussian(GaussianParams),
    /// Logits `[B, A]`.
    Categorical(Tensor),
}

impl PolicyOutput {
    /// The rows (states) at `index`. # Shapes `[B, ...]`, `index [R] i64 -> [R, ...]`.
    pub fn rows(&self, index: &Tensor) -> Self {
        match self {
            PolicyOutput::Gaussian(g) => PolicyOutput::Gaussian(GaussianParams {
                mean: g.mean.index_select(0, index),
                std: g.std.index_select(0, index),
            }),
            PolicyOutput::Categorical(logits) => {
                PolicyOutput::Categorical(logits.index_select(0, index))
            }
        }
    }

    /// Each member's rows at its own indices (states along axis 1).
    /// # Shapes `[P, B, ...]`, `index [P, R] i64 -> [P, R, ...]`.
    pub fn member_rows(&self, index: &Tensor) -> Self {
        let pick = |t: &Tensor| gather_rows(t, index);
        match self {
            PolicyOutput::Gaussian(g) => PolicyOutput::Gaussian(GaussianParams {
                mean: pick(&g.mean),
                std: pick(&g.std),
            }),
            PolicyOutput::Categorical(logits) => PolicyOutput::Categorical(pick(logits)),
        }
    }

    /// The first `len` states of every member (axis 1).
    pub fn narrow_states(&self, len: i64) -> Self {
        match self {
            PolicyOutput::Gaussian(g) => PolicyOutput::Gaussian(GaussianParams {
                mean: g.mean.narrow(1, 0, len),
                std: g.std.narrow(1, 0, len),
            }),
            PolicyOutput::Categorical(l) => PolicyOutput::Categorical(l.narrow(1, 0, len)),
        }
    }

    /// Log-probability of taken actions.
    /// # Shapes
    /// Gaussian `[B, D] f32`, categorical `[B] i64` `-> [B]`.
    pub fn log_prob(&self, actions: &Tensor) -> Tensor {
        match self {
            PolicyOutput::Gaussian(g) => g.log_prob(actions),
            PolicyOutput::Categorical(logits) => logits
                .log_softmax(-1, Kind::Float)
                .gather(-1, &actions.unsqueeze(-1), false)
                .squeeze_dim(-1),
        }
    }
}

/// Rows of `t [P, B, ...]` at `index [P, R]` along axis 1 `-> [P, R, ...]`.
pub fn gather_rows(t: &Tensor, index: &Tensor) -> Tensor {
    let size = t.size();
    let mut shape = index.size();
    shape.extend_from_slice(&size[2..]);
    let mut idx = index.shallow_clone();
    for _ in 2..size.len() {
        idx = idx.unsqueeze(-1);
    }
    t.gather(1, &idx.expand(shape.as_slice(), false), false)
}
