//! A sweep's files: `points.csv`, `front.csv`, `summary.json`, `front.{png,svg}` and
//! the optional ε-ratio plot.

use std::collections::BTreeMap;
use std::path::PathBuf;

use super::{SweepConfig, SweepPoint, SweepSummary, invalid};
use crate::metrics::write_json_atomic;
use crate::plot::{Figure, Series, SeriesKind};
use crate::train::TrainError;

pub(super) fn write_outputs(sweep: &SweepConfig, s: &SweepSummary) -> Result<(), TrainError> {
    let io = |path: PathBuf| move |source| TrainError::Io { path, source };
    let names: Vec<String> = sweep
        .settings()
        .first()
        .map(|f| f.keys().cloned().collect())
        .unwrap_or_default();
    let mut csv = String::new();
    let header: Vec<String> = names
        .iter()
        .map(|n| format!("setting_{n}"))
        .chain(["seed".into()])
        .chain(s.objectives.iter().map(|o| format!("return_{o}")))
        .chain(
            s.objectives
                .iter()
                .map(|o| format!("discounted_return_{o}")),
        )
        .chain(["on_front".into(), "run_dir".into()])
        .collect();
    csv.push_str(&header.join(","));
    csv.push('\n');
    for p in &s.points {
        let row: Vec<String> = names
            .iter()
            .map(|n| p.setting.get(n).map_or(String::new(), |v| v.to_string()))
            .chain([p.seed.to_string()])
            .chain(p.eval_return.iter().map(|v| v.to_string()))
            .chain(p.eval_discounted_return.iter().map(|v| v.to_string()))
            .chain([p.on_front.to_string(), p.run_dir.display().to_string()])
            .collect();
        csv.push_str(&row.join(","));
        csv.push('\n');
    }
    let points_csv = s.dir.join("points.csv");
    std::fs::write(&points_csv, &csv).map_err(io(points_csv.clone()))?;
    let front: Vec<&str> = csv
        .lines()
        .enumerate()
        .filter(|(i, l)| *i == 0 || l.contains(",true,"))
        .map(|(_, l)| l)
        .collect();
    let front_csv = s.dir.join("front.csv");
    std::fs::write(&front_csv, front.join("\n") + "\n").map_err(io(front_csv.clone()))?;
    write_json_atomic(&s.dir.join("summary.json"), s).map_err(io(s.dir.join("summary.json")))?;
    if s.objectives.len() >= 2 {
        let xy = |p: &SweepPoint| (p.eval_return[0], p.eval_return[1]);
        let mut front: Vec<(f64, f64)> = s.points.iter().filter(|p| p.on_front).map(xy).collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        let figure = Figure {
            title: format!("{}: hypervolume {:.1}", sweep.name, s.hypervolume),
            x_label: format!("{} return", s.objectives[0]),
            y_label: format!("{} return", s.objectives[1]),
            series: vec![
                Series {
                    label: "all runs".into(),
                    points: s.points.iter().map(xy).collect(),
                    kind: SeriesKind::Markers,
                },
                Series {
                    label: "non-dominated".into(),
                    points: front,
                    kind: SeriesKind::Line,
                },
            ],
            log_x: false,
        };
        crate::plot::save(&figure, &s.dir.join("front"))?;
    }
    if let Some(rp) = &sweep.ratio_plot {
        let y = s
            .objectives
            .iter()
            .position(|o| o == &rp.y_objective)
            .ok_or_else(|| invalid("ratio_plot.y_objective", "an objective", &rp.y_objective))?;
        let mut by_series: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
        for p in &s.points {
            let ratio = p.setting[&rp.numerator] / p.setting[&rp.denominator];
            by_series
                .entry(format!(
                    "ε_{} = {}",
                    rp.denominator, p.setting[&rp.denominator]
                ))
                .or_default()
                .push((ratio, p.eval_return[y]));
        }
        let series = by_series
            .into_iter()
            .map(|(label, mut points)| {
                points.sort_by(|a, b| a.0.total_cmp(&b.0));
                Series {
                    label,
                    points,
                    kind: SeriesKind::Line,
                }
            })
            .collect();
        let figure = Figure {
            title: format!("{}: {} reached vs ε ratio", sweep.name, rp.y_objective),
            x_label: format!("ε_{} / ε_{}", rp.numerator, rp.denominator),
            y_label: format!("{} return", rp.y_objective),
            series,
            log_x: true,
        };
        crate::plot::save(&figure, &s.dir.join("ratio"))?;
    }
    Ok(())
}
