//! Behavioural tests of MO-V-MPO (appendix D) through full learner steps on on-policy
//! batches from a one-state bandit with a 1-D continuous action and two objectives in
//! conflict, r_1(a) = -(a-1)^2 and r_2(a) = -(a+1)^2 (one-step episodes, so the value
//! targets are the rewards and the advantages are r_k - V_k).
//!
//! The actions are drawn from libtorch's process-global RNG (`common::exclusive_rng`).
//! (Measured when written: a 10:1 epsilon ratio moves the mean action by about 0.15
//! from the equal-epsilon compromise, and epsilon = 0 switches an objective off.)

mod common;

use agent::algo::{Learner, SnippetBatch};
use agent::config::Algorithm;
use tch::{Device, Kind, Tensor};

const UNROLLS: i64 = 64;

fn bandit(eps: [f64; 2]) -> Learner {
    let mut cfg = common::bandit_config(Algorithm::MoVmpo, eps, vec![16], 3);
    cfg.vmpo.unroll_length = 1;
    cfg.vmpo.batch_size = UNROLLS as usize;
    cfg.vmpo.learning_rate = 3e-3;
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
    tch::set_num_threads(1);
    tch::manual_seed(0);
    let right = trained_mean([0.1, 0.01], 400);
    let left = trained_mean([0.01, 0.1], 400);
    let equal = trained_mean([0.05, 0.05], 400);
    // The lean is milder than MO-MPO's: the top-k selection alone still pulls toward
    // an objective with a small (but non-zero) epsilon, whose weights are then near
    // uniform over its selected half (measured: left -0.18, equal -0.01, right 0.14).
    assert!(
        equal.abs() < 0.1,
        "equal epsilons give a compromise near 0, got {equal}"
    );
    assert!(
        right > equal + 0.07,
        "eps_right = 10 eps_left should lean right (to +1): {right} vs equal {equal}"
    );
    assert!(
        left < equal - 0.07,
        "eps_left = 10 eps_right should lean left (to -1): {left} vs equal {equal}"
    );
}

#[test]
fn a_zero_epsilon_objective_has_no_influence() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    tch::manual_seed(1);
    let only_right = trained_mean([0.1, 0.0], 400);
    assert!(
        (only_right - 1.0).abs() < 0.25,
        "eps_left = 0: expected the optimum +1 of the right objective, got {only_right}"
    );
}

/// `bandit` with `vmpo.epochs` and `vmpo.minibatches` set and pi_old never renewed
/// within the test, so that learner steps differ only in their updates.
fn bandit_passes(epochs: usize, minibatches: usize) -> Learner {
    let mut cfg = common::bandit_config(Algorithm::MoVmpo, [0.1, 0.05], vec![16], 3);
    cfg.vmpo.unroll_length = 1;
    cfg.vmpo.batch_size = UNROLLS as usize;
    cfg.vmpo.learning_rate = 3e-3;
    cfg.vmpo.target_update_period = 1000;
    cfg.vmpo.epochs = epochs;
    cfg.vmpo.minibatches = minibatches;
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
