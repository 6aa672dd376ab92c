//! Learner configuration for MO-MPO and scalarized MPO.
//!
//! `Default` gives the paper's Table 2 values (Abdolmaleki et al. 2020, appendix A);
//! every Table 3 override (humanoid, Shadow Hand, Sawyer) is a field here, so a preset
//! is a TOML file. Each field's comment names the table row it comes from, or says
//! where it comes from when the paper leaves it open (Acme's TF MO-MPO, see
//! `research/acme_mompo.md` §7).

use serde::{Deserialize, Serialize};

/// Sizes and options of the policy and critic networks (Table 2 "policy network",
/// "critic network(s)", "both policy and critic networks").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Table 2 "policy network: layer sizes" (300, 200); humanoid (400, 400, 300).
    /// The first layer is Linear -> LayerNorm -> tanh, later ones Linear -> ELU.
    pub policy_layers: Vec<i64>,
    /// Table 2 "critic network(s): layer sizes" (400, 400, 300); humanoid (500, 500, 400).
    /// The first layer is shared by all critic heads, the rest are per objective.
    pub critic_layers: Vec<i64>,
    /// Table 2 "take tanh of action mean?" yes; humanoid no.
    pub tanh_on_action_mean: bool,
    /// Table 2 "minimum variance" 1e-12; humanoid 1e-8. The policy's standard
    /// deviation is `softplus(x) + sqrt(min_variance)`.
    pub min_variance: f64,
    /// Table 2 "take tanh of action?" (critic input) yes; humanoid no.
    pub tanh_on_critic_action: bool,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        Self {
            policy_layers: vec![300, 200],
            critic_layers: vec![400, 400, 300],
            tanh_on_action_mean: true,
            min_variance: 1e-12,
            tanh_on_critic_action: true,
        }
    }
}

/// MPO, policy-evaluation and training hyperparameters (Table 2 "MPO", "training").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MpoConfig {
    /// Table 2 "actions sampled per state" M = 20; Shadow Hand 30, Sawyer 15.
    pub num_samples: i64,
    /// Table 2 "KL-constraint on policy mean" beta_mu = 1e-3; humanoid 5e-3.
    /// Bounds the KL summed over action dimensions (eq. 20).
    pub beta_mean: f64,
    /// Table 2 "KL-constraint on policy covariance" beta_Sigma = 1e-5; humanoid 1e-6.
    pub beta_cov: f64,
    /// A.2: KL constraint beta of the categorical policy (Deep Sea Treasure), 1e-3.
    pub beta_categorical: f64,
    /// Table 2 "initial temperature eta" 1 (the value of eta, not of its parameter).
    pub init_temperature: f64,
    /// Initial Lagrange multiplier alpha_mu. Not in the paper; Acme TF MO-MPO starts
    /// its parameter at 1, i.e. softplus(1) ~ 1.31.
    pub init_alpha_mean: f64,
    /// Initial Lagrange multiplier alpha_Sigma. Not in the paper; Acme TF MO-MPO: 10.
    pub init_alpha_cov: f64,
    /// Initial Lagrange multiplier of the categorical KL. Not in the paper; 1.0.
    pub init_alpha_categorical: f64,
    /// Adam learning rate of all dual variables (eta_k, alpha). Not in the paper;
    /// Acme uses 1e-2.
    pub dual_learning_rate: f64,
    /// Table 2 "Retrace sequence size" 8. A.2 (Deep Sea Treasure): 1, which makes
    /// the Retrace target a one-step TD target.
    pub retrace_length: usize,
    /// Table 2 "discount factor gamma" 0.99; A.2 (Deep Sea Treasure) 0.999.
    pub discount: f64,
    /// Table 2 "target network update period" 200 learner steps; Sawyer 100.
    pub target_update_period: u64,
    /// Table 2 "Adam learning rate" 3e-4; humanoid 2e-4 (policy and critics).
    pub learning_rate: f64,
    /// Table 2 "Adam epsilon" 1e-3; humanoid 1e-8.
    pub adam_eps: f64,
    /// Table 2 "batch size" 512 (snippets per learner step).
    pub batch_size: usize,
    /// Table 2 "replay buffer size" 1e6 transitions (used by the replay, not the learner).
    pub replay_capacity: usize,
    /// Global-norm clip of policy and critic gradients (duals are never clipped).
    /// Not in the paper; Acme TF clips at 40. `None` disables clipping.
    pub grad_clip_norm: Option<f64>,
}

