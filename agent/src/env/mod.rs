//! Environments as the agent sees them: a batch of B instances with a K-vector reward.
//!
//! [`Env`] is the one interface actors use; [`grpc::RemoteEnv`] implements it over
//! the wire and [`server_process::LocalServer`] starts a local `env_server` for
//! demos and tests. Shapes: observations `[B, ...]` per leaf, reward `[B, K]`.

pub mod connection;
pub mod deadline;
pub mod discovery;
pub mod error;
pub mod frames;
pub mod grpc;
pub mod pool;
pub mod server_process;

use serde::Serialize;

use crate::core::spec::{AutoresetMode, DType, EnvSpec};
use crate::env::error::EnvError;

/// A dense host tensor: little-endian, row-major bytes plus dtype and shape.
#[derive(Debug, Clone, PartialEq)]
pub struct HostTensor {
    /// Element type.
    pub dtype: DType,
    /// Shape, batch dimension first where there is one.
    pub shape: Vec<usize>,
    /// `numel * dtype.itemsize()` bytes.
    pub data: Vec<u8>,
}

impl HostTensor {
    /// A float32 tensor; `values.len()` must equal the product of `shape`.
    pub fn from_f32(shape: Vec<usize>, values: &[f32]) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), values.len());
        let data = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        Self {
            dtype: DType::Float32,
            shape,
            data,
        }
    }

    /// An int64 tensor; `values.len()` must equal the product of `shape`.
    pub fn from_i64(shape: Vec<usize>, values: &[i64]) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), values.len());
        let data = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        Self {
            dtype: DType::Int64,
            shape,
            data,
        }
    }

    /// Number of elements.
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }

    /// Every element converted to f32 (integers and bools included).
    pub fn to_f32_vec(&self) -> Vec<f32> {
        fn chunks<const N: usize>(data: &[u8]) -> impl Iterator<Item = [u8; N]> + '_ {
            data.chunks_exact(N)
                .map(|c| c.try_into().expect("exact chunk"))
        }
        match self.dtype {
            DType::Float32 => chunks::<4>(&self.data).map(f32::from_le_bytes).collect(),
            DType::Float64 => chunks::<8>(&self.data)
                .map(|b| f64::from_le_bytes(b) as f32)
                .collect(),
            DType::Int32 => chunks::<4>(&self.data)
                .map(|b| i32::from_le_bytes(b) as f32)
                .collect(),
            DType::Int64 => chunks::<8>(&self.data)
                .map(|b| i64::from_le_bytes(b) as f32)
                .collect(),
            DType::Uint8 | DType::Bool => self.data.iter().map(|&b| f32::from(b)).collect(),
        }
    }
}

/// One leaf of a batched observation (name "" for non-Dict spaces).
#[derive(Debug, Clone, PartialEq)]
pub struct NamedTensor {
    /// "."-joined Dict path, or "".
    pub name: String,
    /// `[B, ...]` values.
    pub tensor: HostTensor,
}

/// A batched observation: one tensor per leaf, in spec order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Observation {
    /// Leaves in the order of the observation space.
    pub leaves: Vec<NamedTensor>,
}

impl Observation {
    /// Rows (batch size) of the observation; 0 when empty.
    pub fn batch_size(&self) -> usize {
        self.leaves
            .first()
            .and_then(|l| l.tensor.shape.first().copied())
            .unwrap_or(0)
    }

    /// Flatten every leaf of every row into `[B, obs_dim]` f32, leaves concatenated per row.
    pub fn to_flat_f32(&self) -> Vec<f32> {
        let b = self.batch_size();
        if self.leaves.len() == 1 {
            return self.leaves[0].tensor.to_f32_vec();
        }
        let per_leaf: Vec<Vec<f32>> = self.leaves.iter().map(|l| l.tensor.to_f32_vec()).collect();
        let widths: Vec<usize> = per_leaf
            .iter()
            .map(|v| v.len().checked_div(b).unwrap_or(0))
            .collect();
        let mut out = Vec::with_capacity(per_leaf.iter().map(Vec::len).sum());
        for row in 0..b {
            for (values, &w) in per_leaf.iter().zip(&widths) {
                out.extend_from_slice(&values[row * w..(row + 1) * w]);
            }
        }
        out
    }
}

/// Returns of one finished episode, as computed by the server.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpisodeSummary {
    /// Which instance of the session.
    pub env_index: usize,
    /// Undiscounted vector return, K entries.
    pub episode_return: Vec<f64>,
    /// Σ_t γ^t r_t with γ = `EnvSpec::discount`, K entries.
    pub discounted_return: Vec<f64>,
    /// Steps in the episode.
    pub length: u64,
    /// Ended by the MDP (no bootstrapping).
    pub terminated: bool,
    /// Ended by a time limit (bootstrapping is valid).
    pub truncated: bool,
}

