//! What an environment looks like: spaces, objectives, episode limits.
//!
//! Plain Rust mirrors of the wire protocol's `EnvSpec` (the proto conversion
//! lives only in `env/grpc.rs`). The reward of an env with K objectives is a
//! `[B, K]` array whose columns follow `EnvSpec::objectives` order.

use serde::{Deserialize, Serialize};

/// Element type of a tensor or Box space.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DType {
    /// 32-bit float.
    Float32,
    /// 64-bit float.
    Float64,
    /// 32-bit signed integer.
    Int32,
    /// 64-bit signed integer.
    Int64,
    /// 8-bit unsigned integer.
    Uint8,
    /// One byte, 0 or 1.
    Bool,
}

impl DType {
    /// Bytes per element.
    pub fn itemsize(self) -> usize {
        match self {
            DType::Float32 | DType::Int32 => 4,
            DType::Float64 | DType::Int64 => 8,
            DType::Uint8 | DType::Bool => 1,
        }
    }

    /// Lower-case name, as numpy spells it.
    pub fn name(self) -> &'static str {
        match self {
            DType::Float32 => "float32",
            DType::Float64 => "float64",
            DType::Int32 => "int32",
            DType::Int64 => "int64",
            DType::Uint8 => "uint8",
            DType::Bool => "bool",
        }
    }
}

/// A continuous (or integer) box `low <= x <= high` of a fixed shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoxSpace {
    /// Element type.
    pub dtype: DType,
    /// Shape of one sample (without the batch dimension).
    pub shape: Vec<usize>,
    /// Lower bounds, one per element (broadcast already applied).
    pub low: Vec<f64>,
    /// Upper bounds, one per element.
    pub high: Vec<f64>,
}

impl BoxSpace {
    /// Number of elements in one sample.
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }
}

/// `n` choices `start, ..., start + n - 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiscreteSpace {
    /// Number of choices.
    pub n: i64,
    /// Smallest choice.
    pub start: i64,
}

/// A space: Box, Discrete, or an ordered Dict of named sub-spaces.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Space {
    /// Continuous or integer box.
    Box(BoxSpace),
    /// Finite set of integers.
    Discrete(DiscreteSpace),
    /// Ordered named sub-spaces; observation leaves use "."-joined names.
    Dict(Vec<(String, Space)>),
}

impl Space {
    /// Number of scalars in one flattened sample (Discrete counts as 1).
    pub fn flat_dim(&self) -> usize {
        match self {
            Space::Box(b) => b.numel(),
            Space::Discrete(_) => 1,
            Space::Dict(entries) => entries.iter().map(|(_, s)| s.flat_dim()).sum(),
        }
    }
}

/// One named entry of the vector reward.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectiveSpec {
    /// Unique name, e.g. `task`, `action_norm`, `pain`.
    pub name: String,
    /// One line saying what the reward measures.
    pub description: String,
    /// Smallest per-step reward (may be -inf).
    pub min: f64,
    /// Largest per-step reward (may be +inf).
    pub max: f64,
    /// What the server multiplies this reward by (Make kwarg `reward_scale`, e.g.
    /// `[env.kwargs] reward_scale = { task = 10.0 }`); `min` and `max` include it.
    #[serde(default = "unscaled")]
    pub scale: f64,
    /// The formula the env declares for this reward, if the learner may compute it
    /// instead of learning it (`learner.objectives[..].source` other than `learned`).
    #[serde(default)]
    pub closed_form: ClosedForm,
}

fn unscaled() -> f64 {
    1.0
}

/// What an env declares an objective's per-step reward to be as a function of the
/// step's action alone (`ObjectiveSpec.closed_form` on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClosedForm {
    /// Nothing declared either way: the server is older than the declaration (or its
    /// native front was built before it, and dropped the field).
    #[default]
    Undeclared,
    /// No closed form: the reward depends on more than the action.
    None,
    /// `reward = -scale * ||a||_2`, `a` the action the env executes for the step (the
    /// agent sends the policy's sample clipped to [-1, 1] and mapped onto the Box,
    /// `ActionBounds::to_env`; the server refuses actions outside the Box and nothing
    /// clips or rescales them after) and `||.||_2` the Euclidean norm over all its
    /// elements; Box action spaces only, `min`/`max` exact over the Box.
    ActionNorm,
    /// A value this agent does not know (a newer server's closed form).
    Unrecognized(i32),
}

impl std::fmt::Display for ClosedForm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ClosedForm::Undeclared => write!(f, "nothing (the field is unset)"),
            ClosedForm::None => write!(f, "closed_form = none"),
            ClosedForm::ActionNorm => write!(f, "closed_form = action_norm"),
            ClosedForm::Unrecognized(v) => write!(f, "closed_form = {v} (unknown to this agent)"),
        }
    }
}

/// What the server does when an instance's episode ends inside `step`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutoresetMode {
    /// Reset inside the same step; the last observation comes back separately.
    #[default]
    SameStep,
    /// gymnasium's default: the following step resets the instance.
    NextStep,
    /// The client calls `reset` for ended instances.
    Disabled,
}

/// Full description of a made environment session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvSpec {
    /// Registry id, e.g. `dst` or `gym:Pendulum-v1`.
    pub env_id: String,
    /// Number of instances B stepped together.
    pub num_envs: usize,
    /// Space of one instance's observation.
    pub observation_space: Space,
    /// Space of one instance's action.
    pub action_space: Space,
    /// The K objectives, in reward-column order.
    pub objectives: Vec<ObjectiveSpec>,
    /// Time limit, if any.
    pub max_episode_steps: Option<u64>,
    /// Autoreset behaviour of this session.
    pub autoreset_mode: AutoresetMode,
    /// Discount of the server-side discounted returns.
    pub discount: f64,
    /// Info keys this env can report.
    pub info_keys: Vec<String>,
}

impl EnvSpec {
    /// Number of objectives K.
    pub fn num_objectives(&self) -> usize {
        self.objectives.len()
    }

    /// Objective names in reward-column order.
    pub fn objective_names(&self) -> Vec<&str> {
        self.objectives.iter().map(|o| o.name.as_str()).collect()
    }
}

/// One entry of a server's env list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvInfo {
    /// Registry id.
    pub env_id: String,
    /// One-line description.
    pub description: String,
    /// Objectives in reward order.
    pub objectives: Vec<ObjectiveSpec>,
}

/// What `GetVersion` reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ServerVersion {
    /// Wire protocol version, e.g. "1.0.0".
    pub protocol_version: String,
    /// env_server package version.
    pub server_version: String,
    /// Capability flags such as `step_stream`.
    pub capabilities: Vec<String>,
    /// Largest request the server accepts.
    pub max_message_bytes: u64,
}
