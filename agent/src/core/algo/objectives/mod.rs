//! Binding config objectives to the env's reward columns by name (MO-MPO and MO-V-MPO:
//! one epsilon_k per objective; the scalarized baselines: one weight per reward column
//! and one epsilon), checked against the env's dimensions.
//!
//! After binding, the E-step sees K objectives in env order, each either a critic head
//! or the closed-form action norm `-||a||_2` of the executed action (appendix A,
//! humanoid run); with `mpo.action_penalization` one more follows them, the
//! out-of-bounds penalty `-||a - clip(a, -1, 1)||_2` (Acme's MPO; not in the paper),
//! which no env column has. Critic head c
//! learns the reward `sum_j W[j, c] r_j` (W `[K_env, C]`): a one-hot column for MO-MPO,
//! the scalarization weights for scalarized MPO.

use crate::core::learner_config::{
    Architecture, ConfigError, LearnerConfig, ObjectiveConfig, ObjectiveSource, ObjectiveWeight,
};
pub use crate::core::nets::LearnerDims;
use crate::core::nets::{ActionBounds, ActionKind};
use crate::core::spec::{ClosedForm, ObjectiveSpec};
use serde::{Deserialize, Serialize};
use tch::{Kind, Tensor};

/// Where the E-step gets objective k's Q-values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum QSource {
    /// Column `head` of the critic output.
    Critic {
        /// Critic head index.
        head: usize,
    },
    /// `-||a||_2` of the action the env executes for the sample (`action_norm_q`).
    ActionNorm,
    /// `-||a - clip(a, -1, 1)||_2` of the sample (`out_of_bounds_q`).
    OutOfBounds,
}

/// Name of the out-of-bounds penalty objective (`mpo.action_penalization`) among the
/// E-step's objectives, after the env's.
pub const ACTION_PENALTY: &str = "action_penalty";

/// The closed-form out-of-bounds penalty: `-||a - clip(a, -1, 1)||_2` of each sample,
/// in the policy's action units (the env maps [-1, 1] onto its Box). 0 inside the
/// box and growing linearly outside it, as Acme's MPO computes it.
/// # Shapes
/// `actions [..., D] -> [...]`.
pub fn out_of_bounds_q(actions: &Tensor) -> Tensor {
    -(actions - actions.clamp(-1.0, 1.0))
        .square()
        .sum_dim_intlist(-1, false, Kind::Float)
        .sqrt()
}

/// The closed-form action-norm Q: `-||a_env||_2` with `a_env` the action the env would
/// execute for each sample (clipped and mapped onto the Box, `ActionBounds::to_env`),
/// the very quantity the env's `action_norm` reward penalizes. Without bounds (old
/// checkpoints) the sample is clipped to [-1, 1].
/// # Shapes
/// `actions [..., D] -> [...]`.
pub fn action_norm_q(actions: &Tensor, bounds: Option<&ActionBounds>) -> Tensor {
    let executed = match bounds {
        Some(b) => b.to_env(actions),
        None => actions.clamp(-1.0, 1.0),
    };
    -executed
        .square()
        .sum_dim_intlist(-1, false, Kind::Float)
        .sqrt()
}

/// One objective of the E-step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoundObjective {
    /// Objective name (env name, or `scalarized` for scalarized MPO).
    pub name: String,
    /// KL bound epsilon_k.
    pub epsilon: f64,
    /// Where its Q-values come from.
    pub source: QSource,
}

/// The bound objectives and the critic reward map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoundObjectives {
    /// The K objectives of the E-step, in env order.
    pub objectives: Vec<BoundObjective>,
    /// Names of the C critic heads.
    pub critic_names: Vec<String>,
    /// `[K_env][C]`: reward weights of each critic head.
    pub critic_reward_weights: Vec<Vec<f64>>,
}

impl BoundObjectives {
    /// The E-step's objective names in order (what temperatures and E-step KLs are
    /// listed by): the env's, `scalarized` for a scalarized baseline, then
    /// [`ACTION_PENALTY`] when it is on.
    pub fn names(&self) -> Vec<String> {
        self.objectives.iter().map(|o| o.name.clone()).collect()
    }
}

