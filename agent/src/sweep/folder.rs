//! A sweep's folder and what `--resume` and `--report` read from it: `sweep.toml` (the
//! sweep file as resolved, naming `base.toml`, the base config with the sweep's `set`
//! applied), `sweep.json` (the shard and the list of jobs it runs, written last, so
//! that its presence means a complete start), and per job `runs/<job:03>/<run>/`, the
//! job's run folder, whose final `summary.json` says the job finished.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use serde::{Deserialize, Serialize};

use super::{SweepConfig, SweepError, setting_label, shard::Shard};
use crate::core::learner_config::DeviceChoice;
use crate::env::connection::ConnectionConfig;
use crate::env::deadline::DeadlineConfig;
use crate::report::metrics::write_json_atomic;
use crate::runtime::checkpoint::run::latest_checkpoint;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::run_name;

/// The file that marks a sweep folder.
pub const SPEC_FILE: &str = "sweep.json";
/// The resolved sweep file in a sweep folder.
pub const SWEEP_FILE: &str = "sweep.toml";
/// The resolved base config in a sweep folder.
pub const BASE_FILE: &str = "base.toml";
/// `sweep.json`'s layout; a folder of another version is refused, not misread.
const FORMAT_VERSION: u32 = 1;

/// One run of a sweep: a setting with a seed, numbered by its place in the whole
/// sweep (settings in grid order, each with every seed in turn).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Job {
    /// Place in the whole sweep's job list; the run lives in `runs/<index:03>/`.
    pub index: usize,
    /// Objective name -> ε or weight.
    pub setting: BTreeMap<String, f64>,
    /// Seed of the run.
    pub seed: u64,
}

impl Job {
    /// `job 3 (time=0.01 treasure=0.5, seed 1)`, for messages.
    pub fn label(&self) -> String {
        format!(
            "job {} ({}, seed {})",
            self.index,
            setting_label(&self.setting),
            self.seed
        )
    }
}

/// Every job of `sweep`, in order.
pub fn all_jobs(sweep: &SweepConfig) -> Vec<Job> {
    sweep
        .settings()
        .into_iter()
        .flat_map(|s| sweep.seeds.iter().map(move |&seed| (s.clone(), seed)))
        .enumerate()
        .map(|(index, (setting, seed))| Job {
            index,
            setting,
            seed,
        })
        .collect()
}

/// `sweep.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    format_version: u32,
    /// `--shard`, when the folder holds one slice of the sweep.
    shard: Option<Shard>,
    /// The jobs this folder runs.
    jobs: Vec<Job>,
}

/// A sweep folder, opened.
#[derive(Debug, Clone)]
pub struct SweepFolder {
    /// The folder.
    pub dir: PathBuf,
    /// The sweep as resolved at the start (`base` = `base.toml`, `set` applied).
    pub sweep: SweepConfig,
    /// The base config every job's config is made from.
    pub base: TrainConfig,
    /// The slice of the sweep this folder runs, if any.
    pub shard: Option<Shard>,
    /// The jobs this folder runs.
    pub jobs: Vec<Job>,
}

/// Where a job stands in its folder.
#[derive(Debug, Clone)]
pub enum JobState {
    /// Not started: train from the start.
    Fresh,
    /// A run folder with neither a checkpoint nor a final summary: killed before its
    /// first checkpoint (or still before it, when another process runs the job now).
    /// Nothing in it can be continued; a resume removes it and starts over.
    Abandoned(PathBuf),
    /// Stopped with a checkpoint: continue the run in this folder.
    Checkpointed(PathBuf),
    /// Finished: the run folder and its final summary.
    Finished(PathBuf, RunResult),
}

/// What a sweep reads of a run's `summary.json` (a subset of
/// [`crate::runtime::train::TrainSummary`], so unknown fields are expected).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct RunResult {
    /// Objective names in reward order.
    pub objectives: Vec<String>,
    /// Mean undiscounted evaluation return per objective.
    pub eval_return: Vec<f64>,
    /// Mean discounted evaluation return per objective.
    pub eval_discounted_return: Vec<f64>,
    /// Set when a signal stopped the run before its budget (no evaluation then).
    pub interrupted: Option<String>,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> SweepError + '_ {
    move |source| SweepError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// `value` as TOML in `path`, replaced whole.
fn write_toml<T: Serialize>(path: &Path, value: &T) -> Result<(), SweepError> {
    let text = toml::to_string_pretty(value).map_err(|e| SweepError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e),
    })?;
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    std::fs::write(&tmp, text).map_err(io(path))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

