//! M-step of MO-MPO (Sec. 4.2.2; appendix C.3, eqs. 16-20; Algorithm 3 lines 15-21).
//!
//! Gaussian, decoupled (eqs. 18-20): with online (mu, sigma) and target (mu', sigma'),
//! `pi_mu = N(mu, sigma')` and `pi_Sigma = N(mu', sigma)`. The loss is
//! `-mean_s sum_j w_j [log pi_mu(a_j|s) + log pi_Sigma(a_j|s)]` with `w_j = sum_k q_k(a_j|s)`
//! (the weights sum to K per state), plus `sg(alpha_mu) KL_mu + sg(alpha_Sigma) KL_Sigma`.
//! The KLs are old || new, summed over action dimensions (documented choice: eq. 20
//! bounds the full-distribution KL with one beta each; Acme's per-dimension variant is
//! not used) and averaged over states:
//! `KL_mu = mean_s sum_d (mu' - mu)^2 / (2 sigma'^2)`,
//! `KL_Sigma = mean_s sum_d [log(sigma / sigma') + sigma'^2 / (2 sigma^2) - 1/2]`.
//! The multipliers' loss is `alpha_mu (beta_mu - sg(KL_mu)) + alpha_Sigma (beta_Sigma - sg(KL_Sigma))`,
//! so alpha grows while the KL exceeds its bound.
//!
//! Categorical (A.2): `-mean_s sum_a w_a log pi(a|s) + sg(alpha) KL(pi_old || pi)` and
//! `alpha (beta - sg(KL))`.
//!
//! Shape legend: M samples (or A actions), B states, D action dims.

use crate::nets::GaussianParams;
use tch::{Kind, Tensor};

/// Losses of the decoupled Gaussian M-step.
#[derive(Debug)]
pub struct GaussianMStepOutput {
    /// Scalar; gradient to the online policy only.
    pub policy_loss: Tensor,
    /// Scalar; gradient to alpha_mu and alpha_Sigma only.
    pub alpha_loss: Tensor,
    /// Scalar, no gradient: KL(pi_old || pi_mu).
    pub kl_mean: Tensor,
    /// Scalar, no gradient: KL(pi_old || pi_Sigma).
    pub kl_cov: Tensor,
}

/// Bounds and multipliers of the Gaussian trust region.
#[derive(Debug)]
pub struct TrustRegion<'a> {
    /// alpha_mu (scalar, positive, may require grad).
    pub alpha_mean: &'a Tensor,
    /// alpha_Sigma (scalar, positive, may require grad).
    pub alpha_cov: &'a Tensor,
    /// beta_mu.
    pub beta_mean: f64,
    /// beta_Sigma.
    pub beta_cov: f64,
}

/// Decoupled KL terms, each `[B]` summed over D.
/// # Shapes
/// `online, target: [B, D] -> ([B], [B])`.
pub fn decoupled_kl(online: &GaussianParams, target: &GaussianParams) -> (Tensor, Tensor) {
    let target_var = target.std.square();
    let kl_mean = ((&target.mean - &online.mean).square() / (&target_var * 2.0)).sum_dim_intlist(
        -1,
        false,
        Kind::Float,
    );
    let kl_cov = ((&online.std / &target.std).log() + &target_var / (online.std.square() * 2.0)
        - 0.5)
        .sum_dim_intlist(-1, false, Kind::Float);
    (kl_mean, kl_cov)
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
    let target = target.detach();
    let fixed_std = GaussianParams {
        mean: online.mean.shallow_clone(),
        std: target.std.shallow_clone(),
    };
    let fixed_mean = GaussianParams {
        mean: target.mean.shallow_clone(),
        std: online.std.shallow_clone(),
    };
    let log_lik = fixed_std.log_prob(actions) + fixed_mean.log_prob(actions);
    let nll = -(weights.detach() * log_lik)
        .sum_dim_intlist(0, false, Kind::Float)
        .mean(Kind::Float);
    let (kl_mean_s, kl_cov_s) = decoupled_kl(online, &target);
    let kl_mean = kl_mean_s.mean(Kind::Float);
    let kl_cov = kl_cov_s.mean(Kind::Float);
    let policy_loss =
        nll + region.alpha_mean.detach() * &kl_mean + region.alpha_cov.detach() * &kl_cov;
    let alpha_loss = region.alpha_mean * (region.beta_mean - kl_mean.detach())
        + region.alpha_cov * (region.beta_cov - kl_cov.detach());
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
    /// Scalar, no gradient: KL(pi_old || pi).
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
    let log_online = online_logits.log_softmax(-1, Kind::Float);
    let log_target = target_logits.detach().log_softmax(-1, Kind::Float);
    let nll = -(weights.detach().transpose(0, 1) * &log_online)
        .sum_dim_intlist(-1, false, Kind::Float)
        .mean(Kind::Float);
    let kl = (log_target.exp() * (&log_target - &log_online))
        .sum_dim_intlist(-1, false, Kind::Float)
        .mean(Kind::Float);
    let policy_loss = nll + alpha.detach() * &kl;
    let alpha_loss = alpha * (beta - kl.detach());
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
        let (km, kc) = decoupled_kl(&target, &target);
        assert!(km.abs().max().double_value(&[]) < 1e-7 && kc.abs().max().double_value(&[]) < 1e-6);
        let moved = GaussianParams {
            mean: &target.mean + 0.1,
            std: &target.std * 1.1,
        };
        let (km, kc) = decoupled_kl(&moved, &target);
        assert!(km.min().double_value(&[]) > 0.0 && kc.min().double_value(&[]) > 0.0);
    }
}
