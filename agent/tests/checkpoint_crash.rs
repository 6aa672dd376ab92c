//! A kill -9 in the middle of writing a checkpoint never leaves a broken latest one.
//!
//! A child process (this test binary again, running `writer_child`) writes whole-run
//! checkpoints back to back (replay segments, learner directory, `latest.json`,
//! pruning) of a replay whose snippets carry their own numbers; the parent SIGKILLs
//! it at random moments, five times, each time resuming in the same directory. After
//! every kill the latest checkpoint loads, its replay holds exactly the snippets its
//! counters say, and the next child resumes from it.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use agent::core::replay::{Snippet, SnippetLayout, SnippetReplay};
use agent::report::metrics::RunFiles;
use agent::runtime::checkpoint::run::{PaceOrigin, latest_checkpoint};
use agent::runtime::resume::{Checkpointer, Reopened, open_checkpoint, restore_schedule};
use agent::runtime::schedule::{ActorStep, Counters, Pace, Schedule};
use tch::Device;

const CHILD_DIR: &str = "AGENT_TEST_CHECKPOINT_WRITER_DIR";
const LAYOUT: SnippetLayout = SnippetLayout {
    length: 8,
    obs_dim: 16,
    action_width: 2,
    num_rewards: 2,
    discrete: false,
    on_policy: false,
};
/// Ring of 2,000 snippets: it wraps after a few checkpoints, so old segments go.
const CAPACITY_TRANSITIONS: usize = 16_000;
const PER_CHECKPOINT: u64 = 300;

/// Snippet number `j`: every value is `j` (exact in f32 below 2^24).
fn snippet(j: u64) -> Snippet {
    let v = j as f32;
    let t = LAYOUT.length;
    Snippet {
        observations: vec![v; (t + 1) * LAYOUT.obs_dim],
        actions: vec![v; t * LAYOUT.action_width],
        rewards: vec![v; t * LAYOUT.num_rewards],
        discounts: vec![v; t],
        behaviour_log_probs: vec![v; t],
        valid: vec![v; t],
    }
}

/// The replay of `dir`'s latest checkpoint, with its counters and pace origin.
fn reopen(dir: &Path) -> (Reopened, SnippetReplay, PaceOrigin) {
    let reopened = open_checkpoint(dir, Device::Cpu).expect("the latest checkpoint loads");
    let mut replay = SnippetReplay::new(LAYOUT, CAPACITY_TRANSITIONS, 0);
    let origin = restore_schedule(dir, &reopened.progress, &mut replay).unwrap();
    (reopened, replay, origin)
}

#[test]
fn writer_child() {
    // Only as the child of `a_kill_during_a_checkpoint_leaves_the_latest_loadable`.
    let Ok(dir) = std::env::var(CHILD_DIR) else {
        return;
    };
    let dir = Path::new(&dir);
    let objectives = ["a".to_string(), "b".to_string()];
    let (learner, replay, counters, origin, segments_end) = if latest_checkpoint(dir).is_ok() {
        let (reopened, replay, origin) = reopen(dir);
        let p = &reopened.progress;
        let counters = Counters {
            env_steps: p.env_steps,
            episodes: p.episodes,
            ..Counters::default()
        };
        let end = replay.inserted();
        (reopened.learner, replay, counters, origin, end)
    } else {
        let replay = SnippetReplay::new(LAYOUT, CAPACITY_TRANSITIONS, 0);
        let learner = common::continuous_learner();
        (
            learner,
            replay,
            Counters::default(),
            PaceOrigin::default(),
            0,
        )
    };
    let pace = Pace::Ratio {
        learner_steps_per_env_step: 0.1,
        min_replay_transitions: 1,
    };
    let schedule = Schedule::new(replay, pace, counters, origin);
    let files = Arc::new(RunFiles::open(dir, &objectives, &[]).unwrap());
    let mut checkpointer = Checkpointer::new(files, true, segments_end);
    loop {
        let first = schedule.replay.lock().unwrap().inserted();
        let step = ActorStep {
            actor: 0,
            acts: first,
            env_steps: PER_CHECKPOINT * LAYOUT.length as u64,
            snippets: (first..first + PER_CHECKPOINT).map(snippet).collect(),
            episode_returns: Vec::new(),
        };
        schedule.commit(step, |_| Ok(())).unwrap();
        checkpointer.save(&learner, &schedule).unwrap();
    }
}

#[test]
fn a_kill_during_a_checkpoint_leaves_the_latest_loadable() {
    let dir = tempfile::tempdir().unwrap();
    let mut last_inserted = 0;
    for round in 0..5 {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "writer_child", "--nocapture", "--test-threads=1"])
            .env(CHILD_DIR, dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // Past this round's first new checkpoint, then a random moment: checkpoints
        // are all the child does, so the kill lands in one.
        let started = Instant::now();
        loop {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "round {round}: no checkpoint"
            );
            if latest_checkpoint(dir.path())
                .is_ok_and(|(_, p)| p.replay.is_some_and(|r| r.inserted > last_inserted))
            {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap()
            .subsec_nanos();
        std::thread::sleep(Duration::from_micros(u64::from(nanos % 300_000)));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();

        let (reopened, replay, _) = reopen(dir.path());
        let p = &reopened.progress;
        let state = p.replay.as_ref().unwrap();
        assert_eq!(replay.inserted(), state.inserted);
        assert_eq!(
            p.env_steps,
            state.inserted * LAYOUT.length as u64,
            "counters and replay agree"
        );
        assert!(
            state.inserted > last_inserted,
            "round {round} made progress"
        );
        let held = replay.snippets_from(0);
        assert_eq!(held.len(), 2_000.min(state.inserted as usize));
        for (snippet, j) in held.iter().zip(replay.held_from()..) {
            assert_eq!(snippet.observations[0], j as f32, "snippet {j}");
            assert_eq!(*snippet.valid.last().unwrap(), j as f32, "snippet {j}");
        }
        // Pruning keeps what the two newest checkpoints read, not every segment.
        let segments = std::fs::read_dir(dir.path().join("replay"))
            .unwrap()
            .count();
        assert!(
            segments <= 2_000 / PER_CHECKPOINT as usize + 4,
            "{segments} segments"
        );
        last_inserted = state.inserted;
    }
}
