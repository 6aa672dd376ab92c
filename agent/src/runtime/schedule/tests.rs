//! The pace, the actors' wait and a resume's origin, on a replay filled by hand.

use super::*;
use crate::core::replay::{Snippet, SnippetLayout};

fn schedule(ratio: f64, min_replay: usize) -> Schedule {
    resumed_schedule(
        ratio,
        min_replay,
        Counters::default(),
        PaceOrigin::default(),
    )
}

fn resumed_schedule(
    ratio: f64,
    min_replay: usize,
    counters: Counters,
    origin: PaceOrigin,
) -> Schedule {
    let pace = Pace::Ratio {
        learner_steps_per_env_step: ratio,
        min_replay_transitions: min_replay,
    };
    Schedule::new(
        SnippetReplay::new(layout(false), 1000, 0),
        pace,
        counters,
        origin,
    )
}

/// A one-step snippet of the test layouts.
fn snippet() -> Snippet {
    Snippet {
        observations: vec![0.0, 0.0],
        actions: vec![0.0],
        rewards: vec![0.0],
        discounts: vec![1.0],
        behaviour_log_probs: vec![0.0],
        valid: vec![1.0],
    }
}

/// One-step snippets of one observation, action and reward.
fn layout(on_policy: bool) -> SnippetLayout {
    SnippetLayout {
        length: 1,
        obs_dim: 1,
        action_width: 1,
        num_rewards: 1,
        discrete: true,
        on_policy,
    }
}

/// An on-policy schedule of one-step unrolls, `batch_size` per learner step.
fn on_policy_schedule(batch_size: usize) -> Schedule {
    Schedule::new(
        SnippetReplay::new(layout(true), usize::MAX, 0),
        Pace::OnPolicy { batch_size },
        Counters::default(),
        PaceOrigin::default(),
    )
}

fn fill(s: &Schedule, n: usize) {
    let mut r = s.replay.lock().unwrap();
    for _ in 0..n {
        r.insert(snippet()).unwrap();
    }
}

#[test]
fn learner_budget_follows_the_ratio_after_warm_up() {
    let s = schedule(0.25, 10);
    fill(&s, 9);
    s.add_env_steps(9, []);
    assert_eq!(s.allowed(&s.counters(), s.fill()), 0, "replay not warm yet");
    fill(&s, 11);
    s.add_env_steps(11, []);
    // 20 env steps, 10 past warm-up, ratio 1/4 -> 2 learner steps.
    assert_eq!(s.allowed(&s.counters(), s.fill()), 2);
    assert!(s.wait_for_work());
    s.learner_stepped();
    assert!(s.wait_for_work());
    s.learner_stepped();
    s.stop(None);
    assert!(
        !s.wait_for_work(),
        "no third step: the budget is 2, and the run stopped"
    );
}

#[test]
fn on_policy_allows_one_step_per_batch_of_unrolls() {
    let s = on_policy_schedule(4);
    fill(&s, 3);
    assert_eq!(s.allowed(&s.counters(), s.fill()), 0, "3 of 4 unrolls");
    fill(&s, 6);
    assert_eq!(
        s.allowed(&s.counters(), s.fill()),
        2,
        "9 unrolls make two batches"
    );
    assert_eq!(s.replay.lock().unwrap().sample(4).batch_size(), 4);
    s.learner_stepped();
    assert_eq!(
        s.allowed(&s.counters(), s.fill()),
        2,
        "consuming a batch does not change the budget"
    );
}

#[tokio::test]
async fn actors_wait_until_the_learner_catches_up() {
    let s = std::sync::Arc::new(schedule(1.0, 1));
    fill(&s, 3);
    s.add_env_steps(3, []);
    let learner = {
        let s = s.clone();
        std::thread::spawn(move || {
            let mut steps = 0;
            while s.wait_for_work() {
                s.learner_stepped();
                steps += 1;
                if steps == 2 {
                    break;
                }
            }
        })
    };
    tokio::time::timeout(std::time::Duration::from_secs(10), s.wait_for_learner())
        .await
        .unwrap();
    assert_eq!(
        s.counters().learner_steps,
        2,
        "(3 - 1) * 1.0 learner steps before the actor resumes"
    );
    learner.join().unwrap();
}

#[test]
fn a_resume_without_replay_refills_then_goes_on_at_the_ratio() {
    // Resumed at 10,000 env steps and 2,497 learner steps with an empty replay.
    let (env_steps, learner_steps) = (10_000, 2_497);
    let counters = Counters {
        env_steps,
        learner_steps,
        ..Counters::default()
    };
    let origin = PaceOrigin {
        env_steps,
        learner_steps,
        inserted: 0,
    };
    let s = resumed_schedule(0.25, 10, counters, origin);
    fill(&s, 9);
    s.add_env_steps(9, []);
    assert_eq!(
        s.allowed(&s.counters(), s.fill()),
        learner_steps,
        "refilling"
    );
    fill(&s, 11);
    s.add_env_steps(11, []);
    // 20 env steps since the resume, 10 past the refill: 2 more learner steps, where
    // counting from zero would allow (10,020 - 10) * 0.25 - 2,497 = 5 at once (and
    // about min_replay * ratio more at a realistic warm-up).
    assert_eq!(s.allowed(&s.counters(), s.fill()), learner_steps + 2);
}

/// Microseconds [`preempted_after_fill`] pauses for (0: none).
static PAUSE_AFTER_FILL_US: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Where `wait_for_work` has read the replay's fill and not yet decided to wait: a
/// pause here is what a preemption on a loaded machine makes.
pub(super) fn preempted_after_fill() {
    let us = PAUSE_AFTER_FILL_US.load(std::sync::atomic::Ordering::Relaxed);
    if us > 0 {
        std::thread::sleep(std::time::Duration::from_micros(us));
    }
}

/// A learner that waits for work wakes for every commit that allows a step, also when
/// it is preempted between reading the replay's fill and deciding to wait. It once
/// read the fill before taking the counters' lock: with this pause between the two,
/// that code hung within 10 of these rounds (a commit in the gap was judged with the
/// old fill, and its wake-up was spent before the learner waited). An actor commits one
/// unroll at a time (one learner step each) and waits for the learner before the next,
/// as on-policy actors do.
#[test]
fn the_learner_never_misses_a_commit() {
    const ROUNDS: u64 = 2_000;
    PAUSE_AFTER_FILL_US.store(20, std::sync::atomic::Ordering::Relaxed);
    let s = std::sync::Arc::new(on_policy_schedule(1));
    let learner = {
        let s = s.clone();
        std::thread::spawn(move || {
            while s.wait_for_work() {
                s.learner_stepped();
            }
        })
    };
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    let actor = {
        let s = s.clone();
        std::thread::spawn(move || {
            for acts in 1..=ROUNDS {
                let step = ActorStep {
                    actor: 0,
                    acts,
                    env_steps: 1,
                    snippets: vec![snippet()],
                    episode_returns: Vec::new(),
                };
                s.commit(step, |_| Ok(())).unwrap();
                while !s.caught_up() {
                    std::thread::yield_now();
                }
                s.replay.lock().unwrap().sample(1);
            }
            done_tx.send(()).unwrap();
        })
    };
    let finished = done_rx.recv_timeout(std::time::Duration::from_secs(60));
    PAUSE_AFTER_FILL_US.store(0, std::sync::atomic::Ordering::Relaxed);
    let steps = s.counters().learner_steps;
    s.stop(None);
    assert!(
        finished.is_ok(),
        "the learner slept through a commit: {steps} learner steps of {ROUNDS}"
    );
    actor.join().unwrap();
    learner.join().unwrap();
}
