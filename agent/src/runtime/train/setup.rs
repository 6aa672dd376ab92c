//! A run's state before its first step: the run directory (made, or reopened to
//! resume from its latest checkpoint, `resume.rs`), the learner, and the schedule
//! that paces actors and learner (replay layout, rate limit, counters, solve tracker).

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use tch::Device;

use super::{TrainError, TrainOptions, io};
use crate::core::algo::Learner;
use crate::core::algo::objectives::LearnerDims;
use crate::core::learner_config::ConfigError;
use crate::core::nets::ActionKind;
use crate::core::replay::{SnippetLayout, SnippetReplay};
use crate::runtime::checkpoint::run::{PaceOrigin, RunProgress};
use crate::runtime::resume::{Reopened, open_checkpoint, restore_schedule};
use crate::runtime::run_config::TrainConfig;
use crate::runtime::run_name;
use crate::runtime::schedule::{Counters, Pace, Schedule};
use crate::runtime::solve::SolveTracker;

/// One member's run directory and the counters it starts from.
pub(super) struct OpenedRun {
    pub run_dir: PathBuf,
    /// Zero for a new run; the checkpoint's progress when resuming.
    pub counters: Counters,
    /// The checkpoint resumed from.
    pub resumed: Option<RunProgress>,
}

/// The members' runs and their learner.
pub(super) struct Opened {
    pub runs: Vec<OpenedRun>,
    pub learner: Learner,
}

/// A new run directory holding the resolved `config.toml` per member, or, with
/// `resume` (one member), that directory's latest checkpoint.
pub(super) fn open_population(
    cfgs: &[TrainConfig],
    resume: Option<&Path>,
    dims: &LearnerDims,
    device: Device,
) -> Result<Opened, TrainError> {
    if let (Some(dir), [cfg]) = (resume, cfgs) {
        let Reopened { learner, progress } = open_checkpoint(dir, device)?;
        // The run's config as this invocation changed it (`--set` of the fields a
        // running run may change), for the next resume.
        write_config(dir, cfg)?;
        return Ok(Opened {
            runs: vec![OpenedRun {
                run_dir: dir.to_path_buf(),
                counters: Counters {
                    env_steps: progress.env_steps,
                    learner_steps: progress.learner_steps,
                    episodes: progress.episodes,
                    recent_returns: progress.recent_returns.iter().cloned().collect(),
                    actors: progress.actors.clone(),
                    ..Counters::default()
                },
                resumed: Some(progress),
            }],
            learner,
        });
    }
    let mut runs = Vec::with_capacity(cfgs.len());
    for cfg in cfgs {
        let dir = new_run_dir(cfg)?;
        write_config(&dir, cfg)?;
        runs.push(OpenedRun {
            run_dir: dir,
            counters: Counters::default(),
            resumed: None,
        });
    }
    let learners = cfgs.iter().map(|c| c.learner.clone()).collect();
    Ok(Opened {
        runs,
        learner: Learner::population(learners, dims.clone(), device)?,
    })
}

fn write_config(dir: &Path, cfg: &TrainConfig) -> Result<(), TrainError> {
    let path = dir.join("config.toml");
    let text = toml::to_string_pretty(cfg).map_err(|e| TrainError::Io {
        path: path.clone(),
        source: std::io::Error::other(e),
    })?;
    write_text_atomic(&path, &text).map_err(io(&path))
}

fn write_text_atomic(path: &Path, text: &str) -> std::io::Result<()> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, path)
}

/// How actors write snippets and the learner reads them.
pub(super) fn snippet_layout(
    cfg: &TrainConfig,
    dims: &LearnerDims,
    num_rewards: usize,
) -> SnippetLayout {
    SnippetLayout {
        length: cfg.learner.shared().sequence_length,
        obs_dim: dims.obs_dim as usize,
        action_width: match dims.action {
            ActionKind::Continuous { dim } => dim as usize,
            ActionKind::Discrete { .. } => 1,
        },
        num_rewards,
        discrete: matches!(dims.action, ActionKind::Discrete { .. }),
        on_policy: cfg.learner.algorithm.on_policy(),
    }
}

/// The schedule over a fresh replay, or the checkpoint's when resuming: off-policy,
/// the ratio pace after a warm-up; on-policy, a queue the actors fill one batch ahead.
pub(super) fn schedule_for(
    cfg: &TrainConfig,
    layout: SnippetLayout,
    objectives: &[String],
    counters: Counters,
    run_dir: &Path,
    resumed: Option<&RunProgress>,
) -> Result<Schedule, TrainError> {
    let settings = cfg.learner.shared();
    let (capacity, pace) = if layout.on_policy {
        // The queue never holds much more than one batch: actors wait for the learner.
        (
            usize::MAX,
            Pace::OnPolicy {
                batch_size: settings.batch_size,
            },
        )
    } else {
        let pace = Pace::Ratio {
            learner_steps_per_env_step: cfg.run.learner_steps_per_env_step,
            min_replay_transitions: cfg.run.min_replay_transitions.max(settings.sequence_length),
        };
        (cfg.learner.mpo.replay_capacity, pace)
    };
    let mut replay = SnippetReplay::new(layout, capacity, cfg.seed);
    let mut solve = SolveTracker::new(&cfg.run.solve_threshold, objectives)?;
    solve.stop_on_solve = cfg.run.stop_on_solve;
    let mut origin = PaceOrigin::default();
    if let Some(progress) = resumed {
        solve.restore(progress.solve.clone());
        origin = restore_schedule(run_dir, progress, &mut replay)?;
    }
    let counters = Counters { solve, ..counters };
    let elapsed_before = resumed.map_or(0.0, |p| p.wall_seconds);
    Ok(Schedule::new(replay, pace, counters, origin).continuing_from(elapsed_before))
}

/// A new folder `<runs_dir>/<task>__<algo>__<seed>__<UTC start time>` (see [`run_name`]).
fn new_run_dir(cfg: &TrainConfig) -> Result<PathBuf, TrainError> {
    let task: String = cfg
        .env
        .id
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let stem = format!("{task}__{}__{}", cfg.algo_name(), cfg.seed);
    run_name::create_run_dir(&cfg.run.runs_dir, &stem, SystemTime::now())
        .map_err(io(&cfg.run.runs_dir))
}

/// A population of more than one must be new and without periodic videos; its
/// members must share their population key.
pub(super) fn check_population_run(
    cfgs: &[TrainConfig],
    options: &TrainOptions,
) -> Result<(), TrainError> {
    let Some(first) = cfgs.first() else {
        return Err(TrainError::Stopped("a population needs a run".into()));
    };
    if cfgs.len() == 1 {
        return Ok(());
    }
    if options.resume.is_some() {
        return Err(TrainError::Stopped(
            "--resume continues one run; a population's members resume as single runs".into(),
        ));
    }
    let key = first.population_key();
    for (p, c) in cfgs.iter().enumerate().skip(1) {
        if c.population_key() != key {
            return Err(ConfigError::Invalid {
                field: format!("population member {p}"),
                requirement: "the first member's run config except seed, ε, \
                              scalarization weights and runs_dir"
                    .into(),
                got: "a run config that differs elsewhere".into(),
            }
            .into());
        }
    }
    let learners: Vec<_> = cfgs.iter().map(|c| c.learner.clone()).collect();
    crate::core::algo::population::check_population(&learners)?;
    Ok(())
}
