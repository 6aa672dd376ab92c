//! The README's main job as a user runs it: `configs/sweeps/dst-quick.toml` against a
//! real local env_server, trained as populations (issue 22: "the DST quick sweep
//! reaches its treasures through the population path").

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::sweep::SweepConfig;

/// Deep Sea Treasure's ten treasures (env_server/env_server/envs/dst.py).
const TREASURES: [f64; 10] = [0.7, 8.2, 11.5, 14.0, 15.1, 16.1, 19.6, 20.3, 22.4, 23.7];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_quick_sweep_reaches_nine_treasures_as_populations() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/sweeps/dst-quick.toml");
    let (sweep_cfg, mut base) = SweepConfig::load(&path).unwrap();
    base.run.runs_dir = dir.path().join("runs");
    // The file itself: nine settings in populations, none capped to single runs.
    assert_eq!(sweep_cfg.parallel, 2);
    assert_ne!(sweep_cfg.population, Some(1));
    let s = integration_tests::run_sweep(&sweep_cfg, &base, &server).await;
    server.stop().await.unwrap();
    assert_eq!(s.points.len(), 9);
    // Every run takes all the learner steps its env steps allow (the pace's formula,
    // schedule/mod.rs), its last ones included: actors that step their envs while the
    // learner trains must not end a run before it has caught up.
    let r = &base.run;
    let allowed = ((r.total_env_steps - r.min_replay_transitions as u64) as f64
        * r.learner_steps_per_env_step)
        .floor() as u64;
    for p in &s.points {
        let text = std::fs::read_to_string(p.run_dir.join("summary.json")).unwrap();
        let summary: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(summary["env_steps"].as_u64(), Some(r.total_env_steps));
        assert_eq!(
            summary["learner_steps"].as_u64(),
            Some(allowed),
            "{:?}",
            p.run_dir
        );
    }
    // The treasure each deterministic policy collects (return index 1), matched to
    // the env's list; a policy that loops collects none.
    let mut reached: Vec<f64> = s
        .points
        .iter()
        .filter_map(|p| {
            TREASURES
                .iter()
                .copied()
                .find(|t| (p.eval_return[1] - t).abs() < 1e-3)
        })
        .collect();
    reached.sort_by(f64::total_cmp);
    reached.dedup();
    // Issue 22's bar for the main job: nine of the ten treasures, HV >= 390 of 401.8.
    assert!(reached.len() >= 9, "treasures reached: {reached:?}");
    assert!(s.hypervolume >= 390.0, "hypervolume {}", s.hypervolume);
}
