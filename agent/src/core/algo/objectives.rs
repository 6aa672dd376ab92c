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
mod tests {
    #[test]
    fn the_closed_form_action_norm_is_that_of_the_executed_action() {
        use super::*;
        // Pendulum: torque in [-2, 2]. Samples -3 and 1.7 are clipped to -1 and 1, then
        // mapped: -2 and 2; 0.25 maps to 0.5. The env's action_norm is -|u| of those.
        let pendulum = ActionBounds {
            low: vec![-2.0],
            high: vec![2.0],
        };
        let samples = Tensor::from_slice(&[-3.0f32, 0.25, 1.7]).reshape([3, 1]);
        let q = Vec::<f32>::try_from(&action_norm_q(&samples, Some(&pendulum))).unwrap();
        assert_eq!(q, vec![-2.0, -0.5, -2.0]);
        // Two dims, one unbounded (left clipped): ||(0.5 + 1.5 * 0.5, 1)|| for bounds
        // [-1, 2] (center 0.5, half-range 1.5) and sample (0.5, 4).
        let mixed = ActionBounds {
            low: vec![-1.0, f32::NEG_INFINITY],
            high: vec![2.0, f32::INFINITY],
        };
        let q = action_norm_q(&Tensor::from_slice(&[0.5f32, 4.0]), Some(&mixed));
        let want = -(1.25f64.powi(2) + 1.0).sqrt();
        assert!((q.double_value(&[]) - want).abs() < 1e-6);
        // No bounds stored: clipped to [-1, 1] only.
        let q = action_norm_q(&Tensor::from_slice(&[3.0f32, 0.0]), None);
        assert_eq!(q.double_value(&[]), -1.0);
    }

    use super::*;

    fn obj(name: &str, epsilon: f64, source: ObjectiveSource) -> ObjectiveConfig {
        ObjectiveConfig {
            name: name.into(),
            epsilon,
            source,
        }
    }

    fn env() -> Vec<String> {
        vec!["task".into(), "action_norm".into()]
    }

    #[test]
    fn binds_in_env_order_with_closed_form_action_norm() {
        let cfg = [
            obj("action_norm", 0.01, ObjectiveSource::ActionNorm),
            obj("task", 0.1, ObjectiveSource::Learned),
        ];
        let b = bind_names(&cfg, &env()).unwrap();
        assert_eq!(b.objectives[0].source, QSource::Critic { head: 0 });
        assert_eq!(b.objectives[1].source, QSource::ActionNorm);
        assert_eq!(b.critic_names, vec!["task".to_string()]);
        assert_eq!(b.critic_reward_weights, vec![vec![1.0], vec![0.0]]);
    }

    #[test]
    fn names_missing_extra_and_duplicates() {
        let cfg = [
            obj("task", 0.1, ObjectiveSource::Learned),
            obj("task", 0.2, ObjectiveSource::Learned),
            obj("pain", 0.1, ObjectiveSource::Learned),
        ];
        let msg = bind_names(&cfg, &env()).unwrap_err().to_string();
        assert_eq!(
            msg,
            r#"learner.objectives must name each of the env's objectives ["task", "action_norm"] once, got ["task", "task", "pain"]: missing ["action_norm"]; not objectives of this env ["pain"]; named more than once ["task"]"#
        );
        // Only the kinds of problem that occur are named (no empty lists).
        let cfg = [
            obj("task", 0.1, ObjectiveSource::Learned),
            obj("energy", 0.1, ObjectiveSource::Learned),
        ];
        let msg = bind_names(&cfg, &env()).unwrap_err().to_string();
        assert_eq!(
            msg,
            r#"learner.objectives must name each of the env's objectives ["task", "action_norm"] once, got ["task", "energy"]: missing ["action_norm"]; not objectives of this env ["energy"]"#
        );
    }

