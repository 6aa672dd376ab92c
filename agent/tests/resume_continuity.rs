//! The pendulum preset SIGKILLed five times at random moments and resumed each time
//! learns as an uninterrupted run does (issue 23, "Continuity").
//!
//! One run of `configs/mompo/pendulum.toml` is killed five times and resumed with
//! `agent train --resume`; three uninterrupted runs of the same preset (seeds s, s + 1,
//! s + 2, the killed run's seed s = 0 unless `MO_MPO_TEST_SEED` says otherwise) run
//! beside it, at the same time. The killed run must:
//! - reach the budget with the counters of its uninterrupted twin (seed 0): same env
//!   steps, same learner steps;
//! - log every learner.jsonl row once (steps 100, 200, ... in order) and one
//!   episodes.csv row per counted episode;
//! - train on after each resume: the median task return of the first 10 episodes
//!   after it is not below the range of the last 10 before it. A resume that lost its
//!   replay or reset its networks falls back to about -1200, below any range of a
//!   learning run. Above the range is allowed: early in the run the policy improves
//!   that fast (measured: -1409 to -254 before the first resume, -243 after it). The
//!   median, not the mean: the preset's stochastic policy fails a swing-up now and then
//!   however long it has trained (-1349 among -120s in the killed run, -926 at episode
//!   17 of seed 1's uninterrupted run), and one such episode moves a mean of ten by 120;
//! - solve the task (the preset's `run.solve_threshold`, tracked across resumes) no
//!   later than twice the slowest uninterrupted run;
//! - end as the uninterrupted runs end: its final deterministic evaluation (8
//!   episodes) is no worse than the worst of theirs by more than 20% of that one's
//!   magnitude (the benchmarks' stability margin, docs/benchmarks/mujoco.md). Seeds
//!   end at different returns (-126 to -219 at 14k env steps over seeds 0-7, below), so
//!   the bar is theirs rather than a fixed one; a resume that lost its replay or
//!   networks, or a policy that fell back, ends near -1200. This needs a preset that
//!   holds what it learns (its trust region, docs/stability.md); before it did, the
//!   killed run ended at -1577 against the seeds' -136 to -182.
//!
//! "Random moments": after each (re)start, once the run's latest checkpoint holds 10
//! episodes more than the resume began with, the test waits for 0 to 3 more checkpoints
//! (drawn from a fixed ChaCha stream) and kills as soon as the last one is written.
//! Where in a checkpoint period the kill lands does not matter to a resume (it restarts
//! from the checkpoint, truncating what came after), so choosing the checkpoint is
//! choosing the moment; and because a resume from a given checkpoint is deterministic
//! (resume.rs), the whole killed run repeats on every invocation. Episodes in flight at
//! the kill are lost (env sessions cannot be saved), so the killed run counts fewer
//! episodes than its twin; its env and learner steps are exact.

mod cli;
mod seed;

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::checkpoint::run::{RunProgress, latest_checkpoint};
use cli::{agent_cmd, episode_rows, learner_steps, run_dir_in, summary};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use seed::{report_figures, test_seed};

const BUDGET: &str = "14000";
const KILLS: usize = 5;
/// Episodes each (re)start must checkpoint before its kill: the window the return
/// comparison reads on each side of a resume.
const WINDOW: usize = 10;
/// Learner steps between checkpoints (the preset: 2,000): about one episode's worth.
const CHECKPOINT_PERIOD: u64 = 100;

fn preset() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/mompo/pendulum.toml")
}

/// `agent train` of the preset with `seed` under `runs`.
fn train(server: &str, runs: &Path, seed: u64) -> Command {
    let mut cmd = agent_cmd(&["train", "--config", preset().to_str().unwrap()]);
    cmd.args(["--server", server, "--total-env-steps", BUDGET])
        .args(["--set", &format!("seed={seed}")])
        .args(["--set", &format!("run.runs_dir={runs:?}")])
        .args([
            "--set",
            &format!("run.checkpoint_period={CHECKPOINT_PERIOD}"),
        ]);
    cmd
}

