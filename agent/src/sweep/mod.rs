//! ε (or weight) sweeps that trace a Pareto front (paper Sec. 5, Table 4, Fig. 5).
//!
//! A sweep file names a base run config and a grid of settings. Every setting is
//! trained with every seed, its final deterministic policy evaluated, and the
//! undiscounted evaluation returns become the sweep's points. Written under
//! `runs/sweep__<name>__<UTC time>/`: `points.csv`, `front.csv`, `summary.json`
//! (hypervolume with the stated reference point, EUM), `front.{png,svg}` and, when
//! configured, the Fig. 5-style plot of one objective's return against an ε ratio.
//!
//! A sweep survives and spreads: its folder keeps what it was started with
//! (`folder.rs`), so `--resume` keeps the finished jobs and continues the others from
//! their checkpoints; `--shard I/N` runs the jobs j with j mod N = I in a folder of its
//! own (`shard.rs`); and the report is always made from the folders on disk
//! (`merge.rs`), which is how `--report` merges shards into the unsharded sweep's front.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

mod file;
mod folder;
mod merge;
mod shard;

pub use crate::report::front::{FrontPoint, FrontReport, FrontSummary, seeds};
pub use file::{Grid, GridKind, RatioPlot, SweepConfig, Values, apply};
pub use folder::{
    BASE_FILE, Job, JobState, RunResult, SPEC_FILE, SWEEP_FILE, SweepFolder, all_jobs,
};
pub use merge::report;
pub use shard::{Shard, ShardError};

use futures::StreamExt;

use crate::core::algo::population::unbatchable;
use crate::core::learner_config::ConfigError;
use crate::report::metrics::format_vector;
use crate::report::video::{VideoOptions, VideoPlan};
use crate::runtime::run_config::TrainConfig;
use crate::runtime::train::{TrainError, TrainOptions, train_population};

/// `pain=0.9 task=0.1`: each value rounded to 12 decimals, so that a complemented weight
/// (1 - 0.9) does not print as 0.09999999999999998.
pub fn setting_label(s: &BTreeMap<String, f64>) -> String {
    s.iter()
        .map(|(k, v)| format!("{k}={}", (v * 1e12).round() / 1e12))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Errors of a sweep, its resume and its report.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// A run of the sweep failed or was stopped.
    #[error(transparent)]
    Train(#[from] TrainError),
    /// The sweep file or base config is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Measuring or writing the front failed.
    #[error(transparent)]
    Front(#[from] crate::report::front::FrontError),
    /// A sweep file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// `--resume` or `--report` was given a folder that is no sweep's.
    #[error(
        "{dir}: expected a sweep folder (agent sweep writes {} there), found none",
        folder::SPEC_FILE
    )]
    NotASweep {
        /// The folder given.
        dir: PathBuf,
    },
    /// `--dir` names a folder that holds a sweep already.
    #[error(
        "--dir {dir}: expected a folder without a sweep, got one holding {}; continue it with --resume {dir}",
        folder::SPEC_FILE
    )]
    Exists {
        /// The folder given.
        dir: PathBuf,
    },
    /// `--shard I/N` with more shards than jobs (a shard without a job has no front).
    #[error("--shard: expected N at most {jobs} (the sweep has {jobs} jobs), got N = {count}")]
    TooManyShards {
        /// N.
        count: usize,
        /// Jobs in the sweep.
        jobs: usize,
    },
    /// A sweep folder's file does not hold what it should.
    #[error("{path}: {message}")]
    Content {
        /// File involved.
        path: PathBuf,
        /// What was expected and what it holds.
        message: String,
    },
    /// `--report` of folders from different sweeps.
    #[error(
        "{path}: expected the same as {first}, got a different one (the folders are not shards of one sweep)"
    )]
    Mismatch {
        /// The differing folder's sweep file or base config.
        path: PathBuf,
        /// The same file of the first folder given.
        first: PathBuf,
    },
    /// `--report` of folders that share a job.
    #[error(
        "{job} is in both {first} and {second}: expected each job in one folder (the same shard given twice?)"
    )]
    Overlap {
        /// The job.
        job: String,
        /// One folder holding it.
        first: PathBuf,
        /// The other.
        second: PathBuf,
    },
    /// `--report` of shard folders that leave jobs out.
    #[error("expected every job of the sweep in the folders {folders:?}, missing {}: a shard's folder left out?", jobs.join(", "))]
    Missing {
        /// The jobs no folder holds.
        jobs: Vec<String>,
        /// The folders given.
        folders: Vec<PathBuf>,
    },
    /// `--report` of a folder whose job has no final summary.
    #[error(
        "{job} has not finished: expected a run with a final summary.json in {dir}, got none (continue its sweep with --resume)"
    )]
    Unfinished {
        /// The job.
        job: String,
        /// Its job folder.
        dir: PathBuf,
    },
    /// A job folder with more than one run folder.
    #[error("{dir}: expected one run folder, found {found:?}")]
    RunFolders {
        /// The job folder.
        dir: PathBuf,
        /// The run folders in it.
        found: Vec<PathBuf>,
    },
    /// `--report` without a folder.
    #[error("--report: expected at least one sweep folder, got none")]
    NoFolders,
}

