//! MO-V-MPO's step 1 (appendix D.2.1, eqs. 22-24) and the top-k selection that goes
//! with it. With one action per state, q_k is a distribution over the batch's (s, a)
//! pairs, `q_k ∝ p_old exp(A_k / eta_k)` (eq. 23), p_old uniform over the eligible
//! pairs (real steps: padding after an episode's end, and episode starts where a
//! caller's unrolls cross episodes, are never eligible).
//!
//! **Top-k** (D.2.1, "the top 50% of advantages in each batch", after Song et al.
//! 2020; rlax `get_top_k_weights`): with n eligible pairs and a score per pair,
//! k = max(1, floor(fraction n)), the threshold is the k-th largest score, and every
//! eligible pair scoring >= it is kept (ties can admit more than k). `TopK` says whose
//! score and what the fit weights are (docs/algorithms/mo-v-mpo-preferences.md
//! derives them); with `lambda_k = 1 / eta_k` for objectives with eps_k > 0 and 0
//! otherwise:
//! - `joint`: one selection S by `s_i = sum_k lambda_k A_ki`, the log-density ratio
//!   of the product `p_old prod_k exp(A_k / eta_k)`; fit weights `softmax_S(s)`, one
//!   distribution, so an objective with eps_k = 0 leaves the step exactly as it is
//!   without that objective.
//! - `shared`: S as `joint`; fit weights `sum_k q_k` with `q_k = softmax_S(A_k / eta_k)`
//!   (uniform over S for eps_k = 0).
//! - `per_objective`: S_k the top of A_k; `q_k = softmax_{S_k}(A_k / eta_k)`, uniform
//!   over the eligible pairs for eps_k = 0.
//! - `duals_only`: S_k as `per_objective` for the duals only; `q_k = softmax(A_k /
//!   eta_k)` over every eligible pair.
//!
//! Every rule's dual for eta_k is eq. 24 over the pairs S_k selected for objective k
//! (S for `joint` and `shared`), with m_k = sg(max_{S_k} A_k / eta_k):
//! `g(eta_k) = eta_k (eps_k + log mean_{S_k} exp(A_k / eta_k))`
//! `         = eta_k (eps_k + m_k + log sum_{S_k} exp(A_k / eta_k - m_k) - log |S_k|)`;
//! objectives with eps_k = 0 get no dual gradient (their limit is eta_k -> infinity).
//! The other rules' fit weights sum to K per member, the mass of eq. 25's sum of K
//! log-likelihoods. With one objective every rule but `duals_only` is V-MPO's step.
//!
//! Populations: every tensor may carry a leading member axis (`[P, N, K]`,
//! temperatures `[P, 1, K]`); selections, softmaxes and duals are each member's own.
//!
//! Shape legend: P members, N (s, a) pairs, K objectives.

pub use crate::core::learner_config::TopK;
use tch::{Kind, Tensor};

/// What step 1 reads.
#[derive(Debug)]
pub struct StepOneInputs<'a> {
    /// `[.., N, K]` A_k per pair (no gradient needed).
    pub advantages: &'a Tensor,
    /// `[.., N]` f32 in {0, 1}, at least one 1 per member.
    pub eligible: &'a Tensor,
    /// eta_k, `[K]` or `[P, 1, K]`, positive; may require grad.
    pub temperature: &'a Tensor,
    /// eps_k, shaped as `temperature`.
    pub epsilon: &'a Tensor,
    /// The top-k fraction in (0, 1].
    pub fraction: f64,
    /// Whose top-k and which weights.
    pub rule: TopK,
}

/// Result of MO-V-MPO's step 1 for all objectives.
#[derive(Debug)]
pub struct StepOneOutput {
    /// `[.., N]`, no gradient: the policy fit's weight of each pair (eq. 25), summing
    /// per member to 1 (`joint`) or K (the other rules).
    pub fit_weights: Tensor,
    /// `[.., N, K]` f32 in {0, 1}: the pairs each objective's dual averages over.
    pub selected: Tensor,
    /// Scalar: sum over members and objectives with eps_k > 0 of g(eta_k); gradient
    /// only with respect to `temperature`.
    pub temperature_loss: Tensor,
    /// `[.., K]`, no gradient: for eps_k > 0 the KL from p_old of q_k ∝ exp(A_k /
    /// eta_k) on objective k's selection, log(n / |S_k|) plus the KL its dual bounds
    /// by eps_k; 0 for eps_k = 0.
    pub kl: Tensor,
}

