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
//! `setup` opens the runs and builds their schedules, `actors` starts the actors,
//! `progress` draws the bar and takes the signals, `finish` evaluates and writes the
//! reports; this module starts the learner and waits for them all.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::Serialize;
use tokio::sync::watch;

use crate::core::algo::LearnerStats;
use crate::core::algo::objectives::{LearnerDims, check_declared};
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::device::{choose_device, configure_threads};
use crate::core::learner_config::ConfigError;
use crate::core::nets::PolicySnapshot;
use crate::env::EpisodeSummary;
use crate::env::error::EnvError;
use crate::env::pool::{ActorServers, EnvFaults, ServerPool};
use crate::report::front::FrontSummary;
use crate::report::metrics::RunFiles;
use crate::report::plot::PlotError;
use crate::report::video::{VideoPlan, VideoReport};
use crate::runtime::env_setup::probe_spec;
use crate::runtime::learner::{
    LearnerContext, LearnerDone, LearnerLoopError, MemberLoop, run_learner,
};
use crate::runtime::resume::Checkpointer;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::schedule::Schedule;
use crate::runtime::solve::SolveRecord;
use videos::{PeriodicContext, record_periodically};

mod actors;
mod curves;
mod evals;
mod finish;
mod front;
mod progress;
mod setup;
mod videos;