fn check_names(what: &str, given: &[&str], env: &[String]) -> Result<(), ConfigError> {
    let mut duplicate: Vec<String> = Vec::new();
    for (i, name) in given.iter().enumerate() {
        if given[..i].contains(name) && !duplicate.iter().any(|d| d == name) {
            duplicate.push((*name).to_string());
        }
    }
    let missing: Vec<String> = env
        .iter()
        .filter(|e| !given.contains(&e.as_str()))
        .cloned()
        .collect();
    let mut extra: Vec<String> = given
        .iter()
        .filter(|g| !env.iter().any(|e| e == *g))
        .map(|g| g.to_string())
        .collect();
    extra.dedup();
    if missing.is_empty() && extra.is_empty() && duplicate.is_empty() {
        return Ok(());
    }
    Err(ConfigError::ObjectiveNames {
        what: what.into(),
        env: env.to_vec(),
        given: given.iter().map(|g| g.to_string()).collect(),
        missing,
        extra,
        duplicate,
    })
}

/// Binds MO-MPO objectives to env objectives by name (`bind_names` on the spec's names),
/// after `check_declared_sources`.
pub fn bind(
    objectives: &[ObjectiveConfig],
    env: &[ObjectiveSpec],
) -> Result<BoundObjectives, ConfigError> {
    check_declared_sources(objectives, env)?;
    let names: Vec<String> = env.iter().map(|o| o.name.clone()).collect();
    bind_names(objectives, &names)
}

/// The closed form a source computes, `None` for a learned critic.
fn closed_form_of(source: ObjectiveSource) -> Option<ClosedForm> {
    match source {
        ObjectiveSource::Learned => None,
        ObjectiveSource::ActionNorm => Some(ClosedForm::ActionNorm),
    }
}

/// Refuses a closed-form `source` on an objective the env does not declare with that
/// closed form (`ObjectiveSpec::closed_form`): the learner would optimize a formula the
/// env's reward is not. A server older than the declaration declares nothing, so every
/// closed-form source is refused against it. Objectives the env does not have are left
/// to `bind_names`.
pub fn check_declared_sources(
    objectives: &[ObjectiveConfig],
    env: &[ObjectiveSpec],
) -> Result<(), ConfigError> {
    for (i, cfg) in objectives.iter().enumerate() {
        let (Some(wanted), Some(spec)) = (
            closed_form_of(cfg.source),
            env.iter().find(|o| o.name == cfg.name),
        ) else {
            continue;
        };
        if spec.closed_form != wanted {
            return Err(ConfigError::Undeclared {
                field: format!("learner.objectives.{i}.source"),
                name: cfg.name.clone(),
                given: cfg.source,
                wanted,
                declared: spec.closed_form,
            });
        }
    }
    Ok(())
}

/// `check_declared_sources` for a learner config: the objectives of MO-MPO and MO-V-MPO
/// (the scalarized baselines learn every reward column and ignore them).
pub fn check_declared(cfg: &LearnerConfig, env: &[ObjectiveSpec]) -> Result<(), ConfigError> {
    match cfg.algorithm.scalarization() {
        Some(_) => Ok(()),
        None => check_declared_sources(&cfg.objectives, env),
    }
}

/// Binds MO-MPO objectives to env reward names: every env objective exactly once.
pub fn bind_names(
    objectives: &[ObjectiveConfig],
    env: &[String],
) -> Result<BoundObjectives, ConfigError> {
    let given: Vec<&str> = objectives.iter().map(|o| o.name.as_str()).collect();
    check_names("learner.objectives", &given, env)?;
    let mut bound = BoundObjectives {
        objectives: Vec::new(),
        critic_names: Vec::new(),
        critic_reward_weights: vec![Vec::new(); env.len()],
    };
    for (column, name) in env.iter().enumerate() {
        let cfg = objectives
            .iter()
            .find(|o| &o.name == name)
            .expect("checked above");
        let source = match cfg.source {
            ObjectiveSource::ActionNorm => QSource::ActionNorm,
            ObjectiveSource::Learned => {
                let head = bound.critic_names.len();
                bound.critic_names.push(name.clone());
                for (j, row) in bound.critic_reward_weights.iter_mut().enumerate() {
                    row.push(if j == column { 1.0 } else { 0.0 });
                }
                QSource::Critic { head }
            }
        };
        bound.objectives.push(BoundObjective {
            name: name.clone(),
            epsilon: cfg.epsilon,
            source,
        });
    }
    Ok(bound)
}

