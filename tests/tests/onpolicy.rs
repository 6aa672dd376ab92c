//! MO-V-MPO trains end to end over a real server: on-policy unrolls from the actors,
//! each batch used once, and the preferred objective's return improves on DST.
//!
//! Its own test binary, so that libtorch's process-global random generator serves only
//! this run (one actor, fixed seed: the curve is the same on every run on a machine).

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};
use integration_tests::{episode_column, mean};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn movmpo_on_dst_learns_the_preferred_objective() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst-movmpo.toml");
    let mut cfg = TrainConfig::load(&path).unwrap();
    cfg.run.runs_dir = runs.path().to_path_buf();
    let summary = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap();
    assert_eq!(summary.env_steps, 12000);
    assert!(
        summary.learner_steps >= 12000 / (8 * 16),
        "one step per 16 unrolls: {}",
        summary.learner_steps
    );
    // epsilon_time / epsilon_treasure = 50: the random start wanders before it finds a
    // treasure (time return about -4.4 over the first 200 episodes when written); the
    // trained policy heads for the nearest one (about -2.4 over the last 200).
    let time = episode_column(&summary.run_dir, "return_time");
    assert!(time.len() >= 400, "only {} episodes", time.len());
    let (first, last) = (mean(&time[..200]), mean(&time[time.len() - 200..]));
    assert!(
        last > first + 1.0,
        "time return did not improve: first {first:.2}, last {last:.2}"
    );
    assert!(
        summary.eval_return[0] >= first,
        "deterministic policy {:?} vs first {first:.2}",
        summary.eval_return
    );
    for file in [
        "config.toml",
        "summary.json",
        "learner.jsonl",
        "curves.png",
        "checkpoints/latest.json",
    ] {
        assert!(summary.run_dir.join(file).exists(), "{file} missing");
    }
    server.stop().await.unwrap();
}
