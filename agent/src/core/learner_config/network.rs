//! Network sizes and options (Table 2 "policy network", "critic network(s)", "both
//! policy and critic networks"; A.3 for the humanoid mocap architecture).

use serde::{Deserialize, Serialize};

use super::ConfigError;
use super::error::check;

/// Which policy torso to build.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Architecture {
    /// One LayerNorm MLP of `policy_layers` on the whole observation (Table 2).
    #[default]
    Mlp,
    /// A.3 (humanoid mocap): a reference encoder MLP on the whole observation gives
    /// the mean and log standard deviation of a stochastic latent; the latent sample,
    /// concatenated with the proprioceptive observation, feeds the `policy_layers`
    /// MLP that outputs the action distribution. Needs a Dict observation space: the
    /// leaves whose name contains `reference_match` are the reference observation,
    /// the others proprioception.
    Mocap {
        /// Hidden sizes of the reference encoder; A.3: (1024, 1024).
        #[serde(default = "default_encoder_layers")]
        encoder_layers: Vec<i64>,
        /// Size of the latent. Not in the paper; 60 as in Hasenclever et al. (2020).
        #[serde(default = "default_latent_dim")]
        latent_dim: i64,
        /// Substring that marks reference-observation leaves (dm_control's tracking
        /// task names them `walker/reference_*`).
        #[serde(default = "default_reference_match")]
        reference_match: String,
    },
}

fn default_encoder_layers() -> Vec<i64> {
    vec![1024, 1024]
}

fn default_latent_dim() -> i64 {
    60
}

fn default_reference_match() -> String {
    "reference".into()
}

/// Where the Gaussian policy's standard deviation comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PolicyStd {
    /// The paper's (appendix A): the network outputs the diagonal Cholesky factor
    /// `A(s)` beside the mean, so mean and standard deviation share the torso.
    #[default]
    StateDependent,
    /// Not in the paper: one learned standard deviation per action dimension
    /// (`softplus` of a free parameter, PPO's and TRPO's choice), so the covariance's
    /// KL depends on that vector alone and the trust region's projection
    /// (`mpo.max_kl_ratio`) shortens the mean's and the covariance's steps each
    /// against its own bound, instead of shortening the mean's step whenever the torso's
    /// move changes the covariance (docs/benchmarks/mujoco.md).
    StateIndependent,
}

/// Where an ε-conditioned network reads its preference features (not in the paper,
/// whose networks are not conditioned; docs/algorithms/conditioned.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PreferenceFeatures {
    /// Appended to the observation, so they enter through the first layer only (as
    /// CAPQL's and most conditioned networks' inputs).
    #[default]
    Input,
    /// Also appended to the input of every later layer and of the heads, so that each
    /// layer can tell the preferences apart directly instead of through the first
    /// layer's LayerNorm, which normalises them together with the observation (and,
    /// in a critic, the action).
    EveryLayer,
}

/// Sizes and options of the policy and critic networks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Table 2 "policy network: layer sizes" (300, 200); humanoid (400, 400, 300);
    /// mocap (A.3) (1024, 1024) after the latent. The first layer is Linear ->
    /// LayerNorm -> tanh, later ones Linear -> ELU.
    pub policy_layers: Vec<i64>,
    /// Table 2 "critic network(s): layer sizes" (400, 400, 300); humanoid (500, 500,
    /// 400); mocap (A.3) (1024, 1024, 1024).
    pub critic_layers: Vec<i64>,
    /// How many of `critic_layers` all objectives share; the rest are per objective.
    /// Table 2: 1 ("shared first layer"); A.3 MO-V-MPO: 2.
    pub critic_shared_layers: usize,
    /// Table 2 "take tanh of action mean?" yes; humanoid no.
    pub tanh_on_action_mean: bool,
    /// Table 2 "minimum variance" 1e-12; humanoid 1e-8. The policy's standard
    /// deviation is `softplus(x) + sqrt(min_variance)`.
    pub min_variance: f64,
    /// Table 2 "take tanh of action?" (critic input) yes; humanoid no.
    pub tanh_on_critic_action: bool,
    /// The policy torso: the plain MLP, or A.3's mocap encoder with a latent.
    pub architecture: Architecture,
    /// The Gaussian policy's standard deviation: per state from the network (the
    /// paper's) or one learned value per action dimension.
    pub policy_std: PolicyStd,
    /// Where an ε-conditioned policy reads its preference features: `input` (with the
    /// observation) or `every_layer` (also beside every later layer's input and the
    /// head's). Needs `[learner.conditioning]` and the plain MLP torso.
    pub policy_preference: PreferenceFeatures,
    /// Where ε-conditioned Q critics read their preference features: `input` (with
    /// the observation and the action) or `every_layer` (also beside the input of
    /// every layer after the first, and of every head layer). Needs
    /// `[learner.conditioning]`.
    pub critic_preference: PreferenceFeatures,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        Self {
            policy_layers: vec![300, 200],
            critic_layers: vec![400, 400, 300],
            critic_shared_layers: 1,
            tanh_on_action_mean: true,
            min_variance: 1e-12,
            tanh_on_critic_action: true,
            architecture: Architecture::Mlp,
            policy_std: PolicyStd::StateDependent,
            policy_preference: PreferenceFeatures::Input,
            critic_preference: PreferenceFeatures::Input,
        }
    }
}

fn positive_sizes(field: &str, sizes: &[i64]) -> Result<(), ConfigError> {
    check(!sizes.is_empty(), field, "non-empty", sizes)?;
    check(sizes.iter().all(|&h| h > 0), field, "all > 0", sizes)
}

impl NetworkConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        positive_sizes("network.policy_layers", &self.policy_layers)?;
        positive_sizes("network.critic_layers", &self.critic_layers)?;
        check(
            (1..=self.critic_layers.len()).contains(&self.critic_shared_layers),
            "network.critic_shared_layers",
            &format!(
                "in 1..={} (the number of critic_layers)",
                self.critic_layers.len()
            ),
            self.critic_shared_layers,
        )?;
        check(
            self.min_variance.is_finite() && self.min_variance > 0.0,
            "network.min_variance",
            "> 0",
            self.min_variance,
        )?;
        if let Architecture::Mocap {
            encoder_layers,
            latent_dim,
            reference_match,
        } = &self.architecture
        {
            positive_sizes("network.architecture.encoder_layers", encoder_layers)?;
            check(
                *latent_dim > 0,
                "network.architecture.latent_dim",
                "> 0",
                latent_dim,
            )?;
            check(
                !reference_match.is_empty(),
                "network.architecture.reference_match",
                "non-empty",
                reference_match,
            )?;
        }
        Ok(())
    }
}
