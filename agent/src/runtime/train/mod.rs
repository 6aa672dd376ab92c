//! One training run: actors + learner + progress + checkpoints + final evaluation.
//!
//! `train` makes (or, with `resume`, reopens) `runs/<task>__<algo>__<seed>__<UTC time>/`,
//! writes the resolved config there, runs the actors (tokio tasks) and the learner
//! (an OS thread) under the schedule's rate limit, stops on the env-step budget,
//! evaluates the deterministic policy, and writes `summary.json` and the learning
//! curves (`curves.png`, `curves.svg`). Ctrl-C or SIGTERM stops it early: the learner
//! writes a checkpoint and the run still writes its summary (marked `interrupted`, no
//! evaluation), curves and TensorBoard events; a second Ctrl-C exits at once.
//!
//! `train_population` trains P runs as one population (docs/design.md, "Populations"): one
//! learner of P members, actors with one env session for all of them, and a folder
//! per run as `train` writes it; `train` is a population of one.
//!
//! `train_population` is four steps around one [`Population`] value: `open` (the
//! servers, the env's spec and each member's run; `setup` makes the run folders and
//! schedules), `start` and `wait` (`launch`: the learner thread, `actors`, periodic
//! `videos`, `progress`), and `finish` (final evaluations, fronts, reports).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use serde::Serialize;
use tch::Device;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::core::algo::LearnerStats;
use crate::core::algo::objectives::LearnerDims;
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::learner_config::ConfigError;
use crate::core::nets::PolicySnapshot;
use crate::core::replay::SnippetLayout;
use crate::env::EpisodeSummary;
use crate::env::error::EnvError;
use crate::env::pool::{ActorServers, EnvFaults, ServerPool};
use crate::report::front::FrontSummary;
use crate::report::metrics::RunFiles;
use crate::report::plot::PlotError;
use crate::report::video::{VideoPlan, VideoReport};
use crate::runtime::learner::LearnerLoopError;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::schedule::Schedule;
use crate::runtime::solve::SolveRecord;

mod actors;
mod curves;
mod evals;
mod finish;
mod front;
mod launch;
mod open;
mod progress;
mod setup;
mod videos;

use open::Opening;
use setup::check_population_run;

