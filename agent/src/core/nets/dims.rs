//! The learner's view of an env's sizes: the flattened observation (and, for Dict
//! observations, which slice each named leaf occupies), the action space and the
//! reward columns. Networks are built from it; checkpoints store it.

use serde::{Deserialize, Serialize};
use tch::Tensor;

use super::ActionKind;
use crate::core::learner_config::{ConfigError, PreferenceFeatures};
use crate::core::spec::{EnvSpec, Space};

/// One leaf of the flattened observation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObsLeaf {
    /// "."-joined Dict path ("" for a non-Dict space).
    pub name: String,
    /// Number of scalars.
    pub dim: i64,
}

/// Box bounds of a continuous action space, one pair per action dimension.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActionBounds {
    /// Lower bound per dimension (`-inf` when unbounded).
    pub low: Vec<f32>,
    /// Upper bound per dimension (`+inf` when unbounded).
    pub high: Vec<f32>,
}

impl ActionBounds {
    /// The action the env executes for policy actions `a`: clipped to [-1, 1], then
    /// mapped linearly onto [low, high] in every dimension whose bounds are both finite
    /// (left clipped elsewhere). The actor sends exactly this, and the closed-form
    /// action-norm objective is the norm of exactly this, so MO-MPO and a scalarized
    /// baseline (which learns from the env's reward) penalize the same quantity.
    /// # Shapes
    /// `a [..., D] -> [..., D]`.
    pub fn to_env(&self, a: &Tensor) -> Tensor {
        let finite = |d: usize| self.low[d].is_finite() && self.high[d].is_finite();
        let dims = 0..self.low.len();
        let center: Vec<f32> = dims
            .clone()
            .map(|d| {
                if finite(d) {
                    0.5 * (self.low[d] + self.high[d])
                } else {
                    0.0
                }
            })
            .collect();
        let half: Vec<f32> = dims
            .map(|d| {
                if finite(d) {
                    0.5 * (self.high[d] - self.low[d])
                } else {
                    1.0
                }
            })
            .collect();
        let device = a.device();
        a.clamp(-1.0, 1.0) * Tensor::from_slice(&half).to_device(device)
            + Tensor::from_slice(&center).to_device(device)
    }
}

/// Name of the observation leaf that ε-conditioned learners append to the env's
/// observation: the preference features of `algo::preferences`.
pub const PREFERENCE_LEAF: &str = "preference";

/// Sizes the networks need, taken from an `EnvSpec`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LearnerDims {
    /// Flattened observation size.
    pub obs_dim: i64,
    /// Continuous (D) or discrete (A) actions.
    pub action: ActionKind,
    /// Env objective names in reward-column order (K_env columns).
    pub reward_names: Vec<String>,
    /// Observation leaves in flattening order (their dims sum to `obs_dim`).
    #[serde(default)]
    pub obs_leaves: Vec<ObsLeaf>,
    /// Bounds of a continuous action space (`None`: discrete, or a checkpoint from
    /// before they were stored, whose actions are taken as executed clipped to [-1, 1]).
    #[serde(default)]
    pub action_bounds: Option<ActionBounds>,
}

fn leaves(prefix: &str, space: &Space, out: &mut Vec<ObsLeaf>) {
    match space {
        Space::Dict(entries) => {
            for (key, sub) in entries {
                let name = if prefix.is_empty() {
                    key.clone()
                } else {
                    format!("{prefix}.{key}")
                };
                leaves(&name, sub, out);
            }
        }
        other => out.push(ObsLeaf {
            name: prefix.to_string(),
            dim: other.flat_dim() as i64,
        }),
    }
}

impl LearnerDims {
    /// The same sizes with `features` preference features appended to every
    /// observation (none: unchanged).
    pub fn with_preference_features(mut self, features: usize) -> Self {
        if features > 0 {
            self.obs_dim += features as i64;
            self.obs_leaves.push(ObsLeaf {
                name: PREFERENCE_LEAF.into(),
                dim: features as i64,
            });
        }
        self
    }

    /// How many preference features the observations end with (0: not conditioned).
    pub fn preference_features(&self) -> usize {
        self.obs_leaves
            .iter()
            .find(|l| l.name == PREFERENCE_LEAF)
            .map_or(0, |l| l.dim as usize)
    }

    /// How many trailing observation columns a network whose preference features are
    /// read `where_` carries to its later layers (0 for `Input`).
    pub fn carried_features(&self, where_: PreferenceFeatures) -> i64 {
        match where_ {
            PreferenceFeatures::Input => 0,
            PreferenceFeatures::EveryLayer => self.preference_features() as i64,
        }
    }

    /// Reads the dimensions from a spec; a Dict action space is rejected.
    pub fn from_spec(spec: &EnvSpec) -> Result<Self, ConfigError> {
        let action = match &spec.action_space {
            Space::Box(b) => ActionKind::Continuous {
                dim: b.numel() as i64,
            },
            Space::Discrete(d) => ActionKind::Discrete { n: d.n },
            other => {
                return Err(ConfigError::Invalid {
                    field: "env action_space".into(),
                    requirement: "a Box or Discrete space".into(),
                    got: format!("{other:?}"),
                });
            }
        };
        let mut obs_leaves = Vec::new();
        leaves("", &spec.observation_space, &mut obs_leaves);
        let action_bounds = match &spec.action_space {
            Space::Box(b) => Some(ActionBounds {
                low: b.low.iter().map(|&v| v as f32).collect(),
                high: b.high.iter().map(|&v| v as f32).collect(),
            }),
            _ => None,
        };
        Ok(Self {
            action_bounds,
            obs_dim: spec.observation_space.flat_dim() as i64,
            action,
            reward_names: spec
                .objective_names()
                .into_iter()
                .map(String::from)
                .collect(),
            obs_leaves,
        })
    }

    /// Flat indices of the leaves whose name contains `pattern`, and of the others.
    pub fn split_observation(&self, pattern: &str) -> ObsSplit {
        let mut split = ObsSplit {
            matching: Vec::new(),
            rest: Vec::new(),
        };
        let mut start = 0;
        for leaf in &self.obs_leaves {
            let side = if leaf.name.contains(pattern) {
                &mut split.matching
            } else {
                &mut split.rest
            };
            side.extend(start..start + leaf.dim);
            start += leaf.dim;
        }
        split
    }
}

/// Observation indices split by leaf name.
#[derive(Debug, Clone, PartialEq)]
pub struct ObsSplit {
    /// Indices of the matching leaves, ascending.
    pub matching: Vec<i64>,
    /// Indices of the other leaves, ascending.
    pub rest: Vec<i64>,
}