/// Run the whole sweep against `addresses` in a new folder; `progress` draws a bar
/// over the runs; `video` records each run's final evaluation
/// (`runs/<i>/<run>/videos/final.mp4`).
pub async fn sweep(
    sweep: &SweepConfig,
    base: &TrainConfig,
    addresses: &[String],
    progress: bool,
    video: Option<&VideoOptions>,
) -> Result<FrontSummary, SweepError> {
    let folder = SweepFolder::create(sweep, base, None, None)?;
    run(&folder, addresses, progress, video).await
}

/// Run `folder`'s jobs (a new sweep or shard, or one to resume) and report its front:
/// finished jobs are kept, a job with a checkpoint continues from it alone, the others
/// train from the start in populations (`populations`).
pub async fn run(
    folder: &SweepFolder,
    addresses: &[String],
    progress: bool,
    video: Option<&VideoOptions>,
) -> Result<FrontSummary, SweepError> {
    let started = Instant::now();
    let progress = Progress::new(progress, folder.jobs.len());
    let parallel = folder.sweep.parallel.max(1);
    let units = plan_units(folder, &progress, parallel)?;
    let runs = futures::stream::iter(
        units
            .into_iter()
            .map(|unit| train_unit(unit, folder, addresses, video, &progress)),
    )
    .buffer_unordered(parallel)
    .collect::<Vec<_>>()
    .await;
    runs.into_iter().collect::<Result<Vec<()>, _>>()?;
    progress.bar.finish_and_clear();
    merge::write_report(
        std::slice::from_ref(folder),
        folder.dir.clone(),
        started.elapsed().as_secs_f64(),
    )
}

/// A sweep's progress: a bar over its runs, and lines printed above it.
struct Progress {
    bar: indicatif::ProgressBar,
}

impl Progress {
    fn new(shown: bool, runs: usize) -> Self {
        let bar = if shown {
            indicatif::ProgressBar::new(runs as u64)
        } else {
            indicatif::ProgressBar::hidden()
        };
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:30} run {pos}/{len} [{elapsed_precise}<{eta}] {msg}",
            )
            .expect("valid template"),
        );
        Progress { bar }
    }

    fn say(&self, line: String) {
        // A bar drawn to a non-terminal is hidden and would swallow println.
        if self.bar.is_hidden() {
            tracing::info!("{}", line.trim())
        } else {
            self.bar.println(line)
        }
    }
}

/// What is left to train of `folder`'s jobs, as units that each train as one
/// population: finished jobs are kept (and counted done), a checkpointed job resumes
/// alone, an abandoned one (a folder without a checkpoint) starts over.
fn plan_units<'a>(
    folder: &'a SweepFolder,
    progress: &Progress,
    parallel: usize,
) -> Result<Vec<Vec<Unit<'a>>>, SweepError> {
    let mut units: Vec<Vec<Unit>> = Vec::new();
    let mut fresh = Vec::new();
    for job in &folder.jobs {
        let cfg = job_config(folder, job)?;
        match folder.job_state(job)? {
            JobState::Finished(run, _) => {
                let label = job.label();
                progress.say(format!("  {label}: finished in {}, kept", run.display()));
                progress.bar.inc(1);
            }
            JobState::Checkpointed(run) => {
                // As `agent train --resume`: the run continues as it was configured.
                let mut stored = TrainConfig::load(&run.join("config.toml"))?;
                // The job's folder is where the run is found now: the sweep folder may
                // have been moved, or be named by another path (relative, a mount).
                stored.run.runs_dir = cfg.run.runs_dir.clone();
                cfg.check_resume_changes(&stored)?;
                progress.say(format!("  {}: resuming {}", job.label(), run.display()));
                units.push(vec![Unit {
                    job,
                    cfg,
                    resume: Some(run),
                }]);
            }
            JobState::Abandoned(run) => {
                let label = job.label();
                progress.say(format!(
                    "  {label}: {} has no checkpoint, starting over",
                    run.display()
                ));
                std::fs::remove_dir_all(&run).map_err(|source| SweepError::Io {
                    path: run.clone(),
                    source,
                })?;
                fresh.push((job, cfg));
            }
            JobState::Fresh => fresh.push((job, cfg)),
        }
    }
    units.extend(populations(fresh, folder.sweep.population, parallel));
    Ok(units)
}

