//! Reproducibility: the same config and seed give the same learning curve (one actor).
//!
//! Its own test binary on purpose: libtorch's random generator is process-global, so
//! runs training concurrently in one process (other tests, or a sweep with
//! `parallel > 1`) draw from the same stream.

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::train::{TrainOptions, train};
use integration_tests::smoke_config;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_config_and_seed_give_the_same_learning_curve() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut curves = Vec::new();
    for _ in 0..2 {
        let mut cfg = smoke_config(runs.path());
        cfg.run.total_env_steps = 2500;
        let s = train(
            cfg,
            &[server.address().to_string()],
            TrainOptions::default(),
        )
        .await
        .unwrap();
        // episodes.csv without its last column, the wall-clock stamp.
        let episodes: Vec<String> = std::fs::read_to_string(s.run_dir.join("episodes.csv"))
            .unwrap()
            .lines()
            .map(|l| l.rsplit_once(',').unwrap().0.to_string())
            .collect();
        // learner.jsonl without its wall-clock fields (times and rates).
        let learner: Vec<String> = std::fs::read_to_string(s.run_dir.join("learner.jsonl"))
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
        assert!(learner.len() >= 10);
        curves.push((episodes, learner));
    }
    assert_eq!(
        curves[0].0, curves[1].0,
        "episodes.csv differs between identical runs"
    );
    assert_eq!(
        curves[0].1, curves[1].1,
        "learner statistics differ between identical runs"
    );
    server.stop().await.unwrap();
}
