//! Policy and critic networks (appendix A, Tables 2 and 3).
//!
//! Every network starts with Linear -> LayerNorm -> tanh and uses ELU after the
//! other hidden layers. Shape legend: B batch (states), M sampled actions per state,
//! D action dims, A discrete actions, C learned critics (heads).

pub mod activation;
pub mod critic;
pub mod dims;
pub mod distribution;
pub mod heads;
pub mod mlp;
pub mod policy;
pub mod snapshot;
#[cfg(test)]
mod testing;
pub mod torso;
pub mod value;

pub use critic::MultiCritic;
pub use dims::{ActionBounds, LearnerDims, ObsLeaf, ObsSplit};
pub use distribution::{GaussianParams, PolicyOutput, gather_rows};
pub use mlp::Members;
pub use policy::{ActOutput, Acting, CategoricalPolicy, GaussianPolicy, Policy, STD_VARIABLE};
pub use snapshot::{ActorPolicy, NamedArray, PolicySnapshot, SnapshotError};
pub use value::ValueNet;

/// The action space as the networks see it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActionKind {
    /// A box of `dim` reals (Gaussian policy).
    Continuous {
        /// Number of action dimensions D.
        dim: i64,
    },
    /// `n` choices 0..n (categorical policy, one-hot critic input).
    Discrete {
        /// Number of actions A.
        n: i64,
    },
}

impl ActionKind {
    /// Width of the critic's action input (D, or A for one-hot).
    pub fn critic_input_dim(self) -> i64 {
        match self {
            ActionKind::Continuous { dim } => dim,
            ActionKind::Discrete { n } => n,
        }
    }
}
