//! Training on DST improves the preferred objective, end to end over a real server.
//!
//! Its own test binary: with one actor, the same seed, and no other run drawing from
//! libtorch's process-global random generator, the learning curve is the same on
//! every run on the same machine, so the threshold below is not a coin toss.

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::train::{TrainOptions, train};
use integration_tests::{episode_column, report_figures, smoke_config, test_seed, with_seed};

/// Mean of column `name` over rows `range` of a run's episodes.csv.
fn episode_mean(run_dir: &Path, name: &str, take_last: bool, n: usize) -> f64 {
    let values = episode_column(run_dir, name);
    assert!(values.len() >= 2 * n, "only {} episodes", values.len());
    let slice = if take_last {
        &values[values.len() - n..]
    } else {
        &values[..n]
    };
    slice.iter().sum::<f64>() / n as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn training_on_dst_improves_the_preferred_objective() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = with_seed(smoke_config(runs.path()), test_seed());
    // Twice the smoke config's learner steps: at 0.25 per env step the improvement
    // was 0.65-1.7 over seeds 0-5 (three of six under the bar below); at 0.5 it is
    // 3.8-5.4 for the same seeds, and the run still takes about 20 s.
    cfg.run.learner_steps_per_env_step = 0.5;
    let summary = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap();
    assert_eq!(summary.env_steps, 8000);
    // (8000 - 500 warm-up) * 0.5 learner steps.
    assert_eq!(summary.learner_steps, 3750);
    // epsilon_treasure / epsilon_time = 100 prefers treasure: the random start mostly
    // takes the 0.7 next to the start; the trained policy reaches farther treasures.
    let first = episode_mean(&summary.run_dir, "return_treasure", false, 200);
    let last = episode_mean(&summary.run_dir, "return_treasure", true, 200);
    report_figures("dst_improves", &format!("first {first:.2} last {last:.2}"));
    // +1.0 is about three standard errors of a 200-episode mean here. The bar held
    // for seeds 1-5 (MO_MPO_TEST_SEED, scripts/learning_seeds.sh), first -> last: 0: 2.88 -> 8.17,
    // 1: 1.54 -> 6.95, 2: 2.24 -> 6.07, 3: 3.13 -> 8.55, 4: 2.54 -> 7.33,
    // 5: 3.67 -> 8.47 (agent train on configs/smoke/dst.toml, the same settings).
    assert!(
        last > first + 1.0,
        "treasure return did not improve: first {first:.2}, last {last:.2}"
    );
    for file in [
        "config.toml",
        "summary.json",
        "learner.jsonl",
        "curves.png",
        "curves.svg",
        "checkpoints/latest.json",
    ] {
        assert!(summary.run_dir.join(file).exists(), "{file} missing");
    }
    server.stop().await.unwrap();
}
