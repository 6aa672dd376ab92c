//! What a whole-run checkpoint costs at a preset's size (`configs/mompo/<preset>.toml`):
//! the learner's files, the replay at the end of the preset's budget (the smaller of
//! `total_env_steps` and `replay_capacity` transitions), and the time to write
//!
//! - `first`: a checkpoint that writes that whole replay as one segment (what every
//!   checkpoint would cost if the replay were rewritten whole);
//! - `incremental`: the next checkpoint, `checkpoint_period` learner steps later,
//!   which appends only the snippets inserted since (`checkpoint_period /
//!   learner_steps_per_env_step` env steps of them);
//! - `no_replay`: a checkpoint with `run.checkpoint_replay = false`.
//!
//! Each time is the median of `--reps` (5) writes to a temporary directory (page
//! cache, no fsync of the segments). The snippets' values do not matter: safetensors stores raw f32.
//!
//! Run: `cargo bench -p agent --bench checkpoint_cost [-- --presets dst,pendulum,humanoid-run --reps 5]`
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use agent::core::algo::{Learner, LearnerDims};
use agent::core::nets::ActionKind;
use agent::core::replay::{Snippet, SnippetLayout, SnippetReplay};
use agent::report::metrics::RunFiles;
use agent::runtime::checkpoint::run::PaceOrigin;
use agent::runtime::resume::Checkpointer;
use agent::runtime::run_config::TrainConfig;
use agent::runtime::schedule::{ActorStep, Counters, Pace, Schedule};
use tch::Device;

/// Observation size, action kind and reward names of a preset's env (its EnvSpec).
fn env_dims(preset: &str) -> LearnerDims {
    let (obs_dim, action, rewards) = match preset {
        "dst" => (2, ActionKind::Discrete { n: 4 }, ["time", "treasure"]),
        "pendulum" => (
            3,
            ActionKind::Continuous { dim: 1 },
            ["task", "action_norm"],
        ),
        "humanoid-run" => (
            67,
            ActionKind::Continuous { dim: 21 },
            ["task", "action_norm"],
        ),
        other => panic!("no dimensions for preset {other:?}"),
    };
    LearnerDims {
        action_bounds: None,
        obs_dim,
        action,
        reward_names: rewards.map(String::from).to_vec(),
        obs_leaves: Vec::new(),
    }
}

fn snippet(l: &SnippetLayout, v: f32) -> Snippet {
    let t = l.length;
    Snippet {
        observations: vec![v; (t + 1) * l.obs_dim],
        actions: vec![0.0; t * l.action_width],
        rewards: vec![v; t * l.num_rewards],
        discounts: vec![1.0; t],
        behaviour_log_probs: vec![-1.0; t],
        valid: vec![1.0; t],
    }
}

fn bytes_under(path: &Path) -> u64 {
    std::fs::read_dir(path).map_or(0, |entries| {
        entries
            .flatten()
            .map(|e| {
                let p = e.path();
                if p.is_dir() {
                    bytes_under(&p)
                } else {
                    e.metadata().map_or(0, |m| m.len())
                }
            })
            .sum()
    })
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

fn measure(preset: &str) {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../configs/mompo/{preset}.toml"));
    let cfg = TrainConfig::load(&path).expect("the preset loads");
    let dims = env_dims(preset);
    let settings = cfg.learner.shared();
    let layout = SnippetLayout {
        length: settings.sequence_length,
        obs_dim: dims.obs_dim as usize,
        action_width: match dims.action {
            ActionKind::Continuous { dim } => dim as usize,
            ActionKind::Discrete { .. } => 1,
        },
        num_rewards: dims.reward_names.len(),
        discrete: matches!(dims.action, ActionKind::Discrete { .. }),
        on_policy: false,
    };
    let capacity = cfg.learner.mpo.replay_capacity;
    let held = (cfg.run.total_env_steps as usize).min(capacity) / layout.length;
    let per_checkpoint = ((cfg.run.checkpoint_period as f64 / cfg.run.learner_steps_per_env_step)
        as usize)
        .div_ceil(layout.length);
    let learner = Learner::new(cfg.learner.clone(), dims.clone(), Device::Cpu).expect("valid");
    let objectives = dims.reward_names.clone();
    let pace = Pace::Ratio {
        learner_steps_per_env_step: cfg.run.learner_steps_per_env_step,
        min_replay_transitions: 1,
    };

    let (mut first, mut incremental, mut no_replay) = (Vec::new(), Vec::new(), Vec::new());
    let (mut learner_bytes, mut whole_bytes, mut segment_bytes) = (0, 0, 0);
    for _ in 0..common::arg("--reps", 5) {
        let dir = tempfile::tempdir().unwrap();
        let mut replay = SnippetReplay::new(layout, capacity, 0);
        for j in 0..held {
            replay.insert(snippet(&layout, j as f32)).unwrap();
        }
        let schedule = Schedule::new(replay, pace, Counters::default(), PaceOrigin::default());
        let files = Arc::new(RunFiles::open(dir.path(), &objectives, &[]).unwrap());
        let mut checkpointer = Checkpointer::new(files.clone(), true, 0);
        let t0 = Instant::now();
        let ckpt = checkpointer.save(&learner, &schedule).unwrap();
        first.push(t0.elapsed().as_secs_f64() * 1e3);
        learner_bytes = bytes_under(&ckpt);
        whole_bytes = bytes_under(&dir.path().join("replay"));
        let step = ActorStep {
            actor: 0,
            acts: 1,
            env_steps: (per_checkpoint * layout.length) as u64,
            snippets: (0..per_checkpoint).map(|_| snippet(&layout, 0.5)).collect(),
            episode_returns: Vec::new(),
        };
        schedule.commit(step, |_| Ok(())).unwrap();
        let t0 = Instant::now();
        checkpointer.save(&learner, &schedule).unwrap();
        incremental.push(t0.elapsed().as_secs_f64() * 1e3);
        segment_bytes = bytes_under(&dir.path().join("replay")).saturating_sub(whole_bytes);

        let small = tempfile::tempdir().unwrap();
        let files = Arc::new(RunFiles::open(small.path(), &objectives, &[]).unwrap());
        let mut without = Checkpointer::new(files, false, 0);
        let t0 = Instant::now();
        without.save(&learner, &schedule).unwrap();
        no_replay.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    println!(
        "{preset}: learner {:.2} MiB, replay {held} snippets of T={} ({:.1} MiB), \
         {per_checkpoint} new snippets per checkpoint ({:.2} MiB)",
        mib(learner_bytes),
        layout.length,
        mib(whole_bytes),
        mib(segment_bytes),
    );
    println!(
        "{preset}: first_ms={:.1} incremental_ms={:.1} no_replay_ms={:.1}",
        common::median(first),
        common::median(incremental),
        common::median(no_replay)
    );
}

fn main() {
    let presets: String = common::arg("--presets", "dst,pendulum".to_string());
    for preset in presets.split(',') {
        measure(preset);
    }
}