impl SweepFolder {
    /// Start a sweep folder for `sweep` on `base` (`shard`: only its slice of the jobs):
    /// `dir` when given (made if missing, refused if it holds a sweep already), else a
    /// new `<runs_dir>/sweep__<name>[__shard<I>of<N>]__<UTC time>/`.
    pub fn create(
        sweep: &SweepConfig,
        base: &TrainConfig,
        shard: Option<Shard>,
        dir: Option<&Path>,
    ) -> Result<SweepFolder, SweepError> {
        let every = all_jobs(sweep);
        if let Some(s) = shard
            && s.count > every.len()
        {
            return Err(SweepError::TooManyShards {
                count: s.count,
                jobs: every.len(),
            });
        }
        let dir = match dir {
            Some(dir) => {
                if dir.join(SPEC_FILE).exists() {
                    return Err(SweepError::Exists {
                        dir: dir.to_path_buf(),
                    });
                }
                std::fs::create_dir_all(dir).map_err(io(dir))?;
                dir.to_path_buf()
            }
            None => {
                let stem = match shard {
                    Some(s) => format!("sweep__{}__shard{}of{}", sweep.name, s.index, s.count),
                    None => format!("sweep__{}", sweep.name),
                };
                run_name::create_run_dir(&base.run.runs_dir, &stem, SystemTime::now())
                    .map_err(io(&base.run.runs_dir))?
            }
        };
        let jobs: Vec<Job> = every
            .into_iter()
            .filter(|j| shard.is_none_or(|s| s.owns(j.index)))
            .collect();
        // The base is stored resolved, so the stored sweep has nothing left to `set`.
        let stored = SweepConfig {
            base: PathBuf::from(BASE_FILE),
            set: Vec::new(),
            ..sweep.clone()
        };
        write_toml(&dir.join(BASE_FILE), base)?;
        write_toml(&dir.join(SWEEP_FILE), &stored)?;
        let spec = Spec {
            format_version: FORMAT_VERSION,
            shard,
            jobs: jobs.clone(),
        };
        let spec_path = dir.join(SPEC_FILE);
        write_json_atomic(&spec_path, &spec).map_err(io(&spec_path))?;
        Ok(SweepFolder {
            dir,
            sweep: stored,
            base: base.clone(),
            shard,
            jobs,
        })
    }

    /// Open the sweep folder `dir`, checking that its job list is the one its sweep
    /// file makes.
    pub fn open(dir: &Path) -> Result<SweepFolder, SweepError> {
        let spec_path = dir.join(SPEC_FILE);
        let text = match std::fs::read_to_string(&spec_path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(SweepError::NotASweep {
                    dir: dir.to_path_buf(),
                });
            }
            Err(e) => return Err(io(&spec_path)(e)),
        };
        let content = |message: String| SweepError::Content {
            path: spec_path.clone(),
            message,
        };
        let spec: Spec = serde_json::from_str(&text).map_err(|e| content(e.to_string()))?;
        if spec.format_version != FORMAT_VERSION {
            return Err(content(format!(
                "format_version: expected {FORMAT_VERSION}, got {}",
                spec.format_version
            )));
        }
        let (sweep, base) = SweepConfig::load(&dir.join(SWEEP_FILE))?;
        let expected: Vec<Job> = all_jobs(&sweep)
            .into_iter()
            .filter(|j| spec.shard.is_none_or(|s| s.owns(j.index)))
            .collect();
        if spec.jobs != expected {
            return Err(content(format!(
                "jobs: expected the {} jobs {} makes{}, got {} others",
                expected.len(),
                SWEEP_FILE,
                spec.shard
                    .map_or(String::new(), |s| format!(" for shard {s}")),
                spec.jobs.len()
            )));
        }
        Ok(SweepFolder {
            dir: dir.to_path_buf(),
            sweep,
            base,
            shard: spec.shard,
            jobs: spec.jobs,
        })
    }

    /// The folder holding `job`'s run folder.
    pub fn job_dir(&self, job: &Job) -> PathBuf {
        self.dir.join("runs").join(format!("{:03}", job.index))
    }

    /// Where `job` stands (reads only: a report may run beside the sweep).
    pub fn job_state(&self, job: &Job) -> Result<JobState, SweepError> {
        let job_dir = self.job_dir(job);
        let runs: Vec<PathBuf> = match std::fs::read_dir(&job_dir) {
            Ok(entries) => entries
                .filter_map(|e| e.ok())
                .map(|e| e.path())
                .filter(|p| p.is_dir())
                .collect(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(JobState::Fresh),
            Err(e) => return Err(io(&job_dir)(e)),
        };
        let run = match runs.as_slice() {
            [] => return Ok(JobState::Fresh),
            [run] => run.clone(),
            _ => {
                return Err(SweepError::RunFolders {
                    dir: job_dir,
                    found: runs,
                });
            }
        };
        if let Some(result) = read_result(&run)?
            && result.interrupted.is_none()
        {
            return Ok(JobState::Finished(run, result));
        }
        if latest_checkpoint(&run).is_ok() {
            return Ok(JobState::Checkpointed(run));
        }
        Ok(JobState::Abandoned(run))
    }

    /// The sweep and base config with what may differ between two machines running
    /// the same sweep (learner device, servers, how to reach them and how long to wait
    /// for them) set aside.
    pub(super) fn comparable(&self) -> (SweepConfig, TrainConfig) {
        let mut base = self.base.clone();
        base.learner.device = DeviceChoice::default();
        base.env.servers.clear();
        base.env.connection = ConnectionConfig::default();
        base.env.deadlines = DeadlineConfig::default();
        (self.sweep.clone(), base)
    }
}