/// The task return of every episodes.csv row, in order.
fn task_returns(run: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(run.join("episodes.csv")).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let column = header.iter().position(|h| *h == "return_task").unwrap();
    episode_rows(run)
        .iter()
        .map(|r| r.split(',').nth(column).unwrap().parse().unwrap())
        .collect()
}

/// Waits until `run`'s latest checkpoint satisfies `ready`; returns its progress.
fn wait_for_checkpoint(
    child: &mut Child,
    run: &Path,
    what: &str,
    ready: impl Fn(&RunProgress) -> bool,
) -> RunProgress {
    let started = Instant::now();
    loop {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before a checkpoint with {what}"
        );
        assert!(
            started.elapsed() < Duration::from_secs(300),
            "no checkpoint with {what} in 300 s"
        );
        if let Ok((_, progress)) = latest_checkpoint(run)
            && ready(&progress)
        {
            return progress;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn median(xs: &[f64]) -> f64 {
    let mut sorted = xs.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    (sorted[(n - 1) / 2] + sorted[n / 2]) / 2.0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pendulum_run_killed_five_times_learns_as_an_uninterrupted_one() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let address = server.address().to_string();
    let dir = tempfile::tempdir().unwrap();
    // The uninterrupted runs, all at once beside the killed one.
    let seed = test_seed();
    let reference_runs: Vec<PathBuf> = (0..3)
        .map(|i| dir.path().join(format!("uninterrupted-{i}")))
        .collect();
    let mut reference_children: Vec<Child> = reference_runs
        .iter()
        .zip(seed..)
        .map(|(runs, seed)| train(&address, runs, seed).spawn().unwrap())
        .collect();

    let runs = dir.path().join("killed");
    let mut moments = ChaCha8Rng::seed_from_u64(23);
    let mut child = train(&address, &runs, seed).spawn().unwrap();
    let started = Instant::now();
    let run = loop {
        if let Some(run) = run_dir_in(&runs) {
            break run;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "no run dir");
        std::thread::sleep(Duration::from_millis(20));
    };
    // The episode count each resume began from (the rows kept from before it).
    let mut resumed_at: Vec<usize> = Vec::new();
    for _ in 0..KILLS {
        let from = resumed_at.last().copied().unwrap_or(0) as u64;
        let window = wait_for_checkpoint(&mut child, &run, "the window's episodes", |p| {
            p.episodes >= from + WINDOW as u64
        });
        let at = window.learner_steps + CHECKPOINT_PERIOD * moments.random_range(0..=3);
        wait_for_checkpoint(&mut child, &run, &format!("learner step {at}"), |p| {
            p.learner_steps >= at
        });
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        let (_, progress) = latest_checkpoint(&run).expect("a checkpoint survives kill -9");
        resumed_at.push(progress.episodes as usize);
        child = agent_cmd(&["train", "--resume", run.to_str().unwrap()])
            .args(["--server", &address])
            .spawn()
            .unwrap();
    }
    assert!(child.wait().unwrap().success(), "the last resume finishes");
    let references: Vec<serde_json::Value> = reference_children
        .iter_mut()
        .zip(&reference_runs)
        .map(|(child, runs)| {
            assert!(child.wait().unwrap().success());
            summary(&run_dir_in(runs).unwrap())
        })
        .collect();
    server.stop().await.unwrap();

    // Exact counters: those of the uninterrupted twin.
    let last = summary(&run);
    let twin = &references[0];
    for counter in ["env_steps", "learner_steps"] {
        assert_eq!(last[counter], twin[counter], "{counter}");
    }
    // Every row once.
    let logged = learner_steps(&run);
    let every: Vec<u64> = (1..=logged.len() as u64).map(|i| i * 100).collect();
    assert_eq!(logged, every, "learner.jsonl rows");
    assert_eq!(
        *logged.last().unwrap(),
        last["learner_steps"].as_u64().unwrap() / 100 * 100
    );
    let returns = task_returns(&run);
    assert_eq!(returns.len() as u64, last["episodes"].as_u64().unwrap());

    // Learning goes on across each resume. This bar and the two below held for seeds
    // 1-5 (and 0; MO_MPO_TEST_SEED, scripts/learning_seeds.sh); the solves and finals
    // they compare are recorded at the last assert.
    for &at in &resumed_at {
        assert!(
            at >= WINDOW && at + WINDOW <= returns.len(),
            "{resumed_at:?}"
        );
        let before = &returns[at - WINDOW..at];
        let after = median(&returns[at..at + WINDOW]);
        let low = before.iter().copied().fold(f64::MAX, f64::min);
        assert!(
            after >= low,
            "resume at episode {at}: first {WINDOW} episodes after it have median {after:.1}, \
             below the last {WINDOW} before it {before:.1?} (resumes at {resumed_at:?})"
        );
    }

    // Solved as the uninterrupted runs are (the preset's run.solve_threshold: the mean
    // task return of 10 training episodes reaches -200, tracked across resumes), and
    // no later than twice the slowest of them.
    let solved_at = |s: &serde_json::Value| s["solved"]["env_steps"].as_u64();
    let reference_solves: Vec<u64> = references
        .iter()
        .map(|r| solved_at(r).expect("every uninterrupted run solves"))
        .collect();
    let slowest = reference_solves.iter().copied().max().unwrap_or(0);
    let killed = solved_at(&last);
    // Ends as they end: the killed run's final deterministic evaluation within 20% of
    // the worst uninterrupted run's magnitude below it.
    let final_task = |s: &serde_json::Value| s["eval_return"][0].as_f64().unwrap();
    let reference_finals: Vec<f64> = references.iter().map(final_task).collect();
    let worst = reference_finals
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let bar = worst - 0.2 * worst.abs();
    report_figures(
        "resume_continuity",
        &format!(
            "killed: solved at {killed:?}, final {:.1}; uninterrupted: solved at \
             {reference_solves:?}, final {reference_finals:.1?}",
            final_task(&last)
        ),
    );
    assert!(
        killed.is_some_and(|k| k <= 2 * slowest),
        "killed run solved at {killed:?} env steps, uninterrupted runs at {reference_solves:?}"
    );
    // Held for seeds 1-5 (and 0; MO_MPO_TEST_SEED, scripts/learning_seeds.sh). Per base
    // seed s, the killed run's solve / final against the uninterrupted runs' solves and
    // finals (seeds s, s + 1, s + 2):
    // 0: 8,200 / -153.7 against 4,800 5,600 7,200 / -151.8 -140.8 -166.1;
    // 1: 5,600 / -140.8 against 5,600 7,200 5,200 / -140.8 -166.1 -181.3;
    // 2: 7,800 / -166.7 against 7,200 5,200 5,600 / -166.1 -181.3 -206.4;
    // 3: 7,000 / -186.0 against 5,200 5,600 5,600 / -181.3 -206.4 -218.6;
    // 4: 5,200 / -205.9 against 5,600 5,600 5,600 / -206.4 -218.6 -184.3;
    // 5: 6,400 / -217.8 against 5,600 5,600 4,800 / -218.6 -184.3 -125.7.
    // (175-214 s per seed while other runs shared the machine.) Those ran on an AMD
    // EPYC; on an Intel Xeon (2026-12-07, 112-125 s per seed, alone) the pendulum runs
    // take other paths, and every bar held for seeds 0-5 again (MO_MPO_TEST_SEED,
    // scripts/learning_seeds.sh "0 1 2 3 4 5" resume_continuity):
    // 0: 11,200 / -152.5 against 4,800 5,600 8,000 / -153.8 -140.5 -166.3;
    // 1: 6,400 / -139.3 against 5,600 8,000 5,200 / -140.5 -166.3 -181.4;
    // 2: 7,400 / -170.5 against 8,000 5,200 5,200 / -166.3 -181.4 -206.2;
    // 3: 7,000 / -187.6 against 5,200 5,200 5,600 / -181.4 -206.2 -219.0;
    // 4: 5,200 / -204.5 against 5,200 5,600 5,600 / -206.2 -219.0 -185.3;
    // 5: 6,400 / -217.9 against 5,600 5,600 4,800 / -219.0 -185.3 -124.7.
    assert!(
        final_task(&last) >= bar,
        "the killed run ended at {:.1}, below {bar:.1} (uninterrupted: {reference_finals:.1?})",
        final_task(&last)
    );
}
