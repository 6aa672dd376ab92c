//! Per-run files under `runs/<task>__<algo>__<seed>__<time>/`.
//!
//! - `config.toml`: the resolved config (what `--resume` reads back);
//! - `episodes.csv`: one row per finished training episode, with the server's
//!   undiscounted and discounted vector returns and the seconds since training began;
//! - `learner.jsonl`: learner statistics every `log_period` learner steps;
//! - `eval.csv`: the deterministic policy's evaluations every `run.eval_period` env
//!   steps, when asked for (`train/evals.rs`);
//! - `events.out.tfevents.*`: the same figures for TensorBoard, every chart by env
//!   step (training returns, learner statistics, throughput, final evaluation returns);
//! - `checkpoints/`, `replay/` (the checkpoints' replay segments), `summary.json`,
//!   `curves.{png,svg}` (written by `train`).

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::Serialize;

use crate::env::EpisodeSummary;
use crate::report::tensorboard::{EventWriter, Scalar};

/// The periodic evaluations of a run (`run.eval_period`, written by `train`).
pub const EVAL_CSV: &str = "eval.csv";

/// Append-only writers of one run directory.
#[derive(Debug)]
pub struct RunFiles {
    dir: PathBuf,
    objectives: Vec<String>,
    episodes: Mutex<BufWriter<File>>,
    learner: Mutex<BufWriter<File>>,
    events: Mutex<EventWriter>,
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
    /// ε-conditioned runs: the ε of each conditioned objective the episode acted with
    /// (columns `epsilon_<name>`); empty otherwise.
    pub preference: Vec<f64>,
}

fn append(path: &Path) -> std::io::Result<(BufWriter<File>, bool)> {
    let existed = path.exists() && std::fs::metadata(path)?.len() > 0;
    let file = OpenOptions::new().create(true).append(true).open(path)?;
    Ok((BufWriter::new(file), existed))
}

impl RunFiles {
    /// Open (or, when resuming, reopen for appending) the files of `dir`;
    /// `preference_names`: the conditioned objectives of an ε-conditioned run.
    pub fn open(
        dir: &Path,
        objective_names: &[String],
        preference_names: &[String],
    ) -> std::io::Result<Self> {
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
            header.extend(preference_names.iter().map(|n| format!("epsilon_{n}")));
            writeln!(episodes, "{}", header.join(","))?;
        }
        let (learner, _) = append(&dir.join("learner.jsonl"))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            objectives: objective_names.to_vec(),
            episodes: Mutex::new(episodes),
            learner: Mutex::new(learner),
            events: Mutex::new(EventWriter::create(dir)?),
        })
    }

    /// The run directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Objective names in reward order.
    pub fn objectives(&self) -> &[String] {
        &self.objectives
    }

    /// Append one episode row (and its returns to the TensorBoard file, by env step).
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
        row.extend(record.preference.iter().map(|v| v.to_string()));
        {
            let mut w = self.episodes.lock().unwrap_or_else(|p| p.into_inner());
            writeln!(w, "{}", row.join(","))?;
        }
        let mut scalars = self.per_objective("train/return", &e.episode_return);
        scalars.extend(self.per_objective("train/discounted_return", &e.discounted_return));
        scalars.push(Scalar::new("train/episode_length", e.length as f64));
        self.scalars(record.env_steps, &scalars)
    }

    /// `<prefix>/<objective name>` for each entry of a vector in reward order.
    pub fn per_objective(&self, prefix: &str, values: &[f64]) -> Vec<Scalar> {
        self.objectives
            .iter()
            .zip(values)
            .map(|(name, v)| Scalar::new(format!("{prefix}/{name}"), *v))
            .collect()
    }

    /// The TensorBoard event file this process writes (errors name it).
    pub fn events_path(&self) -> PathBuf {
        self.events
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .path()
            .to_path_buf()
    }

    /// Write scalars to the TensorBoard file at `step` (flushed with the other files).
    pub fn scalars(&self, step: u64, scalars: &[Scalar]) -> std::io::Result<()> {
        self.events
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .scalars(step, scalars)
    }

    /// Append one JSON line to `learner.jsonl`, then flush every file so a run can be
    /// followed with `tail -f` or TensorBoard (records come every `log_period` learner steps).
    pub fn learner<T: Serialize>(&self, record: &T) -> std::io::Result<()> {
        let line = serde_json::to_string(record).map_err(std::io::Error::other)?;
        {
            let mut w = self.learner.lock().unwrap_or_else(|p| p.into_inner());
            writeln!(w, "{line}")?;
        }
        self.flush()
    }

    /// Flush every file (at checkpoints, log records and exit).
    pub fn flush(&self) -> std::io::Result<()> {
        self.episodes
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .flush()?;
        self.events
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .flush()?;
        self.learner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .flush()
    }
}