/// Binds scalarization weights: one critic on `sum_k w_k r_k`, one objective.
pub fn bind_scalarized(
    epsilon: f64,
    weights: &[ObjectiveWeight],
    env: &[String],
) -> Result<BoundObjectives, ConfigError> {
    let given: Vec<&str> = weights.iter().map(|w| w.name.as_str()).collect();
    check_names("learner.algorithm.weights", &given, env)?;
    let critic_reward_weights = env
        .iter()
        .map(|name| {
            vec![
                weights
                    .iter()
                    .find(|w| &w.name == name)
                    .expect("checked above")
                    .weight,
            ]
        })
        .collect();
    Ok(BoundObjectives {
        objectives: vec![BoundObjective {
            name: "scalarized".into(),
            epsilon,
            source: QSource::Critic { head: 0 },
        }],
        critic_names: vec!["scalarized".into()],
        critic_reward_weights,
    })
}

/// Validates `cfg` and binds it against `dims`.
pub fn bind_config(
    cfg: &LearnerConfig,
    dims: &LearnerDims,
) -> Result<BoundObjectives, ConfigError> {
    cfg.validate()?;
    let bound = match cfg.algorithm.scalarization() {
        None => bind_names(&cfg.objectives, &dims.reward_names)?,
        Some((epsilon, weights)) => bind_scalarized(epsilon, weights, &dims.reward_names)?,
    };
    if let Some(o) = bound
        .objectives
        .iter()
        .find(|o| o.source == QSource::ActionNorm)
    {
        let reason = if cfg.algorithm.on_policy() {
            Some(
                "V-MPO cannot use (its step 1 needs one advantage per taken action; make it learned)",
            )
        } else if let ActionKind::Discrete { .. } = dims.action {
            Some("needs continuous actions")
        } else {
            None
        };
        if let Some(reason) = reason {
            return Err(ConfigError::Unsupported {
                name: o.name.clone(),
                kind: ObjectiveSource::ActionNorm,
                reason: reason.into(),
            });
        }
    }
    let bound = with_action_penalty(cfg, dims, bound)?;
    if bound.critic_names.is_empty() {
        return Err(ConfigError::Invalid {
            field: "objectives".into(),
            requirement: "at least one learned objective".into(),
            got: format!("{:?}", cfg.objectives),
        });
    }
    if let Architecture::Mocap {
        reference_match, ..
    } = &cfg.network.architecture
    {
        let split = dims.split_observation(reference_match);
        if split.matching.is_empty() || split.rest.is_empty() {
            let leaves: Vec<&str> = dims.obs_leaves.iter().map(|l| l.name.as_str()).collect();
            return Err(ConfigError::Invalid {
                field: "network.architecture.reference_match".into(),
                requirement: format!(
                    "a substring of some but not all observation leaf names (a Dict observation space; humanoid-mocap needs kwargs dict_observation = true), matched {reference_match:?} against"
                ),
                got: format!("{leaves:?}"),
            });
        }
    }
    Ok(bound)
}

/// `bound` with the out-of-bounds penalty objective appended when
/// `mpo.action_penalization` is set: MPO-family learners with continuous actions only.
fn with_action_penalty(
    cfg: &LearnerConfig,
    dims: &LearnerDims,
    mut bound: BoundObjectives,
) -> Result<BoundObjectives, ConfigError> {
    let Some(epsilon) = cfg.mpo.action_penalization else {
        return Ok(bound);
    };
    let refuse = |requirement: &str, got: String| ConfigError::Invalid {
        field: "mpo.action_penalization".into(),
        requirement: requirement.into(),
        got,
    };
    if cfg.algorithm.on_policy() {
        return Err(refuse(
            "unset for V-MPO (its step 1 weighs taken actions, not samples)",
            format!("{epsilon} with {}", cfg.algorithm.short_name()),
        ));
    }
    if let ActionKind::Discrete { .. } = dims.action {
        return Err(refuse(
            "unset for discrete actions (no bounds to leave)",
            format!("{epsilon} with a discrete action space"),
        ));
    }
    if dims.reward_names.iter().any(|n| n == ACTION_PENALTY) {
        return Err(refuse(
            &format!("unset when the env has an objective named {ACTION_PENALTY:?}"),
            format!("{epsilon} with env objectives {:?}", dims.reward_names),
        ));
    }
    bound.objectives.push(BoundObjective {
        name: ACTION_PENALTY.into(),
        epsilon,
        source: QSource::OutOfBounds,
    });
    Ok(bound)
}

#[cfg(test)]
mod tests;