/// A run folder's final `summary.json`, when it has one.
fn read_result(run: &Path) -> Result<Option<RunResult>, SweepError> {
    let path = run.join("summary.json");
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io(&path)(e)),
    };
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|e| SweepError::Content {
            path,
            message: e.to_string(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-setting, two-seed sweep on the smoke DST config, its runs under `dir`.
    fn tiny(dir: &Path) -> (SweepConfig, TrainConfig) {
        let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
        std::fs::copy(smoke, dir.join("dst.toml")).unwrap();
        std::fs::write(
            dir.join("sweep.toml"),
            r#"
name = "t"
base = "dst.toml"
seeds = [0, 1]
set = ["learner.mpo.batch_size=32"]
reference_point = { time = -25.0, treasure = 0.0 }
[grid]
kind = "epsilon"
product = { time = [0.01], treasure = [0.1, 1.0] }
"#,
        )
        .unwrap();
        SweepConfig::load(&dir.join("sweep.toml")).unwrap()
    }

    #[test]
    fn a_shard_folder_reopens_alone_and_refuses_what_does_not_fit() {
        let tmp = tempfile::tempdir().unwrap();
        let (sweep, base) = tiny(tmp.path());
        let dir = tmp.path().join("shard");
        let shard = Some(Shard { index: 1, count: 2 });
        let made = SweepFolder::create(&sweep, &base, shard, Some(&dir)).unwrap();
        // Jobs 1 and 3 of (0.1, 0), (0.1, 1), (1.0, 0), (1.0, 1): seed 1 of each setting.
        let picked: Vec<(usize, u64)> = made.jobs.iter().map(|j| (j.index, j.seed)).collect();
        assert_eq!(picked, [(1, 1), (3, 1)]);
        let opened = SweepFolder::open(&dir).unwrap();
        assert_eq!(opened.jobs, made.jobs);
        assert_eq!(opened.shard, shard);
        // The sweep's `set` lives on in base.toml, not as overrides to apply again.
        assert!(opened.sweep.set.is_empty());
        assert_eq!(opened.base.learner.mpo.batch_size, 32);
        assert_eq!(opened.comparable(), made.comparable());

        let e = SweepFolder::create(&sweep, &base, shard, Some(&dir)).unwrap_err();
        assert!(matches!(e, SweepError::Exists { .. }), "{e}");
        let e = SweepFolder::create(&sweep, &base, Some(Shard { index: 0, count: 5 }), None);
        assert_eq!(
            e.unwrap_err().to_string(),
            "--shard: expected N at most 4 (the sweep has 4 jobs), got N = 5"
        );

        // Job states: none yet, a run folder with only its config, two run folders.
        let job = &opened.jobs[0];
        assert!(matches!(opened.job_state(job).unwrap(), JobState::Fresh));
        let run = opened.job_dir(job).join("dst__mompo__1__20261125-000000");
        std::fs::create_dir_all(&run).unwrap();
        assert!(matches!(opened.job_state(job).unwrap(), JobState::Abandoned(r) if r == run));
        assert!(run.exists(), "looking does not remove");
        std::fs::create_dir_all(opened.job_dir(job).join("other")).unwrap();
        let e = opened.job_state(job).unwrap_err().to_string();
        assert!(e.contains("expected one run folder"), "{e}");

        // A job list that is not the one the sweep file makes for the shard.
        let spec = dir.join(SPEC_FILE);
        let text = std::fs::read_to_string(&spec).unwrap();
        std::fs::write(&spec, text.replace("\"index\": 3", "\"index\": 2")).unwrap();
        let e = SweepFolder::open(&dir).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: jobs: expected the 2 jobs", spec.display()))
                && e.contains("for shard 1/2"),
            "{e}"
        );
        std::fs::write(
            &spec,
            text.replace("\"format_version\": 1", "\"format_version\": 9"),
        )
        .unwrap();
        let e = SweepFolder::open(&dir).unwrap_err().to_string();
        assert!(e.contains("format_version: expected 1, got 9"), "{e}");
    }
}