/// One value rounded for reading: two decimals from 1 up, three significant digits
/// below (at most six decimals). Returns summed from float32 rewards carry float32
/// noise (0.7 arrives as 0.699999988079071), which no reader wants to see.
pub fn format_value(v: f64) -> String {
    let magnitude = v.abs();
    if !v.is_finite() || magnitude >= 1.0 {
        return format!("{v:.2}");
    }
    if magnitude == 0.0 {
        return "0.00".into();
    }
    let decimals = (2 - magnitude.log10().floor() as i32).clamp(2, 6) as usize;
    format!("{v:.decimals$}")
}

/// `[a, b, ...]` with each value rounded by [`format_value`].
pub fn format_vector(values: &[f64]) -> String {
    let parts: Vec<String> = values.iter().map(|v| format_value(*v)).collect();
    format!("[{}]", parts.join(", "))
}

/// The temperatures as a user reads them: the K values `[a, b]`, or for an
/// ε-conditioned learner's G x K (grid point by grid point) each objective's range
/// over the grid, `[0.0047..18.6, 4.3..11.0] over 22 grid points`.
pub fn format_temperatures(temperature: &[f32], k: usize) -> String {
    let values: Vec<f64> = temperature.iter().map(|&t| f64::from(t)).collect();
    if k == 0 || values.len() <= k {
        return format_vector(&values);
    }
    let ranges: Vec<String> = (0..k)
        .map(|j| {
            let column = values.iter().skip(j).step_by(k);
            let (lo, hi) = column.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
            format!("{}..{}", format_value(lo), format_value(hi))
        })
        .collect();
    format!(
        "[{}] over {} grid points",
        ranges.join(", "),
        values.len() / k
    )
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

/// Per objective, the mean over `rows` (each a vector of K values; empty: none).
pub fn mean_of<'a>(rows: impl Iterator<Item = &'a Vec<f64>>) -> Vec<f64> {
    let rows: Vec<&Vec<f64>> = rows.collect();
    let k = rows.first().map_or(0, |r| r.len());
    (0..k)
        .map(|i| rows.iter().map(|r| r[i]).sum::<f64>() / rows.len() as f64)
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn conditioned_temperatures_show_each_objectives_range() {
        assert_eq!(super::format_temperatures(&[1.5, 2.0], 2), "[1.50, 2.00]");
        let grid = [1.0, 5.0, 3.0, 0.5, 2.0, 4.0];
        assert_eq!(
            super::format_temperatures(&grid, 2),
            "[1.00..3.00, 0.500..5.00] over 3 grid points"
        );
    }

    use super::*;

    #[test]
    fn printed_values_are_rounded_for_reading() {
        assert_eq!(format_value(f64::from(0.7f32)), "0.700");
        assert_eq!(format_value(-0.012_345), "-0.0123");
        assert_eq!(format_value(124.0), "124.00");
        assert_eq!(format_value(-1234.5678), "-1234.57");
        assert_eq!(format_value(1e-9), "0.000000");
        assert_eq!(format_value(0.0), "0.00");
        assert_eq!(format_value(f64::NAN), "NaN");
        assert_eq!(format_vector(&[1.0, 0.25]), "[1.00, 0.250]");
    }
}
