//! V-MPO hyperparameters of MO-V-MPO and scalarized V-MPO (appendix D; Table 5, the
//! humanoid mocap experiments, which are the paper's only on-policy ones, so its
//! values are the defaults; A.3 for the discount).

use serde::{Deserialize, Serialize};

use super::error::{check, finite_pos, non_negative};
use super::{ConfigError, KlConstraint, TemperatureParameterization};

/// Which (s, a) pairs step 1 keeps (D.2.1 "top-k advantages") and how the objectives'
/// improved distributions become the fit's weights. With one objective every rule is
/// V-MPO's step; they differ in how ε_k acts as a preference
/// (docs/algorithms/mo-v-mpo-preferences.md has the derivation and measurements).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TopK {
    /// One selection for all objectives, the top `top_k_fraction` of the pairs by
    /// sum_k A_k / eta_k over the objectives with ε_k > 0, and fit weights
    /// proportional to exp(sum_k A_k / eta_k) on it; each eta_k's dual (eq. 24) is over
    /// the selection. ε_k -> 0 removes objective k continuously, and a larger ε_k never
    /// lowers the fit's mean A_k (ours; the default).
    #[default]
    Joint,
    /// The `joint` selection, with the fit weights the sum over objectives of each
    /// q_k over it (eq. 25 as written; uniform for ε_k = 0). ε_k -> 0 removes
    /// objective k continuously, but a change of the selection can lower the fit's
    /// mean A_k when ε_k grows.
    Shared,
    /// Each objective keeps the top of its own advantages and q_k sums to 1 over
    /// them; ε_k = 0 gives uniform weights over all real pairs. Every ε_k > 0 then
    /// carries the same mass into the fit: the rule before issue 38, kept to
    /// reproduce its results and as "each objective improves, ε only shapes how".
    PerObjective,
    /// Each objective's top half sets its dual, and the fit weights every real pair
    /// by the sum over objectives of softmax(A_k / eta_k) over all of them (no
    /// selection in the fit; with one objective this is not V-MPO's step).
    DualsOnly,
}

/// V-MPO, policy-evaluation and training hyperparameters (Table 5; appendix D).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VmpoConfig {
    /// Table 5 "unroll length (for n-step return, Sec. D.1)" 32: transitions per
    /// unroll, and the T of the T-step return targets (eq. 21).
    pub unroll_length: usize,
    /// Discount gamma of the critics' targets (the T-step returns, eq. 21). A.3:
    /// "k-step returns ... with a discount factor of 0.95".
    pub discount: f64,
    /// D.2.1 "top-k advantages": the fraction of the batch's (s, a) pairs kept, 0.5
    /// (Song et al. 2020); which pairs, per `top_k`.
    pub top_k_fraction: f64,
    /// How the top-k selection and the objectives' weights combine (see `TopK`).
    /// Not in the paper, which keeps "the top 50% of advantages in each batch"
    /// without saying how for several objectives; `"joint"`, so that ε_k is a
    /// preference (issue 38).
    pub top_k: TopK,
    /// KL bound beta_mu of the Gaussian policy's mean (eq. 25): on the KL summed over
    /// action dimensions, or on each dimension's KL with `kl_constraint = "per_dimension"`.
    /// Table 5 "KL-constraint on policy mean" 0.1.
    pub beta_mean: f64,
    /// KL bound beta_Sigma of the Gaussian policy's covariance (eq. 25), summed or per
    /// dimension as `beta_mean`. Table 5 "KL-constraint on policy covariance" 1e-5.
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
    /// KL bound beta of a categorical policy. Not in the paper (its V-MPO runs are all
    /// Gaussian); 0.01, V-MPO's epsilon_alpha for discrete actions (Song et al. 2020).
    pub beta_categorical: f64,
    /// Initial temperature eta_k (its value, not its parameter's). Table 5 "initial
    /// temperature eta" 1.
    pub init_temperature: f64,
    /// Initial Lagrange multiplier alpha_mu (its value). Not in the paper; 1.
    pub init_alpha_mean: f64,
    /// Initial Lagrange multiplier alpha_Sigma (its value). Not in the paper; 1.
    pub init_alpha_cov: f64,
    /// Initial Lagrange multiplier alpha of a categorical policy (its value). Not in
    /// the paper; 1.
    pub init_alpha_categorical: f64,
    /// Adam learning rate of the duals (eta_k, alpha). Not in the paper; 1e-2, as for
    /// MO-MPO, so that one gradient step per learner step (D.2.1) moves eta.
    pub dual_learning_rate: f64,
    /// Adam learning rate of policy and critics. Table 5 "Adam learning rate" 1e-4.
    pub learning_rate: f64,
    /// Adam epsilon of policy and critics. Not in Table 5; 1e-8 (Adam's usual value).
    pub adam_eps: f64,
    /// Table 5 "batch size" 128 (unrolls per learner step); each is used once (more
    /// often with `epochs` > 1).
    pub batch_size: usize,
    /// Learner steps between target-network updates: of pi_old, the target of the KL
    /// trust region (eq. 25); V-MPO's critics have no target. Not in the paper; V-MPO's
    /// T_target, 100.
    pub target_update_period: u64,
    /// Global-norm clip of policy and critic gradients (duals are never clipped);
    /// unset (default): no clipping. Not in the paper.
    pub grad_clip_norm: Option<f64>,
    /// Passes over each batch. Not in the paper: V-MPO uses each batch once (1, the
    /// default). More passes do more updates per env step, as PPO's epochs do; every
    /// update of a learner step is bounded by the same pi_old (see `target_update_period`).
    pub epochs: usize,
    /// Disjoint minibatches of unrolls per pass, shuffled afresh each pass; one update
    /// each. Not in the paper; 1 (the whole batch). Must divide `batch_size`.
    pub minibatches: usize,
    /// When a learner step makes more than one update (`epochs` x `minibatches` > 1)
    /// and ends with KL(pi_old || pi) above a beta, pull the policy's parameters back
    /// along the line from the step's start to its end until every part is within
    /// its beta (at the step's real states). Each update's Lagrangian bounds the KL
    /// only on average over updates; this bounds the step. Not in the paper (one
    /// update per batch); on by default (ours). No effect on one-update steps.
    pub project_step_kl: bool,
}

