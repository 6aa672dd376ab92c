//! The hyperparameters MPO and V-MPO have in common, read from the section of the
//! configured family (`mpo` or `vmpo`), so that the machinery both use (optimizers,
//! duals, trust region, targets, batching) has one source.

use super::LearnerConfig;
use serde::{Deserialize, Serialize};

/// How the Gaussian trust region of the policy fit (eq. 20 for MO-MPO, eq. 25 for
/// MO-V-MPO) bounds KL(pi_old || pi) over the D action dimensions. Categorical
/// policies have one KL either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KlConstraint {
    /// The KL of the full D-dimensional Gaussian (summed over dimensions) is bounded
    /// by beta, with one alpha_mu and one alpha_Sigma: eqs. 20 and 25 as the paper
    /// writes them.
    #[default]
    Summed,
    /// Each dimension's KL is bounded by beta separately, with D multipliers
    /// alpha_mu and D alpha_Sigma: Acme's `per_dim_constraining` (its default). With
    /// the same beta this allows up to D times more change per step than `summed`.
    PerDimension,
}

/// How the temperatures eta_k are parameterized for their Adam steps (`dual.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TemperatureParameterization {
    /// eta = softplus(p) + 1e-8, as Acme. One Adam step moves p, and so eta, by about
    /// one dual learning rate: a reward k times larger needs about k times more steps
    /// before eta has grown to match it, so preferences hold only at the fixed point.
    #[default]
    Softplus,
    /// eta = exp(p) + 1e-8: one Adam step changes eta by a factor of about
    /// exp(dual learning rate), whatever its size, so the lag after a reward is
    /// rescaled grows only with the log of the scale.
    Log,
}

/// The hyperparameters both algorithm families have, read from `mpo` (MO-MPO,
/// scalarized MPO) or `vmpo` (MO-V-MPO, scalarized V-MPO), so that the shared
/// machinery (optimizers, duals, trust region, targets, batching) has one source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SharedSettings {
    /// Adam learning rate of the policy.
    pub policy_learning_rate: f64,
    /// Adam learning rate of the critics.
    pub critic_learning_rate: f64,
    /// Adam epsilon of policy and critics.
    pub adam_eps: f64,
    /// Adam learning rate of the duals.
    pub dual_learning_rate: f64,
    /// Initial eta_k.
    pub init_temperature: f64,
    /// Initial alpha_mu.
    pub init_alpha_mean: f64,
    /// Initial alpha_Sigma.
    pub init_alpha_cov: f64,
    /// Initial categorical alpha.
    pub init_alpha_categorical: f64,
    /// beta_mu.
    pub beta_mean: f64,
    /// beta_Sigma.
    pub beta_cov: f64,
    /// Categorical beta.
    pub beta_categorical: f64,
    /// Snippets (MPO) or unrolls (V-MPO) per learner step.
    pub batch_size: usize,
    /// Transitions per snippet (Retrace length) or unroll.
    pub sequence_length: usize,
    /// gamma.
    pub discount: f64,
    /// Learner steps between target-network updates.
    pub target_update_period: u64,
    /// How far each target update moves the targets towards the online networks (1:
    /// a copy).
    pub target_update_rate: f64,
    /// Lower bounds of the trust-region multipliers: (alpha_mu, alpha_Sigma) and the
    /// categorical alpha.
    pub min_alpha: MinAlpha,
    /// Second-moment decay of the duals' Adam.
    pub dual_adam_beta2: f64,
    /// The trust region's projection: KL at most this times beta after each step.
    pub max_kl_ratio: Option<f64>,
    /// Gradient clip of policy and critics.
    pub grad_clip_norm: Option<f64>,
    /// Summed or per-dimension Gaussian trust region.
    pub kl_constraint: KlConstraint,
    /// How the temperatures are parameterized.
    pub temperature_parameterization: TemperatureParameterization,
}

/// Lower bounds of the trust-region multipliers (0: only the parameter floor).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MinAlpha {
    /// alpha_mu.
    pub mean: f64,
    /// alpha_Sigma.
    pub cov: f64,
    /// The categorical policy's alpha.
    pub categorical: f64,
}

impl LearnerConfig {
    /// The shared hyperparameters of this config's algorithm family.
    pub fn shared(&self) -> SharedSettings {
        if self.algorithm.on_policy() {
            let v = &self.vmpo;
            SharedSettings {
                policy_learning_rate: v.learning_rate,
                critic_learning_rate: v.learning_rate,
                adam_eps: v.adam_eps,
                dual_learning_rate: v.dual_learning_rate,
                init_temperature: v.init_temperature,
                init_alpha_mean: v.init_alpha_mean,
                init_alpha_cov: v.init_alpha_cov,
                init_alpha_categorical: v.init_alpha_categorical,
                beta_mean: v.beta_mean,
                beta_cov: v.beta_cov,
                beta_categorical: v.beta_categorical,
                batch_size: v.batch_size,
                sequence_length: v.unroll_length,
                discount: v.discount,
                target_update_period: v.target_update_period,
                // V-MPO copies pi_old (Song et al. 2020); its duals keep Adam's
                // defaults and only the parameter floor.
                target_update_rate: 1.0,
                min_alpha: MinAlpha::default(),
                dual_adam_beta2: 0.999,
                max_kl_ratio: None,
                grad_clip_norm: v.grad_clip_norm,
                kl_constraint: v.kl_constraint,
                temperature_parameterization: v.temperature_parameterization,
            }
        } else {
            let m = &self.mpo;
            SharedSettings {
                policy_learning_rate: m.policy_learning_rate.unwrap_or(m.learning_rate),
                critic_learning_rate: m.critic_learning_rate.unwrap_or(m.learning_rate),
                adam_eps: m.adam_eps,
                dual_learning_rate: m.dual_learning_rate,
                init_temperature: m.init_temperature,
                init_alpha_mean: m.init_alpha_mean,
                init_alpha_cov: m.init_alpha_cov,
                init_alpha_categorical: m.init_alpha_categorical,
                beta_mean: m.beta_mean,
                beta_cov: m.beta_cov,
                beta_categorical: m.beta_categorical,
                batch_size: m.batch_size,
                sequence_length: m.retrace_length,
                discount: m.discount,
                target_update_period: m.target_update_period,
                target_update_rate: m.target_update_rate,
                min_alpha: MinAlpha {
                    mean: m.min_alpha_mean,
                    cov: m.min_alpha_cov,
                    categorical: m.min_alpha_categorical,
                },
                dual_adam_beta2: m.dual_adam_beta2,
                max_kl_ratio: m.max_kl_ratio,
                grad_clip_norm: m.grad_clip_norm,
                kl_constraint: m.kl_constraint,
                temperature_parameterization: m.temperature_parameterization,
            }
        }
    }
}
