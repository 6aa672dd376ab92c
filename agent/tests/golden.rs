//! Golden-value tests: the Rust E-step, M-step (summed and per-dimension KL
//! constraints), Retrace, Gaussian log-likelihood and MO-V-MPO's top-k weights,
//! temperature loss, T-step targets and policy fit against values computed
//! independently in PyTorch by `golden/make_golden.py` (the MO-V-MPO parts through
//! `golden/make_golden_vmpo_parts.py`); and three whole MO-MPO learner
//! steps (`Learner::step` with given parameters and sampling noise) against
//! `golden/make_golden_step.py` (float64; the JSON files are committed, so no Python
//! is needed here), and three ε-conditioned ones against
//! `golden/make_golden_conditioned_step.py`.

#[path = "golden/compare.rs"]
mod compare;

use agent::core::algo::dual::positive;
use agent::core::algo::estep::{exact_estep, sampled_estep};
use agent::core::algo::movmpo::{UnrollTargetInputs, unroll_targets};
use agent::core::algo::mstep::{KlConstraint, TrustRegion, categorical_mstep, gaussian_mstep};
use agent::core::algo::retrace::{RetraceInputs, importance_weights, retrace_targets};
use agent::core::algo::vmpo_estep::{StepOneInputs, TopK, advantage_estep};
use agent::core::algo::{Learner, LearnerDims, NoiseSource, SnippetBatch};
use agent::core::learner_config::LearnerConfig;
use agent::core::nets::GaussianParams;
use compare::{
    assert_close, assert_close_scalar, assert_close_vec, golden, named_arrays, scalar, tensor,
    vector,
};
use serde_json::Value;
use tch::{Device, Tensor};

#[test]
fn sampled_estep_weights_loss_and_dual_gradient() {
    let g = golden("estep_sampled");
    let param = vector(&g["temperature_param"]).set_requires_grad(true);
    let eta = positive(&param);
    assert_close(&eta, &vector(&g["temperature"]), "eta from its parameter");
    let out = sampled_estep(&tensor(&g["q"]), &eta, &vector(&g["epsilon"]));
    assert_close(&out.weights, &tensor(&g["weights"]), "weights");
    assert_close_scalar(
        out.temperature_loss.double_value(&[]),
        scalar(&g["loss"]),
        "temperature loss",
    );
    out.temperature_loss.backward();
    assert_close(&param.grad(), &vector(&g["grad_param"]), "d loss / d param");
}

#[test]
fn categorical_estep_weights_loss_and_dual_gradient() {
    let g = golden("estep_categorical");
    let param = vector(&g["temperature_param"]).set_requires_grad(true);
    let log_prior = tensor(&g["prior"]).log().transpose(0, 1);
    let out = exact_estep(
        &tensor(&g["q"]),
        &log_prior,
        &positive(&param),
        &vector(&g["epsilon"]),
    );
    assert_close(&out.weights, &tensor(&g["weights"]), "weights");
    assert_close_scalar(
        out.temperature_loss.double_value(&[]),
        scalar(&g["loss"]),
        "temperature loss",
    );
    out.temperature_loss.backward();
    assert_close(&param.grad(), &vector(&g["grad_param"]), "d loss / d param");
}

#[test]
fn gaussian_log_likelihood() {
    let g = golden("mstep_gaussian");
    let dist = GaussianParams {
        mean: tensor(&g["online_mean"]),
        std: tensor(&g["online_std"]),
    };
    assert_close(
        &dist.log_prob(&tensor(&g["actions"])),
        &tensor(&g["log_prob_online"]),
        "log N(a; mu, sigma)",
    );
}

/// A number as a 0-d tensor, or a list as a 1-d tensor.
fn number_or_vector(v: &Value) -> Tensor {
    match v.as_array() {
        Some(_) => vector(v),
        None => Tensor::from(scalar(v) as f32),
    }
}

