//! Behavioural tests of MO-V-MPO (appendix D) through full learner steps on on-policy
//! batches from a one-state bandit with a 1-D continuous action and two objectives in
//! conflict, r_1(a) = -(a-1)^2 and r_2(a) = -(a+1)^2 (one-step episodes, so the value
//! targets are the rewards and the advantages are r_k - V_k).
//!
//! The actions come from the learner's own stream (`Learner::act`, keyed by the
//! config's seed), so a run repeats exactly; `common::exclusive_rng` only keeps tests
//! from sharing libtorch's threads. The config seed is 3 plus `MO_MPO_TEST_SEED`, so
//! `scripts/learning_seeds.sh`'s seeds 1-5 are the config seeds 4-8 recorded below.

mod common;
mod seed;

use agent::core::algo::{Learner, SnippetBatch};
use agent::core::learner_config::{Algorithm, LearnerConfig};
use tch::{Device, Kind, Tensor};

const UNROLLS: i64 = 64;

/// The bandit's MO-V-MPO config: one-step unrolls, `UNROLLS` of them per batch.
fn bandit_config(eps: [f64; 2], learning_rate: f64) -> LearnerConfig {
    let mut cfg = common::bandit_config(Algorithm::MoVmpo, eps, vec![16], 3 + seed::test_seed());
    cfg.vmpo.unroll_length = 1;
    cfg.vmpo.batch_size = UNROLLS as usize;
    cfg.vmpo.learning_rate = learning_rate;
    cfg
}

fn bandit(eps: [f64; 2]) -> Learner {
    let mut cfg = bandit_config(eps, 3e-3);
    cfg.vmpo.dual_learning_rate = 0.1;
    cfg.vmpo.beta_mean = 0.01;
    cfg.vmpo.target_update_period = 10;
    common::bandit_learner(cfg)
}

/// One on-policy batch: actions from the current policy, their rewards, terminal.
fn batch(learner: &Learner) -> SnippetBatch {
    let opts = (Kind::Float, Device::Cpu);
    let act = learner.act(&Tensor::zeros([UNROLLS, 1], opts), false);
    let a = act.actions.squeeze_dim(-1);
    let rewards = Tensor::stack(&[-(&a - 1.0).square(), -(&a + 1.0).square()], -1);
    SnippetBatch {
        observations: Tensor::zeros([2, UNROLLS, 1], opts),
        actions: act.actions.unsqueeze(0),
        rewards: rewards.unsqueeze(0),
        discounts: Tensor::zeros([1, UNROLLS], opts),
        behaviour_log_probs: act.log_probs.unsqueeze(0),
        valid: Tensor::ones([1, UNROLLS], opts),
    }
}

/// The deterministic action after `steps` learner steps (mean of the last 50).
fn trained_mean(eps: [f64; 2], steps: usize) -> f64 {
    let mut learner = bandit(eps);
    let obs = Tensor::zeros([1, 1], (Kind::Float, Device::Cpu));
    let mut sum = 0.0;
    for i in 0..steps {
        let b = batch(&learner);
        learner.step(&b).unwrap();
        if i >= steps - 50 {
            sum += learner.act(&obs, true).actions.double_value(&[0, 0]);
        }
    }
    sum / 50.0
}

#[test]
fn the_larger_epsilon_pulls_the_policy_to_its_objective() {
    let _rng = common::exclusive_rng();
    let right = trained_mean([0.1, 0.01], 400);
    let left = trained_mean([0.01, 0.1], 400);
    let equal = trained_mean([0.05, 0.05], 400);
    seed::report_figures(
        "the_larger_epsilon_pulls",
        &format!("right {right:.3} left {left:.3} equal {equal:.3}"),
    );
    // With `vmpo.top_k = "joint"` (issue 38) an objective's pull grows with its
    // epsilon: a 10:1 ratio takes the policy to the preferred optimum. Equal epsilons
    // give no fixed compromise: both objectives are linear in the action near the
    // policy, so their advantages scaled by their temperatures cancel at any mean,
    // and the mean settles where the exploration noise collapsed. Measured (config
    // seed 3, and seeds 4-8 to check the thresholds): right 0.994 (0.990, 0.982,
    // 0.991, 0.987, 0.990), left -0.990 (-0.992, -0.980, -0.987, -0.983, -0.993),
    // equal -0.55 (-0.38, -0.13, 0.03, -0.09, -0.09). Under the rule before issue 38
    // (`per_objective`) the lean was 0.16 / -0.13 around 0.02.
    assert!(
        right > 0.9,
        "eps_right = 10 eps_left: expected about +1, got {right}"
    );
    assert!(
        left < -0.9,
        "eps_left = 10 eps_right: expected about -1, got {left}"
    );
    assert!(
        left < equal && equal < right,
        "equal epsilons {equal} should lie between {left} and {right}"
    );
}

#[test]
fn a_zero_epsilon_objective_has_no_influence() {
    let _rng = common::exclusive_rng();
    let only_right = trained_mean([0.1, 0.0], 400);
    // Measured (config seed 3): 1.001; seeds 4-8: 0.999, 0.999, 1.001, 1.000, 1.000.
    seed::report_figures(
        "a_zero_epsilon_objective",
        &format!("right {only_right:.3}"),
    );
    assert!(
        (only_right - 1.0).abs() < 0.25,
        "eps_left = 0: expected the optimum +1 of the right objective, got {only_right}"
    );
}

