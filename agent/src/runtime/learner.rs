//! The learner loop (Algorithm 3's outer loop): sample snippets, take a learner
//! step, publish the policy to the actors, log, and checkpoint.
//!
//! Runs on its own OS thread (libtorch calls block). Checkpoints of the whole run
//! (`resume.rs`, `checkpoint/run.rs`) are written every `checkpoint_period` steps
//! and at the end.
//!
//! A population learner steps its P members in lockstep, each with its own run:
//! schedule (replay, pace, counters), published policy, logs and checkpoints. A step
//! waits until every running member's schedule allows one. A member whose run stops
//! without an error (solved with `run.stop_on_solve`, or a signal) gets its final
//! checkpoint and policy there and leaves the population; the others go on. An error
//! in any member's run stops them all.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::Serialize;
use tokio::sync::watch;

use crate::core::algo::objectives::BoundObjectives;
use crate::core::algo::{Learner, LearnerStats, PhaseTimings, SnippetBatch};
use crate::core::nets::PolicySnapshot;
use crate::report::metrics::RunFiles;
use crate::report::tensorboard::Scalar;
use crate::runtime::checkpoint::CheckpointError;
use crate::runtime::resume::Checkpointer;
use crate::runtime::schedule::Schedule;

/// Errors of the learner loop.
#[derive(Debug, thiserror::Error)]
pub enum LearnerLoopError {
    /// The learner step failed.
    #[error(transparent)]
    Step(#[from] crate::core::algo::LearnerError),
    /// Writing or reading a checkpoint failed.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// Another member's run failed, which stops the population.
    #[error("{0}")]
    Stopped(String),
    /// A run file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> LearnerLoopError + '_ {
    move |source| LearnerLoopError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// One `learner.jsonl` record.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LearnerRecord {
    /// Learner steps done.
    pub learner_step: u64,
    /// Env steps at that moment.
    pub env_steps: u64,
    /// The run's training wall seconds ([`Schedule::elapsed_seconds`]: a resumed
    /// run's go on from its checkpoint's).
    pub wall_seconds: f64,
    /// Per critic head: 0.5 * mean squared Retrace error.
    pub critic_loss: Vec<f32>,
    /// Per objective: temperature eta_k.
    pub temperature: Vec<f32>,
    /// Per objective: realised KL(q_k || pi_old).
    pub estep_kl: Vec<f32>,
    /// Lagrange multipliers (alpha_mu, alpha_Sigma) or (alpha); with a per-dimension
    /// KL constraint, the mean over action dimensions of each.
    pub alpha: Vec<f32>,
    /// KL(pi_old || pi) parts before the update (at the end of a V-MPO step of several
    /// updates); with a per-dimension KL constraint,
    /// the mean over action dimensions of each (`LearnerStats::policy_kl`).
    pub policy_kl: Vec<f32>,
    /// The fraction of its M-step the policy kept after the trust region's projection
    /// (`LearnerStats::policy_step_kept`).
    pub policy_step_kept: f32,
    /// Milliseconds of the step.
    pub step_ms: f64,
    /// Where `step_ms` went; what they leave of it is the loop's bookkeeping.
    pub phases: StepPhases,
    /// Env steps per second since the previous record (or the start).
    pub env_steps_per_second: f64,
    /// Learner steps per second since the previous record (or the start).
    pub learner_steps_per_second: f64,
}

/// Milliseconds of one logged learner step by phase (the step's own, not an average).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StepPhases {
    /// Drawing the members' batches from replay and moving them to the device.
    pub sample_ms: f64,
    /// The learner's phases (`PhaseTimings`).
    #[serde(flatten)]
    pub learner: PhaseTimings,
}

/// Labels for a vector of statistics: objective names when there is one entry per
/// objective, the two parts of the Gaussian trust region when there are two, else indices.
fn labels(values: &[f32], objectives: &[String], parts: bool) -> Vec<String> {
    if !parts && values.len() == objectives.len() {
        objectives.to_vec()
    } else if parts && values.len() == 2 {
        vec!["mean".into(), "covariance".into()]
    } else {
        (0..values.len()).map(|i| i.to_string()).collect()
    }
}

