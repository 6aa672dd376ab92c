//! Scalarized V-MPO trains end to end, and MO-V-MPO follows its epsilon ratio, on Deep
//! Sea Treasure over a real server (on-policy unrolls, each batch used once).
//!
//! Its own test binary; its two tests run one at a time (`ONE_RUN`), so each run has
//! the machine's cores to itself and sees the same curve on every invocation.

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, TrainSummary, train};
use integration_tests::{episode_column, mean, report_figures, test_seed, with_seed};

static ONE_RUN: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// A finished run and the directory that holds its files.
struct Trained {
    summary: TrainSummary,
    _runs: tempfile::TempDir,
}

impl Trained {
    /// The deterministic policy's evaluation return of `objective`.
    fn eval(&self, objective: &str) -> f64 {
        let i = self.summary.objectives.iter().position(|o| o == objective);
        self.summary.eval_return[i.expect("objective")]
    }
}

/// Trains `configs/smoke/<name>.toml`, changed by `change`, against `server`.
async fn run(server: &LocalServer, name: &str, change: impl FnOnce(&mut TrainConfig)) -> Trained {
    let runs = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../configs/smoke/{name}.toml"));
    let mut cfg = with_seed(TrainConfig::load(&path).unwrap(), test_seed());
    cfg.run.runs_dir = runs.path().to_path_buf();
    change(&mut cfg);
    let summary = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap();
    Trained {
        summary,
        _runs: runs,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scalarized_vmpo_on_dst_learns_its_weighted_return() {
    let _one = ONE_RUN.lock().await;
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let trained = run(&server, "dst-vmpo", |_| {}).await;
    let summary = &trained.summary;
    assert_eq!(summary.env_steps, 12000);
    // w = (time 1, treasure 0.1): the random start wanders before it finds a treasure;
    // the trained policy heads for the nearest one. Every bar here held for seeds 1-5 and
    // 6-10 (and 0; MO_MPO_TEST_SEED, scripts/learning_seeds.sh). Scalarized return
    // over the first / last 200 episodes, seed 0: -3.94 / -1.02; seeds 1-5: -3.28 / -1.02, -15.16 /
    // -1.70, -7.40 / -1.33, -8.54 / -1.17, -6.31 / -1.25; seeds 6-10: -6.19 / -1.12,
    // -7.05 / -1.13, -4.52 / -1.16, -7.21 / -1.26, -4.49 / -1.09; -0.93 deterministic
    // on all eleven.
    let time = episode_column(&summary.run_dir, "return_time");
    let treasure = episode_column(&summary.run_dir, "return_treasure");
    let scalarized: Vec<f64> = time
        .iter()
        .zip(&treasure)
        .map(|(t, r)| t + 0.1 * r)
        .collect();
    assert!(
        scalarized.len() >= 400,
        "only {} episodes",
        scalarized.len()
    );
    let (first, last) = (
        mean(&scalarized[..200]),
        mean(&scalarized[scalarized.len() - 200..]),
    );
    assert!(
        last > first + 1.0,
        "scalarized return did not improve: first {first:.2}, last {last:.2}"
    );
    let eval = trained.eval("time") + 0.1 * trained.eval("treasure");
    report_figures(
        "scalarized_vmpo_on_dst",
        &format!("scalarized return first {first:.2} last {last:.2} eval {eval:.2}"),
    );
    assert!(
        eval > last - 1.0,
        "deterministic policy {eval:.2} vs last {last:.2}"
    );
    server.stop().await.unwrap();
}

/// Sets the smoke run's epsilon of `name`.
fn epsilon(cfg: &mut TrainConfig, name: &str, value: f64) {
    let o = cfg.learner.objectives.iter_mut().find(|o| o.name == name);
    o.expect("objective").epsilon = value;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn movmpo_on_dst_reaches_a_farther_treasure_with_a_larger_epsilon_ratio() {
    let _one = ONE_RUN.lock().await;
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let mut treasure = Vec::new();
    for (eps_treasure, eps_time) in [(0.01, 0.5), (0.5, 0.01)] {
        let trained = run(&server, "dst-movmpo", |cfg| {
            // 376 learner steps: at the smoke config's 94 the ratio-0.02 run had not
            // settled on the nearest treasure on seeds 2-5 (seed 2: both ratios 11.5);
            // at 376 the bar below held for seeds 1-5 and 6-10 (and 0; MO_MPO_TEST_SEED,
            // scripts/learning_seeds.sh).
            cfg.run.total_env_steps = 48_000;
            epsilon(cfg, "treasure", eps_treasure);
            epsilon(cfg, "time", eps_time);
        })
        .await;
        treasure.push(trained.eval("treasure"));
    }
    let (small, large) = (treasure[0], treasure[1]);
    report_figures(
        "movmpo_epsilon_ratio",
        &format!("treasure reached: ratio 0.02 -> {small}, ratio 50 -> {large}"),
    );
    // The ten treasures are 0.7 (one step away) to 23.7 (19 steps). This bar held for
    // seeds 1-5 and 6-10 (and 0; MO_MPO_TEST_SEED, scripts/learning_seeds.sh).
    // Measured: ratio 0.02 reaches 0.7 and ratio 50 reaches 11.5 (five steps away) on seeds 0-5, and on
    // seeds 6-10, checked after the budget was chosen (seed 9: 8.2 and 11.5).
    assert!(
        large > small,
        "eps_treasure / eps_time = 50 reached treasure {large}, = 0.02 reached {small}"
    );
    server.stop().await.unwrap();
}
