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
//! ε-conditioned with a trust region per grid point (`TrustRegion::per_point`): the
//! KLs are averaged over each grid point's states instead, against that point's
//! multipliers (`[G]` or `[G * D]`); each state's KL enters the policy loss with its
//! own point's alpha, and a point without states in the batch keeps its alpha.
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
//! trust-region part (1 summed, D per dimension; G times that per grid point), G grid
//! points; leading `..` member axes.

use super::estep::StateMean;
use super::preferences::StatePreferences;
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
    /// ε-conditioned with one set of multipliers per grid point
    /// (`learner.conditioning.trust_region = "per_point"`): each state's grid point,
    /// and alpha_mu, alpha_Sigma are `[G]` (summed) or `[G * D]` (per dimension).
    pub per_point: Option<&'a StatePreferences>,
}

/// The trust region's constrained KLs lined up with their multipliers, each
/// multiplier's weight in the policy loss and whether its constraint is active.
struct Constrained {
    mean: Tensor,
    cov: Tensor,
    /// Weight of each `alpha * KL` term in the policy loss.
    penalty_weight: Tensor,
    /// 1 where a multiplier's constraint has states in the batch.
    active: Tensor,
}

/// Lines the KLs up with the multipliers: over all states (one multiplier, or one
/// per dimension), or per grid point. Per grid point, each state's KL is penalised
/// with its own point's alpha (the penalty is the mean over states of
/// `alpha_g(s) KL(s)`: point g's term weighs its share of the states), while each
/// alpha_g's own loss sees its point's KL against beta unweighted, as the shared
/// alpha does; a point without states in the batch leaves its alpha unchanged.
fn constrained(
    online: &GaussianParams,
    target: &GaussianParams,
    region: &TrustRegion<'_>,
    states: StateMean<'_>,
) -> (DecoupledKl, Constrained) {
    let per_state = decoupled_kl(online, target);
    let kl = bounded_kl(&per_state, region.constraint, states);
    let against_alpha = |kl: &Tensor| match region.constraint {
        KlConstraint::Summed => kl.unsqueeze(-1),
        KlConstraint::PerDimension => kl.shallow_clone(),
    };
    let lined_up = match region.per_point {
        None => Constrained {
            mean: against_alpha(&kl.mean),
            cov: against_alpha(&kl.cov),
            penalty_weight: Tensor::ones([], (Kind::Float, kl.mean.device())),
            active: Tensor::ones([], (Kind::Float, kl.mean.device())),
        },
        Some(points) => {
            let DecoupledKl { mean, cov } = &per_state;
            let d = mean.size()[mean.dim() - 1];
            // [.., G, D] -> [.., G] summed or [.., G * D] per dimension, g-major.
            let per_point = |kl: &Tensor| {
                let kl = points.mean_per_point(kl);
                match region.constraint {
                    KlConstraint::Summed => kl.sum_dim_intlist(-1, false, Kind::Float),
                    KlConstraint::PerDimension => kl.flatten(-2, -1),
                }
            };
            let per_multiplier = |g: Tensor| match region.constraint {
                KlConstraint::Summed => g,
                KlConstraint::PerDimension => g.unsqueeze(-1).repeat([1, d]).flatten(0, 1),
            };
            Constrained {
                mean: per_point(mean),
                cov: per_point(cov),
                penalty_weight: per_multiplier(points.share()),
                active: per_multiplier(points.present()),
            }
        }
    };
    (kl, lined_up)
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
    bounded_kl(&decoupled_kl(online, target), constraint, states)
}