impl LearnerRecord {
    /// The fields that read a clock: they differ between two runs that are otherwise
    /// the same, which is what the reproducibility and resume checks leave out.
    pub const CLOCK_FIELDS: [&str; 5] = [
        "wall_seconds",
        "step_ms",
        "phases",
        "env_steps_per_second",
        "learner_steps_per_second",
    ];

    /// The record as TensorBoard scalars (`learner/...`, `throughput/...`), labelled by
    /// critic head (`names.critic_names`), by the E-step's objective
    /// (`BoundObjectives::names`), or `mean`/`covariance` for the Gaussian trust
    /// region's parts (each the mean over action dimensions under a per-dimension KL
    /// constraint).
    pub fn scalars(&self, names: &BoundObjectives) -> Vec<Scalar> {
        let mut out = Vec::new();
        let (critics, objectives) = (&names.critic_names, &names.names());
        let groups: [(&str, &[f32], &[String], bool); 5] = [
            ("critic_loss", &self.critic_loss, critics, false),
            ("temperature", &self.temperature, objectives, false),
            ("estep_kl", &self.estep_kl, objectives, false),
            ("alpha", &self.alpha, &[], true),
            ("policy_kl", &self.policy_kl, &[], true),
        ];
        for (name, values, objectives, parts) in groups {
            for (label, v) in labels(values, objectives, parts).iter().zip(values) {
                out.push(Scalar::new(
                    format!("learner/{name}/{label}"),
                    f64::from(*v),
                ));
            }
        }
        out.push(Scalar::new(
            "learner/policy_step_kept",
            f64::from(self.policy_step_kept),
        ));
        out.push(Scalar::new("learner/step_ms", self.step_ms));
        let timings = &self.phases.learner;
        for (phase, ms) in [
            ("sample", self.phases.sample_ms),
            ("policy_evaluation", timings.policy_evaluation_ms),
            ("e_step", timings.e_step_ms),
            ("m_step", timings.m_step_ms),
            ("target_update", timings.target_update_ms),
        ] {
            out.push(Scalar::new(format!("learner/phase_ms/{phase}"), ms));
        }
        out.push(Scalar::new(
            "learner/learner_steps",
            self.learner_step as f64,
        ));
        out.push(Scalar::new(
            "throughput/env_steps_per_second",
            self.env_steps_per_second,
        ));
        out.push(Scalar::new(
            "throughput/learner_steps_per_second",
            self.learner_steps_per_second,
        ));
        out
    }
}

/// One member's run as the learner loop sees it.
#[derive(Debug)]
pub struct MemberLoop {
    /// Rate limiter and replay.
    pub schedule: Arc<Schedule>,
    /// Where published policies go.
    pub params: watch::Sender<Arc<PolicySnapshot>>,
    /// Run files.
    pub files: Arc<RunFiles>,
    /// The latest statistics, for the progress display.
    pub latest: Arc<Mutex<Option<LearnerStats>>>,
    /// Writes the run's checkpoints.
    pub checkpointer: Checkpointer,
}

/// What the learner thread needs.
#[derive(Debug)]
pub struct LearnerContext {
    /// The learner (fresh or restored), of one or more members.
    pub learner: Learner,
    /// Each member's run, in member order.
    pub members: Vec<MemberLoop>,
    /// How often it publishes, checkpoints and logs.
    pub periods: LoopPeriods,
}

/// The learner loop's periods, in learner steps (each at least 1, `run_config`'s
/// `validate`).
#[derive(Debug, Clone, Copy)]
pub struct LoopPeriods {
    /// Steps between publications beyond the catch-up ones (`run_learner`).
    pub publish: u64,
    /// Steps between checkpoints.
    pub checkpoint: u64,
    /// Steps between log records.
    pub log: u64,
}

