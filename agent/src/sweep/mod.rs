//! ε (or weight) sweeps that trace a Pareto front (paper Sec. 5, Table 4, Fig. 5).
//!
//! A sweep file names a base run config and a grid of settings. Every setting is
//! trained with every seed, its final deterministic policy evaluated, and the
//! undiscounted evaluation returns become the sweep's points. Written under
//! `runs/sweep__<name>__<UTC time>/`: `points.csv`, `front.csv`, `summary.json`
//! (hypervolume with the stated reference point, EUM), `front.{png,svg}` and, when
//! configured, the Fig. 5-style plot of one objective's return against an ε ratio.

use std::collections::BTreeMap;
use std::time::{Instant, SystemTime};

mod config;

pub use crate::front::{FrontPoint, FrontReport, FrontSummary, seeds};
pub use config::{Grid, GridKind, RatioPlot, SweepConfig, Values, apply};

use futures::StreamExt;

use crate::metrics::format_vector;
use crate::run_config::TrainConfig;
use crate::run_name;
use crate::train::{TrainError, TrainOptions, TrainSummary, train};
use crate::video::{VideoOptions, VideoPlan};

/// `pain=0.9 task=0.1`: each value rounded to 12 decimals, so that a complemented weight
/// (1 - 0.9) does not print as 0.09999999999999998.
pub fn setting_label(s: &BTreeMap<String, f64>) -> String {
    s.iter()
        .map(|(k, v)| format!("{k}={}", (v * 1e12).round() / 1e12))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Run the whole sweep against `addresses`; `progress` draws a bar over the runs;
/// `video` records each run's final evaluation (`runs/<i>/<run>/videos/final.mp4`).
pub async fn sweep(
    sweep: &SweepConfig,
    base: &TrainConfig,
    addresses: &[String],
    progress: bool,
    video: Option<&VideoOptions>,
) -> Result<FrontSummary, TrainError> {
    let started = Instant::now();
    let stem = format!("sweep__{}", sweep.name);
    let dir = run_name::create_run_dir(&base.run.runs_dir, &stem, SystemTime::now()).map_err(
        |source| TrainError::Io {
            path: base.run.runs_dir.clone(),
            source,
        },
    )?;
    let jobs: Vec<(BTreeMap<String, f64>, u64)> = sweep
        .settings()
        .into_iter()
        .flat_map(|s| sweep.seeds.iter().map(move |&seed| (s.clone(), seed)))
        .collect();
    let bar = if progress {
        indicatif::ProgressBar::new(jobs.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:30} run {pos}/{len} [{elapsed_precise}<{eta}] {msg}",
        )
        .expect("valid template"),
    );
    let runs = futures::stream::iter(jobs.into_iter().enumerate().map(|(i, (setting, seed))| {
        let (bar, dir) = (bar.clone(), dir.clone());
        async move {
            let mut cfg = apply(base, &setting, seed)?;
            // One directory per job, so that each job's run is found by its index.
            cfg.run.runs_dir = dir.join("runs").join(format!("{i:03}"));
            if let Some(n) = sweep.total_env_steps {
                cfg.run.total_env_steps = n;
            }
            let s: TrainSummary = train(
                cfg,
                addresses,
                TrainOptions {
                    resume: None,
                    progress: false,
                    video: video.map(|options| VideoPlan {
                        every: None,
                        options: options.clone(),
                    }),
                },
            )
            .await?;
            if let Some(signal) = &s.interrupted {
                // The signal reached every run: end the sweep instead of starting more.
                return Err(TrainError::Stopped(format!(
                    "interrupted ({signal}); run {} has its checkpoint and report",
                    s.run_dir.display()
                )));
            }
            let line = format!(
                "  {:<40} seed {seed}: eval return {}",
                setting_label(&setting),
                format_vector(&s.eval_return)
            );
            // A bar drawn to a non-terminal is hidden and would swallow println.
            if bar.is_hidden() {
                tracing::info!("{}", line.trim())
            } else {
                bar.println(line)
            }
            bar.inc(1);
            Ok::<_, TrainError>((i, setting, seed, s))
        }
    }))
    .buffer_unordered(sweep.parallel.max(1))
    .collect::<Vec<_>>()
    .await;
    let mut finished = runs.into_iter().collect::<Result<Vec<_>, _>>()?;
    finished.sort_by_key(|(i, ..)| *i);
    let objectives = finished
        .first()
        .map(|(.., s)| s.objectives.clone())
        .unwrap_or_default();
    let points: Vec<FrontPoint> = finished
        .into_iter()
        .map(|(_, setting, seed, s)| FrontPoint {
            setting,
            seed,
            eval_return: s.eval_return,
            eval_discounted_return: s.eval_discounted_return,
            run_dir: s.run_dir,
            on_front: false,
        })
        .collect();
    bar.finish_and_clear();
    let report = FrontReport {
        name: &sweep.name,
        reference_point: &sweep.reference_point,
        true_front: &sweep.true_front,
        ratio_plot: sweep.ratio_plot.as_ref(),
    };
    Ok(report.write(dir, objectives, points, started.elapsed().as_secs_f64())?)
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