/// The decoupled Gaussian M-step on golden file `g`'s policies and multipliers, for
/// `actions [M, B, D]` and `weights [M, B]`: KLs, both losses, and their gradients.
/// The multipliers (and so the KLs) are numbers for the summed constraint and
/// `[D]` lists for the per-dimension one.
#[track_caller]
fn check_gaussian_mstep(g: &Value, actions: &Tensor, weights: &Tensor, constraint: KlConstraint) {
    let online = GaussianParams {
        mean: tensor(&g["online_mean"]).set_requires_grad(true),
        std: tensor(&g["online_std"]).set_requires_grad(true),
    };
    let target = GaussianParams {
        mean: tensor(&g["target_mean"]),
        std: tensor(&g["target_std"]),
    };
    let alpha_mean = number_or_vector(&g["alpha_mean"]).set_requires_grad(true);
    let alpha_cov = number_or_vector(&g["alpha_cov"]).set_requires_grad(true);
    let region = TrustRegion {
        alpha_mean: &alpha_mean,
        alpha_cov: &alpha_cov,
        beta_mean: scalar(&g["beta_mean"]),
        beta_cov: scalar(&g["beta_cov"]),
        constraint,
        per_point: None,
    };
    let out = gaussian_mstep(&online, &target, actions, weights, &region);
    assert_close(&out.kl_mean, &number_or_vector(&g["kl_mean"]), "KL_mu");
    assert_close(&out.kl_cov, &number_or_vector(&g["kl_cov"]), "KL_Sigma");
    assert_close_scalar(
        out.policy_loss.double_value(&[]),
        scalar(&g["policy_loss"]),
        "policy loss",
    );
    assert_close_scalar(
        out.alpha_loss.double_value(&[]),
        scalar(&g["alpha_loss"]),
        "alpha loss",
    );
    (out.policy_loss + out.alpha_loss).backward();
    assert_close(
        &alpha_mean.grad(),
        &number_or_vector(&g["grad_alpha_mean"]),
        "d/d alpha_mu = beta_mu - KL_mu",
    );
    assert_close(
        &alpha_cov.grad(),
        &number_or_vector(&g["grad_alpha_cov"]),
        "d/d alpha_Sigma",
    );
    // Stop-gradients: alpha enters the policy loss only as a constant, the KL enters
    // the alpha loss only as a constant, so the policy gradients match PyTorch's.
    assert_close(
        &online.mean.grad(),
        &tensor(&g["grad_online_mean"]),
        "d/d mu",
    );
    assert_close(
        &online.std.grad(),
        &tensor(&g["grad_online_std"]),
        "d/d sigma",
    );
}

#[test]
fn decoupled_kl_terms_and_multiplier_losses() {
    let g = golden("mstep_gaussian");
    let (actions, weights) = (tensor(&g["actions"]), tensor(&g["weights"]));
    check_gaussian_mstep(&g, &actions, &weights, KlConstraint::Summed);
}

#[test]
fn per_dimension_kl_terms_and_multiplier_losses() {
    let g = golden("mstep_gaussian_per_dimension");
    let (actions, weights) = (tensor(&g["actions"]), tensor(&g["weights"]));
    check_gaussian_mstep(&g, &actions, &weights, KlConstraint::PerDimension);
}

#[test]
fn categorical_mstep_losses() {
    let g = golden("mstep_categorical");
    let logits = tensor(&g["online_logits"]).set_requires_grad(true);
    let alpha = Tensor::from(scalar(&g["alpha"]) as f32).set_requires_grad(true);
    let out = categorical_mstep(
        &logits,
        &tensor(&g["target_logits"]),
        &tensor(&g["weights"]),
        &alpha,
        scalar(&g["beta"]),
    );
    assert_close_scalar(out.kl.double_value(&[]), scalar(&g["kl"]), "KL");
    assert_close_scalar(
        out.policy_loss.double_value(&[]),
        scalar(&g["policy_loss"]),
        "policy loss",
    );
    assert_close_scalar(
        out.alpha_loss.double_value(&[]),
        scalar(&g["alpha_loss"]),
        "alpha loss",
    );
    (out.policy_loss + out.alpha_loss).backward();
    assert_close_scalar(
        alpha.grad().double_value(&[]),
        scalar(&g["grad_alpha"]),
        "d/d alpha",
    );
    assert_close(
        &logits.grad(),
        &tensor(&g["grad_online_logits"]),
        "d/d logits",
    );
}

