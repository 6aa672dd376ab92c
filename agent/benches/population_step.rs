//! Whole learner steps of a population (issue 22): P members of a shipped preset
//! trained as one batched program (`Learner::population`) against P single learners
//! (`Learner::new`, one after the other), at Deep Sea Treasure's, the pendulum
//! preset's and humanoid run's sizes (`configs/mompo/{dst,pendulum,humanoid-run}.toml`:
//! networks, batch, T, M as shipped), and MO-V-MPO's DST and pendulum presets
//! (`configs/movmpo/{dst,pendulum}.toml`: unrolls, epochs and minibatches as shipped).
//! Members differ in seed and ε as a sweep's do.
//!
//! Each member gets its own fixed random batch (real observations need no env: the
//! step's cost does not depend on their values). Each round times `--steps` population
//! steps, then the same number of steps of each single learner; a round's two figures
//! see the same machine, so the ratio is the median of the per-round ratios (a shared
//! VM's speed drifts within a minute). Prints, per size and P: t(P) total and per
//! member, t(P) / t(1), the P singles' time and singles / population, and the fit
//! t(P) = F + m P (least squares over the sizes run): F is what a population shares,
//! m what each member adds.
//!
//! Run: `cargo bench -p agent --bench population_step [-- --task
//! dst|pendulum|dst-vmpo|pendulum-vmpo|humanoid|all
//! --sizes 1,2,6,16,39 --steps 10 --rounds 5 --threads 1 --device cpu|cuda]`.
//! Defaults: all five tasks; sizes 1,2,6,16,39 (humanoid 1,2,8, with 1 step in 2
//! rounds on a CPU); one thread; the CPU.
#![allow(clippy::print_stdout, reason = "a benchmark reports on stdout")]

mod common;

use agent::core::algo::{Learner, LearnerDims, SnippetBatch};
use agent::core::learner_config::LearnerConfig;
use agent::core::nets::ActionKind;
use agent::core::random::{Purpose, StreamKey};
use agent::runtime::run_config::TrainConfig;
use std::path::Path;
use std::time::Instant;
use tch::{Device, Kind, Tensor};

struct Task {
    name: &'static str,
    preset: &'static str,
    dims: LearnerDims,
    default_sizes: Vec<i64>,
}

fn tasks() -> Vec<Task> {
    let dims = |obs_dim, action, rewards: [&str; 2]| LearnerDims {
        action_bounds: None,
        obs_dim,
        action,
        reward_names: rewards.iter().map(|r| r.to_string()).collect(),
        obs_leaves: Vec::new(),
    };
    vec![
        Task {
            name: "dst",
            preset: "configs/mompo/dst.toml",
            dims: dims(2, ActionKind::Discrete { n: 4 }, ["time", "treasure"]),
            default_sizes: vec![1, 2, 6, 16, 39],
        },
        Task {
            name: "pendulum",
            preset: "configs/mompo/pendulum.toml",
            dims: dims(
                3,
                ActionKind::Continuous { dim: 1 },
                ["task", "action_norm"],
            ),
            default_sizes: vec![1, 2, 6, 16, 39],
        },
        Task {
            name: "dst-vmpo",
            preset: "configs/movmpo/dst.toml",
            dims: dims(2, ActionKind::Discrete { n: 4 }, ["time", "treasure"]),
            default_sizes: vec![1, 2, 6, 16, 39],
        },
        Task {
            name: "pendulum-vmpo",
            preset: "configs/movmpo/pendulum.toml",
            dims: dims(
                3,
                ActionKind::Continuous { dim: 1 },
                ["task", "action_norm"],
            ),
            default_sizes: vec![1, 2, 6, 16, 39],
        },
        Task {
            name: "humanoid",
            preset: "configs/mompo/humanoid-run.toml",
            dims: dims(
                67,
                ActionKind::Continuous { dim: 21 },
                ["task", "action_norm"],
            ),
            default_sizes: vec![1, 2, 8],
        },
    ]
}

/// The preset's learner with member `p`'s seed and a distinct first ε.
fn member(base: &LearnerConfig, p: i64) -> LearnerConfig {
    let mut cfg = base.clone();
    cfg.seed = p as u64;
    if let Some(o) = cfg.objectives.first_mut() {
        o.epsilon *= 1.0 + 0.1 * p as f64;
    }
    cfg
}

/// A fixed random batch for `learner` from member `p`'s stream.
fn batch(learner: &Learner, p: i64, device: Device) -> SnippetBatch {
    let s = learner.settings();
    let (t, b) = (s.sequence_length as i64, s.batch_size as i64);
    let dims = learner.dims();
    let mut r = StreamKey::new(p as u64, Purpose::Replay, 1).at(0);
    let actions = match dims.action {
        ActionKind::Continuous { dim } => r.normal(&[t, b, dim], device),
        ActionKind::Discrete { n } => (r.uniform(&[t, b], device) * n as f64)
            .floor()
            .to_kind(Kind::Int64),
    };
    let ones = Tensor::ones([t, b], (Kind::Float, device));
    SnippetBatch {
        observations: r.normal(&[t + 1, b, dims.obs_dim], device),
        actions,
        rewards: r.normal(&[t, b, dims.reward_names.len() as i64], device),
        discounts: ones.copy(),
        behaviour_log_probs: r.uniform(&[t, b], device) * -2.0,
        valid: ones,
    }
}

