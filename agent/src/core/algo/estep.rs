//! E-step of MO-MPO (Sec. 4.2.1; appendix E.1, eqs. 32-34; Algorithm 3 lines 9-13),
//! vectorised over the K objectives.
//!
//! Sampled (Gaussian policies): the M actions per state are drawn from the target
//! policy, so the prior pi_old is implicit and the weights are a softmax over samples,
//! `q_k(a_j|s) = softmax_j(Q_k(s, a_j) / eta_k)`. The temperature dual of eq. 34 is
//! estimated by Monte Carlo,
//! `g(eta_k) = eta_k * (eps_k + mean_s log mean_j exp(Q_kj / eta_k))`
//! `         = eta_k * (eps_k + mean_s logsumexp_j(Q_kj / eta_k) - log M)`.
//! Exact (categorical policies, A.2 and acme_mompo.md §3): all A actions are enumerated
//! with pi_old as the prior, `q_k = softmax_a(Q_k / eta_k + log pi_old)` and
//! `g(eta_k) = eta_k * (eps_k + mean_s logsumexp_a(Q_k / eta_k + log pi_old))` (no -log M).
//!
//! `torch.logsumexp` subtracts the per-state maximum over the sample axis before
//! exponentiating, so large Q / eta never overflow. Q and the weights carry no gradient;
//! the loss's gradient reaches only eta (`d g / d eta_k = eps_k - KL(q_k || pi_old)`).
//! `eps_k = 0` is the limit eta_k -> infinity: q_k is pi_old itself (uniform weights
//! over the samples, the prior for the exact case) and eta_k gets no gradient.
//!
//! MO-V-MPO's step 1 (appendix D.2.1) is `vmpo_estep.rs`.
//!
//! **Populations** (`StateMean::Members`): P members' E-steps at once, every tensor
//! member-first (`q [P, M, B, K]`, `temperature`, `epsilon [P, 1, K]`); each member's
//! dual averages over its own real states with the given state weights, so the loss
//! is the sum of the P members' losses and each eta gets exactly its member's gradient.
//!
//! Shape legend: P members, M samples (or A actions), B states, K objectives.

use tch::{Kind, Tensor};

/// Result of the E-step for all objectives.
#[derive(Debug)]
pub struct EStepOutput {
    /// `[M, B, K]`, no gradient; sums to 1 over M for every state and objective.
    pub weights: Tensor,
    /// Scalar: sum over objectives with eps_k > 0 of the dual g(eta_k); gradient only
    /// with respect to `temperature`.
    pub temperature_loss: Tensor,
    /// `[K]` (`[P, K]` for members), no gradient: realised KL(q_k || pi_old)
    /// averaged over states.
    pub kl: Tensor,
}

fn active_mask(epsilon: &Tensor) -> Tensor {
    epsilon.gt(0.0).to_kind(Kind::Float)
}

/// How the temperature dual of eq. 34 averages over states.
#[derive(Debug, Clone, Copy)]
pub enum StateMean<'a> {
    /// One ε and eta per objective (`[K]`): the plain mean over the B states.
    Uniform,
    /// ε-conditioned MO-MPO: `temperature` and `epsilon` are `[B, K]`, each state's
    /// grid point's, and each grid point's dual averages over its own states
    /// (`weights [B]`, summing to 1 over the states of one grid point); the duals of
    /// all grid points are summed, each depending only on its own eta.
    PerGridPoint(&'a Tensor),
    /// A population: `temperature` and `epsilon` are `[P, 1, K]`, and each member's
    /// dual averages over its own states with `weights [P, B]` (summing to 1 over a
    /// member's real states, 0 at the rows that only fill its batch to B).
    Members(&'a Tensor),
}

impl StateMean<'_> {
    /// `temperature` or `epsilon` shaped to divide `q [.., M, B, K]`.
    fn per_sample(self, t: &Tensor) -> Tensor {
        match self {
            StateMean::Members(_) => t.unsqueeze(-3),
            _ => t.shallow_clone(),
        }
    }

    /// The mean over states of `x [.., B, K]` (per member for a population).
    pub(crate) fn over_states(self, x: &Tensor) -> Tensor {
        match self {
            StateMean::Members(w) => (x * w.unsqueeze(-1)).sum_dim_intlist(-2, false, Kind::Float),
            _ => x.mean_dim(-2, false, Kind::Float),
        }
    }

    /// The mean over states of `x [.., B]` (per member for a population).
    pub(crate) fn over_state_rows(self, x: &Tensor) -> Tensor {
        match self {
            StateMean::Members(w) => (x * w).sum_dim_intlist(-1, false, Kind::Float),
            _ => x.mean_dim(-1, false, Kind::Float),
        }
    }

    /// `sum_k` of the dual `eta (eps + log_partition - offset)` over active objectives
    /// (`offset` = log M for the sampled E-step, 0 for the exact one).
    /// # Shapes
    /// `log_partition [B, K]`; `temperature`, `epsilon`, `active`: `[K]` (uniform) or
    /// `[B, K]` (per grid point).
    fn temperature_loss(
        self,
        log_partition: &Tensor,
        offset: f64,
        temperature: &Tensor,
        epsilon: &Tensor,
        active: &Tensor,
    ) -> Tensor {
        match self {
            StateMean::Uniform => {
                let mean = log_partition.mean_dim(-2, false, Kind::Float) - offset;
                let dual = temperature * (epsilon + mean);
                (dual * active).sum(Kind::Float)
            }
            StateMean::PerGridPoint(weights) | StateMean::Members(weights) => {
                let dual = temperature * (epsilon + (log_partition - offset));
                (dual * active * weights.unsqueeze(-1)).sum(Kind::Float)
            }
        }
    }
}