#[test]
fn retrace_targets_with_terminal_and_truncated_traces() {
    let g = golden("retrace");
    let c = importance_weights(
        &tensor(&g["target_log_probs"]),
        &tensor(&g["behaviour_log_probs"]),
    );
    assert_close(&c, &tensor(&g["importance"]), "c = min(1, pi/b)");
    assert!(
        c.min().double_value(&[]) < 0.5,
        "the snippet exercises c < 1"
    );
    let targets = retrace_targets(&RetraceInputs {
        q_taken: &tensor(&g["q_taken"]),
        v_next: &tensor(&g["v_next"]),
        rewards: &tensor(&g["rewards"]),
        discounts: &tensor(&g["discounts"]),
        importance: &c,
        gamma: scalar(&g["gamma"]),
    });
    assert_close(&targets, &tensor(&g["targets"]), "Q_ret");
}

#[test]
fn vmpo_top_k_weights_temperature_loss_and_kl_under_every_rule() {
    let g = golden("vmpo_estep");
    for (name, rule) in [
        ("joint", TopK::Joint),
        ("shared", TopK::Shared),
        ("per_objective", TopK::PerObjective),
        ("duals_only", TopK::DualsOnly),
    ] {
        let want = &g["rules"][name];
        let param = vector(&g["temperature_param"]).set_requires_grad(true);
        let out = advantage_estep(&StepOneInputs {
            advantages: &tensor(&g["advantages"]),
            eligible: &vector(&g["eligible"]),
            temperature: &positive(&param),
            epsilon: &vector(&g["epsilon"]),
            fraction: scalar(&g["fraction"]),
            rule,
        });
        assert_close(
            &out.selected,
            &tensor(&want["selected"]),
            &format!("{name}: top-k selection (ties in, ineligible out)"),
        );
        assert_close(
            &out.fit_weights,
            &vector(&want["fit_weights"]),
            &format!("{name}: fit weights"),
        );
        assert_close(
            &out.kl,
            &vector(&want["kl"]),
            &format!("{name}: KL(q_k || p_old)"),
        );
        assert_close_scalar(
            out.temperature_loss.double_value(&[]),
            scalar(&want["temperature_loss"]),
            &format!("{name}: eq. 24 loss"),
        );
        out.temperature_loss.backward();
        assert_close(
            &param.grad(),
            &vector(&want["grad_temperature_param"]),
            &format!("{name}: d loss / d eta param"),
        );
    }
}

#[test]
fn vmpo_unroll_targets_bootstrap_and_cut_like_the_reference() {
    let g = golden("vmpo_targets");
    let targets = unroll_targets(&UnrollTargetInputs {
        rewards: &tensor(&g["rewards"]),
        discounts: &tensor(&g["discounts"]),
        valid: &tensor(&g["valid"]),
        values: &tensor(&g["values"]),
        gamma: scalar(&g["gamma"]),
    });
    // Padding steps have no target of their own; compare real steps only.
    let mask = tensor(&g["valid_mask"]).unsqueeze(-1);
    assert_close(
        &(targets * &mask),
        &(tensor(&g["targets"]) * &mask),
        "T-step targets",
    );
}

#[test]
fn vmpo_policy_fit_and_multiplier_losses() {
    let g = golden("vmpo_mstep");
    // Eq. 25 through the shared M-step: one action per state ([1, N, D]) and the batch
    // weights scaled by N, because the M-step averages over states (as movmpo.rs does).
    let w = vector(&g["weights"]);
    let n = w.size()[0] as f64;
    check_gaussian_mstep(
        &g,
        &tensor(&g["actions"]).unsqueeze(0),
        &(w * n).unsqueeze(0),
        KlConstraint::Summed,
    );
}

