//! `--resume` continues a run: after kill -9 it reaches its budget with exact counters,
//! every log row once (learner.jsonl, episodes.csv, TensorBoard) and wall times that
//! go on from the checkpoint's; resuming one checkpoint twice gives the same
//! learner.jsonl; a checkpoint without replay resumes without a catch-up burst;
//! `--set` of a field a running run may not change is refused. Runs the real CLI
//! binary against a real env_server.
//!
//! A resumed run matches the uninterrupted one only up to its actor's first env step:
//! env sessions cannot be saved, so a resume starts new episodes (seeded from the act
//! counter) and the two runs see different transitions from there on (resume.rs).
//! The kill test compares the learner steps in between.

mod cli;

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::checkpoint::run::latest_checkpoint;
use cli::{
    agent_cmd, copy_dir, episode_rows, learner_rows, learner_steps, run_dir_in, smoke_dst, summary,
    tensorboard_scalars,
};

fn resume(run: &Path, server: &str, extra: &[&str]) {
    let status = agent_cmd(&["train", "--resume", run.to_str().unwrap()])
        .args(["--server", server])
        .args(extra)
        .status()
        .unwrap();
    assert!(status.success(), "{status:?}");
}

/// learner.jsonl's `wall_seconds` column.
fn learner_walls(run: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(run.join("learner.jsonl")).unwrap();
    text.lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["wall_seconds"]
                .as_f64()
                .unwrap()
        })
        .collect()
}

/// The learner steps logged every 20 up to `last`: each exactly once, in order.
fn every_log_step(last: u64) -> Vec<u64> {
    (1..=last / 20).map(|i| i * 20).collect()
}

