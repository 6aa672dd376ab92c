//! End-to-end runtime: real env_server processes, the real actor-learner loop.

use std::path::Path;

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::report::pareto::hypervolume;
use agent::runtime::train::{TrainOptions, train};
use agent::sweep::SweepConfig;
use integration_tests::smoke_config;

/// The two settings train as one population (one batched learner, one env session)
/// and still get a run folder each.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sweep_on_a_two_point_grid_writes_csv_hypervolume_and_plots() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
    let runs_dir = dir.path().join("runs");
    let base_text = std::fs::read_to_string(&smoke)
        .unwrap()
        .replace("[run]\n", &format!("[run]\nruns_dir = {runs_dir:?}\n"));
    std::fs::write(dir.path().join("base.toml"), base_text).unwrap();
    let sweep_path = dir.path().join("sweep.toml");
    std::fs::write(
        &sweep_path,
        r#"
name = "two-point"
base = "base.toml"
parallel = 2
population = 2
total_env_steps = 1500
reference_point = { time = -25.0, treasure = 0.0 }
[grid]
kind = "epsilon"
product = { time = [0.01], treasure = [0.01, 1.0] }
[ratio_plot]
numerator = "treasure"
denominator = "time"
y_objective = "treasure"
"#,
    )
    .unwrap();
    let (sweep_cfg, base) = SweepConfig::load(&sweep_path).unwrap();
    let s = integration_tests::run_sweep(&sweep_cfg, &base, &server).await;
    assert_eq!(s.points.len(), 2);
    // Each member has its own run, and the population stepped them in lockstep.
    let learner_steps: Vec<u64> = s
        .points
        .iter()
        .map(|p| {
            let text = std::fs::read_to_string(p.run_dir.join("summary.json")).unwrap();
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            assert!(p.run_dir.join("learner.jsonl").exists());
            v["learner_steps"].as_u64().unwrap()
        })
        .collect();
    assert_ne!(s.points[0].run_dir, s.points[1].run_dir);
    assert!(
        learner_steps[0] > 0 && learner_steps[0] == learner_steps[1],
        "{learner_steps:?}"
    );
    let returns: Vec<Vec<f64>> = s.points.iter().map(|p| p.eval_return.clone()).collect();
    assert_eq!(s.hypervolume, hypervolume(&returns, &[-25.0, 0.0]));
    let csv = std::fs::read_to_string(s.dir.join("points.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "header + 2 points:\n{csv}");
    assert!(
        csv.lines()
            .next()
            .unwrap()
            .starts_with("setting_time,setting_treasure,seed,return_time,return_treasure")
    );
    for file in [
        "front.csv",
        "summary.json",
        "front.png",
        "front.svg",
        "ratio.png",
        "ratio.svg",
    ] {
        assert!(s.dir.join(file).exists(), "{file} missing");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s.dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["hypervolume"].as_f64().unwrap(), s.hypervolume);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_restart_during_training_costs_a_reconnect_not_the_run() {
    let first = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let port = first.port();
    let address = first.address().to_string();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = smoke_config(runs.path());
    cfg.run.total_env_steps = 6000;
    let run = tokio::spawn(async move { train(cfg, &[address], TrainOptions::default()).await });
    // Let training get going, then crash the server and bring it back on the same port.
    let runs_path = runs.path().to_path_buf();
    tokio::time::timeout(std::time::Duration::from_secs(120), async {
        loop {
            let lines = std::fs::read_dir(&runs_path)
                .ok()
                .and_then(|mut d| d.next())
                .and_then(|e| std::fs::read_to_string(e.ok()?.path().join("episodes.csv")).ok())
                .map_or(0, |t| t.lines().count());
            if lines > 200 {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        }
    })
    .await
    .expect("training makes progress");
    first.kill().await.unwrap();
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let second = LocalServer::start(&ServerOptions {
        port,
        ..ServerOptions::default()
    })
    .await
    .unwrap();
    let summary = run.await.unwrap().expect("the run survives the restart");
    assert_eq!(summary.env_steps, 6000);
    second.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn time_to_solve_matches_episodes_csv_and_stop_on_solve_ends_the_run_there() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = smoke_config(runs.path());
    // Every DST episode lasts at most 200 steps, so time >= -200 holds for any policy:
    // the run counts as solved when its 10th episode ends, whatever was learned.
    cfg.run.solve_threshold = [("time".to_string(), -200.0)].into();
    cfg.run.stop_on_solve = true;
    let s = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .unwrap();
    let solved = s.solved.clone().expect("solved at the 10th episode");
    let text = std::fs::read_to_string(s.run_dir.join("episodes.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header.last(), Some(&"wall_seconds"));
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.parse().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    assert!(rows.len() >= 10, "{} episodes", rows.len());
    let tenth = &rows[9];
    assert_eq!(solved.episodes, 10);
    assert_eq!(solved.env_steps as f64, tenth[col("env_steps")]);
    for (k, name) in ["return_time", "return_treasure"].iter().enumerate() {
        let mean = rows[..10].iter().map(|r| r[col(name)]).sum::<f64>() / 10.0;
        assert!(
            (solved.running_mean[k] - mean).abs() < 1e-9,
            "{name}: {} vs {mean}",
            solved.running_mean[k]
        );
    }
    // Both stamps are seconds since train started, taken moments apart.
    let stamped = tenth[col("wall_seconds")];
    assert!(
        solved.wall_seconds >= stamped - 1e-3 && solved.wall_seconds < stamped + 1.0,
        "{} vs {stamped}",
        solved.wall_seconds
    );
    // stop_on_solve: no env step after the batch that solved it (budget: 8000).
    assert_eq!(s.env_steps, solved.env_steps);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s.run_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(
        summary["solved"]["env_steps"].as_u64(),
        Some(solved.env_steps)
    );
    assert_eq!(summary["solve_threshold"]["time"].as_f64(), Some(-200.0));
    server.stop().await.unwrap();
}
