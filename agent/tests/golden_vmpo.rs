//! Whole V-MPO learner steps against a float64 transcription of appendix D:
//! `Learner::step` with given parameters on given unrolls (T-step value targets and the
//! critic's Adam step, top-k advantage weights and temperature duals, the policy fit
//! under the KL trust region with its alpha duals, the Adam steps of policy and duals,
//! the pi_old copy) against `golden/make_golden_vmpo_step.py`. MO-V-MPO with a
//! Gaussian policy and two objectives; scalarized V-MPO with a categorical policy. The
//! JSON files are committed, so no Python is needed here.
//!
//! Shape legend: T unroll length, B unrolls, D action dims, K objectives.

#[path = "golden/compare.rs"]
mod compare;

use agent::core::algo::{Learner, LearnerDims, SnippetBatch};
use agent::core::learner_config::LearnerConfig;
use agent::core::nets::ActionKind;
use compare::{assert_close, assert_close_vec, golden, named_arrays, tensor};
use serde_json::Value;
use tch::{Device, Kind, Tensor};

/// The step's statistics, the per-part alphas and every parameter after step `step`.
#[track_caller]
fn check_step(
    learner: &Learner,
    stats: &agent::core::algo::LearnerStats,
    want_step: &Value,
    step: usize,
) {
    let want = &want_step["stats"];
    let fields: [(&[f32], &str); 6] = [
        (&stats.critic_loss, "critic_loss"),
        (&stats.temperature, "temperature"),
        (&stats.estep_kl, "estep_kl"),
        (&stats.q_mean, "q_mean"),
        (&stats.alpha, "alpha"),
        (&stats.policy_kl, "policy_kl"),
    ];
    for (got, name) in fields {
        assert_close_vec(got, &want[name], &format!("step {step}: {name}"));
    }
    let parts = want["alpha_by_part"].as_array().unwrap();
    assert_eq!(learner.alpha_by_part().len(), parts.len());
    for (got, want) in learner.alpha_by_part().iter().zip(parts) {
        assert_close_vec(got, want, &format!("step {step}: alpha part"));
    }
    let want_params = named_arrays(&want_step["parameters"]);
    let got_params = learner.parameters();
    assert_eq!(got_params.len(), want_params.len(), "parameter count");
    for p in &got_params {
        let w = want_params.iter().find(|w| w.name == p.name).unwrap();
        assert_close(
            &Tensor::from_slice(&p.data),
            &Tensor::from_slice(&w.data),
            &format!("step {step}: {}", p.name),
        );
    }
}

/// Runs the golden file's three steps: step 2 has pi_old != pi, step 3 starts from the
/// pi_old copied after step 2.
fn check_full_vmpo_steps(name: &str) {
    let g = golden(name);
    let cfg: LearnerConfig = serde_json::from_value(g["config"].clone()).unwrap();
    assert!(cfg.algorithm.on_policy(), "{name} is a V-MPO case");
    let dims: LearnerDims = serde_json::from_value(g["dims"].clone()).unwrap();
    let discrete = matches!(dims.action, ActionKind::Discrete { .. });
    let mut learner = Learner::new(cfg, dims, Device::Cpu).unwrap();
    learner
        .load_parameters(&named_arrays(&g["initial_parameters"]))
        .unwrap();
    for (i, s) in g["steps"].as_array().unwrap().iter().enumerate() {
        let b = &s["batch"];
        let actions = tensor(&b["actions"]);
        let batch = SnippetBatch {
            observations: tensor(&b["observations"]),
            actions: if discrete {
                actions.to_kind(Kind::Int64)
            } else {
                actions
            },
            rewards: tensor(&b["rewards"]),
            discounts: tensor(&b["discounts"]),
            behaviour_log_probs: tensor(&b["behaviour_log_probs"]),
            valid: tensor(&b["valid"]),
        };
        let stats = learner.step(&batch).unwrap();
        check_step(&learner, &stats, s, i + 1);
    }
}

#[test]
fn full_movmpo_steps_with_a_gaussian_policy() {
    check_full_vmpo_steps("vmpo_step_gaussian");
}

#[test]
fn full_scalarized_vmpo_steps_with_a_categorical_policy() {
    check_full_vmpo_steps("vmpo_step_categorical");
}