/// The kill test's schedule: 2 learner steps per env step and 8 envs make bursts of
/// 16 learner steps between two actor steps (ending at steps 8 + 16 k), and a
/// checkpoint every 96 steps falls in the middle of one, so the 8 steps from the
/// checkpoint to the burst's end see the same replay with and without the kill.
const KILL_RUN: [&str; 8] = [
    "--total-env-steps",
    "1504",
    "--set",
    "run.learner_steps_per_env_step=2.0",
    "--set",
    "run.log_period=1",
    "--set",
    "run.checkpoint_period=96",
];
/// (1504 - 500 warm-up) * 2.
const KILL_RUN_LEARNER_STEPS: u64 = 2008;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_then_resume_reaches_the_budget_with_every_row_once() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (runs, config) = smoke_dst(dir.path());
    let train = |runs: &Path| {
        let mut cmd = agent_cmd(&["train", "--config", config.to_str().unwrap()]);
        cmd.args(["--server", server.address()])
            .args(KILL_RUN)
            .args(["--set", &format!("run.runs_dir={runs:?}")]);
        cmd
    };
    let whole_runs = dir.path().join("uninterrupted");
    assert!(train(&whole_runs).status().unwrap().success());
    let whole = learner_rows(&run_dir_in(&whole_runs).unwrap());

    let mut child = train(&runs).spawn().unwrap();
    // Kill once the run has logged past a checkpoint: the rows after it are what a
    // resume must not duplicate.
    let started = Instant::now();
    let run = loop {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no checkpoint in 60 s"
        );
        if let Some(run) = run_dir_in(&runs)
            && let Ok((_, progress)) = latest_checkpoint(&run)
            && progress.learner_steps >= 96
            && learner_steps(&run).last() > Some(&progress.learner_steps)
        {
            break run;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let (ckpt, before) = latest_checkpoint(&run).expect("a complete checkpoint survives kill -9");
    let written = std::fs::metadata(run.join("learner.jsonl")).unwrap().len();
    assert!(
        written > before.logs.learner_jsonl,
        "rows past the checkpoint {} exist before the resume",
        ckpt.display()
    );
    let replay = before
        .replay
        .clone()
        .expect("the checkpoint holds the replay");
    assert!(replay.inserted > 0 && run.join("replay").read_dir().unwrap().count() > 0);

    resume(&run, server.address(), &[]);
    let last = summary(&run);
    assert_eq!(last["env_steps"].as_u64().unwrap(), 1504);
    let (_, after) = latest_checkpoint(&run).unwrap();
    assert_eq!(after.learner_steps, KILL_RUN_LEARNER_STEPS);
    // Every log row once: learner.jsonl every step, TensorBoard's learner-step chart
    // likewise, and one episodes.csv row per counted episode.
    let all: Vec<u64> = (1..=KILL_RUN_LEARNER_STEPS).collect();
    assert_eq!(learner_steps(&run), all);
    let scalars = tensorboard_scalars(&run);
    let charted: Vec<u64> = scalars["learner/learner_steps"]
        .iter()
        .map(|(_, v)| *v as u64)
        .collect();
    assert_eq!(charted, all);
    let episodes = episode_rows(&run);
    assert_eq!(episodes.len() as u64, last["episodes"].as_u64().unwrap());
    assert_eq!(episodes.len() as u64, after.episodes);
    assert_eq!(
        scalars["train/return/treasure"].len(),
        episodes.len(),
        "one TensorBoard return per episode row"
    );
    let stamps: Vec<u64> = episodes
        .iter()
        .map(|r| r.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert!(stamps.windows(2).all(|w| w[0] <= w[1]), "{stamps:?}");
    // The run's clock goes on from the checkpoint's: every row after it, and the
    // summary, count the first invocation's training time too. Not a threshold on
    // learning: the run's clock is compared with itself, so no trajectory can pass or
    // fail it; run five times (the kill lands at a different moment each time), it held,
    // and once each with seeds 1-5 (`--set seed=S` added to KILL_RUN), it held too.
    let walls = learner_walls(&run);
    let at = before.learner_steps as usize;
    assert!(before.wall_seconds > 0.0, "{before:?}");
    assert!(
        walls[at..].iter().all(|&w| w >= before.wall_seconds),
        "wall_seconds after the checkpoint's {}: {:?}",
        before.wall_seconds,
        &walls[at..]
    );
    assert!(walls.windows(2).all(|w| w[0] <= w[1]), "{walls:?}");
    assert!(last["wall_seconds"].as_f64().unwrap() >= walls[walls.len() - 1]);

    // Up to the checkpoint the run is the uninterrupted one; after it, the learner
    // steps up to the burst's end are too (same learner, replay, sampler position and
    // noise counters); from the next actor step on, the resumed run's new env
    // sessions make the data differ.
    let resumed = learner_rows(&run);
    let env_at = whole[at - 1]["env_steps"].as_u64().unwrap();
    let burst_end = whole
        .iter()
        .take_while(|r| r["env_steps"].as_u64().unwrap() <= env_at)
        .count();
    assert!(
        burst_end > at,
        "checkpoint {at} at a burst's end: nothing to compare"
    );
    if let Some(i) = (0..burst_end).find(|&i| resumed[i] != whole[i]) {
        panic!(
            "learner step {} after the resume at {at} (burst to {burst_end}): {} vs uninterrupted {}",
            i + 1,
            resumed[i],
            whole[i]
        );
    }
    assert_ne!(resumed, whole, "new env sessions after the resume");
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resuming_one_checkpoint_twice_logs_the_same_rows() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (runs, config) = smoke_dst(dir.path());
    let status = agent_cmd(&["train", "--config", config.to_str().unwrap()])
        .args(["--server", server.address(), "--total-env-steps", "2000"])
        .status()
        .unwrap();
    assert!(status.success());
    let run = run_dir_in(&runs).unwrap();
    let copies: Vec<PathBuf> = ["a", "b"].iter().map(|n| dir.path().join(n)).collect();
    for copy in &copies {
        copy_dir(&run, copy);
        // A longer budget is one of the changes a resume may make.
        resume(
            copy,
            server.address(),
            &["--set", "run.total_env_steps=3000"],
        );
    }
    let (a, b) = (learner_rows(&copies[0]), learner_rows(&copies[1]));
    // (3000 - 500) * 0.25 learner steps, logged every 20.
    assert_eq!(a.len(), every_log_step(625).len());
    assert_eq!(a, b, "learner.jsonl differs between two resumes");
    assert_eq!(episode_rows(&copies[0]), episode_rows(&copies[1]));
    assert_eq!(summary(&copies[0])["env_steps"].as_u64().unwrap(), 3000);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_resume_without_replay_refills_and_takes_no_catch_up_burst() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (runs, config) = smoke_dst(dir.path());
    let status = agent_cmd(&["train", "--config", config.to_str().unwrap()])
        .args(["--server", server.address(), "--total-env-steps", "2000"])
        .args(["--set", "run.checkpoint_replay=false"])
        .status()
        .unwrap();
    assert!(status.success());
    let run = run_dir_in(&runs).unwrap();
    let (_, before) = latest_checkpoint(&run).unwrap();
    assert!(before.replay.is_none() && !run.join("replay").exists());
    // (2000 - 500) * 0.25.
    assert_eq!(before.learner_steps, 375);
    resume(&run, server.address(), &["--total-env-steps", "3000"]);
    // From the resume the pace counts afresh: 500 transitions to refill, then 0.25
    // learner steps per env step: 375 + (3000 - 2000 - 500) * 0.25 = 500, where
    // counting from zero would allow (3000 - 500) * 0.25 = 625, 125 of them at once.
    let (_, after) = latest_checkpoint(&run).unwrap();
    assert_eq!(after.learner_steps, 500);
    for row in learner_rows(&run) {
        let step = row["learner_step"].as_u64().unwrap();
        let env_steps = row["env_steps"].as_u64().unwrap();
        if step > 375 {
            let allowed = 375 + (env_steps.saturating_sub(2500) as f64 * 0.25) as u64;
            assert!(step <= allowed, "step {step} at {env_steps} env steps");
        }
    }
    server.stop().await.unwrap();
}

#[test]
fn set_with_resume_refuses_a_field_a_running_run_may_not_change() {
    let dir = tempfile::tempdir().unwrap();
    let (_, config) = smoke_dst(dir.path());
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::copy(&config, run.join("config.toml")).unwrap();
    let out = agent_cmd(&["train", "--resume", run.to_str().unwrap()])
        .args(["--set", "run.total_env_steps=9000"])
        .args(["--set", "learner.mpo.batch_size=32"])
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(
            "learner.mpo.batch_size must be unchanged when resuming: the run has 64 \
             (a resumed run may change only run.total_env_steps"
        ) && stderr.contains(", got 32"),
        "{stderr}"
    );
}
