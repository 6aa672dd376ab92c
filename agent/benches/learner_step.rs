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
//! `agent/benches/learner_step_torch.py` is the same step in plain PyTorch.
//!
//! Then, unless `--no-torch`, it runs that script in the same invocation (same
//! threads) and prints the ratio of the two medians.
//!
//! Run: `cargo bench -p agent --bench learner_step [-- --threads N --steps N --no-torch]`
//! (prints its figures last).
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use agent::config::{LearnerConfig, NetworkConfig};

fn main() {
    let mut cfg = LearnerConfig {
        objectives: common::task_and_action_norm(0.05),
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
    let rust_ms = common::run(common::StepSize {
        name: "learner_step",
        obs_dim: 67,
        act_dim: 21,
        cfg,
    });
    if std::env::args().any(|a| a == "--no-torch") {
        return;
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let threads = tch::get_num_threads().to_string();
    let out = std::process::Command::new(root.join(".venv/bin/python"))
        .args([
            root.join("agent/benches/learner_step_torch.py")
                .to_str()
                .expect("utf-8 path"),
            "--threads",
            &threads,
        ])
        .output()
        .expect(
            "run .venv/bin/python agent/benches/learner_step_torch.py (made by scripts/setup.sh)",
        );
    let text = String::from_utf8_lossy(&out.stdout);
    print!("{text}");
    let torch_ms: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("learner_step_ms_median="))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| {
            panic!(
                "no figure from the PyTorch script: {}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
    println!(
        "ratio_rust_over_torch={:.3}  (Rust {rust_ms:.1} ms, PyTorch {torch_ms:.1} ms, {threads} threads)",
        rust_ms / torch_ms
    );
}