    #[test]
    fn vmpo_rejects_closed_form_objectives_and_mocap_needs_named_leaves() {
        use crate::core::learner_config::{Algorithm, Architecture};
        use crate::core::nets::ObsLeaf;
        let mut cfg = LearnerConfig {
            algorithm: Algorithm::MoVmpo,
            objectives: vec![
                obj("task", 0.1, ObjectiveSource::Learned),
                obj("action_norm", 0.1, ObjectiveSource::ActionNorm),
            ],
            ..LearnerConfig::default()
        };
        let mut dims = LearnerDims {
            action_bounds: None,
            obs_dim: 4,
            action: ActionKind::Continuous { dim: 2 },
            reward_names: env(),
            obs_leaves: vec![ObsLeaf {
                name: String::new(),
                dim: 4,
            }],
        };
        let msg = bind_config(&cfg, &dims).unwrap_err().to_string();
        assert!(
            msg.contains(r#"objective "action_norm""#) && msg.contains("V-MPO"),
            "{msg}"
        );
        cfg.objectives[1].source = ObjectiveSource::Learned;
        bind_config(&cfg, &dims).unwrap();
        cfg.network.architecture = Architecture::Mocap {
            encoder_layers: vec![8],
            latent_dim: 2,
            reference_match: "reference".into(),
        };
        let msg = bind_config(&cfg, &dims).unwrap_err().to_string();
        assert!(
            msg.starts_with("network.architecture.reference_match must be"),
            "{msg}"
        );
        assert!(msg.ends_with(r#"got [""]"#), "{msg}");
        dims.obs_leaves = vec![
            ObsLeaf {
                name: "walker/joints".into(),
                dim: 1,
            },
            ObsLeaf {
                name: "walker/reference_pos".into(),
                dim: 3,
            },
        ];
        bind_config(&cfg, &dims).unwrap();
    }

    fn declared(name: &str, closed_form: ClosedForm) -> ObjectiveSpec {
        ObjectiveSpec {
            name: name.into(),
            description: String::new(),
            min: -1.0,
            max: 0.0,
            scale: 1.0,
            closed_form,
        }
    }

    #[test]
    fn a_closed_form_source_needs_the_envs_declaration() {
        let cfg = [
            obj("reach", 0.1, ObjectiveSource::Learned),
            obj("energy", 0.01, ObjectiveSource::ActionNorm),
        ];
        let env = |energy| {
            vec![
                declared("reach", ClosedForm::None),
                declared("energy", energy),
            ]
        };
        bind(&cfg, &env(ClosedForm::ActionNorm)).unwrap();
        let msg = bind(&cfg, &env(ClosedForm::None)).unwrap_err().to_string();
        assert_eq!(
            msg,
            r#"learner.objectives.1.source: source = "action_norm" computes objective "energy" in closed form, which needs the env to declare closed_form = action_norm for it; the env declares closed_form = none (use source = "learned")"#
        );
        // A server older than the declaration: refused, and the message says why.
        let msg = bind(&cfg, &env(ClosedForm::Undeclared))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("the env declares nothing (the field is unset): its server is older than ObjectiveSpec.closed_form"),
            "{msg}"
        );
        let msg = bind(&cfg, &env(ClosedForm::Unrecognized(7)))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("closed_form = 7 (unknown to this agent)"),
            "{msg}"
        );
        // Learned sources need nothing declared, so an old server still trains them.
        let learned = [
            obj("reach", 0.1, ObjectiveSource::Learned),
            obj("energy", 0.01, ObjectiveSource::Learned),
        ];
        bind(&learned, &env(ClosedForm::Undeclared)).unwrap();
        // The scalarized baselines ignore `objectives`: nothing to refuse.
        let scalarized = LearnerConfig {
            algorithm: crate::core::learner_config::Algorithm::ScalarizedMpo {
                epsilon: 0.1,
                weights: Vec::new(),
            },
            objectives: cfg.to_vec(),
            ..LearnerConfig::default()
        };
        check_declared(&scalarized, &env(ClosedForm::None)).unwrap();
        let mompo = LearnerConfig {
            algorithm: crate::core::learner_config::Algorithm::MoMpo,
            ..scalarized
        };
        assert!(check_declared(&mompo, &env(ClosedForm::None)).is_err());
    }

    #[test]
    fn the_out_of_bounds_penalty_is_the_distance_to_the_box() {
        // Inside the box: 0. Outside: the Euclidean distance to its nearest point,
        // ||(2 - 1, -1.5 + 1)|| for (2, -1.5); a sample out in one dimension only
        // counts that dimension.
        let samples = Tensor::from_slice(&[0.5f32, -1.0, 2.0, -1.5, 0.0, 4.0]).reshape([3, 2]);
        let q = Vec::<f32>::try_from(&out_of_bounds_q(&samples)).unwrap();
        let want = [0.0, -(1.25f32.sqrt()), -3.0];
        for (got, want) in q.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{q:?}");
        }
    }

