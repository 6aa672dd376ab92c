#![allow(dead_code, unreachable_pub, reason = "each benchmark uses a subset")]
//! The learner-step benchmarks' shared parts: `learner_step` (humanoid size, Table 3)
//! and `learner_step_pendulum` (the old pendulum preset's size) run one full MO-MPO
//! step on a fixed random batch through `run` (or, `learner_step` against PyTorch,
//! through `prepare`, `warm_up` and `timed` in rounds); `learner_step_locomotion`
//! builds its learner from a run config and uses `set_up`, `random_batch` and
//! `time_steps`; `vmpo_step` uses `time_steps` and `arg`, `checkpoint_cost` `arg` and
//! `median`. A step is timed as the median of `--steps` steps after warm-up steps,
//! with the share of each phase.

use agent::core::algo::{Learner, LearnerDims, SnippetBatch};
use agent::core::learner_config::{LearnerConfig, ObjectiveConfig, ObjectiveSource};
use agent::core::nets::ActionKind;
use tch::{Kind, Tensor};

/// What one benchmark measures.
pub struct StepSize {
    /// Printed name.
    pub name: &'static str,
    /// Observation and action sizes.
    pub obs_dim: i64,
    /// Action dimensions D.
    pub act_dim: i64,
    /// The learner (networks, batch, M, ...).
    pub cfg: LearnerConfig,
}

/// `task` learned, `action_norm` in closed form (humanoid run and pendulum).
pub fn task_and_action_norm(action_norm_epsilon: f64) -> Vec<ObjectiveConfig> {
    vec![
        ObjectiveConfig {
            name: "task".into(),
            epsilon: 0.1,
            source: ObjectiveSource::Learned,
        },
        ObjectiveConfig {
            name: "action_norm".into(),
            epsilon: action_norm_epsilon,
            source: ObjectiveSource::ActionNorm,
        },
    ]
}

/// `--name value` from the command line.
pub fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map_or(default, |v| {
            v.parse()
                .unwrap_or_else(|_| panic!("{name}: cannot parse {v}"))
        })
}

/// The median of `v`.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Step times in ms and the summed time of each phase (`PhaseTimings` order).
pub struct Timed {
    /// One entry per step.
    pub totals: Vec<f64>,
    /// Policy evaluation, E-step, M-step + duals, target update.
    pub phases: [f64; 4],
}

/// Times `steps` learner steps on `batch`.
pub fn timed(learner: &mut Learner, batch: &SnippetBatch, steps: usize) -> Timed {
    let mut out = Timed {
        totals: Vec::new(),
        phases: [0.0; 4],
    };
    for _ in 0..steps {
        let start = std::time::Instant::now();
        let p = learner.step(batch).expect("step").timings;
        out.totals.push(start.elapsed().as_secs_f64() * 1e3);
        for (acc, v) in out.phases.iter_mut().zip([
            p.policy_evaluation_ms,
            p.e_step_ms,
            p.m_step_ms,
            p.target_update_ms,
        ]) {
            *acc += v;
        }
    }
    out
}

/// Takes `steps` untimed steps (allocator, caches and libtorch's lazy set-up).
pub fn warm_up(learner: &mut Learner, batch: &SnippetBatch, steps: usize) {
    for _ in 0..steps {
        learner.step(batch).expect("step");
    }
}

/// Prints each phase's share of the time (`names` in `PhaseTimings` order).
pub fn print_phases(phases: &[f64; 4], names: [&str; 4]) {
    let sum: f64 = phases.iter().sum();
    for (name, v) in names.iter().zip(phases) {
        println!("  {:>5.1}%  {name}", 100.0 * v / sum);
    }
}

/// Times `steps` learner steps on `batch` after `warmup` untimed ones, prints each
/// phase's share of the time and returns the step times in ms.
pub fn time_steps(
    learner: &mut Learner,
    batch: &SnippetBatch,
    warmup: usize,
    steps: usize,
    names: [&str; 4],
) -> Vec<f64> {
    warm_up(learner, batch, warmup);
    let t = timed(learner, batch, steps);
    print_phases(&t.phases, names);
    t.totals
}

