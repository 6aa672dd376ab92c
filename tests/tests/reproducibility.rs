//! Reproducibility: the same config and seed give the same learning curve (one actor),
//! alone or while other runs train in the same process, as a sweep's runs do.
//!
//! Every draw of a run comes from its own keyed streams (`agent::random`), so a run
//! beside another must match the same run alone: the categorical DST run checks
//! initialisation and actor sampling, the Gaussian pendulum run the learner's noise.

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::run_config::TrainConfig;
use agent::train::{TrainOptions, train};
use integration_tests::smoke_config;

/// What a run wrote that must repeat: `episodes.csv` and `learner.jsonl` without
/// their wall-clock fields.
#[derive(Debug, PartialEq)]
struct Curve {
    episodes: Vec<String>,
    learner: Vec<String>,
}

fn curve(run_dir: &Path) -> Curve {
    // episodes.csv without its last column, the wall-clock stamp.
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
            for clock in [
                "wall_seconds",
                "step_ms",
                "env_steps_per_second",
                "learner_steps_per_second",
            ] {
                o.remove(clock);
            }
            v.to_string()
        })
        .collect();
    Curve { episodes, learner }
}

async fn run(cfg: TrainConfig, server: &LocalServer) -> Curve {
    let s = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap();
    curve(&s.run_dir)
}

/// A short Gaussian MO-MPO run on the pendulum preset (learner noise every step).
fn pendulum_config(runs_dir: &Path) -> TrainConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/mompo/pendulum.toml");
    let mut cfg = TrainConfig::load_with(
        &path,
        &[
            "run.total_env_steps=1600".into(),
            "run.min_replay_transitions=400".into(),
            "run.log_period=25".into(),
            "run.eval_episodes=1".into(),
        ],
    )
    .expect("pendulum preset loads");
    cfg.run.runs_dir = runs_dir.to_path_buf();
    cfg
}

fn with_seed(mut cfg: TrainConfig, seed: u64) -> TrainConfig {
    cfg.seed = seed;
    cfg.learner.seed = seed;
    cfg
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_config_and_seed_give_the_same_learning_curve() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = smoke_config(runs.path());
    cfg.run.total_env_steps = 2500;
    let first = run(cfg.clone(), &server).await;
    assert!(first.learner.len() >= 10);
    let second = run(cfg, &server).await;
    assert_eq!(
        first.episodes, second.episodes,
        "episodes.csv differs between identical runs"
    );
    assert_eq!(
        first.learner, second.learner,
        "learner statistics differ between identical runs"
    );
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_beside_other_runs_matches_the_same_run_alone() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut dst = smoke_config(runs.path());
    dst.run.total_env_steps = 2500;
    for (name, cfg) in [("dst", dst), ("pendulum", pendulum_config(runs.path()))] {
        let alone = run(cfg.clone(), &server).await;
        assert!(alone.learner.len() >= 10, "{name}: too few learner rows");
        // The same run again, now while a run of another seed trains beside it, both
        // drawing random numbers at the same time.
        let (beside, other) = tokio::join!(
            run(cfg.clone(), &server),
            run(with_seed(cfg.clone(), 7), &server)
        );
        assert_eq!(
            alone, beside,
            "{name}: a run beside another differs from the same run alone"
        );
        assert_ne!(
            alone.learner, other.learner,
            "{name}: another seed must give other numbers"
        );
    }
    server.stop().await.unwrap();
}
