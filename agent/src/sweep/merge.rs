//! A sweep's report from its folders: the finished jobs' run summaries, read back from
//! disk, become the front (`points.csv`, `front.csv`, `summary.json`, plots). An
//! unsharded sweep ends by reporting its own folder this way, and `agent sweep
//! --report A B ...` merges shard folders through the same code, so that the merged
//! files equal the unsharded sweep's apart from wall-clock fields and folder names.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use super::folder::{Job, JobState, SweepFolder, all_jobs};
use super::{FrontPoint, FrontReport, FrontSummary, SweepError};
use crate::runtime::run_name;

/// Report the sweep folders `dirs` (one sweep, or shards of one) into `out`: by
/// default the folder itself when there is one, else a new `sweep__<name>__<time>`
/// folder beside the first. Several folders must hold every job of the sweep once.
pub fn report(dirs: &[PathBuf], out: Option<&Path>) -> Result<FrontSummary, SweepError> {
    let folders: Vec<SweepFolder> = dirs
        .iter()
        .map(|d| SweepFolder::open(d))
        .collect::<Result<_, _>>()?;
    let Some(first) = folders.first() else {
        return Err(SweepError::NoFolders);
    };
    let out = match (out, dirs) {
        (Some(out), _) => {
            std::fs::create_dir_all(out).map_err(|source| SweepError::Io {
                path: out.to_path_buf(),
                source,
            })?;
            out.to_path_buf()
        }
        (None, [one]) => one.clone(),
        (None, _) => {
            let parent = first.dir.parent().unwrap_or(Path::new("."));
            let stem = format!("sweep__{}", first.sweep.name);
            run_name::create_run_dir(parent, &stem, SystemTime::now()).map_err(|source| {
                SweepError::Io {
                    path: parent.to_path_buf(),
                    source,
                }
            })?
        }
    };
    // Shards run side by side: the merged sweep took as long as its slowest shard.
    let wall_seconds = folders
        .iter()
        .filter_map(|f| reported_wall_seconds(&f.dir))
        .fold(0.0, f64::max);
    write_report(&folders, out, wall_seconds)
}

/// `wall_seconds` of a folder's own `summary.json`, when it has reported before.
fn reported_wall_seconds(dir: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(dir.join("summary.json")).ok()?;
    serde_json::from_str::<serde_json::Value>(&text).ok()?["wall_seconds"].as_f64()
}

/// Folders of one sweep: the same sweep file and base config as the first.
fn check_comparable(folders: &[SweepFolder]) -> Result<(), SweepError> {
    let first = &folders[0];
    let (sweep, base) = first.comparable();
    for f in &folders[1..] {
        let (other_sweep, other_base) = f.comparable();
        let differs = if other_sweep != sweep {
            Some(super::folder::SWEEP_FILE)
        } else if other_base != base {
            Some(super::folder::BASE_FILE)
        } else {
            None
        };
        if let Some(file) = differs {
            return Err(SweepError::Mismatch {
                path: f.dir.join(file),
                first: first.dir.join(file),
            });
        }
    }
    Ok(())
}

/// Every job of `folders` by index, each in exactly one folder; several folders must
/// together hold every job of the sweep.
fn jobs_once(folders: &[SweepFolder]) -> Result<BTreeMap<usize, (&SweepFolder, &Job)>, SweepError> {
    let mut jobs: BTreeMap<usize, (&SweepFolder, &Job)> = BTreeMap::new();
    for f in folders {
        for job in &f.jobs {
            if let Some((other, _)) = jobs.insert(job.index, (f, job)) {
                return Err(SweepError::Overlap {
                    job: job.label(),
                    first: other.dir.clone(),
                    second: f.dir.clone(),
                });
            }
        }
    }
    if folders.len() > 1 {
        let missing: Vec<String> = all_jobs(&folders[0].sweep)
            .iter()
            .filter(|j| !jobs.contains_key(&j.index))
            .map(Job::label)
            .collect();
        if !missing.is_empty() {
            return Err(SweepError::Missing {
                jobs: missing,
                folders: folders.iter().map(|f| f.dir.clone()).collect(),
            });
        }
    }
    Ok(jobs)
}

/// Measure and write the front of `folders`' jobs into `out`. One folder reports its
/// own jobs (a shard alone, its slice); several must agree on the sweep and hold
/// each of its jobs exactly once.
pub(super) fn write_report(
    folders: &[SweepFolder],
    out: PathBuf,
    wall_seconds: f64,
) -> Result<FrontSummary, SweepError> {
    check_comparable(folders)?;
    let jobs = jobs_once(folders)?;
    let mut objectives: Option<Vec<String>> = None;
    let mut points = Vec::with_capacity(jobs.len());
    for (folder, job) in jobs.values() {
        // Fresh, abandoned or checkpointed: no final summary to report.
        let JobState::Finished(run_dir, result) = folder.job_state(job)? else {
            return Err(SweepError::Unfinished {
                job: job.label(),
                dir: folder.job_dir(job),
            });
        };
        match &objectives {
            None => objectives = Some(result.objectives.clone()),
            Some(o) if *o != result.objectives => {
                return Err(SweepError::Content {
                    path: run_dir.join("summary.json"),
                    message: format!(
                        "objectives: expected {o:?} as in the sweep's other runs, got {:?}",
                        result.objectives
                    ),
                });
            }
            Some(_) => {}
        }
        points.push(FrontPoint {
            setting: job.setting.clone(),
            seed: job.seed,
            eval_return: result.eval_return,
            eval_discounted_return: result.eval_discounted_return,
            run_dir,
            on_front: false,
        });
    }
    let (sweep, _) = folders[0].comparable();
    let report = FrontReport {
        name: &sweep.name,
        reference_point: &sweep.reference_point,
        true_front: &sweep.true_front,
        ratio_plot: sweep.ratio_plot.as_ref(),
    };
    Ok(report.write(out, objectives.unwrap_or_default(), points, wall_seconds)?)
}
