//! The end of an ε-conditioned run: its deterministic policy evaluated at every point
//! of its preference grid, measured and drawn as a sweep measures its runs
//! (`<run>/front/`: `points.csv`, `front.csv`, `summary.json`, `front.png`, and the
//! ratio plot when `[front]` asks for one; with one conditioned objective also
//! `returns.png`: every objective's evaluation return against its ε, and the mean
//! training return of the run's last quarter of episodes at each ε).

use std::collections::BTreeMap;
use std::path::Path;

use super::TrainError;
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::nets::{ActorPolicy, LearnerDims, PolicySnapshot};
use crate::env::pool::ServerPool;
use crate::report::front::{FrontPoint, FrontReport, FrontSummary};
use crate::report::metrics::mean_of;
use crate::report::plot::{Figure, Series, SeriesKind};
use crate::runtime::eval::evaluate;
use crate::runtime::run_config::TrainConfig;
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
        let path = run_dir.join("episodes.csv");
        let episodes = std::fs::read_to_string(&path).map_err(|source| TrainError::Io {
            path: path.clone(),
            source,
        })?;
        let mut figure = returns_figure(&name, axis, &summary);
        figure
            .series
            .extend(training_returns(&episodes, axis, &summary.objectives));
        crate::report::plot::save(&figure, &summary.dir.join("returns"))?;
    }
    Ok(summary)
}

/// Per objective, the mean training return at each ε of the conditioned objective
/// `axis`, over the episodes that ended in the last quarter of the run's env steps
/// (`episodes.csv`, columns `env_steps`, `return_<objective>`, `epsilon_<axis>`).
fn training_returns(csv: &str, axis: &str, objectives: &[String]) -> Vec<Series> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name);
    let (Some(steps), Some(eps)) = (column("env_steps"), column(&format!("epsilon_{axis}"))) else {
        return Vec::new();
    };
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.parse().unwrap_or(f64::NAN))
                .collect()
        })
        .filter(|r: &Vec<f64>| r.len() == header.len())
        .collect();
    let last = rows.iter().map(|r| r[steps]).fold(0.0, f64::max);
    // Grid values are exact copies of one another, so their bits group them.
    let mut by_eps: BTreeMap<u64, Vec<&Vec<f64>>> = BTreeMap::new();
    for r in rows.iter().filter(|r| r[steps] >= 0.75 * last) {
        by_eps.entry(r[eps].to_bits()).or_default().push(r);
    }
    objectives
        .iter()
        .filter_map(|objective| {
            let col = column(&format!("return_{objective}"))?;
            let mut points: Vec<(f64, f64)> = by_eps
                .iter()
                .map(|(bits, rows)| {
                    let mean = rows.iter().map(|r| r[col]).sum::<f64>() / rows.len() as f64;
                    (f64::from_bits(*bits), mean)
                })
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Some(Series {
                label: format!("{objective} training return (last quarter)"),
                points,
                kind: SeriesKind::Markers,
            })
        })
        .collect()
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
                label: format!("{objective} evaluation return"),
                points,
                kind: SeriesKind::Line,
            }
        })
        .collect();
    Figure {
        title: format!("{name}: returns against ε_{axis}"),
        x_label: format!("ε_{axis}"),
        y_label: "episode return".into(),
        series,
        log_x: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn training_returns_average_the_last_quarter_per_epsilon() {
        // Rows at env steps 100 and 200 are before the last quarter (>= 300 of 400).
        let csv = "env_steps,actor,return_a,return_b,wall_seconds,epsilon_x\n\
                   100,0,-9,-9,0.1,0.5\n\
                   300,0,-1,-2,0.1,0.5\n\
                   400,0,-3,-4,0.1,0.5\n\
                   400,0,-5,-6,0.1,0.05\n\
                   200,0,-9,-9,0.1,0.05\n";
        let series = training_returns(csv, "x", &["a".into(), "b".into()]);
        assert_eq!(series.len(), 2);
        assert_eq!(series[0].points, vec![(0.05, -5.0), (0.5, -2.0)]);
        assert_eq!(series[1].points, vec![(0.05, -6.0), (0.5, -3.0)]);
        assert!(training_returns(csv, "y", &["a".into()]).is_empty());
    }
}
