//! M-step of MO-MPO (Sec. 4.2.2; appendix C.3, eqs. 16-20; Algorithm 3 lines 15-21).
//!
//! Gaussian, decoupled (eqs. 18-20): with online (mu, sigma) and target (mu', sigma'),
//! `pi_mu = N(mu, sigma')` and `pi_Sigma = N(mu', sigma)`. The loss is
//! `-mean_s sum_j w_j [log pi_mu(a_j|s) + log pi_Sigma(a_j|s)]` with `w_j = sum_k q_k(a_j|s)`
//! (the weights sum to K per state), plus the trust-region terms. The KLs are
//! old || new, per dimension
//! `KL_mu,d = (mu'_d - mu_d)^2 / (2 sigma'_d^2)`,
//! `KL_Sigma,d = log(sigma_d / sigma'_d) + sigma'_d^2 / (2 sigma_d^2) - 1/2`,
//! averaged over states, and bounded in one of two ways (`KlConstraint`):
//! - **summed** (eq. 20 as written): `KL_mu = sum_d KL_mu,d` against beta_mu with one
//!   scalar alpha_mu (likewise Sigma). Policy term `sg(alpha_mu) KL_mu + sg(alpha_Sigma) KL_Sigma`,
//!   multiplier loss `alpha_mu (beta_mu - sg(KL_mu)) + alpha_Sigma (beta_Sigma - sg(KL_Sigma))`.
//! - **per dimension** (Acme's `per_dim_constraining`): every `KL_mu,d` against beta_mu
//!   with its own alpha_mu,d; the terms above become sums over d of
//!   `sg(alpha_mu,d) KL_mu,d` and `alpha_mu,d (beta_mu - sg(KL_mu,d))`.
//!
//! Either way alpha grows while its KL exceeds its bound.
//!
//! Categorical (A.2): `-mean_s sum_a w_a log pi(a|s) + sg(alpha) KL(pi_old || pi)` and
//! `alpha (beta - sg(KL))`.
//!
//! Populations: every tensor may carry leading member axes (`online [P, B, D]`,
//! `actions [P, M, B, D]`, alpha `[P, 1]` or `[P, D]`); the means over states are
//! then each member's (`StateMean::Members`), the KLs and multipliers per member, and
//! the losses the sums of the members' losses.
//!
//! Shape legend: M samples (or A actions), B states, D action dims, P multipliers per
//! trust-region part (1 summed, D per dimension); leading `..` member axes.

use super::estep::StateMean;
pub use crate::core::learner_config::KlConstraint;
use crate::core::nets::GaussianParams;
use tch::{Kind, Tensor};

/// Losses of the decoupled Gaussian M-step.
#[derive(Debug)]
pub struct GaussianMStepOutput {
    /// Scalar; gradient to the online policy only.
    pub policy_loss: Tensor,
    /// Scalar; gradient to alpha_mu and alpha_Sigma only.
    pub alpha_loss: Tensor,
    /// No gradient: KL(pi_old || pi_mu) averaged over states; a scalar (summed over
    /// D) or `[D]` (per dimension).
    pub kl_mean: Tensor,
    /// No gradient: KL(pi_old || pi_Sigma), shaped as `kl_mean`.
    pub kl_cov: Tensor,
}

/// Bounds and multipliers of the Gaussian trust region.
#[derive(Debug)]
pub struct TrustRegion<'a> {
    /// alpha_mu: scalar or `[1]` (summed), `[D]` (per dimension); positive, may
    /// require grad.
    pub alpha_mean: &'a Tensor,
    /// alpha_Sigma, shaped as `alpha_mean`.
    pub alpha_cov: &'a Tensor,
    /// Whether the bounds apply to the summed KL or to each dimension's.
    pub constraint: KlConstraint,
    /// beta_mu.
    pub beta_mean: f64,
    /// beta_Sigma.
    pub beta_cov: f64,
}

/// The decoupled KL terms of one state and action dimension.
#[derive(Debug)]
pub struct DecoupledKl {
    /// KL(pi_old || pi_mu).
    pub mean: Tensor,
    /// KL(pi_old || pi_Sigma).
    pub cov: Tensor,
}

/// Decoupled KL terms per state and action dimension.
/// # Shapes
/// `online, target: [B, D] -> [B, D]` each.
pub fn decoupled_kl(online: &GaussianParams, target: &GaussianParams) -> DecoupledKl {
    let target_var = target.std.square();
    DecoupledKl {
        mean: (&target.mean - &online.mean).square() / (&target_var * 2.0),
        cov: (&online.std / &target.std).log() + &target_var / (online.std.square() * 2.0) - 0.5,
    }
}

/// The decoupled KLs as the trust region bounds them: averaged over states (each
/// member's, by `states`), then summed over the D dimensions (`[..]`) or kept per
/// dimension (`[.., D]`).
/// # Shapes
/// `online, target [.., B, D]` (target without gradient).
pub fn trust_region_kl(
    online: &GaussianParams,
    target: &GaussianParams,
    constraint: KlConstraint,
    states: StateMean<'_>,
) -> DecoupledKl {
    let kl = decoupled_kl(online, target);
    let constrained = |kl: &Tensor| {
        let over_states = states.over_states(kl);
        match constraint {
            KlConstraint::Summed => over_states.sum_dim_intlist(-1, false, Kind::Float),
            KlConstraint::PerDimension => over_states,
        }
    };
    DecoupledKl {
        mean: constrained(&kl.mean),
        cov: constrained(&kl.cov),
    }
}

