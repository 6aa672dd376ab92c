//! MPO policy-evaluation and training hyperparameters of MO-MPO and scalarized MPO
//! (Table 2 "MPO", "training"; Table 3 overrides are presets in `configs/`).

use serde::{Deserialize, Serialize};

use super::error::{check, finite_pos, non_negative};
use super::{ConfigError, KlConstraint, TemperatureParameterization};

/// MPO, policy-evaluation and training hyperparameters (Table 2 "MPO", "training").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MpoConfig {
    /// Table 2 "actions sampled per state" M = 20; Shadow Hand 30, Sawyer 15.
    pub num_samples: i64,
    /// KL bound beta_mu of the Gaussian policy's mean (eq. 20): on the KL summed over
    /// action dimensions, or on each dimension's KL with `kl_constraint = "per_dimension"`.
    /// Table 2 "KL-constraint on policy mean" 1e-3; humanoid 5e-3.
    pub beta_mean: f64,
    /// KL bound beta_Sigma of the Gaussian policy's covariance (eq. 20), summed or per
    /// dimension as `beta_mean`. Table 2 "KL-constraint on policy covariance" 1e-5;
    /// humanoid 1e-6.
    pub beta_cov: f64,
    /// How beta_mu and beta_Sigma bound the Gaussian policy's KL over the D action
    /// dimensions. The paper does not say which its betas were tuned for. No effect on
    /// categorical policies.
    pub kl_constraint: KlConstraint,
    /// How eta_k is parameterized for its Adam steps: `"softplus"` (default, Acme's
    /// eta = softplus(p)) or `"log"` (eta = exp(p)), whose steps are relative, so that
    /// eta catches up with a rescaled reward in about log(scale) / dual learning rate
    /// steps instead of about scale times more (docs/algorithms/mo-mpo.md, "Reward
    /// scale: a bandit").
    pub temperature_parameterization: TemperatureParameterization,
    /// KL bound beta of a categorical policy. A.2 (Deep Sea Treasure): 1e-3.
    pub beta_categorical: f64,
    /// Initial temperature eta_k (its value, not its parameter's). Table 2 "initial
    /// temperature eta" 1.
    pub init_temperature: f64,
    /// Initial Lagrange multiplier alpha_mu (its value). Not in the paper; 1 (Acme TF
    /// MO-MPO starts its parameter at 1, i.e. softplus(1) ~ 1.31).
    pub init_alpha_mean: f64,
    /// Initial Lagrange multiplier alpha_Sigma (its value). Not in the paper; 10, as
    /// Acme TF MO-MPO.
    pub init_alpha_cov: f64,
    /// Initial Lagrange multiplier alpha of a categorical policy (its value). Not in
    /// the paper; 1.
    pub init_alpha_categorical: f64,
    /// Adam learning rate of the duals (eta_k, alpha). Not in the paper; 1e-2, as
    /// Acme.
    pub dual_learning_rate: f64,
    /// Table 2 "Retrace sequence size" 8. A.2 (Deep Sea Treasure): 1, which makes
    /// the Retrace target a one-step TD target.
    pub retrace_length: usize,
    /// Discount gamma of the critics' targets (Retrace, eq. 15). Table 2 "discount
    /// factor gamma" 0.99; A.2 (Deep Sea Treasure) 0.999.
    pub discount: f64,
    /// Learner steps between target-network updates (C.1): of pi_old, the target of
    /// the KL trust region, and of the target critics. Table 2 "target network update
    /// period" 200; Sawyer 100.
    pub target_update_period: u64,
    /// Adam learning rate of policy and critics (`policy_learning_rate` and
    /// `critic_learning_rate` can set them apart). Table 2 "Adam learning rate" 3e-4;
    /// humanoid 2e-4.
    pub learning_rate: f64,
    /// Adam epsilon of policy and critics. Table 2 "Adam epsilon" 1e-3; humanoid 1e-8.
    pub adam_eps: f64,
    /// Table 2 "batch size" 512 (snippets per learner step).
    pub batch_size: usize,
    /// Table 2 "replay buffer size" 1e6 transitions (used by the replay, not the learner).
    pub replay_capacity: usize,
    /// Global-norm clip of policy and critic gradients (duals are never clipped);
    /// unset (default): no clipping. Not in the paper; Acme TF clips at 40.
    pub grad_clip_norm: Option<f64>,
    /// Adam learning rate of the policy alone, when it should differ from
    /// `learning_rate` (Table 2 has one rate for policy and critics; Acme sets them
    /// apart). `None` (default): `learning_rate`.
    pub policy_learning_rate: Option<f64>,
    /// Adam learning rate of the critics alone; `None` (default): `learning_rate`.
    pub critic_learning_rate: Option<f64>,
    /// How far the target networks move towards the online ones at each target
    /// update, in (0, 1]: 1 (default) copies them, as C.1 and Algorithm 3 line 32 do;
    /// a small rate with `target_update_period = 1` is Polyak averaging
    /// (`target <- target + rate (online - target)` every learner step; Acme's JAX
    /// MPO offers both). Not in the paper.
    pub target_update_rate: f64,
    /// Lower bound of alpha_mu: after each dual step alpha_mu is projected onto
    /// [bound, inf). The paper's multiplier only has to stay positive (C.3); 0
    /// (default) keeps the parameter floor every dual has (alpha >= ~1.5e-8). A bound
    /// keeps alpha from decaying towards 0 while the policy's KL stays under beta_mu;
    /// on its own it did not stop the KL spikes measured on pendulum
    /// (docs/stability.md), `max_kl_ratio` does.
    pub min_alpha_mean: f64,
    /// Lower bound of alpha_Sigma, as `min_alpha_mean`; 0 (default): none.
    pub min_alpha_cov: f64,
    /// Lower bound of the categorical policy's alpha, as `min_alpha_mean`; 0
    /// (default): none.
    pub min_alpha_categorical: f64,
    /// Second-moment decay of the duals' Adam (eta_k and alpha). Not in the paper;
    /// 0.999 (default) is Adam's and Acme's. Adam divides each step by the root of
    /// this average of squared gradients, so after one spike of KL far over beta
    /// (a gradient hundreds of times the usual) alpha's steps stay tiny for about
    /// 1 / (1 - beta2) steps: with 0.999 alpha stays high, and the policy frozen,
    /// for thousands of learner steps. 0.9 forgets a spike within a few hundred.
    pub dual_adam_beta2: f64,
    /// Projection of the policy onto its trust region: after each M-step, a policy
    /// whose KL from the target policy exceeds `max_kl_ratio` times beta (either
    /// part of the Gaussian KL, or the categorical KL) is moved back towards the
    /// target policy along its displacement: first to where a KL growing as the
    /// square of the displacement would be 0.9 of the bound, then halved until the
    /// KL is within, and put at the target after ten halvings
    /// (`algo/projection.rs`); with `network.policy_std = "state_independent"` the
    /// mean and the covariance each along their own parameters. The paper keeps
    /// the KL under beta by Lagrangian relaxation alone (C.3), which holds it on
    /// average but lets one target period of steps move the policy by hundreds of
    /// times beta after alpha has decayed (docs/stability.md). `None` (default): the
    /// paper's relaxation only.
    pub max_kl_ratio: Option<f64>,
    /// ε of MPO's out-of-bounds action penalty (Acme's `action_penalization`, there
    /// on by default with ε 1e-3): one more E-step objective, `action_penalty`, whose
    /// Q is `-||a - clip(a, -1, 1)||_2` of each sampled action in closed form, with its
    /// own temperature (per grid point when ε-conditioned); its weights join the
    /// others' in the M-step. The env executes a clipped action, so the critics score
    /// every sample beyond a bound alike, and a mean that has drifted past a bound
    /// gets no pull back from them (measured on mo-halfcheetah: docs/benchmarks/mujoco.md);
    /// the penalty pulls it back. Continuous actions and the off-policy learners only.
    /// The paper does not say how samples beyond the bounds are treated; `None`
    /// (default): no penalty.
    pub action_penalization: Option<f64>,
}