/// Trains one unit as a population and reports each of its runs; a signal that
/// interrupted them ends the sweep (it reached every run) instead of starting more.
async fn train_unit(
    unit: Vec<Unit<'_>>,
    folder: &SweepFolder,
    addresses: &[String],
    video: Option<&VideoOptions>,
    progress: &Progress,
) -> Result<(), SweepError> {
    let options = TrainOptions {
        resume: unit[0].resume.clone(),
        progress: false,
        video: video.map(|options| VideoPlan {
            every: None,
            options: options.clone(),
        }),
    };
    let cfgs = unit.iter().map(|u| u.cfg.clone()).collect();
    let summaries = train_population(cfgs, addresses, options).await?;
    for (u, s) in unit.iter().zip(&summaries) {
        if let Some(signal) = &s.interrupted {
            return Err(SweepError::Train(TrainError::Stopped(format!(
                "interrupted ({signal}); run {} has its checkpoint and report, \
                 and agent sweep --resume {} continues the sweep",
                s.run_dir.display(),
                folder.dir.display()
            ))));
        }
        progress.say(format!(
            "  {:<40} seed {}: eval return {}",
            setting_label(&u.job.setting),
            u.job.seed,
            format_vector(&s.eval_return)
        ));
        progress.bar.inc(1);
    }
    Ok(())
}

/// One job as it will train.
struct Unit<'a> {
    job: &'a Job,
    cfg: TrainConfig,
    /// Its run's folder, when it continues from a checkpoint (alone).
    resume: Option<PathBuf>,
}

/// The run config of `job`: the base with its setting and seed, in its own folder.
fn job_config(folder: &SweepFolder, job: &Job) -> Result<TrainConfig, SweepError> {
    let mut cfg = apply(&folder.base, &job.setting, job.seed)?;
    // One directory per job, so that each job's run is found by its index.
    cfg.run.runs_dir = folder.job_dir(job);
    if let Some(n) = folder.sweep.total_env_steps {
        cfg.run.total_env_steps = n;
    }
    Ok(cfg)
}

/// New jobs grouped into populations: jobs of one population key (in job order) that
/// batch, in at most `cap` members each, or (unset) split evenly into `parallel`
/// populations; jobs that do not batch train alone.
fn populations(
    jobs: Vec<(&Job, TrainConfig)>,
    cap: Option<usize>,
    parallel: usize,
) -> Vec<Vec<Unit<'_>>> {
    let mut groups: Vec<(String, Vec<Unit<'_>>)> = Vec::new();
    for (job, cfg) in jobs {
        let key = serde_json::to_string(&cfg.population_key()).unwrap_or_default();
        let unit = Unit {
            job,
            cfg,
            resume: None,
        };
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, members)) => members.push(unit),
            None => groups.push((key, vec![unit])),
        }
    }
    let mut out = Vec::new();
    for (_, members) in groups {
        let batches = unbatchable(&members[0].cfg.learner).is_none();
        let size = match (batches, cap) {
            (false, _) => 1,
            (true, Some(cap)) => cap,
            (true, None) => members.len().div_ceil(parallel),
        }
        .max(1);
        let mut members = members.into_iter().peekable();
        while members.peek().is_some() {
            out.push(members.by_ref().take(size).collect());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_round_complemented_weights() {
        // 1.0 - 0.9 is 0.09999999999999998 in f64; the label shows the weight meant.
        let s = BTreeMap::from([("pain".to_string(), 0.9), ("task".to_string(), 1.0 - 0.9)]);
        assert_eq!(setting_label(&s), "pain=0.9 task=0.1");
        let exact = BTreeMap::from([("task".to_string(), 0.01), ("pain".to_string(), 0.0015)]);
        assert_eq!(setting_label(&exact), "pain=0.0015 task=0.01");
    }
}