/// What the learner loop leaves: the learner, and each member's policy at the end of
/// its run (its final checkpoint's).
#[derive(Debug)]
pub struct LearnerDone {
    /// The learner.
    pub learner: Learner,
    /// Each member's final policy, in member order.
    pub policies: Vec<PolicySnapshot>,
}

/// Where a member's rates were last measured from.
#[derive(Debug, Clone, Copy)]
struct Mark {
    wall_seconds: f64,
    env_steps: u64,
    learner_steps: u64,
}

/// A member's bookkeeping in the loop.
struct Running {
    run: MemberLoop,
    /// The previous log record's mark, for the rates.
    previous: Mark,
    /// The final policy once the member's run has ended.
    done: Option<PolicySnapshot>,
}

/// Run until every member's schedule stops; always writes each member's final
/// checkpoint. Returns the learner and the members' final policies.
pub fn run_learner(ctx: LearnerContext) -> Result<LearnerDone, LearnerLoopError> {
    let LearnerContext {
        mut learner,
        members,
        periods,
    } = ctx;
    let mut members: Vec<Running> = members
        .into_iter()
        .map(|run| Running {
            previous: Mark {
                wall_seconds: run.schedule.elapsed_seconds(),
                env_steps: run.schedule.counters().env_steps,
                learner_steps: learner.step_count(),
            },
            run,
            done: None,
        })
        .collect();
    let result = (|| -> Result<(), LearnerLoopError> {
        loop {
            if wait_for_members(&mut members, &learner)? {
                return Ok(());
            }
            let t0 = Instant::now();
            let batches = sample_batches(&members, &learner);
            let sample_ms = t0.elapsed().as_secs_f64() * 1e3;
            // Actors load policies only once the learner has caught up (a population's
            // actor: with any running member, `wait_for_population_learner`), so those
            // steps always publish; `publish_period` adds publications in between.
            let actors_may_load = members
                .iter()
                .any(|m| m.done.is_none() && m.run.schedule.next_step_catches_up());
            let all_stats = learner.step_members(&batches)?;
            let step = Stepped {
                step_ms: t0.elapsed().as_secs_f64() * 1e3,
                sample_ms,
                n: learner.step_count(),
                actors_may_load,
            };
            for (p, (m, stats)) in members.iter_mut().zip(all_stats).enumerate() {
                if m.done.is_none() {
                    after_step(m, p, stats, &learner, &step, periods)?;
                }
            }
            // Only now may actors act again: every member's policy of this step is
            // published, so none acts with the previous one by a race.
            for m in members.iter().filter(|m| m.done.is_none()) {
                m.run.schedule.learner_stepped();
            }
        }
    })();
    if let Err(e) = &result {
        for m in &members {
            m.run.schedule.stop(Some(e.to_string()));
        }
    }
    // Whatever happened, leave a checkpoint of the state each member reached.
    let mut policies = Vec::with_capacity(members.len());
    for (p, m) in members.iter_mut().enumerate() {
        if m.done.is_none() {
            m.run.checkpointer.save(&learner, &m.run.schedule)?;
        }
        policies.push(
            m.done
                .take()
                .unwrap_or_else(|| learner.member_policy_snapshot(p)),
        );
    }
    result.map(|()| LearnerDone { learner, policies })
}

/// One learner step as each member's bookkeeping needs it.
struct Stepped {
    step_ms: f64,
    /// The part of `step_ms` spent sampling the batches.
    sample_ms: f64,
    /// The learner's step count after it.
    n: u64,
    /// Whether an actor may load a policy before the next step (then it is published).
    actors_may_load: bool,
}

/// Lockstep: waits until every running member allows a step. A member whose run
/// stopped without an error gets its final checkpoint and policy here and leaves the
/// population; whether every member has.
fn wait_for_members(members: &mut [Running], learner: &Learner) -> Result<bool, LearnerLoopError> {
    for (p, m) in members.iter_mut().enumerate() {
        if m.done.is_some() || m.run.schedule.wait_for_work() {
            continue;
        }
        if let Some(error) = m.run.schedule.counters().error {
            return Err(LearnerLoopError::Stopped(error));
        }
        m.run.checkpointer.save(learner, &m.run.schedule)?;
        m.done = Some(learner.member_policy_snapshot(p));
    }
    Ok(members.iter().all(|m| m.done.is_some()))
}