/// The top-`fraction` selection per member and column among its eligible pairs.
/// k is computed on the device (in f64, as `floor(fraction * n)` on the host would
/// be), and the threshold is the k-th value of a descending sort: the k-th largest,
/// with no host read and one k per member.
/// # Shapes
/// `scores [.., N, C]`, `eligible [.., N]` f32 in {0, 1} (at least one 1 per
/// member) `-> [.., N, C]` f32.
pub fn top_k_mask(scores: &Tensor, eligible: &Tensor, fraction: f64) -> Tensor {
    let n_eligible = eligible.sum_dim_intlist(-1, true, Kind::Double);
    let k = (n_eligible * fraction)
        .floor()
        .clamp_min(1.0)
        .to_kind(Kind::Int64);
    let is_eligible = eligible.gt(0.5).unsqueeze(-1);
    let masked = scores
        .detach()
        .masked_fill(&is_eligible.logical_not(), f64::NEG_INFINITY);
    let (sorted, _) = masked.sort(-2, true);
    let columns = *scores.size().last().expect("[.., N, C]");
    let mut at = (k - 1).unsqueeze(-1);
    let mut shape = at.size();
    *shape.last_mut().expect("[.., 1, 1]") = columns;
    at = at.expand(shape.as_slice(), false);
    let threshold = sorted.gather(-2, &at, false);
    masked
        .ge_tensor(&threshold)
        .logical_and(&is_eligible)
        .to_kind(Kind::Float)
}

/// Softmax over the pairs of `x [.., N, C]` restricted to `mask` (each column has at
/// least one 1).
fn masked_softmax(x: &Tensor, mask: &Tensor) -> Tensor {
    x.masked_fill(&mask.lt(0.5), f64::NEG_INFINITY)
        .softmax(-2, Kind::Float)
}

/// Uniform weights over `mask [.., N, C]`, per column.
fn uniform(mask: &Tensor) -> Tensor {
    mask / mask.sum_dim_intlist(-2, true, Kind::Float)
}

/// Eq. 24 per objective over its selection: `[.., 1, K]`, gradient to eta only.
fn duals(scaled: &Tensor, selected: &Tensor, temperature: &Tensor, epsilon: &Tensor) -> Tensor {
    let over_pairs = [-2i64];
    let kept = scaled.masked_fill(&selected.lt(0.5), f64::NEG_INFINITY);
    let max = kept.detach().amax(over_pairs.as_slice(), true);
    let log_sum = (&kept - &max).logsumexp(over_pairs.as_slice(), true);
    let count = selected.sum_dim_intlist(-2, true, Kind::Float);
    temperature * (epsilon + log_sum + max - count.log())
}

