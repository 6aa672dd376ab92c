//! Shared helpers for the end-to-end tests in `tests/tests/`.
//!
//! Every test starts its own real `env_server` on 127.0.0.1 with an OS-chosen
//! port (through [`agent::env::server_process::LocalServer`]) and stops it.

use std::path::Path;

use agent::env::grpc::EnvClient;
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::learner::LearnerRecord;
use agent::runtime::run_config::TrainConfig;
use agent::sweep::{FrontSummary, SweepConfig};

/// The base seed of a learning test: 0, or `MO_MPO_TEST_SEED` when set. A learning
/// test trains from it, so that `scripts/learning_seeds.sh` can check its threshold on
/// other seeds (float kernels differ between CPUs, so one seed's trajectory differs
/// between machines: a threshold must hold across seeds). Each learning test's
/// comment records the seeds it was checked on.
pub fn test_seed() -> u64 {
    std::env::var("MO_MPO_TEST_SEED").map_or(0, |v| {
        v.parse()
            .unwrap_or_else(|_| panic!("MO_MPO_TEST_SEED: expected an unsigned integer, got {v:?}"))
    })
}

/// `cfg` trained from `seed` (envs, sampling, networks).
pub fn with_seed(mut cfg: TrainConfig, seed: u64) -> TrainConfig {
    cfg.seed = seed;
    cfg.learner.seed = seed;
    cfg
}

/// Prints a learning test's measured figures on one line, which
/// `scripts/learning_seeds.sh` collects (cargo shows it with `--nocapture`).
pub fn report_figures(test: &str, figures: &str) {
    eprintln!("learning-figures {test} seed {}: {figures}", test_seed());
}

/// What a run wrote that must repeat: `episodes.csv` without its last column (the
/// wall-clock stamp) and `learner.jsonl` without its timing fields.
#[derive(Debug, PartialEq)]
pub struct Curve {
    /// `episodes.csv`'s lines, header included, each without its last column.
    pub episodes: Vec<String>,
    /// `learner.jsonl`'s rows without their timing fields, as JSON text.
    pub learner: Vec<String>,
}

/// The [`Curve`] of the run in `run_dir`.
pub fn curve(run_dir: &Path) -> Curve {
    let episodes = std::fs::read_to_string(run_dir.join("episodes.csv"))
        .unwrap()
        .lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect();
    let learner = std::fs::read_to_string(run_dir.join("learner.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let o = v.as_object_mut().unwrap();
            for clock in LearnerRecord::CLOCK_FIELDS {
                o.remove(clock);
            }
            v.to_string()
        })
        .collect();
    Curve { episodes, learner }
}

/// `configs/smoke/dst.toml` (a seconds-long DST run) writing its runs under `runs_dir`.
pub fn smoke_config(runs_dir: &Path) -> TrainConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
    let mut cfg = TrainConfig::load(&path).expect("smoke config loads");
    cfg.run.runs_dir = runs_dir.to_path_buf();
    cfg
}

/// The pendulum preset (`configs/mompo/pendulum.toml`) cut to a short run: 1,600 env
/// steps, 400 transitions before the first learner step, one evaluation episode,
/// its runs under `runs_dir`.
pub fn short_pendulum(runs_dir: &Path) -> TrainConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/mompo/pendulum.toml");
    let mut cfg = TrainConfig::load_with(
        &path,
        &[
            "run.total_env_steps=1600".into(),
            "run.min_replay_transitions=400".into(),
            "run.eval_episodes=1".into(),
        ],
    )
    .expect("pendulum preset loads");
    cfg.run.runs_dir = runs_dir.to_path_buf();
    cfg
}

/// A local env_server with `extra_args` (e.g. `--max-sessions 4`), started.
pub async fn start_server(extra_args: &[String]) -> LocalServer {
    let options = ServerOptions {
        extra_args: extra_args.to_vec(),
        ..ServerOptions::default()
    };
    LocalServer::start(&options)
        .await
        .expect("env_server starts")
}

/// Column `name` of a run's `episodes.csv`, one value per training episode in order.
pub fn episode_column(run_dir: &Path, name: &str) -> Vec<f64> {
    let text = std::fs::read_to_string(run_dir.join("episodes.csv")).expect("episodes.csv");
    let mut lines = text.lines();
    let col = lines
        .next()
        .expect("a header")
        .split(',')
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no column {name} in episodes.csv"));
    lines
        .map(|l| l.split(',').nth(col).unwrap().parse().unwrap())
        .collect()
}

/// The mean of `v`.
pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// A started server and a client connected to it.
#[derive(Debug)]
pub struct Harness {
    /// The server process (killed on drop).
    pub server: LocalServer,
    /// A client connected to it.
    pub client: EnvClient,
}

impl Harness {
    /// Start a server with extra flags and connect to it.
    pub async fn start(extra_args: &[&str]) -> Harness {
        let args: Vec<String> = extra_args.iter().map(|s| s.to_string()).collect();
        let server = start_server(&args).await;
        let client = EnvClient::connect(server.address())
            .await
            .expect("client connects");
        Harness { server, client }
    }
}

/// Runs `sweep` (its base config `base`) against one local server, no resume.
pub async fn run_sweep(
    sweep: &SweepConfig,
    base: &TrainConfig,
    server: &LocalServer,
) -> FrontSummary {
    agent::sweep::sweep(sweep, base, &[server.address().to_string()], false, None)
        .await
        .unwrap()
}
pub mod chaos;
pub mod faults;
pub mod proxy;