/// Seconds per step of `steps` population steps.
fn time_population(learner: &mut Learner, batches: &[SnippetBatch], steps: usize) -> f64 {
    let start = Instant::now();
    for _ in 0..steps {
        learner.step_members(batches).expect("population step");
    }
    agent::core::device::synchronize(learner.device());
    start.elapsed().as_secs_f64() / steps as f64
}

/// Seconds per step (all P singles stepped once) of `steps` such rounds.
fn time_singles(singles: &mut [Learner], batches: &[SnippetBatch], steps: usize) -> f64 {
    let start = Instant::now();
    for _ in 0..steps {
        for (learner, batch) in singles.iter_mut().zip(batches) {
            learner.step(batch).expect("single step");
        }
    }
    if let Some(l) = singles.first() {
        agent::core::device::synchronize(l.device());
    }
    start.elapsed().as_secs_f64() / steps as f64
}

struct Row {
    p: i64,
    population_ms: f64,
    singles_ms: f64,
    ratio: f64,
}

fn run_task(task: &Task, sizes: &[i64], device: Device) -> Vec<Row> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let base = TrainConfig::load(&root.join(task.preset))
        .expect("shipped preset loads")
        .learner;
    let cpu_humanoid = task.name == "humanoid" && device == Device::Cpu;
    let steps: usize = common::arg("--steps", if cpu_humanoid { 1 } else { 10 });
    let rounds: usize = common::arg("--rounds", if cpu_humanoid { 2 } else { 5 });
    let mut rows = Vec::new();
    for &p in sizes {
        let cfgs: Vec<LearnerConfig> = (0..p).map(|i| member(&base, i)).collect();
        let mut population =
            Learner::population(cfgs.clone(), task.dims.clone(), device).expect("population");
        let mut singles: Vec<Learner> = cfgs
            .into_iter()
            .map(|c| Learner::new(c, task.dims.clone(), device).expect("single"))
            .collect();
        let batches: Vec<SnippetBatch> = (0..p).map(|i| batch(&population, i, device)).collect();
        // Warm-up: allocator, MKL and (on a GPU) kernel selection.
        time_population(&mut population, &batches, 2);
        time_singles(&mut singles, &batches, 2);
        let (mut pop, mut sing, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..rounds {
            let a = time_population(&mut population, &batches, steps);
            let b = time_singles(&mut singles, &batches, steps);
            pop.push(a);
            sing.push(b);
            ratios.push(b / a);
        }
        rows.push(Row {
            p,
            population_ms: common::median(pop) * 1e3,
            singles_ms: common::median(sing) * 1e3,
            ratio: common::median(ratios),
        });
        let last = rows.last().expect("pushed");
        eprintln!(
            "  {} P = {p}: population {:.2} ms, singles {:.2} ms",
            task.name, last.population_ms, last.singles_ms
        );
    }
    rows
}

/// Least-squares `t = F + m P` over the rows.
fn fit(rows: &[Row]) -> Option<(f64, f64)> {
    let n = rows.len() as f64;
    if rows.len() < 2 {
        return None;
    }
    let (sp, st): (f64, f64) = rows.iter().fold((0.0, 0.0), |(a, b), r| {
        (a + r.p as f64, b + r.population_ms)
    });
    let (mp, mt) = (sp / n, st / n);
    let (mut cov, mut var) = (0.0, 0.0);
    for r in rows {
        cov += (r.p as f64 - mp) * (r.population_ms - mt);
        var += (r.p as f64 - mp).powi(2);
    }
    let m = cov / var;
    Some((mt - m * mp, m))
}

fn main() {
    let threads: i32 = common::arg("--threads", 1);
    tch::set_num_threads(threads);
    let device = match common::arg("--device", "cpu".to_string()).as_str() {
        "cuda" => Device::Cuda(0),
        _ => Device::Cpu,
    };
    let which: String = common::arg("--task", "all".to_string());
    let sizes_arg: String = common::arg("--sizes", String::new());
    let mut report = Vec::new();
    for task in tasks() {
        if which != "all" && which != task.name {
            continue;
        }
        let sizes: Vec<i64> = if sizes_arg.is_empty() || task.name == "humanoid" {
            task.default_sizes.clone()
        } else {
            sizes_arg
                .split(',')
                .map(|s| s.trim().parse().expect("--sizes"))
                .collect()
        };
        eprintln!("{} ({}):", task.name, task.preset);
        let rows = run_task(&task, &sizes, device);
        report.push((task, rows));
    }
    println!("population_step: device {device:?}, {threads} thread(s)");
    for (task, rows) in &report {
        println!("\n{} ({})", task.name, task.preset);
        println!(
            "| P | population ms | per member ms | t(P) / t(1) | P singles ms | singles / population |"
        );
        println!("|---|---|---|---|---|---|");
        let t1 = rows.first().map_or(f64::NAN, |r| r.population_ms);
        for r in rows {
            println!(
                "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
                r.p,
                r.population_ms,
                r.population_ms / r.p as f64,
                r.population_ms / t1,
                r.singles_ms,
                r.ratio
            );
        }
        if let Some((f, m)) = fit(rows) {
            println!("fit t(P) = F + m P: F = {f:.2} ms shared, m = {m:.2} ms per member");
        }
    }
}
