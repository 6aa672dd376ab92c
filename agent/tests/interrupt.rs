//! SIGTERM, then Ctrl-C (SIGINT), during `agent train`, then `--resume` to the end:
//! every stop still leaves a report (summary marked interrupted, curves, TensorBoard
//! events that TensorBoard's own reader accepts), and the run finishes where an
//! uninterrupted one would. Runs the real CLI binary against a real env_server.

mod cli;

use std::path::{Path, PathBuf};
use std::process::Child;
use std::time::{Duration, Instant};

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::checkpoint::run::latest_checkpoint;
use cli::{agent_cmd, run_dir_in, smoke_dst, summary, tensorboard_scalars};

/// Wait until the run in `runs` has a checkpoint past `learner_steps`, then send `signal`.
fn signal_after(child: &mut Child, runs: &Path, learner_steps: u64, signal: i32) -> PathBuf {
    let started = Instant::now();
    let run = loop {
        assert!(
            started.elapsed() < Duration::from_secs(180),
            "no checkpoint past {learner_steps} learner steps within 180 s"
        );
        if let Some(run) = run_dir_in(runs)
            && let Ok((_, progress)) = latest_checkpoint(&run)
            && progress.learner_steps >= learner_steps
        {
            break run;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let pid = i32::try_from(child.id()).unwrap();
    // SAFETY: kill(2) on our own child's pid, with a valid signal number.
    assert_eq!(unsafe { libc::kill(pid, signal) }, 0);
    run
}

/// learner.jsonl's phases of each logged step: the policy evaluation, E-step and
/// M-step took time, and together with the sampling and the target update they fit in
/// the step's `step_ms` (all are read off one clock within the step). No learning
/// threshold: it compares one clock's readings, whatever the trajectory. This test
/// reads no test seed (the smoke config's seed 0). Held for seeds 1-5: with the seed
/// in configs/smoke/dst.toml set to each, the whole test passed once (9.6-10.4 s).
fn assert_phases_add_up(run: &Path) {
    let text = std::fs::read_to_string(run.join("learner.jsonl")).unwrap();
    for line in text.lines() {
        let row: serde_json::Value = serde_json::from_str(line).unwrap();
        let ms = |key: &str| {
            row["phases"][key]
                .as_f64()
                .unwrap_or_else(|| panic!("{key}: {row}"))
        };
        for key in ["policy_evaluation_ms", "e_step_ms", "m_step_ms"] {
            assert!(ms(key) > 0.0, "{key}: {row}");
        }
        let keys = [
            "sample_ms",
            "policy_evaluation_ms",
            "e_step_ms",
            "m_step_ms",
            "target_update_ms",
        ];
        assert!(keys.iter().all(|k| ms(k) >= 0.0), "{row}");
        let total: f64 = keys.iter().map(|k| ms(k)).sum();
        let step_ms = row["step_ms"].as_f64().unwrap();
        assert!(
            total <= step_ms * (1.0 + 1e-9),
            "phases {total} ms > step {step_ms} ms: {row}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interrupted_run_still_reports_and_resumes_to_the_end() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (runs, config) = smoke_dst(dir.path());
    let address = server.address().to_string();

    // 1. SIGTERM (what a scheduler or `kill` sends).
    let mut child = agent_cmd(&["train", "--config", config.to_str().unwrap()])
        .args(["--server", &address])
        .spawn()
        .unwrap();
    let run = signal_after(&mut child, &runs, 100, libc::SIGTERM);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{status:?}");
    let first = summary(&run);
    assert_eq!(first["interrupted"], "SIGTERM");
    assert_eq!(first["eval_episodes"].as_array().unwrap().len(), 0);
    let stopped_at = first["env_steps"].as_u64().unwrap();
    assert!(
        stopped_at > 0 && stopped_at < 8000,
        "stopped at {stopped_at}"
    );
    assert!(run.join("curves.png").exists() && run.join("curves.svg").exists());
    let scalars = tensorboard_scalars(&run);
    for tag in [
        "train/return/treasure",
        "train/return/time",
        "learner/temperature/treasure",
        "learner/alpha/0",
        "learner/phase_ms/m_step",
        "throughput/env_steps_per_second",
    ] {
        assert!(
            scalars.get(tag).is_some_and(|v| !v.is_empty()),
            "{tag} missing from {:?}",
            scalars.keys()
        );
    }
    assert_phases_add_up(&run);
    // Every chart is by env step, and no training episode is stamped past the stop.
    assert!(
        scalars["train/return/treasure"]
            .iter()
            .all(|(step, _)| *step <= stopped_at)
    );
    assert!(!scalars.contains_key("eval/return/treasure"));

    // 2. Ctrl-C (SIGINT) on the resumed run.
    let mut child = agent_cmd(&["train", "--resume", run.to_str().unwrap()])
        .args(["--server", &address])
        .spawn()
        .unwrap();
    let (_, before) = latest_checkpoint(&run).unwrap();
    signal_after(&mut child, &runs, before.learner_steps + 100, libc::SIGINT);
    assert_eq!(child.wait().unwrap().code(), Some(130));
    let second = summary(&run);
    assert_eq!(second["interrupted"], "Ctrl-C");
    assert!(second["env_steps"].as_u64().unwrap() > stopped_at);

    // 3. Resume to the budget: the summary is complete and evaluation reaches TensorBoard.
    let status = agent_cmd(&["train", "--resume", run.to_str().unwrap()])
        .args(["--server", &address])
        .status()
        .unwrap();
    assert!(status.success());
    let last = summary(&run);
    assert!(last["interrupted"].is_null());
    assert_eq!(last["env_steps"].as_u64().unwrap(), 8000);
    assert_eq!(last["eval_episodes"].as_array().unwrap().len(), 2);
    let scalars = tensorboard_scalars(&run);
    let eval = &scalars["eval/return/treasure"];
    assert_eq!(eval.len(), 1);
    assert_eq!(eval[0].0, 8000);
    let expected = last["eval_return"][1].as_f64().unwrap();
    assert!(
        (eval[0].1 - expected).abs() <= 1e-4 * expected.abs().max(1.0),
        "{} vs {expected}",
        eval[0].1
    );
    // Three processes wrote event files; TensorBoard reads them as one run whose
    // training-return steps only grow (each resume supersedes the stale tail).
    let files = std::fs::read_dir(&run)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("events.out.tfevents.")
        })
        .count();
    assert_eq!(files, 3);
    let steps: Vec<u64> = scalars["train/return/treasure"]
        .iter()
        .map(|(s, _)| *s)
        .collect();
    assert!(steps.windows(2).all(|w| w[0] <= w[1]), "{steps:?}");
    assert!(*steps.last().unwrap() <= 8000);
    server.stop().await.unwrap();
}