/// Sampled E-step (Gaussian policy).
/// # Shapes
/// `q [M, B, K]`, `temperature [K]` (positive, may require grad), `epsilon [K]`.
pub fn sampled_estep(q: &Tensor, temperature: &Tensor, epsilon: &Tensor) -> EStepOutput {
    sampled_estep_with(q, temperature, epsilon, StateMean::Uniform)
}

/// [`sampled_estep`] with temperature and epsilon `[K]`, per grid point `[B, K]`, or
/// for a population `[P, 1, K]` with `q [P, M, B, K]`.
pub fn sampled_estep_with(
    q: &Tensor,
    temperature: &Tensor,
    epsilon: &Tensor,
    states: StateMean<'_>,
) -> EStepOutput {
    let m = q.size()[q.dim() - 3];
    let active = active_mask(epsilon);
    let active_q = states.per_sample(&active);
    let scaled = q.detach() / states.per_sample(temperature);
    let softmax = scaled.detach().softmax(-3, Kind::Float);
    let weights: Tensor = &softmax * &active_q + (1.0 - &active_q) / (m as f64);
    let log_sum_exp = scaled.logsumexp([-3i64].as_slice(), false);
    let temperature_loss =
        states.temperature_loss(&log_sum_exp, (m as f64).ln(), temperature, epsilon, &active);
    let kl = states.over_states(
        &(&weights * (&weights * (m as f64)).clamp_min(1e-30).log()).sum_dim_intlist(
            -3,
            false,
            Kind::Float,
        ),
    );
    EStepOutput {
        weights,
        temperature_loss,
        kl,
    }
}

/// Exact E-step over all discrete actions with `log_prior = log pi_old`.
/// # Shapes
/// `q [A, B, K]`, `log_prior [A, B]`, `temperature [K]`, `epsilon [K]`.
pub fn exact_estep(
    q: &Tensor,
    log_prior: &Tensor,
    temperature: &Tensor,
    epsilon: &Tensor,
) -> EStepOutput {
    exact_estep_with(q, log_prior, temperature, epsilon, StateMean::Uniform)
}