impl Default for MpoConfig {
    fn default() -> Self {
        Self {
            num_samples: 20,
            beta_mean: 1e-3,
            beta_cov: 1e-5,
            beta_categorical: 1e-3,
            init_temperature: 1.0,
            init_alpha_mean: 1.0,
            init_alpha_cov: 10.0,
            init_alpha_categorical: 1.0,
            dual_learning_rate: 1e-2,
            retrace_length: 8,
            discount: 0.99,
            target_update_period: 200,
            learning_rate: 3e-4,
            adam_eps: 1e-3,
            batch_size: 512,
            replay_capacity: 1_000_000,
            grad_clip_norm: None,
        }
    }
}

/// Where an objective's Q-value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectiveSource {
    /// A critic head trained on the env's reward column of the same name.
    #[default]
    Learned,
    /// `-||a||_2` computed exactly from the sampled action (humanoid run, appendix A);
    /// no critic. The env's reward column of that name is only logged.
    ActionNorm,
}

/// One MO-MPO objective, bound by name to an env reward column (Table 4 epsilons).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectiveConfig {
    /// Name of the env objective (`EnvSpec::objectives[..].name`).
    pub name: String,
    /// KL bound epsilon_k of the E-step (Table 2 "default epsilon" 0.1). 0 means the
    /// objective has no influence: its improved distribution is the target policy.
    pub epsilon: f64,
    /// Learned critic or closed form.
    #[serde(default)]
    pub source: ObjectiveSource,
}

/// One scalarization weight, bound by name to an env reward column (Table 4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectiveWeight {
    /// Name of the env objective.
    pub name: String,
    /// Weight w_k of its reward in sum_k w_k r_k.
    pub weight: f64,
}

/// Which learner to run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Algorithm {
    /// MO-MPO (Algorithm 3): one critic and one epsilon per objective.
    MoMpo,
    /// Scalarized MPO: one critic on sum_k w_k r_k and one epsilon.
    ScalarizedMpo {
        /// KL bound of the single E-step (Table 2 "default epsilon" 0.1).
        epsilon: f64,
        /// One weight per env objective.
        weights: Vec<ObjectiveWeight>,
    },
}

/// Everything the learner needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerConfig {
    /// MO-MPO or scalarized MPO.
    pub algorithm: Algorithm,
    /// MO-MPO objectives (ignored by scalarized MPO).
    pub objectives: Vec<ObjectiveConfig>,
    /// Network sizes and options.
    pub network: NetworkConfig,
    /// MPO and training hyperparameters.
    pub mpo: MpoConfig,
    /// Seed of network initialisation.
    pub seed: u64,
    /// libtorch intra-op threads; `None` = all available cores.
    pub num_threads: Option<usize>,
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            algorithm: Algorithm::MoMpo,
            objectives: Vec::new(),
            network: NetworkConfig::default(),
            mpo: MpoConfig::default(),
            seed: 0,
            num_threads: None,
        }
    }
}

