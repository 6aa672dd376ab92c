//! A sweep's files: `points.csv`, `front.csv`, `summary.json`, `front.{png,svg}` and
//! the optional ε-ratio plot.

use std::collections::BTreeMap;
use std::path::PathBuf;

use super::{FrontError, FrontReport, FrontSummary, RatioPlot, invalid};
use crate::report::metrics::write_json_atomic;
use crate::report::pareto::attainment_surface;
use crate::report::plot::{Figure, Series, SeriesKind};

/// Writes every file of a sweep's front into its folder.
pub(super) fn write_outputs(sweep: &FrontReport<'_>, s: &FrontSummary) -> Result<(), FrontError> {
    let csv = points_csv(s);
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
        crate::report::plot::save(&front_figure(sweep.name, s), &s.dir.join("front"))?;
    }
    if let Some(rp) = sweep.ratio_plot {
        crate::report::plot::save(&ratio_figure(sweep.name, rp, s)?, &s.dir.join("ratio"))?;
    }
    Ok(())
}

/// Names `path` in an I/O error.
fn io(path: PathBuf) -> impl FnOnce(std::io::Error) -> FrontError {
    move |source| FrontError::Io { path, source }
}

/// `points.csv`: a row per run (setting, seed, returns, discounted returns, whether it
/// is on the front, its folder).
fn points_csv(s: &FrontSummary) -> String {
    let names: Vec<String> = s
        .points
        .first()
        .map(|p| p.setting.keys().cloned().collect())
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
    csv
}

/// The ε-ratio plot (the paper's Fig. 5): `y_objective`'s return against the ratio of
/// two objectives' ε, a series per value of the denominator's ε.
fn ratio_figure(name: &str, rp: &RatioPlot, s: &FrontSummary) -> Result<Figure, FrontError> {
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
    // Steps, not lines: between two tried ratios nothing says the policy collects
    // anything in between (DST's treasures are discrete).
    let mut series: Vec<Series> = by_series
        .into_iter()
        .map(|(label, mut points)| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series {
                label,
                points,
                kind: SeriesKind::Steps,
            }
        })
        .collect();
    if !s.true_front.is_empty() {
        let x = series
            .iter()
            .flat_map(|r| r.points.iter().map(|p| p.0))
            .fold(f64::INFINITY, f64::min);
        series.insert(
            0,
            Series {
                label: format!("{} on the true front", rp.y_objective),
                points: s.true_front.iter().map(|p| (x, p[y])).collect(),
                kind: SeriesKind::Levels,
            },
        );
    }
    Ok(Figure {
        title: format!("{name}: {} reached vs ε ratio", rp.y_objective),
        x_label: format!("ε_{} / ε_{}", rp.numerator, rp.denominator),
        y_label: format!("{} return", rp.y_objective),
        series,
        log_x: true,
    })
}

/// The first two objectives' returns: the region the found front dominates above the
/// reference point (a staircase, which invents no trade-off between points), every run
/// as a marker per seed, the reference point, and the true front when known.
fn front_figure(name: &str, s: &FrontSummary) -> Figure {
    let xy = |p: &[f64]| (p[0], p[1]);
    let reference = xy(&s.reference_point);
    let all: Vec<(f64, f64)> = s.points.iter().map(|p| xy(&p.eval_return)).collect();
    let mut series = vec![Series {
        label: "dominated region of the found front".into(),
        points: attainment_surface(&all, reference),
        kind: SeriesKind::Region,
    }];
    if !s.true_front.is_empty() {
        series.push(Series {
            label: "true Pareto front".into(),
            points: s.true_front.iter().map(|p| xy(p)).collect(),
            kind: SeriesKind::OpenMarkers,
        });
    }
    let mut by_seed: BTreeMap<u64, Vec<(f64, f64)>> = BTreeMap::new();
    for p in &s.points {
        by_seed.entry(p.seed).or_default().push(xy(&p.eval_return));
    }
    series.extend(by_seed.into_iter().map(|(seed, points)| Series {
        label: format!("runs, seed {seed}"),
        points,
        kind: SeriesKind::Markers,
    }));
    series.push(Series {
        label: "reference point".into(),
        points: vec![reference],
        kind: SeriesKind::Crosses,
    });
    let mut title = format!("{name}: hypervolume {:.1}", s.hypervolume);
    if let Some(best) = s.true_hypervolume {
        title.push_str(&format!(" of {best:.1}"));
    }
    Figure {
        title,
        x_label: format!("{} return", s.objectives[0]),
        y_label: format!("{} return", s.objectives[1]),
        series,
        log_x: false,
    }
}