impl Default for VmpoConfig {
    fn default() -> Self {
        Self {
            unroll_length: 32,
            discount: 0.95,
            top_k_fraction: 0.5,
            beta_mean: 0.1,
            beta_cov: 1e-5,
            kl_constraint: KlConstraint::Summed,
            temperature_parameterization: TemperatureParameterization::Softplus,
            beta_categorical: 0.01,
            init_temperature: 1.0,
            init_alpha_mean: 1.0,
            init_alpha_cov: 1.0,
            init_alpha_categorical: 1.0,
            dual_learning_rate: 1e-2,
            learning_rate: 1e-4,
            adam_eps: 1e-8,
            batch_size: 128,
            target_update_period: 100,
            grad_clip_norm: None,
            epochs: 1,
            minibatches: 1,
            top_k: TopK::Joint,
            project_step_kl: true,
        }
    }
}

impl VmpoConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let v = self;
        check(
            v.unroll_length >= 1,
            "vmpo.unroll_length",
            ">= 1",
            v.unroll_length,
        )?;
        check(
            (0.0..=1.0).contains(&v.discount),
            "vmpo.discount",
            "in [0, 1]",
            v.discount,
        )?;
        check(
            v.top_k_fraction > 0.0 && v.top_k_fraction <= 1.0,
            "vmpo.top_k_fraction",
            "in (0, 1]",
            v.top_k_fraction,
        )?;
        non_negative("vmpo.beta_mean", v.beta_mean)?;
        non_negative("vmpo.beta_cov", v.beta_cov)?;
        non_negative("vmpo.beta_categorical", v.beta_categorical)?;
        for (field, x) in [
            ("vmpo.init_temperature", v.init_temperature),
            ("vmpo.init_alpha_mean", v.init_alpha_mean),
            ("vmpo.init_alpha_cov", v.init_alpha_cov),
            ("vmpo.init_alpha_categorical", v.init_alpha_categorical),
            ("vmpo.dual_learning_rate", v.dual_learning_rate),
            ("vmpo.learning_rate", v.learning_rate),
            ("vmpo.adam_eps", v.adam_eps),
        ] {
            check(finite_pos(x), field, "> 0", x)?;
        }
        check(v.batch_size >= 1, "vmpo.batch_size", ">= 1", v.batch_size)?;
        check(
            v.target_update_period >= 1,
            "vmpo.target_update_period",
            ">= 1",
            v.target_update_period,
        )?;
        if let Some(c) = v.grad_clip_norm {
            check(finite_pos(c), "vmpo.grad_clip_norm", "> 0 when set", c)?;
        }
        check(v.epochs >= 1, "vmpo.epochs", ">= 1", v.epochs)?;
        check(
            v.minibatches >= 1 && v.batch_size.is_multiple_of(v.minibatches),
            "vmpo.minibatches",
            &format!(">= 1 and a divisor of vmpo.batch_size ({})", v.batch_size),
            v.minibatches,
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_need_one_epoch_and_minibatches_that_divide_the_batch() {
        let uneven = VmpoConfig {
            batch_size: 64,
            minibatches: 3,
            ..VmpoConfig::default()
        };
        let err = uneven.validate().unwrap_err().to_string();
        assert!(
            err.contains("vmpo.minibatches") && err.contains("(64)") && err.contains('3'),
            "{err}"
        );
        let none = VmpoConfig {
            epochs: 0,
            ..VmpoConfig::default()
        };
        assert!(
            none.validate()
                .unwrap_err()
                .to_string()
                .contains("vmpo.epochs")
        );
        let ok = VmpoConfig {
            batch_size: 64,
            minibatches: 4,
            epochs: 3,
            ..VmpoConfig::default()
        };
        ok.validate().unwrap();
    }
}