/// A batch per member from its own replay. A stopped member's slot trains on a running
/// member's batch (a shallow copy): its results are discarded (its last checkpoint and
/// policy were taken when it stopped), and its on-policy queue, no longer filled, may
/// hold less than a batch.
fn sample_batches(members: &[Running], learner: &Learner) -> Vec<SnippetBatch> {
    let device = learner.device();
    let batch_size = learner.settings().batch_size;
    let sampled: Vec<Option<SnippetBatch>> = members
        .iter()
        .map(|m| {
            m.done.is_none().then(|| {
                let replay = m.run.schedule.replay.lock();
                let batch = replay.unwrap_or_else(|e| e.into_inner()).sample(batch_size);
                batch.to_device(device)
            })
        })
        .collect();
    let stand_in = sampled
        .iter()
        .flatten()
        .next()
        .expect("checked above: a member is running")
        .to_device(device);
    sampled
        .into_iter()
        .map(|b| b.unwrap_or_else(|| stand_in.to_device(device)))
        .collect()
}

/// A running member after a learner step: publish its policy, log, keep its latest
/// statistics for the progress display, and checkpoint, each on its period.
fn after_step(
    m: &mut Running,
    p: usize,
    stats: LearnerStats,
    learner: &Learner,
    step: &Stepped,
    periods: LoopPeriods,
) -> Result<(), LearnerLoopError> {
    let n = step.n;
    if step.actors_may_load || n.is_multiple_of(periods.publish) {
        m.run
            .params
            .send_replace(Arc::new(learner.member_policy_snapshot(p)));
    }
    if n.is_multiple_of(periods.log) {
        log_step(m, &stats, step, learner.objectives())?;
    }
    *m.run.latest.lock().unwrap_or_else(|e| e.into_inner()) = Some(stats);
    if n.is_multiple_of(periods.checkpoint) {
        m.run.checkpointer.save(learner, &m.run.schedule)?;
    }
    Ok(())
}

/// A member's log record of this step: learner.jsonl and TensorBoard.
/// `objectives`: the learner's critic heads and E-step objectives, which label the
/// statistics.
fn log_step(
    m: &mut Running,
    stats: &LearnerStats,
    step: &Stepped,
    objectives: &BoundObjectives,
) -> Result<(), LearnerLoopError> {
    let now = Mark {
        wall_seconds: m.run.schedule.elapsed_seconds(),
        env_steps: m.run.schedule.counters().env_steps,
        learner_steps: step.n,
    };
    let previous = m.previous;
    let dt = (now.wall_seconds - previous.wall_seconds).max(1e-9);
    let record = LearnerRecord {
        learner_step: step.n,
        env_steps: now.env_steps,
        wall_seconds: now.wall_seconds,
        critic_loss: stats.critic_loss.clone(),
        temperature: stats.temperature.clone(),
        estep_kl: stats.estep_kl.clone(),
        alpha: stats.alpha.clone(),
        policy_kl: stats.policy_kl.clone(),
        policy_step_kept: stats.policy_step_kept,
        step_ms: step.step_ms,
        phases: StepPhases {
            sample_ms: step.sample_ms,
            learner: stats.timings,
        },
        env_steps_per_second: now.env_steps.saturating_sub(previous.env_steps) as f64 / dt,
        learner_steps_per_second: step.n.saturating_sub(previous.learner_steps) as f64 / dt,
    };
    m.previous = now;
    // Every TensorBoard chart is by env step, as in SB3 and Acme.
    let files = &m.run.files;
    files
        .scalars(now.env_steps, &record.scalars(objectives))
        .map_err(io_err(&files.events_path()))?;
    let path = files.dir().join("learner.jsonl");
    files.learner(&record).map_err(io_err(&path))?;
    Ok(())
}