/// Whole learner steps (`Learner::step`: Retrace with the target networks, critic
/// loss and its Adam step, E-step and temperature duals, decoupled M-step, alpha
/// duals, the Adam steps of policy and duals, the target copy) against
/// `make_golden_step.py`, which computes them in float64 from the same config,
/// initial parameters, batches and sampling noise. Step 2 runs with online and
/// target networks apart, step 3 after the target copy of step 2.
fn check_full_steps(name: &str) {
    let g = golden(name);
    let cfg: LearnerConfig = serde_json::from_value(g["config"].clone()).unwrap();
    let dims: LearnerDims = serde_json::from_value(g["dims"].clone()).unwrap();
    let mut learner = Learner::new(cfg, dims, Device::Cpu).unwrap();
    learner
        .load_parameters(&named_arrays(&g["initial_parameters"]))
        .unwrap();
    let steps = g["steps"].as_array().unwrap();
    let noise = steps.iter().map(|s| tensor(&s["noise"])).collect();
    learner.set_noise_source(NoiseSource::Given(noise));
    for (i, s) in steps.iter().enumerate() {
        let b = &s["batch"];
        let batch = SnippetBatch {
            observations: tensor(&b["observations"]),
            actions: tensor(&b["actions"]),
            rewards: tensor(&b["rewards"]),
            discounts: tensor(&b["discounts"]),
            behaviour_log_probs: tensor(&b["behaviour_log_probs"]),
            valid: tensor(&b["valid"]),
        };
        let stats = learner.step(&batch).unwrap();
        let want = &s["stats"];
        let step = i + 1;
        assert_close_vec(
            &stats.critic_loss,
            &want["critic_loss"],
            &format!("step {step}: critic loss"),
        );
        assert_close_vec(
            &stats.temperature,
            &want["temperature"],
            &format!("step {step}: eta"),
        );
        assert_close_vec(
            &stats.estep_kl,
            &want["estep_kl"],
            &format!("step {step}: E-step KL"),
        );
        assert_close_vec(
            &stats.q_mean,
            &want["q_mean"],
            &format!("step {step}: mean Q"),
        );
        assert_close_vec(&stats.alpha, &want["alpha"], &format!("step {step}: alpha"));
        assert_close_vec(
            &stats.policy_kl,
            &want["policy_kl"],
            &format!("step {step}: policy KL"),
        );
        let parts = want["alpha_by_part"].as_array().unwrap();
        for (got, want) in learner.alpha_by_part().iter().zip(parts) {
            assert_close_vec(got, want, &format!("step {step}: alpha per dimension"));
        }
        let want_params = named_arrays(&s["parameters"]);
        let got_params = learner.parameters();
        assert_eq!(got_params.len(), want_params.len());
        for p in &got_params {
            let w = want_params.iter().find(|w| w.name == p.name).unwrap();
            assert_close(
                &Tensor::from_slice(&p.data),
                &Tensor::from_slice(&w.data),
                &format!("step {step}: {}", p.name),
            );
        }
    }
}

#[test]
fn full_mpo_steps_with_the_summed_kl_constraint() {
    check_full_steps("mpo_step_summed");
}

#[test]
fn full_mpo_steps_with_the_per_dimension_kl_constraint() {
    check_full_steps("mpo_step_per_dimension");
}

/// ε-conditioned MO-MPO (`golden/make_golden_conditioned_step.py`): the observations
/// end with each snippet's grid-point feature, and each grid point's temperatures
/// answer only to its own states.
#[test]
fn full_conditioned_mpo_steps_solve_the_e_step_per_grid_point() {
    check_full_steps("mpo_step_conditioned");
}