/// Per-state decoupled KLs `[.., B, D]` reduced as [`trust_region_kl`] does.
fn bounded_kl(kl: &DecoupledKl, constraint: KlConstraint, states: StateMean<'_>) -> DecoupledKl {
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
    let (kl, lined_up) = constrained(online, &target, region, states);
    let Constrained {
        mean: kl_mu,
        cov: kl_sigma,
        penalty_weight,
        active,
    } = lined_up;
    let penalty = (region.alpha_mean.detach() * &kl_mu * &penalty_weight).sum(Kind::Float)
        + (region.alpha_cov.detach() * &kl_sigma * &penalty_weight).sum(Kind::Float);
    let policy_loss = nll + penalty;
    let alpha_loss = (region.alpha_mean * (region.beta_mean - kl_mu.detach()) * &active)
        .sum(Kind::Float)
        + (region.alpha_cov * (region.beta_cov - kl_sigma.detach()) * &active).sum(Kind::Float);
    let DecoupledKl {
        mean: kl_mean,
        cov: kl_cov,
    } = kl;
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

    /// Spread, repeatable values of `shape` (no global generator): sin(1.7 i + phase).
    fn spread(shape: &[i64], phase: f64) -> Tensor {
        let count: i64 = shape.iter().product();
        (Tensor::arange(count, (Kind::Float, Device::Cpu)) * 1.7 + phase)
            .sin()
            .reshape(shape)
    }

    #[test]
    fn a_per_point_trust_region_penalises_each_state_with_its_points_alpha() {
        let (n, d, m) = (6, 3, 4);
        let target = GaussianParams {
            mean: spread(&[n, d], 0.0),
            std: spread(&[n, d], 1.0).abs() + 0.2,
        };
        let online = GaussianParams {
            mean: &target.mean + spread(&[n, d], 2.0) * 0.3,
            std: &target.std * (spread(&[n, d], 3.0) * 0.2 + 1.0),
        };
        let actions = spread(&[m, n, d], 4.0);
        let weights = spread(&[m, n], 5.0).abs();
        // Three grid points; the last has no state in the batch.
        let points = StatePreferences::new(
            Tensor::from_slice(&[0i64, 0, 1, 1, 1, 0]),
            &Tensor::ones([3, 1], (Kind::Float, Device::Cpu)),
        );
        for (constraint, per_point_len) in [
            (KlConstraint::Summed, 3),
            (KlConstraint::PerDimension, 3 * d),
        ] {
            let shared_len = if per_point_len == 3 { 1 } else { d };
            let run = |len: i64, per_point: Option<&StatePreferences>| {
                let alpha_mean =
                    Tensor::full([len], 0.7, (Kind::Float, Device::Cpu)).set_requires_grad(true);
                let alpha_cov =
                    Tensor::full([len], 2.0, (Kind::Float, Device::Cpu)).set_requires_grad(true);
                let region = TrustRegion {
                    alpha_mean: &alpha_mean,
                    alpha_cov: &alpha_cov,
                    constraint,
                    beta_mean: 0.05,
                    beta_cov: 1e-3,
                    per_point,
                };
                let out = gaussian_mstep(&online, &target, &actions, &weights, &region);
                out.alpha_loss.backward();
                (out.policy_loss.double_value(&[]), alpha_mean.grad())
            };
            // Equal multipliers: each state's KL weighs the same as with one shared alpha.
            let (shared_loss, _) = run(shared_len, None);
            let (loss, grad) = run(per_point_len, Some(&points));
            assert!((shared_loss - loss).abs() < 1e-5, "{shared_loss} vs {loss}");
            // Each alpha_g's gradient is beta - KL_g over its own states; none at point 2.
            let kl = decoupled_kl(&online, &target).mean.detach();
            let grad = grad.reshape([3, -1]);
            for (g, rows) in [(0usize, vec![0i64, 1, 5]), (1, vec![2, 3, 4])] {
                let own =
                    kl.index_select(0, &Tensor::from_slice(&rows))
                        .mean_dim(0, false, Kind::Float);
                let own = match constraint {
                    KlConstraint::Summed => own.sum(Kind::Float).reshape([1]),
                    KlConstraint::PerDimension => own,
                };
                let want = -(own - 0.05);
                let got = grad.get(g as i64);
                assert!(
                    (&got - &want).abs().max().double_value(&[]) < 1e-5,
                    "{constraint:?} point {g}: {got:?} vs {want:?}"
                );
            }
            assert_eq!(grad.get(2).abs().max().double_value(&[]), 0.0);
        }
    }
}
