//! MO-V-MPO trains end to end over a real server: on-policy unrolls from the actors,
//! each batch used once, and the preferred objective's return improves on DST.
//!
//! Its own test binary, so that libtorch's process-global random generator serves only
//! this run (one actor, fixed seed: the curve is the same on every run on a machine).

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};
use integration_tests::{episode_column, mean, report_figures, test_seed, with_seed};

/// Env steps of the run: 376 learner steps of 16 unrolls of 8 steps. The smoke
/// config's 12,000 (94 learner steps) learned on seeds 0 and 1 but not on all of
/// seeds 2-5 (seed 3: -7.49 -> -6.88 over the run, deterministic -3); at 48,000 the
/// test's bars held for seeds 1-5 and 6-10 (and 0; MO_MPO_TEST_SEED,
/// scripts/learning_seeds.sh), figures at the asserts.
const ON_POLICY_BUDGET: u64 = 48_000;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn movmpo_on_dst_learns_the_preferred_objective() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst-movmpo.toml");
    let mut cfg = with_seed(TrainConfig::load(&path).unwrap(), test_seed());
    cfg.run.runs_dir = runs.path().to_path_buf();
    cfg.run.total_env_steps = ON_POLICY_BUDGET;
    let summary = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap();
    assert_eq!(summary.env_steps, ON_POLICY_BUDGET);
    assert!(
        summary.learner_steps >= ON_POLICY_BUDGET / (8 * 16),
        "one step per 16 unrolls: {}",
        summary.learner_steps
    );
    // epsilon_time / epsilon_treasure = 50: the random start wanders before it finds a
    // treasure; the trained policy heads for the nearest one (time return -1). Every
    // bar here held for seeds 1-5 and 6-10 (and 0; MO_MPO_TEST_SEED,
    // scripts/learning_seeds.sh). Time return over the first / last 200 episodes and
    // deterministic, seed 0: -4.64 /
    // -1.00 / -1; seeds 1-5: -3.64 / -1.00, -12.91 / -1.52, -7.49 / -1.47, -9.71 /
    // -1.01, -7.45 / -1.25, each -1 deterministic; checked on seeds 6-10 after the
    // budget was chosen: -7.22 / -1.71, -7.96 / -1.86, -5.37 / -1.00, -8.43 / -2.84
    // (deterministic -3), -5.07 / -1.07.
    let time = episode_column(&summary.run_dir, "return_time");
    assert!(time.len() >= 400, "only {} episodes", time.len());
    let (first, last) = (mean(&time[..200]), mean(&time[time.len() - 200..]));
    report_figures(
        "movmpo_on_dst",
        &format!(
            "time return first {first:.2} last {last:.2} eval {:.2}",
            summary.eval_return[0]
        ),
    );
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
