//! Learner configuration for MO-MPO, MO-V-MPO and their scalarized baselines.
//!
//! `Default` gives the paper's values (Abdolmaleki et al. 2020, appendix A): Table 2 in
//! `mpo`, Table 5 in `vmpo`; every Table 3 override (humanoid, Shadow Hand, Sawyer) is
//! a field, so a preset is a TOML file. Each field's comment names the table row it
//! comes from, or says where it comes from when the paper leaves it open (Acme's TF
//! MO-MPO and rlax's V-MPO, see `research/acme_mompo.md` §6-7).

mod conditioning;
mod error;
mod mpo;
mod network;
mod shared;
mod vmpo;

pub use conditioning::{ConditioningConfig, GridTrustRegion, MAX_GRID_POINTS};
pub use error::ConfigError;
use error::{check, finite_pos};
pub use mpo::MpoConfig;
pub use network::{Architecture, NetworkConfig, PolicyStd, PreferenceFeatures};
pub use shared::{KlConstraint, MinAlpha, SharedSettings, TemperatureParameterization};
pub use vmpo::{TopK, VmpoConfig};

use serde::{Deserialize, Serialize};

/// Where an objective's Q-value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectiveSource {
    /// A critic head trained on the env's reward column of the same name.
    #[default]
    Learned,
    /// `-||a||_2` computed exactly from the sampled action (humanoid run, appendix A);
    /// no critic. The env's reward column of that name is only logged. Allowed only on
    /// an objective whose env declares `closed_form = action_norm`
    /// (`ObjectiveSpec::closed_form`: pendulum, humanoid-run); any other objective, and
    /// every objective of a server older than that declaration, is refused before
    /// training.
    ActionNorm,
}

impl std::fmt::Display for ObjectiveSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ObjectiveSource::Learned => "learned",
            ObjectiveSource::ActionNorm => "action_norm",
        })
    }
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
    /// MO-V-MPO (appendix D): on-policy, one state-value critic and one epsilon per
    /// objective.
    MoVmpo,
    /// Scalarized V-MPO: one state-value critic on sum_k w_k r_k (eq. 8 for mocap)
    /// and one epsilon.
    ScalarizedVmpo {
        /// KL bound of the single step 1 (Table 5 "default epsilon" 0.1).
        epsilon: f64,
        /// One weight per env objective.
        weights: Vec<ObjectiveWeight>,
    },
}

impl Algorithm {
    /// V-MPO family: on-policy unrolls, state-value critics, `vmpo` hyperparameters.
    pub fn on_policy(&self) -> bool {
        matches!(self, Algorithm::MoVmpo | Algorithm::ScalarizedVmpo { .. })
    }

    /// Short name for run directories and tables.
    pub fn short_name(&self) -> &'static str {
        match self {
            Algorithm::MoMpo => "mompo",
            Algorithm::ScalarizedMpo { .. } => "mpo",
            Algorithm::MoVmpo => "movmpo",
            Algorithm::ScalarizedVmpo { .. } => "vmpo",
        }
    }

    /// The scalarization (epsilon, weights) of the scalarized baselines.
    pub fn scalarization(&self) -> Option<(f64, &[ObjectiveWeight])> {
        match self {
            Algorithm::ScalarizedMpo { epsilon, weights }
            | Algorithm::ScalarizedVmpo { epsilon, weights } => Some((*epsilon, weights)),
            Algorithm::MoMpo | Algorithm::MoVmpo => None,
        }
    }
}

/// Everything the learner needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerConfig {
    /// Which algorithm.
    pub algorithm: Algorithm,
    /// MO-MPO / MO-V-MPO objectives (ignored by the scalarized baselines).
    pub objectives: Vec<ObjectiveConfig>,
    /// Network sizes and options.
    pub network: NetworkConfig,
    /// MPO and training hyperparameters (MO-MPO, scalarized MPO).
    pub mpo: MpoConfig,
    /// V-MPO and training hyperparameters (MO-V-MPO, scalarized V-MPO).
    pub vmpo: VmpoConfig,
    /// Seed of network initialisation.
    pub seed: u64,
    /// libtorch intra-op threads; `None` = all available cores.
    pub num_threads: Option<usize>,
    /// Where the learner runs: `auto` (a GPU when libtorch sees one and the networks
    /// are large enough to gain from it, see `device.rs`), `cpu` or `cuda`.
    pub device: DeviceChoice,
    /// ε-conditioned MO-MPO: one run learns a grid of preferences (a whole front)
    /// instead of one ε vector. Absent: the paper's MO-MPO, one preference per run.
    pub conditioning: Option<ConditioningConfig>,
}