/// A configuration that cannot be used; the message quotes the received values.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// One field has an invalid value.
    #[error("{field} must be {requirement}, got {got}")]
    Invalid {
        /// Dotted field path, e.g. `network.min_variance`.
        field: String,
        /// What the value must satisfy.
        requirement: String,
        /// The received value.
        got: String,
    },
    /// Config names and env objective names do not match one to one.
    #[error(
        "{what} do not match the env objectives {env:?}: missing {missing:?}, extra {extra:?}, duplicate {duplicate:?}"
    )]
    ObjectiveNames {
        /// `objectives` or `algorithm.weights`.
        what: String,
        /// The env's objective names in reward-column order.
        env: Vec<String>,
        /// Env objectives the config does not mention.
        missing: Vec<String>,
        /// Config names the env does not have.
        extra: Vec<String>,
        /// Names given more than once.
        duplicate: Vec<String>,
    },
    /// A closed-form objective that the action space does not allow.
    #[error("objective {name:?} has source {kind:?}, which needs continuous actions")]
    Unsupported {
        /// Objective name.
        name: String,
        /// Its source.
        kind: ObjectiveSource,
    },
}

fn invalid(field: &str, requirement: &str, got: impl std::fmt::Debug) -> ConfigError {
    ConfigError::Invalid {
        field: field.into(),
        requirement: requirement.into(),
        got: format!("{got:?}"),
    }
}

fn check(
    ok: bool,
    field: &str,
    requirement: &str,
    got: impl std::fmt::Debug,
) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(invalid(field, requirement, got))
    }
}

