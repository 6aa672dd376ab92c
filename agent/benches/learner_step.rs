//! One full MO-MPO learner step at the humanoid-run size (Table 3):
//! obs 67, act 21, B = 512 snippets of T = 8, M = 20 samples, policy (400, 400, 300),
//! critic (500, 500, 400), K = 2 objectives: `task` (learned critic) and
//! `action_norm` (closed form, no critic).
//!
//! The step computes: target policy on N = (T+1)B = 4608 states, M = 20 samples each;
//! target critic forward on all N*M = 92,160 (state, action) pairs (V for Retrace and
//! Q for the E-step); target critic on the T*B = 4096 taken pairs; Retrace targets;
//! online critic forward+backward on the 4096 pairs and Adam; E-step weights and
//! temperature duals; decoupled M-step on the 4608 states x 20 samples, backward,
//! Adam on the policy and on the duals. Timed: median of 20 steps after 3 warm-up steps.
//!
//! Run: `cargo bench -p agent --bench learner_step` (prints its figure last).
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

use agent::algo::{LearnerDims, Learner, SnippetBatch};
use agent::config::{LearnerConfig, NetworkConfig, ObjectiveConfig, ObjectiveSource};
use agent::nets::ActionKind;
use tch::{Kind, Tensor};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn main() {
    let threads = agent::device::configure_threads(None);
    let device = agent::device::learner_device();
    let mut cfg = LearnerConfig {
        objectives: vec![
            ObjectiveConfig {
                name: "task".into(),
                epsilon: 0.1,
                source: ObjectiveSource::Learned,
            },
            ObjectiveConfig {
                name: "action_norm".into(),
                epsilon: 0.05,
                source: ObjectiveSource::ActionNorm,
            },
        ],
        network: NetworkConfig {
            policy_layers: vec![400, 400, 300],
            critic_layers: vec![500, 500, 400],
            tanh_on_action_mean: false,
            min_variance: 1e-8,
            tanh_on_critic_action: false,
            ..NetworkConfig::default()
        },
        ..LearnerConfig::default()
    };
    cfg.mpo.beta_mean = 5e-3;
    cfg.mpo.beta_cov = 1e-6;
    cfg.mpo.learning_rate = 2e-4;
    cfg.mpo.adam_eps = 1e-8;
    let (t, b, obs_dim, act_dim) = (
        cfg.mpo.retrace_length as i64,
        cfg.mpo.batch_size as i64,
        67,
        21,
    );
    let dims = LearnerDims {
        obs_dim,
        action: ActionKind::Continuous { dim: act_dim },
        reward_names: vec!["task".into(), "action_norm".into()],
        obs_leaves: Vec::new(),
    };
    let mut learner = Learner::new(cfg.clone(), dims, device).expect("valid config");
    tch::manual_seed(0);
    let opts = (Kind::Float, tch::Device::Cpu);
    let batch = SnippetBatch {
        observations: Tensor::randn([t + 1, b, obs_dim], opts),
        actions: Tensor::randn([t, b, act_dim], opts).clamp(-1.0, 1.0),
        rewards: Tensor::randn([t, b, 2], opts),
        discounts: Tensor::ones([t, b], opts),
        behaviour_log_probs: Tensor::randn([t, b], opts) - 20.0,
        valid: Tensor::ones([t, b], opts),
    }
    .to_device(device);
    println!(
        "learner_step: obs {obs_dim}, act {act_dim}, B {b}, T {t}, M {}, policy {:?}, critic {:?}, K 2 (task + closed-form action_norm), device {device:?}, threads {threads}",
        cfg.mpo.num_samples, cfg.network.policy_layers, cfg.network.critic_layers
    );
    for _ in 0..3 {
        learner.step(&batch).expect("step");
    }
    let mut totals = Vec::new();
    let mut phases = [0.0f64; 4];
    for _ in 0..20 {
        let start = std::time::Instant::now();
        let stats = learner.step(&batch).expect("step");
        totals.push(start.elapsed().as_secs_f64() * 1e3);
        let p = stats.timings;
        for (acc, v) in phases.iter_mut().zip([
            p.policy_evaluation_ms,
            p.e_step_ms,
            p.m_step_ms,
            p.target_update_ms,
        ]) {
            *acc += v;
        }
    }
    let sum: f64 = phases.iter().sum();
    let names = [
        "policy evaluation (sampling, target critic x M, Retrace, critic update)",
        "E-step",
        "M-step + duals",
        "target update",
    ];
    for (name, v) in names.iter().zip(phases) {
        println!("  {:>5.1}%  {name}", 100.0 * v / sum);
    }
    println!("learner_step_ms_median={:.1}", median(totals));
}
