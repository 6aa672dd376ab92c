//! Per-run files under `runs/<task>__<algo>__<seed>__<time>/`.
//!
//! - `config.toml`: the resolved config (what `--resume` reads back);
//! - `episodes.csv`: one row per finished training episode, with the server's
//!   undiscounted and discounted vector returns and the seconds since training began;
//! - `learner.jsonl`: learner statistics every `log_period` learner steps;
//! - `checkpoints/`, `summary.json`, `curves.{png,svg}` (written by `train`).

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::Serialize;

use crate::env::EpisodeSummary;

/// Append-only writers of one run directory.
#[derive(Debug)]
pub struct RunFiles {
    dir: PathBuf,
    episodes: Mutex<BufWriter<File>>,
    learner: Mutex<BufWriter<File>>,
}

/// One row of `episodes.csv`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpisodeRecord {
    /// Env steps of the run when the episode ended.
    pub env_steps: u64,
    /// Actor that ran it.
    pub actor: usize,
    /// The server's summary.
    pub episode: EpisodeSummary,
    /// Seconds since this `train` invocation began training (`Schedule::elapsed_seconds`).
    pub wall_seconds: f64,
}

fn append(path: &Path) -> std::io::Result<(BufWriter<File>, bool)> {
    let existed = path.exists() && std::fs::metadata(path)?.len() > 0;
    let file = OpenOptions::new().create(true).append(true).open(path)?;
    Ok((BufWriter::new(file), existed))
}

impl RunFiles {
    /// Open (or, when resuming, reopen for appending) the files of `dir`.
    pub fn open(dir: &Path, objective_names: &[String]) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let (mut episodes, existed) = append(&dir.join("episodes.csv"))?;
        if !existed {
            let mut header = vec![
                "env_steps".to_string(),
                "actor".into(),
                "env_index".into(),
                "length".into(),
            ];
            header.extend(objective_names.iter().map(|n| format!("return_{n}")));
            header.extend(
                objective_names
                    .iter()
                    .map(|n| format!("discounted_return_{n}")),
            );
            header.push("terminated".into());
            header.push("wall_seconds".into());
            writeln!(episodes, "{}", header.join(","))?;
        }
        let (learner, _) = append(&dir.join("learner.jsonl"))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            episodes: Mutex::new(episodes),
            learner: Mutex::new(learner),
        })
    }

    /// The run directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Append one episode row.
    pub fn episode(&self, record: &EpisodeRecord) -> std::io::Result<()> {
        let e = &record.episode;
        let mut row = vec![
            record.env_steps.to_string(),
            record.actor.to_string(),
            e.env_index.to_string(),
            e.length.to_string(),
        ];
        row.extend(e.episode_return.iter().map(|v| format!("{v}")));
        row.extend(e.discounted_return.iter().map(|v| format!("{v}")));
        row.push(e.terminated.to_string());
        row.push(format!("{:.3}", record.wall_seconds));
        let mut w = self.episodes.lock().unwrap_or_else(|p| p.into_inner());
        writeln!(w, "{}", row.join(","))
    }

    /// Append one JSON line to `learner.jsonl`, then flush both files so a run can be
    /// followed with `tail -f` (records come every `log_period` learner steps).
    pub fn learner<T: Serialize>(&self, record: &T) -> std::io::Result<()> {
        let line = serde_json::to_string(record).map_err(std::io::Error::other)?;
        {
            let mut w = self.learner.lock().unwrap_or_else(|p| p.into_inner());
            writeln!(w, "{line}")?;
        }
        self.flush()
    }

    /// Flush both files (at checkpoints and at exit).
    pub fn flush(&self) -> std::io::Result<()> {
        self.episodes
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .flush()?;
        self.learner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .flush()
    }
}

/// Write `value` as pretty JSON to `path` atomically (temp file + rename).
pub fn write_json_atomic<T: Serialize>(path: &Path, value: &T) -> std::io::Result<()> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    let text = serde_json::to_string_pretty(value).map_err(std::io::Error::other)?;
    {
        let mut f = File::create(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}