/// [`exact_estep`] with temperature and epsilon `[K]`, per grid point `[B, K]`, or
/// for a population `[P, 1, K]` with `q [P, A, B, K]` and `log_prior [P, A, B]`.
pub fn exact_estep_with(
    q: &Tensor,
    log_prior: &Tensor,
    temperature: &Tensor,
    epsilon: &Tensor,
    states: StateMean<'_>,
) -> EStepOutput {
    let active = active_mask(epsilon);
    let active_q = states.per_sample(&active);
    let log_prior = log_prior.detach().unsqueeze(-1);
    let scaled = q.detach() / states.per_sample(temperature) + &log_prior;
    let posterior = scaled.detach().softmax(-3, Kind::Float);
    let weights: Tensor = &posterior * &active_q + log_prior.exp() * (1.0 - &active_q);
    let log_partition = scaled.logsumexp([-3i64].as_slice(), false);
    let temperature_loss =
        states.temperature_loss(&log_partition, 0.0, temperature, epsilon, &active);
    let kl = states.over_states(
        &(&weights * (weights.clamp_min(1e-30).log() - &log_prior)).sum_dim_intlist(
            -3,
            false,
            Kind::Float,
        ),
    );
    EStepOutput {
        weights,
        temperature_loss,
        kl,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn huge_q_over_small_eta_stays_finite() {
        let q = Tensor::from_slice(&[1e4f32, 0.0, -1e4]).reshape([3, 1, 1]);
        let eta = Tensor::from_slice(&[1e-3f32]);
        let out = sampled_estep(&q, &eta, &Tensor::from_slice(&[0.1f32]));
        assert_eq!(out.weights.double_value(&[0, 0, 0]), 1.0);
        assert!(out.temperature_loss.double_value(&[]).is_finite());
    }

    #[test]
    fn zero_epsilon_gives_prior_weights_and_no_dual_gradient() {
        let q = Tensor::randn([4, 3, 2], (Kind::Float, Device::Cpu));
        let eta = Tensor::from_slice(&[0.5f32, 0.5]).set_requires_grad(true);
        let eps = Tensor::from_slice(&[0.1f32, 0.0]);
        let out = sampled_estep(&q, &eta, &eps);
        assert!(out.weights.select(2, 1).allclose(
            &Tensor::full([4, 3], 0.25, (Kind::Float, Device::Cpu)),
            1e-6,
            1e-7,
            false
        ));
        out.temperature_loss.backward();
        assert_eq!(eta.grad().double_value(&[1]), 0.0);
        assert_ne!(eta.grad().double_value(&[0]), 0.0);
        let prior = Tensor::from_slice(&[0.1f32, 0.2, 0.3, 0.4])
            .log()
            .reshape([4, 1])
            .expand([4, 3], false);
        let exact = exact_estep(&q, &prior, &eta.detach(), &eps);
        assert!(
            exact
                .weights
                .select(2, 1)
                .allclose(&prior.exp(), 1e-6, 1e-7, false)
        );
    }

    #[test]
    fn per_grid_point_duals_are_the_grid_points_own_estep_duals() {
        // States 0, 2, 3 are at grid point 0 (eta 1.5, 0.5; eps 0.1, 0.01), states 1, 4
        // at grid point 1 (eta 0.7, 2.0; eps 0.3, 0.05). The conditioned loss must be
        // the sum of the two plain E-steps run on each point's states alone, with the
        // same gradient for each point's temperatures, for both E-step kinds.
        let q =
            crate::core::random::StreamKey::new(9, crate::core::random::Purpose::LearnerNoise, 0)
                .at(0)
                .normal(&[6, 5, 2], Device::Cpu);
        let prior = q.select(2, 0).log_softmax(0, Kind::Float);
        let mut table = Tensor::from_slice(&[1.5f32, 0.5, 0.7, 2.0])
            .reshape([2, 2])
            .set_requires_grad(true);
        let eps = Tensor::from_slice(&[0.1f32, 0.01, 0.3, 0.05]).reshape([2, 2]);
        let index = Tensor::from_slice(&[0i64, 1, 0, 0, 1]);
        let weights = Tensor::from_slice(&[1.0f32 / 3.0, 0.5, 1.0 / 3.0, 1.0 / 3.0, 0.5]);
        let groups = [
            Tensor::from_slice(&[0i64, 2, 3]),
            Tensor::from_slice(&[1i64, 4]),
        ];
        for exact in [false, true] {
            let run = |q: &Tensor, prior: &Tensor, eta: &Tensor, eps: &Tensor, states| {
                if exact {
                    exact_estep_with(q, prior, eta, eps, states)
                } else {
                    sampled_estep_with(q, eta, eps, states)
                }
            };
            let eta = table.index_select(0, &index);
            let e = eps.index_select(0, &index);
            let joint = run(&q, &prior, &eta, &e, StateMean::PerGridPoint(&weights));
            table.zero_grad();
            joint.temperature_loss.backward();
            let joint_grad = table.grad().copy();
            table.zero_grad();
            let mut separate = Tensor::zeros([], (Kind::Float, Device::Cpu));
            for (g, rows) in groups.iter().enumerate() {
                let out = run(
                    &q.index_select(1, rows),
                    &prior.index_select(1, rows),
                    &table.get(g as i64),
                    &eps.get(g as i64),
                    StateMean::Uniform,
                );
                separate += out.temperature_loss;
                let w = joint.weights.index_select(1, rows);
                assert!(
                    w.allclose(&out.weights, 1e-6, 1e-7, false),
                    "weights, exact {exact}"
                );
            }
            separate.backward();
            let close = |a: &Tensor, b: &Tensor| (a - b).abs().max().double_value(&[]) < 1e-5;
            assert!(
                close(&joint.temperature_loss, &separate),
                "loss, exact {exact}"
            );
            assert!(close(&joint_grad, &table.grad()), "gradient, exact {exact}");
        }
    }
}
