//! Scale invariance (paper Sec. 4, issue 13): with MO-MPO the preference between
//! objectives is set by the epsilons, so multiplying one objective's reward by 100 must
//! not move the policy. A one-state bandit, `Q_right = -(a-1)^2`, `Q_left = -(a+1)^2`,
//! eps = [0.04, 0.01], dual learning rate 0.1.
//!
//! The temperatures must grow 100 times to absorb the scale. With eta = softplus(p)
//! one Adam step moves eta by about one dual learning rate, so that takes hundreds of
//! steps more (measured: mean action +0.75 vs -0.78 after 600 policy-improvement
//! steps); with eta = exp(p) (`temperature_parameterization = "log"`) a step is
//! relative and the catch-up takes about ln(100) / 0.1 ~ 46 steps.

mod common;
mod seed;

use agent::core::algo::{Learner, SnippetBatch};
use agent::core::learner_config::{Algorithm, TemperatureParameterization};
use tch::{Device, Kind, Tensor};

const STATES: i64 = 32;
/// Steps per run, and the last ones whose mean actions are averaged (the policy keeps
/// moving a little with each batch of samples).
const STEPS: usize = 2000;
const TAIL: usize = 200;

fn bandit(kind: TemperatureParameterization) -> Learner {
    tch::manual_seed(seed::test_seed() as i64);
    let mut cfg = common::bandit_config(
        Algorithm::MoMpo,
        [0.04, 0.01],
        vec![32, 32],
        1 + seed::test_seed(),
    );
    cfg.mpo.learning_rate = 3e-3;
    cfg.mpo.dual_learning_rate = 0.1;
    cfg.mpo.temperature_parameterization = kind;
    cfg.mpo.retrace_length = 1;
    cfg.mpo.batch_size = STATES as usize;
    cfg.mpo.target_update_period = 10;
    cfg.mpo.adam_eps = 1e-8;
    common::bandit_learner(cfg)
}

fn obs(n: i64) -> Tensor {
    Tensor::zeros([n, 1], (Kind::Float, Device::Cpu))
}

/// The bandit's reward (= Q, one step, no future) with the left objective scaled.
fn q_values(actions: &Tensor, left_scale: f64) -> Tensor {
    let a = actions.squeeze_dim(-1);
    Tensor::stack(
        &[-(&a - 1.0).square(), -(&a + 1.0).square() * left_scale],
        -1,
    )
}

fn mean_action(learner: &Learner) -> f64 {
    learner.act(&obs(1), true).actions.double_value(&[0, 0])
}

/// Policy improvement only, on the closed-form Q: the mean action over the last
/// `TAIL` of `steps` updates.
fn improved(kind: TemperatureParameterization, left_scale: f64, steps: usize) -> f64 {
    let mut learner = bandit(kind);
    let mut tail = 0.0;
    for i in 0..steps {
        learner.improve_policy_with(&obs(STATES), |a| q_values(a, left_scale));
        if i >= steps - TAIL {
            tail += mean_action(&learner) / TAIL as f64;
        }
    }
    tail
}

/// The full learner (critic regression, E-step, M-step, duals) on batches of one-step
/// pulls of the current policy: terminal, so the critic learns the reward itself.
fn learned(kind: TemperatureParameterization, left_scale: f64, steps: usize) -> f64 {
    let mut learner = bandit(kind);
    let mut tail = 0.0;
    for i in 0..steps {
        let act = learner.act(&obs(STATES), false);
        let rewards = q_values(&act.actions, left_scale).to_kind(Kind::Float);
        let batch = SnippetBatch {
            observations: Tensor::zeros([2, STATES, 1], (Kind::Float, Device::Cpu)),
            actions: act.actions.reshape([1, STATES, 1]),
            rewards: rewards.reshape([1, STATES, 2]),
            discounts: Tensor::zeros([1, STATES], (Kind::Float, Device::Cpu)),
            behaviour_log_probs: act.log_probs.reshape([1, STATES]),
            valid: Tensor::ones([1, STATES], (Kind::Float, Device::Cpu)),
        };
        learner.step(&batch).unwrap();
        if i >= steps - TAIL {
            tail += mean_action(&learner) / TAIL as f64;
        }
    }
    tail
}

#[test]
fn a_rescaled_objective_does_not_move_the_policy_with_log_temperatures() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    let log = TemperatureParameterization::Log;
    let (plain, scaled) = (improved(log, 1.0, STEPS), improved(log, 100.0, STEPS));
    seed::report_figures(
        "policy_improvement",
        &format!("x1 {plain:.3} x100 {scaled:.3}"),
    );
    // eps_right = 4 eps_left: the policy leans right, and equally so at either scale.
    // Measured x1 / x100 (seed 0): 0.842 / 0.850; seeds 1-5: 0.839 / 0.873, 0.837 /
    // 0.849, 0.826 / 0.879, 0.844 / 0.858, 0.939 / 0.930.
    assert!(plain > 0.3, "mean action {plain}");
    assert!(
        (plain - scaled).abs() < 0.1,
        "policy improvement: {plain} (left x1) vs {scaled} (left x100)"
    );
}

#[test]
fn a_rescaled_objective_does_not_move_the_full_learner_with_log_temperatures() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    let log = TemperatureParameterization::Log;
    let (plain, scaled) = (learned(log, 1.0, STEPS), learned(log, 100.0, STEPS));
    // Measured x1 / x100 (seed 0): 0.864 / 0.847; seeds 1-5: 0.896 / 0.897, 0.885 /
    // 0.891, 0.890 / 0.894, 0.829 / 0.821, 0.914 / 0.916.
    seed::report_figures("full_learner", &format!("x1 {plain:.3} x100 {scaled:.3}"));
    assert!(plain > 0.3, "mean action {plain}");
    assert!(
        (plain - scaled).abs() < 0.1,
        "full learner: {plain} (left x1) vs {scaled} (left x100)"
    );
}

/// The measurement behind the choice (ignored: it prints, it does not decide).
/// `cargo test -p agent --test scale_invariance -- --ignored --nocapture`
#[test]
#[ignore]
#[allow(clippy::print_stdout, reason = "a measurement to read, not a check")]
fn measure_both_parameterizations() {
    let _rng = common::exclusive_rng();
    tch::set_num_threads(1);
    for kind in [
        TemperatureParameterization::Softplus,
        TemperatureParameterization::Log,
    ] {
        for steps in [300, 600, STEPS] {
            let row: Vec<String> = [1.0, 100.0]
                .iter()
                .map(|&s| {
                    format!(
                        "x{s}: improve {:+.3} learned {:+.3}",
                        improved(kind, s, steps),
                        learned(kind, s, steps)
                    )
                })
                .collect();
            println!("{kind:?} {steps} steps: {}", row.join(" | "));
        }
    }
}