use actors::{ActorPlan, spawn_actors};
use evals::{EvalPlan, finish_evaluations, start_evaluations};
use finish::finish_member;
use progress::{progress_bar, spawn_ticker};
use setup::{
    Opened, OpenedRun, check_population_run, open_population, schedule_for, snippet_layout,
};

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
    /// Wall time of this invocation.
    pub wall_seconds: f64,
    /// Mean undiscounted return of the last training episodes.
    pub recent_train_return: Vec<f64>,
    /// Temperatures eta_k at the end.
    pub temperature: Vec<f32>,
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
    let started = Instant::now();
    check_population_run(&cfgs, &options)?;
    let cfg = cfgs[0].clone();
    configure_threads(cfg.learner.num_threads);
    let servers = Arc::new(
        ServerPool::connect_with(addresses, &cfg.env.connection, cfg.env.deadlines).await?,
    );
    let probe = &cfg;
    let spec = servers
        .on_live("spec probe", |client| async move {
            probe_spec(&client, probe).await
        })
        .await?;
    let dims =
        LearnerDims::from_spec(&spec)?.with_preference_features(cfg.learner.preference_features());
    for c in &cfgs {
        check_declared(&c.learner, &spec.objectives)?;
    }
    let objectives: Vec<String> = spec.objectives.iter().map(|o| o.name.clone()).collect();

    let device = choose_device(&cfg.learner, &dims, cfgs.len())?;
    let Opened {
        runs: opened,
        learner,
    } = open_population(&cfgs, options.resume.as_deref(), &dims, device)?;
    let grid = learner.preference_grid().cloned().map(Arc::new);
    let conditioned: Vec<String> = grid.as_ref().map_or_else(Vec::new, |g| {
        g.conditioned_names()
            .into_iter()
            .map(String::from)
            .collect()
    });
    let layout = snippet_layout(&cfg, &dims, objectives.len());
    let mut runs = Vec::with_capacity(cfgs.len());
    let mut loops = Vec::with_capacity(cfgs.len());
    let mut evaluations = Vec::with_capacity(cfgs.len());
    for (p, (member_cfg, opened)) in cfgs.iter().zip(opened).enumerate() {
        let OpenedRun {
            run_dir,
            counters,
            resumed,
        } = opened;
        let files =
            Arc::new(RunFiles::open(&run_dir, &objectives, &conditioned).map_err(io(&run_dir))?);
        let first_acts: Vec<u64> = counters.actors.iter().map(|a| a.acts).collect();
        let schedule = Arc::new(schedule_for(
            member_cfg,
            layout,
            &objectives,
            counters,
            &run_dir,
            resumed.as_ref(),
        )?);
        let segments_end = resumed
            .as_ref()
            .and_then(|r| r.replay.as_ref())
            .map_or(0, |r| r.inserted);
        let (params_tx, params_rx) = watch::channel(Arc::new(learner.member_policy_snapshot(p)));
        let latest = Arc::new(Mutex::new(None));
        // Before any actor commits, so that no evaluation point is missed.
        let plan = EvalPlan {
            cfg: member_cfg.clone(),
            dims: dims.clone(),
            grid: grid.clone(),
            servers: servers.clone(),
            files: files.clone(),
        };
        evaluations.push(start_evaluations(plan, &schedule, params_rx.clone()));
        loops.push(MemberLoop {
            schedule: schedule.clone(),
            params: params_tx,
            files: files.clone(),
            latest: latest.clone(),
            checkpointer: Checkpointer::new(
                files.clone(),
                member_cfg.run.checkpoint_replay,
                segments_end,
            )
            .for_member(p),
        });
        runs.push(MemberRun {
            cfg: member_cfg.clone(),
            run_dir,
            files,
            schedule,
            params: params_rx,
            latest,
            first_acts,
        });
    }

    let learner_thread = {
        let ctx = LearnerContext {
            learner,
            members: loops,
            publish_period: cfg.run.publish_period,
            checkpoint_period: cfg.run.checkpoint_period,
            log_period: cfg.run.log_period,
        };
        std::thread::Builder::new()
            .name("learner".into())
            .spawn(move || run_learner(ctx))
            .map_err(io(&runs[0].run_dir))?
    };
    let stop_all = {
        let schedules: Vec<Arc<Schedule>> = runs.iter().map(|r| r.schedule.clone()).collect();
        move |reason: Option<String>| {
            for s in &schedules {
                s.stop(reason.clone());
            }
        }
    };

    let actors = spawn_actors(
        &ActorPlan {
            cfg: &cfg,
            runs: &runs,
            dims: &dims,
            servers: &servers,
            grid: grid.as_ref(),
            layout,
        },
        &stop_all,
    )?;

    // Periodic videos follow a single run's policy.
    let videos = options
        .video
        .as_ref()
        .filter(|_| runs.len() == 1)
        .and_then(|plan| {
            let run = &runs[0];
            let ctx = PeriodicContext {
                client: servers.first().client,
                cfg: cfg.clone(),
                dims: dims.clone(),
                preference: grid.as_deref().map(PreferenceGrid::default_features),
                params: run.params.clone(),
                schedule: run.schedule.clone(),
                dir: run.run_dir.join("videos"),
            };
            let every = plan.every?;
            Some(tokio::spawn(record_periodically(
                ctx,
                every,
                plan.options.clone(),
            )))
        });

    let mut bars = Vec::new();
    let mut tickers = Vec::new();
    for run in &runs {
        let bar = progress_bar(options.progress && runs.len() == 1, &cfg, &run.schedule);
        tickers.push(spawn_ticker(
            run.schedule.clone(),
            run.latest.clone(),
            bar.clone(),
            objectives.clone(),
        ));
        bars.push(bar);
    }

    for actor in actors {
        // The task itself catches panics; a join error is a cancelled runtime.
        if let Err(e) = actor.await {
            stop_all(Some(format!("an actor task ended abnormally: {e}")));
        }
    }
    stop_all(None);
    for ticker in tickers {
        ticker.abort();
    }
    if let Some(videos) = videos {
        videos.abort(); // a video in progress is cut short (its file may be incomplete)
    }
    let done = tokio::task::spawn_blocking(move || learner_thread.join())
        .await
        .map_err(|e| TrainError::Stopped(e.to_string()))?
        .map_err(|_| TrainError::Stopped("the learner thread panicked".into()))?;
    for bar in bars {
        bar.finish_and_clear();
    }
    if let Some(error) = runs.iter().find_map(|r| r.schedule.counters().error) {
        // The learner wrote a final checkpoint of every member before returning.
        return Err(TrainError::Stopped(error));
    }
    let LearnerDone { learner, policies } = done?;
    drop(learner);
    for (run, task) in runs.iter().zip(evaluations) {
        let interrupted = run.schedule.counters().interrupted.is_some();
        finish_evaluations(task, &run.schedule, interrupted, &run.run_dir).await?;
    }

    let mut summaries = Vec::with_capacity(runs.len());
    for (run, snapshot) in runs.iter().zip(policies) {
        summaries.push(
            finish_member(
                run,
                &snapshot,
                &servers,
                &dims,
                grid.as_deref(),
                &options,
                (&objectives, spec.discount, device, started),
            )
            .await?,
        );
    }
    Ok(summaries)
}

/// The text of a caught panic (`panic!` with a message gives a `&str` or a `String`).
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}
