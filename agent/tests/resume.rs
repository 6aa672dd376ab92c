//! kill -9 during `agent train`, then `--resume`: the run continues from its last
//! checkpoint with its step counters, duals and optimizer state; nothing is lost.
//! Runs the real CLI binary against a real env_server.

mod cli;

use std::time::{Duration, Instant};

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::learner::latest_checkpoint;
use cli::{agent_cmd, run_dir_in, smoke_dst};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_then_resume_continues_from_the_last_checkpoint() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (runs, config) = smoke_dst(dir.path());

    let mut child = agent_cmd(&[
        "train",
        "--config",
        config.to_str().unwrap(),
        "--server",
        server.address(),
    ])
    .spawn()
    .unwrap();
    // Wait for the second checkpoint (learner step 200), then kill -9.
    let started = Instant::now();
    let run_dir = loop {
        assert!(
            started.elapsed() < Duration::from_secs(180),
            "no checkpoint within 180 s"
        );
        if let Some(run) = run_dir_in(&runs)
            && let Ok((_, progress)) = latest_checkpoint(&run)
            && progress.learner_steps >= 200
        {
            break run;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let (ckpt, before) =
        latest_checkpoint(&run_dir).expect("a complete checkpoint survives kill -9");
    assert!(
        ckpt.join("params.safetensors").exists() && ckpt.join("optimizer.safetensors").exists()
    );
    let episodes_before = std::fs::read_to_string(run_dir.join("episodes.csv"))
        .unwrap()
        .lines()
        .count();

    let status = agent_cmd(&[
        "train",
        "--resume",
        run_dir.to_str().unwrap(),
        "--server",
        server.address(),
    ])
    .status()
    .unwrap();
    assert!(status.success());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["env_steps"].as_u64().unwrap(), 8000);
    // The learner's own step counter (restored from the checkpoint) ends where the
    // schedule says: (8000 - 500 warm-up) * 0.25 = 1875. A learner rebuilt from
    // scratch would count only the steps after the resume.
    let (_, after) = latest_checkpoint(&run_dir).unwrap();
    assert_eq!(after.learner_steps, 1875);
    assert!(after.env_steps == 8000 && after.episodes > before.episodes);
    // The env-step counter continued too: the first episode logged after the
    // resume is stamped beyond the checkpoint's env steps.
    let text = std::fs::read_to_string(run_dir.join("episodes.csv")).unwrap();
    let stamps: Vec<u64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    let first_resumed = stamps[episodes_before - 1..]
        .iter()
        .copied()
        .next()
        .unwrap();
    assert!(
        first_resumed > before.env_steps,
        "{first_resumed} <= {}",
        before.env_steps
    );
    // Episodes logged before the kill are still there; more were appended.
    let episodes_after = std::fs::read_to_string(run_dir.join("episodes.csv"))
        .unwrap()
        .lines()
        .count();
    assert!(episodes_after > episodes_before);
    server.stop().await.unwrap();
}