/// MO-V-MPO step 1 (see module docs), for one learner or a population's members at
/// once (each member's selection, weights and dual over its own pairs).
pub fn advantage_estep(x: &StepOneInputs<'_>) -> StepOneOutput {
    let active = x.epsilon.gt(0.0).to_kind(Kind::Float);
    let eligible = x.eligible.detach().to_kind(Kind::Float);
    let advantages = x.advantages.detach();
    let scaled = &advantages / x.temperature;
    let tilts = scaled.detach();
    let all = eligible.unsqueeze(-1).expand_as(&advantages);
    let score = (&tilts * &active).sum_dim_intlist(-1, true, Kind::Float);
    let selected = match x.rule {
        TopK::Joint | TopK::Shared => {
            top_k_mask(&score, &eligible, x.fraction).expand_as(&advantages)
        }
        TopK::PerObjective | TopK::DualsOnly => top_k_mask(&advantages, &eligible, x.fraction),
    };
    let temperature_loss =
        (duals(&scaled, &selected, x.temperature, x.epsilon) * &active).sum(Kind::Float);
    let on_selection = masked_softmax(&tilts, &selected);
    // ε_k = 0 is the limit eta_k -> infinity of each rule's q_k.
    let mixed = |q: &Tensor, limit: &Tensor| {
        let mix: Tensor = q * &active + limit * (1.0 - &active);
        mix.sum_dim_intlist(-1, false, Kind::Float)
    };
    let fit_weights = match x.rule {
        TopK::Joint => masked_softmax(&score, &selected.narrow(-1, 0, 1)).squeeze_dim(-1),
        TopK::Shared => mixed(&on_selection, &uniform(&selected)),
        TopK::PerObjective => mixed(&on_selection, &uniform(&all)),
        TopK::DualsOnly => mixed(&masked_softmax(&tilts, &all), &uniform(&all)),
    };
    let n_eligible = eligible
        .sum_dim_intlist(-1, true, Kind::Float)
        .unsqueeze(-1);
    let active_k = match active.dim() {
        1 => active.shallow_clone(),
        _ => active.squeeze_dim(-2),
    };
    let kl = (&on_selection * (&on_selection * n_eligible).clamp_min(1e-30).log()).sum_dim_intlist(
        -2,
        false,
        Kind::Float,
    ) * active_k;
    StepOneOutput {
        fit_weights,
        selected,
        temperature_loss,
        kl,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::random::{Purpose, StreamKey};
    use tch::Device;

    /// `[n, k]` standard normals from a keyed stream, column c scaled by `scales[c]`;
    /// with `conflict`, column 1 is mostly -column 0 (objectives in conflict).
    fn advantages(seed: u64, n: i64, scales: &[f64], conflict: bool) -> Tensor {
        let k = scales.len() as i64;
        let a = StreamKey::new(seed, Purpose::LearnerNoise, 7)
            .at(0)
            .normal(&[n, k], Device::Cpu);
        if conflict {
            let mixed = a.select(1, 0) * -0.7 + a.select(1, 1) * 0.5;
            a.select(1, 1).copy_(&mixed);
        }
        a * Tensor::from_slice(scales).to_kind(Kind::Float)
    }

    fn step(a: &Tensor, eligible: &Tensor, eta: &[f64], eps: &[f64], rule: TopK) -> StepOneOutput {
        let f = |v: &[f64]| Tensor::from_slice(v).to_kind(Kind::Float);
        advantage_estep(&StepOneInputs {
            advantages: a,
            eligible,
            temperature: &f(eta),
            epsilon: &f(eps),
            fraction: 0.5,
            rule,
        })
    }

    fn values(t: &Tensor) -> Vec<f64> {
        Vec::<f64>::try_from(&t.to_kind(Kind::Double).flatten(0, -1)).expect("values")
    }

    #[test]
    fn top_k_keeps_ties_and_skips_ineligible_pairs() {
        // Column 0: eligible values 3, 1, 1, 0 (the 9 is ineligible): k = 2, threshold 1,
        // so both tied 1s are kept. Column 1: the top 2 eligible are 5 and 4.
        let a = Tensor::from_slice(&[9.0f32, 0.0, 3.0, 5.0, 1.0, 4.0, 1.0, -1.0, 0.0, 2.0])
            .reshape([5, 2]);
        let eligible = Tensor::from_slice(&[0.0f32, 1.0, 1.0, 1.0, 1.0]);
        let mask = top_k_mask(&a, &eligible, 0.5);
        let want = Tensor::from_slice(&[0.0f32, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
            .reshape([5, 2]);
        assert!(mask.equal(&want), "{mask}");
    }

    /// V-MPO's step 1 written out on the host: the top floor(n / 2) eligible pairs by
    /// A (ties in), weights exp(A / eta) normalised over them, and the dual
    /// eta (eps + log mean_S exp(A / eta)).
    fn vmpo_by_hand(a: &[f64], eligible: &[f64], eta: f64, eps: f64) -> (Vec<f64>, f64) {
        let mut ranked: Vec<f64> = (0..a.len())
            .filter(|&i| eligible[i] > 0.5)
            .map(|i| a[i])
            .collect();
        ranked.sort_by(|x, y| y.total_cmp(x));
        let threshold = ranked[(ranked.len() / 2).max(1) - 1];
        let kept: Vec<bool> = (0..a.len())
            .map(|i| eligible[i] > 0.5 && a[i] >= threshold)
            .collect();
        let z: f64 = (0..a.len())
            .filter(|&i| kept[i])
            .map(|i| (a[i] / eta).exp())
            .sum();
        let count = kept.iter().filter(|&&k| k).count() as f64;
        let w = (0..a.len())
            .map(|i| if kept[i] { (a[i] / eta).exp() / z } else { 0.0 })
            .collect();
        (w, eta * (eps + (z / count).ln()))
    }

    #[test]
    fn with_one_objective_every_selecting_rule_is_v_mpos_step() {
        let a = advantages(1, 41, &[2.0], false);
        let mut el = vec![1.0f64; 41];
        (el[3], el[17], el[40]) = (0.0, 0.0, 0.0);
        let eligible = Tensor::from_slice(&el).to_kind(Kind::Float);
        let (want_w, want_dual) = vmpo_by_hand(&values(&a), &el, 0.7, 0.05);
        for rule in [TopK::Joint, TopK::Shared, TopK::PerObjective] {
            let out = step(&a, &eligible, &[0.7], &[0.05], rule);
            for (got, want) in values(&out.fit_weights).iter().zip(&want_w) {
                assert!(
                    (got - want).abs() < 1e-6,
                    "{rule:?}: weight {got} vs {want}"
                );
            }
            let dual = out.temperature_loss.double_value(&[]);
            assert!(
                (dual - want_dual).abs() < 1e-5,
                "{rule:?}: dual {dual} vs {want_dual}"
            );
        }
    }

    /// The eta minimising objective 0's dual (eq. 24) over a fixed selection, by
    /// bisection on the sign of d g / d eta = eps - KL.
    fn dual_optimum(a: &Tensor, eligible: &Tensor, eps: f64) -> f64 {
        let (mut lo, mut hi) = (1e-3f64, 1e6f64);
        for _ in 0..80 {
            let mid = (lo * hi).sqrt();
            let eta = Tensor::from_slice(&[mid as f32]).set_requires_grad(true);
            let out = advantage_estep(&StepOneInputs {
                advantages: a,
                eligible,
                temperature: &eta,
                epsilon: &Tensor::from_slice(&[eps as f32]),
                fraction: 0.5,
                rule: TopK::Joint,
            });
            out.temperature_loss.backward();
            if eta.grad().double_value(&[0]) > 0.0 {
                hi = mid
            } else {
                lo = mid
            }
        }
        (lo * hi).sqrt()
    }

    #[test]
    fn a_vanishing_epsilon_removes_its_objective_continuously() {
        // (1) eq. 24's optimum eta grows without bound as eps -> 0 (about as eps^-1/2:
        // KL ≈ Var(A) / (2 eta^2) once the weights are near uniform).
        let n = 64;
        let eligible = Tensor::ones([n], (Kind::Float, Device::Cpu));
        let a = advantages(2, n, &[1.5, 1.0], true);
        let etas: Vec<f64> = [0.3, 0.1, 0.01, 1e-3, 1e-4]
            .iter()
            .map(|&e| dual_optimum(&a.narrow(1, 0, 1), &eligible, e))
            .collect();
        assert!(etas.windows(2).all(|w| w[1] > w[0]), "eta*(eps) {etas:?}");
        assert!(
            etas[4] > 20.0 * etas[1],
            "eta*(1e-4) vs eta*(0.1): {etas:?}"
        );
        // (2) As eta_0 grows, the fit weights tend, in L1, to those of eps_0 = 0, which
        // do not depend on A_0 at all (joint and shared); per_objective's stay apart.
        for rule in [TopK::Joint, TopK::Shared, TopK::PerObjective] {
            let off = values(&step(&a, &eligible, &[1.0, 0.5], &[0.0, 0.1], rule).fit_weights);
            let shuffled = a.copy();
            shuffled.select(1, 0).copy_(&a.select(1, 0).flip([0]));
            let other =
                values(&step(&shuffled, &eligible, &[1.0, 0.5], &[0.0, 0.1], rule).fit_weights);
            assert_eq!(off, other, "{rule:?}: eps_0 = 0 still reads A_0");
            if rule == TopK::Joint {
                let without = step(&a.narrow(1, 1, 1), &eligible, &[0.5], &[0.1], rule);
                assert_eq!(
                    off,
                    values(&without.fit_weights),
                    "joint: eps_0 = 0 is no objective 0"
                );
            }
            let distance: Vec<f64> = [1.0, 10.0, 100.0, 1e3, 1e4, 1e5]
                .iter()
                .map(|&eta| {
                    let on = step(&a, &eligible, &[eta, 0.5], &[0.01, 0.1], rule).fit_weights;
                    values(&on)
                        .iter()
                        .zip(&off)
                        .map(|(x, y)| (x - y).abs())
                        .sum()
                })
                .collect();
            eprintln!("{rule:?}: L1 distance to eps_0 = 0 at eta_0 = 1 .. 1e5: {distance:?}");
            if rule == TopK::PerObjective {
                assert!(distance.iter().all(|&d| d > 0.5), "{rule:?}: {distance:?}");
            } else {
                assert!(
                    distance.windows(2).all(|w| w[1] <= w[0] + 1e-6),
                    "{rule:?}: {distance:?}"
                );
                assert!(
                    distance[5] < 1e-4 && distance[0] > 0.1,
                    "{rule:?}: {distance:?}"
                );
            }
        }
    }

    /// The fit's mean A_0, `sum_i w_i A_0i / sum_i w_i`, over a grid of lambda_0 =
    /// 1 / eta_0 (0: eps_0 = 0), and how often the selection changed along it.
    fn influence(rule: TopK, a: &Tensor, others: &[f64]) -> (Vec<f64>, usize) {
        let eligible = Tensor::ones([a.size()[0]], (Kind::Float, Device::Cpu));
        let (mut out, mut changes, mut last) = (Vec::new(), 0, None::<Vec<f64>>);
        for i in 0..=200 {
            let lambda = 5.0 * f64::from(i) / 200.0;
            let mut eta = vec![if i == 0 { 1.0 } else { 1.0 / lambda }];
            eta.extend_from_slice(others);
            let mut eps = vec![if i == 0 { 0.0 } else { 0.1 }];
            eps.extend(others.iter().map(|_| 0.1));
            let s = step(a, &eligible, &eta, &eps, rule);
            let w = values(&s.fit_weights);
            let mean: f64 = w
                .iter()
                .zip(values(&a.select(1, 0)))
                .map(|(w, a)| w * a)
                .sum();
            out.push(mean / w.iter().sum::<f64>());
            let selected = values(&s.selected.select(-1, 1));
            changes += usize::from(last.is_some_and(|l| l != selected));
            last = Some(selected);
        }
        (out, changes)
    }

    #[test]
    fn a_larger_epsilon_never_lowers_its_objectives_mean_advantage_under_the_fit() {
        // eta_0* falls as eps_0 grows (the test above), so lambda_0 = 1 / eta_0 rises.
        // joint: at a fixed selection d/d lambda_0 of the mean is Var_w(A_0) >= 0, and
        // where the selection changes, the pair that enters has the same weight as the
        // one that leaves and a larger A_0. shared renormalises each q_k over the new
        // selection, so there its mean can fall.
        let mut shared_falls = 0.0f64;
        for seed in 0..6u64 {
            let scales: &[f64] = if seed % 2 == 0 {
                &[1.0, 2.0]
            } else {
                &[1.0, 0.5, 1.5]
            };
            let a = advantages(10 + seed, 64, scales, seed % 3 == 0);
            let others: Vec<f64> = (1..scales.len()).map(|k| 0.4 * k as f64).collect();
            let (joint, changes) = influence(TopK::Joint, &a, &others);
            assert!(
                changes > 5,
                "seed {seed}: the grid crosses few selection changes"
            );
            for (i, w) in joint.windows(2).enumerate() {
                assert!(
                    w[1] >= w[0] - 1e-5,
                    "seed {seed}, step {i}: {} -> {}",
                    w[0],
                    w[1]
                );
            }
            let (shared, _) = influence(TopK::Shared, &a, &others);
            let fall = shared.windows(2).map(|w| w[0] - w[1]).fold(0.0, f64::max);
            shared_falls = shared_falls.max(fall);
        }
        eprintln!("shared: largest fall of the mean A_0 along lambda_0: {shared_falls:.4}");
        assert!(shared_falls > 1e-3, "shared never fell: {shared_falls}");
    }
}