    #[test]
    fn action_penalization_appends_one_closed_form_objective_after_the_envs() {
        use crate::core::learner_config::Algorithm;
        let dims = |action, names: &[&str]| LearnerDims {
            action_bounds: None,
            obs_dim: 3,
            action,
            reward_names: names.iter().map(|n| n.to_string()).collect(),
            obs_leaves: Vec::new(),
        };
        let continuous = dims(ActionKind::Continuous { dim: 2 }, &["task", "action_norm"]);
        let mut cfg = LearnerConfig {
            objectives: vec![
                obj("task", 0.1, ObjectiveSource::Learned),
                obj("action_norm", 0.01, ObjectiveSource::ActionNorm),
            ],
            ..LearnerConfig::default()
        };
        assert_eq!(
            bind_config(&cfg, &continuous).unwrap().names(),
            ["task", "action_norm"]
        );
        cfg.mpo.action_penalization = Some(1e-3);
        let b = bind_config(&cfg, &continuous).unwrap();
        assert_eq!(b.names(), ["task", "action_norm", ACTION_PENALTY]);
        assert_eq!(b.objectives[2].source, QSource::OutOfBounds);
        assert_eq!(b.objectives[2].epsilon, 1e-3);
        // No critic head for it.
        assert_eq!(b.critic_names, ["task"]);
        // Scalarized MPO: after its one objective, as Acme's MPO has it.
        let scalarized = LearnerConfig {
            algorithm: Algorithm::ScalarizedMpo {
                epsilon: 0.1,
                weights: vec![
                    ObjectiveWeight {
                        name: "task".into(),
                        weight: 1.0,
                    },
                    ObjectiveWeight {
                        name: "action_norm".into(),
                        weight: 0.0,
                    },
                ],
            },
            ..cfg.clone()
        };
        assert_eq!(
            bind_config(&scalarized, &continuous).unwrap().names(),
            ["scalarized", ACTION_PENALTY]
        );
        // Refused, naming the field: V-MPO, discrete actions, an env objective of that name.
        let mut learned = cfg.clone();
        learned.objectives[1].source = ObjectiveSource::Learned;
        let vmpo = LearnerConfig {
            algorithm: Algorithm::MoVmpo,
            ..learned.clone()
        };
        let refusals = [
            bind_config(&vmpo, &continuous),
            bind_config(
                &learned,
                &dims(ActionKind::Discrete { n: 4 }, &["task", "action_norm"]),
            ),
            bind_config(
                &LearnerConfig {
                    objectives: vec![
                        obj("task", 0.1, ObjectiveSource::Learned),
                        obj(ACTION_PENALTY, 0.1, ObjectiveSource::Learned),
                    ],
                    ..cfg.clone()
                },
                &dims(ActionKind::Continuous { dim: 2 }, &["task", ACTION_PENALTY]),
            ),
        ];
        for (result, why) in refusals.into_iter().zip(["V-MPO", "discrete", "named"]) {
            let msg = result.unwrap_err().to_string();
            assert!(
                msg.starts_with("mpo.action_penalization must be unset") && msg.contains(why),
                "{msg}"
            );
        }
        cfg.mpo.action_penalization = Some(0.0);
        let msg = bind_config(&cfg, &continuous).unwrap_err().to_string();
        assert_eq!(
            msg,
            "mpo.action_penalization must be an ε > 0 when set, got 0.0"
        );
    }

    #[test]
    fn scalarized_uses_weights_in_env_order() {
        let w = [
            ObjectiveWeight {
                name: "action_norm".into(),
                weight: 0.1,
            },
            ObjectiveWeight {
                name: "task".into(),
                weight: 0.9,
            },
        ];
        let b = bind_scalarized(0.1, &w, &env()).unwrap();
        assert_eq!(b.critic_reward_weights, vec![vec![0.9], vec![0.1]]);
        assert_eq!(b.objectives.len(), 1);
    }
}
