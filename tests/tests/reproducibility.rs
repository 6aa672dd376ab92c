//! Reproducibility: the same config and seed give the same learning curve (one actor),
//! alone or while other runs train in the same process, as a sweep's runs do.
//!
//! Every draw of a run comes from its own keyed streams (`agent::core::random`), so a run
//! beside another must match the same run alone: the categorical DST run checks
//! initialisation and actor sampling, the Gaussian pendulum run the learner's noise.
//!
//! A run trained as a member of a population (issue 22: one batched learner, one env
//! session for all members; MO-MPO and MO-V-MPO) matches the same run alone: its episodes until the
//! learner's first step (the same env seeds and sampling streams), and its learner
//! statistics within 1e-5 relative over the first 50 learner steps (batched and single
//! GEMMs round differently, so not bit for bit; the drift is measured, not assumed).

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train, train_population};
use integration_tests::{Curve, curve, short_pendulum, smoke_config};

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
    // A short Gaussian MO-MPO run on the pendulum preset (learner noise every step).
    let mut pendulum = short_pendulum(runs.path());
    pendulum.run.log_period = 25;
    for (name, cfg) in [("dst", dst), ("pendulum", pendulum)] {
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

/// Learner rows as numbers: every statistic of each `learner.jsonl` row, in order.
fn statistics(curve: &Curve) -> Vec<Vec<f64>> {
    curve
        .learner
        .iter()
        .map(|row| {
            let v: serde_json::Value = serde_json::from_str(row).unwrap();
            let mut out = Vec::new();
            for key in [
                "critic_loss",
                "temperature",
                "estep_kl",
                "alpha",
                "policy_kl",
            ] {
                for x in v[key].as_array().unwrap() {
                    out.push(x.as_f64().unwrap());
                }
            }
            out
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_population_member_matches_the_same_run_alone() {
    let runs = tempfile::tempdir().unwrap();
    let mut base = smoke_config(runs.path());
    base.run.total_env_steps = 1200;
    // Three members: other seeds and another ε_treasure each; 500 transitions (63
    // steps of 8 instances) before the first learner step.
    member_matches_alone(base, &[(0, 1.0), (7, 0.1), (3, 0.5)], 504).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_on_policy_population_member_matches_the_same_run_alone() {
    let runs = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst-movmpo.toml");
    let mut base = TrainConfig::load(&path).unwrap();
    base.run.runs_dir = runs.path().to_path_buf();
    // 54 learner steps of 16 unrolls of 8 steps; 128 transitions before the first.
    base.run.total_env_steps = 7000;
    member_matches_alone(base, &[(0, 0.01), (7, 0.05)], 128).await;
}

/// Trains members of `base` (seed and ε of objective 1 each) as one population, twice,
/// and each alone: the population repeats bit for bit, and every member matches its
/// run alone (episodes until `first_step` transitions, learner statistics within
/// 1e-5 relative over the first 50 learner steps).
async fn member_matches_alone(base: TrainConfig, settings: &[(u64, f64)], first_step: u64) {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let mut base = base;
    base.run.log_period = 1;
    let members: Vec<TrainConfig> = settings
        .iter()
        .map(|&(seed, eps)| {
            let mut cfg = with_seed(base.clone(), seed);
            cfg.learner.objectives[1].epsilon = eps;
            cfg
        })
        .collect();
    let addresses = [server.address().to_string()];
    let train_members = || train_population(members.clone(), &addresses, TrainOptions::default());
    let population = train_members().await.unwrap();
    // The same population again gives every member the same curve, bit for bit: all
    // members' policies are published before actors act on any of them.
    let again = train_members().await.unwrap();
    for (p, (a, b)) in population.iter().zip(&again).enumerate() {
        assert_eq!(
            curve(&a.run_dir),
            curve(&b.run_dir),
            "member {p}: the same population twice differs"
        );
    }
    for (p, (cfg, summary)) in members.into_iter().zip(&population).enumerate() {
        let member = curve(&summary.run_dir);
        let alone = run(cfg, &server).await;
        let first_learned = alone
            .episodes
            .iter()
            .position(|l| {
                l.split(',')
                    .next()
                    .and_then(|s| s.parse::<u64>().ok())
                    .is_some_and(|s| s > first_step)
            })
            .unwrap_or(alone.episodes.len());
        assert!(
            first_learned > 10,
            "member {p}: too few episodes before learning"
        );
        assert_eq!(
            member.episodes[..first_learned],
            alone.episodes[..first_learned],
            "member {p}: episodes before the first learner step differ"
        );
        let (a, b) = (statistics(&member), statistics(&alone));
        assert!(
            a.len() >= 50 && b.len() >= 50,
            "member {p}: too few learner rows"
        );
        for (step, (x, y)) in a.iter().zip(&b).take(50).enumerate() {
            for (u, v) in x.iter().zip(y) {
                assert!(
                    (u - v).abs() <= 1e-5 * v.abs() + 1e-7,
                    "member {p}, learner step {}: {x:?} vs {y:?}",
                    step + 1
                );
            }
        }
    }
    server.stop().await.unwrap();
}