impl Default for MpoConfig {
    fn default() -> Self {
        Self {
            num_samples: 20,
            beta_mean: 1e-3,
            beta_cov: 1e-5,
            kl_constraint: KlConstraint::Summed,
            temperature_parameterization: TemperatureParameterization::Softplus,
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
            policy_learning_rate: None,
            critic_learning_rate: None,
            target_update_rate: 1.0,
            min_alpha_mean: 0.0,
            min_alpha_cov: 0.0,
            min_alpha_categorical: 0.0,
            dual_adam_beta2: 0.999,
            max_kl_ratio: None,
            action_penalization: None,
        }
    }
}

impl MpoConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let m = self;
        check(m.num_samples >= 1, "mpo.num_samples", ">= 1", m.num_samples)?;
        non_negative("mpo.beta_mean", m.beta_mean)?;
        non_negative("mpo.beta_cov", m.beta_cov)?;
        non_negative("mpo.beta_categorical", m.beta_categorical)?;
        for (field, v) in [
            ("mpo.init_temperature", m.init_temperature),
            ("mpo.init_alpha_mean", m.init_alpha_mean),
            ("mpo.init_alpha_cov", m.init_alpha_cov),
            ("mpo.init_alpha_categorical", m.init_alpha_categorical),
            ("mpo.dual_learning_rate", m.dual_learning_rate),
            ("mpo.learning_rate", m.learning_rate),
            ("mpo.adam_eps", m.adam_eps),
        ] {
            check(finite_pos(v), field, "> 0", v)?;
        }
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
        for (field, rate) in [
            ("mpo.policy_learning_rate", m.policy_learning_rate),
            ("mpo.critic_learning_rate", m.critic_learning_rate),
        ] {
            if let Some(r) = rate {
                check(finite_pos(r), field, "> 0 when set", r)?;
            }
        }
        check(
            m.target_update_rate > 0.0 && m.target_update_rate <= 1.0,
            "mpo.target_update_rate",
            "in (0, 1]",
            m.target_update_rate,
        )?;
        non_negative("mpo.min_alpha_mean", m.min_alpha_mean)?;
        non_negative("mpo.min_alpha_cov", m.min_alpha_cov)?;
        non_negative("mpo.min_alpha_categorical", m.min_alpha_categorical)?;
        if let Some(r) = m.max_kl_ratio {
            check(
                r.is_finite() && r >= 1.0,
                "mpo.max_kl_ratio",
                ">= 1 when set",
                r,
            )?;
        }
        if let Some(e) = m.action_penalization {
            check(
                finite_pos(e),
                "mpo.action_penalization",
                "an ε > 0 when set",
                e,
            )?;
        }
        check(
            m.dual_adam_beta2 > 0.0 && m.dual_adam_beta2 < 1.0,
            "mpo.dual_adam_beta2",
            "in (0, 1)",
            m.dual_adam_beta2,
        )?;
        Ok(())
    }
}