/// `bandit` with `vmpo.epochs` and `vmpo.minibatches` set and pi_old never renewed
/// within the test, so that learner steps differ only in their updates. The step's
/// projection is off: it would cut a step of two passes and not two steps of one
/// (it has its own test below).
fn bandit_passes(epochs: usize, minibatches: usize) -> Learner {
    let mut cfg = bandit_config([0.1, 0.05], 3e-3);
    cfg.vmpo.target_update_period = 1000;
    cfg.vmpo.epochs = epochs;
    cfg.vmpo.minibatches = minibatches;
    cfg.vmpo.project_step_kl = false;
    common::bandit_learner(cfg)
}

fn max_parameter_difference(a: &Learner, b: &Learner) -> f64 {
    a.parameters()
        .iter()
        .zip(b.parameters())
        .map(|(x, y)| {
            assert_eq!(x.name, y.name);
            x.data
                .iter()
                .zip(&y.data)
                .map(|(u, v)| f64::from((u - v).abs()))
                .fold(0.0, f64::max)
        })
        .fold(0.0, f64::max)
}

#[test]
fn two_epochs_are_two_updates_on_the_same_batch() {
    let _rng = common::exclusive_rng();
    let mut once = bandit_passes(1, 1);
    let mut twice = bandit_passes(2, 1);
    let b = batch(&once);
    once.step(&b).unwrap();
    let after_one = once.parameters();
    once.step(&b).unwrap();
    let stats = twice.step(&b).unwrap();
    assert_eq!(twice.step_count(), 1, "one learner step, two updates");
    assert!(
        max_parameter_difference(&once, &twice) < 1e-6,
        "epochs = 2 should equal two steps on the batch with the same pi_old"
    );
    assert!(
        after_one
            .iter()
            .zip(twice.parameters())
            .any(|(x, y)| x.data != y.data),
        "the second pass changed nothing"
    );
    assert!(
        stats.policy_kl[0] > 0.0,
        "the second pass is measured from pi_old"
    );
}

#[test]
fn minibatches_split_the_batch_into_seeded_shuffled_updates() {
    let _rng = common::exclusive_rng();
    let mut whole = bandit_passes(1, 1);
    let mut split = bandit_passes(1, 4);
    let mut again = bandit_passes(1, 4);
    let b = batch(&whole);
    whole.step(&b).unwrap();
    split.step(&b).unwrap();
    again.step(&b).unwrap();
    assert!(
        max_parameter_difference(&whole, &split) > 1e-5,
        "four updates on quarters should differ from one on the whole batch"
    );
    assert_eq!(
        max_parameter_difference(&split, &again),
        0.0,
        "the shuffle is keyed by seed and step"
    );
}

/// The policy KL parts (KL_mu, KL_Sigma) at the end of each of `steps` learner steps of
/// 8 passes over 2 minibatches, pi_old renewed every step, with a learning rate at
/// which the passes outrun the multipliers.
fn step_end_kls(project: bool, steps: usize) -> Vec<Vec<f32>> {
    let mut cfg = bandit_config([0.1, 0.05], 3e-2);
    cfg.vmpo.target_update_period = 1;
    cfg.vmpo.epochs = 8;
    cfg.vmpo.minibatches = 2;
    cfg.vmpo.beta_mean = 0.01;
    cfg.vmpo.beta_cov = 1e-3;
    cfg.vmpo.project_step_kl = project;
    let mut learner = common::bandit_learner(cfg);
    (0..steps)
        .map(|_| {
            let b = batch(&learner);
            learner.step(&b).unwrap().policy_kl
        })
        .collect()
}

#[test]
fn a_projected_step_of_several_updates_ends_within_beta() {
    let _rng = common::exclusive_rng();
    let betas = [0.01f32, 1e-3];
    let free = step_end_kls(false, 20);
    let over = |kls: &[Vec<f32>]| {
        kls.iter()
            .map(|kl| {
                kl.iter()
                    .zip(&betas)
                    .map(|(k, b)| k / b)
                    .fold(0.0, f32::max)
            })
            .fold(0.0, f32::max)
    };
    // Without the projection the 16 updates of a step end far past beta. The largest
    // ratio KL / beta over the 20 steps, measured (config seed 3, and seeds 4-8 to
    // check the thresholds): 98 (75, 94, 114, 40, 243) without the projection, 0.94
    // (0.91, 0.96, 0.93, 1.00, 0.90) with it.
    assert!(over(&free) > 1.5, "the passes never outran beta: {free:?}");
    let bound = step_end_kls(true, 20);
    assert!(
        over(&bound) <= 1.0 + 1e-4,
        "a projected step ended past beta: {bound:?}"
    );
    // The projection does not just undo the steps: some still move the mean by more
    // than a tenth of beta_mu (measured: 12 of the 20 steps; 14, 1, 15, 5, 11).
    let moved = bound.iter().filter(|kl| kl[0] > 0.1 * betas[0]).count();
    seed::report_figures(
        "a_projected_step",
        &format!(
            "max KL/beta free {:.2} projected {:.2}, moved {moved}",
            over(&free),
            over(&bound)
        ),
    );
    assert!(moved >= 1, "every projected step was undone: {bound:?}");
}