/// Errors of a training run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// Bad configuration (including objective names that do not match the env).
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Talking to the env server failed.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// The learner loop or its checkpoints failed.
    #[error(transparent)]
    Learner(#[from] LearnerLoopError),
    /// Building the learner failed.
    #[error(transparent)]
    Build(#[from] crate::core::algo::LearnerError),
    /// Restoring a checkpoint failed.
    #[error(transparent)]
    Checkpoint(#[from] crate::runtime::checkpoint::CheckpointError),
    /// Writing a figure failed.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// Measuring or writing a front failed.
    #[error(transparent)]
    Front(#[from] crate::report::front::FrontError),
    /// Recording a video failed.
    #[error(transparent)]
    Video(#[from] crate::report::video::VideoError),
    /// The final evaluation failed.
    #[error(transparent)]
    Eval(#[from] crate::runtime::eval::EvalError),
    /// A run file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// An actor or the learner stopped the run.
    #[error("run stopped: {0}")]
    Stopped(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// How to run `train`.
#[derive(Debug, Clone, Default)]
pub struct TrainOptions {
    /// Continue the run in this directory from its latest checkpoint.
    pub resume: Option<PathBuf>,
    /// Draw a progress bar.
    pub progress: bool,
    /// Record videos (under `<run>/videos/`): of the final evaluation, and every N env steps.
    pub video: Option<VideoPlan>,
}

/// What a finished run reports (also `summary.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrainSummary {
    /// The run directory.
    pub run_dir: PathBuf,
    /// Objective names in reward order.
    pub objectives: Vec<String>,
    /// Env steps done.
    pub env_steps: u64,
    /// Learner steps done.
    pub learner_steps: u64,
    /// Training episodes finished.
    pub episodes: u64,
    /// The run's training wall seconds, a resumed run's summed over its invocations
    /// (from each one's first env step; connecting and building the learner, a
    /// second or so, are left out).
    pub wall_seconds: f64,
    /// Mean undiscounted return of the last training episodes.
    pub recent_train_return: Vec<f64>,
    /// Temperatures eta_k at the end, by `learner_objectives` (grid point by grid
    /// point when ε-conditioned).
    pub temperature: Vec<f32>,
    /// The learner's E-step objectives: `objectives` (or `scalarized`), then
    /// `action_penalty` with `mpo.action_penalization`.
    pub learner_objectives: Vec<String>,
    /// Evaluation episodes (deterministic policy), as reported by the server.
    pub eval_episodes: Vec<EpisodeSummary>,
    /// Mean undiscounted evaluation return per objective.
    pub eval_return: Vec<f64>,
    /// Mean discounted evaluation return per objective.
    pub eval_discounted_return: Vec<f64>,
    /// The discount of `eval_discounted_return`.
    pub eval_discount: f64,
    /// Where the learner ran (`learner.device` resolved: `Cpu` or `Cuda(i)`).
    pub learner_device: String,
    /// `run.solve_threshold`: returns that count as solved, by objective.
    pub solve_threshold: std::collections::BTreeMap<String, f64>,
    /// When the mean of the last 10 training episodes first reached every threshold
    /// (`null` when it never did, or no threshold was given).
    pub solved: Option<SolveRecord>,
    /// The signal (`Ctrl-C`, `SIGTERM`) that stopped the run before its budget; `null`
    /// when it ran to the end. An interrupted run has no evaluation episodes.
    pub interrupted: Option<String>,
    /// The video of the final evaluation, when videos were asked for.
    pub eval_video: Option<VideoReport>,
    /// The env servers each actor had its session on, in order (more than one when
    /// its server was lost and it moved).
    pub actor_servers: Vec<ActorServers>,
    /// What env faults (missed deadlines, lost sessions) cost the run's actors; shared
    /// by a population's members.
    pub env_faults: EnvFaults,
    /// ε-conditioned runs: the front of the deterministic policy over the preference
    /// grid (also `<run>/front/`); the evaluation above is at the grid's middle point.
    pub front: Option<FrontSummary>,
}

/// Run one training job against the servers `addresses` name (plain addresses, `dns:`
/// names or `file:` lists; actors spread over every address found, see [`ServerPool`]).
pub async fn train(
    cfg: TrainConfig,
    addresses: &[String],
    options: TrainOptions,
) -> Result<TrainSummary, TrainError> {
    let mut summaries = train_population(vec![cfg], addresses, options).await?;
    Ok(summaries.swap_remove(0))
}

/// One member's run: its folder, files, schedule and published policy.
struct MemberRun {
    cfg: TrainConfig,
    run_dir: PathBuf,
    files: Arc<RunFiles>,
    schedule: Arc<Schedule>,
    params: watch::Receiver<Arc<PolicySnapshot>>,
    latest: Arc<Mutex<Option<LearnerStats>>>,
    first_acts: Vec<u64>,
    /// The periodic evaluations' task (`run.eval_period`), started before any actor
    /// commits so that no evaluation point is missed.
    evaluations: Option<JoinHandle<()>>,
}

/// A population run from its opening to its summaries: what its members share (the
/// servers, the env's objectives, the learner's dimensions, device and preference
/// grid) and each member's run. `open` opens it, `launch` starts and waits for its
/// actors and learner, `finish` evaluates and reports.
struct Population {
    /// The first member's config: the env, actors, budget and periods all members share.
    cfg: TrainConfig,
    servers: Arc<ServerPool>,
    /// Objective names in reward order.
    objectives: Vec<String>,
    /// The learner's E-step objectives (`BoundObjectives::names`), which its
    /// temperatures are listed by.
    learner_objectives: Vec<String>,
    /// The env's discount, for discounted evaluation returns.
    discount: f64,
    dims: LearnerDims,
    device: Device,
    /// An ε-conditioned run's preference grid.
    grid: Option<Arc<PreferenceGrid>>,
    /// Snippet sizes of the replays.
    layout: SnippetLayout,
    runs: Vec<MemberRun>,
}

/// Train the runs `cfgs` as one population (docs/design.md, "Populations"): one learner
/// whose members are the runs (`Learner::population`), one env session of P x B
/// instances per actor, and a folder per run exactly as `train` writes it. The configs
/// must agree on everything but their seeds, ε and scalarization weights
/// ([`TrainConfig::population_key`]); a population of more than one is new (no
/// `resume`, no periodic videos). Summaries in `cfgs`' order.
pub async fn train_population(
    cfgs: Vec<TrainConfig>,
    addresses: &[String],
    options: TrainOptions,
) -> Result<Vec<TrainSummary>, TrainError> {
    check_population_run(&cfgs, &options)?;
    let Opening {
        mut population,
        learner,
    } = Population::open(cfgs, addresses, &options).await?;
    let running = population.start(learner, &options)?;
    let policies = population.wait(running).await?;
    population.finish(policies, &options).await
}

/// The text of a caught panic (`panic!` with a message gives a `&str` or a `String`).
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}
