//! Periodic evaluation (`run.eval_period`, issue 35): a run evaluates its
//! deterministic policy every period without changing a training step, writes one
//! `eval.csv` row per evaluation (one per grid point for an ε-conditioned run), and
//! draws the evaluation curve. Real local server, the smoke configs.
//!
//! No learning threshold: what is asserted (identical training logs, the rows' env and
//! learner steps, returns inside DST's reward ranges) holds for any seed and float
//! trajectory, so no other seeds need recording.

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, TrainSummary, train};
use integration_tests::{curve, smoke_config};

/// `eval.csv` as a header and rows of numbers.
fn eval_rows(run_dir: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(run_dir.join("eval.csv")).expect("eval.csv");
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

async fn run(cfg: TrainConfig, server: &LocalServer) -> TrainSummary {
    train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn periodic_evaluations_change_no_training_step() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let plain = run(smoke_config(&dir.path().join("plain")), &server).await;
    let mut cfg = smoke_config(&dir.path().join("evaluated"));
    cfg.run.eval_period = 2000;
    let evaluated = run(cfg.clone(), &server).await;
    server.stop().await.unwrap();

    assert_eq!(
        curve(&plain.run_dir),
        curve(&evaluated.run_dir),
        "evaluations changed the training episodes or learner statistics"
    );
    assert!(!plain.run_dir.join("eval.csv").exists());

    let (header, rows) = eval_rows(&evaluated.run_dir);
    assert_eq!(
        header,
        [
            "env_steps",
            "learner_steps",
            "return_time",
            "return_treasure",
            "discounted_return_time",
            "discounted_return_treasure"
        ]
    );
    let at: Vec<f64> = rows.iter().map(|r| r[0]).collect();
    assert_eq!(at, [2000.0, 4000.0, 6000.0, 8000.0], "one row per period");
    // The policy evaluated at X is the one the actors held then: that of the learner
    // steps the env steps before X's actor step allowed ((X - min_replay) * ratio,
    // less one actor step of B envs), never fewer than the previous row's.
    let r = &cfg.run;
    let one_actor_step = cfg.env.num_envs as f64 * r.learner_steps_per_env_step;
    for pair in rows.windows(2) {
        assert!(
            pair[0][1] <= pair[1][1],
            "learner steps go forwards: {rows:?}"
        );
    }
    for row in &rows {
        let allowed = (row[0] - r.min_replay_transitions as f64) * r.learner_steps_per_env_step;
        assert!(
            row[1] <= allowed && row[1] >= (allowed - one_actor_step).floor(),
            "{row:?} vs {allowed}"
        );
        // Deep Sea Treasure's returns: time in [-25, 0) per step, treasure in [0, 23.7].
        assert!((-1000.0..0.0).contains(&row[2]) && (0.0..=23.7).contains(&row[3]));
    }
    assert!(
        evaluated.run_dir.join("eval.png").exists() && evaluated.run_dir.join("eval.svg").exists()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_conditioned_run_evaluates_every_grid_point_each_period() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst-conditioned.toml");
    let mut cfg = TrainConfig::load_with(
        &path,
        &[
            "run.total_env_steps=4000".into(),
            "run.eval_period=2000".into(),
            "front.discounted_reference_point={ time = -25.0, treasure = 0.0 }".into(),
        ],
    )
    .unwrap();
    cfg.run.runs_dir = dir.path().to_path_buf();
    let summary = run(cfg, &server).await;
    server.stop().await.unwrap();

    let (header, rows) = eval_rows(&summary.run_dir);
    assert_eq!(
        header[..3],
        ["env_steps", "learner_steps", "epsilon_treasure"]
    );
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (r[0], r[2])).collect();
    let grid = [0.005, 0.05, 0.5];
    let expected: Vec<(f64, f64)> = [2000.0, 4000.0]
        .iter()
        .flat_map(|&at| grid.iter().map(move |&e| (at, e)))
        .collect();
    assert_eq!(points, expected, "every grid point at every evaluation");
}
