//! One full MO-MPO learner step at the size of the pendulum preset as it shipped
//! before the learning-speed work (`configs/mompo/pendulum.toml`): obs 3, act 1,
//! B = 128 snippets of T = 8, M = 20, policy (64, 64), critic (128, 128), `task`
//! learned and `action_norm` in closed form. The size is fixed here, not read from
//! the preset, so that a smaller preset cannot stand in for a faster step.
//!
//! Run: `cargo bench -p agent --bench learner_step_pendulum [-- --threads 1 --batch 128]`
//! (prints its figure last).
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use agent::core::learner_config::{LearnerConfig, NetworkConfig};

fn main() {
    let mut cfg = LearnerConfig {
        objectives: common::task_and_action_norm(0.01),
        network: NetworkConfig {
            policy_layers: vec![64, 64],
            critic_layers: vec![128, 128],
            ..NetworkConfig::default()
        },
        ..LearnerConfig::default()
    };
    // `--batch 2` leaves the step's fixed cost (dispatch, autograd, Adam, syncs) alone.
    cfg.mpo.batch_size = common::arg("--batch", 128);
    common::run(common::StepSize {
        name: "learner_step_pendulum",
        obs_dim: 3,
        act_dim: 1,
        cfg,
    });
}