/// What `reset` returns.
#[derive(Debug, Clone, PartialEq)]
pub struct ResetResult {
    /// `[n, ...]` for the n reset instances.
    pub observation: Observation,
    /// Requested info keys.
    pub info: Vec<NamedTensor>,
}

/// What `step` returns for the whole batch.
#[derive(Debug, Clone, PartialEq)]
pub struct StepResult {
    /// `[B, ...]` next observations (first observation of a new episode after an autoreset).
    pub observation: Observation,
    /// `[B, K]` row-major rewards in objective order.
    pub reward: Vec<f32>,
    /// `[B]` episode ended by the MDP.
    pub terminated: Vec<bool>,
    /// `[B]` episode ended by a time limit.
    pub truncated: Vec<bool>,
    /// Requested info keys, `[B, ...]` each.
    pub info: Vec<NamedTensor>,
    /// One entry per instance whose episode ended in this step.
    pub episodes: Vec<EpisodeSummary>,
    /// SAME_STEP autoreset: last observation of each ended episode, in `episodes` order.
    pub final_observation: Observation,
}

/// How to create a session.
#[derive(Debug, Clone, PartialEq)]
pub struct MakeOptions {
    /// Registry id, e.g. `dst`, `humanoid-run`, `gym:Pendulum-v1`.
    pub env_id: String,
    /// Number of instances B.
    pub num_envs: usize,
    /// Constructor keyword arguments (a JSON object).
    pub kwargs: serde_json::Map<String, serde_json::Value>,
    /// Instance i is seeded with seed + i.
    pub seed: Option<u64>,
    /// What happens when an episode ends inside `step`.
    pub autoreset_mode: AutoresetMode,
    /// Discount for the server's discounted returns (server default 0.99).
    pub discount: Option<f64>,
    /// Info keys to receive with every step.
    pub info_keys: Vec<String>,
    /// Worker processes that step shares of the instances in parallel with the server
    /// process (0 = none; at most `num_envs - 1`).
    pub num_workers: usize,
}

impl MakeOptions {
    /// Defaults for everything but the id and batch size.
    pub fn new(env_id: impl Into<String>, num_envs: usize) -> Self {
        Self {
            env_id: env_id.into(),
            num_envs,
            kwargs: serde_json::Map::new(),
            seed: None,
            autoreset_mode: AutoresetMode::SameStep,
            discount: None,
            info_keys: Vec::new(),
            num_workers: 0,
        }
    }
}

/// A batch of B environment instances with a vector reward.
#[allow(
    async_fn_in_trait,
    reason = "used with concrete types inside this crate's runtime"
)]
pub trait Env {
    /// The session's spec.
    fn spec(&self) -> &EnvSpec;

    /// Reset the given instances (empty = all) with optional seeds.
    async fn reset(
        &mut self,
        env_indices: &[usize],
        seeds: &[u64],
    ) -> Result<ResetResult, EnvError>;

    /// Step all B instances; `action` is `[B, ...]` (f32 Box or i64 Discrete).
    async fn step(&mut self, action: &HostTensor) -> Result<StepResult, EnvError>;

    /// Release the session.
    async fn close(self) -> Result<(), EnvError>;
}

/// Uniformly random actions for all B instances: inside the Box bounds (unbounded
/// dimensions use [-1, 1]) or uniform over the Discrete choices.
pub fn random_action<R: rand::RngExt>(
    space: &crate::core::spec::Space,
    num_envs: usize,
    rng: &mut R,
) -> HostTensor {
    use crate::core::spec::Space;
    match space {
        Space::Box(b) => {
            let mut values = Vec::with_capacity(num_envs * b.numel());
            for _ in 0..num_envs {
                for (&lo, &hi) in b.low.iter().zip(&b.high) {
                    let (lo, hi) = if lo.is_finite() && hi.is_finite() {
                        (lo, hi)
                    } else {
                        (-1.0, 1.0)
                    };
                    values.push(rng.random_range(lo..=hi) as f32);
                }
            }
            let mut shape = vec![num_envs];
            shape.extend(&b.shape);
            HostTensor::from_f32(shape, &values)
        }
        Space::Discrete(d) => {
            let values: Vec<i64> = (0..num_envs)
                .map(|_| d.start + rng.random_range(0..d.n))
                .collect();
            HostTensor::from_i64(vec![num_envs], &values)
        }
        Space::Dict(_) => panic!("Dict action spaces are not supported by random_action"),
    }
}