/// The learner's device setting (`learner.device`, `--device`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum DeviceChoice {
    /// CUDA for networks large enough to gain from it, when a GPU is visible; else CPU.
    #[default]
    Auto,
    /// Always the CPU.
    Cpu,
    /// CUDA device 0; an error when libtorch sees no GPU.
    Cuda,
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            algorithm: Algorithm::MoMpo,
            objectives: Vec::new(),
            network: NetworkConfig::default(),
            mpo: MpoConfig::default(),
            vmpo: VmpoConfig::default(),
            seed: 0,
            num_threads: None,
            device: DeviceChoice::Auto,
            conditioning: None,
        }
    }
}

impl LearnerConfig {
    /// Input features an ε-conditioned learner appends to observations (0 otherwise).
    pub fn preference_features(&self) -> usize {
        self.conditioning.as_ref().map_or(0, |c| c.epsilon.len())
    }

    /// Checks every field (names against the env are checked by `algo::objectives::bind`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.network.validate()?;
        if self.algorithm.on_policy() {
            self.vmpo.validate()?;
        } else {
            self.mpo.validate()?;
        }
        if let Some(t) = self.num_threads {
            check(t >= 1, "num_threads", ">= 1 when set", t)?;
        }
        match &self.algorithm {
            Algorithm::MoMpo | Algorithm::MoVmpo => {
                check(
                    !self.objectives.is_empty(),
                    "objectives",
                    &format!("non-empty for {}", self.algorithm.short_name()),
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
            Algorithm::ScalarizedMpo { epsilon, weights }
            | Algorithm::ScalarizedVmpo { epsilon, weights } => {
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
        for (field, features) in [
            ("network.policy_preference", self.network.policy_preference),
            ("network.critic_preference", self.network.critic_preference),
        ] {
            check(
                features == PreferenceFeatures::Input || self.conditioning.is_some(),
                field,
                "\"input\" without [learner.conditioning] (there are no preference features)",
                "every_layer",
            )?;
        }
        if let Some(c) = &self.conditioning {
            c.validate_for(self)?;
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
    fn vmpo_defaults_are_table_5() {
        let v = VmpoConfig::default();
        assert_eq!((v.beta_mean, v.beta_cov), (0.1, 1e-5));
        assert_eq!(
            (v.learning_rate, v.batch_size, v.unroll_length),
            (1e-4, 128, 32)
        );
        assert_eq!(
            (v.init_temperature, v.discount, v.top_k_fraction),
            (1.0, 0.95, 0.5)
        );
        let c = LearnerConfig {
            algorithm: Algorithm::MoVmpo,
            ..LearnerConfig::default()
        };
        assert_eq!(
            (c.shared().batch_size, c.shared().sequence_length),
            (128, 32)
        );
        assert_eq!(
            LearnerConfig::default().shared().sequence_length,
            8,
            "MPO: the Retrace length"
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
        c.network.min_variance = 1e-12;
        c.network.policy_preference = PreferenceFeatures::EveryLayer;
        assert_eq!(
            c.validate().unwrap_err().to_string(),
            "network.policy_preference must be \"input\" without [learner.conditioning] \
             (there are no preference features), got \"every_layer\""
        );
        c.network.policy_preference = PreferenceFeatures::Input;
        c.network.critic_preference = PreferenceFeatures::EveryLayer;
        assert_eq!(
            c.validate().unwrap_err().to_string(),
            "network.critic_preference must be \"input\" without [learner.conditioning] \
             (there are no preference features), got \"every_layer\""
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
        let per_dim: LearnerConfig =
            toml::from_str("[mpo]\nkl_constraint = \"per_dimension\"\n").unwrap();
        assert_eq!(per_dim.mpo.kl_constraint, KlConstraint::PerDimension);
        assert_eq!(c.mpo.kl_constraint, KlConstraint::Summed, "the default");
        let err = toml::from_str::<LearnerConfig>("[vmpo]\nkl_constraint = \"per_dim\"\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("per_dimension"), "{err}");
        let bad = "[mpo]\nbeta_mena = 1.0\n";
        let err = toml::from_str::<LearnerConfig>(bad)
            .unwrap_err()
            .to_string();
        assert!(err.contains("beta_mena"), "{err}");
    }
}
