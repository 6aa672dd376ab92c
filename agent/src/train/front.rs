//! The end of an ε-conditioned run: its deterministic policy evaluated at every point
//! of its preference grid, measured and drawn as a sweep measures its runs
//! (`<run>/front/`: `points.csv`, `front.csv`, `summary.json`, `front.png`, and the
//! ratio plot when `[front]` asks for one; with one conditioned objective also
//! `returns.png`, every objective's evaluation return against its ε).

use std::path::Path;

use super::{TrainError, mean_of};
use crate::algo::preferences::PreferenceGrid;
use crate::env::pool::ServerPool;
use crate::eval::evaluate;
use crate::front::{FrontPoint, FrontReport, FrontSummary};
use crate::nets::{ActorPolicy, LearnerDims, PolicySnapshot};
use crate::plot::{Figure, Series, SeriesKind};
use crate::run_config::TrainConfig;
use tch::Device;

/// Evaluates `snapshot` at every grid point (`run.eval_episodes` episodes each) and
/// writes the front into `<run_dir>/front/`.
pub(super) async fn conditioned_front(
    cfg: &TrainConfig,
    servers: &ServerPool,
    grid: &PreferenceGrid,
    dims: &LearnerDims,
    snapshot: &PolicySnapshot,
    objectives: Vec<String>,
    run_dir: &Path,
) -> Result<FrontSummary, TrainError> {
    let front = cfg
        .front
        .as_ref()
        .expect("validate() requires [front] with learner.conditioning");
    let started = std::time::Instant::now();
    let client = servers.live().await?.client;
    let mut points = Vec::with_capacity(grid.len());
    for g in 0..grid.len() {
        let mut policy = ActorPolicy::new(&cfg.learner.network, dims, Device::Cpu);
        policy
            .load(snapshot)
            .map_err(|e| TrainError::Stopped(e.to_string()))?;
        let policy = policy.at_preference(&grid.features(g));
        let episodes = evaluate(&client, cfg, policy, cfg.run.eval_episodes).await?;
        points.push(FrontPoint {
            setting: grid.setting(g),
            seed: cfg.seed,
            eval_return: mean_of(episodes.iter().map(|e| &e.episode_return)),
            eval_discounted_return: mean_of(episodes.iter().map(|e| &e.discounted_return)),
            run_dir: run_dir.to_path_buf(),
            on_front: false,
        });
    }
    let dir = run_dir.join("front");
    std::fs::create_dir_all(&dir).map_err(|source| TrainError::Io {
        path: dir.clone(),
        source,
    })?;
    let name = run_dir
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let report = FrontReport {
        name: &name,
        reference_point: &front.reference_point,
        true_front: &front.true_front,
        ratio_plot: front.ratio_plot.as_ref(),
    };
    let summary = report.write(dir, objectives, points, started.elapsed().as_secs_f64())?;
    if let [axis] = grid.conditioned_names().as_slice() {
        crate::plot::save(
            &returns_figure(&name, axis, &summary),
            &summary.dir.join("returns"),
        )?;
    }
    Ok(summary)
}

/// Each objective's evaluation return against the one conditioned objective's ε.
fn returns_figure(name: &str, axis: &str, front: &FrontSummary) -> Figure {
    let series = front
        .objectives
        .iter()
        .enumerate()
        .map(|(k, objective)| {
            let mut points: Vec<(f64, f64)> = front
                .points
                .iter()
                .map(|p| (p.setting[axis], p.eval_return[k]))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series {
                label: format!("{objective} return"),
                points,
                kind: SeriesKind::Line,
            }
        })
        .collect();
    Figure {
        title: format!("{name}: evaluation returns against ε_{axis}"),
        x_label: format!("ε_{axis}"),
        y_label: "evaluation return".into(),
        series,
        log_x: true,
    }
}
