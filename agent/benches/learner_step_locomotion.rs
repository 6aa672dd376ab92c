//! One MO-MPO learner step at the size a run config trains at: by default the
//! ε-conditioned locomotion preset (`configs/mompo/locomotion-conditioned.toml`) on
//! mo-halfcheetah-v5 (obs 17 plus the preset's preference features, act 6 on [-1, 1],
//! K = 2 learned critics, B snippets of T = `retrace_length`, M = `num_samples`).
//! Unlike `learner_step` and `learner_step_pendulum`, the size is read from the config
//! (with `--set` overrides, as `agent train` takes them): this benchmark answers what a
//! setting costs per learner step and per budget, the wall side of
//! docs/benchmarks/mujoco.md's two-objective comparison.
//!
//! Prints each phase's share, the median step and the learner's time over the config's
//! budget (`run.learner_steps_per_env_step` x `run.total_env_steps`; env stepping,
//! evaluation and checkpoints come on top of it in a run's wall time).
//!
//! Run: `cargo bench -p agent --bench learner_step_locomotion [-- --threads 1 --steps 20
//! --config FILE --set PATH=VALUE ... --obs 17 --act 6]` (mo-hopper-2obj: `--obs 11 --act 3`).
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use agent::core::algo::{Learner, LearnerDims};
use agent::core::nets::{ActionBounds, ActionKind};
use agent::runtime::run_config::TrainConfig;
use std::path::PathBuf;

fn main() {
    let (threads, device) = common::set_up();
    let default_config = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../configs/mompo/locomotion-conditioned.toml");
    let path: PathBuf = common::arg("--config", default_config);
    let args: Vec<String> = std::env::args().collect();
    let sets: Vec<String> = args
        .windows(2)
        .filter(|w| w[0] == "--set")
        .map(|w| w[1].clone())
        .collect();
    let TrainConfig {
        learner: learner_cfg,
        run,
        ..
    } = TrainConfig::load_with(&path, &sets)
        .unwrap_or_else(|e| panic!("--config {}: {e}", path.display()));
    let (obs_dim, act_dim): (i64, i64) = (common::arg("--obs", 17), common::arg("--act", 6));
    let k = learner_cfg.objectives.len() as i64;
    let dims = LearnerDims {
        action_bounds: Some(ActionBounds {
            low: vec![-1.0; act_dim as usize],
            high: vec![1.0; act_dim as usize],
        }),
        obs_dim,
        action: ActionKind::Continuous { dim: act_dim },
        reward_names: learner_cfg
            .objectives
            .iter()
            .map(|o| o.name.clone())
            .collect(),
        obs_leaves: Vec::new(),
    }
    .with_preference_features(learner_cfg.preference_features());
    let (t, b) = (
        learner_cfg.mpo.retrace_length as i64,
        learner_cfg.mpo.batch_size as i64,
    );
    let batch = common::random_batch(t, b, dims.obs_dim, act_dim, k, device);
    println!(
        "learner_step_locomotion: {} {sets:?}: obs {obs_dim} + {} preference features, act {act_dim}, B {b}, T {t}, M {}, policy {:?} ({:?} preference), critic {:?} ({} shared), K {k}, device {device:?}, threads {threads}",
        path.display(),
        learner_cfg.preference_features(),
        learner_cfg.mpo.num_samples,
        learner_cfg.network.policy_layers,
        learner_cfg.network.policy_preference,
        learner_cfg.network.critic_layers,
        learner_cfg.network.critic_shared_layers,
    );
    let mut learner = Learner::new(learner_cfg, dims, device).expect("valid config");
    let steps: usize = common::arg("--steps", 20);
    let totals = common::time_steps(&mut learner, &batch, 3, steps, common::MPO_PHASES);
    let ms = common::median(totals);
    let learner_steps = run.learner_steps_per_env_step * run.total_env_steps as f64;
    println!(
        "learner time for {} env steps at {} learner steps each: {:.0} s",
        run.total_env_steps,
        run.learner_steps_per_env_step,
        ms * learner_steps / 1e3
    );
    println!("learner_step_ms_median={ms:.2}");
}