fn finite_pos(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

impl LearnerConfig {
    /// Checks every field (names against the env are checked by `algo::objectives::bind`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let n = &self.network;
        check(
            !n.policy_layers.is_empty(),
            "network.policy_layers",
            "non-empty",
            &n.policy_layers,
        )?;
        check(
            n.policy_layers.iter().all(|&h| h > 0),
            "network.policy_layers",
            "all > 0",
            &n.policy_layers,
        )?;
        check(
            !n.critic_layers.is_empty(),
            "network.critic_layers",
            "non-empty",
            &n.critic_layers,
        )?;
        check(
            n.critic_layers.iter().all(|&h| h > 0),
            "network.critic_layers",
            "all > 0",
            &n.critic_layers,
        )?;
        check(
            finite_pos(n.min_variance),
            "network.min_variance",
            "> 0",
            n.min_variance,
        )?;
        let m = &self.mpo;
        check(m.num_samples >= 1, "mpo.num_samples", ">= 1", m.num_samples)?;
        check(
            m.beta_mean >= 0.0 && m.beta_mean.is_finite(),
            "mpo.beta_mean",
            ">= 0",
            m.beta_mean,
        )?;
        check(
            m.beta_cov >= 0.0 && m.beta_cov.is_finite(),
            "mpo.beta_cov",
            ">= 0",
            m.beta_cov,
        )?;
        check(
            m.beta_categorical >= 0.0 && m.beta_categorical.is_finite(),
            "mpo.beta_categorical",
            ">= 0",
            m.beta_categorical,
        )?;
        check(
            finite_pos(m.init_temperature),
            "mpo.init_temperature",
            "> 0",
            m.init_temperature,
        )?;
        check(
            finite_pos(m.init_alpha_mean),
            "mpo.init_alpha_mean",
            "> 0",
            m.init_alpha_mean,
        )?;
        check(
            finite_pos(m.init_alpha_cov),
            "mpo.init_alpha_cov",
            "> 0",
            m.init_alpha_cov,
        )?;
        check(
            finite_pos(m.init_alpha_categorical),
            "mpo.init_alpha_categorical",
            "> 0",
            m.init_alpha_categorical,
        )?;
        check(
            finite_pos(m.dual_learning_rate),
            "mpo.dual_learning_rate",
            "> 0",
            m.dual_learning_rate,
        )?;
        check(
            m.retrace_length >= 1,
            "mpo.retrace_length",
            ">= 1",
            m.retrace_length,
        )?;
        check(
            (0.0..=1.0).contains(&m.discount),
            "mpo.discount",
            "in [0, 1]",
            m.discount,
        )?;
        check(
            m.target_update_period >= 1,
            "mpo.target_update_period",
            ">= 1",
            m.target_update_period,
        )?;
        check(
            finite_pos(m.learning_rate),
            "mpo.learning_rate",
            "> 0",
            m.learning_rate,
        )?;
        check(finite_pos(m.adam_eps), "mpo.adam_eps", "> 0", m.adam_eps)?;
        check(m.batch_size >= 1, "mpo.batch_size", ">= 1", m.batch_size)?;
        check(
            m.replay_capacity >= m.batch_size,
            "mpo.replay_capacity",
            ">= mpo.batch_size",
            m.replay_capacity,
        )?;
        if let Some(c) = m.grad_clip_norm {
            check(finite_pos(c), "mpo.grad_clip_norm", "> 0 when set", c)?;
        }
        if let Some(t) = self.num_threads {
            check(t >= 1, "num_threads", ">= 1 when set", t)?;
        }
        match &self.algorithm {
            Algorithm::MoMpo => {
                check(
                    !self.objectives.is_empty(),
                    "objectives",
                    "non-empty for mo_mpo",
                    &self.objectives,
                )?;
                for (i, o) in self.objectives.iter().enumerate() {
                    let field = format!("objectives[{i}].epsilon ({})", o.name);
                    check(
                        o.epsilon >= 0.0 && o.epsilon.is_finite(),
                        &field,
                        ">= 0",
                        o.epsilon,
                    )?;
                }
            }
            Algorithm::ScalarizedMpo { epsilon, weights } => {
                check(finite_pos(*epsilon), "algorithm.epsilon", "> 0", epsilon)?;
                check(
                    !weights.is_empty(),
                    "algorithm.weights",
                    "non-empty",
                    weights,
                )?;
                for (i, w) in weights.iter().enumerate() {
                    let field = format!("algorithm.weights[{i}].weight ({})", w.name);
                    check(w.weight.is_finite(), &field, "finite", w.weight)?;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_table_2() {
        let c = LearnerConfig::default();
        assert_eq!(c.network.policy_layers, vec![300, 200]);
        assert_eq!(c.network.critic_layers, vec![400, 400, 300]);
        assert_eq!(c.mpo.num_samples, 20);
        assert_eq!((c.mpo.beta_mean, c.mpo.beta_cov), (1e-3, 1e-5));
        assert_eq!((c.mpo.learning_rate, c.mpo.adam_eps), (3e-4, 1e-3));
        assert_eq!(
            (
                c.mpo.batch_size,
                c.mpo.target_update_period,
                c.mpo.retrace_length
            ),
            (512, 200, 8)
        );
    }

    #[test]
    fn messages_quote_values() {
        let mut c = LearnerConfig::default();
        c.objectives.push(ObjectiveConfig {
            name: "task".into(),
            epsilon: 0.1,
            source: ObjectiveSource::Learned,
        });
        c.validate().unwrap();
        c.network.min_variance = -1e-3;
        assert_eq!(
            c.validate().unwrap_err().to_string(),
            "network.min_variance must be > 0, got -0.001"
        );
    }

    #[test]
    fn toml_round_trip_and_unknown_fields() {
        let text = r#"
            seed = 3
            [algorithm]
            kind = "scalarized_mpo"
            epsilon = 0.1
            weights = [{ name = "task", weight = 0.9 }, { name = "action_norm", weight = 0.1 }]
            [network]
            policy_layers = [400, 400, 300]
            tanh_on_action_mean = false
            [mpo]
            beta_mean = 5e-3
        "#;
        let c: LearnerConfig = toml::from_str(text).unwrap();
        assert_eq!(c.network.policy_layers, vec![400, 400, 300]);
        assert_eq!(c.mpo.beta_mean, 5e-3);
        assert!(
            matches!(c.algorithm, Algorithm::ScalarizedMpo { ref weights, .. } if weights.len() == 2)
        );
        c.validate().unwrap();
        let bad = "[mpo]\nbeta_mena = 1.0\n";
        let err = toml::from_str::<LearnerConfig>(bad)
            .unwrap_err()
            .to_string();
        assert!(err.contains("beta_mena"), "{err}");
    }
}