/// The phases of an MO-MPO step, as `time_steps` prints them.
pub const MPO_PHASES: [&str; 4] = [
    "policy evaluation (sampling, target critic x M, Retrace, critic update)",
    "E-step",
    "M-step + duals",
    "target update",
];

/// A learner and a fixed random batch at one benchmark's size, ready to step.
pub struct Prepared {
    /// The learner, on the benchmark's device.
    pub learner: Learner,
    /// The batch every step trains on.
    pub batch: SnippetBatch,
    /// `--steps N` (default 20).
    pub steps: usize,
}

/// Sets up libtorch for a timed benchmark: the allocator, `--threads N` (default: every
/// core) and the learner's device. Returns the thread count and the device.
pub fn set_up() -> (usize, tch::Device) {
    agent::core::device::tune_allocator();
    let threads = agent::core::device::configure_threads(
        Some(arg::<usize>("--threads", 0)).filter(|&n| n > 0),
    );
    (threads, agent::core::device::learner_device())
}

/// A fixed random batch of `b` snippets of length `t` with `k` reward columns (libtorch's
/// generator seeded 0, so every invocation steps on the same data).
pub fn random_batch(
    t: i64,
    b: i64,
    obs_dim: i64,
    act_dim: i64,
    k: i64,
    device: tch::Device,
) -> SnippetBatch {
    tch::manual_seed(0);
    let opts = (Kind::Float, tch::Device::Cpu);
    SnippetBatch {
        observations: Tensor::randn([t + 1, b, obs_dim], opts),
        actions: Tensor::randn([t, b, act_dim], opts).clamp(-1.0, 1.0),
        rewards: Tensor::randn([t, b, k], opts),
        discounts: Tensor::ones([t, b], opts),
        behaviour_log_probs: Tensor::randn([t, b], opts) - 20.0,
        valid: Tensor::ones([t, b], opts),
    }
    .to_device(device)
}

/// Builds the learner and batch for `size` and prints the size: `--threads N` (default:
/// every core), `--steps N`; `--batch B` and `--samples M` change the size for
/// exploration (the default is the size the benchmark is named for).
pub fn prepare(size: StepSize) -> Prepared {
    let (threads, device) = set_up();
    let steps: usize = arg("--steps", 20);
    let StepSize {
        name,
        obs_dim,
        act_dim,
        mut cfg,
    } = size;
    cfg.mpo.batch_size = arg("--batch", cfg.mpo.batch_size);
    cfg.mpo.num_samples = arg("--samples", cfg.mpo.num_samples);
    let (t, b) = (cfg.mpo.retrace_length as i64, cfg.mpo.batch_size as i64);
    let dims = LearnerDims {
        action_bounds: None,
        obs_dim,
        action: ActionKind::Continuous { dim: act_dim },
        reward_names: vec!["task".into(), "action_norm".into()],
        obs_leaves: Vec::new(),
    };
    let learner = Learner::new(cfg.clone(), dims, device).expect("valid config");
    let batch = random_batch(t, b, obs_dim, act_dim, 2, device);
    println!(
        "{name}: obs {obs_dim}, act {act_dim}, B {b}, T {t}, M {}, policy {:?}, critic {:?}, K 2 (task + closed-form action_norm), device {device:?}, threads {threads}",
        cfg.mpo.num_samples, cfg.network.policy_layers, cfg.network.critic_layers
    );
    Prepared {
        learner,
        batch,
        steps,
    }
}

/// Runs the benchmark (see `prepare` for the flags): the median of `--steps` steps
/// after 3 warm-up steps, with the share of each phase.
/// Prints `learner_step_ms_median=<ms>` last and returns that median.
pub fn run(size: StepSize) -> f64 {
    let Prepared {
        mut learner,
        batch,
        steps,
    } = prepare(size);
    let totals = time_steps(&mut learner, &batch, 3, steps, MPO_PHASES);
    let ms = median(totals);
    println!("learner_step_ms_median={ms:.2}");
    ms
}