/// Decoupled Gaussian M-step loss.
/// # Shapes
/// `online, target [B, D]`, `actions [M, B, D]`, `weights [M, B]` (no gradient).
pub fn gaussian_mstep(
    online: &GaussianParams,
    target: &GaussianParams,
    actions: &Tensor,
    weights: &Tensor,
    region: &TrustRegion<'_>,
) -> GaussianMStepOutput {
    gaussian_mstep_with(online, target, actions, weights, region, StateMean::Uniform)
}

/// [`gaussian_mstep`] with leading member axes and each member's mean over its states.
pub fn gaussian_mstep_with(
    online: &GaussianParams,
    target: &GaussianParams,
    actions: &Tensor,
    weights: &Tensor,
    region: &TrustRegion<'_>,
    states: StateMean<'_>,
) -> GaussianMStepOutput {
    let target = target.detach();
    // Against the sample axis of `actions [.., M, B, D]`.
    let per_sample = |t: &Tensor| t.unsqueeze(-3);
    let fixed_std = GaussianParams {
        mean: per_sample(&online.mean),
        std: per_sample(&target.std),
    };
    let fixed_mean = GaussianParams {
        mean: per_sample(&target.mean),
        std: per_sample(&online.std),
    };
    let log_lik = fixed_std.log_prob(actions) + fixed_mean.log_prob(actions);
    let nll = -states
        .over_state_rows(&(weights.detach() * log_lik).sum_dim_intlist(-2, false, Kind::Float))
        .sum(Kind::Float);
    let DecoupledKl {
        mean: kl_mean,
        cov: kl_cov,
    } = trust_region_kl(online, &target, region.constraint, states);
    // Each multiplier against its KL: one per member (summed) or one per dimension.
    let against_alpha = |kl: &Tensor| match region.constraint {
        KlConstraint::Summed => kl.unsqueeze(-1),
        KlConstraint::PerDimension => kl.shallow_clone(),
    };
    let (kl_mu, kl_sigma) = (against_alpha(&kl_mean), against_alpha(&kl_cov));
    let penalty = (region.alpha_mean.detach() * &kl_mu).sum(Kind::Float)
        + (region.alpha_cov.detach() * &kl_sigma).sum(Kind::Float);
    let policy_loss = nll + penalty;
    let alpha_loss = (region.alpha_mean * (region.beta_mean - kl_mu.detach())).sum(Kind::Float)
        + (region.alpha_cov * (region.beta_cov - kl_sigma.detach())).sum(Kind::Float);
    GaussianMStepOutput {
        policy_loss,
        alpha_loss,
        kl_mean: kl_mean.detach(),
        kl_cov: kl_cov.detach(),
    }
}

/// Losses of the categorical M-step.
#[derive(Debug)]
pub struct CategoricalMStepOutput {
    /// Scalar; gradient to the online policy only.
    pub policy_loss: Tensor,
    /// Scalar; gradient to alpha only.
    pub alpha_loss: Tensor,
    /// Scalar (`[P]` for members), no gradient: KL(pi_old || pi).
    pub kl: Tensor,
}

/// Categorical M-step with one KL bound `beta`.
/// # Shapes
/// `online_logits, target_logits [B, A]`, `weights [A, B]` (no gradient), `alpha` scalar.
pub fn categorical_mstep(
    online_logits: &Tensor,
    target_logits: &Tensor,
    weights: &Tensor,
    alpha: &Tensor,
    beta: f64,
) -> CategoricalMStepOutput {
    categorical_mstep_with(
        online_logits,
        target_logits,
        weights,
        alpha,
        beta,
        StateMean::Uniform,
    )
}

/// [`categorical_mstep`] with leading member axes (`logits [P, B, A]`, `weights
/// [P, A, B]`, `alpha [P]`) and each member's mean over its states.
pub fn categorical_mstep_with(
    online_logits: &Tensor,
    target_logits: &Tensor,
    weights: &Tensor,
    alpha: &Tensor,
    beta: f64,
    states: StateMean<'_>,
) -> CategoricalMStepOutput {
    let log_online = online_logits.log_softmax(-1, Kind::Float);
    let log_target = target_logits.detach().log_softmax(-1, Kind::Float);
    let nll = -states
        .over_state_rows(
            &(weights.detach().transpose(-2, -1) * &log_online).sum_dim_intlist(
                -1,
                false,
                Kind::Float,
            ),
        )
        .sum(Kind::Float);
    let kl = states.over_state_rows(
        &(log_target.exp() * (&log_target - &log_online)).sum_dim_intlist(-1, false, Kind::Float),
    );
    let policy_loss = nll + (alpha.detach() * &kl).sum(Kind::Float);
    let alpha_loss = (alpha * (beta - kl.detach())).sum(Kind::Float);
    CategoricalMStepOutput {
        policy_loss,
        alpha_loss,
        kl: kl.detach(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn kl_is_zero_at_the_target_and_positive_elsewhere() {
        let opts = (Kind::Float, Device::Cpu);
        let target = GaussianParams {
            mean: Tensor::randn([4, 3], opts),
            std: Tensor::rand([4, 3], opts) + 0.1,
        };
        let kl = decoupled_kl(&target, &target);
        assert!(
            kl.mean.abs().max().double_value(&[]) < 1e-7
                && kl.cov.abs().max().double_value(&[]) < 1e-6
        );
        let moved = GaussianParams {
            mean: &target.mean + 0.1,
            std: &target.std * 1.1,
        };
        let kl = decoupled_kl(&moved, &target);
        assert!(kl.mean.min().double_value(&[]) > 0.0 && kl.cov.min().double_value(&[]) > 0.0);
    }
}
